"""Residual centroid drift during a hold (6.3): column pixels linear, row pixels linear plus a sinusoid.

After the drift estimation the FPI centroids of a held star still drifted in 2004: the columns
linearly (-2.5 to +1 px/min), the rows linearly (1.4 px/min) plus a sinusoid (period 5.2 min,
amplitude 2.2 px), fitted with a nonlinear curve fit to segments that show a full period
([Harms 2005c]). Here each series is fitted with scipy's curve_fit: the line, and for the rows
the line plus a sinusoid whose period lies between four frame intervals and the span of the
series (a full period inside the hold), started from the best period of a frequency grid. The
sinusoid is kept only when it lowers the BIC by at least SIGNIFICANT_DELTA_BIC (analysis.ranking).
Sigmas are curve_fit's, scaled by the scatter about the fit.
"""

from __future__ import annotations

import warnings
from typing import TypedDict

import numpy as np
import numpy.typing as npt
from scipy.optimize import OptimizeWarning, curve_fit

from sofia_ros.analysis.ranking import SIGNIFICANT_DELTA_BIC, bic
from sofia_ros.errors import FitError, InvalidArgumentError
from sofia_ros.units import DEG_PER_RAD
from sofia_ros.validate import finite_array

__all__ = ['line_and_sinusoid_px', 'fit_centroid_drift', 'MIN_SINUSOID_FRAMES', 'CentroidDrift', 'LineDrift',
           'RowDrift', 'SinusoidDrift']

#: Line plus sinusoid has five parameters: fit it only to at least twice as many frames.
MIN_SINUSOID_FRAMES = 10
#: Shortest period tried, in frame intervals (two frames per half period).
_MIN_PERIOD_INTERVALS = 4.0
#: Steps of the start grid per frequency resolution 1/span (a peak is about one resolution wide).
_GRID_OVERSAMPLING = 5


class LineDrift(TypedDict):
    """The linear drift of one pixel axis (its part of the JSON output)."""

    drift_px_per_min: float
    drift_sigma: float
    offset_px: float
    rms_px: float


class SinusoidDrift(TypedDict):
    """The sinusoid of the rows, where BIC keeps it; sigmas in the unit of their value."""

    period_s: float
    period_sigma: float
    amplitude_px: float
    amplitude_sigma: float
    phase_deg: float
    phase_sigma: float


class RowDrift(LineDrift):
    """The rows: the line (of line + sinusoid where kept), the sinusoid's delta-BIC and the sinusoid."""

    #: None where the series is too short to try a sinusoid.
    sinusoid_delta_bic: float | None
    sinusoid: SinusoidDrift | None


class CentroidDrift(TypedDict):
    """The hold drift of one centroid series (fit_centroid_drift)."""

    frames: int
    span_s: float
    reference_time_s: float
    column: LineDrift
    row: RowDrift


def line_and_sinusoid_px(time_s: np.ndarray, offset_px: float, slope_px_per_s: float, amplitude_px: float,
                         period_s: float, phase_rad: float) -> np.ndarray:
    """Residual centroid drift a + b t + A sin(2 pi t / P + phi), t from the series' reference time (6.3).

    Args:
        time_s: time from the series' reference time [s].
        offset_px: a, the centroid at the reference time [px].
        slope_px_per_s: b [px/s].
        amplitude_px: A [px].
        period_s: P [s].
        phase_rad: phi [rad].

    Returns:
        The centroid [px] at each time.
    """
    return offset_px + slope_px_per_s * time_s + amplitude_px * np.sin(2.0 * np.pi * time_s / period_s + phase_rad)


def _line_px(time_s, offset_px, slope_px_per_s):
    return offset_px + slope_px_per_s * time_s


def _curve_fit(model, time_s, values_px, start, bounds=(-np.inf, np.inf)):
    """Values, 1-sigma errors (inf where the data leave a parameter undetermined) and RSS of one fit."""
    with warnings.catch_warnings():
        # A covariance that cannot be estimated comes back as inf: reported as unconstrained.
        warnings.simplefilter('ignore', OptimizeWarning)
        try:
            values, covariance = curve_fit(model, time_s, values_px, p0=start, bounds=bounds)
        except RuntimeError as err:
            raise FitError(f'centroid drift: the fit did not converge ({err})') from err
    residual = values_px - model(time_s, *values)
    return values, np.sqrt(np.abs(np.diag(covariance))), float(residual @ residual)


def _sinusoid_start(time_s, values_px, min_period_s, max_period_s):
    """Start values of line + sinusoid: the best period of a frequency grid, each fitted linearly."""
    frequencies_hz = np.arange(1.0 / max_period_s, 1.0 / min_period_s, 1.0 / (_GRID_OVERSAMPLING * max_period_s))
    best = None
    for frequency_hz in frequencies_hz:
        phase = 2.0 * np.pi * frequency_hz * time_s
        design = np.column_stack([np.ones_like(time_s), time_s, np.sin(phase), np.cos(phase)])
        coefficients, *_ = np.linalg.lstsq(design, values_px, rcond=None)
        residual = values_px - design @ coefficients
        if best is None or residual @ residual < best[0]:
            best = (residual @ residual, frequency_hz, coefficients)
    _, frequency_hz, (offset, slope, sine, cosine) = best
    # A sin(wt + phi) = A cos(phi) sin(wt) + A sin(phi) cos(wt).
    period_s = float(np.clip(1.0 / frequency_hz, min_period_s, max_period_s))
    return [offset, slope, max(np.hypot(sine, cosine), 1e-9), period_s, np.arctan2(cosine, sine)]


def _line_entry(values: np.ndarray, sigma: np.ndarray, rss: float, count: int) -> LineDrift:
    return {'drift_px_per_min': float(values[1] * 60.0), 'drift_sigma': float(sigma[1] * 60.0),
            'offset_px': float(values[0]), 'rms_px': float(np.sqrt(rss / count))}


def fit_centroid_drift(time_s: npt.ArrayLike, column_px: npt.ArrayLike, row_px: npt.ArrayLike) -> CentroidDrift:
    """Hold drift of a centroid series: column linear, row linear + sinusoid when BIC selects it (6.3).

    Args:
        time_s: N increasing frame times [s].
        column_px: N centroid columns (X) [px].
        row_px: N centroid rows (Y) [px].

    Returns:
        The column's line and the row's line with its sinusoid (None unless BIC keeps it).

    Raises:
        InvalidArgumentError: fewer than 3 frames, times not increasing, or values not finite or of other lengths.
        FitError: a curve fit did not converge.
    """
    times = finite_array('time_s', time_s, shape=(None,))
    count = len(times)
    columns = finite_array('column_px', column_px, shape=(count,))
    rows = finite_array('row_px', row_px, shape=(count,))
    if count < 3:
        raise InvalidArgumentError(f'centroid drift needs at least 3 frames, got {count}')
    if np.any(np.diff(times) <= 0):
        raise InvalidArgumentError('centroid drift: time_s must increase')
    reference_s = float((times[0] + times[-1]) / 2.0)
    elapsed = times - reference_s
    column_fit = _curve_fit(_line_px, elapsed, columns, [columns.mean(), 0.0])
    row_line = _curve_fit(_line_px, elapsed, rows, [rows.mean(), 0.0])
    row: RowDrift = {**_line_entry(*row_line, count), 'sinusoid_delta_bic': None, 'sinusoid': None}
    span_s = float(times[-1] - times[0])
    min_period_s = _MIN_PERIOD_INTERVALS * float(np.median(np.diff(times)))
    if count >= MIN_SINUSOID_FRAMES and span_s > min_period_s:
        start = _sinusoid_start(elapsed, rows, min_period_s, span_s)
        values, sigma, rss = _curve_fit(line_and_sinusoid_px, elapsed, rows, start,
                                        ([-np.inf, -np.inf, 0.0, min_period_s, -np.inf],
                                         [np.inf, np.inf, np.inf, span_s, np.inf]))
        delta_bic = bic(row_line[2], count, 2) - bic(rss, count, 5)
        row['sinusoid_delta_bic'] = float(delta_bic)
        if delta_bic >= SIGNIFICANT_DELTA_BIC:
            phase_rad = float(np.angle(np.exp(1j * values[4])))
            row.update(_line_entry(values, sigma, rss, count))
            row['sinusoid'] = {'period_s': float(values[3]), 'period_sigma': float(sigma[3]),
                               'amplitude_px': float(values[2]), 'amplitude_sigma': float(sigma[2]),
                               'phase_deg': phase_rad * DEG_PER_RAD, 'phase_sigma': float(sigma[4] * DEG_PER_RAD)}
    return {'frames': count, 'span_s': span_s, 'reference_time_s': reference_s,
            'column': _line_entry(*column_fit, count), 'row': row}
