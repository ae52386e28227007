"""Node parameters that describe the graph (campaign, truth file, seed, plan, tick), shared by every node.

The plan is the campaign's plan dataclass, one parameter ``plan.<field>`` per field (tuples as
arrays). A field of rows whose dataclass metadata names its ``columns`` is one array per column,
``plan.<field>.<column>``: the star hop's observations are ``plan.observations.star`` (string
array) and ``plan.observations.offset_s`` (double array, seconds after Table D.3's first
observation), entry i of both being observation i. Plan parameters left out take the dataclass
defaults.
"""

from __future__ import annotations

from dataclasses import fields, replace

import yaml

from sofia_ros.campaigns.registry import CAMPAIGNS as _REGISTRY, graph_campaign_of_plan
from sofia_ros.config import load_effect_config
from sofia_ros.errors import ConfigError, InvalidArgumentError, UnknownStarError
from sofia_ros.topics import DEFAULT_TICK_NS

__all__ = ['CAMPAIGNS', 'GRAPH_PARAMETERS', 'graph_parameters', 'graph_config_from_parameters', 'plan_parameters',
           'plan_from_parameters', 'write_params_file']

#: the campaigns with a node graph (campaigns.registry), whose nodes take these parameters
CAMPAIGNS = {name: spec for name, spec in _REGISTRY.items() if spec.build_config is not None}

#: name -> (default, description); the plan.* parameters come from the campaign's plan dataclass
GRAPH_PARAMETERS = {
    'campaign': ('alignment', f'campaign whose graph this node belongs to: {", ".join(CAMPAIGNS)}'),
    'truth_file': ('', 'truth YAML (effects: ..., scenario: ...) of the run'),
    'seed': (0, 'run seed; each node draws its own stream from it'),
    'tick_ns': (DEFAULT_TICK_NS, 'lock-step tick in ns of sim time'),
    'max_sim_s': (7200.0, 'the clock stops the run after this much sim time'),
    'stall_timeout_s': (15.0, 'the clock stops the run when a node is silent this long (wall time)'),
    'bag_path': ('', 'recorder: output bag directory'),
    'model_file': ('', 'recorder: model YAML stored in the bag as /config/model'),
}

#: type of a parameter's default -> (what one value must be, what an array's entries must be)
_KINDS = {bool: ('true or false', 'booleans'), int: ('an integer', 'integers'), float: ('a number', 'numbers'),
          str: ('a string', 'strings')}


def graph_parameters(truth_file, seed, plan, *, tick_ns, max_sim_s, bag_path='', stall_timeout_s=15.0, model_file=''):
    """Parameter values of one run; the campaign is the one whose plan dataclass ``plan`` is."""
    return {'campaign': graph_campaign_of_plan(plan).name, 'truth_file': str(truth_file), 'seed': int(seed), 'tick_ns': int(tick_ns),
            'max_sim_s': float(max_sim_s), 'stall_timeout_s': float(stall_timeout_s), 'bag_path': str(bag_path),
            'model_file': str(model_file), **plan_parameters(plan)}


def plan_parameters(plan):
    """The plan as plan.* parameter values: one per field, a field with ``columns`` one array per column."""
    values = {}
    for spec in fields(plan):
        value = getattr(plan, spec.name)
        columns = spec.metadata.get('columns')
        if columns:
            values.update({f'plan.{spec.name}.{column}': list(rows) for column, rows in zip(columns, zip(*value))})
        else:
            values[f'plan.{spec.name}'] = list(value) if isinstance(value, tuple) else value
    return values


def plan_from_parameters(campaign, values):
    """The campaign's plan from plan.* parameter values (the others take the dataclass defaults).

    ConfigError names an unknown parameter, a value of the wrong type, columns of unequal
    length and whatever the plan itself refuses (an unknown star, a hold of 0 s).
    """
    plan_class = CAMPAIGNS[campaign].plan_type
    defaults = plan_parameters(plan_class())
    unknown = sorted(set(values) - set(defaults))
    if unknown:
        raise ConfigError(f'the {campaign} plan has no parameter {", ".join(unknown)}; '
                          f'its plan parameters are {", ".join(defaults)}')
    checked = {name: _checked(name, values.get(name, default), default) for name, default in defaults.items()}
    try:
        return plan_class(**{spec.name: _field_value(spec, checked) for spec in fields(plan_class)})
    except (InvalidArgumentError, UnknownStarError) as err:
        raise ConfigError(f'plan.* parameters of the {campaign} campaign: {err}') from err


def _field_value(spec, values):
    """One dataclass field from checked plan.* values: its parameter, or its column arrays zipped into rows."""
    columns = spec.metadata.get('columns')
    if not columns:
        return values[f'plan.{spec.name}']
    names = [f'plan.{spec.name}.{column}' for column in columns]
    lengths = [len(values[name]) for name in names]
    if len(set(lengths)) > 1:
        listed = ', '.join(f'{name} has {length}' for name, length in zip(names, lengths))
        raise ConfigError(f'{listed} entries; give {" and ".join(names)} with one entry per row of plan.{spec.name}')
    return tuple(zip(*(values[name] for name in names)))


def _checked(name, value, example):
    """``value`` of parameter ``name`` if it has the type of ``example`` (arrays as tuples); else ConfigError."""
    if not isinstance(example, list):
        if not _is_kind(value, type(example)):
            raise ConfigError(f'parameter {name} must be {_KINDS[type(example)][0]}, got {value!r}')
        return value
    kind = type(example[0])
    if not isinstance(value, (list, tuple)) or not all(_is_kind(item, kind) for item in value):
        raise ConfigError(f'parameter {name} must be an array of {_KINDS[kind][1]}, got {value!r}')
    return tuple(value)


def _is_kind(value, kind):
    """Whether ``value`` passes as a ``kind`` (an integer passes as a float, a bool only as a bool)."""
    accepted = (int, float) if kind is float else kind
    return isinstance(value, bool) == (kind is bool) and isinstance(value, accepted)


def graph_config_from_parameters(values):
    """The run's GraphConfig from node parameter values: the campaign's builder over truth, seed and plan."""
    campaign = values.get('campaign')
    if campaign not in CAMPAIGNS:
        raise ConfigError(f'parameter campaign is {campaign!r}; use one of {", ".join(CAMPAIGNS)} '
                          f'(e.g. -p campaign:=star-hop)')
    if not values.get('truth_file'):
        raise ConfigError('parameter truth_file is empty; pass -p truth_file:=config/truth/nominal.yaml')
    truth = load_effect_config(values['truth_file'])
    plan = plan_from_parameters(campaign, {name: value for name, value in values.items() if name.startswith('plan.')})
    config = CAMPAIGNS[campaign].build_config(truth, int(values['seed']), plan)
    return replace(config, tick_ns=int(values['tick_ns']))


def write_params_file(path, values, per_node=None):
    """A --params-file with the graph parameters for every node (``/**``) plus per-node sections."""
    document = {'/**': {'ros__parameters': values}}
    for node, node_values in (per_node or {}).items():
        document[node] = {'ros__parameters': node_values}
    path.write_text(yaml.safe_dump(document, sort_keys=False))
