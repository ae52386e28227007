"""The atlas grid: effects x sizes x campaign variants x seeds, from command-line lists or a YAML file.

A size is a multiple of the effect's thesis default: every scaling parameter (docs/effects.md) is
multiplied by it, the shaping ones (periods, phases, weather, axis names) keep their defaults, so
size 0 hides nothing (a control run) and size 1 is the thesis' magnitude.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import dataclass
from pathlib import Path

import yaml

from sofia_ros.campaigns.registry import campaign_named
from sofia_ros.config import EffectConfig, load_effect_config, parse_effect_config, safe_load_limited
from sofia_ros.effects import CATALOGUE, get_effect, is_empirical
from sofia_ros.errors import ConfigError, UnknownEffectError

__all__ = ['AtlasGrid', 'AtlasTask', 'DEFAULT_MODEL', 'DEFAULT_TRUTH', 'NOISE_EFFECTS', 'grid_from_file',
           'grid_from_lists', 'hidden_truth_text', 'scaled_params']

DEFAULT_MODEL, DEFAULT_TRUTH = 'config/model/nominal.yaml', 'config/truth/nominal.yaml'
#: Random processes set the noise floor; compare never ranks them, so hiding them measures nothing.
NOISE_EFFECTS = ('gyro_noise', 'seeing')
#: Keys a grid file may hold.
_GRID_KEYS = ('effects', 'sizes', 'campaigns', 'seeds', 'model', 'truth', 'candidates')
_MAX_SEED = 2**32 - 1


@dataclass(frozen=True)
class AtlasTask:
    """One cell of the grid: hide ``effect`` at ``size`` x default in one campaign variant, one seed."""

    effect: str
    size: float
    campaign: str
    variant: str
    seed: int

    @property
    def key(self) -> str:
        """The row's key in the results table (a resumed atlas skips the keys it holds)."""
        return f'{self.effect}|{self.size:g}|{self.campaign}|{self.variant}|{self.seed}'


@dataclass(frozen=True)
class AtlasGrid:
    """What the atlas runs: the axes, the truth the effects are hidden in, the model compare fits."""

    effects: tuple[str, ...]
    sizes: tuple[float, ...]
    #: (campaign, variant) pairs
    campaigns: tuple[tuple[str, str], ...]
    seeds: tuple[int, ...]
    truth: EffectConfig
    model: EffectConfig
    #: compare's catalogue candidates (None: the whole catalogue); empirical shapes are always ranked
    candidates: tuple[str, ...] | None = None

    def tasks(self) -> list[AtlasTask]:
        """Every cell, campaigns outermost and seeds innermost (a partial atlas covers every effect early)."""
        return [AtlasTask(effect, size, campaign, variant, seed)
                for campaign, variant in self.campaigns for seed in self.seeds
                for size in self.sizes for effect in self.effects]

    def fingerprint(self) -> str:
        """sha256 of everything that decides a row: a results table from another grid is refused with it."""
        document = {'effects': self.effects, 'sizes': [float(s) for s in self.sizes],
                    'campaigns': [list(pair) for pair in self.campaigns], 'seeds': self.seeds,
                    'truth': self.truth.text, 'model': self.model.text, 'candidates': self.candidates}
        return hashlib.sha256(json.dumps(document, sort_keys=True).encode()).hexdigest()

    def describe(self) -> dict:
        """The grid as plain data (written beside the results table)."""
        return {'effects': list(self.effects), 'sizes': [float(s) for s in self.sizes],
                'campaigns': [f'{c}:{v}' for c, v in self.campaigns], 'seeds': list(self.seeds),
                'truth': self.truth.source, 'model': self.model.source,
                'candidates': None if self.candidates is None else list(self.candidates),
                'fingerprint': self.fingerprint()}


def scaled_params(effect: str, size: float) -> dict:
    """The effect's defaults with every scaling parameter (number or list of numbers) times ``size``."""
    spec = get_effect(effect)
    params = {}
    for param in spec.params:
        value = param.default
        if param.shape or param.choices or isinstance(value, (str, bool)):
            continue
        if isinstance(value, (list, tuple)):
            if all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value):
                params[param.name] = [float(v) * size for v in value]
        elif isinstance(value, (int, float)):
            params[param.name] = float(value) * size
    return params


def hidden_truth_text(truth: EffectConfig, effect: str, size: float) -> str:
    """The truth document with ``effect`` added at ``size`` x its default (YAML text)."""
    document = safe_load_limited(truth.text, truth.source) or {}
    effects = dict(document.get('effects') or {})
    effects[effect] = scaled_params(effect, size)
    document['effects'] = effects
    document.pop('description', None)
    return f'# {truth.source} with {effect} at {size:g} x its default (sofia atlas)\n' + yaml.safe_dump(
        document, sort_keys=False)


def _campaign_pair(text: str) -> tuple[str, str]:
    name, _, variant = str(text).partition(':')
    spec = campaign_named(name.strip())
    variant = variant.strip() or 'full'
    if 'compare' not in spec.analyses:
        raise ConfigError(f'campaign {spec.name!r} is not read by sofia compare; the atlas takes '
                          'alignment or star-hop')
    spec.plan(variant)  # ConfigError for an unknown variant
    return spec.name, variant


def _checked_effect(name: str, model: EffectConfig, truth: EffectConfig) -> str:
    if not isinstance(name, str) or is_empirical(name):
        raise ConfigError(f'atlas effect {name!r}: give a catalogue effect or plug-in name (sofia effects)')
    get_effect(name)  # UnknownEffectError with the closest names
    if name in NOISE_EFFECTS:
        raise ConfigError(f'atlas effect {name!r} is a noise process compare never ranks; hide a physical effect')
    if name in model.effects:
        raise ConfigError(f'atlas effect {name!r} is a term of the model {model.source}; the atlas hides '
                          'effects the model lacks')
    if name in truth.effects:
        raise ConfigError(f'atlas effect {name!r} is already in the truth {truth.source}; '
                          'hide effects the truth lacks')
    return name


def _size(value) -> float:
    try:
        size = float(value)
    except (TypeError, ValueError) as err:
        raise ConfigError(f'atlas size {value!r} is not a number; sizes are multiples of the default, '
                          'e.g. 0.5,1,2') from err
    if not math.isfinite(size) or size < 0.0:
        raise ConfigError(f'atlas size {value!r} must be finite and >= 0 (0: nothing hidden, 1: the default)')
    return size


def _seed(value) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not 0 <= value <= _MAX_SEED:
        raise ConfigError(f'atlas seed {value!r} must be an integer in 0..{_MAX_SEED}')
    return value


def _nonempty(name: str, values) -> list:
    if not values:
        raise ConfigError(f'the atlas grid is empty: no {name} given; give at least one '
                          f'(--{name} or "{name}:" in the grid file)')
    return list(values)


def _unique(values: list) -> tuple:
    return tuple(dict.fromkeys(values))


def grid_from_lists(*, effects, sizes, campaigns, seeds, model: str = DEFAULT_MODEL, truth: str = DEFAULT_TRUTH,
                    candidates=None) -> AtlasGrid:
    """The grid from plain lists (``effects`` may be ['all']: every effect the model lacks); ConfigError if bad."""
    model_config = load_effect_config(model)
    truth_config = load_effect_config(truth)
    effects = _nonempty('effects', effects)
    if effects == ['all']:
        effects = [name for name in CATALOGUE if name not in model_config.effects and name not in truth_config.effects
                   and name not in NOISE_EFFECTS]
    effect_names = _unique([_checked_effect(name, model_config, truth_config) for name in effects])
    size_values = _unique([_size(value) for value in _nonempty('sizes', sizes)])
    pairs = _unique([_campaign_pair(text) for text in _nonempty('campaigns', campaigns)])
    seed_values = _unique([_seed(value) for value in _nonempty('seeds', seeds)])
    if candidates is not None:
        for name in candidates:
            get_effect(name)
        candidates = _unique(list(candidates))
    for effect in effect_names:  # every hidden truth must be a valid truth file (ranges) before anything runs
        for size in size_values:
            parse_effect_config(hidden_truth_text(truth_config, effect, size), f'{truth} with {effect} at {size:g}x')
    return AtlasGrid(effect_names, size_values, pairs, seed_values, truth_config, model_config, candidates)


def _listed(document: dict, key: str, source: str):
    value = document.get(key)
    if value is None:
        return []
    if key == 'seeds' and isinstance(value, int) and not isinstance(value, bool):
        return list(range(1, value + 1))  # a count: seeds 1..N
    if not isinstance(value, list):
        raise ConfigError(f'{source}: {key} must be a list')
    return value


def grid_from_file(path) -> AtlasGrid:
    """The grid of a YAML file (keys: effects, sizes, campaigns, seeds, model, truth, candidates)."""
    path = Path(path)
    try:
        text = path.read_text(encoding='utf-8')
    except (OSError, UnicodeDecodeError) as err:
        raise ConfigError(f'cannot read the grid file {path}: {err}; check the path') from err
    document = safe_load_limited(text, str(path))
    if not isinstance(document, dict):
        raise ConfigError(f'{path}: a grid file is a mapping with effects, sizes, campaigns and seeds')
    unknown = sorted(set(document) - set(_GRID_KEYS))
    if unknown:
        raise ConfigError(f'{path}: unknown key(s) {", ".join(map(str, unknown))} (allowed: {", ".join(_GRID_KEYS)})')
    candidates = document.get('candidates')
    if candidates is not None and not isinstance(candidates, list):
        raise ConfigError(f'{path}: candidates must be a list of effect names')
    try:
        return grid_from_lists(effects=_listed(document, 'effects', str(path)),
                               sizes=_listed(document, 'sizes', str(path)),
                               campaigns=_listed(document, 'campaigns', str(path)),
                               seeds=_listed(document, 'seeds', str(path)),
                               model=str(document.get('model', DEFAULT_MODEL)),
                               truth=str(document.get('truth', DEFAULT_TRUTH)), candidates=candidates)
    except UnknownEffectError as err:
        raise UnknownEffectError(f'{path}: {err}') from err
    except ConfigError as err:
        raise ConfigError(f'{path}: {err}') from err
