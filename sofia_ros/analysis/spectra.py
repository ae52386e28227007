"""Rate power spectral density and spectrogram of gyro data (sections 4.2.1, 5.2.2, 5.2.5).

Welch settings of 5.2.5: 2^14-sample Hamming segments, 50 % overlap, 2^16 FFT points, one-sided
PSD (4.5) from 0 to the Nyquist frequency. MATLAB's pwelch does not detrend; here each segment's
mean is removed (scipy's default) so that the rate bias (Earth rate, 5.2.4) does not leak into
the lowest bins through the window's side lobes.

Records shorter than four 2^14-sample segments (e.g. housekeeping data decimated as in 4.2.5) get
the largest power-of-two segment that still leaves four, with the same 4x zero padding.

For the model-versus-measurement loop: the expected Welch estimate of a sinusoid (the window's
transform around the line, aliases included) and the equivalent degrees of freedom of the estimate,
whose chi-square scatter sets the bias and the error of a log-PSD value.
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt
from scipy import signal, special

from sofia_ros.errors import InvalidArgumentError
from sofia_ros.units import GYRO_SAMPLE_RATE_HZ
from sofia_ros.validate import finite_array, finite_scalar, positive_scalar

__all__ = [
    'WELCH_SEGMENT_SAMPLES',
    'WELCH_FFT_POINTS',
    'welch_rate_psd',
    'welch_segment_samples',
    'welch_sinusoid_psd',
    'welch_equivalent_dof',
    'log_chi_square_bias_and_sigma',
    'rate_spectrogram',
]

WELCH_SEGMENT_SAMPLES = 2**14
WELCH_FFT_POINTS = 2**16
#: Shortest segment offered for short records (0.64 s at 400 Hz).
_SHORTEST_SEGMENT = 2**8
#: Hamming window of 5.2.5: 0.54 - 0.46 cos(2 pi n / N), periodic as scipy builds it for Welch.
_HAMMING = (0.54, 0.46)


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


def welch_rate_psd(rate: npt.ArrayLike, sample_rate_hz: float = GYRO_SAMPLE_RATE_HZ,
                   segment_samples: int = WELCH_SEGMENT_SAMPLES, fft_points: int = WELCH_FFT_POINTS,
                   overlap: float = 0.5) -> tuple[np.ndarray, np.ndarray]:
    """(freq_hz, psd): one-sided rate PSD, (rate unit)^2/Hz per column, by Welch as in 5.2.5 (eq. 4.5).

    Args:
        rate: N samples of one rate, or (N, k) of k rates.
        sample_rate_hz: the sample rate [Hz].
        segment_samples: the Hamming segment length, at most N.
        fft_points: the FFT length (zero padding), at least segment_samples.
        overlap: the segments' overlap, a fraction in [0, 1).

    Returns:
        The frequencies [Hz] and the PSD, (F,) or (F, k).

    Raises:
        InvalidArgumentError: a rate not 1-D or 2-D, not finite or shorter than a segment, or invalid settings.
    """
    data, rate_hz, length, overlap_samples = _rate_and_segments(rate, sample_rate_hz, segment_samples, overlap)
    points = int(positive_scalar('fft_points', fft_points))
    if points < length:
        raise InvalidArgumentError(f'fft_points ({points}) must be >= segment_samples ({length})')
    return signal.welch(
        data, fs=rate_hz, window='hamming', nperseg=length, noverlap=overlap_samples, nfft=points,
        detrend='constant', return_onesided=True, scaling='density', axis=0,
    )


def welch_segment_samples(n_samples: int) -> int:
    """Segment length: 2^14 as in 5.2.5, or for short records the largest power of two leaving four segments.

    Args:
        n_samples: the record's length in samples.

    Returns:
        The segment length in samples.

    Raises:
        InvalidArgumentError: a record shorter than four of the shortest segments (2^8).
    """
    count = int(positive_scalar('n_samples', n_samples))
    if count < 4 * _SHORTEST_SEGMENT:
        raise InvalidArgumentError(f'a rate PSD needs at least {4 * _SHORTEST_SEGMENT} samples, got {count}')
    return min(WELCH_SEGMENT_SAMPLES, 1 << (count // 4).bit_length() - 1)


def _hamming_transform(frequency_hz, sample_rate_hz, segment_samples):
    """DTFT of the periodic Hamming window, sum_n w_n exp(-2 pi i f n / fs), in closed form."""
    theta = 2.0 * np.pi * np.asarray(frequency_hz, dtype=float) / sample_rate_hz
    step = 2.0 * np.pi / segment_samples

    def dirichlet(angle):
        half = np.sin(0.5 * angle)
        small = np.abs(half) < 1e-12
        ratio = np.where(small, segment_samples * np.cos(0.5 * angle * (segment_samples - 1)),
                         np.sin(0.5 * segment_samples * angle) / np.where(small, 1.0, half))
        return np.exp(-0.5j * angle * (segment_samples - 1)) * ratio

    a0, a1 = _HAMMING
    return a0 * dirichlet(theta) - 0.5 * a1 * (dirichlet(theta - step) + dirichlet(theta + step))


def welch_sinusoid_psd(freq_hz: npt.ArrayLike, amplitude_arcsec_per_s: float, line_hz: float,
                       sample_rate_hz: float = GYRO_SAMPLE_RATE_HZ,
                       segment_samples: int = WELCH_SEGMENT_SAMPLES) -> np.ndarray:
    """Expected one-sided Welch PSD (5.2.5) of A sin(2 pi f0 t): A^2 (|W(f-f0)|^2 + |W(f+f0)|^2) / (2 fs sum w^2).

    Args:
        freq_hz: the frequencies the PSD is wanted at [Hz].
        amplitude_arcsec_per_s: the sinusoid's rate amplitude A [arcsec/s].
        line_hz: its frequency f0 [Hz] (above the Nyquist frequency it lands on its alias).
        sample_rate_hz: the sample rate fs [Hz].
        segment_samples: the Hamming segment length.

    Returns:
        The PSD [(arcsec/s)^2/Hz] at freq_hz.

    Raises:
        InvalidArgumentError: a frequency not finite, or a rate or segment length not positive.
    """
    # Averaged over the line's phase in each segment; W is periodic in fs, so lines above the
    # Nyquist frequency land on their aliases (Tables 5.4, 5.5). Integrates to A^2 / 2 (4.5).
    rate_hz = positive_scalar('sample_rate_hz', sample_rate_hz)
    length = int(positive_scalar('segment_samples', segment_samples))
    frequency = finite_array('freq_hz', freq_hz)
    line = finite_scalar('line_hz', line_hz)
    window = signal.get_window('hamming', length)
    power = (np.abs(_hamming_transform(frequency - line, rate_hz, length)) ** 2
             + np.abs(_hamming_transform(frequency + line, rate_hz, length)) ** 2)
    return amplitude_arcsec_per_s**2 * power / (2.0 * rate_hz * np.sum(window**2))


def welch_equivalent_dof(n_samples: int, segment_samples: int = WELCH_SEGMENT_SAMPLES,
                         overlap: float = 0.5) -> float:
    """Equivalent chi-square degrees of freedom of a Hamming Welch estimate, 2K / (1 + 2 sum (1-j/K) rho_j^2).

    Args:
        n_samples: the record's length in samples.
        segment_samples: the Hamming segment length.
        overlap: the segments' overlap, a fraction in [0, 1).

    Returns:
        The equivalent degrees of freedom.

    Raises:
        InvalidArgumentError: a record shorter than one segment, or a length not positive.
    """
    # Welch (1967); Percival & Walden (1993) eq. 292b: rho_j is the window's overlap correlation at
    # a shift of j segment steps, K the number of segments.
    length = int(positive_scalar('segment_samples', segment_samples))
    step = length - int(round(float(overlap) * length))
    segments = (int(positive_scalar('n_samples', n_samples)) - length) // step + 1
    if segments < 1:
        raise InvalidArgumentError(f'n_samples ({n_samples}) is shorter than one segment ({length})')
    window = signal.get_window('hamming', length)
    energy = np.sum(window**2)
    total = 0.0
    for shift in range(1, segments):
        if shift * step >= length:
            break
        rho = np.dot(window[:length - shift * step], window[shift * step:]) / energy
        total += (1.0 - shift / segments) * rho**2
    return 2.0 * segments / (1.0 + 2.0 * total)


def log_chi_square_bias_and_sigma(dof: float) -> tuple[float, float]:
    """Mean and standard deviation of ln(S_hat / S) for a chi-square estimate with dof degrees of freedom.

    Args:
        dof: the degrees of freedom, > 0.

    Returns:
        The mean (a bias, negative) and the standard deviation of the log estimate.

    Raises:
        InvalidArgumentError: dof not finite or not positive.
    """
    # ln of chi^2_nu / nu: mean digamma(nu/2) - ln(nu/2), variance trigamma(nu/2).
    half = 0.5 * positive_scalar('dof', dof)
    return float(special.digamma(half) - np.log(half)), float(np.sqrt(special.polygamma(1, half)))


def rate_spectrogram(rate: npt.ArrayLike, sample_rate_hz: float = GYRO_SAMPLE_RATE_HZ, segment_samples: int = 2**12,
                     overlap: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(freq_hz, time_s, psd[freq, (column,) time]): short-time one-sided PSD as in Fig. 5.5 (5.2.2).

    Args:
        rate: N samples of one rate, or (N, k) of k rates.
        sample_rate_hz: the sample rate [Hz].
        segment_samples: the Hamming segment length, at most N.
        overlap: the segments' overlap, a fraction in [0, 1).

    Returns:
        The frequencies [Hz], the segments' centre times [s] and the PSD, (F, T) or (F, k, T).

    Raises:
        InvalidArgumentError: a rate not 1-D or 2-D, not finite or shorter than a segment, or invalid settings.
    """
    data, rate_hz, length, overlap_samples = _rate_and_segments(rate, sample_rate_hz, segment_samples, overlap)
    return signal.spectrogram(
        data, fs=rate_hz, window='hamming', nperseg=length, noverlap=overlap_samples,
        detrend='constant', return_onesided=True, scaling='density', axis=0,
    )
