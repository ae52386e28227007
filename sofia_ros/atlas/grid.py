"""The atlas grid: effects x sizes x campaign variants x seeds, and truths with several effects hidden at once,
from command-line lists or a YAML file.

A size is a multiple of the effect's thesis default: every scaling parameter (docs/effects.md) is
multiplied by it, the shaping ones (periods, phases, weather, axis names) keep their defaults, so
size 0 hides nothing (a control run) and size 1 is the thesis' magnitude.

A **truth** hides a set of effects at their defaults: an explicit list, k effects drawn (seeded, each
set once) from a pool, or none (a control). Truth number i of a campaign is flown with seed s + i for
every seed s of the grid, so no two truths share a noise realisation.
"""

from __future__ import annotations

import hashlib
import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Iterator

import numpy as np
import yaml

from sofia_ros.campaigns.registry import campaign_named
from sofia_ros.config import EffectConfig, load_effect_config, parse_effect_config, safe_load_limited
from sofia_ros.effects import CATALOGUE, NOISE_EFFECTS, get_effect, is_empirical
from sofia_ros.errors import ConfigError, UnknownEffectError
from sofia_ros.input_files import read_text_capped, shipped_file

__all__ = ['AtlasGrid', 'AtlasTask', 'CONTROL', 'DEFAULT_MODEL', 'DEFAULT_TRUTH', 'FORCED_MAX_TASKS', 'MAX_TASKS',
           'NOISE_EFFECTS', 'TruthDraws', 'VISIBLE_EFFECTS', 'draw_truths', 'grid_from_file', 'grid_from_lists',
           'hidden_truth_text', 'scaled_params', 'seeds_of_text', 'truth_draws', 'truth_label']

DEFAULT_MODEL, DEFAULT_TRUTH = 'config/model/nominal.yaml', 'config/truth/nominal.yaml'
#: Keys a grid file may hold.
_GRID_KEYS = ('effects', 'sizes', 'campaigns', 'seeds', 'model', 'truth', 'candidates', 'truths', 'draws', 'controls',
              'search_rounds')
_DRAW_KEYS = ('count', 'k', 'pool', 'seed')
#: The label of a truth that hides nothing (a control), in its key and its ``effect`` column.
CONTROL = 'none'
#: The catalogue effects each campaign reveals alone at their defaults, the pool truths are drawn from by default.
#: Alignment: the single-effect atlas rows and bench/bench_search_truths.py of the reduced alignment (each found
#: alone at delta-BIC >= 6). Star hop: not yet measured by an atlas; the same list, which holds the Waco 2004
#: star hop's five effects (docs/tutorials/search-waco-2004.md).
VISIBLE_EFFECTS = {
    'alignment': ('gyro_scale_factor', 'gyro_axis_swap', 'fpi_internal_flexure', 'imager_boresight_offset',
                  'imager_rotation_of_field', 'imager_scale_error', 'hipo_fiducial_error', 'tracker_drift',
                  'timestamp_offset'),
}
VISIBLE_EFFECTS['star-hop'] = VISIBLE_EFFECTS['alignment']
_MAX_SEED = 2**32 - 1
#: The most tasks a grid may have: 10 000 tasks of ~20 s are days on a workstation, so more is a typo.
MAX_TASKS = 10_000
#: The most with --force: the store holds every key in memory and a run that long is months of CPU.
FORCED_MAX_TASKS = 1_000_000
_FORCE_HINT = f' (--force allows up to {FORCED_MAX_TASKS})'
_FORCED_HINT = ' even with --force'
#: A grid file is a few lines of YAML.
_MAX_GRID_FILE_BYTES = 1 << 20


def truth_label(effects) -> str:
    """A truth's name in keys and rows: its effects joined by '+', or 'none' for a control."""
    return '+'.join(effects) or CONTROL


@dataclass(frozen=True)
class AtlasTask:
    """One cell of the grid: hide ``effect`` at ``size`` x default in one campaign variant, one seed.

    A truth task (``truth_index`` set) hides the effects of its label (truth_label) at their defaults,
    or nothing (a control, size 0), and runs the search when ``search_rounds`` > 0.
    """

    effect: str
    size: float
    campaign: str
    variant: str
    seed: int
    #: the truth's place in its campaign's list (None: a cell of the effects axis)
    truth_index: int | None = None
    #: rounds of compare.search.search_model (0: one compare of the model)
    search_rounds: int = 0

    @property
    def key(self) -> str:
        """The row's key in the results table (a resumed atlas skips the keys it holds)."""
        key = f'{self.effect}|{self.size:g}|{self.campaign}|{self.variant}|{self.seed}'
        return key if self.truth_index is None else f'{key}|truth{self.truth_index}'

    @property
    def hidden(self) -> tuple[str, ...]:
        """The effects hidden in the truth (none for a size-0 cell or a control)."""
        if self.truth_index is None:
            return (self.effect,) if self.size > 0 else ()
        return () if self.effect == CONTROL else tuple(self.effect.split('+'))


@dataclass(frozen=True)
class TruthDraws:
    """Random truths: ``count`` distinct sets of k effects (k cycling through ``ks``) from a pool, seeded."""

    count: int
    ks: tuple[int, ...]
    seed: int
    #: None: the campaign's VISIBLE_EFFECTS less what the model or the truth already holds
    pool: tuple[str, ...] | None = None


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
    #: per (campaign, variant) of ``campaigns``: the truths hidden there (effect sets; () a control), in order
    truths: tuple[tuple[tuple[str, ...], ...], ...] = ()
    #: rounds of the search each truth task runs (0: one compare)
    search_rounds: int = 0

    def iter_tasks(self) -> Iterator[AtlasTask]:
        """Every cell, campaigns outermost and seeds innermost (a partial atlas covers every effect early), then
        the truths, truth i of every campaign before truth i + 1 (a partial atlas covers every campaign).

        One at a time, so a grid of a million tasks is never a list of them.
        """
        for campaign, variant in self.campaigns:
            for seed in self.seeds:
                for size in self.sizes:
                    for effect in self.effects:
                        yield AtlasTask(effect, size, campaign, variant, seed)
        truths = self.truths or ((),) * len(self.campaigns)
        for seed in self.seeds:
            for number in range(max(map(len, truths), default=0)):
                for (campaign, variant), campaign_truths in zip(self.campaigns, truths):
                    if number < len(campaign_truths):
                        effects = campaign_truths[number]
                        yield AtlasTask(truth_label(effects), 1.0 if effects else 0.0, campaign, variant,
                                        seed + number, number, self.search_rounds)

    def tasks(self) -> list[AtlasTask]:
        """Every cell as a list (iter_tasks' order)."""
        return list(self.iter_tasks())

    def task_count(self) -> int:
        """How many cells the grid has."""
        cells = len(self.effects) * len(self.sizes) * len(self.campaigns)
        return (cells + sum(map(len, self.truths))) * len(self.seeds)

    def _truth_document(self) -> dict:
        """The truths and the search, only when the grid has truths (a single-effect grid keeps its fingerprint)."""
        if not any(self.truths):
            return {}
        return {'truths': {f'{c}:{v}': [truth_label(effects) for effects in truths]
                           for (c, v), truths in zip(self.campaigns, self.truths)},
                'search_rounds': self.search_rounds}

    def fingerprint(self) -> str:
        """sha256 of everything that decides a row: a results table from another grid is refused with it."""
        document = {'effects': self.effects, 'sizes': [float(s) for s in self.sizes],
                    'campaigns': [list(pair) for pair in self.campaigns], 'seeds': self.seeds,
                    'truth': self.truth.text, 'model': self.model.text, 'candidates': self.candidates,
                    **self._truth_document()}
        return hashlib.sha256(json.dumps(document, sort_keys=True).encode()).hexdigest()

    def describe(self) -> dict:
        """The grid as plain data (written beside the results table)."""
        return {'effects': list(self.effects), 'sizes': [float(s) for s in self.sizes],
                'campaigns': [f'{c}:{v}' for c, v in self.campaigns], 'seeds': list(self.seeds),
                'truth': self.truth.source, 'model': self.model.source,
                'candidates': None if self.candidates is None else list(self.candidates),
                **self._truth_document(), 'fingerprint': self.fingerprint()}


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


def hidden_truth_text(truth: EffectConfig, effect: str | tuple[str, ...], size: float) -> str:
    """The truth document with ``effect`` (a name or several) added at ``size`` x its default (YAML text)."""
    hidden = (effect,) if isinstance(effect, str) else tuple(effect)
    document = safe_load_limited(truth.text, truth.source) or {}
    effects = dict(document.get('effects') or {})
    for name in hidden:
        effects[name] = scaled_params(name, size)
    document['effects'] = effects
    document.pop('description', None)
    return (f'# {truth.source} with {truth_label(hidden)} at {size:g} x the default (sofia atlas)\n'
            + yaml.safe_dump(document, sort_keys=False))


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


def _truth_set(value, model: EffectConfig, truth: EffectConfig) -> tuple[str, ...]:
    """One explicit truth: a list of effect names or 'a+b' ('none' or [] a control), checked, sorted."""
    if isinstance(value, str):
        names = [] if value.strip() == CONTROL else [part.strip() for part in value.split('+')]
    elif isinstance(value, list):
        names = value
    else:
        raise ConfigError(f'atlas truth {value!r}: give a list of effects, A+B, or [] / none for a control')
    checked = [_checked_effect(name, model, truth) for name in names]
    if len(set(checked)) < len(checked):
        raise ConfigError(f'atlas truth {truth_label(checked)} names an effect twice; hide each effect once')
    return tuple(sorted(checked))


def draw_truths(pool: tuple[str, ...], count: int, ks: tuple[int, ...], seed: int,
                listed: tuple[tuple[str, ...], ...] = ()) -> list[tuple[str, ...]]:
    """``count`` distinct sets of k effects from ``pool`` (k cycling through ``ks``), none of the sets ``listed``
    already (sorted tuples), the same for the same seed."""
    for k in ks:
        if not 1 <= k <= len(pool):
            raise ConfigError(f'draws: k = {k} is outside 1..{len(pool)} (the {len(pool)} effects of the pool); '
                              'give k within it')
    for k in set(ks):
        wanted = sum(1 for index in range(count) if ks[index % len(ks)] == k)
        free = math.comb(len(pool), k) - sum(1 for truth in set(listed) if len(truth) == k and set(truth) <= set(pool))
        if wanted > free:
            raise ConfigError(f'draws: {wanted} distinct sets of {k} effects asked from a pool of {len(pool)}, which '
                              f'has only {free} (besides the truths listed); draw fewer or widen the pool')
    rng = np.random.default_rng(seed)
    drawn: list[tuple[str, ...]] = []
    seen: set[tuple[str, ...]] = set(listed)
    for index in range(count):
        k = ks[index % len(ks)]
        chosen = tuple(sorted(str(name) for name in rng.choice(pool, size=k, replace=False)))
        while chosen in seen:  # each set once: a repeated set would only count its truth twice
            chosen = tuple(sorted(str(name) for name in rng.choice(pool, size=k, replace=False)))
        seen.add(chosen)
        drawn.append(chosen)
    return drawn


def _draw_pool(draws: TruthDraws, campaign: str, model: EffectConfig, truth: EffectConfig) -> tuple[str, ...]:
    """The pool of one campaign: the one given (checked) or the campaign's visible effects the model and truth lack."""
    if draws.pool is not None:
        return _unique([_checked_effect(name, model, truth) for name in draws.pool])
    return tuple(name for name in VISIBLE_EFFECTS[campaign] if name not in model.effects and name not in truth.effects)


def _checked_truths(campaign: str, explicit: list, draws: TruthDraws | None, controls: int,
                    model: EffectConfig, truth: EffectConfig) -> tuple[tuple[str, ...], ...]:
    """One campaign's truths: the explicit ones, then the draws (none of the sets listed), with
    the controls spread evenly among them (a partial atlas has its share of controls)."""
    truths = list(_unique([_truth_set(value, model, truth) for value in explicit]))
    if draws is not None:
        truths += draw_truths(_draw_pool(draws, campaign, model, truth), draws.count, draws.ks, draws.seed,
                              tuple(truths))
    spread: list[tuple[str, ...]] = []
    placed = 0
    for index, effects in enumerate(truths):
        spread.append(effects)
        while placed < (index + 1) * controls // len(truths):
            spread.append(())
            placed += 1
    return tuple(spread + [()] * (controls - placed))


def _count(value, what: str, low: int, high: int) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or not low <= value <= high:
        raise ConfigError(f'{what} {value!r} must be an integer in {low}..{high}')
    return value


def truth_draws(count, ks, seed, pool=None, max_tasks: int = MAX_TASKS) -> TruthDraws:
    """TruthDraws checked: a count within the task limit, each k an integer (draw_truths holds it against the
    pool), a seed, an optional pool of names."""
    if not isinstance(ks, list) or not ks:
        ks = [ks]
    if pool is not None and (not isinstance(pool, list) or not pool):
        raise ConfigError('draws: pool must be a non-empty list of effect names (leave it out for the campaign\'s '
                          'visible effects)')
    return TruthDraws(_count(count, 'draws: count', 1, max_tasks), tuple(_count(k, 'draws: k', 0, 1000) for k in ks),
                      _seed(seed), None if pool is None else tuple(pool))


def _size(value) -> float:
    if isinstance(value, bool):  # YAML's true ran as size 1
        raise ConfigError(f'atlas size {value!r} is not a number; sizes are multiples of the default, e.g. 0.5,1,2')
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


def _checked_task_count(counts: dict, max_tasks: int, truths: int = 0) -> None:
    """ConfigError when the axes multiply to more than ``max_tasks`` (before any hidden truth is built); ``truths``
    are the truth tasks of every campaign, flown with every seed."""
    seeds = counts.pop('seeds')
    cells = math.prod(counts.values())
    total = (cells + truths) * seeds
    if total > max_tasks:
        axes = [' x '.join(f'{count} {name}' for name, count in counts.items())] if cells or not truths else []
        axes += [f'{truths} truths'] if truths else []
        axes = f'{" + ".join(axes)}{", x" if truths and cells else " x"} {seeds} seeds'
        raise ConfigError(f'the grid is {total} tasks ({axes}), more than the {max_tasks} an atlas may have'
                          f'{_FORCE_HINT if max_tasks < FORCED_MAX_TASKS else _FORCED_HINT}; narrow an axis')


def _nonempty(name: str, values) -> list:
    if not values:
        raise ConfigError(f'the atlas grid is empty: no {name} given; give at least one '
                          f'(--{name} or "{name}:" in the grid file)')
    return list(values)


def _unique(values: list) -> tuple:
    return tuple(dict.fromkeys(values))


def _shipped_default(path: str, default: str) -> str | Path:
    """``path``, or where the checkout or the install keeps ``default`` when that is what ``path`` is and the current
    folder has no such file: the atlas run outside the checkout found no config/model/nominal.yaml."""
    if path != default or Path(path).exists():
        return path
    return shipped_file(default) or path


def grid_from_lists(*, effects, sizes, campaigns, seeds, model: str = DEFAULT_MODEL, truth: str = DEFAULT_TRUTH,
                    candidates=None, max_tasks: int = MAX_TASKS, truths=(), draws: TruthDraws | None = None,
                    controls: int = 0, search_rounds: int = 0) -> AtlasGrid:
    """The grid from plain lists (``effects`` may be ['all']: every effect the model lacks), with the truths
    (``truths`` explicit sets, ``draws``, ``controls``) of each campaign; ConfigError if bad or if it has more than
    ``max_tasks`` tasks."""
    from sofia_ros.compare.search import SEARCH_ROUNDS_RANGE

    model_config = load_effect_config(_shipped_default(model, DEFAULT_MODEL))
    truth_config = load_effect_config(_shipped_default(truth, DEFAULT_TRUTH))
    controls = _count(controls, 'controls', 0, max_tasks)
    has_truths = bool(truths) or draws is not None or controls > 0
    effects = list(effects) if has_truths else _nonempty('effects', effects)
    if effects == ['all']:
        effects = [name for name in CATALOGUE if name not in model_config.effects and name not in truth_config.effects
                   and name not in NOISE_EFFECTS]
    effect_names = _unique([_checked_effect(name, model_config, truth_config) for name in effects])
    size_values = _unique([_size(value) for value in (_nonempty('sizes', sizes) if effect_names else sizes)])
    pairs = _unique([_campaign_pair(text) for text in _nonempty('campaigns', campaigns)])
    seed_values = _unique([_seed(value) for value in _nonempty('seeds', seeds)])
    if search_rounds and not has_truths:
        raise ConfigError('search_rounds is for truths (truths, draws or controls); the effects axis runs one compare '
                          'per cell')
    low, high = SEARCH_ROUNDS_RANGE
    if search_rounds != 0:
        _count(search_rounds, 'search_rounds', low, high)
    truth_count = len(truths) + (draws.count if draws is not None else 0) + controls
    _checked_task_count({'effects': len(effect_names), 'sizes': len(size_values), 'campaigns': len(pairs),
                         'seeds': len(seed_values)}, max_tasks, truth_count * len(pairs))
    truth_sets = tuple(_checked_truths(campaign, list(truths), draws, controls, model_config, truth_config)
                       for campaign, _ in pairs) if has_truths else ()
    longest = max(map(len, truth_sets), default=0)
    if longest and max(seed_values) + longest - 1 > _MAX_SEED:
        raise ConfigError(f'seed {max(seed_values)} + {longest - 1} (truth {longest - 1} is flown with seed s + '
                          f'{longest - 1}) is beyond the largest seed {_MAX_SEED}; give smaller seeds')
    if candidates is not None:
        if not candidates:
            raise ConfigError('candidates names no effect; leave it out to rank the whole catalogue')
        for name in candidates:
            get_effect(name)
        candidates = _unique(list(candidates))
    for effect in effect_names:  # every hidden truth must be a valid truth file (ranges) before anything runs
        for size in size_values:
            parse_effect_config(hidden_truth_text(truth_config, effect, size), f'{truth} with {effect} at {size:g}x')
    for hidden in sorted({effects for campaign_truths in truth_sets for effects in campaign_truths}):
        parse_effect_config(hidden_truth_text(truth_config, hidden, 1.0), f'{truth} with {truth_label(hidden)}')
    return AtlasGrid(effect_names, size_values, pairs, seed_values, truth_config, model_config, candidates,
                     truth_sets, search_rounds)


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


def _draws_of_document(value, max_tasks: int) -> TruthDraws | None:
    """The ``draws:`` mapping of a grid file (count, k, pool, seed)."""
    if value is None:
        return None
    if not isinstance(value, dict):
        raise ConfigError(f'draws must be a mapping with {", ".join(_DRAW_KEYS)} (e.g. {{count: 20, k: [2, 3], '
                          'seed: 1}})')
    unknown = sorted(set(map(str, value)) - set(_DRAW_KEYS))
    if unknown:
        raise ConfigError(f'draws: unknown key(s) {", ".join(unknown)} (allowed: {", ".join(_DRAW_KEYS)})')
    if 'count' not in value:
        raise ConfigError('draws: count missing; give how many truths to draw')
    return truth_draws(value['count'], value.get('k', [2, 3]), value.get('seed', 1), value.get('pool'), max_tasks)


def _beside(path: Path, document: dict, key: str, default: str) -> str:
    """The ``model`` or ``truth`` file a grid file names, a relative path read from the grid file's folder (as the
    file is written, wherever the atlas runs); ``default`` where it names none."""
    if key not in document:
        return default
    named = Path(str(document[key]))
    return str(named if named.is_absolute() else path.parent / named)


def grid_from_file(path, max_tasks: int = MAX_TASKS) -> AtlasGrid:
    """The grid of a YAML file (keys: effects, sizes, campaigns, seeds, model, truth, candidates, and the truths:
    truths, draws, controls, search_rounds); ``model`` and ``truth`` relative to the file's folder."""
    path = Path(path)
    text = read_text_capped(path, _MAX_GRID_FILE_BYTES, 'grid file')
    document = safe_load_limited(text, str(path))
    if not isinstance(document, dict):
        raise ConfigError(f'{path}: a grid file is a mapping with effects, sizes, campaigns and seeds')
    unknown = sorted(set(map(str, document)) - set(_GRID_KEYS))
    if unknown:
        raise ConfigError(f'{path}: unknown key(s) {", ".join(unknown)} (allowed: {", ".join(_GRID_KEYS)})')
    candidates = document.get('candidates')
    if candidates is not None and not isinstance(candidates, list):
        raise ConfigError(f'{path}: candidates must be a list of effect names')
    try:
        truths = _listed(document, 'truths', max_tasks)
        return grid_from_lists(effects=_listed(document, 'effects', max_tasks),
                               sizes=_listed(document, 'sizes', max_tasks),
                               campaigns=_listed(document, 'campaigns', max_tasks),
                               seeds=_listed(document, 'seeds', max_tasks),
                               model=_beside(path, document, 'model', DEFAULT_MODEL),
                               truth=_beside(path, document, 'truth', DEFAULT_TRUTH), candidates=candidates,
                               max_tasks=max_tasks, truths=truths,
                               draws=_draws_of_document(document.get('draws'), max_tasks),
                               controls=document.get('controls', 0),
                               search_rounds=document.get('search_rounds', 0))
    except UnknownEffectError as err:
        raise UnknownEffectError(f'{path}: {err}') from err
    except ConfigError as err:
        raise ConfigError(f'{path}: {err}') from err
