"""The campaigns, one record each: what a campaign is called, what plans it, how it runs, what reads its bags.

ROS-free: the CLI, the graph parameters, the launch code, compare and the atlas look campaigns up
here, so adding a campaign is one module under ``campaigns/`` plus one entry in :data:`CAMPAIGNS` (and its
named plans, config/plans/<campaign>-<variant>.yaml).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from types import MappingProxyType
from typing import Any, Callable, Mapping

from sofia_ros.errors import ConfigError

__all__ = ['CAMPAIGNS', 'CampaignSpec', 'campaign_named']


@dataclass(frozen=True)
class CampaignSpec:
    """One campaign: its plan dataclass, how its graph is configured and run, its named plans."""

    name: str
    #: one line for `sofia run --help` and the README
    summary: str
    #: the plan dataclass (None: the campaign has no node graph and no plan, e.g. gyro-stability)
    plan_type: type | None
    #: (truth, seed, plan) -> sim.graph.GraphConfig; None for a campaign without a node graph
    build_config: Callable[..., Any] | None
    #: runs it and writes the bag and its side files: campaigns.<module>.run_<campaign>
    run: Callable[..., Any]
    #: the offline tools that understand its bags ('compare', 'noise')
    analyses: tuple[str, ...]
    #: its named plans, each the plan file config/plans/<campaign>-<variant>.yaml ('full': the thesis' own)
    variants: tuple[str, ...] = ('full',)

    def plan(self, variant: str = 'full', **overrides: Any) -> Any:
        """The plan of a named variant (fields overridden by ``overrides``); ConfigError for an unknown variant."""
        from sofia_ros.campaigns.plan_files import read_plan_file, variant_plan_path

        if self.plan_type is None:
            raise ConfigError(f'the {self.name} campaign has no plan; it takes its own options')
        if variant not in self.variants:
            raise ConfigError(f'the {self.name} campaign has no variant {variant!r}; '
                              f'use one of {", ".join(self.variants)}')
        return replace(read_plan_file(variant_plan_path(self.name, variant), self.name), **overrides)


def _alignment() -> CampaignSpec:
    from sofia_ros.campaigns.alignment import graph_config, run_alignment
    from sofia_ros.sim.calibration import AlignmentPlan

    # 'minimal' is the atlas' tests' plan: the same code path at the least sim time (one frame, no series).
    return CampaignSpec(
        AlignmentPlan.campaign, 'Table 3.4 at the reference elevation on Polaris, then the boresight series (6.1, 6.2)',
        AlignmentPlan, graph_config, run_alignment, ('compare',), ('full', 'reduced', 'minimal'))


def _star_hop() -> CampaignSpec:
    from sofia_ros.campaigns.star_hop import run_star_hop, star_hop_config
    from sofia_ros.sim.star_hop import StarHopPlan

    return CampaignSpec(
        StarHopPlan.campaign,
        "Table D.3's 17 observations of six stars: absolute pointing and differential flexure (6.2, 6.3)",
        StarHopPlan, star_hop_config, run_star_hop, ('compare',), ('full', 'reduced'))


def _gyro_stability() -> CampaignSpec:
    from sofia_ros.campaigns.gyro_stability import run_gyro_stability

    return CampaignSpec('gyro-stability', 'the gyro box alone, one Table 5.2 test case (5.3)',
                        None, None, run_gyro_stability, ('noise',), ())


#: every campaign by name, in the order `sofia run` lists them
CAMPAIGNS: Mapping[str, CampaignSpec] = MappingProxyType(
    {spec.name: spec for spec in (_alignment(), _star_hop(), _gyro_stability())})


def campaign_named(name: str) -> CampaignSpec:
    """The campaign called ``name``; ConfigError naming the known ones otherwise."""
    try:
        return CAMPAIGNS[name]
    except KeyError as err:
        raise ConfigError(f'unknown campaign {name!r}; available: {", ".join(CAMPAIGNS)}') from err

