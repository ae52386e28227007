"""Rate power spectral density and spectrogram of gyro data (sections 4.2.1, 5.2.2, 5.2.5).

Welch settings of 5.2.5: 2^14-sample Hamming segments, 50 % overlap, 2^16 FFT points, one-sided
PSD (4.5) from 0 to the Nyquist frequency. MATLAB's pwelch does not detrend; here each segment's
mean is removed (scipy's default) so that the rate bias (Earth rate, 5.2.4) does not leak into
the lowest bins through the window's side lobes.
"""

from __future__ import annotations

from scipy import signal

from sofia_ros.errors import InvalidArgumentError
from sofia_ros.units import GYRO_SAMPLE_RATE_HZ
from sofia_ros.validate import finite_array, positive_scalar

__all__ = [
    'WELCH_SEGMENT_SAMPLES',
    'WELCH_FFT_POINTS',
    'welch_rate_psd',
    'rate_spectrogram',
]

WELCH_SEGMENT_SAMPLES = 2**14
WELCH_FFT_POINTS = 2**16


def _rate_and_segments(rate, sample_rate_hz, segment_samples, overlap):
    data = finite_array('rate', rate)
    if data.ndim not in (1, 2):
        raise InvalidArgumentError(f'rate must have shape N or Nxk, got {data.shape}')
    rate_hz = positive_scalar('sample_rate_hz', sample_rate_hz)
    length = int(positive_scalar('segment_samples', segment_samples))
    if data.shape[0] < length:
        raise InvalidArgumentError(f'rate has {data.shape[0]} samples, fewer than segment_samples ({length})')
    fraction = float(overlap)
    if not 0.0 <= fraction < 1.0:
        raise InvalidArgumentError(f'overlap must be in [0, 1), got {overlap}')
    return data, rate_hz, length, int(round(fraction * length))


def welch_rate_psd(rate, sample_rate_hz=GYRO_SAMPLE_RATE_HZ, segment_samples=WELCH_SEGMENT_SAMPLES,
                   fft_points=WELCH_FFT_POINTS, overlap=0.5):
    """(freq_hz, psd): one-sided rate PSD, (rate unit)^2/Hz per column, by Welch as in 5.2.5 (eq. 4.5)."""
    data, rate_hz, length, overlap_samples = _rate_and_segments(rate, sample_rate_hz, segment_samples, overlap)
    points = int(positive_scalar('fft_points', fft_points))
    if points < length:
        raise InvalidArgumentError(f'fft_points ({points}) must be >= segment_samples ({length})')
    return signal.welch(
        data, fs=rate_hz, window='hamming', nperseg=length, noverlap=overlap_samples, nfft=points,
        detrend='constant', return_onesided=True, scaling='density', axis=0,
    )


def rate_spectrogram(rate, sample_rate_hz=GYRO_SAMPLE_RATE_HZ, segment_samples=2**12, overlap=0.5):
    """(freq_hz, time_s, psd[freq, (column,) time]): short-time one-sided PSD as in Fig. 5.5 (5.2.2)."""
    data, rate_hz, length, overlap_samples = _rate_and_segments(rate, sample_rate_hz, segment_samples, overlap)
    return signal.spectrogram(
        data, fs=rate_hz, window='hamming', nperseg=length, noverlap=overlap_samples,
        detrend='constant', return_onesided=True, scaling='density', axis=0,
    )
