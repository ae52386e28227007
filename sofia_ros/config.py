"""Truth and model configuration files: ``effects:`` (docs/effects.md) and an optional ``scenario:``."""

from __future__ import annotations

import datetime as dt
from dataclasses import dataclass

import yaml

from sofia_ros.effects import resolve_params
from sofia_ros.errors import ConfigError
from sofia_ros.input_files import read_text_capped

__all__ = ['EffectConfig', 'load_effect_config', 'parse_effect_config', 'safe_load_limited', 'MAX_CONFIG_BYTES',
           'MAX_YAML_NODES', 'MAX_YAML_ALIASES', 'MAX_YAML_DEPTH']

_TOP_LEVEL_KEYS = {'effects', 'scenario', 'description'}

#: A truth or model file is a few kB; these caps stop alias bombs and huge files before they are built.
MAX_CONFIG_BYTES = 1 << 20
MAX_YAML_NODES = 100_000
MAX_YAML_ALIASES = 100
MAX_YAML_DEPTH = 50


#: Any valid epoch: the scenario keys are checked at load against a placeholder default.
_CHECK_EPOCH = dt.datetime(2004, 9, 3, tzinfo=dt.timezone.utc)


class _LimitedLoader(yaml.SafeLoader):
    """SafeLoader that counts nodes as they would be expanded (aliases included), aliases and depth."""

    def __init__(self, stream):
        super().__init__(stream)
        self._expanded = {}
        self._aliases = 0
        self._depth = 0

    def compose_node(self, parent, index):
        if self.check_event(yaml.AliasEvent):
            self._aliases += 1
            if self._aliases > MAX_YAML_ALIASES:
                raise ConfigError(f'more than {MAX_YAML_ALIASES} YAML aliases (*name); write the values out')
        self._depth += 1
        if self._depth > MAX_YAML_DEPTH:
            raise ConfigError(f'YAML nested deeper than {MAX_YAML_DEPTH} levels')
        try:
            node = super().compose_node(parent, index)
        finally:
            self._depth -= 1
        if id(node) not in self._expanded:
            if isinstance(node, yaml.MappingNode):
                children = [child for pair in node.value for child in pair]
            elif isinstance(node, yaml.SequenceNode):
                children = node.value
            else:
                children = []
            self._expanded[id(node)] = 1 + sum(self._expanded.get(id(child), 1) for child in children)
        if self._expanded[id(node)] > MAX_YAML_NODES:
            raise ConfigError(f'the YAML expands to more than {MAX_YAML_NODES} values (aliases counted as '
                              'often as they are used); a truth, model or plan file is far smaller')
        return node

    def construct_mapping(self, node, deep=False):
        # PyYAML keeps the last of two equal keys; a file that says a value twice is ambiguous.
        seen = set()
        for key_node, _ in node.value:
            if key_node.tag == 'tag:yaml.org,2002:merge':
                continue
            key = self.construct_object(key_node, deep=True)
            try:
                duplicate = key in seen
            except TypeError:
                continue  # an unhashable key: the base constructor names it
            if duplicate:
                raise ConfigError(f'key {str(key)[:40]!r} given twice (line {key_node.start_mark.line + 1}); '
                                  'keep one')
            seen.add(key)
        return super().construct_mapping(node, deep)


def safe_load_limited(text, source='<text>'):
    """yaml.safe_load with caps on size, expansion, aliases and depth; ConfigError naming ``source``."""
    if len(text) > MAX_CONFIG_BYTES:
        raise ConfigError(f'{source}: {len(text)} characters, more than the {MAX_CONFIG_BYTES} a config may have')
    try:
        loader = _LimitedLoader(text)
    except yaml.YAMLError as err:  # the reader checks the characters as it is built (a control character)
        raise ConfigError(f'{source}: not valid YAML ({str(err).splitlines()[0]}); fix the syntax') from err
    try:
        return loader.get_single_data()
    except ConfigError as err:
        raise ConfigError(f'{source}: {err}') from err
    except yaml.YAMLError as err:
        raise ConfigError(f'{source}: not valid YAML ({str(err).splitlines()[0]}); fix the syntax') from err
    except (ValueError, TypeError, OverflowError) as err:
        # PyYAML builds timestamps and numbers itself: 2004-13-45T99:00:00 raises ValueError.
        raise ConfigError(f'{source}: a value cannot be read ({err}); quote dates as "2004-09-03T04:32:51Z"') from err
    finally:
        loader.dispose()


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
    document = safe_load_limited(text, source)
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
    from sofia_ros.effects.empirical import term_identity

    effects, fitted, spelled = {}, set(), {}
    for name, params in raw_effects.items():
        if not isinstance(name, str):
            raise ConfigError(f'{source}: effect names are text, got {str(name)[:40]!r}')
        try:
            effects[name] = resolve_params(name, params, within_ranges=True)
        except ConfigError as err:
            raise ConfigError(f'{source}: {err}') from err
        # Two spellings of one empirical term were fitted side by side, every amplitude unconstrained.
        first = spelled.setdefault(term_identity(name), name)
        if first != name:
            raise ConfigError(f'{source}: {name} is {first} spelled otherwise; give each term once')
        if isinstance(params, dict) and params.get('fit'):
            fitted.add(name)
    scenario = document.get('scenario')
    if scenario is not None and not isinstance(scenario, dict):
        raise ConfigError(f'{source}: scenario must be a mapping')
    if scenario:
        from sofia_ros.scenario import Scenario, scenario_from_mapping
        from sofia_ros.sky import WACO_2004_SITE

        try:
            scenario_from_mapping(Scenario(WACO_2004_SITE, _CHECK_EPOCH, 0.0, 40.0), scenario)
        except ConfigError as err:
            raise ConfigError(f'{source}: {err}') from err
    return EffectConfig(effects, frozenset(fitted), scenario, text, source)


def load_effect_config(path):
    """Read (at most MAX_CONFIG_BYTES, a regular file) and parse a truth/model file."""
    text = read_text_capped(path, MAX_CONFIG_BYTES, 'truth or model file (a few kB)')
    return parse_effect_config(text, str(path))
