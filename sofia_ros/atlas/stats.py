"""What a planner reads from the atlas' rows: detection against size, detectable sizes, sigma calibration,
confused pairs, the thesis' Table 6.5 as one slice, and for truths with several effects the success rates per
campaign and k, the controls' rate and the pairs most often confused.

Rows are the dicts of atlas.task.ROW_FIELDS; failed rows (``error`` set) count nowhere. The rows of the effects
axis (``truth_effects`` null) make the single-effect tables, the truth rows the truth tables.
"""

from __future__ import annotations

import json
import math
from collections import Counter, defaultdict
from dataclasses import dataclass

import numpy as np
from scipy.stats import binomtest

from sofia_ros.atlas.scoring import SCORES, SUCCESSES, confused_pairs, stated_pairs
from sofia_ros.calibration.accuracy import sigma_beta_from_length_rad, sigma_r_rad, standard_error_of_mean
from sofia_ros.units import ARCSEC_PER_RAD, RAD_PER_ARCSEC, RAD_PER_DEG

__all__ = ['CONFIDENCE', 'Calibration', 'Confusion', 'DetectableSize', 'DetectionPoint', 'Table65Row',
           'TABLE_6_5', 'TruthConfusion', 'TruthRate', 'campaign_label', 'thesis_sigmas_arcsec', 'confusions',
           'detectable_sizes', 'detection_curves', 'fit_calibration', 'table_6_5_slice', 'truth_confusions',
           'truth_misses', 'truth_rates']

#: Two-sided confidence of the binomial intervals (Clopper-Pearson, scipy.stats.binomtest).
CONFIDENCE = 0.95
#: Table 6.5 as printed: n -> (sigma_R arcsec, sigma_beta arcmin), sigma_c = 0.327" (one HIPO pixel).
TABLE_6_5 = {1: (5.3, 5.5), 18: (1.2, 1.3)}
_TABLE_6_5_SIGMA_C_ARCSEC = 0.327
#: Table 6.5 is headed gamma = 4 deg, but its sigma_R follows from eq. 3.32 with 5 deg (the demo's note).
_TABLE_6_5_LOS_ROTATION_DEG = 5.0
_TABLE_6_5_LENGTH_ARCMIN = 4.8


@dataclass(frozen=True)
class DetectionPoint:
    """Detections of one effect at one size in one campaign variant, with the binomial interval."""

    effect: str
    campaign: str
    size: float
    trials: int
    detections: int
    probability: float
    low: float
    high: float


@dataclass(frozen=True)
class DetectableSize:
    """The size (x default) at which the detection probability reaches ``level``.

    ``bound``: '=' interpolated between two sizes of the grid, '<=' reached at the smallest size
    tried (``size`` is that size), '>' never reached (``size`` is the largest tried).
    """

    effect: str
    campaign: str
    level: float
    size: float
    bound: str


@dataclass(frozen=True)
class Calibration:
    """Fitted reference parameter of one effect at one size: bias and scatter against the reported sigma."""

    effect: str
    campaign: str
    size: float
    param: str
    count: int
    true_value: float
    bias: float
    scatter: float
    median_sigma: float
    #: mean and standard deviation of (fitted - true) / sigma: 0 and 1 for honest sigmas
    pull_mean: float
    pull_std: float
    #: fitted values without a sigma (null, or inf: the data do not determine the parameter): in no pull
    unconstrained: int = 0


@dataclass(frozen=True)
class Confusion:
    """How often compare named ``other`` for hidden ``effect`` (top candidate or a degenerate pair)."""

    effect: str
    other: str
    campaign: str
    count: int
    trials: int
    kind: str


@dataclass(frozen=True)
class Table65Row:
    """Alignment accuracy at n measurements per axis: this atlas against Table 6.5 and eqs. 3.32, 3.34, 3.37."""

    variant: str
    measurements: int
    runs: int
    #: RMS over runs of the accepted matrix against /truth: EL and XEL pooled (the LOS tilt), LOS
    tilt_rms_arcsec: float
    los_rms_arcsec: float
    #: the calibration node's own predicted sigma (mean over runs)
    predicted_tilt_arcsec: float
    predicted_los_arcsec: float
    #: eqs. 3.32, 3.34 with 3.37 at Table 6.5's sigma_c = 0.327" and this n
    thesis_sigma_r_arcsec: float
    thesis_sigma_beta_arcsec: float


@dataclass(frozen=True)
class TruthRate:
    """How often the truths with k hidden effects (k = 0: the controls) of one campaign variant ended right."""

    campaign: str
    k: int
    trials: int
    #: exact + equivalent (docs/atlas.md: a control is right when explained with nothing added)
    successes: int
    counts: dict
    probability: float
    low: float
    high: float


@dataclass(frozen=True)
class TruthConfusion:
    """A hidden effect missing from final models that held ``named`` instead; ``stated``: of them, how often the
    output named the two as competitors or equivalents."""

    hidden: str
    named: str
    campaign: str
    count: int
    stated: int


def campaign_label(row: dict) -> str:
    """``campaign:variant``, as the grid names it."""
    return f'{row["campaign"]}:{row["variant"]}'


def _good(rows):
    return [row for row in rows if row['error'] is None]


def _cells(rows):
    """The good rows of the effects axis (one hidden effect at a size)."""
    return [row for row in _good(rows) if row['truth_effects'] is None]


def _truth_rows(rows):
    """The good rows of truths (several effects, or a control)."""
    return [row for row in _good(rows) if row['truth_effects'] is not None]


def _names(text) -> list[str]:
    return [name for name in (text or '').split(',') if name]


def truth_rates(rows: list[dict]) -> list[TruthRate]:
    """Success per campaign variant and number of hidden effects (k = 0: the controls), with its Clopper-Pearson
    interval and the count of each score."""
    groups = defaultdict(list)
    for row in _truth_rows(rows):
        groups[(campaign_label(row), row['k'])].append(row['score'])
    rates = []
    for (campaign, k), scores in sorted(groups.items()):
        successes = sum(score in SUCCESSES for score in scores)
        interval = binomtest(successes, len(scores)).proportion_ci(confidence_level=CONFIDENCE)
        rates.append(TruthRate(campaign, k, len(scores), successes, {name: scores.count(name) for name in SCORES},
                               successes / len(scores), float(interval.low), float(interval.high)))
    return rates


def truth_confusions(rows: list[dict]) -> list[TruthConfusion]:
    """Pairs (hidden, in the final model instead) over the truth rows, most often first."""
    counts, stated = Counter(), Counter()
    for row in _truth_rows(rows):
        pairs = stated_pairs(json.loads(row['competing'] or '[]'),
                             [{'model': label} for label in json.loads(row['equivalents'] or '[]')])
        for hidden, named in confused_pairs(_names(row['truth_effects']), _names(row['final_added'])):
            key = (hidden, named, campaign_label(row))
            counts[key] += 1
            stated[key] += frozenset((hidden, named)) in pairs
    return sorted((TruthConfusion(*key, count, stated[key]) for key, count in counts.items()),
                  key=lambda c: (-c.count, c.hidden, c.named, c.campaign))


def truth_misses(rows: list[dict]) -> list[dict]:
    """The truth rows that did not end right (score extra or missed), in key order."""
    return sorted((row for row in _truth_rows(rows) if row['score'] not in SUCCESSES), key=lambda row: row['key'])


def detection_curves(rows: list[dict]) -> list[DetectionPoint]:
    """Detection probability per effect, campaign variant and size, with its Clopper-Pearson interval."""
    groups = defaultdict(list)
    for row in _cells(rows):
        groups[(row['effect'], campaign_label(row), row['size'])].append(bool(row['detected']))
    points = []
    for (effect, campaign, size), hits in sorted(groups.items()):
        result = binomtest(sum(hits), len(hits))
        interval = result.proportion_ci(confidence_level=CONFIDENCE)
        points.append(DetectionPoint(effect, campaign, size, len(hits), sum(hits), sum(hits) / len(hits),
                                     float(interval.low), float(interval.high)))
    return points


def detectable_sizes(points: list[DetectionPoint], levels=(0.5, 0.9)) -> list[DetectableSize]:
    """The 50 % and 90 % detectable sizes: linear between the sizes around the first crossing."""
    curves = defaultdict(list)
    for point in points:
        curves[(point.effect, point.campaign)].append(point)
    found = []
    for (effect, campaign), curve in sorted(curves.items()):
        curve = sorted(curve, key=lambda point: point.size)
        for level in levels:
            index = next((i for i, point in enumerate(curve) if point.probability >= level), None)
            if index is None:
                found.append(DetectableSize(effect, campaign, level, curve[-1].size, '>'))
            elif index == 0:
                found.append(DetectableSize(effect, campaign, level, curve[0].size, '<='))
            else:
                below, above = curve[index - 1], curve[index]
                share = (level - below.probability) / (above.probability - below.probability)
                found.append(DetectableSize(effect, campaign, level,
                                            below.size + share * (above.size - below.size), '='))
    return found


def fit_calibration(rows: list[dict]) -> list[Calibration]:
    """Bias and scatter of the fitted reference parameter against the sigma compare reported, per size."""
    groups = defaultdict(list)
    for row in _cells(rows):
        if row['size'] > 0 and row['fitted_value'] is not None and row['true_value'] is not None:
            groups[(row['effect'], campaign_label(row), row['size'], row['param'])].append(row)
    found = []
    for (effect, campaign, size, param), members in sorted(groups.items()):
        fitted = np.array([row['fitted_value'] for row in members])
        true_value = float(members[0]['true_value'])
        sigmas = np.array([row['fitted_sigma'] if row['fitted_sigma'] is not None else math.nan for row in members])
        # compare's sigma is inf (null in its JSON) where the data do not determine the parameter: such a value has
        # no pull, where (fitted - true) / inf would count as a perfect one (0).
        sigmas[~np.isfinite(sigmas)] = math.nan
        pulls = (fitted - true_value) / sigmas
        pulls = pulls[np.isfinite(pulls)]
        found.append(Calibration(
            effect, campaign, size, param, len(members), true_value, float(np.mean(fitted) - true_value),
            float(np.std(fitted, ddof=1)) if len(fitted) > 1 else math.nan,
            float(np.nanmedian(sigmas)) if np.any(np.isfinite(sigmas)) else math.nan,
            float(np.mean(pulls)) if len(pulls) else math.nan,
            float(np.std(pulls, ddof=1)) if len(pulls) > 1 else math.nan, int(np.sum(np.isnan(sigmas)))))
    return found


def confusions(rows: list[dict]) -> list[Confusion]:
    """Effects compare took for the hidden one (a significant other top candidate), and degenerate partners."""
    trials = Counter()
    named = Counter()
    for row in _cells(rows):
        if row['size'] <= 0:
            continue
        campaign = campaign_label(row)
        trials[(row['effect'], campaign)] += 1
        if not row['detected'] and row['top_candidate'] not in (None, row['effect']) and row['top_delta_bic'] >= 6.0:
            named[(row['effect'], row['top_candidate'], campaign, 'top candidate')] += 1
        for other in (row['degenerate_with'] or '').split(','):
            if other:
                named[(row['effect'], other, campaign, 'degenerate')] += 1
    return sorted((Confusion(effect, other, campaign, count, trials[(effect, campaign)], kind)
                   for (effect, other, campaign, kind), count in named.items()),
                  key=lambda c: (-c.count / c.trials, c.effect, c.other))


def thesis_sigmas_arcsec(measurements: int) -> tuple[float, float]:
    """Table 6.5's sigma_R and sigma_beta for n measurements (eqs. 3.32, 3.34, 3.37), arcsec."""
    sigma_c_rad = _TABLE_6_5_SIGMA_C_ARCSEC * RAD_PER_ARCSEC
    sigma_r = sigma_r_rad(sigma_c_rad, _TABLE_6_5_LOS_ROTATION_DEG * RAD_PER_DEG)
    sigma_beta = sigma_beta_from_length_rad(sigma_c_rad, _TABLE_6_5_LENGTH_ARCMIN / 60.0 * RAD_PER_DEG)
    return (float(standard_error_of_mean(sigma_r, measurements)) * ARCSEC_PER_RAD,
            float(standard_error_of_mean(sigma_beta, measurements)) * ARCSEC_PER_RAD)


def table_6_5_slice(rows: list[dict]) -> tuple[list[Table65Row], str]:
    """Alignment accuracy against the number of measurements per axis, and which rows it used.

    The control rows (size 0, nothing hidden; truth controls too) when the grid has them, else every alignment row
    of one hidden effect.
    """
    alignment = [row for row in _good(rows) if row['campaign'] == 'alignment' and not row['k']
                 and row['misalignment_el_arcsec'] is not None and row['measurements'] is not None]
    control = [row for row in alignment if row['size'] == 0]
    used, which = (control, 'control runs (size 0)') if control else (alignment, 'every alignment run')
    groups = defaultdict(list)
    for row in used:
        groups[(row['measurements'], row['variant'])].append(row)
    table = []
    for (measurements, variant), members in sorted(groups.items()):
        tilt = np.array([[row['misalignment_el_arcsec'], row['misalignment_xel_arcsec']] for row in members])
        los = np.array([row['misalignment_los_arcsec'] for row in members])
        sigma_r, sigma_beta = thesis_sigmas_arcsec(measurements)
        table.append(Table65Row(variant, measurements, len(members), float(np.sqrt(np.mean(tilt**2))),
                                float(np.sqrt(np.mean(los**2))),
                                float(np.mean([row['predicted_sigma_el_arcsec'] for row in members])),
                                float(np.mean([row['predicted_sigma_los_arcsec'] for row in members])),
                                sigma_r, sigma_beta))
    return table, which
