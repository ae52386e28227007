"""Rate PSD by Welch with the settings of 5.2.5, spectrogram (5.2.2), PSD slopes of Table 4.1, 4.14/4.15."""

import numpy as np
import pytest
from scipy import stats

from sofia_ros.analysis.allan import psd_corrected_for_sampling
from sofia_ros.analysis.lines import find_lines, likely_source, line_threshold, silent_sources
from sofia_ros.analysis.spectra import (
    log_chi_square_bias_and_sigma,
    rate_spectrogram,
    welch_equivalent_dof,
    welch_rate_psd,
    welch_segment_samples,
    welch_sinusoid_psd,
)
from sofia_ros.errors import InvalidArgumentError
from sofia_ros.noise.fit import arw_deg_per_sqrt_h_from_white_psd, loglog_slope, noise_psd
from sofia_ros.sensors.gyro_noise import QUANTIZATION_ARCSEC, SPECIFICATION, NoiseCoefficients, gyro_rate_arcsec_per_s

SAMPLE_RATE_HZ = 400.0  # 2.4.1
ARW_ONLY = NoiseCoefficients(arw_deg_per_sqrt_h=0.0003)  # specification N, Table 5.1
N = 0.018  # arcsec/sqrt(s), Table 5.8 specification


def _mean_psd(coefficients, sample_rate_hz, n_samples, seed):
    rate = gyro_rate_arcsec_per_s(coefficients, n_samples, sample_rate_hz, rng=seed)
    freq_hz, psd = welch_rate_psd(rate, sample_rate_hz)
    return freq_hz, psd.mean(axis=1)


def test_welch_settings_of_5_2_5():
    freq_hz, psd = welch_rate_psd(np.zeros((2**15, 3)))
    assert freq_hz.size == 2**15 + 1  # nfft 2^16, one-sided
    assert freq_hz[-1] == pytest.approx(200.0)  # Nyquist
    assert freq_hz[1] == pytest.approx(400.0 / 2**16)
    assert psd.shape == (2**15 + 1, 3)


def test_white_rate_noise_psd_is_2_n_squared_and_4_15_gives_the_specification():
    freq_hz, psd = _mean_psd(ARW_ONLY, SAMPLE_RATE_HZ, 2**20, seed=1)
    band = (freq_hz > 1.0) & (freq_hz < 190.0)
    level = psd[band].mean()
    assert level == pytest.approx(2.0 * N**2, rel=0.02)  # eq. 4.14: 6.48e-4 (arcsec/s)^2/Hz
    # (arcsec/s)^2/Hz is numerically (deg/h)^2/Hz; 4.15 turns it into 0.0003 deg/sqrt(h), Table 5.1.
    assert arw_deg_per_sqrt_h_from_white_psd(level) == pytest.approx(0.0003, rel=0.01)


def test_quantized_gyro_psd_follows_4_11_plus_4_14_up_to_the_nyquist_frequency():
    freq_hz, psd = _mean_psd(SPECIFICATION, SAMPLE_RATE_HZ, 2**20, seed=2)
    model = noise_psd(freq_hz[1:], quantization_arcsec=QUANTIZATION_ARCSEC, arw_arcsec_per_sqrt_s=N)
    for low_hz, high_hz in [(1.0, 50.0), (50.0, 100.0), (100.0, 150.0), (150.0, 199.0)]:
        band = (freq_hz[1:] > low_hz) & (freq_hz[1:] < high_hz)
        assert psd[1:][band].mean() == pytest.approx(model[band].mean(), rel=0.02)
    # At 200 Hz quantization adds 2 SF^2 / (3 t_s) = 1.6e-4, a quarter of the white level.
    assert model[-1] / (2.0 * N**2) == pytest.approx(1.24, abs=0.01)


@pytest.mark.parametrize('coefficients, sample_rate_hz, n_samples, band_hz, slope', [
    (ARW_ONLY, 400.0, 2**19, (0.5, 150.0), 0.0),
    (NoiseCoefficients(bias_instability_deg_per_h=0.002), 40.0, 2**21, (0.01, 2.0), -1.0),
    (NoiseCoefficients(rrw_deg_per_h_sqrt_h=0.01), 10.0, 2**20, (0.005, 1.0), -2.0),
])
def test_single_process_psd_slopes_of_table_4_1(coefficients, sample_rate_hz, n_samples, band_hz, slope):
    freq_hz, psd = _mean_psd(coefficients, sample_rate_hz, n_samples, seed=3)
    band = (freq_hz >= band_hz[0]) & (freq_hz <= band_hz[1])
    assert loglog_slope(freq_hz[band], psd[band]) == pytest.approx(slope, abs=0.05)


def test_quantization_psd_slope_2_from_the_rounding_error_alone():
    with_sf = NoiseCoefficients(quantization_arcsec=QUANTIZATION_ARCSEC, arw_deg_per_sqrt_h=0.0003)
    error = (gyro_rate_arcsec_per_s(with_sf, 2**19, rng=4, true_rate_arcsec_per_s=10.0)
             - gyro_rate_arcsec_per_s(ARW_ONLY, 2**19, rng=4, true_rate_arcsec_per_s=10.0))
    freq_hz, psd = welch_rate_psd(error)
    band = (freq_hz >= 0.5) & (freq_hz <= 20.0)  # f << fs / 2, where sin^2 of 4.11 is f^2
    assert loglog_slope(freq_hz[band], psd[band].mean(axis=1)) == pytest.approx(2.0, abs=0.05)


def test_a_deterministic_ramp_has_no_minus_3_psd_slope_in_data():
    # Table 4.1's -3 belongs to the formal PSD 4.21; a ramp is not stationary, and the Welch estimate of
    # R t depends on the window (here about -2.5), so the -3 is checked on 4.21 only (test_noise_model).
    freq_hz, psd = _mean_psd(NoiseCoefficients(rate_ramp_deg_per_h2=0.01), SAMPLE_RATE_HZ, 2**20, seed=5)
    band = (freq_hz >= 0.02) & (freq_hz <= 5.0)
    assert abs(loglog_slope(freq_hz[band], psd[band]) + 3.0) > 0.3


def test_psd_of_every_40th_sample_is_corrected_by_4_29():
    rate = gyro_rate_arcsec_per_s(ARW_ONLY, 2**21, SAMPLE_RATE_HZ, n_axes=1, rng=6)[::40]
    freq_hz, psd = welch_rate_psd(rate, SAMPLE_RATE_HZ / 40.0, segment_samples=2**12, fft_points=2**14)
    level = psd[freq_hz > 0.1].mean()
    assert level == pytest.approx(40.0 * 2.0 * N**2, rel=0.03)  # aliased white noise, 40x too high
    assert psd_corrected_for_sampling(level, SAMPLE_RATE_HZ / 40.0) == pytest.approx(2.0 * N**2, rel=0.03)


def test_a_disturbance_line_shows_at_its_frequency_with_its_power():
    # Main oil pump line at 30.0 Hz (Table 5.5) on the specified white noise.
    amplitude_arcsec_per_s, line_hz = 0.05, 30.0
    time_s = np.arange(2**19) / SAMPLE_RATE_HZ
    rate = gyro_rate_arcsec_per_s(ARW_ONLY, time_s.size, n_axes=1, rng=7)[:, 0]
    rate += amplitude_arcsec_per_s * np.sin(2.0 * np.pi * line_hz * time_s)
    freq_hz, psd = welch_rate_psd(rate)
    assert freq_hz[np.argmax(psd)] == pytest.approx(line_hz, abs=freq_hz[1])
    near = np.abs(freq_hz - line_hz) < 0.2
    line_power = np.sum(psd[near] - 2.0 * N**2) * freq_hz[1]
    assert line_power == pytest.approx(amplitude_arcsec_per_s**2 / 2.0, rel=0.05)


def test_spectrogram_shows_a_line_switched_off_halfway():
    # Fig. 5.5: cooling carts shut down; their 45.1 Hz EL line (Table 5.4) disappears.
    time_s = np.arange(2**18) / SAMPLE_RATE_HZ
    rate = gyro_rate_arcsec_per_s(ARW_ONLY, time_s.size, n_axes=1, rng=8)[:, 0]
    rate += np.where(time_s < time_s[-1] / 2.0, 0.2 * np.sin(2.0 * np.pi * 45.1 * time_s), 0.0)
    freq_hz, segment_s, power = rate_spectrogram(rate)
    line = np.argmin(np.abs(freq_hz - 45.1))
    before, after = power[line, segment_s < 250.0], power[line, segment_s > 410.0]
    # A 0.2 arcsec/s line is ~150x the white level in a 0.1 Hz bin; noise alone stays below ~5x.
    assert before.min() > 20.0 * 2.0 * N**2
    assert after.max() < 10.0 * 2.0 * N**2


@pytest.mark.parametrize('call, match', [
    (lambda: welch_rate_psd(np.ones(1000)), 'rate has 1000 samples, fewer than segment_samples'),
    (lambda: welch_rate_psd(np.full(2**14, np.nan)), 'rate contains NaN'),
    (lambda: welch_rate_psd(np.ones((2**14, 2, 2))), 'rate must have shape'),
    (lambda: welch_rate_psd(np.ones(2**14), sample_rate_hz=0.0), 'sample_rate_hz must be > 0'),
    (lambda: welch_rate_psd(np.ones(2**14), fft_points=2**10), 'fft_points .* must be >= segment_samples'),
    (lambda: rate_spectrogram(np.ones(2**14), overlap=1.0), 'overlap must be in'),
])
def test_bad_input_raises_invalid_argument_naming_it(call, match):
    with pytest.raises(InvalidArgumentError, match=match):
        call()


@pytest.mark.parametrize('line_hz', [30.0123, 230.0, 0.7])
def test_expected_welch_estimate_of_a_line_is_scipys_welch_of_it(line_hz):
    # Main oil pump 30 Hz (Table 5.5), a 230 Hz line that lands on 170 Hz, and the 0.7 Hz line of
    # 5.2.5: the window transform in closed form against scipy's Welch.
    time_s = np.arange(2**18) / SAMPLE_RATE_HZ
    freq_hz, psd = welch_rate_psd(0.15 * np.sin(2.0 * np.pi * line_hz * time_s + 0.3))
    expected = welch_sinusoid_psd(freq_hz, 0.15, line_hz)
    near = np.abs(freq_hz - freq_hz[np.argmax(psd)]) < 0.2
    np.testing.assert_allclose(psd[near], expected[near], rtol=0, atol=1e-4 * psd.max())
    assert np.sum(expected) * freq_hz[1] == pytest.approx(0.15**2 / 2.0, rel=1e-3)  # A^2 / 2 (4.5)


def test_welch_dof_sets_the_scatter_and_the_bias_of_the_log_psd():
    # White noise at the specified ARW, 3 minutes at 400 Hz (the short records of the tests), 20 records.
    segment = welch_segment_samples(72_000)
    dof = welch_equivalent_dof(72_000, segment)
    assert (segment, round(dof, 1)) == (2**14, 12.8)
    bias, sigma = log_chi_square_bias_and_sigma(dof)
    logs = []
    for seed in range(20):
        rate = gyro_rate_arcsec_per_s(ARW_ONLY, 72_000, SAMPLE_RATE_HZ, n_axes=1, rng=100 + seed)[:, 0]
        freq_hz, psd = welch_rate_psd(rate, segment_samples=segment, fft_points=4 * segment)
        logs.append(np.log(psd[(freq_hz > 1.0) & (freq_hz < 190.0)][::4] / (2.0 * N**2)))
    logs = np.concatenate(logs)
    assert np.mean(logs) == pytest.approx(bias, abs=0.01)  # -0.08 in ln: a 7 % low mean
    assert np.std(logs) == pytest.approx(sigma, rel=0.05)
    # The chi-square formulas themselves, against scipy's distribution.
    draws = stats.chi2(dof).rvs(200_000, random_state=1) / dof
    assert np.mean(np.log(draws)) == pytest.approx(bias, abs=0.002)
    assert np.std(np.log(draws)) == pytest.approx(sigma, rel=0.01)


def test_lines_above_the_chi_square_threshold_are_found_and_noise_is_not():
    # Noise alone: no line in 20 three-minute records at 1 % false alarms per record.
    segment = welch_segment_samples(72_000)
    dof = welch_equivalent_dof(72_000, segment)
    found = 0
    for seed in range(20):
        rate = gyro_rate_arcsec_per_s(ARW_ONLY, 72_000, SAMPLE_RATE_HZ, n_axes=1, rng=200 + seed)[:, 0]
        found += len(find_lines(*welch_rate_psd(rate, segment_samples=segment, fft_points=4 * segment),
                                dof=dof))
    assert found == 0
    # A 0.02"/s line of the 3.3 Hz TC-1 series (5.2.5) stands ~5x over the median there; at 20x it would be lost.
    time_s = np.arange(72_000) / SAMPLE_RATE_HZ
    rate = gyro_rate_arcsec_per_s(ARW_ONLY, 72_000, SAMPLE_RATE_HZ, n_axes=1, rng=7)[:, 0]
    rate += 0.02 * np.sin(2.0 * np.pi * 49.6 * time_s)
    lines = find_lines(*welch_rate_psd(rate, segment_samples=segment, fft_points=4 * segment), dof=dof)
    assert [round(line.freq_hz, 1) for line in lines] == [49.6]
    assert line_threshold(dof, 32_768) < 5.0


def test_known_sources_are_matched_where_decimation_folds_them():
    # Main oil pump 30 Hz and 190.2 Hz (Table 5.5) in every 10th sample (40 Hz): at 10.0 and 9.8 Hz.
    assert likely_source(30.0) == 'main oil pump'
    assert likely_source(10.0, 40.0) == 'main oil pump'
    assert likely_source(9.8, 40.0) == 'main oil pump'
    assert likely_source(10.0) == 'unknown'


def test_short_records_get_four_power_of_two_segments():
    assert welch_segment_samples(5_760_000) == 2**14  # 4 h, the 5.2.5 setting
    assert welch_segment_samples(7_200) == 2**10  # 3 min every 10th sample
    with pytest.raises(InvalidArgumentError, match='a rate PSD needs at least 1024 samples, got 1000'):
        welch_segment_samples(1000)


def test_sources_whose_subsystem_is_off_are_not_named():
    # TC-1 (Table 5.2: RIS shut down, so no oil pumps): a line at 29.8 Hz is not the main oil pump's.
    from sofia_ros.campaigns.gyro_stability import CASES

    tc1, tc4 = silent_sources(dict(CASES['TC-1'].subsystems)), silent_sources(dict(CASES['TC-4'].subsystems))
    assert likely_source(29.8) == 'main oil pump' and likely_source(29.8, silent=tc1) == 'unknown'
    assert {'main oil pump', 'return pump 1', 'cooling carts', 'FD open loop (TC-4)'} <= tc1
    assert likely_source(3.4, silent=tc4) == 'FD open loop (TC-4)' and likely_source(30.0, silent=tc4) == 'main oil pump'
    assert silent_sources(None) == frozenset()
