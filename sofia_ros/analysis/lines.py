"""Spectral lines in gyro rate data and their likely sources (5.2.2, 5.2.5, Tables 5.4, 5.5)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy import ndimage, signal, stats

from sofia_ros.units import GYRO_SAMPLE_RATE_HZ

__all__ = ['KNOWN_LINES_HZ', 'SpectralLine', 'find_lines', 'likely_source', 'line_threshold', 'silent_sources']

#: Frequencies the thesis names, with their source (Tables 5.4, 5.5 and 5.2.5), as measured at 400 Hz.
KNOWN_LINES_HZ = (
    (0.7, '0.7 Hz line (all cases, spherical sensors?)'), (1.3, '1.3 Hz line (all cases, spherical sensors?)'),
    (1.0, 'FD open loop (TC-4)'), (2.3, 'VIS natural frequency (uncaged)'), (3.4, 'FD open loop (TC-4)'),
    (11.7, 'return pump 1'), (30.0, 'main oil pump'), (179.1, 'the gyros themselves'),
    (45.1, 'cooling carts'), (58.7, 'cooling carts'), (73.1, 'cooling carts'), (98.3, 'cooling carts'),
    (115.3, 'cooling carts'), (118.4, 'cooling carts'), (120.0, 'cooling carts'), (163.3, 'cooling carts'),
    (186.6, 'cooling carts'), (189.7, 'cooling carts'), (196.8, 'cooling carts'),
    (71.9, 'aircraft fans'), (95.0, 'aircraft fans'), (122.8, 'aircraft fans'), (135.6, 'aircraft fans'),
    (143.8, 'aircraft fans'), (146.1, 'aircraft fans'), (190.0, 'aircraft fans'), (194.4, 'aircraft fans'),
    (120.3, 'return pump 1'), (139.9, 'return pump 1'), (159.9, 'return pump 1'), (186.5, 'return pump 1'),
    (130.3, 'return pump 2'), (170.5, 'return pump 2'), (175.2, 'return pump 2'), (190.2, 'main oil pump'),
)
_MATCH_HZ = 0.3
#: The Table 5.2 subsystem (key of the campaign's /ta/subsystem_status) each source needs running.
_SOURCE_SUBSYSTEM = {'main oil pump': 'main_oil_pump', 'return pump 1': 'return_pumps',
                     'return pump 2': 'return_pumps', 'cooling carts': 'cooling_carts',
                     'aircraft fans': 'aircraft_fans'}


@dataclass(frozen=True)
class SpectralLine:
    """One line: frequency, rate amplitude of the sinusoid, and the likely source or 'unknown'."""

    freq_hz: float
    amplitude_arcsec_per_s: float
    source: str


def silent_sources(subsystems: Mapping[str, str] | None) -> frozenset[str]:
    """Sources the record's Table 5.2 states rule out: their subsystem is off, or the FD is braked (TC-4 lines).

    Args:
        subsystems: Table 5.2 subsystem -> state ('on', 'off', 'braked', ...), or None if not recorded.

    Returns:
        The KNOWN_LINES_HZ sources that cannot have been running.
    """
    if not subsystems:
        return frozenset()
    silent = {source for source, key in _SOURCE_SUBSYSTEM.items() if subsystems.get(key) == 'off'}
    if subsystems.get('fd') == 'braked':
        silent.add('FD open loop (TC-4)')
    return frozenset(silent)


def likely_source(freq_hz: float, sample_rate_hz: float = GYRO_SAMPLE_RATE_HZ,
                  silent: frozenset[str] = frozenset()) -> str:
    """The thesis' source of a line within 0.3 Hz, where it lands when sampled at sample_rate_hz, else 'unknown'.

    Args:
        freq_hz: the line's frequency as measured [Hz].
        sample_rate_hz: the record's sample rate [Hz].
        silent: sources ruled out (silent_sources).

    Returns:
        A source of KNOWN_LINES_HZ, or 'unknown'.
    """
    # The table values are as measured at 400 Hz; every k-th sample (4.2.5) folds them again.
    def landed(known_hz: float) -> float:
        folded = known_hz % sample_rate_hz
        return min(folded, sample_rate_hz - folded)

    known = [entry for entry in KNOWN_LINES_HZ if entry[1] not in silent]
    best = min(known, key=lambda entry: abs(landed(entry[0]) - freq_hz))
    return best[1] if abs(landed(best[0]) - freq_hz) <= _MATCH_HZ else 'unknown'


def line_threshold(dof: float, n_bins: int, false_alarms: float = 0.01) -> float:
    """Ratio to the running median that chi-square noise of dof degrees of freedom passes in false_alarms of records.

    Args:
        dof: the chi-square degrees of freedom of a PSD value.
        n_bins: the number of bins searched.
        false_alarms: the fraction of noise-only records allowed one false line.

    Returns:
        The threshold as a ratio to the running median.
    """
    # A Welch value is S chi^2_dof / dof and the running median S median(chi^2_dof) / dof, so noise
    # alone exceeds q times the median in a bin with probability P(chi^2_dof > q median(chi^2_dof)).
    return float(stats.chi2.isf(false_alarms / n_bins, dof) / stats.chi2.median(dof))


def find_lines(freq_hz: npt.ArrayLike, psd: npt.ArrayLike, dof: float, *, min_freq_hz: float = 0.3,
               sample_rate_hz: float = GYRO_SAMPLE_RATE_HZ, silent: frozenset[str] = frozenset()) -> list[SpectralLine]:
    """Lines standing out of a one-sided rate PSD of dof degrees of freedom, with amplitude and source (5.2.5).

    Args:
        freq_hz: the PSD's equally spaced frequencies [Hz].
        psd: the one-sided rate PSD [(arcsec/s)^2/Hz] at those frequencies.
        dof: the chi-square degrees of freedom of a PSD value.
        min_freq_hz: the lowest frequency searched [Hz].
        sample_rate_hz: the record's sample rate [Hz] (its Nyquist frequency ends the search).
        silent: sources ruled out (silent_sources).

    Returns:
        The lines in order of frequency.
    """
    freq = np.asarray(freq_hz)
    power = np.asarray(psd)
    df = float(freq[1] - freq[0])
    band = (freq >= min_freq_hz) & (freq <= sample_rate_hz / 2.0)
    # The background from a running median over about 2 Hz, robust against the lines themselves;
    # reflected at 0 and fs/2 (zero padding would halve it there and raise false lines).
    width = max(3, int(2.0 / df) | 1)
    background = ndimage.median_filter(power, size=width, mode='reflect')
    threshold = line_threshold(dof, int(band.sum()))
    peaks, _ = signal.find_peaks(power, height=threshold * background, distance=max(1, int(0.5 / df)))
    lines = []
    for peak in peaks[band[peaks]]:
        # A sinusoid of amplitude A carries A^2/2 of one-sided power, spread over a few bins by the window.
        lo, hi = max(peak - 4, 0), min(peak + 5, len(power))
        excess = np.clip(power[lo:hi] - background[lo:hi], 0.0, None)
        amplitude = float(np.sqrt(2.0 * excess.sum() * df))
        source = likely_source(float(freq[peak]), sample_rate_hz, silent)
        lines.append(SpectralLine(float(freq[peak]), amplitude, source))
    return lines
