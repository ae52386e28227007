"""Rate PSD by Welch with the settings of 5.2.5, spectrogram (5.2.2), PSD slopes of Table 4.1, 4.14/4.15."""

import numpy as np
import pytest

from sofia_ros.analysis.allan import psd_corrected_for_sampling
from sofia_ros.analysis.noise_model import arw_deg_per_sqrt_h_from_white_psd, loglog_slope, noise_psd
from sofia_ros.analysis.spectra import rate_spectrogram, welch_rate_psd
from sofia_ros.errors import InvalidArgumentError
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
