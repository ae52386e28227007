"""Overlapping Allan deviation (4.6-4.8), its accuracy (4.25, 4.26), sampling-rate correction (4.27-4.29)."""

import allantools
import numpy as np
import pytest

from sofia_ros.analysis.allan import (
    LARGEST_TAU_FRACTION,
    adev_corrected_for_sampling,
    allan_relative_error,
    arw_corrected_for_sampling,
    log_spaced_cluster_sizes,
    octave_cluster_sizes,
    overlapping_allan_deviation,
    psd_corrected_for_sampling,
    required_test_time_s,
)
from sofia_ros.errors import InvalidArgumentError
from sofia_ros.noise.fit import arw_from_slope_fit
from sofia_ros.sensors.gyro_noise import GYRO_001_1999, NoiseCoefficients, gyro_rate_arcsec_per_s

SAMPLE_RATE_HZ = 400.0  # FOG180 read-out rate (2.4.1)
# Table 5.7, average of all test cases (deg/h, numerically arcsec/s): the Earth rate the gyros see.
EARTH_RATE_ARCSEC_PER_S = [10.4747, -10.5610, 0.2581]


def _table_record(n_samples, seed):
    return gyro_rate_arcsec_per_s(GYRO_001_1999, n_samples, SAMPLE_RATE_HZ, rng=seed,
                                  true_rate_arcsec_per_s=EARTH_RATE_ARCSEC_PER_S)


def _drifting_record(n_samples, seed):
    """Table 5.1 noise under a strong rate ramp and random walk: the case where expansions cancel."""
    rng = np.random.default_rng(seed)
    ramp = 1e-4 * np.arange(n_samples)[:, np.newaxis]
    walk = np.cumsum(rng.standard_normal((n_samples, 3)), axis=0) * 1e-3
    return _table_record(n_samples, seed) + ramp + walk


def _direct_adev(rate, sizes):
    """4.6-4.7 with overlapping clusters, one O(n) pass per cluster size: the reference."""
    phase = np.concatenate([[0.0], np.cumsum(rate - rate.mean())]) / SAMPLE_RATE_HZ
    values = []
    for m in sizes:
        second = phase[2 * m:] - 2.0 * phase[m:-m] + phase[:-2 * m]
        values.append(np.sqrt(np.sum(second**2) / (2.0 * (m / SAMPLE_RATE_HZ) ** 2 * second.size)))
    return np.array(values)


@pytest.mark.parametrize('make_record', [_table_record, _drifting_record])
def test_matches_allantools_oadev_to_1e_9_on_dense_and_octave_grids(make_record):
    rate = make_record(2**17, seed=1)
    for sizes in (log_spaced_cluster_sizes(rate.shape[0], 100), octave_cluster_sizes(rate.shape[0])):
        curves = overlapping_allan_deviation(rate, SAMPLE_RATE_HZ, sizes)
        for axis, curve in enumerate(curves):
            # allantools integrates 'freq' data as phase = [0, cumsum(y - mean) / rate]: the same estimator.
            taus, adev, _, _ = allantools.oadev(rate[:, axis], rate=SAMPLE_RATE_HZ, data_type='freq',
                                                taus=sizes / SAMPLE_RATE_HZ)
            np.testing.assert_allclose(curve.tau_s, taus, rtol=1e-15)
            np.testing.assert_allclose(curve.adev, adev, rtol=1e-9, atol=0.0)


def test_fast_path_alone_is_exact_on_table_5_1_data_and_fallback_covers_drift():
    n_samples = 2**20
    sizes = log_spaced_cluster_sizes(n_samples, 100)
    table = _table_record(n_samples, seed=2)[:, 0]
    drifting = _drifting_record(n_samples, seed=2)[:, 0]
    # rtol=1 disables the direct sums: lagged products alone, against one pass per tau.
    fast = overlapping_allan_deviation(table, SAMPLE_RATE_HZ, sizes, rtol=1.0)
    np.testing.assert_allclose(fast.adev, _direct_adev(table, sizes), rtol=1e-9, atol=0.0)
    checked = overlapping_allan_deviation(drifting, SAMPLE_RATE_HZ, sizes)
    np.testing.assert_allclose(checked.adev, _direct_adev(drifting, sizes), rtol=1e-9, atol=0.0)


def test_columns_are_analysed_independently():
    rate = _table_record(20_000, seed=3)
    curves = overlapping_allan_deviation(rate, SAMPLE_RATE_HZ)
    single = overlapping_allan_deviation(rate[:, 1].copy(), SAMPLE_RATE_HZ)
    np.testing.assert_allclose(curves[1].adev, single.adev, rtol=1e-13)  # strided vs contiguous summation
    assert len(curves) == 3


def test_white_rate_noise_follows_4_16_within_the_4_25_error():
    arw_arcsec_per_sqrt_s = 0.018  # specification, Table 5.8
    rate = gyro_rate_arcsec_per_s(NoiseCoefficients(arw_deg_per_sqrt_h=0.0003), 2**20, SAMPLE_RATE_HZ,
                                  n_axes=1, rng=4)[:, 0]
    curve = overlapping_allan_deviation(rate, SAMPLE_RATE_HZ, octave_cluster_sizes(rate.size))
    expected = arw_arcsec_per_sqrt_s / np.sqrt(curve.tau_s)
    assert np.all(np.abs(curve.adev / expected - 1.0) < 3.0 * curve.sigma_rel)


def test_accuracy_4_25_and_test_time_4_26_reproduce_the_numbers_of_4_2_4_and_5_2_6():
    # 4.2.4: more than 200 clusters give an error below 5 %.
    assert allan_relative_error(201) == pytest.approx(0.05)
    assert allan_relative_error(202) < 0.05
    # 5.2.6: the largest tau, a third of the test time, has K = 3 clusters and a 50 % error.
    assert allan_relative_error(3) == pytest.approx(0.5)
    # 4.26 inverts 4.25 with K = T / tau.
    tau_s, error = 700.0, 0.1
    test_time_s = required_test_time_s(tau_s, error)
    assert allan_relative_error(test_time_s / tau_s) == pytest.approx(error)
    # 4.2.4 / Fig. 4.5: a 24 h test observes tau = 6000 s (RRW, "over 3000 s") to about 20 %.
    assert allan_relative_error(24 * 3600.0 / 6000.0) == pytest.approx(0.19, abs=0.01)


def test_cluster_size_grids():
    n_samples = 5_760_000  # 4 h at 400 Hz (5.2.1)
    dense = log_spaced_cluster_sizes(n_samples, 100)
    assert dense.size == 100 and dense[0] == 1 and dense[-1] == int(n_samples * LARGEST_TAU_FRACTION)
    assert np.all(np.diff(dense) > 0)
    ratios = np.diff(np.log(dense[dense > 100]))
    assert ratios.max() / ratios.min() < 1.05  # log-uniform where integers allow
    octave = octave_cluster_sizes(n_samples)  # 4.8
    np.testing.assert_array_equal(octave, 2 ** np.arange(21))


def test_arw_of_every_40th_sample_is_corrected_back_by_4_27_to_4_29():
    arw_arcsec_per_sqrt_s = 0.018
    rate = gyro_rate_arcsec_per_s(NoiseCoefficients(arw_deg_per_sqrt_h=0.0003), 2**21, SAMPLE_RATE_HZ,
                                  n_axes=1, rng=5)[:, 0]
    sampled_hz = SAMPLE_RATE_HZ / 40.0
    picked = rate[::40]  # housekeeping data: every 40th read-out, neither filtered nor averaged (4.2.5)
    curve = overlapping_allan_deviation(picked, sampled_hz, octave_cluster_sizes(picked.size))
    sampled = arw_from_slope_fit(curve, 0.1, 1000.0)
    # Uncorrected, the ARW is sqrt(400/10) = 6.3 times too high.
    assert sampled.arw_arcsec_per_sqrt_s == pytest.approx(arw_arcsec_per_sqrt_s * np.sqrt(40.0), rel=0.03)
    corrected = arw_corrected_for_sampling(sampled.arw_arcsec_per_sqrt_s, sampled_hz)
    sigma = arw_corrected_for_sampling(sampled.sigma_arcsec_per_sqrt_s, sampled_hz)
    assert abs(corrected - arw_arcsec_per_sqrt_s) < 3.0 * sigma
    # 4.28 on the AV point at 0.8 s (K = 6553, 1 % error) and 4.29 on the white PSD level 2 N^2.
    point = np.argmin(np.abs(curve.tau_s - 0.8))
    assert adev_corrected_for_sampling(curve.adev[point], sampled_hz) == pytest.approx(
        arw_arcsec_per_sqrt_s / np.sqrt(curve.tau_s[point]), rel=0.03)
    sampled_psd = 2.0 * np.var(picked) / sampled_hz
    assert psd_corrected_for_sampling(sampled_psd, sampled_hz) == pytest.approx(2.0 * arw_arcsec_per_sqrt_s**2,
                                                                                 rel=0.03)


@pytest.mark.parametrize('call, match', [
    (lambda: overlapping_allan_deviation([1.0, np.nan, 2.0, 3.0], 400.0), 'rate contains NaN'),
    (lambda: overlapping_allan_deviation(np.ones((4, 2, 2)), 400.0), 'rate must have shape'),
    (lambda: overlapping_allan_deviation(np.ones(10), 0.0), 'sample_rate_hz must be > 0'),
    (lambda: overlapping_allan_deviation(np.ones(10), 400.0, [6]), 'cluster_sizes up to 6 need at least 12'),
    (lambda: overlapping_allan_deviation(np.ones(10), 400.0, [0, 2]), 'cluster_sizes must be positive integers'),
    (lambda: overlapping_allan_deviation(np.ones(10), 400.0, [1.5]), 'cluster_sizes must be positive integers'),
    (lambda: overlapping_allan_deviation(np.ones(10), 400.0, rtol=-1.0), 'rtol must be > 0'),
    (lambda: required_test_time_s(0.0, 0.1), 'tau_s must be > 0'),
    (lambda: required_test_time_s(10.0, -0.1), 'relative_error must be > 0'),
    (lambda: allan_relative_error(1), 'n_clusters must be >= 2'),
    (lambda: arw_corrected_for_sampling(0.1, 800.0), 'sampled_rate_hz .* must not exceed'),
    (lambda: log_spaced_cluster_sizes(30, 100), 'n_taus \\(100\\) exceeds'),
    (lambda: octave_cluster_sizes(10, 0.9), 'max_fraction must be <= 0.5'),
])
def test_bad_input_raises_invalid_argument_naming_it(call, match):
    with pytest.raises(InvalidArgumentError, match=match):
        call()
