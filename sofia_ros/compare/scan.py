"""Where a model fails: trends and periods in what the fit leaves (the signature scan of `sofia compare`).

Each camera axis (pixel X, Y) is regressed on one variable at a time - elevation, time, slew
angle (the rotation of the last move, from the gyros), fine-drive LOS angle, temperature - and
the frame-averaged residual is searched for a period with the Lomb-Scargle periodogram
(scipy.signal.lombscargle), between two minutes and half the record.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import lombscargle
from scipy.spatial.transform import Rotation

__all__ = ['signature_scan', 'row_variables', 'VARIABLES']

VARIABLES = {'elevation_deg': 'elevation', 'time_s': 'time', 'slew_angle_deg': 'slew angle',
             'los_angle_deg': 'LOS angle', 'temperature_c': 'temperature'}
#: A trend is reported when its slope differs from zero by this many sigma.
TREND_SIGMA = 5.0
_MIN_PERIOD_S = 120.0


def row_variables(observations, fit, predictor):
    """Per-row values of every scanned variable (N,) each."""
    centroids = observations.centroids
    times = predictor.row_times_s(fit.effects)
    attitudes = predictor.attitudes(fit.effects, times)
    move_start = observations.move_start_s
    slew_deg = np.zeros(len(times))
    if len(move_start):
        index = np.searchsorted(move_start, times, side='right') - 1
        moved = index >= 0
        before = predictor.attitudes(fit.effects, np.maximum(move_start[np.maximum(index, 0)], times.min()))
        relative = np.einsum('nij,nkj->nik', attitudes, before)
        angle = np.degrees(np.linalg.norm(Rotation.from_matrix(relative).as_rotvec(), axis=1))
        slew_deg = np.where(moved, angle, 0.0)
    return {'elevation_deg': centroids.elevation_deg, 'time_s': centroids.stamp_s, 'slew_angle_deg': slew_deg,
            'los_angle_deg': centroids.fd_los_deg, 'temperature_c': centroids.temperature_c}


def _trend(values, residual):
    """Least-squares slope of residual on values with its sigma."""
    spread = values - values.mean()
    denominator = float(spread @ spread)
    if len(values) < 10 or denominator <= 0.0:
        return 0.0, np.inf
    slope = float(spread @ (residual - residual.mean())) / denominator
    scatter = residual - residual.mean() - slope * spread
    return slope, float(np.sqrt(scatter @ scatter / (len(values) - 2) / denominator))


def _strongest_period(times_s, residual):
    """Period, amplitude and normalized power of the strongest sinusoid in frame-averaged residuals."""
    span = times_s.max() - times_s.min()
    if span < 4 * _MIN_PERIOD_S or len(times_s) < 20:
        return None
    periods = np.geomspace(_MIN_PERIOD_S, span / 2.0, 400)
    centred = residual - residual.mean()
    power = lombscargle(times_s, centred, 2.0 * np.pi / periods, normalize=True)
    best = int(np.argmax(power))
    omega = 2.0 * np.pi / periods[best]
    design = np.column_stack([np.sin(omega * times_s), np.cos(omega * times_s)])
    coefficients, *_ = np.linalg.lstsq(design, centred, rcond=None)
    return float(periods[best]), float(np.hypot(*coefficients)), float(power[best])


def signature_scan(observations, fit, predictor):
    """Trends beyond TREND_SIGMA and the strongest period per camera axis, strongest first."""
    centroids = observations.centroids
    variables = row_variables(observations, fit, predictor)
    keep = ~fit.outlier
    trends, periods = [], []
    for index, camera in enumerate(centroids.cameras):
        rows = keep & (centroids.camera_index == index)
        if np.count_nonzero(rows) < 10:
            continue
        for axis_index, axis in enumerate(('x', 'y')):
            residual = fit.residual_arcsec[rows, axis_index]
            for key, values in variables.items():
                slope, sigma = _trend(values[rows], residual)
                if np.isfinite(sigma) and abs(slope) > TREND_SIGMA * sigma:
                    change = slope * float(np.ptp(values[rows]))
                    trends.append({'observable': f'{camera}.{axis}', 'variable': key, 'slope_arcsec_per_unit': slope,
                                   'sigma': sigma, 'change_over_range_arcsec': change,
                                   'significance_sigma': abs(slope) / sigma})
            frames, inverse = np.unique(centroids.frame_index[rows], return_inverse=True)
            frame_times = np.bincount(inverse, centroids.stamp_s[rows]) / np.bincount(inverse)
            frame_residual = np.bincount(inverse, residual) / np.bincount(inverse)
            found = _strongest_period(frame_times, frame_residual) if len(frames) else None
            if found is not None:
                period_s, amplitude, power = found
                periods.append({'observable': f'{camera}.{axis}', 'period_s': period_s,
                                'amplitude_arcsec': amplitude, 'power': power})
    trends.sort(key=lambda trend: -abs(trend['change_over_range_arcsec']))
    periods.sort(key=lambda period: -period['amplitude_arcsec'] * period['power'])
    return {'trends': trends, 'periods': periods}
