"""Plan files: a campaign's plan as YAML a user (or `sofia design`) writes, `sofia run --plan` flies (docs/plans.md).

A plan file names its campaign, gives any of the plan dataclass' fields (the others keep their
defaults) and lists the plan elements flown after the campaign's sequence. Everything is checked
before a run starts: an unknown key or maneuver, a value of the wrong type, an elevation outside
20-60 deg, a LOS angle beyond the fine drive's travel, a hold of 0 s, an unknown star, a plan of
the other campaign: one ConfigError line each. A temperature element is checked against the truth
too (:func:`check_plan_with_truth`, by the campaigns' config builders): its target and rate within
the truth's thermal control, which it must have. A run records its plan beside the bag as
``plan.yaml`` (and in the bag as /config/plan); :func:`read_plan` reads it back.
"""

from __future__ import annotations

import math
from dataclasses import fields
from os import PathLike
from pathlib import Path
from typing import Any

import yaml

from sofia_ros.config import safe_load_limited
from sofia_ros.errors import ConfigError, InvalidArgumentError, UnknownStarError
from sofia_ros.input_files import read_text_capped, shipped_paths
from sofia_ros.output_files import write_text_atomically
from sofia_ros.scenario import Scenario
from sofia_ros.sim.calibration import AlignmentPlan
from sofia_ros.sim.sequence import PLAN_FILE_NAME, plan_document, plan_text
from sofia_ros.sim.star_hop import StarHopPlan
from sofia_ros.validate import number_text_hint

__all__ = ['PLAN_FILE_NAME', 'PLAN_TYPES', 'check_plan_with_truth', 'plan_document', 'plan_from_document', 'plan_text',
           'plans_directory', 'read_plan', 'read_plan_file', 'variant_plan_path', 'write_plan_file']

#: the plan dataclass of each campaign that has one (the registry's plan_type; below it, since it reads these)
PLAN_TYPES = {plan_type.campaign: plan_type for plan_type in (AlignmentPlan, StarHopPlan)}
_MAX_PLAN_BYTES = 1 << 20
#: other names a plan might give a temperature plateau or ramp, which are the temperature element (docs/plans.md)
_THERMAL_NAMES = frozenset({'temperature', 'temperature_plateau', 'temperature_ramp', 'thermal_step'})
_THERMAL_HINT = ("the simulated temperature follows the truth's scenario and, where the truth has a "
                 'scenario.thermal_control, the elements of the form - temperature: {target_c: T, duration_s: S} '
                 '(a plateau; add rate_c_per_h: R for a ramp) (docs/plans.md)')
#: a truth whose thermal environment a plan can command (docs/plans.md)
THERMAL_TRUTH = 'config/truth/nominal-thermal.yaml'


def _plan_type(campaign: str, source: str) -> type:
    """The plan dataclass of ``campaign``; ConfigError naming the campaigns that take a plan."""
    if campaign not in PLAN_TYPES:
        raise ConfigError(f'{source}: campaign is {campaign!r}; a plan is for one of {", ".join(PLAN_TYPES)}')
    return PLAN_TYPES[campaign]


def plan_from_document(document: Any, source: str, campaign: str | None = None) -> Any:
    """The plan of a plan file's parsed YAML; ConfigError naming ``source`` and what to fix.

    ``campaign``: the campaign being run, whose plan the document must be.
    """
    if not isinstance(document, dict) or not isinstance(document.get('campaign'), str):
        raise ConfigError(f'{source}: a plan file is a mapping that starts with campaign: alignment or '
                          'campaign: star-hop (docs/plans.md)')
    named = document['campaign']
    # The name checked first: the hint below would otherwise send the user to a campaign that does not exist.
    plan_type = _plan_type(named, source)
    if campaign is not None and named != campaign:
        raise ConfigError(f'{source} is a plan of the {named} campaign, not of {campaign}; give a plan of the '
                          f'{campaign} campaign, or fly this one with `sofia run {named} --plan {source}`')
    defaults = plan_type()
    keys = {spec.name: spec for spec in fields(plan_type) if spec.name != 'elements_yaml'}
    unknown = [str(key) for key in document if key not in (*keys, 'campaign', 'elements')]
    if unknown:
        if _THERMAL_NAMES & set(unknown):
            raise ConfigError(f'{source}: {unknown[0]}: {_THERMAL_HINT}')
        raise ConfigError(f'{source}: unknown key {unknown[0]!r} in the {named} plan; it takes campaign, '
                          f'{", ".join(keys)}, elements (docs/plans.md)')
    values = {name: _checked(f'{source}: {name}', document[name], getattr(defaults, name))
              for name in keys if name in document}
    try:
        return plan_type(**values, elements_yaml=_elements_text(document.get('elements'), source))
    except (InvalidArgumentError, UnknownStarError) as err:
        raise ConfigError(f'{source}: {err}') from err


def _elements_text(elements: Any, source: str) -> str:
    """The ``elements`` list as the plan's elements_yaml (the plan checks each element)."""
    if elements is None:
        return ''
    if not isinstance(elements, list):
        raise ConfigError(f'{source}: elements must be a list of {{maneuver: {{field: value}}}} (docs/plans.md)')
    for element in elements:
        kind = next(iter(element), None) if isinstance(element, dict) else None
        if kind in _THERMAL_NAMES - {'temperature'}:
            raise ConfigError(f'{source}: element {kind}: {_THERMAL_HINT}')
    return yaml.safe_dump(elements, default_flow_style=True, sort_keys=False, width=1 << 16)


def check_plan_with_truth(plan: Any, scenario: Scenario, truth_source: str) -> None:
    """ConfigError in one line for a temperature element the truth cannot fly: no thermal control, or a target or
    rate beyond it (the rest of a plan is checked without the truth, as it is read)."""
    control = scenario.thermal_control
    for index, element in enumerate(plan.elements, 1):
        if element.kind != 'temperature':
            continue
        where = f'element {index} (temperature)'
        if control is None:
            raise ConfigError(f'{where}: the truth {truth_source} has no scenario.thermal_control, so nothing can '
                              f'command its temperature; fly it on a truth that has one, e.g. {THERMAL_TRUTH} '
                              '(docs/plans.md)')
        rate_c_per_h = control.max_rate_c_per_h if element.rate_c_per_h is None else element.rate_c_per_h
        reason = control.refusal(element.target_c, rate_c_per_h)
        if reason is not None:
            raise ConfigError(f'{where}: {reason} (scenario.thermal_control of {truth_source})')


def _checked(name: str, value: Any, example: Any) -> Any:
    """``value`` of a plan field if it has the shape and types of ``example`` (its default); ConfigError otherwise."""
    if isinstance(example, tuple):
        if not isinstance(value, list):
            raise ConfigError(f'{name} must be a list, got {value!r:.60}')
        if example and isinstance(example[0], tuple):  # rows, e.g. the star hop's [star, offset_s]
            row_example = example[0]
            return tuple(_row(f'{name}[{index}]', row, row_example) for index, row in enumerate(value))
        return tuple(_checked(f'{name}[{index}]', item, example[0] if example else 0.0)
                     for index, item in enumerate(value))
    kind = type(example)
    if kind is bool:
        ok = isinstance(value, bool)
    elif kind is float:
        ok = isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)
    else:
        ok = isinstance(value, kind) and not isinstance(value, bool)
    if not ok:
        wanted = {bool: 'true or false', int: 'an integer', float: 'a finite number', str: 'a string'}[kind]
        hint = number_text_hint(value) if isinstance(value, str) and kind is not str else ''
        raise ConfigError(f'{name} must be {wanted}, got {value!r:.60}{hint}')
    return float(value) if kind is float else value


def _row(name: str, row: Any, example: tuple) -> tuple:
    if not isinstance(row, list) or len(row) != len(example):
        raise ConfigError(f'{name} must be a list of {len(example)} values like {list(example)}, got {row!r:.60}')
    return tuple(_checked(f'{name}[{index}]', item, item_example)
                 for index, (item, item_example) in enumerate(zip(row, example)))


def read_plan_file(path: str | PathLike[str], campaign: str | None = None) -> Any:
    """The plan in a plan file (of ``campaign`` if given); ConfigError in one line for any fault."""
    text = read_text_capped(path, _MAX_PLAN_BYTES, 'plan file')
    return plan_from_document(safe_load_limited(text, str(path)), str(path), campaign)


def write_plan_file(plan: Any, path: str | PathLike[str]) -> Path:
    """Write ``plan`` as a plan file, whole or not at all (OutputError otherwise); the path."""
    write_text_atomically(Path(path), plan_text(plan))
    return Path(path)


def read_plan(bag_path: str | PathLike[str]) -> Any:
    """The plan a bag was flown with, from its ``plan.yaml``; ConfigError if the bag has none."""
    path = Path(bag_path, PLAN_FILE_NAME)
    if not path.exists() and Path(bag_path).is_dir():
        raise ConfigError(f'{bag_path} has no {PLAN_FILE_NAME}: it was not recorded by `sofia run` with plans '
                          '(an imported or older bag); give the plan with --plan')
    return read_plan_file(path)


def plans_directory() -> Path:
    """config/plans of the checkout, else share/sofia_ros/config/plans of the install (colcon: above the package;
    pip: under sys.prefix); ConfigError if none has it."""
    for folder in shipped_paths('config/plans'):
        if folder.is_dir():
            return folder
    raise ConfigError('the named plans (config/plans) are not installed here; give a plan file with --plan')


def variant_plan_path(campaign: str, variant: str) -> Path:
    """The plan file of a campaign's named variant: config/plans/<campaign>-<variant>.yaml."""
    return plans_directory() / f'{campaign}-{variant}.yaml'
