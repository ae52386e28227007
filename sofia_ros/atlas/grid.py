"""The atlas grid: effects x sizes x campaign variants x seeds, from command-line lists or a YAML file.

A size is a multiple of the effect's thesis default: every scaling parameter (docs/effects.md) is
multiplied by it, the shaping ones (periods, phases, weather, axis names) keep their defaults, so
size 0 hides nothing (a control run) and size 1 is the thesis' magnitude.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import yaml

from sofia_ros.campaigns.registry import campaign_named
from sofia_ros.config import EffectConfig, load_effect_config, parse_effect_config, safe_load_limited
from sofia_ros.effects import CATALOGUE, NOISE_EFFECTS, get_effect, is_empirical
from sofia_ros.errors import ConfigError, UnknownEffectError
from sofia_ros.input_files import read_text_capped

__all__ = ['AtlasGrid', 'AtlasTask', 'DEFAULT_MODEL', 'DEFAULT_TRUTH', 'FORCED_MAX_TASKS', 'MAX_TASKS', 'NOISE_EFFECTS',
           'grid_from_file', 'grid_from_lists', 'hidden_truth_text', 'scaled_params', 'seeds_of_text']

DEFAULT_MODEL, DEFAULT_TRUTH = 'config/model/nominal.yaml', 'config/truth/nominal.yaml'
#: Keys a grid file may hold.
_GRID_KEYS = ('effects', 'sizes', 'campaigns', 'seeds', 'model', 'truth', 'candidates')
_MAX_SEED = 2**32 - 1
#: The most tasks a grid may have: 10 000 tasks of ~20 s are days on a workstation, so more is a typo.
MAX_TASKS = 10_000
#: The most with --force: the store holds every key in memory and a run that long is months of CPU.
FORCED_MAX_TASKS = 1_000_000
_FORCE_HINT = f' (--force allows up to {FORCED_MAX_TASKS})'
_FORCED_HINT = ' even with --force'
#: A grid file is a few lines of YAML.
_MAX_GRID_FILE_BYTES = 1 << 20


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

    def iter_tasks(self) -> Iterator[AtlasTask]:
        """Every cell, campaigns outermost and seeds innermost (a partial atlas covers every effect early).

        One at a time, so a grid of a million tasks is never a list of them.
        """
        return (AtlasTask(effect, size, campaign, variant, seed)
                for campaign, variant in self.campaigns for seed in self.seeds
                for size in self.sizes for effect in self.effects)

    def tasks(self) -> list[AtlasTask]:
        """Every cell as a list (iter_tasks' order)."""
        return list(self.iter_tasks())

    def task_count(self) -> int:
        """How many cells the grid has."""
        return len(self.effects) * len(self.sizes) * len(self.campaigns) * len(self.seeds)

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


def _seed_span(first: int, last: int, what: str, max_tasks: int) -> list[int]:
    """Seeds first..last, their bounds and count checked before the list is built (99999999999999 seeds
    would fill the memory before any range check)."""
    if last > _MAX_SEED:
        raise ConfigError(f'{what}: seed {last} is beyond the largest seed {_MAX_SEED}; give seeds in 0..{_MAX_SEED}')
    if first > last:
        raise ConfigError(f'{what}: the range {first}-{last} is empty; give A-B with A <= B')
    if last - first + 1 > max_tasks:
        raise ConfigError(f'{what}: {last - first + 1} seeds are more than the {max_tasks} tasks an atlas may have'
                          f'{_FORCE_HINT if max_tasks < FORCED_MAX_TASKS else _FORCED_HINT}; give fewer seeds')
    return list(range(first, last + 1))


def seeds_of_text(text: str, what: str, max_tasks: int = MAX_TASKS) -> list[int]:
    """``N`` (1..N), ``A-B`` or ``a,b,c``; ConfigError naming ``what`` otherwise or when too many."""
    text = text.strip()
    too_long = re.search(r'\d{11,}', text)  # beyond any seed, and int() refuses more than 4300 digits
    if too_long:
        digits = too_long[0] if len(too_long[0]) <= 20 else f'{too_long[0][:20]}...'
        raise ConfigError(f'{what}: seed {digits} is beyond the largest seed {_MAX_SEED}; give seeds in 0..{_MAX_SEED}')
    if re.fullmatch(r'\d+', text):
        return _seed_span(1, int(text), what, max_tasks)
    match = re.fullmatch(r'(\d+)-(\d+)', text)
    if match:
        return _seed_span(int(match[1]), int(match[2]), what, max_tasks)
    if re.fullmatch(r'\d+(,\d*)*', text):
        parts = [part for part in text.split(',') if part]
        if len(parts) > max_tasks:
            raise ConfigError(f'{what}: {len(parts)} seeds are more than the {max_tasks} tasks an atlas may have; '
                              'give fewer seeds')
        return [_seed(int(part)) for part in parts]
    raise ConfigError(f'{what} {text!r}: give N (seeds 1..N), A-B or a comma list such as 1,2,7')


def _checked_task_count(counts: dict, max_tasks: int) -> None:
    """ConfigError when the axes multiply to more than ``max_tasks`` (before any hidden truth is built)."""
    total = math.prod(counts.values())
    if total > max_tasks:
        axes = ' x '.join(f'{count} {name}' for name, count in counts.items())
        raise ConfigError(f'the grid is {total} tasks ({axes}), more than the {max_tasks} an atlas may have'
                          f'{_FORCE_HINT if max_tasks < FORCED_MAX_TASKS else _FORCED_HINT}; narrow an axis')


def _nonempty(name: str, values) -> list:
    if not values:
        raise ConfigError(f'the atlas grid is empty: no {name} given; give at least one '
                          f'(--{name} or "{name}:" in the grid file)')
    return list(values)


def _unique(values: list) -> tuple:
    return tuple(dict.fromkeys(values))


def grid_from_lists(*, effects, sizes, campaigns, seeds, model: str = DEFAULT_MODEL, truth: str = DEFAULT_TRUTH,
                    candidates=None, max_tasks: int = MAX_TASKS) -> AtlasGrid:
    """The grid from plain lists (``effects`` may be ['all']: every effect the model lacks); ConfigError if bad
    or if it has more than ``max_tasks`` tasks."""
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
    _checked_task_count({'effects': len(effect_names), 'sizes': len(size_values), 'campaigns': len(pairs),
                         'seeds': len(seed_values)}, max_tasks)
    if candidates is not None:
        for name in candidates:
            get_effect(name)
        candidates = _unique(list(candidates))
    for effect in effect_names:  # every hidden truth must be a valid truth file (ranges) before anything runs
        for size in size_values:
            parse_effect_config(hidden_truth_text(truth_config, effect, size), f'{truth} with {effect} at {size:g}x')
    return AtlasGrid(effect_names, size_values, pairs, seed_values, truth_config, model_config, candidates)


def _listed(document: dict, key: str, max_tasks: int):
    value = document.get(key)
    if value is None:
        return []
    if key == 'seeds' and isinstance(value, (int, str)) and not isinstance(value, bool):
        # a count N (seeds 1..N) or the text --seeds takes, both counted before they are expanded
        return seeds_of_text(str(value), 'seeds', max_tasks)
    if not isinstance(value, list):
        raise ConfigError(f'{key} must be a list' + (', a count N or "A-B"' if key == 'seeds' else ''))
    return value


def grid_from_file(path, max_tasks: int = MAX_TASKS) -> AtlasGrid:
    """The grid of a YAML file (keys: effects, sizes, campaigns, seeds, model, truth, candidates)."""
    path = Path(path)
    text = read_text_capped(path, _MAX_GRID_FILE_BYTES, 'grid file')
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
        return grid_from_lists(effects=_listed(document, 'effects', max_tasks),
                               sizes=_listed(document, 'sizes', max_tasks),
                               campaigns=_listed(document, 'campaigns', max_tasks),
                               seeds=_listed(document, 'seeds', max_tasks),
                               model=str(document.get('model', DEFAULT_MODEL)),
                               truth=str(document.get('truth', DEFAULT_TRUTH)), candidates=candidates,
                               max_tasks=max_tasks)
    except UnknownEffectError as err:
        raise UnknownEffectError(f'{path}: {err}') from err
    except ConfigError as err:
        raise ConfigError(f'{path}: {err}') from err
