"""Truth and model configuration files: ``effects:`` (docs/effects.md) and an optional ``scenario:``."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import yaml

from sofia_ros.effects import resolve_params
from sofia_ros.errors import ConfigError

__all__ = ['EffectConfig', 'load_effect_config', 'parse_effect_config']

_TOP_LEVEL_KEYS = {'effects', 'scenario', 'description'}


@dataclass(frozen=True)
class EffectConfig:
    """A parsed truth or model file: resolved effect parameters, fitted-term flags, scenario, source text."""

    effects: dict
    fitted: frozenset
    scenario: dict | None
    text: str
    source: str


def parse_effect_config(text, source='<text>'):
    """Parse and validate a truth/model YAML document; ConfigError names the problem and the fix."""
    try:
        document = yaml.safe_load(text)
    except yaml.YAMLError as err:
        raise ConfigError(f'{source}: not valid YAML ({str(err).splitlines()[0]}); fix the syntax') from err
    if document is None:
        document = {}
    if not isinstance(document, dict):
        raise ConfigError(f'{source}: expected a mapping with an effects: section')
    unknown = sorted(set(document) - _TOP_LEVEL_KEYS)
    if unknown:
        raise ConfigError(f'{source}: unknown top-level key(s) {", ".join(unknown)} '
                          f'(allowed: {", ".join(sorted(_TOP_LEVEL_KEYS))})')
    raw_effects = document.get('effects') or {}
    if not isinstance(raw_effects, dict):
        raise ConfigError(f'{source}: effects must be a mapping of effect name to parameters')
    effects, fitted = {}, set()
    for name, params in raw_effects.items():
        try:
            effects[name] = resolve_params(name, params)
        except ConfigError as err:
            raise ConfigError(f'{source}: {err}') from err
        if isinstance(params, dict) and params.get('fit'):
            fitted.add(name)
    scenario = document.get('scenario')
    if scenario is not None and not isinstance(scenario, dict):
        raise ConfigError(f'{source}: scenario must be a mapping')
    return EffectConfig(effects, frozenset(fitted), scenario, text, source)


def load_effect_config(path):
    """Read and parse a truth/model file."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as err:
        raise ConfigError(f'cannot read {path}: {err.strerror}; check the path') from err
    return parse_effect_config(text, str(path))
