"""Is there structure in a residual? Trend, category and period tests with false-alarm probabilities.

Each test compares a residual series against the null hypothesis "white noise of unknown
variance" and returns a p-value, which callers turn into a family-wise significance in
sigma (Bonferroni over every test they ran: the look-elsewhere effect):

- a smooth trend with a variable: weighted least squares of Legendre polynomials P0..P3 of
  the variable against P0 alone, F-test (the TPOINT-style question "does it follow X?");
- a smooth field over two variables (the detector position): products of Legendre polynomials
  P_i(x) P_j(y), i + j <= 3, against P0 alone, F-test: a distortion such as x y or x r^2
  averages away along either axis alone;
- a dependence on a category (the star): one-way analysis of variance, F-test;
- a period: the classical (Schuster) periodogram of the weighted series on a regular grid,
  normalized by the series' own variance so that each power is Exp(1) under the null, with
  the false-alarm probability of the highest of M independent frequencies, 1 - (1 - e^-z)^M
  (Scargle 1982), then the period refined by a least-squares sinusoid fit. M is three times
  the band's Rayleigh resolutions: the oversampled search finds peaks between them, and three
  calibrates the probability on white noise with gaps or irregular sampling (a test pins it).

Weights are inverse variances up to a common factor (e.g. the number of stars averaged in a
frame). Nothing is clipped: rows far from the rest are the signal these tests look for.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from numpy.polynomial import legendre
# The distributions' functions from scipy.special, which scipy.stats calls for them: importing scipy.stats cost
# every compare 0.4 s and 23 MB.
from scipy import optimize, special

from sofia_ros.effects.empirical import field_columns, field_terms
from sofia_ros.errors import InvalidArgumentError

__all__ = ['TrendTest', 'PeriodTest', 'trend_test', 'field_test', 'category_test', 'period_test', 'sigma_of_probability',
           'TREND_DEGREE']

TREND_DEGREE = 3
_MIN_ROWS = 12
_OVERSAMPLING = 4
#: Independent frequencies per Rayleigh resolution, calibrated by simulation (test_structure.py).
_FREQUENCIES_PER_RESOLUTION = 3.0


@dataclass(frozen=True)
class TrendTest:
    """A dependence of the residual on a variable: p-value, the fitted shape's half range, the shape on a grid."""

    p_value: float
    amplitude: float
    centres: np.ndarray
    shape: np.ndarray


@dataclass(frozen=True)
class PeriodTest:
    """The strongest sinusoid: period, amplitude, normalized power and false-alarm probability."""

    period: float
    amplitude: float
    power: float
    false_alarm_probability: float


def sigma_of_probability(probability: float) -> float:
    """Two-sided Gaussian significance of a probability: p = erfc(sigma / sqrt 2).

    Args:
        probability: a p-value (clipped to [1e-300, 1]).

    Returns:
        The significance in sigma.
    """
    # norm.isf(q) = -ndtri(q); 0.0 - keeps an exact zero positive, as norm.isf gives it.
    return 0.0 - float(special.ndtri(np.clip(probability, 1e-300, 1.0) / 2.0))


def _unit_interval(values):
    """The values mapped linearly onto [-1, 1] over their own range (the Legendre polynomials' domain)."""
    return 2.0 * (values - np.min(values)) / np.ptp(values) - 1.0


def _weighted_rss(design, values, weights):
    root = np.sqrt(weights)
    coefficients, *_ = np.linalg.lstsq(design * root[:, None], values * root, rcond=None)
    residual = values - design @ coefficients
    return float(weights @ residual**2), coefficients


def trend_test(variable: npt.ArrayLike, values: npt.ArrayLike, weights: npt.ArrayLike | None = None,
               degree: int = TREND_DEGREE, *, whitening: npt.ArrayLike | None = None) -> TrendTest | None:
    """F-test of Legendre P0..P_degree of the variable against a constant; None where it cannot be tested.

    With ``whitening`` (rows of values x rows of variable), the values are already whitened
    residuals of correlated data and the test is generalized least squares: the Legendre columns
    are whitened the same way (the trend is then a shape of the data before whitening).

    Args:
        variable: the variable at each row (at each row before whitening, with ``whitening``).
        values: the residuals.
        weights: inverse variances up to a common factor; None for equal weights.
        degree: the highest Legendre degree (lowered to the distinct values of the variable less one).
        whitening: (residual rows, variable rows) matrix of whitened residuals; None for independent rows.

    Returns:
        The p-value, the shape's half range and the shape on 25 points over the variable's range; None with
        fewer than 12 rows, a constant variable, or no degrees of freedom left.

    Raises:
        InvalidArgumentError: the variable's (or the whitening's) shape does not fit the residuals.
    """
    variable, values = np.asarray(variable, dtype=float), np.asarray(values, dtype=float)
    weights = np.ones(len(values)) if weights is None else np.asarray(weights, dtype=float)
    if whitening is None and len(variable) != len(values):
        raise InvalidArgumentError(f'{len(variable)} variable values for {len(values)} residuals')
    if whitening is not None and np.shape(whitening) != (len(values), len(variable)):
        raise InvalidArgumentError(f'whitening of shape {np.shape(whitening)} for {len(values)} residuals of '
                                   f'{len(variable)} variable values')
    if len(values) < _MIN_ROWS:
        return None
    low, high = float(np.min(variable)), float(np.max(variable))
    degree = min(degree, len(np.unique(np.round(variable, 9))) - 1)
    if high <= low or degree < 1:
        return None
    scaled = _unit_interval(variable)
    shape_columns = np.column_stack([legendre.legval(scaled, np.eye(degree + 1)[k]) for k in range(degree + 1)])
    design = shape_columns if whitening is None else np.asarray(whitening) @ shape_columns
    rss_constant, _ = _weighted_rss(design[:, :1], values, weights)
    rss_shape, coefficients = _weighted_rss(design, values, weights)
    dof = len(values) - degree - 1
    if dof <= 0 or rss_shape <= 0.0:
        return None
    f_value = (rss_constant - rss_shape) / degree / (rss_shape / dof)
    centres = np.linspace(low, high, 25)
    grid = 2.0 * (centres - low) / (high - low) - 1.0
    shape = legendre.legval(grid, coefficients)
    fitted = shape_columns @ coefficients
    return TrendTest(float(special.fdtrc(degree, dof, max(f_value, 0.0))), float(np.ptp(fitted) / 2.0), centres, shape)


def field_test(x: npt.ArrayLike, y: npt.ArrayLike, values: npt.ArrayLike, weights: npt.ArrayLike | None = None,
               degree: int = TREND_DEGREE) -> TrendTest | None:
    """F-test of the products P_i(x) P_j(y), i + j <= degree, against a constant; None where it cannot be tested.

    Each variable is mapped onto [-1, 1] over the rows' range. The amplitude is half the range of the fitted
    field over the rows (the shape grid of a one-variable trend has no meaning here: both are empty).

    Args:
        x: the first variable at each row (the detector column).
        y: the second variable at each row (the detector row).
        values: the residuals.
        weights: inverse variances up to a common factor; None for equal weights.
        degree: the highest total degree i + j.

    Returns:
        The p-value and the field's half range (empty centres and shape); None with too few rows, a constant
        variable, or fewer than two independent columns.

    Raises:
        InvalidArgumentError: x, y and values of different lengths.
    """
    x, y, values = (np.asarray(array, dtype=float) for array in (x, y, values))
    weights = np.ones(len(values)) if weights is None else np.asarray(weights, dtype=float)
    if not len(x) == len(y) == len(values):
        raise InvalidArgumentError(f'{len(x)} x and {len(y)} y values for {len(values)} residuals')
    columns = len(field_terms(degree))
    if len(values) < max(_MIN_ROWS, 2 * columns) or np.ptp(x) <= 0.0 or np.ptp(y) <= 0.0:
        return None
    design = field_columns(_unit_interval(x), _unit_interval(y), degree)
    # Stars at a few fixed positions, or x following y, leave fewer independent columns: the F-test counts those.
    rank = int(np.linalg.matrix_rank(design * np.sqrt(weights)[:, None]))
    dof = len(values) - rank
    if rank < 2 or dof <= 0:
        return None
    rss_constant, _ = _weighted_rss(design[:, :1], values, weights)
    rss_field, coefficients = _weighted_rss(design, values, weights)
    if rss_field <= 0.0:
        return None
    f_value = (rss_constant - rss_field) / (rank - 1) / (rss_field / dof)
    return TrendTest(float(special.fdtrc(rank - 1, dof, max(f_value, 0.0))), float(np.ptp(design @ coefficients) / 2.0),
                     np.zeros(0), np.zeros(0))


def category_test(categories: npt.ArrayLike, values: npt.ArrayLike,
                  weights: npt.ArrayLike | None = None) -> TrendTest | None:
    """One-way ANOVA F-test of the residual's mean per category; None with fewer than two categories.

    Args:
        categories: the category of each row (numeric labels, e.g. the star's HIP number).
        values: the residuals.
        weights: inverse variances up to a common factor; None for equal weights.

    Returns:
        The p-value, half the range of the means, the categories as centres and each mean less the grand mean
        as shape; None with fewer than two categories, too few rows, or no scatter within them.
    """
    values = np.asarray(values, dtype=float)
    weights = np.ones(len(values)) if weights is None else np.asarray(weights, dtype=float)
    labels, index = np.unique(np.asarray(categories), return_inverse=True)
    if len(labels) < 2 or len(values) <= len(labels) + 1:
        return None
    total = np.bincount(index, weights)
    means = np.bincount(index, weights * values) / total
    grand = float(weights @ values / weights.sum())
    between = float(total @ (means - grand) ** 2)
    within = float(weights @ (values - means[index]) ** 2)
    dof_between, dof_within = len(labels) - 1, len(values) - len(labels)
    if within <= 0.0:
        return None
    f_value = between / dof_between / (within / dof_within)
    return TrendTest(float(special.fdtrc(dof_between, dof_within, f_value)), float(np.ptp(means) / 2.0),
                     labels.astype(float), means - grand)


def _sinusoid_rss(times, values, weights, period, whitening=None):
    phase = 2.0 * np.pi * times / period
    design = np.column_stack([np.sin(phase), np.cos(phase), np.ones(len(times))])
    return _weighted_rss(design if whitening is None else whitening @ design, values, weights)


def _search_band(times, min_period, max_period):
    """(span, spacing, shortest and longest period searched) of sorted times, or None where nothing can be searched."""
    span = float(times[-1] - times[0])
    step = float(np.median(np.diff(times)))
    min_period = max(2.0 * step, min_period or 0.0)
    max_period = min(span / 2.0, max_period or np.inf)
    if step <= 0.0 or max_period <= min_period:
        return None
    return span, step, min_period, max_period


def _false_alarm(z, span, min_period, max_period):
    """Probability that the highest of the band's independent frequencies reaches normalized power z (Scargle 1982)."""
    independent = max(_FREQUENCIES_PER_RESOLUTION * span * (1.0 / min_period - 1.0 / max_period), 1.0)
    return float(-np.expm1(independent * np.log1p(-np.exp(-z)))) if z < 700 else 0.0


def _refined(times, values, weights, frequencies, best, min_period, max_period, whitening=None):
    """The period and amplitude of the exact least-squares sinusoid within one padded bin of the peak."""
    bin_width = frequencies[1]
    result = optimize.minimize_scalar(
        lambda frequency: _sinusoid_rss(times, values, weights, 1.0 / frequency, whitening)[0],
        bounds=(max(frequencies[best] - bin_width, 1.0 / max_period), min(frequencies[best] + bin_width,
                                                                            1.0 / min_period)),
        method='bounded', options={'xatol': bin_width * 1e-3})
    period = 1.0 / float(result.x)
    _, coefficients = _sinusoid_rss(times, values, weights, period, whitening)
    return period, float(np.hypot(coefficients[0], coefficients[1]))


def period_test(times: npt.ArrayLike, values: npt.ArrayLike, weights: npt.ArrayLike | None = None, *,
                min_period: float | None = None, max_period: float | None = None,
                whitening: npt.ArrayLike | None = None) -> PeriodTest | None:
    """The strongest period between the shortest the sampling resolves and half the record; None if too short.

    With ``whitening`` (rows of values x times), the values are whitened residuals of correlated
    data: the power at each frequency is then the generalized least-squares one (the sinusoid's
    columns whitened like the values, the reduction of the residual sum of squares over a
    constant, halved and in units of the residual variance: Exp(1) under the null as the
    classical power is), and the amplitude is the sinusoid's before whitening.

    Args:
        times: the time of each row (of each row before whitening, increasing, with ``whitening``).
        values: the residuals.
        weights: inverse variances up to a common factor; None for equal weights (ignored with ``whitening``).
        min_period: the shortest period searched, at least two sample spacings; None for that.
        max_period: the longest period searched, at most half the span; None for that.
        whitening: (residual rows, time rows) matrix of whitened residuals; None for independent rows.

    Returns:
        The refined period, its amplitude, the normalized power and the false-alarm probability; None with
        fewer than 12 rows, an empty band, or no scatter.

    Raises:
        InvalidArgumentError: a whitening whose shape does not fit the residuals and times.
    """
    if whitening is not None:
        return _whitened_period_test(times, values, whitening, min_period, max_period)
    times, values = np.asarray(times, dtype=float), np.asarray(values, dtype=float)
    weights = np.ones(len(values)) if weights is None else np.asarray(weights, dtype=float)
    order = np.argsort(times)
    times, values, weights = times[order], values[order], weights[order]
    if len(times) < _MIN_ROWS:
        return None
    band_limits = _search_band(times, min_period, max_period)
    if band_limits is None:
        return None
    span, step, min_period, max_period = band_limits
    centred = values - float(weights @ values / weights.sum())
    variance = float(weights @ centred**2) / (len(values) - 1)
    if variance <= 0.0:
        return None
    # The weighted series on a regular grid of the median spacing (gaps stay empty), zero-padded.
    slots = np.rint((times - times[0]) / step).astype(int)
    length = _OVERSAMPLING * (slots[-1] + 1)
    grid = np.zeros(length)
    np.add.at(grid, slots, weights * centred)
    power = np.abs(np.fft.rfft(grid)) ** 2 / (variance * weights.sum())
    frequencies = np.fft.rfftfreq(length, step)
    band = (frequencies >= 1.0 / max_period) & (frequencies <= 1.0 / min_period)
    if not np.any(band):
        return None
    best = np.flatnonzero(band)[np.argmax(power[band])]
    z = float(power[best])
    period, amplitude = _refined(times, centred, weights, frequencies, best, min_period, max_period)
    return PeriodTest(period, amplitude, z, _false_alarm(z, span, min_period, max_period))


def _whitened_period_test(times, values, whitening, min_period, max_period):
    """period_test's generalized least-squares branch: whitened values, their whitening (rows x times)."""
    times, values, whitening = np.asarray(times, dtype=float), np.asarray(values, dtype=float), np.asarray(whitening)
    if whitening.shape != (len(values), len(times)):
        raise InvalidArgumentError(f'whitening of shape {whitening.shape} for {len(values)} residuals at '
                                   f'{len(times)} times')
    if len(values) < _MIN_ROWS or np.any(np.diff(times) <= 0.0):
        return None
    band_limits = _search_band(times, min_period, max_period)
    if band_limits is None:
        return None
    span, step, min_period, max_period = band_limits
    length = _OVERSAMPLING * (int(np.rint(span / step)) + 1)
    frequencies = np.fft.rfftfreq(length, step)
    band = np.flatnonzero((frequencies >= 1.0 / max_period) & (frequencies <= 1.0 / min_period))
    if not len(band):
        return None
    # Everything relative to the whitened constant: the null model is a constant before whitening.
    constant = whitening @ np.ones(len(times))
    norm = float(constant @ constant)
    project = (lambda columns: columns - np.outer(constant, constant @ columns) / norm) if norm > 0 else (
        lambda columns: columns)
    centred = project(values[:, None])[:, 0]
    dof = len(values) - (1 if norm > 0 else 0)
    variance = float(centred @ centred) / max(dof, 1)
    if variance <= 0.0:
        return None
    phase = 2.0 * np.pi * np.outer(times, frequencies[band])
    sine, cosine = project(whitening @ np.sin(phase)), project(whitening @ np.cos(phase))
    ss, cc, sc = np.sum(sine**2, axis=0), np.sum(cosine**2, axis=0), np.sum(sine * cosine, axis=0)
    sv, cv = sine.T @ centred, cosine.T @ centred
    determinant = ss * cc - sc**2
    usable = determinant > 1e-12 * np.maximum(ss * cc, 1e-300)
    reduction = np.where(usable, (cc * sv**2 - 2.0 * sc * sv * cv + ss * cv**2) / np.where(usable, determinant, 1.0),
                         0.0)
    power = reduction / (2.0 * variance)
    peak = int(np.argmax(power))
    z = float(power[peak])
    period, amplitude = _refined(times, values, np.ones(len(values)), frequencies, band[peak], min_period, max_period,
                                 whitening)
    return PeriodTest(period, amplitude, z, _false_alarm(z, span, min_period, max_period))
