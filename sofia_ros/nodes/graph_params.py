"""Node parameters that describe the graph (truth file, seed, plan, tick), shared by every node."""

from __future__ import annotations

from dataclasses import asdict, fields

import yaml

from sofia_ros.config import load_effect_config
from sofia_ros.errors import ConfigError
from sofia_ros.sim.calibration import AlignmentPlan
from sofia_ros.sim.protocol import DEFAULT_TICK_NS

__all__ = ['GRAPH_PARAMETERS', 'graph_parameters', 'graph_config_from_parameters', 'write_params_file']

#: name -> (default, description)
GRAPH_PARAMETERS = {
    'campaign': ('alignment', 'campaign whose graph this node belongs to'),
    'truth_file': ('', 'truth YAML (effects: ..., scenario: ...) of the run'),
    'seed': (0, 'run seed; each node draws its own stream from it'),
    'tick_ns': (DEFAULT_TICK_NS, 'lock-step tick in ns of sim time'),
    'max_sim_s': (7200.0, 'the clock stops the run after this much sim time'),
    'stall_timeout_s': (15.0, 'the clock stops the run when a node is silent this long (wall time)'),
    'bag_path': ('', 'recorder: output bag directory'),
    'model_file': ('', 'recorder: model YAML stored in the bag as /config/model'),
    **{f'plan.{f.name}': (f.default, f'calibration plan: {f.name}') for f in fields(AlignmentPlan)},
}


def graph_parameters(truth_file, seed, plan, *, tick_ns, max_sim_s, bag_path='', stall_timeout_s=15.0, model_file=''):
    """Parameter values of one run."""
    values = {'campaign': 'alignment', 'truth_file': str(truth_file), 'seed': int(seed), 'tick_ns': int(tick_ns),
              'max_sim_s': float(max_sim_s), 'stall_timeout_s': float(stall_timeout_s), 'bag_path': str(bag_path),
              'model_file': str(model_file)}
    values.update({f'plan.{name}': value for name, value in asdict(plan).items()})
    return values


def graph_config_from_parameters(values):
    """GraphConfig of the alignment campaign from node parameter values."""
    from sofia_ros.campaigns.alignment import graph_config

    if values.get('campaign') != 'alignment':
        raise ConfigError(f"campaign {values.get('campaign')!r} has no node graph yet; use 'alignment'")
    if not values.get('truth_file'):
        raise ConfigError('parameter truth_file is empty; pass -p truth_file:=config/truth/nominal.yaml')
    truth = load_effect_config(values['truth_file'])
    plan = AlignmentPlan(**{name: values[f'plan.{name}'] for name in (f.name for f in fields(AlignmentPlan))})
    config = graph_config(truth, int(values['seed']), plan)
    return config.__class__(config.truth, config.scenario, config.seed, config.plan, int(values['tick_ns']))


def write_params_file(path, values, per_node=None):
    """A --params-file with the graph parameters for every node (``/**``) plus per-node sections."""
    document = {'/**': {'ros__parameters': values}}
    for node, node_values in (per_node or {}).items():
        document[node] = {'ros__parameters': node_values}
    path.write_text(yaml.safe_dump(document, sort_keys=False))
