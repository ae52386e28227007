"""`sofia noise`: a stability record's rates against Earth rate, its noise coefficients and lines, the model loop (5.2).

One record of `sofia run gyro-stability` is read once (load_noise_record) and analyzed
(analyze_record), optionally as if only every k-th sample had been kept (the housekeeping case of
4.2.5, corrected by 4.27 with the quantization term of noise.fit.arw_of_decimated_record):

- the Earth-rate table of Table 5.7 with the heading search and its degeneracy (noise.earth_rate);
- per axis, the overlapping Allan deviation (4.6-4.8) of the mean-removed rate, its five-term fit
  (4.24) with 4.25 errors and the PSD's lines as nuisance terms, the bias stability read at the
  curve's minimum (Table 5.8) among points known to 25 % and whether the record resolves it, the
  Welch PSD of 5.2.5 and its lines with their likely sources, and the largest excursion of the
  integrated angle (Figs. 5.8-5.9);
- the noise-model loop (noise.candidates): the model's residual and the missing terms ranked.

The document is the `sofia noise --json` contract (docs/noise.md).
"""

from __future__ import annotations

from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypedDict

import numpy as np
import yaml

from sofia_ros.analysis.allan import AllanCurve, log_spaced_cluster_sizes, overlapping_allan_deviation
from sofia_ros.analysis.lines import SpectralLine, find_lines, silent_sources
from sofia_ros.analysis.spectra import welch_equivalent_dof, welch_rate_psd, welch_segment_samples
from sofia_ros.bag import BagReader
from sofia_ros.effects.base import Effects
from sofia_ros.errors import BagError, InvalidArgumentError
from sofia_ros.frames import AXES
from sofia_ros.noise.candidates import (
    BaseFit,
    NoiseCandidate,
    ResidualSummary,
    fit_base,
    rank_missing_terms,
    residual_summary,
)
from sofia_ros.noise.earth_rate import DEGENERATE_PAIR, EarthRateTable, earth_rate_table
from sofia_ros.noise.fit import NoiseFit, arw_of_decimated_record, bias_stability, fit_noise_model
from sofia_ros.noise.measure import MeasuredNoise, measured_noise
from sofia_ros.noise.predict import check_noise_model
from sofia_ros.sensors.gyro_errors import tarf_from_gyrf_dcm
from sofia_ros.sensors.gyro_noise import QUANTIZATION_ARCSEC
from sofia_ros.topics import CASE_DOCUMENT, GYRO_IMU, SUBSYSTEM_STATUS
from sofia_ros.units import GYRO_SAMPLE_RATE_HZ, RAD_PER_ARCSEC

if TYPE_CHECKING:  # the model arrives parsed: noise/ does not load config files itself
    from sofia_ros.config import EffectConfig

__all__ = [
    'MIN_SAMPLES',
    'NoiseRecord',
    'NoiseAnalysis',
    'checked_decimation',
    'integrated_angle_arcsec',
    'load_noise_record',
    'analyze_record',
    'analyze_noise',
    'NoiseDocument',
    'AxisNoise',
    'NoiseLine',
    'NoiseModelSummary',
]

#: Shortest analyzable record: four Welch segments of 256 samples (spectra.welch_segment_samples).
MIN_SAMPLES = 1024
_N_TAUS = 60
#: The bias stability is read among AV points known to 25 % (4.25: at least 9 clusters, tau <= T/9).
BIAS_STABILITY_MAX_SIGMA_REL = 0.25


class NoiseLine(TypedDict):
    """A line of an axis's PSD with its likely source (analysis.lines.SpectralLine)."""

    freq_hz: float
    amplitude_arcsec_per_s: float
    source: str


class _DecimatedArw(TypedDict, total=False):
    # A base of its own: NotRequired is not seen at run time under `from __future__ import annotations` (3.11).
    #: the ARW as fitted on a decimated record, before 4.27
    arw_sampled_arcsec_per_sqrt_s: float


class AxisNoise(_DecimatedArw):
    """One axis of `sofia noise --json` (docs/noise.md): the five-term fit, bias stability, lines, angle."""

    arw_arcsec_per_sqrt_s: float
    arw_sigma: float
    bias_stability_arcsec_per_s: float
    bias_stability_sigma: float
    bias_stability_tau_s: float
    bias_stability_resolved: bool
    rrw_arcsec_per_s_sqrt_s: float
    rrw_sigma: float
    quantization_arcsec: float
    quantization_sigma: float
    bias_instability_arcsec_per_s: float
    bias_instability_sigma: float
    rate_ramp_arcsec_per_s2: float
    rate_ramp_sigma: float
    integrated_angle_max_arcsec: float
    lines: list[NoiseLine]


class NoiseModelSummary(TypedDict):
    """The model object of `sofia noise --json`: the model, its refitted ARW and its residual."""

    path: str | None
    effects: list[str]
    arw_refit_arcsec_per_sqrt_s: dict[str, float]
    residual: ResidualSummary


class NoiseDocument(TypedDict):
    """The `sofia noise --json` document (docs/noise.md)."""

    bag: str
    case: str | None
    description: str | None
    samples_per_axis: int
    record_s: float
    sample_rate_hz: float
    readout_rate_hz: float
    decimation: int
    subsystems: dict[str, str] | None
    axes: dict[str, AxisNoise]
    earth_rate_deg_per_h: EarthRateTable
    model: NoiseModelSummary
    candidates: list[NoiseCandidate]
    degenerate: list[list[str]]


@dataclass(frozen=True)
class NoiseRecord:
    """What `sofia noise` reads from a bag: GYRF rates at the read-out rate, the case and the TA configuration."""

    bag_path: Path
    rates_arcsec_per_s: np.ndarray
    #: the /config/case document (case, description, latitude_deg, heading_deg, elevation_deg, ...)
    case: dict[str, Any]
    #: Table 5.2 subsystem -> state, as last recorded; None if the bag has none
    subsystems: dict[str, str] | None


@dataclass(frozen=True)
class NoiseAnalysis:
    """The JSON document and the arrays the report plots."""

    document: NoiseDocument
    sample_rate_hz: float
    noise_arcsec_per_s: np.ndarray
    curves: tuple[AllanCurve, ...]
    fits: tuple[NoiseFit, ...]
    freq_hz: np.ndarray
    psd: np.ndarray
    segment_samples: int
    measured: MeasuredNoise
    base: BaseFit
    effects: Effects


def checked_decimation(decimate: int | str) -> int:
    """The --decimate factor as an int >= 1, or InvalidArgumentError naming the fix.

    Args:
        decimate: the factor as given (a number or the option's text).

    Returns:
        The factor as an int >= 1.

    Raises:
        InvalidArgumentError: not a whole number, or below 1.
    """
    try:
        factor = int(str(decimate))
    except ValueError as err:
        raise InvalidArgumentError(
            f'--decimate must be a whole number of read-out samples (>= 1), got {decimate!r}') from err
    if factor < 1:
        raise InvalidArgumentError(f'--decimate must be >= 1 (1 keeps every 400 Hz sample), got {factor}')
    return factor


def integrated_angle_arcsec(noise_arcsec_per_s: np.ndarray, sample_rate_hz: float) -> np.ndarray:
    """Mean-removed rate summed into angle, the angular error of Figs. 5.8-5.9 (5.2.4).

    Args:
        noise_arcsec_per_s: (N, 3) rates [arcsec/s].
        sample_rate_hz: their sample rate [Hz].

    Returns:
        (N, 3) angles [arcsec], the mean rate removed first.
    """
    return np.cumsum(noise_arcsec_per_s - noise_arcsec_per_s.mean(axis=0), axis=0) / sample_rate_hz


def load_noise_record(bag_path: str | PathLike[str], imu_topic: str = GYRO_IMU.name) -> NoiseRecord:
    """Read a gyro-stability bag: /gyro_box/imu, /config/case and, if recorded, /ta/subsystem_status.

    Args:
        bag_path: the bag of a gyro-stability run.
        imu_topic: the IMU topic to read the rates from.

    Returns:
        The GYRF rates [arcsec/s], the case document and the last subsystem states (None if not recorded).

    Raises:
        BagError: the bag lacks the IMU topic or /config/case (or cannot be read).
    """
    with BagReader(bag_path) as bag:
        names = {topic.name for topic in bag.topics}
        if imu_topic not in names:
            raise BagError(f'{bag_path} has no {imu_topic}; record a gyro-stability campaign first')
        if CASE_DOCUMENT.name not in names:
            raise BagError(f'{bag_path} has no {CASE_DOCUMENT.name}; '
                           '`sofia noise` reads the geometry of a gyro-stability run')
        case = yaml.safe_load(bag.document(CASE_DOCUMENT.name))
        subsystems = None
        if SUBSYSTEM_STATUS.name in names:
            for _, _, message in bag.messages(SUBSYSTEM_STATUS.name):
                subsystems = {value.key: value.value for value in message.values}
        imu = bag.imu_arrays(imu_topic)
    return NoiseRecord(Path(bag_path), imu.angular_velocity_rad_per_s / RAD_PER_ARCSEC, case, subsystems)


def _decimated_arw(fit, sample_rate_hz, quantization_arcsec):
    """(read-out ARW, its sigma) of a decimated record's fit (noise.fit.arw_of_decimated_record)."""
    arw = float(arw_of_decimated_record(fit.arw_arcsec_per_sqrt_s, sample_rate_hz, quantization_arcsec))
    # dN/dN_sampled = N_sampled (f_sampled / f_read-out) / N
    slope = fit.arw_arcsec_per_sqrt_s * sample_rate_hz / GYRO_SAMPLE_RATE_HZ / arw if arw > 0.0 else np.inf
    return arw, float(fit.arw_sigma_arcsec_per_sqrt_s * slope)


def _axis_document(curve: AllanCurve, fit: NoiseFit, lines: list[SpectralLine], angle_max_arcsec: float,
                   sample_rate_hz: float, quantization_arcsec: float) -> AxisNoise:
    stability = bias_stability(curve, BIAS_STABILITY_MAX_SIGMA_REL)
    # Table 5.8 reads the minimum where the curve turns up again: resolved when a readable point after
    # it stands 2 sigma (4.25) above it; else the value is an upper bound (TC-4: "no statement possible").
    after = (curve.sigma_rel <= BIAS_STABILITY_MAX_SIGMA_REL) & (curve.tau_s > stability.tau_s)
    rise = curve.adev[after] - stability.bias_stability_arcsec_per_s
    document: AxisNoise = {
        'arw_arcsec_per_sqrt_s': fit.arw_arcsec_per_sqrt_s, 'arw_sigma': fit.arw_sigma_arcsec_per_sqrt_s,
        'bias_stability_arcsec_per_s': stability.bias_stability_arcsec_per_s,
        'bias_stability_sigma': stability.sigma_arcsec_per_s,
        'bias_stability_tau_s': stability.tau_s,
        'bias_stability_resolved': bool(np.any(rise > 2.0 * curve.sigma_rel[after] * curve.adev[after])),
        'rrw_arcsec_per_s_sqrt_s': fit.rrw_arcsec_per_s_sqrt_s, 'rrw_sigma': fit.rrw_sigma_arcsec_per_s_sqrt_s,
        'quantization_arcsec': fit.quantization_arcsec, 'quantization_sigma': fit.quantization_sigma_arcsec,
        'bias_instability_arcsec_per_s': fit.bias_instability_arcsec_per_s,
        'bias_instability_sigma': fit.bias_instability_sigma_arcsec_per_s,
        'rate_ramp_arcsec_per_s2': fit.rate_ramp_arcsec_per_s2, 'rate_ramp_sigma': fit.rate_ramp_sigma_arcsec_per_s2,
        'integrated_angle_max_arcsec': angle_max_arcsec,
        'lines': [{'freq_hz': line.freq_hz, 'amplitude_arcsec_per_s': line.amplitude_arcsec_per_s,
                   'source': line.source} for line in lines],
    }
    if sample_rate_hz < GYRO_SAMPLE_RATE_HZ:
        document['arw_sampled_arcsec_per_sqrt_s'] = fit.arw_arcsec_per_sqrt_s
        document['arw_arcsec_per_sqrt_s'], document['arw_sigma'] = _decimated_arw(fit, sample_rate_hz,
                                                                                   quantization_arcsec)
    return document


def _degenerate_pairs(candidates: list[NoiseCandidate]) -> list[list[str]]:
    pairs = [list(DEGENERATE_PAIR)]
    for candidate in candidates:
        for other in candidate['degenerate_with']:
            pair = sorted((candidate['label'], other))
            if pair not in pairs:
                pairs.append(pair)
    return pairs


def analyze_record(record: NoiseRecord, *, model: EffectConfig | None = None,
                   decimate: int | str = 1) -> NoiseAnalysis:
    """The `sofia noise` analysis of a record against a noise model (an EffectConfig, or None for none).

    Args:
        record: the record read by load_noise_record.
        model: the noise model; None for no effects.
        decimate: keep every k-th sample (4.2.5), k >= 1.

    Returns:
        The `sofia noise --json` document and the arrays the report plots.

    Raises:
        InvalidArgumentError: a bad factor, or fewer than MIN_SAMPLES samples after decimation.
        ConfigError: a model that cannot predict noise (noise.predict.check_noise_model).
    """
    factor = checked_decimation(decimate)
    effects = dict(model.effects) if model is not None else {}
    check_noise_model(effects)
    sample_rate_hz = GYRO_SAMPLE_RATE_HZ / factor
    rates = np.ascontiguousarray(record.rates_arcsec_per_s[::factor])
    if len(rates) < MIN_SAMPLES:
        hint = 'use a smaller --decimate' if factor > 1 else 'record a longer run'
        raise InvalidArgumentError(f'{record.bag_path}: {len(rates)} samples at {sample_rate_hz:g} Hz; the analysis '
                                   f'needs at least {MIN_SAMPLES} ({hint})')
    case = record.case
    tarf_from_gyrf = tarf_from_gyrf_dcm(effects) if 'gyro_misalignment' in effects else None
    # arcsec/s and deg/h are the same number (3600 / 3600).
    earth = earth_rate_table(rates.mean(axis=0), case['latitude_deg'], case['heading_deg'], case['elevation_deg'],
                             tarf_from_gyrf)
    # Noise about the mean rate: Earth rate and the constant biases are not noise (5.2.6).
    noise = rates - rates.mean(axis=0)
    curves = overlapping_allan_deviation(noise, sample_rate_hz, log_spaced_cluster_sizes(len(noise), _N_TAUS))
    segment = welch_segment_samples(len(noise))
    freq_hz, psd = welch_rate_psd(noise, sample_rate_hz, segment_samples=segment, fft_points=4 * segment)
    angle_max = np.abs(integrated_angle_arcsec(noise, sample_rate_hz)).max(axis=0)
    quantization = effects['gyro_noise']['quantization_arcsec'] if effects.get('gyro_noise') else QUANTIZATION_ARCSEC
    dof = welch_equivalent_dof(len(noise), segment)
    silent = silent_sources(record.subsystems)
    lines = [find_lines(freq_hz, psd[:, index], dof, sample_rate_hz=sample_rate_hz, silent=silent)
             for index in range(3)]
    fits = tuple(fit_noise_model(curve, lines_hz=[line.freq_hz for line in axis_lines], sample_rate_hz=sample_rate_hz)
                 for curve, axis_lines in zip(curves, lines))
    axes = {axis: _axis_document(curve, fit, axis_lines, float(angle_max[index]), sample_rate_hz, quantization)
            for index, (axis, curve, fit, axis_lines) in enumerate(zip(AXES, curves, fits, lines))}
    measured = measured_noise(curves, freq_hz, psd, sample_rate_hz=sample_rate_hz,
                              readout_rate_hz=GYRO_SAMPLE_RATE_HZ, segment_samples=segment, n_samples=len(noise))
    base = fit_base(measured, effects)
    candidates = rank_missing_terms(measured, base, effects, silent)
    document: NoiseDocument = {
        'bag': str(record.bag_path), 'case': case.get('case'), 'description': case.get('description'),
        'samples_per_axis': int(len(noise)), 'record_s': len(noise) / sample_rate_hz,
        'sample_rate_hz': sample_rate_hz, 'readout_rate_hz': GYRO_SAMPLE_RATE_HZ, 'decimation': factor,
        'subsystems': record.subsystems,
        'axes': axes,
        'earth_rate_deg_per_h': earth,
        'model': {
            'path': None if model is None else model.source,
            'effects': sorted(effects),
            'arw_refit_arcsec_per_sqrt_s': dict(zip(AXES, map(float, base.arw_readout_arcsec_per_sqrt_s))),
            'residual': residual_summary(measured, base.av, base.psd),
        },
        'candidates': candidates,
        'degenerate': _degenerate_pairs(candidates),
    }
    return NoiseAnalysis(document, sample_rate_hz, noise, curves, fits, freq_hz, psd, segment, measured, base, effects)


def analyze_noise(bag_path: str | PathLike[str], *, model: EffectConfig | None = None, decimate: int | str = 1,
                  imu_topic: str = GYRO_IMU.name) -> NoiseDocument:
    """The `sofia noise --json` document of a bag (docs/noise.md).

    Args:
        bag_path: the bag of a gyro-stability run.
        model: the noise model; None for no effects.
        decimate: keep every k-th sample (4.2.5), k >= 1.
        imu_topic: the IMU topic to read the rates from.

    Returns:
        The document.

    Raises:
        BagError: the bag lacks a topic the analysis reads.
        InvalidArgumentError: a bad factor or a record too short.
        ConfigError: a model that cannot predict noise.
    """
    return analyze_record(load_noise_record(bag_path, imu_topic), model=model, decimate=decimate).document
