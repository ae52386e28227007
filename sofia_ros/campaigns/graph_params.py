"""The graph's node parameters read back: a node executable's GraphConfig from its parameter values.

How they are written is ``campaigns.run_parameters``; plan parameters left out take the dataclass
defaults. Every value is checked against the type of its default, with one clear error line.
"""

from __future__ import annotations

from dataclasses import fields, replace

from sofia_ros.campaigns.registry import CAMPAIGNS as _REGISTRY
from sofia_ros.campaigns.run_parameters import plan_parameters
from sofia_ros.config import load_effect_config
from sofia_ros.errors import ConfigError, InvalidArgumentError, UnknownStarError
from sofia_ros.sim.graph import DEFAULT_MAX_SIM_S
from sofia_ros.topics import DEFAULT_TICK_NS

__all__ = ['CAMPAIGNS', 'GRAPH_PARAMETERS', 'graph_config_from_parameters', 'plan_from_parameters']

#: the campaigns with a node graph (campaigns.registry), whose nodes take these parameters
CAMPAIGNS = {name: spec for name, spec in _REGISTRY.items() if spec.build_config is not None}

#: name -> (default, description); the plan.* parameters come from the campaign's plan dataclass
GRAPH_PARAMETERS = {
    'campaign': ('alignment', f'campaign whose graph this node belongs to: {", ".join(CAMPAIGNS)}'),
    'truth_file': ('', 'truth YAML (effects: ..., scenario: ...) of the run'),
    'seed': (0, 'run seed; each node draws its own stream from it'),
    'tick_ns': (DEFAULT_TICK_NS, 'lock-step tick in ns of sim time'),
    'max_sim_s': (DEFAULT_MAX_SIM_S, 'the clock stops the run after this much sim time'),
    'stall_timeout_s': (15.0, 'the clock stops the run when a node is silent this long (wall time)'),
    'bag_path': ('', 'recorder: output bag directory'),
    'model_file': ('', 'recorder: model YAML stored in the bag as /config/model'),
}

#: type of a parameter's default -> (what one value must be, what an array's entries must be)
_KINDS = {bool: ('true or false', 'booleans'), int: ('an integer', 'integers'), float: ('a number', 'numbers'),
          str: ('a string', 'strings')}


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
    if value is None:
        # An empty array in a params file (`plan.flexure_elevations_deg: []`, the minimal alignment's) has no type for
        # rcl, which gives it unset: a parameter absent is not here at all, so unset is the empty array.
        return ()
    if not isinstance(value, (list, tuple)) or not all(_is_kind(item, kind) for item in value):
        raise ConfigError(f'parameter {name} must be an array of {_KINDS[kind][1]}, got {value!r}')
    return tuple(value)


def _is_kind(value, kind):
    """Whether ``value`` passes as a ``kind`` (an integer passes as a float, a bool only as a bool)."""
    accepted = (int, float) if kind is float else kind
    return isinstance(value, bool) == (kind is bool) and isinstance(value, accepted)


#: The node executables' run parameters: (the least, the most) of each (sofia run checks its options alike).
_RUN_VALUE_RANGES = {'seed': (0, 2**32 - 1), 'tick_ns': (1, 10**10), 'max_sim_s': (0.0, 1e7),
                     'stall_timeout_s': (0.0, 86400.0)}


def _check_run_values(values):
    """ConfigError for a seed, tick or time limit of the wrong type or outside _RUN_VALUE_RANGES: a node started by hand
    with -p seed:=-1 or tick_ns:=0 died with a traceback, or waited for ever with a negative tick."""
    for name, (low, high) in _RUN_VALUE_RANGES.items():
        value = values.get(name, GRAPH_PARAMETERS[name][0])
        kind = type(GRAPH_PARAMETERS[name][0])
        if not _is_kind(value, kind) or not low <= value <= high or (kind is float and value == low):
            bound = f'above {low:g} to {high:g}' if kind is float else f'from {low} to {high}'
            raise ConfigError(f'parameter {name} must be {_KINDS[kind][0]} {bound}, got {value!r}; '
                              f'pass e.g. -p {name}:={GRAPH_PARAMETERS[name][0]}')


def graph_config_from_parameters(values):
    """The run's GraphConfig from node parameter values: the campaign's builder over truth, seed and plan."""
    campaign = values.get('campaign')
    if campaign not in CAMPAIGNS:
        raise ConfigError(f'parameter campaign is {campaign!r}; use one of {", ".join(CAMPAIGNS)} '
                          f'(e.g. -p campaign:=star-hop)')
    if not values.get('truth_file'):
        raise ConfigError('parameter truth_file is empty; pass -p truth_file:=config/truth/nominal.yaml')
    _check_run_values(values)
    truth = load_effect_config(values['truth_file'])
    plan = plan_from_parameters(campaign, {name: value for name, value in values.items() if name.startswith('plan.')})
    config = CAMPAIGNS[campaign].build_config(truth, int(values['seed']), plan)
    return replace(config, tick_ns=int(values['tick_ns']))

