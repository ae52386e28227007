"""Overlapping Allan deviation of rate data and its accuracy (sections 4.2.2, 4.2.4, 4.2.5).

The estimator is 4.6-4.7 with overlapping clusters (stride one sample), the same as
``allantools.oadev(rate, rate=fs, data_type='freq')`` (NIST SP 1065 eq. 11): with the phase
x = [0, cumsum(rate - mean) t_s] (n + 1 points) and tau = m t_s,

    AV(tau) = S(m) / (2 tau^2 (n + 1 - 2m)),   S(m) = sum_i (x[i+2m] - 2 x[i+m] + x[i])^2.

Speed without approximation. S(m) is an exact combination of lagged products, so a dense tau
grid costs about two passes over the data instead of one pass per tau:

- small m (<= 8192): from the rate autocorrelation A_y(l), l < 2m, computed for all lags at once
  by a block FFT; S = sum_l c_m(l) A_y(l) over the zero-extended record, minus the 2(2m - 1)
  overhanging second differences, each O(1) from the phase;
- large m: S = 6 A(0) - 8 A(m) + 2 A(2m) of the phase, one dot product per lag, minus O(m) edges.

The rate's least-squares line is removed first and its exact contribution added back, so rate
ramps cost no precision. Where rounding could still exceed ``rtol`` (estimated from the size of
the cancelling terms, e.g. small m on random-walk-dominated data), S(m) is summed directly.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
import scipy.fft

from sofia_ros.errors import InvalidArgumentError
from sofia_ros.units import GYRO_SAMPLE_RATE_HZ
from sofia_ros.validate import finite_array, positive_scalar

__all__ = [
    'AllanCurve',
    'overlapping_allan_deviation',
    'allan_relative_error',
    'required_test_time_s',
    'log_spaced_cluster_sizes',
    'octave_cluster_sizes',
    'arw_corrected_for_sampling',
    'adev_corrected_for_sampling',
    'psd_corrected_for_sampling',
    'LARGEST_TAU_FRACTION',
]

#: Largest cluster time as a fraction of the record: a third, 50 % error by 4.25 (section 5.2.6).
LARGEST_TAU_FRACTION = 1.0 / 3.0
#: Rounding error of each lagged product in units of eps * A(0): measured up to ~40 on adversarial
#: data (flicker on a random walk), ~5 on gyro data.
_ROUNDING_FACTOR = 64.0
#: Largest FFT block: lags beyond cost one dot product each. Blocks of 2^12-2^14 and ~2^18 spectrum
#: values per chunk were fastest on the 2-core target machine.
_LARGEST_BLOCK = 2**14
_CHUNK_VALUES = 2**18
#: Threads for the lagged products. Dot products avoid BLAS: its spinning worker threads stalled
#: for seconds on the 2-vCPU target machine, while GIL-free numpy calls in our own threads do not.
_WORKERS = max(1, min(4, os.cpu_count() or 1))


@dataclass(frozen=True)
class AllanCurve:
    """Root AV (unit of the rate) against tau, with K = n // m clusters and the 4.25 relative error."""

    tau_s: np.ndarray
    adev: np.ndarray
    n_clusters: np.ndarray
    sigma_rel: np.ndarray


def allan_relative_error(n_clusters: npt.ArrayLike) -> np.ndarray:
    """1-sigma relative error of a root AV point from K clusters, 1/sqrt(2(K-1)) (eq. 4.25).

    Args:
        n_clusters: the number of clusters K of each point, at least 2.

    Returns:
        The relative error of each point, same shape.

    Raises:
        InvalidArgumentError: a K below 2 or not finite.
    """
    clusters = finite_array('n_clusters', n_clusters)
    if np.any(clusters < 2):
        raise InvalidArgumentError(f'n_clusters must be >= 2, got {clusters.min():g}')
    return 1.0 / np.sqrt(2.0 * (clusters - 1.0))


def required_test_time_s(tau_s: npt.ArrayLike, relative_error: npt.ArrayLike) -> np.ndarray:
    """Record length to reach a relative root-AV error at tau, tau (1 + 1/(2 error^2)) (eq. 4.26).

    Args:
        tau_s: cluster time [s], > 0.
        relative_error: the relative 1-sigma error wanted, > 0 (broadcast with tau_s).

    Returns:
        The record length [s].

    Raises:
        InvalidArgumentError: a value not finite or not positive.
    """
    tau = finite_array('tau_s', tau_s)
    error = finite_array('relative_error', relative_error)
    if np.any(tau <= 0.0):
        raise InvalidArgumentError('tau_s must be > 0')
    if np.any(error <= 0.0):
        raise InvalidArgumentError('relative_error must be > 0')
    return tau * (1.0 + 1.0 / (2.0 * error**2))


def arw_corrected_for_sampling(arw_sampled: npt.ArrayLike, sampled_rate_hz: float,
                               readout_rate_hz: float = GYRO_SAMPLE_RATE_HZ) -> np.ndarray:
    """ARW of the read-out data from every k-th sample, N sqrt(f_sampled / f_read-out) (eq. 4.27).

    Args:
        arw_sampled: the ARW N measured on the sampled data (any unit).
        sampled_rate_hz: the rate the data were kept at [Hz].
        readout_rate_hz: the gyro read-out rate [Hz], at least sampled_rate_hz.

    Returns:
        The ARW of the read-out data, in the unit of arw_sampled.

    Raises:
        InvalidArgumentError: a value not finite, a rate not positive, or sampled above read-out.
    """
    return finite_array('arw_sampled', arw_sampled) * np.sqrt(_rate_ratio(sampled_rate_hz, readout_rate_hz))


def adev_corrected_for_sampling(adev_sampled: npt.ArrayLike, sampled_rate_hz: float,
                                readout_rate_hz: float = GYRO_SAMPLE_RATE_HZ) -> np.ndarray:
    """White-noise root AV corrected to the read-out rate, sigma sqrt(f_sampled / f_read-out) (eq. 4.28).

    Args:
        adev_sampled: the white-noise root AV of the sampled data (any unit).
        sampled_rate_hz: the rate the data were kept at [Hz].
        readout_rate_hz: the gyro read-out rate [Hz], at least sampled_rate_hz.

    Returns:
        The root AV of the read-out data, in the unit of adev_sampled.

    Raises:
        InvalidArgumentError: a value not finite, a rate not positive, or sampled above read-out.
    """
    # 4.28 prints sqrt(f_sampled) alone; only the ratio is dimensionless and agrees with 4.27.
    return finite_array('adev_sampled', adev_sampled) * np.sqrt(_rate_ratio(sampled_rate_hz, readout_rate_hz))


def psd_corrected_for_sampling(psd_sampled: npt.ArrayLike, sampled_rate_hz: float,
                               readout_rate_hz: float = GYRO_SAMPLE_RATE_HZ) -> np.ndarray:
    """White rate PSD corrected to the read-out rate, S f_sampled / f_read-out (eq. 4.29, ratio as 4.28).

    Args:
        psd_sampled: the white rate PSD of the sampled data (any unit).
        sampled_rate_hz: the rate the data were kept at [Hz].
        readout_rate_hz: the gyro read-out rate [Hz], at least sampled_rate_hz.

    Returns:
        The PSD of the read-out data, in the unit of psd_sampled.

    Raises:
        InvalidArgumentError: a value not finite, a rate not positive, or sampled above read-out.
    """
    return finite_array('psd_sampled', psd_sampled) * _rate_ratio(sampled_rate_hz, readout_rate_hz)


def _rate_ratio(sampled_rate_hz, readout_rate_hz):
    sampled = positive_scalar('sampled_rate_hz', sampled_rate_hz)
    readout = positive_scalar('readout_rate_hz', readout_rate_hz)
    if sampled > readout:
        raise InvalidArgumentError(f'sampled_rate_hz ({sampled:g}) must not exceed readout_rate_hz ({readout:g})')
    return sampled / readout


def log_spaced_cluster_sizes(n_samples: int, n_taus: int = 100,
                             max_fraction: float = LARGEST_TAU_FRACTION) -> np.ndarray:
    """``n_taus`` distinct cluster sizes m, log-spaced from 1 to max_fraction * n (4.8 generalized).

    Args:
        n_samples: the record's length n in samples.
        n_taus: how many sizes.
        max_fraction: the largest size as a fraction of the record, at most 0.5.

    Returns:
        The sizes, ascending int64: consecutive from 1 while a geometric step is under one sample.

    Raises:
        InvalidArgumentError: more sizes than distinct ones fit, a record too short, or max_fraction above 0.5.
    """
    largest = _largest_cluster_size(n_samples, max_fraction)
    count = int(positive_scalar('n_taus', n_taus))
    if count > largest:
        raise InvalidArgumentError(f'n_taus ({count}) exceeds the {largest} distinct cluster sizes available')
    # Consecutive integers until the geometric step exceeds one sample, then geometric.
    for start in range(1, largest + 1):
        steps = count - start
        if steps <= 0 or start * (largest / start) ** (1.0 / steps) >= start + 1.0:
            break
    head = np.arange(1, start)
    tail = np.rint(np.geomspace(start, largest, count - start + 1)).astype(np.int64)
    return np.unique(np.concatenate([head, tail]))


def octave_cluster_sizes(n_samples: int, max_fraction: float = LARGEST_TAU_FRACTION) -> np.ndarray:
    """Cluster sizes m = 2^j up to max_fraction * n (eq. 4.8).

    Args:
        n_samples: the record's length n in samples.
        max_fraction: the largest size as a fraction of the record, at most 0.5.

    Returns:
        The sizes 1, 2, 4, ..., ascending int64.

    Raises:
        InvalidArgumentError: a record too short, or max_fraction above 0.5.
    """
    largest = _largest_cluster_size(n_samples, max_fraction)
    return 2 ** np.arange(int(np.log2(largest)) + 1, dtype=np.int64)


def _largest_cluster_size(n_samples, max_fraction):
    samples = int(positive_scalar('n_samples', n_samples))
    fraction = positive_scalar('max_fraction', max_fraction)
    if fraction > 0.5:
        raise InvalidArgumentError(f'max_fraction must be <= 0.5 (two clusters, 4.25), got {fraction:g}')
    largest = int(samples * fraction)
    if largest < 1:
        raise InvalidArgumentError(f'n_samples ({samples}) too short for max_fraction {fraction:g}')
    return largest


def overlapping_allan_deviation(rate: npt.ArrayLike, sample_rate_hz: float,
                                cluster_sizes: npt.ArrayLike | None = None,
                                rtol: float = 1e-9) -> AllanCurve | tuple[AllanCurve, ...]:
    """Overlapping root AV at cluster sizes m of rate N (a curve) or Nxk (k curves), exact to rtol (4.6-4.8).

    Args:
        rate: N samples of one rate, or (N, k) of k rates (any unit).
        sample_rate_hz: the sample rate [Hz].
        cluster_sizes: the sizes m in samples, at most N // 2; None for up to 100 log-spaced up to N / 3.
        rtol: the relative error allowed in each AV (rounding of the fast sums).

    Returns:
        One AllanCurve for a 1-D rate, a tuple of k for (N, k).

    Raises:
        InvalidArgumentError: a rate not 1-D or 2-D, too short or not finite, or invalid cluster sizes.
    """
    data = finite_array('rate', rate)
    if data.ndim not in (1, 2):
        raise InvalidArgumentError(f'rate must have shape N or Nxk, got {data.shape}')
    n_samples = data.shape[0]
    if n_samples < 2:
        raise InvalidArgumentError(f'rate needs at least 2 samples, got {n_samples}')
    sample_time_s = 1.0 / positive_scalar('sample_rate_hz', sample_rate_hz)
    tolerance = positive_scalar('rtol', rtol)
    sizes = _checked_cluster_sizes(cluster_sizes, n_samples)
    workspace = _Workspace(n_samples, sizes)
    columns = data[:, np.newaxis] if data.ndim == 1 else data
    with ThreadPoolExecutor(max_workers=_WORKERS) as pool:
        curves = tuple(_allan_curve(columns[:, axis], sample_time_s, sizes, tolerance, workspace, pool)
                       for axis in range(columns.shape[1]))
    return curves[0] if data.ndim == 1 else curves


def _checked_cluster_sizes(cluster_sizes, n_samples):
    if cluster_sizes is None:
        if n_samples < 3:
            raise InvalidArgumentError(f'rate has {n_samples} samples; default cluster sizes (up to a third) need 3')
        return log_spaced_cluster_sizes(n_samples, n_taus=min(100, int(n_samples * LARGEST_TAU_FRACTION)))
    sizes = finite_array('cluster_sizes', cluster_sizes)
    if sizes.ndim != 1 or sizes.size == 0:
        raise InvalidArgumentError(f'cluster_sizes must be a non-empty 1-D array, got shape {sizes.shape}')
    if np.any(sizes != np.rint(sizes)) or np.any(sizes < 1):
        raise InvalidArgumentError('cluster_sizes must be positive integers (samples per cluster)')
    if sizes.max() > n_samples // 2:
        raise InvalidArgumentError(
            f'cluster_sizes up to {int(sizes.max())} need at least {2 * int(sizes.max())} samples '
            f'(two clusters, 4.25); the rate has {n_samples}'
        )
    return np.unique(sizes.astype(np.int64))


class _Workspace:
    """Rate blocks and phase reused by every axis: fresh large arrays cost page faults."""

    def __init__(self, n_samples, sizes):
        small = sizes[sizes <= _LARGEST_BLOCK // 2]
        self.block = 1 << int(2 * small.max() - 1).bit_length() if small.size else _LARGEST_BLOCK
        self.n_samples = n_samples
        self.rows = np.empty((-(-n_samples // self.block) + 1, self.block))
        self.phase = np.empty(n_samples + 1)


def _allan_curve(rate, sample_time_s, sizes, rtol, workspace, pool):
    rows, phase, slope = _residual_rate_and_phase(rate, workspace)
    small = sizes <= _LARGEST_BLOCK // 2
    sums, scales = np.empty(sizes.size), np.empty(sizes.size)
    sums[small], scales[small] = _sums_from_rate(rows, phase, sizes[small], pool)
    phase -= phase.mean()  # second differences ignore constants, rounding in A(l) does not
    sums[~small], scales[~small] = _sums_from_phase(phase, sizes[~small], pool)
    lossy = np.flatnonzero(_ROUNDING_FACTOR * np.finfo(float).eps * scales > rtol * sums)
    sums[lossy] = list(pool.map(lambda m: _direct_second_difference_sum(phase, m), sizes[lossy]))
    sums += _rate_line_terms(phase, sizes, slope)
    terms = phase.size - 2 * sizes
    adev = np.sqrt(np.maximum(sums, 0.0) / (2.0 * sizes.astype(float) ** 2 * terms))
    clusters = rate.size // sizes
    return AllanCurve(
        tau_s=_frozen(sizes * sample_time_s), adev=_frozen(adev), n_clusters=_frozen(clusters),
        sigma_rel=_frozen(allan_relative_error(clusters)),
    )


def _frozen(array):
    array = np.asarray(array)
    array.flags.writeable = False
    return array


def _residual_rate_and_phase(rate, workspace):
    """Rate minus its least-squares line (zero-padded blocks), its phase in rate x samples, the slope."""
    # Cache-sized chunks: two passes over the (possibly strided) input instead of eight. Any slope
    # would do, since _rate_line_terms adds back exactly the line that was removed.
    rows, phase, size = workspace.rows, workspace.phase, workspace.n_samples
    flat = rows.reshape(-1)
    index = np.arange(_CHUNK_VALUES, dtype=float)
    total, moment = 0.0, 0.0  # sum_i y_i, sum_i i y_i
    for start in range(0, size, _CHUNK_VALUES):
        part = rate[start:start + _CHUNK_VALUES]
        part_total = part.sum()
        total += part_total
        moment += _dot(part, index[:part.size]) + start * part_total
    mean, centre = total / size, 0.5 * (size - 1)
    slope = (moment - centre * size * mean) / (size * (size**2 - 1.0) / 12.0)
    phase[0] = 0.0
    for start in range(0, size, _CHUNK_VALUES):
        stop = min(start + _CHUNK_VALUES, size)
        residual = flat[start:stop]
        np.subtract(rate[start:stop], mean, out=residual)
        residual -= slope * (index[:stop - start] + (start - centre))
        np.cumsum(residual, out=phase[start + 1:stop + 1])
        phase[start + 1:stop + 1] += phase[start]
    flat[size:] = 0.0
    return rows, phase, slope


def _rate_line_terms(phase, sizes, slope):
    """S(m) of (d + slope m^2) minus S(m) of d, the second differences d of the residual phase."""
    # = 2 slope m^2 sum(d) + (L - 2m) slope^2 m^4, where sum(d) telescopes to 2 H(m) - H(2m)
    # + 2 T(m) - T(2m) with H(k), T(k) the sums of the first and last k phase values.
    ends = np.unique(np.concatenate([sizes, 2 * sizes]))
    starts = np.concatenate([[0], ends[:-1]])
    head = dict(zip(ends, np.cumsum(np.add.reduceat(phase[:ends[-1]], starts))))
    tail = dict(zip(ends, np.cumsum(np.add.reduceat(phase[::-1][:ends[-1]], starts))))
    terms = np.empty(sizes.size)
    for index, m in enumerate(sizes):
        telescoped = 2.0 * head[m] - head[2 * m] + 2.0 * tail[m] - tail[2 * m]
        square = slope * float(m) ** 2
        terms[index] = 2.0 * square * telescoped + (phase.size - 2 * m) * square**2
    return terms


def _sums_from_rate(rows, phase, sizes, pool):
    """S(m) for small m from the rate autocorrelation, and the magnitude its rounding scales with."""
    if sizes.size == 0:
        return np.empty(0), np.empty(0)
    products = _block_autocorrelation(rows, pool)
    last = phase.size - 1
    sums, scales = np.empty(sizes.size), np.empty(sizes.size)
    for index, m in enumerate(sizes):
        # Kernel -1 (m times), +1 (m times); c(l) its autocorrelation, over all positions of the
        # zero-extended rate.
        lag = np.arange(1, 2 * m)
        kernel = np.where(lag <= m, 2 * m - 3 * lag, lag - 2 * m).astype(float)
        full = 2 * m * products[0] + 2.0 * _dot(kernel, products[1:2 * m])
        # Positions overhanging either end: second differences of the phase clamped to [0, last].
        head = phase[lag] - 2.0 * phase[np.maximum(lag - m, 0)]
        start = np.arange(last - 2 * m + 1, last)
        tail = phase[last] - 2.0 * phase[np.minimum(start + m, last)] + phase[start]
        sums[index] = full - _dot(head, head) - _dot(tail, tail)
        scales[index] = products[0] * (2 * m + 2.0 * np.abs(kernel).sum())
    return sums, scales


def _sums_from_phase(phase, sizes, pool):
    """S(m) for large m as 6 A(0) - 8 A(m) + 2 A(2m) minus O(m) edge products, and its magnitude."""
    size = phase.size
    energy = _dot(phase, phase)
    # Octave grids (4.8) share lags: A(2m) of one size is A(m) of the next.
    lags = np.unique(np.concatenate([sizes, 2 * sizes]))
    lagged = dict(zip(lags, pool.map(lambda lag: _dot(phase[:size - lag], phase[lag:]), lags)))
    edges = np.fromiter(pool.map(lambda m: _edge_products(phase, m), sizes), dtype=float, count=sizes.size)
    at_m, at_2m = np.array([lagged[m] for m in sizes]), np.array([lagged[2 * m] for m in sizes])
    return 6.0 * energy - 8.0 * at_m + 2.0 * at_2m - edges, np.full(sizes.size, 16.0 * energy)


def _edge_products(phase, m):
    """The products 6 A(0) - 8 A(m) + 2 A(2m) counts beyond the n + 1 - 2m second differences."""
    terms = phase.size - 2 * m
    head_m, tail_m = _dot(phase[:m], phase[:m]), _dot(phase[-m:], phase[-m:])
    head_2m = head_m + _dot(phase[m:2 * m], phase[m:2 * m])
    tail_2m = tail_m + _dot(phase[-2 * m:-m], phase[-2 * m:-m])
    head_cross = _dot(phase[:m], phase[m:2 * m])
    tail_cross = _dot(phase[terms:phase.size - m], phase[terms + m:])
    return head_2m + 4.0 * head_m + 4.0 * tail_m + tail_2m - 4.0 * head_cross - 4.0 * tail_cross


def _direct_second_difference_sum(phase, m):
    cluster_difference = phase[m:] - phase[:-m]
    second = cluster_difference[m:] - cluster_difference[:-m]
    return float(_dot(second, second))


def _block_autocorrelation(rows, pool):
    """A(0..block) of the flattened zero-padded rows (last row zero), summed in frequency."""
    # Each block is correlated with itself followed by its successor; a few rows at a time keep
    # the spectra in cache; the workers take contiguous ranges of rows.
    n_blocks, block = rows.shape[0] - 1, rows.shape[1]
    chunk = max(4, _CHUNK_VALUES // block)
    starts = np.arange(0, n_blocks, chunk)
    ranges = [starts[worker::_WORKERS] for worker in range(_WORKERS)]
    power, mixed = np.zeros(block + 1), np.zeros(block + 1, dtype=complex)
    for part_power, part_mixed in pool.map(lambda part: _spectral_sums(rows, part, chunk), ranges):
        power += part_power
        mixed += part_mixed
    # The 2*block spectrum of [block j, block j+1] is F_j + (-1)^k F_{j+1}.
    alternating = np.where(np.arange(block + 1) % 2 == 0, 1.0, -1.0)
    return scipy.fft.irfft(power + alternating * mixed, n=2 * block)[:block + 1]


def _spectral_sums(rows, starts, chunk):
    """Sum over blocks of |F_j|^2 and conj(F_j) F_{j+1} for the chunks of rows beginning at starts."""
    n_blocks, block = rows.shape[0] - 1, rows.shape[1]
    power, mixed = np.zeros(block + 1), np.zeros(block + 1, dtype=complex)
    for start in starts:
        spectra = scipy.fft.rfft(rows[start:min(start + chunk, n_blocks) + 1], n=2 * block, axis=1)
        current, following = spectra[:-1], spectra[1:]
        power += np.einsum('ij,ij->j', current.real, current.real) + np.einsum('ij,ij->j', current.imag, current.imag)
        mixed += np.einsum('ij,ij->j', current.conj(), following)
    return power, mixed


def _dot(a, b):
    return float(np.einsum('i,i->', a, b))
