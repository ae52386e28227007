"""The noise-model loop (docs/noise.md, thesis 4.2, 5.2): a noise model against a record, missing terms ranked.

A noise model is an effects file with the schema of a truth (docs/effects.md). Per gyro axis it predicts
the Allan variance and the Welch PSD of the mean-removed rate:

- ``gyro_noise``: quantization 4.13 / 4.11, ARW 4.16 / 4.14, bias instability 4.18 (corrected, see
  noise.fit) / 4.17, RRW 4.20 / 4.19, the same on every axis as the truth simulator applies them;
- ``gyro_bias_drift``: the rate ramp per axis, 4.22 / 4.21;
- ``vibration_lines`` and ``los_oscillation`` (rate amplitude 2 pi A / T): the AV of a sampled
  sinusoid (4.6-4.7, noise.fit.sinusoid_adev) and the expected Welch estimate of a line
  (spectra.welch_sinusoid_psd, aliases included);
- other effects (bias, misalignment, scale factor) are constant rates: the mean removes them.

Decimated records (every k-th read-out, 4.2.5): white noise keeps its per-sample variance, so the
ARW terms are k times larger in AV and PSD (the inverse of 4.27-4.29), and quantization, blue at
the read-out rate (4.11), becomes white (noise.fit.decimated_quantization_variance).

Residual, weighted so that each row has about unit variance and correlated rows count once:
ln(measured / predicted root AV) at the curve's taus with the 4.25 error, times the square root of
the local points per octave (neighbouring taus share their clusters); and ln(measured / predicted
PSD) at the Welch segment resolution from 8 bins up (below, leakage of steep spectra and of the
per-segment mean removal would need a window model), less the chi-square log bias, with its
chi-square scatter times the square root of the bins one Hamming bin correlates with.

Base: the model with the white level (ARW) refitted per axis, since Table 5.8 finds it changes
with the configuration; the remaining misfit is then never blamed on a missing term.

Missing terms, each refined by nonlinear least squares on the same weighted residual before
ranking (analysis.ranking, linearized at the refined values by central differences):
residual PSD peaks as ``vibration_lines`` (frequency from the peak, named from Tables 5.4/5.5),
fitted on the PSD rows around them (the shortest taus hold every line and every unmodelled
high-frequency term at once, which would bias a line's amplitude; its AV is predicted once added);
a slow sinusoid per axis found by a period scan of the log-Allan residual (``los_oscillation``
on LOS, a slow ``vibration_lines`` entry on EL and XEL); and, where the model has them at zero,
quantization, bias instability and RRW (``gyro_noise``, shared by the axes like the effect) and
the rate ramp of each axis (``gyro_bias_drift``), fitted as AV coefficients so that "absent" is a
value the linearization can stand on.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TypedDict

import numpy as np
from scipy import optimize, signal

from sofia_ros.analysis.allan import arw_corrected_for_sampling
from sofia_ros.analysis.lines import likely_source
from sofia_ros.analysis.ranking import CandidateTerm, rank_candidates
from sofia_ros.analysis.spectra import welch_sinusoid_psd
from sofia_ros.effects import resolve_params
from sofia_ros.effects.base import EffectParams, Effects
from sofia_ros.errors import ConfigError
from sofia_ros.frames import AXES
from sofia_ros.noise.fit import (
    BIAS_INSTABILITY_PLATEAU,
    bias_instability_psd,
    quantization_psd,
    rate_ramp_psd,
    rrw_psd,
    sinusoid_adev,
)
from sofia_ros.noise.measure import MeasuredNoise
from sofia_ros.noise.predict import model_lines, predicted_noise
from sofia_ros.sensors.gyro_noise import (
    rate_ramp_arcsec_per_s2_to_deg_per_h2,
    rrw_arcsec_per_s_sqrt_s_to_deg_per_h_sqrt_h,
)

__all__ = [
    'BaseFit',
    'fit_base',
    'rank_missing_terms',
    'residual_summary',
    'model_with_candidate',
    'NoiseCandidate',
    'ResidualSummary',
    'AxisRms',
]

#: A residual PSD peak is a line candidate when it stands this many chi-square sigmas above the model
#: and above its surroundings (noise alone reaches ~5 sigma in 10^7 bins at the 13 dof of 3 minutes).
_PEAK_SIGMAS = 6.0
_PEAKS_PER_AXIS = 5
#: A peak within this many segment bins of a model line on the same axis belongs to that line.
_MODEL_LINE_GUARD_BINS = 3
#: A candidate line is evaluated on the PSD rows this many segment bins around it: the Hamming side
#: lobes fall from -43 dB by 6 dB per octave, to about -67 dB here.
_LINE_WINDOW_BINS = 40
_PERIOD_GRID = 80
#: A fitted period within this fraction of a bound counts as pinned there.
_PINNED = 1e-3
_JACOBIAN_STEP = 1e-4
_DEFAULT_BI_CUTOFF_HZ = 10.0


class AxisRms(TypedDict):
    """RMS of ln(measured / predicted) per axis and over all three."""

    el: float
    xel: float
    los: float
    all: float


class ResidualSummary(TypedDict):
    """The model's residual (the model.residual object of `sofia noise --json`, docs/noise.md)."""

    allan_rms_ln: AxisRms
    psd_rms_ln: AxisRms
    chi2_per_point: float
    points: int


class _LineSource(TypedDict, total=False):
    # A base of its own: NotRequired is not seen at run time under `from __future__ import annotations` (3.11).
    #: the likely source of a line (Tables 5.4, 5.5), where the term is a line
    source: str


class NoiseCandidate(_LineSource):
    """A missing term (one entry of the candidates of `sofia noise --json`, docs/noise.md)."""

    effect: str
    term: str
    #: None for a term shared by the axes (gyro_noise)
    axis: str | None
    label: str
    delta_bic: float
    params: dict[str, float]
    sigma: dict[str, float]
    significant: bool
    observable: bool
    degenerate_with: list[str]


def _linear(av, psd):
    """A prediction as one vector along the residual rows (AV and PSD in linear units)."""
    return np.concatenate([av.ravel(), psd.ravel()])


def _weighted_residual(measured, linear, rows=slice(None)):
    """Rows of (measured - predicted) / error in log space, for a prediction in linear units on those rows."""
    predicted = measured.log_factor[rows] * np.log(np.maximum(linear, np.finfo(float).tiny))
    return measured.weights[rows] * (measured.log_values[rows] - predicted)


@dataclass(frozen=True)
class BaseFit:
    """The model with its white level refitted per axis: prediction, weighted residual and its Jacobian."""

    av: np.ndarray
    psd: np.ndarray
    white_level: np.ndarray
    white_linear: np.ndarray
    arw_readout_arcsec_per_sqrt_s: np.ndarray
    residual: np.ndarray
    jacobian: np.ndarray

    @property
    def linear(self) -> np.ndarray:
        """The prediction along the residual rows."""
        return _linear(self.av, self.psd)


def fit_base(measured: MeasuredNoise, effects: Mapping[str, EffectParams]) -> BaseFit:
    """Refit the per-axis white level (AV a / tau, PSD 2 a) of the model to the record (module docstring).

    Args:
        measured: the record on the loop's grid.
        effects: the noise model, effect name -> parameters.

    Returns:
        The refitted prediction, white levels, the read-out ARW per axis, the weighted residual and its Jacobian
        in the log white levels.
    """
    grid = measured.grid
    rest_av, rest_psd = predicted_noise(effects, grid, include_arw=False)
    white_av, white_psd = 1.0 / grid.tau_s, np.full(grid.freq_hz.shape, 2.0)

    def prediction(log_level):
        level = np.exp(log_level)[:, np.newaxis]
        return rest_av + level * white_av, rest_psd + level * white_psd

    def residual(log_level):
        return _weighted_residual(measured, _linear(*prediction(log_level)))

    start = np.log(np.median(measured.psd, axis=1) / 2.0)
    solution = optimize.least_squares(residual, start, method='lm', x_scale=1.0)
    jacobian = -_central_jacobian(residual, solution.x, np.full(3, _JACOBIAN_STEP))
    level = np.exp(solution.x)
    # The white level a is N_sampled^2 (4.16); 4.27 carries it to the read-out rate. Decimated
    # quantization is a separate white term of the model here, so a holds the ARW alone.
    arw_readout = arw_corrected_for_sampling(np.sqrt(level), grid.sample_rate_hz, grid.readout_rate_hz)
    white = _linear(level[:, np.newaxis] * white_av, level[:, np.newaxis] * white_psd)
    return BaseFit(*prediction(solution.x), level, white, arw_readout, residual(solution.x), jacobian)


def _central_jacobian(function, values, steps):
    """d function / d values by central differences."""
    columns = []
    for index, step in enumerate(steps):
        delta = np.zeros_like(values, dtype=float)
        delta[index] = step
        columns.append((function(values + delta) - function(values - delta)) / (2.0 * step))
    return np.column_stack(columns)


def residual_summary(measured: MeasuredNoise, av: np.ndarray, psd: np.ndarray) -> ResidualSummary:
    """RMS of ln(measured / predicted) per axis for root AV and PSD, and the weighted chi^2 per row.

    Args:
        measured: the record on the loop's grid.
        av: the predicted AV, (3, n_tau) [(arcsec/s)^2].
        psd: the predicted PSD, (3, n_freq) [(arcsec/s)^2/Hz].

    Returns:
        The RMS per axis and over all axes, the weighted chi^2 per row and the number of rows.
    """
    allan = np.log(measured.adev) - 0.5 * np.log(av)
    spectrum = np.log(measured.psd) - np.log(psd) - measured.psd_log_bias
    weighted = _weighted_residual(measured, _linear(av, psd))

    def rms(values: np.ndarray) -> AxisRms:
        return {**{axis: float(np.sqrt(np.mean(row**2))) for axis, row in zip(AXES, values)},
                'all': float(np.sqrt(np.mean(values**2)))}

    return {'allan_rms_ln': rms(allan), 'psd_rms_ln': rms(spectrum),
            'chi2_per_point': float(np.mean(weighted**2)), 'points': int(weighted.size)}


@dataclass(frozen=True)
class _Proposal:
    """A missing term before ranking: fit-space parameters, bounds, scale, and its contribution on its rows."""

    label: str
    effect: str
    term: str
    axis: str | None
    names: tuple[str, ...]
    start: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    scale: np.ndarray
    rows: np.ndarray
    #: fit-space values -> the term's linear AV/PSD on its rows
    contribution: Callable[[np.ndarray], np.ndarray]
    #: (values, sigmas) -> (params, sigma) of the candidate entry
    report: Callable[[np.ndarray, np.ndarray], tuple[dict[str, float], dict[str, float]]]
    source: str | None = None


def _candidate_term(proposal, measured, base):
    """Refine a proposal on its rows with the white level of its axes, then linearize it for rank_candidates."""
    # rank_candidates fits the candidate jointly with the base terms (the white levels); refining it
    # alone against fixed levels would leave the joint optimum a long, nonlinear step away.
    rows, base_linear, white = proposal.rows, base.linear[proposal.rows], base.white_linear[proposal.rows]
    axes, position = np.unique(measured.row_axis[rows], return_inverse=True)
    count = proposal.start.size

    def joint(parameters):
        level_change = np.expm1(parameters[count:])[position] * white
        return _weighted_residual(measured, base_linear + level_change + proposal.contribution(parameters[:count]),
                                  rows)

    def residual(values):
        return _weighted_residual(measured, base_linear + proposal.contribution(values), rows)

    free = np.full(axes.size, np.inf)
    start = np.concatenate([np.clip(proposal.start, proposal.lower, proposal.upper), np.zeros(axes.size)])
    values = optimize.least_squares(joint, start, bounds=(np.concatenate([proposal.lower, -free]),
                                                          np.concatenate([proposal.upper, free])),
                                    x_scale=np.concatenate([proposal.scale, np.full(axes.size, 0.01)]),
                                    diff_step=_JACOBIAN_STEP).x[:count]
    steps = _JACOBIAN_STEP * np.maximum(np.abs(values), proposal.scale)
    jacobian = np.zeros((measured.log_values.size, values.size))
    jacobian[rows] = -_central_jacobian(residual, values, steps)
    shift = np.zeros(measured.log_values.size)
    shift[rows] = base.residual[rows] - residual(values)
    return values, CandidateTerm(proposal.label, proposal.names, values, jacobian=jacobian, shift=shift)


def _line_proposals(measured, base, effects, silent):
    """Residual PSD peaks, per axis, not at a model line: vibration_lines with frequency and amplitude."""
    grid = measured.grid
    bin_hz = grid.sample_rate_hz / grid.segment_samples
    z_scores = (np.log(measured.psd) - np.log(base.psd) - measured.psd_log_bias) / measured.peak_sigma_ln
    model_alias_hz = [(_alias_hz(f, grid.sample_rate_hz), index) for f, _, index in model_lines(effects)]
    proposals = []
    for index in range(3):
        peaks, properties = signal.find_peaks(z_scores[index], height=_PEAK_SIGMAS, prominence=_PEAK_SIGMAS)
        order = np.argsort(properties['peak_heights'])[::-1]
        kept = 0
        for peak in peaks[order]:
            frequency = grid.freq_hz[peak]
            if any(line_index == index and abs(frequency - alias) <= _MODEL_LINE_GUARD_BINS * bin_hz
                   for alias, line_index in model_alias_hz):
                continue
            proposals.append(_line_proposal(measured, base, index, frequency, bin_hz, silent))
            kept += 1
            if kept == _PEAKS_PER_AXIS:
                break
    return proposals


def _alias_hz(frequency_hz, sample_rate_hz):
    """Where a line lands after sampling at sample_rate_hz, in [0, fs/2] (Tables 5.4, 5.5 note)."""
    folded = np.mod(frequency_hz, sample_rate_hz)
    return float(min(folded, sample_rate_hz - folded))


def _line_proposal(measured, base, index, frequency_hz, bin_hz, silent):
    """A line at a residual PSD peak: frequency from the fine Welch grid (parabola in ln PSD), power in excess."""
    grid, fine_hz, fine_psd = measured.grid, measured.fine_freq_hz, measured.fine_psd[index]
    near = np.flatnonzero(np.abs(fine_hz - frequency_hz) <= 2.0 * bin_hz)
    top = int(np.clip(near[np.argmax(fine_psd[near])], 1, fine_hz.size - 2))
    left, centre, right = np.log(fine_psd[top - 1:top + 2])
    curvature = left - 2.0 * centre + right
    offset = float(np.clip(0.5 * (left - right) / curvature, -0.5, 0.5)) if curvature < 0.0 else 0.0
    peak_hz = float(fine_hz[top] + offset * (fine_hz[1] - fine_hz[0]))
    background = np.interp(fine_hz[near], grid.freq_hz, base.psd[index])
    excess = max(float(np.sum(fine_psd[near] - background) * (fine_hz[1] - fine_hz[0])), 0.0)
    amplitude = np.sqrt(2.0 * excess)
    window = np.abs(grid.freq_hz - peak_hz) <= _LINE_WINDOW_BINS * bin_hz
    freq_hz = grid.freq_hz[window]
    rows = measured.psd_rows(index, window)

    def contribution(values):
        return welch_sinusoid_psd(freq_hz, values[1], values[0], grid.sample_rate_hz, grid.segment_samples)

    def report(values, sigmas):
        return ({'frequency_hz': float(values[0]), 'amplitude_arcsec_per_s': float(abs(values[1]))},
                {'frequency_hz': float(sigmas[0]), 'amplitude_arcsec_per_s': float(sigmas[1])})

    axis = AXES[index]
    return _Proposal(f'vibration_lines {axis} {peak_hz:.2f} Hz', 'vibration_lines', 'line', axis,
                     ('frequency_hz', 'amplitude_arcsec_per_s'), np.array([peak_hz, amplitude]),
                     np.array([peak_hz - bin_hz, 0.0]), np.array([peak_hz + bin_hz, np.inf]),
                     np.array([bin_hz / 10.0, max(amplitude, 1e-6)]), rows, contribution, report,
                     likely_source(peak_hz, grid.sample_rate_hz, silent))


def _slow_sinusoid_proposals(measured, base, effects, silent):
    """Per axis, the sinusoid below the PSD rows that best explains the log-Allan residual (period scan)."""
    grid = measured.grid
    shortest_s = 1.0 / grid.freq_hz[0]
    if grid.record_s <= shortest_s:
        return []
    periods_s = np.geomspace(shortest_s, grid.record_s, _PERIOD_GRID)
    proposals = []
    for index, axis in enumerate(AXES):
        rate_amplitude, period_s = _period_scan(measured, base, index, periods_s)
        if rate_amplitude == 0.0:
            continue
        effect = 'los_oscillation' if axis == 'los' and not effects.get('los_oscillation') else 'vibration_lines'
        proposals.append(_slow_proposal(measured, index, period_s, rate_amplitude, effect, silent))
    return proposals


def _period_scan(measured, base, index, periods_s):
    """(rate amplitude, period) of the sinusoid whose AV best fills the axis's log-Allan residual, or (0, 0)."""
    grid = measured.grid
    weights = 1.0 / measured.allan_sigma_ln
    target = np.log(measured.adev[index])
    base_av = base.av[index]
    best = (float(np.sum((weights * (target - 0.5 * np.log(base_av))) ** 2)), 0.0, 0.0)
    for period_s in periods_s:
        shape = sinusoid_adev(grid.tau_s, 1.0, 1.0 / period_s, grid.sample_rate_hz) ** 2
        useful = shape > 0.0
        if not np.any(useful):
            continue
        reference = np.min(base_av[useful] / shape[useful])
        powers = reference * np.geomspace(1e-4, 1e6, 101)
        predicted = 0.5 * np.log(base_av + powers[:, np.newaxis] * shape)
        costs = np.sum((weights * (target - predicted)) ** 2, axis=1)
        choice = int(np.argmin(costs))
        if costs[choice] < best[0]:
            best = (float(costs[choice]), float(np.sqrt(powers[choice])), float(period_s))
    return best[1], best[2]


def _slow_proposal(measured, index, period_s, rate_amplitude, effect, silent):
    """A slow sinusoid in fit space (period s, integrated-angle amplitude arcsec) on the axis's AV rows."""
    grid, axis = measured.grid, AXES[index]
    angle_amplitude = rate_amplitude * period_s / (2.0 * np.pi)

    def contribution(values):
        rate = 2.0 * np.pi * values[1] / values[0]
        return sinusoid_adev(grid.tau_s, rate, 1.0 / values[0], grid.sample_rate_hz) ** 2

    if effect == 'los_oscillation':
        def report(values, sigmas):
            return ({'period_s': float(values[0]), 'amplitude_arcsec': float(abs(values[1]))},
                    {'period_s': float(sigmas[0]), 'amplitude_arcsec': float(sigmas[1])})
        label, source = 'los_oscillation los', 'LOS oscillation (5.2.4, about 20 min)'
    else:
        def report(values, sigmas):
            period, angle = values
            rate = 2.0 * np.pi * abs(angle) / period
            rate_sigma = 2.0 * np.pi * np.hypot(sigmas[1] / period, angle * sigmas[0] / period**2)
            return ({'frequency_hz': float(1.0 / period), 'amplitude_arcsec_per_s': float(rate)},
                    {'frequency_hz': float(sigmas[0] / period**2), 'amplitude_arcsec_per_s': float(rate_sigma)})
        label = f'vibration_lines {axis} slow sinusoid'
        source = likely_source(1.0 / period_s, grid.sample_rate_hz, silent)
    return _Proposal(label, effect, 'slow sinusoid', axis, ('period_s', 'amplitude_arcsec'),
                     np.array([period_s, angle_amplitude]), np.array([1.0 / grid.freq_hz[0], 0.0]),
                     np.array([grid.record_s, np.inf]), np.array([period_s / 100.0, max(angle_amplitude, 1e-6)]),
                     measured.allan_rows(index), contribution, report, source)


def _coefficient_report(names, to_physical):
    """Report of terms fitted as AV coefficients c: the value at max(c, 0), sigma half the mapped 1-sigma interval."""
    def report(values, sigmas):
        params, sigma = {}, {}
        for name, value, error in zip(names, values, sigmas):
            low, high = to_physical(max(value - error, 0.0)), to_physical(max(value + error, 0.0))
            params[name], sigma[name] = to_physical(max(value, 0.0)), 0.5 * (high - low)
        return params, sigma
    return report


def _noise_term_proposals(measured, base, effects):
    """gyro_noise terms the model holds at zero, and each axis's rate ramp if gyro_bias_drift is absent."""
    grid, tau, freq = measured.grid, measured.grid.tau_s, measured.grid.freq_hz
    noise = effects.get('gyro_noise')
    cutoff_hz = noise['bias_instability_cutoff_hz'] if noise else _DEFAULT_BI_CUTOFF_HZ
    terms = [  # (term, parameter, AV shape, PSD per unit AV coefficient, coefficient -> parameter)
        ('bias_instability', 'bias_instability_deg_per_h', np.ones_like(tau),
         bias_instability_psd(freq, 1.0, cutoff_hz) / BIAS_INSTABILITY_PLATEAU**2,
         lambda c: float(np.sqrt(c) / BIAS_INSTABILITY_PLATEAU)),  # arcsec/s is deg/h numerically
        ('rrw', 'rrw_deg_per_h_sqrt_h', tau, 3.0 * rrw_psd(freq, 1.0),
         lambda c: float(rrw_arcsec_per_s_sqrt_s_to_deg_per_h_sqrt_h(np.sqrt(3.0 * c)))),
    ]
    if grid.decimation == 1.0:  # decimated, quantization is white: the refitted ARW holds it (module docstring)
        terms.insert(0, ('quantization', 'quantization_arcsec', tau**-2.0,
                         4.0 * quantization_psd(freq, 1.0, grid.sample_rate_hz), lambda c: float(2.0 * np.sqrt(c))))
    proposals = []
    for term, parameter, av_shape, psd_shape, to_physical in terms:
        if noise and noise[parameter] > 0.0:
            continue
        shape = np.concatenate([np.tile(av_shape, 3), np.tile(psd_shape, 3)])[np.newaxis]
        proposals.append(_coefficient_proposal(measured, base, f'gyro_noise {term}', 'gyro_noise', term, None,
                                               np.arange(shape.shape[1]), shape,
                                               _coefficient_report((parameter,), to_physical)))
    if not effects.get('gyro_bias_drift'):
        # One candidate per axis: the gyros drift independently (Table 5.1: 0.0008 to 0.01224 deg/h^2).
        shape = np.concatenate([tau**2, 2.0 * rate_ramp_psd(freq, 1.0)])[np.newaxis]
        for index, axis in enumerate(AXES):
            report = _coefficient_report((f'{axis}_deg_per_h2',),
                                         lambda c: float(rate_ramp_arcsec_per_s2_to_deg_per_h2(np.sqrt(2.0 * c))))
            rows = np.concatenate([measured.allan_rows(index), measured.psd_rows(index)])
            proposals.append(_coefficient_proposal(measured, base, f'gyro_bias_drift {axis}', 'gyro_bias_drift',
                                                   'rate ramp', axis, rows, shape, report))
    return proposals


def _coefficient_proposal(measured, base, label, effect, term, axis, rows, shapes, report):
    """Terms linear in AV coefficients c >= 0 (one shape row each); started from the linearized fit at c = 0."""
    base_linear = base.linear[rows]
    allan = measured.log_factor[rows] == 0.5
    scales = np.array([np.min(base_linear[allan][shape[allan] > 0.0] / shape[allan][shape[allan] > 0.0])
                       for shape in shapes])
    # ln AV moves by c shape / AV for small c: weighted linear least squares on the AV rows.
    weights = measured.weights[rows][allan]
    excess = np.exp(2.0 * measured.log_values[rows][allan]) / base_linear[allan] - 1.0
    design = (shapes[:, allan] / base_linear[allan]).T * weights[:, np.newaxis]
    start = np.maximum(np.linalg.lstsq(design, excess * weights, rcond=None)[0], 1e-6 * scales)
    names = tuple(f'{term.replace(" ", "_")}_av_coefficient_{index}' for index in range(len(shapes)))

    def contribution(values):
        return values @ shapes

    return _Proposal(label, effect, term, axis, names, start,
                     np.zeros(len(shapes)), np.full(len(shapes), np.inf), scales, rows, contribution, report)


def rank_missing_terms(measured: MeasuredNoise, base: BaseFit, effects: Mapping[str, EffectParams],
                       silent: frozenset[str] = frozenset()) -> list[NoiseCandidate]:
    """Candidates (docs/noise.md `candidates`), best first, by ranking.rank_candidates; silent sources not named.

    Args:
        measured: the record on the loop's grid.
        base: the model with its white levels refitted (fit_base).
        effects: the noise model, effect name -> parameters.
        silent: line sources the record's subsystem states rule out (analysis.lines.silent_sources).

    Returns:
        The candidates that survived refinement, best delta-BIC first.
    """
    proposals = (_line_proposals(measured, base, effects, silent)
                 + _slow_sinusoid_proposals(measured, base, effects, silent)
                 + _noise_term_proposals(measured, base, effects))
    terms, kept = [], {}
    for proposal in proposals:
        values, term = _candidate_term(proposal, measured, base)
        if proposal.term in ('line', 'slow sinusoid') and values[1] <= 0.0:
            continue  # the peak was noise: a zero-amplitude line has no frequency to report
        if proposal.term == 'slow sinusoid' and not (
                proposal.lower[0] * (1.0 + _PINNED) < values[0] < proposal.upper[0] * (1.0 - _PINNED)):
            continue  # pinned at a period bound (bounded fits stop just inside): a PSD-band line or a ramp
        terms.append(term)
        kept[proposal.label] = proposal
    candidates = []
    for candidate in rank_candidates(base.residual, base.jacobian, terms):
        proposal = kept[candidate.name]
        params, sigma = proposal.report(np.array([candidate.params[n] for n in proposal.names]),
                                        np.array([candidate.sigma[n] for n in proposal.names]))
        entry: NoiseCandidate = {'effect': proposal.effect, 'term': proposal.term, 'axis': proposal.axis, 'label': candidate.name,
                 'delta_bic': float(candidate.delta_bic), 'params': params, 'sigma': sigma,
                 'significant': bool(candidate.significant), 'observable': bool(candidate.observable),
                 'degenerate_with': list(candidate.degenerate_with)}
        if proposal.source is not None:
            entry['source'] = proposal.source
        candidates.append(entry)
    return candidates


def model_with_candidate(effects: Mapping[str, EffectParams], candidate: NoiseCandidate) -> Effects:
    """The model's effects with a `candidates` entry added as a term (what `sofia model add` would write).

    Args:
        effects: the noise model, effect name -> parameters.
        candidate: one entry of rank_missing_terms (or of the JSON's candidates).

    Returns:
        A new model with the term added (a line appended, a gyro_noise or drift parameter set).

    Raises:
        ConfigError: a candidate of an effect the noise loop does not add, or parameters the effect refuses.
    """
    updated = {name: dict(params) for name, params in effects.items()}
    effect, params = candidate['effect'], candidate['params']
    if effect == 'vibration_lines':
        lines = updated.get('vibration_lines') or {'frequencies_hz': [], 'amplitudes_arcsec_per_s': [], 'axes': []}
        updated['vibration_lines'] = {
            'frequencies_hz': [*lines['frequencies_hz'], params['frequency_hz']],
            'amplitudes_arcsec_per_s': [*lines['amplitudes_arcsec_per_s'], params['amplitude_arcsec_per_s']],
            'axes': [*lines['axes'], candidate['axis']]}
    elif effect == 'los_oscillation':
        updated['los_oscillation'] = resolve_params('los_oscillation', params)
    elif effect == 'gyro_noise':
        silent = {'quantization_arcsec': 0.0, 'arw_deg_per_sqrt_h': 0.0, 'bias_instability_deg_per_h': 0.0,
                  'rrw_deg_per_h_sqrt_h': 0.0}
        updated['gyro_noise'] = resolve_params('gyro_noise', {**(updated.get('gyro_noise') or silent), **params})
    elif effect == 'gyro_bias_drift':
        drift = updated.get('gyro_bias_drift') or {f'{axis}_deg_per_h2': 0.0 for axis in AXES}
        updated['gyro_bias_drift'] = resolve_params('gyro_bias_drift', {**drift, **params})
    else:
        raise ConfigError(f'cannot add a {effect!r} candidate to a noise model')
    return updated

