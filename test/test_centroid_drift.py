"""The residual centroid drift fit of 6.3: column linear, row linear plus a sinusoid where the BIC keeps it.

Synthetic FPI series at the imager's 2 s frame period with 0.55 px of centroid noise (0.3" seeing at
0.55"/px); the sinusoid is the thesis' (5.2 min, 2.2 px) on a 1.4 px/min line.
"""

import numpy as np
import pytest

from sofia_ros.analysis.centroid_drift import MIN_SINUSOID_FRAMES, fit_centroid_drift, line_and_sinusoid_px
from sofia_ros.analysis.ranking import SIGNIFICANT_DELTA_BIC
from sofia_ros.errors import InvalidArgumentError

FRAME_S = 2.0
NOISE_PX = 0.55


def _hold(seconds, seed):
    times = 1000.0 + np.arange(0.0, seconds, FRAME_S)
    return times, np.random.default_rng(seed).normal(0.0, NOISE_PX, (2, len(times)))


@pytest.mark.parametrize('seed', [1, 2, 3])
def test_line_plus_sinusoid_is_recovered_within_three_sigma(seed):
    times, noise = _hold(330.0, seed)
    reference_s = (times[0] + times[-1]) / 2.0
    slope_px_per_s, amplitude_px, period_s, phase_rad = 1.4 / 60.0, 2.2, 5.2 * 60.0, 0.7
    row = line_and_sinusoid_px(times - reference_s, 540.0, slope_px_per_s, amplitude_px, period_s, phase_rad)
    column = 515.0 - 2.5 / 60.0 * (times - reference_s)
    fit = fit_centroid_drift(times, column + noise[0], row + noise[1])
    assert fit['reference_time_s'] == pytest.approx(reference_s)
    assert abs(fit['column']['drift_px_per_min'] + 2.5) <= 3.0 * fit['column']['drift_sigma']
    row_fit, sine = fit['row'], fit['row']['sinusoid']
    assert sine is not None and row_fit['sinusoid_delta_bic'] >= SIGNIFICANT_DELTA_BIC
    assert abs(row_fit['drift_px_per_min'] - 1.4) <= 3.0 * row_fit['drift_sigma']
    assert abs(sine['period_s'] - period_s) <= 3.0 * sine['period_sigma']
    assert abs(sine['amplitude_px'] - amplitude_px) <= 3.0 * sine['amplitude_sigma']
    assert abs(sine['phase_deg'] - np.rad2deg(phase_rad)) <= 3.0 * sine['phase_sigma']
    assert row_fit['rms_px'] == pytest.approx(NOISE_PX, rel=0.2)


@pytest.mark.parametrize('seconds', [60.0, 330.0])
def test_a_pure_line_keeps_no_sinusoid(seconds):
    times, noise = _hold(seconds, 4)
    line = 512.0 + 0.3 * (times - times[0])
    fit = fit_centroid_drift(times, line + noise[0], line + noise[1])
    assert fit['row']['sinusoid'] is None and fit['row']['sinusoid_delta_bic'] < SIGNIFICANT_DELTA_BIC
    for axis in ('column', 'row'):
        assert abs(fit[axis]['drift_px_per_min'] - 18.0) <= 3.0 * fit[axis]['drift_sigma']


def test_a_short_series_gets_the_line_only():
    times, noise = _hold(FRAME_S * (MIN_SINUSOID_FRAMES - 1), 5)
    fit = fit_centroid_drift(times, noise[0], noise[1])
    assert fit['frames'] == MIN_SINUSOID_FRAMES - 1
    assert fit['row']['sinusoid'] is None and fit['row']['sinusoid_delta_bic'] is None


def test_bad_series_are_refused():
    with pytest.raises(InvalidArgumentError, match='at least 3 frames'):
        fit_centroid_drift([0.0, 2.0], [1.0, 2.0], [1.0, 2.0])
    with pytest.raises(InvalidArgumentError, match='must increase'):
        fit_centroid_drift([0.0, 2.0, 2.0], [1.0, 2.0, 3.0], [1.0, 2.0, 3.0])
    with pytest.raises(InvalidArgumentError, match='row_px must have shape 3'):
        fit_centroid_drift([0.0, 2.0, 4.0], [1.0, 2.0, 3.0], [1.0, 2.0])
