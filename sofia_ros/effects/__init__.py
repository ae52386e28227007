"""The catalogue of physical effects (docs/effects.md), one module per family, plus plug-ins and empirical terms.

A plug-in is one importable module with an ``EFFECTS`` tuple of EffectSpec whose physics is
in the spec's hooks (``gyro_rate_offset``, ``camera_rotation``, ``camera_shift_px``; see
effects.base and effects.context); name its modules in the environment variable
SOFIA_EFFECT_MODULES (comma-separated, importable from PYTHONPATH). Empirical terms
(effects.empirical) are effects named ``empirical:<observable>:<variable>:<shape>``, made on demand.
"""

from __future__ import annotations

import difflib
import importlib
import os
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, TypedDict

import numpy as np

from sofia_ros.effects import gyro, pointing
from sofia_ros.effects.base import HOOKS, EffectParams, Effects, EffectSpec, Parameter, ParameterValue
from sofia_ros.effects.context import CameraContext, GyroContext
from sofia_ros.effects.empirical import empirical_spec, is_empirical
from sofia_ros.errors import ConfigError, UnknownEffectError
from sofia_ros.validate import number_text_hint

__all__ = ['CATALOGUE', 'EffectSpec', 'Parameter', 'PLUGIN_ENVIRONMENT_VARIABLE', 'get_effect', 'resolve_params',
           'catalogue_as_json', 'load_catalogue', 'plugin_terms', 'HookTerm', 'is_empirical', 'NOISE_EFFECTS',
           'EffectParams', 'Effects', 'ParameterValue', 'CatalogueEntry', 'CatalogueParameter']

PLUGIN_ENVIRONMENT_VARIABLE = 'SOFIA_EFFECT_MODULES'
#: Random processes: they set the noise floor (the sigmas), they do not move a prediction; never a candidate.
NOISE_EFFECTS = ('gyro_noise', 'seeing')


def _checked_plugin_specs(module_name, built_in):
    """The EffectSpecs of one plug-in module, or ConfigError naming what is wrong with it."""
    try:
        module = importlib.import_module(module_name)
    except ImportError as err:
        raise ConfigError(f'{PLUGIN_ENVIRONMENT_VARIABLE}: cannot import {module_name!r} ({err}); '
                          'put its folder on PYTHONPATH') from err
    except Exception as err:  # a plug-in is user code: a syntax error or a raise on import is one line
        raise ConfigError(f'{PLUGIN_ENVIRONMENT_VARIABLE}: importing {module_name!r} failed '
                          f'({type(err).__name__}: {str(err).splitlines()[0] if str(err) else "no message"}); '
                          'fix the module or take it out of the variable') from err
    specs = getattr(module, 'EFFECTS', None)
    if not isinstance(specs, tuple) or not all(isinstance(spec, EffectSpec) for spec in specs):
        raise ConfigError(f'effect plug-in {module_name!r} must define EFFECTS as a tuple of EffectSpec')
    for spec in specs:
        if spec.name in built_in:
            raise ConfigError(f'effect plug-in {module_name!r}: {spec.name!r} is already in the catalogue; rename it')
        if is_empirical(spec.name):
            raise ConfigError(f'effect plug-in {module_name!r}: {spec.name!r} uses the reserved prefix "empirical:"; '
                              'rename it')
        if not spec.hooks or not all(callable(getattr(spec, hook)) for hook in spec.hooks):
            raise ConfigError(f'effect plug-in {module_name!r}: {spec.name!r} needs a callable hook: '
                              f'{", ".join(HOOKS)}')
    return specs


def load_catalogue(environ: Mapping[str, str] = os.environ) -> dict[str, EffectSpec]:
    """The built-in effects plus those of the plug-in modules named in SOFIA_EFFECT_MODULES.

    Args:
        environ: the environment to read SOFIA_EFFECT_MODULES from.

    Returns:
        Effect name -> EffectSpec, the built-in effects first.

    Raises:
        ConfigError: a plug-in module cannot be imported, has no valid EFFECTS, or reuses a name.
    """
    built_in = {spec.name: spec for spec in (*gyro.EFFECTS, *pointing.EFFECTS)}
    names = [name.strip() for name in environ.get(PLUGIN_ENVIRONMENT_VARIABLE, '').split(',') if name.strip()]
    plugins: dict[str, EffectSpec] = {}
    for module_name in names:
        for spec in _checked_plugin_specs(module_name, {**built_in, **plugins}):
            plugins[spec.name] = spec
    return {**built_in, **plugins}


CATALOGUE = load_catalogue()


@dataclass(frozen=True, repr=False, eq=False)
class HookTerm:
    """One plug-in hook with its effect's parameters; calling it checks what the hook returns."""

    spec: EffectSpec
    hook: str
    params: EffectParams

    def __call__(self, context: GyroContext | CameraContext) -> np.ndarray:
        """The hook's (N, columns) result for a context of N rows; ConfigError names a failing plug-in."""
        function = getattr(self.spec, self.hook)
        columns = HOOKS[self.hook]
        try:
            result = np.asarray(function(self.params, context), dtype=float)
        except Exception as err:  # a plug-in is user code: any failure becomes one line
            raise ConfigError(f'effect {self.spec.name!r}: its {self.hook} hook raised '
                              f'{type(err).__name__}: {err}; fix the plug-in') from err
        if result.shape != (len(context), columns):
            raise ConfigError(f'effect {self.spec.name!r}: its {self.hook} hook returned shape {result.shape} for '
                              f'{len(context)} rows; it must return ({len(context)}, {columns})')
        if not np.all(np.isfinite(result)):
            raise ConfigError(f'effect {self.spec.name!r}: its {self.hook} hook returned NaN or inf '
                              f'(parameters {self.params}); fix the plug-in')
        return result

    def __repr__(self) -> str:
        return f'HookTerm({self.spec.name!r}, {self.hook!r}, {self.params!r})'


def plugin_terms(effects: Mapping[str, EffectParams], hook: str) -> tuple[HookTerm, ...]:
    """HookTerms of every effect in ``effects`` whose spec brings ``hook`` (plug-ins and empirical terms).

    Args:
        effects: effect name -> resolved parameters (a truth or model).
        hook: one of effects.base.HOOKS.

    Returns:
        One HookTerm per effect with that hook, in the order of ``effects``.
    """
    terms = []
    for name, params in effects.items():
        if name in CATALOGUE or is_empirical(name):
            spec = get_effect(name)
            if getattr(spec, hook) is not None:
                terms.append(HookTerm(spec, hook, params))
    return tuple(terms)


def get_effect(name: str) -> EffectSpec:
    """The catalogue entry (or empirical term) ``name``; UnknownEffectError naming the closest names otherwise.

    Args:
        name: a catalogue effect or an ``empirical:...`` term name.

    Returns:
        The effect's EffectSpec.

    Raises:
        UnknownEffectError: no such effect (the message names the closest ones).
    """
    if is_empirical(name):
        return empirical_spec(name)
    try:
        return CATALOGUE[name]
    except KeyError as err:
        close = difflib.get_close_matches(str(name), CATALOGUE, n=3)
        hint = f'; did you mean {", ".join(close)}?' if close else '; run `sofia effects` for the list'
        raise UnknownEffectError(f'unknown effect {name!r}{hint}') from err


def resolve_params(name: str, given: Mapping[str, Any] | None, *, within_ranges: bool = False) -> EffectParams:
    """Defaults of effect ``name`` overlaid with ``given`` (``{}`` or None takes the thesis defaults).

    Types, finiteness, text choices and the spec's check always hold; ``within_ranges`` also holds
    every number to its parameter's range - what a truth or model file may say (config). A fit
    (sofia compare, the noise loop) may wander outside the ranges while it searches.

    Args:
        name: the effect's name.
        given: the parameters given (a ``fit`` flag is checked and left out), or None.
        within_ranges: also hold every number to its parameter's minimum and maximum.

    Returns:
        Every parameter of the effect, numbers as float.

    Raises:
        UnknownEffectError: no effect of that name.
        ConfigError: ``given`` is no mapping, names an unknown parameter, or holds a value of the wrong type,
            not finite, out of range or choices, or failing the spec's check.
    """
    spec = get_effect(name)
    if given is None:
        given = {}
    if not isinstance(given, dict):
        raise ConfigError(f'effect {name!r}: parameters must be a mapping, got {type(given).__name__}')
    resolved = spec.defaults()
    for key, value in given.items():
        if key == 'fit':
            if not isinstance(value, bool):
                raise ConfigError(f'effect {name!r}: fit must be true or false, got {value!r}')
            continue
        param = spec.parameter(key)
        if param is None:
            known = ', '.join(p.name for p in spec.params)
            raise ConfigError(f'effect {name!r}: unknown parameter {key!r} (known: {known})')
        resolved[key] = _checked_value(name, param, value, within_ranges)
    problem = spec.check(resolved) if spec.check is not None else None
    if problem:
        raise ConfigError(f'effect {name!r}: {problem}')
    return resolved


#: Longest list a parameter may hold (vibration lines and the like).
MAX_LIST_ENTRIES = 1000


def _shown(value, limit=60):
    """``repr(value)`` cut to ``limit`` characters: a message never prints a whole (expanded) structure."""
    text = repr(value)
    return text if len(text) <= limit else text[:limit - 3] + '...'


def _range_text(param):
    low = '-inf' if param.minimum is None else f'{param.minimum:g}'
    high = 'inf' if param.maximum is None else f'{param.maximum:g}'
    return f'[{low}, {high}] {param.unit}'


def _checked_entry(effect_name, label, param, template, value, within_ranges):
    """One value (or list entry) against the type of ``template`` and the parameter's range or choices."""
    if isinstance(template, float):
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            hint = number_text_hint(value) if isinstance(value, str) else ''
            raise ConfigError(f'effect {effect_name!r}: {label} must be a number in {_range_text(param)}, '
                              f'got {_shown(value)}{hint}')
        try:
            number = float(value)
        except OverflowError as err:
            raise ConfigError(f'effect {effect_name!r}: {label} must be finite, in {_range_text(param)}') from err
        if number != number or number in (float('inf'), float('-inf')):
            raise ConfigError(f'effect {effect_name!r}: {label} must be finite, in {_range_text(param)}, '
                              f'got {_shown(value)}')
        if within_ranges and ((param.minimum is not None and number < param.minimum) or
                              (param.maximum is not None and number > param.maximum)):
            raise ConfigError(f'effect {effect_name!r}: {label} = {number:g} is outside {_range_text(param)}')
        return number
    if not isinstance(value, type(template)) or isinstance(value, bool) != isinstance(template, bool):
        raise ConfigError(f'effect {effect_name!r}: {label} must be a {type(template).__name__}, got {_shown(value)}')
    if param.choices and value not in param.choices:
        raise ConfigError(f'effect {effect_name!r}: {label} must be one of {", ".join(param.choices)}, '
                          f'got {_shown(value)}')
    return value


def _checked_value(effect_name, param, value, within_ranges):
    """Coerce ``value`` to the type of the parameter's default within its range, or raise ConfigError."""
    default = param.default
    if isinstance(default, list):
        if not isinstance(value, list):
            raise ConfigError(f'effect {effect_name!r}: {param.name} must be a list ({param.unit}), '
                              f'got {_shown(value)}')
        if len(value) > MAX_LIST_ENTRIES:
            raise ConfigError(f'effect {effect_name!r}: {param.name} has {len(value)} entries '
                              f'(at most {MAX_LIST_ENTRIES})')
        template = default[0] if default else 0.0
        return [_checked_entry(effect_name, f'{param.name}[{index}]', param, template, entry, within_ranges)
                for index, entry in enumerate(value)]
    return _checked_entry(effect_name, param.name, param, default, value, within_ranges)


class CatalogueParameter(TypedDict):
    """One parameter of a `sofia effects --json` entry."""

    default: ParameterValue
    unit: str


class CatalogueEntry(TypedDict):
    """One effect of `sofia effects --json` (docs/effects.md)."""

    name: str
    thesis: str
    description: str
    params: dict[str, CatalogueParameter]


def catalogue_as_json() -> list[CatalogueEntry]:
    """The catalogue in the contract form of `sofia effects --json` (docs/effects.md).

    Returns:
        One entry per effect of the catalogue, plug-ins included, in catalogue order.
    """
    return [
        {
            'name': spec.name,
            'thesis': spec.thesis,
            'description': spec.description,
            'params': {param.name: {'default': param.default, 'unit': param.unit} for param in spec.params},
        }
        for spec in CATALOGUE.values()
    ]
