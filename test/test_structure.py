"""Structure tests (analysis.structure): false-alarm rates on white noise, and known shapes found.

The false-alarm probabilities must mean what they say, or a compare verdict would cry wolf on
untouched data (or miss real structure): on white noise with the gaps of a campaign, the
fraction of trials below a probability p must be about p. Expected rates are binomial: the
tolerances are 4 standard deviations of the trial count.
"""

import numpy as np
import pytest
from scipy import stats

from sofia_ros.analysis.structure import category_test, field_test, period_test, sigma_of_probability, trend_test
from sofia_ros.errors import InvalidArgumentError
from sofia_ros.sensors.gyro_noise import angle_increment_covariance_rad2

#: A campaign-like time axis: 1 s frames with a 300 s gap (a slew without stars).
TIMES_S = np.concatenate([np.arange(0.0, 600.0, 1.0), np.arange(900.0, 1800.0, 1.0)])
TRIALS = 300


def _rate_tolerance(p):
    return 4.0 * np.sqrt(p * (1.0 - p) / TRIALS)


@pytest.mark.parametrize('times_s', [TIMES_S, np.arange(0.0, 1800.0, 2.0),
                                     np.sort(np.random.default_rng(7).uniform(0.0, 1800.0, 400))],
                         ids=['gapped', 'regular', 'irregular'])
def test_period_false_alarm_probability_is_calibrated_on_white_noise(times_s):
    rng = np.random.default_rng(11)
    probabilities = np.array([period_test(times_s, rng.normal(0.0, 0.3, len(times_s))).false_alarm_probability
                              for _ in range(TRIALS)])
    for p in (0.05, 0.2):
        assert abs(np.mean(probabilities < p) - p) <= _rate_tolerance(p), (p, np.mean(probabilities < p))


def test_trend_and_category_p_values_are_uniform_on_white_noise():
    rng = np.random.default_rng(12)
    trend = [trend_test(TIMES_S, rng.normal(0.0, 0.3, len(TIMES_S))).p_value for _ in range(TRIALS)]
    stars = rng.integers(0, 12, len(TIMES_S))
    category = [category_test(stars, rng.normal(0.0, 0.3, len(TIMES_S))).p_value for _ in range(TRIALS)]
    x_px, y_px = rng.uniform(0.0, 1024.0, (2, len(TIMES_S)))
    field = [field_test(x_px, y_px, rng.normal(0.0, 0.3, len(TIMES_S))).p_value for _ in range(TRIALS)]
    for values in (trend, category, field):
        # Kolmogorov-Smirnov against the uniform distribution (p-values of a calibrated test).
        assert stats.kstest(values, 'uniform').pvalue > 1e-3


@pytest.mark.parametrize('period_s', [22.0, 95.0, 400.0])
def test_a_weak_sinusoid_is_found_at_its_period_within_three_sigma(period_s):
    rng = np.random.default_rng(13)
    values = rng.normal(0.0, 0.3, len(TIMES_S)) + 0.08 * np.sin(2.0 * np.pi * TIMES_S / period_s + 0.4)
    found = period_test(TIMES_S, values)
    # Frequency precision of a sinusoid fit: sigma_f = sqrt(12) sigma_phase / (2 pi T), sigma_phase = noise / (A sqrt(N/2)).
    span_s = TIMES_S[-1] - TIMES_S[0]
    sigma_relative = period_s * np.sqrt(12.0) * 0.3 / (0.08 * np.sqrt(len(TIMES_S) / 2.0)) / (2.0 * np.pi * span_s)
    assert abs(found.period / period_s - 1.0) <= 3.0 * sigma_relative, (found.period, sigma_relative)
    assert abs(found.amplitude - 0.08) <= 0.03
    assert sigma_of_probability(found.false_alarm_probability) >= 5.0


def test_a_smooth_trend_is_found_and_its_shape_measured():
    rng = np.random.default_rng(14)
    elevation_deg = rng.choice([23.0, 31.7, 40.0, 50.0, 59.0], len(TIMES_S))
    shape = 0.5 * np.cos(np.radians(elevation_deg)) ** 4
    found = trend_test(elevation_deg, rng.normal(0.0, 0.3, len(TIMES_S)) + shape)
    assert sigma_of_probability(found.p_value) >= 5.0
    # Half the range of the true shape over 23-59 deg: 0.5 (cos^4 23 - cos^4 59) / 2.
    assert abs(found.amplitude - 0.25 * (np.cos(np.radians(23.0)) ** 4 - np.cos(np.radians(59.0)) ** 4)) <= 0.03


def test_a_saddle_over_the_detector_is_a_field_that_neither_axis_alone_shows():
    rng = np.random.default_rng(15)
    # Stars over a 1024 px chip, symmetric about its centre: x y averages away along x and along y.
    x_px, y_px = rng.uniform(0.0, 1024.0, (2, 4000))
    saddle = 0.5 * (x_px - 512.0) * (y_px - 512.0) / 512.0**2
    values = rng.normal(0.0, 0.3, len(x_px)) + saddle
    assert sigma_of_probability(trend_test(x_px, values).p_value) < 3.0
    assert sigma_of_probability(trend_test(y_px, values).p_value) < 3.0
    found = field_test(x_px, y_px, values)
    assert sigma_of_probability(found.p_value) >= 5.0
    # Half the range of the saddle over the rows: 0.5" at the corners, +-.
    assert found.amplitude == pytest.approx(0.5 * np.ptp(saddle), abs=0.05)


def _wandering_increments(rng, knots_s, count, rrw=0.05):
    """``count`` series of anchor increments under unit ARW and an RRW that dominates from minutes on (the
    star hop's at 0.005: Table 5.1's N and K cross near 7 min), and their whitening."""
    covariance = angle_increment_covariance_rad2(knots_s, 1.0, rrw)
    factor = np.linalg.cholesky(covariance)
    return factor @ rng.standard_normal((len(knots_s) - 1, count)), np.linalg.inv(factor)


def test_the_gls_trend_test_is_calibrated_on_a_wandering_bias_and_the_ols_one_is_not():
    """Increments whose bias wanders (RRW) hold no trend; read as white they follow time at once."""
    rng = np.random.default_rng(15)
    knots_s = np.arange(0.0, 30.0 * 101, 30.0)
    middle = (knots_s[:-1] + knots_s[1:]) / 2.0
    increments, whitening = _wandering_increments(rng, knots_s, TRIALS)
    gls = [trend_test(middle, whitening @ series, whitening=whitening).p_value for series in increments.T]
    ols = np.array([trend_test(middle, series).p_value for series in increments.T])
    assert stats.kstest(gls, 'uniform').pvalue > 1e-3
    assert np.mean(ols < 0.01) > 0.5


def test_the_gls_trend_test_finds_a_trend_of_the_increments_and_measures_it():
    """A gyro error that follows elevation, hopping between 23 and 59 deg every 90 s: faster than any wander."""
    rng = np.random.default_rng(16)
    knots_s = np.arange(0.0, 30.0 * 101, 30.0)
    increments, whitening = _wandering_increments(rng, knots_s, 1)
    elevation_deg = np.where(np.arange(len(knots_s) - 1) // 3 % 2 == 0, 23.0, 59.0)
    # +-8 about the middle, 1.5 times the ARW's 5.5 per interval: lost in the wander by eye, found by GLS.
    shape = 8.0 * (elevation_deg - 41.0) / 18.0
    found = trend_test(elevation_deg, whitening @ (increments[:, 0] + shape), whitening=whitening)
    assert sigma_of_probability(found.p_value) >= 5.0
    assert found.amplitude == pytest.approx(8.0, abs=2.5)


def test_the_gls_period_test_is_calibrated_on_a_wandering_bias_and_finds_a_fast_wobble():
    """The whitened periodogram's false-alarm probability on RRW + ARW increments, and a 150 s wobble found."""
    rng = np.random.default_rng(17)
    knots_s = np.arange(0.0, 30.0 * 201, 30.0)
    middle = (knots_s[:-1] + knots_s[1:]) / 2.0
    increments, whitening = _wandering_increments(rng, knots_s, TRIALS)
    probabilities = np.array([period_test(middle, whitening @ series, whitening=whitening).false_alarm_probability
                              for series in increments.T])
    for p in (0.05, 0.2):
        assert abs(np.mean(probabilities < p) - p) <= _rate_tolerance(p), (p, np.mean(probabilities < p))
    # Read as white, the same increments are periodic at once (the wander's red spectrum).
    assert np.mean([period_test(middle, series).false_alarm_probability < 0.01 for series in increments.T]) > 0.5
    # A 150 s wobble of the increments at 0.9 of the ARW's 5.5 per interval, under Table 5.1's proportions.
    increments, whitening = _wandering_increments(rng, knots_s, 1, rrw=0.005)
    wobble = 5.0 * np.sin(2.0 * np.pi * middle / 150.0)
    found = period_test(middle, whitening @ (increments[:, 0] + wobble), whitening=whitening)
    assert sigma_of_probability(found.false_alarm_probability) >= 5.0
    assert found.period == pytest.approx(150.0, rel=0.01)
    assert found.amplitude == pytest.approx(5.0, abs=1.5)


def test_a_whitening_of_the_wrong_shape_is_refused():
    with pytest.raises(InvalidArgumentError, match=r'whitening of shape \(3, 3\) for 20 residuals of 20'):
        trend_test(np.arange(20.0), np.zeros(20), whitening=np.eye(3))
    with pytest.raises(InvalidArgumentError, match='19 variable values for 20 residuals'):
        trend_test(np.arange(19.0), np.zeros(20))
    with pytest.raises(InvalidArgumentError, match='20 x and 19 y values for 20 residuals'):
        field_test(np.arange(20.0), np.arange(19.0), np.zeros(20))
    with pytest.raises(InvalidArgumentError, match=r'whitening of shape \(20, 3\) for 20 residuals at 20 times'):
        period_test(np.arange(20.0), np.zeros(20), whitening=np.ones((20, 3)))


def test_sigma_of_probability_is_the_two_sided_gaussian():
    assert sigma_of_probability(0.0455) == pytest.approx(2.0, abs=1e-3)
    assert sigma_of_probability(5.733e-7) == pytest.approx(5.0, abs=1e-3)
    assert sigma_of_probability(1.0) == 0.0


def test_too_little_data_is_not_tested():
    assert trend_test(np.arange(5.0), np.zeros(5)) is None
    assert trend_test(np.full(50, 3.0), np.zeros(50)) is None
    assert field_test(np.arange(15.0), np.arange(15.0), np.zeros(15)) is None
    assert field_test(np.arange(50.0), np.full(50, 3.0), np.zeros(50)) is None


def test_a_field_over_a_few_fixed_positions_counts_only_the_columns_they_leave():
    # Three stars that never move: three independent columns, not ten; the F-test must still be calibrated.
    rng = np.random.default_rng(16)
    x_px = np.repeat([100.0, 500.0, 900.0], 200)
    y_px = np.repeat([800.0, 200.0, 600.0], 200)
    p_values = [field_test(x_px, y_px, rng.normal(0.0, 0.3, len(x_px))).p_value for _ in range(TRIALS)]
    assert stats.kstest(p_values, 'uniform').pvalue > 1e-3
    assert category_test(np.zeros(50), np.ones(50)) is None
    assert period_test(np.arange(5.0), np.zeros(5)) is None
