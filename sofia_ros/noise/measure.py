"""What a record measured, as the noise-model loop compares it (docs/noise.md, 4.2, 5.2).

Per axis the Allan curve with its 4.25 errors and the Welch PSD from PSD_LOWEST_BIN up, each row
with the weight that gives it about unit variance, correlated rows counting once (noise.candidates
explains the residual).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from sofia_ros.analysis.allan import AllanCurve
from sofia_ros.analysis.spectra import log_chi_square_bias_and_sigma, welch_equivalent_dof

__all__ = ['NoiseGrid', 'MeasuredNoise', 'measured_noise', 'PSD_LOWEST_BIN']

#: The loop's PSD rows start this many segment bins above 0 Hz.
PSD_LOWEST_BIN = 8
#: Periodogram values one segment bin apart are correlated by the window; for Hamming (a0 = 0.54,
#: a1 = 0.46) the correlations of |X|^2 are rho_1^2, rho_2^2 with rho_1 = a0 a1 / (a0^2 + a1^2/2),
#: rho_2 = (a1^2 / 4) / (a0^2 + a1^2/2): each bin carries 1 + 2 (rho_1^2 + rho_2^2) bins' worth.
_HAMMING_RHO = (0.54 * 0.46 / (0.54**2 + 0.46**2 / 2), 0.46**2 / 4 / (0.54**2 + 0.46**2 / 2))
_PSD_REDUNDANCY = 1.0 + 2.0 * sum(rho**2 for rho in _HAMMING_RHO)


@dataclass(frozen=True)
class NoiseGrid:
    """Where a record is compared with a model: AV taus, PSD row frequencies, sample and read-out rates."""

    tau_s: np.ndarray
    freq_hz: np.ndarray
    sample_rate_hz: float
    readout_rate_hz: float
    segment_samples: int
    record_s: float

    @property
    def decimation(self) -> float:
        """Read-out samples per analyzed sample (4.2.5)."""
        return self.readout_rate_hz / self.sample_rate_hz


@dataclass(frozen=True)
class MeasuredNoise:
    """A record's root AV and PSD on the grid, with the per-row log errors (see module docstring).

    Rows of the residual vector: ln root AV for el, xel, los at every tau, then ln PSD for el, xel,
    los at every grid frequency. ``log_values`` holds the measured side (the PSD less its chi-square
    log bias), ``weights`` one over each row's error, ``log_factor`` 1/2 on AV rows (root AV),
    ``row_axis`` the axis index of each row.
    """

    grid: NoiseGrid
    adev: np.ndarray
    allan_sigma_ln: np.ndarray
    psd: np.ndarray
    psd_log_bias: float
    psd_sigma_ln: float
    peak_sigma_ln: float
    fine_freq_hz: np.ndarray
    fine_psd: np.ndarray
    log_values: np.ndarray
    weights: np.ndarray
    log_factor: np.ndarray
    row_axis: np.ndarray

    def allan_rows(self, index: int) -> np.ndarray:
        """Residual rows of one axis's root AV.

        Args:
            index: the axis index (0 el, 1 xel, 2 los).

        Returns:
            The row indices, one per tau.
        """
        return index * self.grid.tau_s.size + np.arange(self.grid.tau_s.size)

    def psd_rows(self, index: int, selection: np.ndarray | slice = slice(None)) -> np.ndarray:
        """Residual rows of one axis's PSD (all, or the selected grid frequencies).

        Args:
            index: the axis index (0 el, 1 xel, 2 los).
            selection: a mask or indices of the grid frequencies; all by default.

        Returns:
            The row indices, one per selected frequency.
        """
        start = 3 * self.grid.tau_s.size + index * self.grid.freq_hz.size
        return start + np.arange(self.grid.freq_hz.size)[selection]


def _points_per_octave(tau_s):
    """Local density of the tau grid: AV points closer than an octave share most clusters."""
    log_tau = np.log2(tau_s)
    spacing = np.gradient(log_tau) if log_tau.size > 1 else np.ones(1)
    return np.maximum(1.0, 1.0 / np.maximum(spacing, 1e-12))


def measured_noise(curves: Sequence[AllanCurve], fine_freq_hz: np.ndarray, fine_psd: np.ndarray, *,
                   sample_rate_hz: float, readout_rate_hz: float, segment_samples: int,
                   n_samples: int) -> MeasuredNoise:
    """The loop's view of a record: Allan curves per axis and the Welch PSD (n_freq x 3) as computed.

    Args:
        curves: the root AV curves of el, xel, los [arcsec/s], on one tau grid.
        fine_freq_hz: the Welch frequencies as computed (zero-padded FFT) [Hz].
        fine_psd: the Welch PSD, (n_freq, 3) [(arcsec/s)^2/Hz].
        sample_rate_hz: the record's sample rate [Hz].
        readout_rate_hz: the gyro read-out rate [Hz] (above sample_rate_hz for a decimated record).
        segment_samples: the Welch segment length.
        n_samples: the record's length in samples.

    Returns:
        The grid (PSD rows one segment bin apart from PSD_LOWEST_BIN up), the measured values and their weights.
    """
    tau_s = np.asarray(curves[0].tau_s, dtype=float)
    stride = max(1, int(round((fine_freq_hz.size - 1) * 2 / segment_samples)))
    coarse = np.arange(0, fine_freq_hz.size, stride)
    bin_hz = sample_rate_hz / segment_samples
    rows = coarse[(fine_freq_hz[coarse] >= PSD_LOWEST_BIN * bin_hz) & (fine_freq_hz[coarse] < sample_rate_hz / 2)]
    bias, sigma = log_chi_square_bias_and_sigma(welch_equivalent_dof(n_samples, segment_samples))
    grid = NoiseGrid(tau_s, np.asarray(fine_freq_hz[rows], dtype=float), float(sample_rate_hz), float(readout_rate_hz),
                     int(segment_samples), n_samples / sample_rate_hz)
    adev = np.array([curve.adev for curve in curves])
    psd = np.asarray(fine_psd[rows].T, dtype=float)
    allan_sigma_ln = np.asarray(curves[0].sigma_rel) * np.sqrt(_points_per_octave(tau_s))
    psd_sigma_ln = sigma * np.sqrt(_PSD_REDUNDANCY)
    return MeasuredNoise(
        grid=grid, adev=adev, allan_sigma_ln=allan_sigma_ln, psd=psd,
        psd_log_bias=bias, psd_sigma_ln=psd_sigma_ln, peak_sigma_ln=sigma,
        fine_freq_hz=np.asarray(fine_freq_hz, dtype=float), fine_psd=np.asarray(fine_psd.T, dtype=float),
        log_values=np.concatenate([np.log(adev).ravel(), (np.log(psd) - bias).ravel()]),
        weights=np.concatenate([np.tile(1.0 / allan_sigma_ln, 3), np.full(psd.size, 1.0 / psd_sigma_ln)]),
        log_factor=np.concatenate([np.full(adev.size, 0.5), np.ones(psd.size)]),
        row_axis=np.concatenate([np.repeat(np.arange(3), tau_s.size), np.repeat(np.arange(3), grid.freq_hz.size)]),
    )
