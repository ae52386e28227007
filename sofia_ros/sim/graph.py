"""The node graph of a campaign: which cores exist, how each is built, and the topics between them.

Every process builds its core from the same :class:`GraphConfig`, so one process
and many processes run identical cores with identical seeds.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Iterable, Sequence

import numpy as np

from sofia_ros.config import EffectConfig
from sofia_ros.errors import ConfigError
from sofia_ros.graph_nodes import CAMERAS, NODE_NAMES, SEEDED_NODES
from sofia_ros.scenario import Scenario
from sofia_ros.sim.calibration import AlignmentPlan, CalibrationCore
from sofia_ros.sim.camera import CameraCore
from sofia_ros.sim.clock import ClockCore
from sofia_ros.sim.gyro_box import GyroBoxCore
from sofia_ros.sim.plant import PlantCore
from sofia_ros.sim.protocol import NodeCore
from sofia_ros.sim.star_hop import StarHopCore, StarHopPlan
from sofia_ros.sim.tascu import TascuCore
from sofia_ros.topics import DEFAULT_TICK_NS

__all__ = ['DEFAULT_MAX_SIM_S', 'GraphConfig', 'build_core', 'build_cores', 'graph_topics', 'topic_table_markdown']

#: Sim time after which the clock stops a graph run unless the campaign gives its own budget (the full
#: alignment campaign takes about 1850 s).
DEFAULT_MAX_SIM_S = 7200.0


@dataclass(frozen=True)
class GraphConfig:
    """Everything a node needs to build its core: truth, scenario, seed, campaign plan, tick."""

    truth: EffectConfig
    scenario: Scenario
    seed: int
    #: the campaign's plan: its dataclass (campaigns.registry) decides the calibration node's sequence
    plan: AlignmentPlan | StarHopPlan = field(default_factory=AlignmentPlan)
    tick_ns: int = DEFAULT_TICK_NS
    fd_braked: bool = False

    def node_seed(self, name: str) -> int:
        """The seed of node ``name``, drawn from the run seed in NODE_NAMES order."""
        children = np.random.SeedSequence(self.seed).spawn(len(SEEDED_NODES))
        return int(children[SEEDED_NODES.index(name)].generate_state(1)[0])


def build_core(name: str, config: GraphConfig) -> NodeCore:
    """The core of node ``name`` for this graph."""
    effects = config.truth.effects
    if name == 'clock':
        return ClockCore()
    if name == 'plant':
        return PlantCore(config.scenario, effects, fd_braked=config.fd_braked, tick_ns=config.tick_ns)
    if name == 'gyro_box':
        return GyroBoxCore(effects, seed=config.node_seed(name))
    if name in CAMERAS:
        return CameraCore(name, config.scenario, effects, seed=config.node_seed(name))
    if name == 'tascu':
        return TascuCore()
    if name == 'calibration':
        if isinstance(config.plan, StarHopPlan):
            return StarHopCore(config.plan, config.scenario)
        return CalibrationCore(config.plan, config.scenario)
    raise ConfigError(f'unknown node {name!r}; nodes are {", ".join(NODE_NAMES)}')


def build_cores(config: GraphConfig, names: Sequence[str] = NODE_NAMES) -> list[NodeCore]:
    """Cores of the named nodes."""
    return [build_core(name, config) for name in names]


def graph_topics(cores: Iterable[NodeCore]) -> dict[str, tuple[str, str | None, tuple[str, ...]]]:
    """topic -> (msgtype, publisher node, subscriber nodes) over a set of cores."""
    topics = {}
    for core in cores:
        for spec in core.outputs():
            topics.setdefault(spec.name, [spec.msgtype, None, []])[1] = core.name
    for core in cores:
        for spec in core.inputs():
            topics.setdefault(spec.name, [spec.msgtype, None, []])[2].append(core.name)
    return {name: (msgtype, publisher, tuple(subscribers)) for name, (msgtype, publisher, subscribers) in topics.items()}


def topic_table_markdown(config: GraphConfig) -> str:
    """The topic table of docs/topics.md: every topic of the graph with type, publisher, subscribers, meaning."""
    cores = build_cores(config)
    meanings = {spec.name: spec.meaning for core in cores for spec in (*core.outputs(), *core.inputs())}
    rows = ['| topic | type | published by | subscribed by (and the recorder) | meaning |', '|---|---|---|---|---|']
    for name, (msgtype, publisher, subscribers) in sorted(graph_topics(cores).items()):
        if publisher is None:
            continue
        rows.append(f'| `{name}` | `{msgtype}` | {publisher} | {", ".join(subscribers) or "-"} '
                    f'| {meanings[name]} |')
    return '\n'.join(rows)
