"""Gyro noise model: rate PSD and root AV of the five processes, and their fit (4.2.3, 5.1, 5.2.6).

Units: rates in arcsec/s, so SF in arcsec, N in arcsec/sqrt(s), B in arcsec/s, K in arcsec/s^1.5,
R in arcsec/s^2; PSDs are one-sided in (arcsec/s)^2/Hz (4.5).

Three printed formulas are not consistent with the rest of 4.2.3 and are used corrected, each
pinned by a test:

- 4.10 prints the factor 2*4 in front of the integral. With the one-sided PSD the factor is 2
  (IEEE 952's 4 applies to the two-sided PSD); 2*4 would turn 4.14 into 2 N tau^-0.5, not 4.16.
- 4.12 prints pi^2 SF^2 t_s f^2 / 3, half the low-frequency limit of 4.11 (2 pi^2 SF^2 t_s f^2 / 3).
- 4.18 prints B / 0.6648. Integrating 4.17 with 4.10 gives sqrt(2 ln 2 / pi) B = 0.6643 B for
  tau >> 1/f0 (IEEE 952: 0.664 B): the plateau is 0.6643 times B, not B divided by it.

4.22 cannot be checked against 4.10: the ramp's PSD 4.21 makes the integral diverge
logarithmically at f -> 0 (a ramp is not stationary); 4.22 is the exact AV of the ramp itself.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.integrate import quad
from scipy.optimize import lsq_linear

from sofia_ros.analysis.allan import AllanCurve
from sofia_ros.errors import InvalidArgumentError
from sofia_ros.units import GYRO_SAMPLE_RATE_HZ
from sofia_ros.validate import finite_array, finite_scalar, positive_scalar

__all__ = [
    'BIAS_INSTABILITY_PLATEAU',
    'NOISE_TERMS',
    'quantization_psd',
    'quantization_psd_low_frequency',
    'arw_psd',
    'bias_instability_psd',
    'rrw_psd',
    'rate_ramp_psd',
    'noise_psd',
    'quantization_adev',
    'arw_adev',
    'bias_instability_adev',
    'rrw_adev',
    'rate_ramp_adev',
    'noise_adev',
    'sinusoid_adev',
    'decimated_quantization_variance',
    'arw_of_decimated_record',
    'allan_variance_from_psd',
    'arw_deg_per_sqrt_h_from_white_psd',
    'loglog_slope',
    'NoiseFit',
    'fit_noise_model',
    'ArwEstimate',
    'arw_from_slope_fit',
    'BiasStability',
    'bias_stability',
]

#: Root AV plateau of bias instability per unit B, sqrt(2 ln 2 / pi) (4.17 in 4.10; printed 0.6648).
BIAS_INSTABILITY_PLATEAU = float(np.sqrt(2.0 * np.log(2.0) / np.pi))
#: The five processes of 4.2.3, in order of increasing AV slope (Table 4.1).
NOISE_TERMS = ('quantization', 'arw', 'bias_instability', 'rrw', 'rate_ramp')
#: Per term: AV = a tau^power; the coefficient is factor * sqrt(a) (4.13, 4.16, 4.18, 4.20, 4.22).
_AV_POWERS = np.array([-2.0, -1.0, 0.0, 1.0, 2.0])
_COEFFICIENT_FACTORS = np.array([2.0, 1.0, 1.0 / BIAS_INSTABILITY_PLATEAU, np.sqrt(3.0), np.sqrt(2.0)])
_KERNEL_PERIODS = 2**18
_REWEIGHTING_PASSES = 4


def _frequency(freq_hz):
    frequency = finite_array('freq_hz', freq_hz)
    if np.any(frequency <= 0.0):
        raise InvalidArgumentError('freq_hz must be > 0')
    return frequency


def _tau(tau_s):
    tau = finite_array('tau_s', tau_s)
    if np.any(tau <= 0.0):
        raise InvalidArgumentError('tau_s must be > 0')
    return tau


def quantization_psd(freq_hz: npt.ArrayLike, quantization_arcsec: float,
                     sample_rate_hz: float = GYRO_SAMPLE_RATE_HZ) -> np.ndarray:
    """Rate PSD of quantization, 2 SF^2 / (3 t_s) sin^2(pi f t_s) (eq. 4.11).

    Args:
        freq_hz: the frequencies [Hz], > 0.
        quantization_arcsec: the quantization SF [arcsec].
        sample_rate_hz: the read-out rate 1 / t_s [Hz].

    Returns:
        The PSD [(arcsec/s)^2/Hz].

    Raises:
        InvalidArgumentError: a frequency not finite or not positive.
    """
    sample_time_s = 1.0 / positive_scalar('sample_rate_hz', sample_rate_hz)
    phase = np.pi * _frequency(freq_hz) * sample_time_s
    return 2.0 * quantization_arcsec**2 / (3.0 * sample_time_s) * np.sin(phase) ** 2


def quantization_psd_low_frequency(freq_hz: npt.ArrayLike, quantization_arcsec: float,
                                   sample_rate_hz: float = GYRO_SAMPLE_RATE_HZ) -> np.ndarray:
    """Low-frequency limit of 4.11, 2 pi^2 SF^2 t_s f^2 / 3 (eq. 4.12, printed without the 2).

    Args:
        freq_hz: the frequencies [Hz], > 0.
        quantization_arcsec: the quantization SF [arcsec].
        sample_rate_hz: the read-out rate 1 / t_s [Hz].

    Returns:
        The PSD [(arcsec/s)^2/Hz].

    Raises:
        InvalidArgumentError: a frequency not finite or not positive.
    """
    sample_time_s = 1.0 / positive_scalar('sample_rate_hz', sample_rate_hz)
    return 2.0 * np.pi**2 * quantization_arcsec**2 * sample_time_s * _frequency(freq_hz) ** 2 / 3.0


def arw_psd(freq_hz: npt.ArrayLike, arw_arcsec_per_sqrt_s: float) -> np.ndarray:
    """Rate PSD of angle random walk, 2 N^2 (eq. 4.14).

    Args:
        freq_hz: the frequencies [Hz], > 0.
        arw_arcsec_per_sqrt_s: the ARW N [arcsec/sqrt(s)].

    Returns:
        The PSD [(arcsec/s)^2/Hz], flat.

    Raises:
        InvalidArgumentError: a frequency not finite or not positive.
    """
    return np.full_like(_frequency(freq_hz), 2.0 * arw_arcsec_per_sqrt_s**2)


def bias_instability_psd(freq_hz: npt.ArrayLike, bias_instability_arcsec_per_s: float,
                         cutoff_hz: float) -> np.ndarray:
    """Rate PSD of bias instability, B^2 / (pi f) up to f0 and zero above (eq. 4.17).

    Args:
        freq_hz: the frequencies [Hz], > 0.
        bias_instability_arcsec_per_s: the bias instability B [arcsec/s].
        cutoff_hz: the cutoff f0 [Hz], > 0.

    Returns:
        The PSD [(arcsec/s)^2/Hz].

    Raises:
        InvalidArgumentError: a frequency or the cutoff not finite or not positive.
    """
    frequency = _frequency(freq_hz)
    cutoff = positive_scalar('cutoff_hz', cutoff_hz)
    return np.where(frequency <= cutoff, bias_instability_arcsec_per_s**2 / (np.pi * frequency), 0.0)


def rrw_psd(freq_hz: npt.ArrayLike, rrw_arcsec_per_s_sqrt_s: float) -> np.ndarray:
    """Rate PSD of rate random walk, 2 (K / (2 pi f))^2 (eq. 4.19).

    Args:
        freq_hz: the frequencies [Hz], > 0.
        rrw_arcsec_per_s_sqrt_s: the rate random walk K [arcsec/s^1.5].

    Returns:
        The PSD [(arcsec/s)^2/Hz].

    Raises:
        InvalidArgumentError: a frequency not finite or not positive.
    """
    return 2.0 * (rrw_arcsec_per_s_sqrt_s / (2.0 * np.pi * _frequency(freq_hz))) ** 2


def rate_ramp_psd(freq_hz: npt.ArrayLike, rate_ramp_arcsec_per_s2: float) -> np.ndarray:
    """Rate PSD of rate ramp, 2 R^2 / (2 pi f)^3 (eq. 4.21).

    Args:
        freq_hz: the frequencies [Hz], > 0.
        rate_ramp_arcsec_per_s2: the rate ramp R [arcsec/s^2].

    Returns:
        The PSD [(arcsec/s)^2/Hz].

    Raises:
        InvalidArgumentError: a frequency not finite or not positive.
    """
    return 2.0 * rate_ramp_arcsec_per_s2**2 / (2.0 * np.pi * _frequency(freq_hz)) ** 3


def noise_psd(freq_hz: npt.ArrayLike, quantization_arcsec: float = 0.0, arw_arcsec_per_sqrt_s: float = 0.0,
              bias_instability_arcsec_per_s: float = 0.0, rrw_arcsec_per_s_sqrt_s: float = 0.0,
              rate_ramp_arcsec_per_s2: float = 0.0, sample_rate_hz: float = GYRO_SAMPLE_RATE_HZ,
              bias_cutoff_hz: float = 10.0) -> np.ndarray:
    """Rate PSD of the five independent processes, their sum (eq. 4.23).

    Args:
        freq_hz: the frequencies [Hz], > 0.
        quantization_arcsec: SF [arcsec].
        arw_arcsec_per_sqrt_s: N [arcsec/sqrt(s)].
        bias_instability_arcsec_per_s: B [arcsec/s].
        rrw_arcsec_per_s_sqrt_s: K [arcsec/s^1.5].
        rate_ramp_arcsec_per_s2: R [arcsec/s^2].
        sample_rate_hz: the read-out rate 1 / t_s [Hz].
        bias_cutoff_hz: the bias instability's cutoff f0 [Hz].

    Returns:
        The PSD [(arcsec/s)^2/Hz].

    Raises:
        InvalidArgumentError: a frequency, rate or cutoff not finite or not positive.
    """
    return (
        quantization_psd(freq_hz, quantization_arcsec, sample_rate_hz)
        + arw_psd(freq_hz, arw_arcsec_per_sqrt_s)
        + bias_instability_psd(freq_hz, bias_instability_arcsec_per_s, bias_cutoff_hz)
        + rrw_psd(freq_hz, rrw_arcsec_per_s_sqrt_s)
        + rate_ramp_psd(freq_hz, rate_ramp_arcsec_per_s2)
    )


def quantization_adev(tau_s: npt.ArrayLike, quantization_arcsec: float) -> np.ndarray:
    """Root AV of quantization noise, SF / (2 tau) (eq. 4.13).

    Args:
        tau_s: the cluster times [s], > 0.
        quantization_arcsec: SF [arcsec].

    Returns:
        The root AV [arcsec/s].

    Raises:
        InvalidArgumentError: a tau not finite or not positive.
    """
    return quantization_arcsec / (2.0 * _tau(tau_s))


def arw_adev(tau_s: npt.ArrayLike, arw_arcsec_per_sqrt_s: float) -> np.ndarray:
    """Root AV of angle random walk, N tau^-0.5 (eq. 4.16).

    Args:
        tau_s: the cluster times [s], > 0.
        arw_arcsec_per_sqrt_s: N [arcsec/sqrt(s)].

    Returns:
        The root AV [arcsec/s].

    Raises:
        InvalidArgumentError: a tau not finite or not positive.
    """
    return arw_arcsec_per_sqrt_s / np.sqrt(_tau(tau_s))


def bias_instability_adev(tau_s: npt.ArrayLike, bias_instability_arcsec_per_s: float) -> np.ndarray:
    """Root AV plateau of bias instability for tau >> 1/f0, 0.6643 B (eq. 4.18 corrected, see module).

    Args:
        tau_s: the cluster times [s], > 0.
        bias_instability_arcsec_per_s: B [arcsec/s].

    Returns:
        The root AV [arcsec/s], flat.

    Raises:
        InvalidArgumentError: a tau not finite or not positive.
    """
    return np.full_like(_tau(tau_s), BIAS_INSTABILITY_PLATEAU * bias_instability_arcsec_per_s)


def rrw_adev(tau_s: npt.ArrayLike, rrw_arcsec_per_s_sqrt_s: float) -> np.ndarray:
    """Root AV of rate random walk, K tau^0.5 / sqrt(3) (eq. 4.20).

    Args:
        tau_s: the cluster times [s], > 0.
        rrw_arcsec_per_s_sqrt_s: K [arcsec/s^1.5].

    Returns:
        The root AV [arcsec/s].

    Raises:
        InvalidArgumentError: a tau not finite or not positive.
    """
    return rrw_arcsec_per_s_sqrt_s * np.sqrt(_tau(tau_s) / 3.0)


def rate_ramp_adev(tau_s: npt.ArrayLike, rate_ramp_arcsec_per_s2: float) -> np.ndarray:
    """Root AV of rate ramp, R tau / sqrt(2) (eq. 4.22).

    Args:
        tau_s: the cluster times [s], > 0.
        rate_ramp_arcsec_per_s2: R [arcsec/s^2].

    Returns:
        The root AV [arcsec/s].

    Raises:
        InvalidArgumentError: a tau not finite or not positive.
    """
    return rate_ramp_arcsec_per_s2 * _tau(tau_s) / np.sqrt(2.0)


def noise_adev(tau_s: npt.ArrayLike, quantization_arcsec: float = 0.0, arw_arcsec_per_sqrt_s: float = 0.0,
               bias_instability_arcsec_per_s: float = 0.0, rrw_arcsec_per_s_sqrt_s: float = 0.0,
               rate_ramp_arcsec_per_s2: float = 0.0) -> np.ndarray:
    """Root of the summed AVs of the five processes (eq. 4.24).

    Args:
        tau_s: the cluster times [s], > 0.
        quantization_arcsec: SF [arcsec].
        arw_arcsec_per_sqrt_s: N [arcsec/sqrt(s)].
        bias_instability_arcsec_per_s: B [arcsec/s].
        rrw_arcsec_per_s_sqrt_s: K [arcsec/s^1.5].
        rate_ramp_arcsec_per_s2: R [arcsec/s^2].

    Returns:
        The root AV [arcsec/s].

    Raises:
        InvalidArgumentError: a tau not finite or not positive.
    """
    return np.sqrt(
        quantization_adev(tau_s, quantization_arcsec) ** 2
        + arw_adev(tau_s, arw_arcsec_per_sqrt_s) ** 2
        + bias_instability_adev(tau_s, bias_instability_arcsec_per_s) ** 2
        + rrw_adev(tau_s, rrw_arcsec_per_s_sqrt_s) ** 2
        + rate_ramp_adev(tau_s, rate_ramp_arcsec_per_s2) ** 2
    )


def sinusoid_adev(tau_s: npt.ArrayLike, amplitude_arcsec_per_s: float, frequency_hz: float,
                  sample_rate_hz: float = GYRO_SAMPLE_RATE_HZ) -> np.ndarray:
    """Root AV of a sampled sinusoid, A sin^2(pi f tau) / |m sin(pi f t_s)| (4.6-4.7 on A sin(2 pi f t)).

    Args:
        tau_s: the cluster times [s], > 0 (rounded to whole samples).
        amplitude_arcsec_per_s: the rate amplitude A [arcsec/s].
        frequency_hz: the line's frequency f [Hz] (above fs/2 it aliases).
        sample_rate_hz: the sample rate 1 / t_s [Hz].

    Returns:
        The root AV [arcsec/s] (zero for a line at a multiple of the sample rate).

    Raises:
        InvalidArgumentError: a tau, the frequency or the rate not finite, or a tau or the rate not positive.
    """
    # Cluster means of m samples scale the sinusoid by sin(pi f tau) / (m sin(pi f t_s)) (the
    # discrete form of 4.10's sin(x)/x, exact for every m and for lines above fs/2, which alias);
    # two means tau apart differ by 2 sin(pi f tau) times that, and 4.7 halves the mean square.
    tau = _tau(tau_s)
    sample_time_s = 1.0 / positive_scalar('sample_rate_hz', sample_rate_hz)
    frequency = finite_scalar('frequency_hz', frequency_hz)
    clusters = np.rint(tau / sample_time_s)
    across_sample = np.sin(np.pi * frequency * sample_time_s)
    across_cluster = np.sin(np.pi * frequency * clusters * sample_time_s)
    if abs(across_sample) < 1e-15:  # a line at a multiple of fs is sampled as a constant
        return np.zeros_like(tau)
    return abs(amplitude_arcsec_per_s) * across_cluster**2 / (clusters * abs(across_sample))


def decimated_quantization_variance(quantization_arcsec: float,
                                    readout_rate_hz: float = GYRO_SAMPLE_RATE_HZ) -> float:
    """Rate variance quantization leaves in every k-th read-out (k >= 2), SF^2 / (6 t_s^2) (4.11 at full band).

    Args:
        quantization_arcsec: SF [arcsec].
        readout_rate_hz: the gyro read-out rate 1 / t_s [Hz].

    Returns:
        The white rate variance [(arcsec/s)^2] of the decimated samples.

    Raises:
        InvalidArgumentError: a read-out rate not finite or not positive.
    """
    # The rate is the difference of two rounded angles (2.11), each off by a uniform error of
    # variance SF^2 / 12: at the read-out rate the difference is blue (4.11); samples k >= 2 apart
    # share no rounding error, so in decimated data it is white noise of variance 2 SF^2 / (12 t_s^2).
    sample_time_s = 1.0 / positive_scalar('readout_rate_hz', readout_rate_hz)
    return quantization_arcsec**2 / (6.0 * sample_time_s**2)


def arw_of_decimated_record(arw_sampled_arcsec_per_sqrt_s: npt.ArrayLike, sampled_rate_hz: float,
                            quantization_arcsec: float,
                            readout_rate_hz: float = GYRO_SAMPLE_RATE_HZ) -> np.ndarray:
    """Read-out ARW from every k-th sample: 4.27, less the white quantization SF^2 / (6 t_s) it carries.

    Args:
        arw_sampled_arcsec_per_sqrt_s: the ARW N of the decimated record [arcsec/sqrt(s)].
        sampled_rate_hz: the rate the record was kept at [Hz], below readout_rate_hz.
        quantization_arcsec: SF [arcsec].
        readout_rate_hz: the gyro read-out rate [Hz].

    Returns:
        The ARW of the read-out data [arcsec/sqrt(s)], zero where quantization explains it all.

    Raises:
        InvalidArgumentError: a value not finite, a rate not positive, or sampled not below read-out.
    """
    # 4.27 assumes white read-out noise; quantization is not (4.11), so in every k-th sample it adds
    # decimated_quantization_variance x t_s = SF^2 / (6 t_s) to N^2 (0.0132"/sqrt(s) reads 0.0146 otherwise).
    sampled = positive_scalar('sampled_rate_hz', sampled_rate_hz)
    readout = positive_scalar('readout_rate_hz', readout_rate_hz)
    if sampled >= readout:
        raise InvalidArgumentError(f'sampled_rate_hz ({sampled:g}) must be below readout_rate_hz ({readout:g})')
    corrected_sq = finite_array('arw_sampled_arcsec_per_sqrt_s', arw_sampled_arcsec_per_sqrt_s) ** 2 * sampled / readout
    floor_sq = decimated_quantization_variance(quantization_arcsec, readout) / readout
    return np.sqrt(np.maximum(corrected_sq - floor_sq, 0.0))


def allan_variance_from_psd(tau_s: float, psd_function: Callable[[np.ndarray], npt.ArrayLike],
                            f_min_hz: float = 0.0, f_max_hz: float = np.inf) -> float:
    """AV from a one-sided rate PSD, 2 int S(f) sin^4(pi f tau) / (pi f tau)^2 df (eq. 4.10, factor 2).

    Args:
        tau_s: one cluster time [s], > 0.
        psd_function: the one-sided rate PSD as a function of frequency [Hz] (vectorized).
        f_min_hz: the lower end of the integral [Hz].
        f_max_hz: the upper end [Hz] (inf for none).

    Returns:
        The AV [(rate unit)^2].

    Raises:
        InvalidArgumentError: tau not positive, or not 0 <= f_min_hz < f_max_hz.
    """
    # In x = pi f tau: Gauss-Legendre on log-spaced pieces of the first half period (where 1/f^n
    # PSDs are steep) and on each later half period, up to 2^18 of them; beyond, sin^4 is replaced
    # by its mean 3/8 and the smooth remainder integrated by quad.
    tau = positive_scalar('tau_s', tau_s)
    low = np.pi * tau * finite_array('f_min_hz', f_min_hz, shape=())
    high = np.pi * tau * float(f_max_hz) if not np.isinf(f_max_hz) else np.inf
    if not 0.0 <= low < high:
        raise InvalidArgumentError(f'need 0 <= f_min_hz < f_max_hz, got {f_min_hz} and {f_max_hz}')
    end = min(high, np.pi * (np.floor(low / np.pi) + _KERNEL_PERIODS))
    first = min(end, np.pi * (np.floor(low / np.pi) + 1.0))
    start = max(low, first * 1e-12)
    periods = np.pi * np.arange(np.ceil(first / np.pi), np.floor(end / np.pi) + 1)
    edges = np.unique(np.concatenate([[low], np.geomspace(start, first, 49), periods, [end]]))
    edges = edges[(edges >= low) & (edges <= end)]
    nodes, weights = np.polynomial.legendre.leggauss(8)
    centre, half = 0.5 * (edges[1:] + edges[:-1]), 0.5 * (edges[1:] - edges[:-1])
    x = centre[:, np.newaxis] + half[:, np.newaxis] * nodes
    total = float(np.sum(half[:, np.newaxis] * weights * _psd_at(psd_function, x, tau) * np.sin(x) ** 4 / x**2))
    if end < high:
        # x = 1/u maps the tail onto [1/high, 1/end]; sin^4 averages to 3/8 over each period.
        tail, _ = quad(lambda u: float(_psd_at(psd_function, np.array(1.0 / u), tau)), 1.0 / high, 1.0 / end, limit=200)
        total += 0.375 * tail
    return 2.0 / (np.pi * tau) * total


def _psd_at(psd_function, x, tau):
    return np.asarray(psd_function(x / (np.pi * tau)), dtype=float)


def arw_deg_per_sqrt_h_from_white_psd(psd_deg_per_h_sq_per_hz: npt.ArrayLike) -> np.ndarray:
    """ARW coefficient from the flat rate PSD level, sqrt(S / 2) / 60 (eq. 4.15).

    Args:
        psd_deg_per_h_sq_per_hz: the flat PSD level S [(deg/h)^2/Hz], >= 0.

    Returns:
        The ARW [deg/sqrt(h)].

    Raises:
        InvalidArgumentError: a level not finite or negative.
    """
    level = finite_array('psd_deg_per_h_sq_per_hz', psd_deg_per_h_sq_per_hz)
    if np.any(level < 0.0):
        raise InvalidArgumentError('psd_deg_per_h_sq_per_hz must be >= 0')
    return np.sqrt(level / 2.0) / 60.0


def loglog_slope(x: npt.ArrayLike, y: npt.ArrayLike) -> float:
    """Least-squares slope of log y against log x, to identify a process by Table 4.1.

    Args:
        x: abscissae (e.g. tau or f), 1-D, > 0.
        y: ordinates (root AV or PSD), same shape, > 0.

    Returns:
        The slope d log y / d log x.

    Raises:
        InvalidArgumentError: shapes that differ, fewer than 2 points, or values not finite or not positive.
    """
    abscissa, ordinate = finite_array('x', x), finite_array('y', y)
    if abscissa.ndim != 1 or abscissa.shape != ordinate.shape or abscissa.size < 2:
        raise InvalidArgumentError(
            f'x and y must be 1-D of equal length >= 2, got {abscissa.shape} and {ordinate.shape}')
    if np.any(abscissa <= 0.0) or np.any(ordinate <= 0.0):
        raise InvalidArgumentError('x and y must be > 0 for a log-log slope')
    return float(np.polyfit(np.log(abscissa), np.log(ordinate), 1)[0])


def _redundancy(tau_s):
    """Points per octave: AV points closer than an octave share most clusters, so count once."""
    octaves = np.log2(tau_s.max() / tau_s.min()) if tau_s.size > 1 else 1.0
    return max(1.0, (tau_s.size - 1) / max(octaves, 1.0))


@dataclass(frozen=True)
class NoiseFit:
    """Fitted coefficients of the five processes with 1-sigma uncertainties from 4.25."""

    quantization_arcsec: float
    arw_arcsec_per_sqrt_s: float
    bias_instability_arcsec_per_s: float
    rrw_arcsec_per_s_sqrt_s: float
    rate_ramp_arcsec_per_s2: float
    quantization_sigma_arcsec: float
    arw_sigma_arcsec_per_sqrt_s: float
    bias_instability_sigma_arcsec_per_s: float
    rrw_sigma_arcsec_per_s_sqrt_s: float
    rate_ramp_sigma_arcsec_per_s2: float

    def as_arcsec(self) -> dict[str, float]:
        """The fitted coefficients as keywords of noise_adev / noise_psd (eqs. 4.24, 4.23).

        Returns:
            The five coefficients by the keyword names of noise_adev and noise_psd.
        """
        return {
            'quantization_arcsec': self.quantization_arcsec,
            'arw_arcsec_per_sqrt_s': self.arw_arcsec_per_sqrt_s,
            'bias_instability_arcsec_per_s': self.bias_instability_arcsec_per_s,
            'rrw_arcsec_per_s_sqrt_s': self.rrw_arcsec_per_s_sqrt_s,
            'rate_ramp_arcsec_per_s2': self.rate_ramp_arcsec_per_s2,
        }


def fit_noise_model(curve: AllanCurve, terms: Sequence[str] = NOISE_TERMS, lines_hz: Sequence[float] = (),
                    sample_rate_hz: float = GYRO_SAMPLE_RATE_HZ) -> NoiseFit:
    """Weighted non-negative least squares of 4.24 (AV space) to a root AV curve in arcsec/s, errors 4.25.

    Args:
        curve: a root AV curve [arcsec/s] with its 4.25 errors.
        terms: the NOISE_TERMS fitted; the others are held at zero.
        lines_hz: frequencies [Hz] of lines fitted as further AV terms and dropped.
        sample_rate_hz: the record's sample rate [Hz] (for the lines' AV).

    Returns:
        The five coefficients with their 1-sigma errors (zero for terms not fitted).

    Raises:
        InvalidArgumentError: unknown or no terms, a curve not finite, or too few points for the terms and lines.
    """
    # AV = sum_k a_k tau^p_k with a_k >= 0, where the terms add. An AV point's relative error is
    # twice the 4.25 error of its root, taken of the model AV (refitted a few times, so that low
    # fluctuations don't pull the fit). The covariance is multiplied by the points per octave, since
    # closer AV points share most clusters; a coefficient's sigma is half the width of the 1-sigma
    # interval of a_k mapped through sqrt. Terms not listed are held at zero. Lines at lines_hz
    # (e.g. found in the PSD) enter as further AV terms A^2 sinusoid_adev(tau, 1, f)^2 whose powers
    # are fitted and dropped: otherwise their bulges below ~10 s (5.2.6) are read as ARW.
    unknown = set(terms) - set(NOISE_TERMS)
    if unknown or not terms:
        raise InvalidArgumentError(f'terms must be a non-empty subset of {NOISE_TERMS}, got {terms}')
    tau = _tau(curve.tau_s)
    variance = finite_array('curve.adev', curve.adev) ** 2
    relative = 2.0 * finite_array('curve.sigma_rel', curve.sigma_rel)
    active = np.array([name in terms for name in NOISE_TERMS])
    line_columns = [sinusoid_adev(tau, 1.0, frequency, sample_rate_hz) ** 2 for frequency in lines_hz]
    if tau.size <= active.sum() + len(line_columns):
        raise InvalidArgumentError(f'curve needs more than {active.sum() + len(line_columns)} points to fit '
                                   f'{len(terms)} terms and {len(line_columns)} lines')
    design = np.column_stack([tau[:, np.newaxis] ** _AV_POWERS[active], *line_columns])
    model = variance
    for _ in range(_REWEIGHTING_PASSES):
        weighted = design / (relative * model)[:, np.newaxis]
        scale = np.linalg.norm(weighted, axis=0)
        solution = lsq_linear(weighted / scale, variance / (relative * model), bounds=(0.0, np.inf), method='bvls')
        amplitudes = solution.x / scale
        model = np.maximum(design @ amplitudes, 1e-300)
    weighted = design / (relative * model)[:, np.newaxis]
    scale = np.linalg.norm(weighted, axis=0)
    try:
        covariance = np.linalg.inv((weighted / scale).T @ (weighted / scale)) / np.outer(scale, scale)
        amplitude_sigma = np.sqrt(np.maximum(np.diag(covariance), 0.0) * _redundancy(tau))
    except np.linalg.LinAlgError:
        amplitude_sigma = np.full(amplitudes.size, np.inf)
    amplitudes, amplitude_sigma = np.maximum(amplitudes[:active.sum()], 0.0), amplitude_sigma[:active.sum()]
    values, sigmas = np.zeros(len(NOISE_TERMS)), np.zeros(len(NOISE_TERMS))
    values[active] = _COEFFICIENT_FACTORS[active] * np.sqrt(amplitudes)
    upper = np.sqrt(amplitudes + amplitude_sigma)
    lower = np.sqrt(np.maximum(amplitudes - amplitude_sigma, 0.0))
    sigmas[active] = _COEFFICIENT_FACTORS[active] * 0.5 * (upper - lower)
    return NoiseFit(*(float(value) for value in np.concatenate([values, sigmas])))


@dataclass(frozen=True)
class ArwEstimate:
    """ARW from a -1/2-slope fit over a tau range, as in Table 5.8."""

    arw_arcsec_per_sqrt_s: float
    sigma_arcsec_per_sqrt_s: float
    tau_min_s: float
    tau_max_s: float


def arw_from_slope_fit(curve: AllanCurve, tau_min_s: float, tau_max_s: float) -> ArwEstimate:
    """Least-squares fit of N tau^-0.5 to the curve between two taus, weighted by 4.25 (5.2.6, Table 5.8).

    Args:
        curve: a root AV curve [arcsec/s] with its 4.25 errors.
        tau_min_s: the shortest tau fitted [s].
        tau_max_s: the longest tau fitted [s].

    Returns:
        N [arcsec/sqrt(s)] with its 1-sigma error and the tau range.

    Raises:
        InvalidArgumentError: a range not positive or holding no curve point.
    """
    low, high = positive_scalar('tau_min_s', tau_min_s), positive_scalar('tau_max_s', tau_max_s)
    tau = _tau(curve.tau_s)
    inside = (tau >= low) & (tau <= high)
    if low >= high or not np.any(inside):
        raise InvalidArgumentError(f'no curve point with tau_min_s ({low:g}) <= tau <= tau_max_s ({high:g})')
    log_arw = np.log(curve.adev[inside]) + 0.5 * np.log(tau[inside])
    weights = 1.0 / curve.sigma_rel[inside] ** 2
    mean = float(np.sum(weights * log_arw) / np.sum(weights))
    sigma_log = np.sqrt(_redundancy(tau[inside]) / np.sum(weights))
    return ArwEstimate(float(np.exp(mean)), float(np.exp(mean) * sigma_log), low, high)


@dataclass(frozen=True)
class BiasStability:
    """Minimum of the root AV curve and where it is, as Table 5.8 reads it (4.2.3, 5.2.6)."""

    bias_stability_arcsec_per_s: float
    tau_s: float
    sigma_arcsec_per_s: float


def bias_stability(curve: AllanCurve, max_sigma_rel: float = np.inf) -> BiasStability:
    """Bias stability: the lowest root AV point with a 4.25 error <= max_sigma_rel, its tau and error (Table 5.8).

    Args:
        curve: a root AV curve with its 4.25 errors.
        max_sigma_rel: the largest relative error of a point read.

    Returns:
        The lowest eligible root AV, its tau and its 1-sigma error.

    Raises:
        InvalidArgumentError: no point with an error that small (the record is too short).
    """
    # The last points of a curve run to T/3 with a 50 % error (5.2.6): the lowest of several such
    # points is mostly the one noise pushed down, so a record reads only where it knows the curve.
    adev = finite_array('curve.adev', curve.adev)
    eligible = np.asarray(curve.sigma_rel) <= max_sigma_rel
    if not np.any(eligible):
        raise InvalidArgumentError(f'no curve point has a 4.25 error <= {max_sigma_rel:g}; the record is too short')
    lowest = int(np.argmin(np.where(eligible, adev, np.inf)))
    return BiasStability(float(adev[lowest]), float(curve.tau_s[lowest]), float(adev[lowest] * curve.sigma_rel[lowest]))
