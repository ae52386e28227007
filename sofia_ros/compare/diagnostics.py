"""Where a model fails: every camera axis and every gyro axis judged against its own noise (docs/compare.md).

Observables:

- a camera axis (``hipo.x``, ``ffi.y``, ...): the residual of every centroid on that pixel axis,
  judged against the camera's centroid noise (compare.floor). Trends are tested on frame means
  (a frame's stars share its moment; weight = stars in the frame) against elevation, time,
  temperature, specific force (TARF, in g), slew angle and fine-drive LOS angle, and on the
  rows themselves against the detector position (each axis, and the two together as a field)
  and the star; periods on the frame means,
  from twice the frame spacing up to half the record.
- a gyro axis (``gyro.el``, ``gyro.xel``, ``gyro.los``): what the attitude anchors had to add to
  the model's gyro propagation over each anchor interval, in TARF axes, whitened by the
  covariance the gyro noise gives those increments (angle and rate random walk, compare.prior)
  and studentized with the hat matrix of the whole fit: a unit normal under the null, shown in
  units of one interval's own walk. A gyro error the model lacks makes the anchors walk
  systematically: too far, or with elevation, temperature, specific force, time, or a period.
  Trends are tested by generalized least squares (the trend's columns whitened as the
  innovations are), so a bias wander the rate random walk allows is no trend with time.

Every test's p-value is corrected for the number of tests run (Bonferroni), so a finding's
``significance_sigma`` already accounts for the look-elsewhere effect; findings at
DETECTION_SIGMA or more are structure. An observable is not explained when it holds structure,
or when its RMS exceeds RATIO_LIMIT times its floor and the excess is significant (chi-square of
the rows in units of the floor, at DETECTION_SIGMA family-wise): a floor known to a few per cent
never makes noise look like signal, and a handful of anchor intervals never cries wolf.
Nothing is clipped or dropped.

Consistency: every fitted term is refitted (one Gauss-Newton step from the converged fit) on
complementary halves of the rows, split by elevation, time, temperature, specific force and
camera; a parameter that differs between the halves beyond DETECTION_SIGMA (family-wise) is
absorbing something it does not describe.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np
from scipy.spatial.transform import Rotation
from scipy import special  # not scipy.stats: see analysis.structure's import

from sofia_ros.analysis.ranking import NormalInverse
from sofia_ros.analysis.structure import PeriodTest, TrendTest, category_test, field_test, period_test, sigma_of_probability, trend_test
from sofia_ros.compare.observations import Observations
from sofia_ros.compare.prior import AnchorPrior
from sofia_ros.compare.records import ConsistencyFinding
from sofia_ros.effects.empirical import DETECTOR_FIELD
from sofia_ros.sensors.gyro_errors import tarf_from_gyrf_dcm
from sofia_ros.units import ARCSEC_PER_RAD, DEG_PER_RAD, STANDARD_GRAVITY_M_PER_S2

if TYPE_CHECKING:
    from sofia_ros.compare.fit import ModelFit
    from sofia_ros.compare.predict import Predictor

__all__ = ['DETECTION_SIGMA', 'REPORT_SIGMA', 'RATIO_LIMIT', 'FRAME_VARIABLES', 'ROW_VARIABLES', 'DETECTOR_FIELD',
           'GYRO_AXES', 'GYRO_TEST_VARIABLES', 'CameraSeries', 'GyroSeries', 'Diagnostics', 'NAMING_PREFERENCE',
           'distinct_findings', 'row_variables', 'residual_diagnostics', 'split_consistency']

#: Family-wise significance at which a finding is structure the model must explain.
DETECTION_SIGMA = 5.0
#: Findings from this family-wise significance on are listed (weaker hints).
REPORT_SIGMA = 3.0
#: An observable whose residual RMS exceeds its floor by more than this is not explained.
RATIO_LIMIT = 1.2
#: Variables tested on frame means (label -> unit).
FRAME_VARIABLES = {'elevation': 'deg', 'time': 's', 'temperature': 'C', 'specific_force_el': 'g',
                   'specific_force_xel': 'g', 'specific_force_los': 'g', 'slew_angle': 'deg', 'los_angle': 'deg'}
#: Variables tested on the centroid rows themselves.
ROW_VARIABLES = {'detector_x': 'px', 'detector_y': 'px', 'star': 'HIP'}
#: Variables a gyro axis is tested against (the anchor intervals have no detector or star).
GYRO_TEST_VARIABLES = ('elevation', 'time', 'temperature', 'specific_force_el', 'specific_force_xel',
                  'specific_force_los', 'rate', 'rate_size')
GYRO_AXES = ('el', 'xel', 'los')
#: Two variables this correlated cannot be told apart by the data (e.g. elevation and the LOS load).
_EQUIVALENT_CORRELATION = 0.95
#: Directions of the anchor innovations that the fit leaves less free than this (inside a slew without stars)
#: are not tested.
_MIN_FREEDOM = 0.05
_MIN_SPLIT_FRACTION = 0.1


@dataclass(frozen=True, eq=False)
class Diagnostics:
    """Per-observable statistics, findings (trends, periods) and the gyro axes' studentized anchor walk."""

    observables: dict
    trends: list
    periods: list
    tests_run: int

    def structured(self, observable: str, sigma: float = DETECTION_SIGMA) -> list[dict[str, Any]]:
        """Findings of one observable at or above ``sigma``.

        Args:
            observable: the observable's name ('hipo.x', 'gyro.el', ...).
            sigma: the least family-wise significance kept.

        Returns:
            Its trends, then its periods.
        """
        return [finding for finding in (*self.trends, *self.periods)
                if finding['observable'] == observable and finding['significance_sigma'] >= sigma]

    def unexplained(self) -> list[str]:
        """Observables that are not explained: RMS beyond RATIO_LIMIT of their floor, or structure.

        Returns:
            Their names, in the order of ``observables``.
        """
        return [name for name, entry in self.observables.items() if not entry['explained']]

    def as_document(self) -> dict[str, Any]:
        """The `signature` block of the JSON (docs/compare.md).

        Returns:
            trends, periods, tests_run and detection_sigma.
        """
        return {'trends': self.trends, 'periods': self.periods, 'tests_run': self.tests_run,
                'detection_sigma': DETECTION_SIGMA}


def _slew_angle_deg(observations, fit, predictor, times):
    """Rotation since the last move started, from the gyros (deg), per row."""
    move_start = observations.move_start_s
    if not len(move_start):
        return np.zeros(len(times))
    index = np.searchsorted(move_start, times, side='right') - 1
    attitudes = predictor.attitudes(fit.effects, times)
    before = predictor.attitudes(fit.effects, np.maximum(move_start[np.maximum(index, 0)], times.min()))
    relative = np.einsum('nij,nkj->nik', attitudes, before)
    angle = np.degrees(np.linalg.norm(Rotation.from_matrix(relative).as_rotvec(), axis=1))
    return np.where(index >= 0, angle, 0.0)


def row_variables(observations: Observations, fit: ModelFit, predictor: Predictor) -> dict[str, np.ndarray]:
    """Per-row values of every tested variable (N,) each, for diagnostics and plots.

    Args:
        observations: the bag's observations.
        fit: the fit whose effects time and place the rows.
        predictor: the bag's predictor.

    Returns:
        Each variable's name and its values, one per centroid row.
    """
    centroids = observations.centroids
    times = predictor.row_times_s(fit.effects)
    force_g = np.empty((len(times), 3))
    for index in range(len(centroids.cameras)):
        rows = centroids.camera_index == index
        force_g[rows] = predictor.camera_context(fit.effects, index, times).specific_force_m_per_s2
    force_g /= STANDARD_GRAVITY_M_PER_S2
    return {'elevation': centroids.elevation_deg, 'time': times, 'temperature': centroids.temperature_c,
            'specific_force_el': force_g[:, 0], 'specific_force_xel': force_g[:, 1],
            'specific_force_los': force_g[:, 2], 'slew_angle': _slew_angle_deg(observations, fit, predictor, times),
            'los_angle': centroids.fd_los_deg, 'detector_x': centroids.measured_px[:, 0],
            'detector_y': centroids.measured_px[:, 1], 'star': centroids.hip}


def _frame_means(frame_index, columns):
    """Means of each column per frame, and the number of rows in each frame."""
    _, inverse, counts = np.unique(frame_index, return_inverse=True, return_counts=True)
    return [np.bincount(inverse, column) / counts for column in columns], counts


@dataclass(frozen=True, eq=False)
class CameraSeries:
    """One camera axis to test: its rows' residuals and variables, and the same as frame means."""

    observable: str
    floor_arcsec: float
    residual_arcsec: np.ndarray
    row_variables: dict
    frame_residual_arcsec: np.ndarray
    frame_weights: np.ndarray
    frame_variables: dict


@dataclass(frozen=True, eq=False)
class GyroSeries:
    """One gyro axis to test: its anchor innovations, decorrelated, with the design that decorrelates a shape."""

    observable: str
    floor_arcsec: float
    decorrelated_arcsec: np.ndarray
    frame_variables: dict
    innovations_arcsec: np.ndarray
    unit_arcsec: float
    design: np.ndarray


@dataclass(frozen=True, eq=False)
class _Test:
    """One structure test: a trend or a period of an observable against a variable, and what it was run on."""

    kind: str
    observable: str
    variable: str
    result: TrendTest | PeriodTest | None
    frame_variables: dict | None
    tested: np.ndarray | None


def _camera_series(observations, fit, noise_arcsec, variables):
    """A CameraSeries per camera axis with at least two rows."""
    centroids = observations.centroids
    for index, camera in enumerate(centroids.cameras):
        rows = centroids.camera_index == index
        if np.count_nonzero(rows) < 2:
            continue
        for axis_index, axis in enumerate(('x', 'y')):
            residual = fit.residual_arcsec[rows, axis_index]
            frame_values, counts = _frame_means(centroids.frame_index[rows],
                                                [residual] + [variables[key][rows] for key in FRAME_VARIABLES])
            yield CameraSeries(f'{camera}.{axis}', float(noise_arcsec[index]), residual,
                               {key: variables[key][rows] for key in ROW_VARIABLES}, frame_values[0],
                               counts.astype(float), dict(zip(FRAME_VARIABLES, frame_values[1:])))


def _prior_residual_covariance(fit):
    """The prior rows' residuals' covariance under the null, (I - H) over those rows with H the whole fit's hat
    matrix, in units of the prior's (3(K-1), 3(K-1))."""
    inverse = fit.weighted_inverse.matrix
    # The prior rows' Jacobian is the prior's matrix over the anchors and zero over the parameters.
    prior = fit.anchor_prior.matrix
    anchors = prior.shape[1]
    return np.eye(prior.shape[0]) - np.asarray(prior @ (prior @ inverse[:anchors, :anchors]).T)


def _gyro_series(observations, fit, prior):
    """Per gyro axis: the anchors' innovations in TARF (arcsec; compare.prior), the same decorrelated (unit normal
    times the prior's unit under the null), the variables at mid-interval and the decorrelation of the increments.

    The fitted innovations r share what the fit took from them: Cov(r) = (I - H) over the prior rows.
    Over its eigenvectors U with eigenvalues l >= _MIN_FREEDOM (directions the data leave free; a
    gap without stars leaves only its total free), z = l^-1/2 U^T r is white, and a shape s of the
    increments enters as l^1/2 U^T W s (W the prior's whitening): every test runs on z with that design.
    """
    if len(prior.knots_s) < 3 or len(fit.prior_residual) == 0:
        return
    unit_arcsec = prior.unit_rad * ARCSEC_PER_RAD
    innovations = -fit.prior_residual.reshape(-1, 3)
    covariance = _prior_residual_covariance(fit)
    middle = prior.middle_s
    centroids, gyro = observations.centroids, observations.gyro
    order = np.argsort(centroids.stamp_s)
    force = np.column_stack([np.interp(middle, gyro.tick_mean_time_s, gyro.tick_mean_specific_force_m_per_s2[:, i])
                             for i in range(3)])
    force_g = force @ tarf_from_gyrf_dcm(fit.effects).T / STANDARD_GRAVITY_M_PER_S2
    frame_variables = {
        'elevation': np.interp(middle, centroids.stamp_s[order], centroids.elevation_deg[order]),
        'time': middle, 'temperature': np.interp(middle, gyro.tick_end_s, gyro.tick_temperature_c),
        'specific_force_el': force_g[:, 0], 'specific_force_xel': force_g[:, 1], 'specific_force_los': force_g[:, 2]}
    rates_deg_per_s = _interval_mean_rates_deg_per_s(gyro, prior.knots_s, fit.effects)
    for axis_index, axis in enumerate(GYRO_AXES):
        # The axis' own rate, its sense and its size: a scale factor follows the one, an asymmetry the other.
        tested = {**frame_variables, 'rate': rates_deg_per_s[:, axis_index],
                  'rate_size': np.abs(rates_deg_per_s[:, axis_index])}
        axis_variables = {key: tested[key] for key in GYRO_TEST_VARIABLES}
        axis_covariance = covariance[axis_index::3, axis_index::3]
        eigenvalues, vectors = np.linalg.eigh(axis_covariance)
        free = eigenvalues >= _MIN_FREEDOM
        if np.count_nonzero(free) < 3:
            continue
        root = np.sqrt(eigenvalues[free])
        decorrelated = vectors[:, free].T @ innovations[:, axis_index] / root * unit_arcsec
        design = root[:, None] * (vectors[:, free].T @ prior.whitening)
        floor = unit_arcsec * float(np.sqrt(np.mean(np.diag(axis_covariance))))
        yield GyroSeries(f'gyro.{axis}', floor, decorrelated, axis_variables, innovations[:, axis_index] * unit_arcsec,
                         unit_arcsec, design)


def _interval_mean_rates_deg_per_s(gyro, knots_s, effects):
    """The TARF rates averaged over each anchor interval (K-1, 3) [deg/s]: what a rate-driven error accumulates
    over the interval, divided by its length; an interval without a tick takes the rate at its middle."""
    rates = gyro.tick_mean_rates_gyrf_rad_per_s @ tarf_from_gyrf_dcm(effects).T * DEG_PER_RAD
    times = gyro.tick_mean_time_s
    edges = np.searchsorted(times, knots_s)
    counts = np.diff(edges)
    cumulative = np.vstack([np.zeros((1, 3)), np.cumsum(rates, axis=0)])
    sums = cumulative[edges[1:]] - cumulative[edges[:-1]]
    middle = (knots_s[:-1] + knots_s[1:]) / 2.0
    at_middle = np.column_stack([np.interp(middle, times, rates[:, axis]) for axis in range(3)])
    return np.where(counts[:, None] > 0, sums / np.maximum(counts, 1)[:, None], at_middle)


def _ranges(values_by_variable, names):
    """[min, max] of each named variable over the tested rows (an empirical term's polynomial spans it)."""
    return {name: [float(np.min(values_by_variable[name])), float(np.max(values_by_variable[name]))] for name in names}


def _equivalents(frame_variables, variable):
    """Variables whose values are so correlated with ``variable`` here that no test can tell them apart."""
    reference = frame_variables[variable]
    same = []
    for key, values in frame_variables.items():
        if key == variable or np.ptp(values) == 0 or np.ptp(reference) == 0:
            continue
        if abs(np.corrcoef(reference, values)[0, 1]) >= _EQUIVALENT_CORRELATION:
            same.append(key)
    return same


def residual_diagnostics(observations: Observations, fit: ModelFit, predictor: Predictor, noise_arcsec: np.ndarray,
                         prior: AnchorPrior, *, variables: Mapping[str, np.ndarray] | None = None) -> Diagnostics:
    """Judge every camera and gyro axis of a fit: RMS against floor, trends and periods (family-wise sigmas).

    Args:
        observations: the bag's observations.
        fit: the fit judged.
        predictor: the bag's predictor.
        noise_arcsec: each camera's centroid noise ["] (compare.floor.centroid_noise_arcsec).
        prior: the anchors' prior (compare.prior).
        variables: the fit's row_variables where the caller has them (split_consistency takes the same), or None.

    Returns:
        Every observable's judgement and the findings, strongest first.
    """
    variables = row_variables(observations, fit, predictor) if variables is None else variables
    tests, observables = [], {}
    for series in _camera_series(observations, fit, noise_arcsec, variables):
        name, floor, residual = series.observable, series.floor_arcsec, series.residual_arcsec
        frames, weights = series.frame_residual_arcsec, series.frame_weights
        rms = float(np.sqrt(np.mean(residual**2)))
        observables[name] = {'kind': 'camera', 'rms_arcsec': rms, 'floor_arcsec': floor, 'ratio': rms / floor,
                             'rows': int(len(residual)), 'chi2': float(np.sum((residual / floor) ** 2))}
        for key, values in series.frame_variables.items():
            tests.append(_Test('trend', name, key, trend_test(values, frames, weights), series.frame_variables,
                               values))
        for key, values in series.row_variables.items():
            test = category_test(values, residual) if key == 'star' else trend_test(values, residual)
            tests.append(_Test('trend', name, key, test, None, values))
        tests.append(_Test('trend', name, DETECTOR_FIELD, field_test(series.row_variables['detector_x'],
                                                                     series.row_variables['detector_y'], residual),
                           None, None))
        tests.append(_Test('period', name, 'time', period_test(series.frame_variables['time'], frames, weights),
                           None, None))
    for series in _gyro_series(observations, fit, prior):
        name, innovations, decorrelated = series.observable, series.innovations_arcsec, series.decorrelated_arcsec
        rms = float(np.sqrt(np.mean(innovations**2)))
        # The excess over the floor counts the decorrelated components (what the data leave free).
        observables[name] = {'kind': 'gyro', 'rms_arcsec': rms, 'floor_arcsec': series.floor_arcsec,
                             'ratio': rms / series.floor_arcsec, 'rows': int(len(decorrelated)),
                             'chi2': float(np.sum((decorrelated / series.unit_arcsec) ** 2))}
        # Generalized least squares: a shape of the increments, decorrelated as the innovations are.
        for key, values in series.frame_variables.items():
            tests.append(_Test('trend', name, key, trend_test(values, decorrelated, whitening=series.design),
                               series.frame_variables, values))
        tests.append(_Test('period', name, 'time', period_test(series.frame_variables['time'], decorrelated,
                                                               whitening=series.design), None, None))
    count = sum(1 for test in tests if test.result is not None)
    trends, periods = [], []
    for entry in tests:
        kind, name, key, test = entry.kind, entry.observable, entry.variable, entry.result
        frame_variables, tested = entry.frame_variables, entry.tested
        if test is None:
            continue
        probability = test.false_alarm_probability if kind == 'period' else test.p_value
        sigma = sigma_of_probability(min(1.0, probability * count))
        if sigma < REPORT_SIGMA:
            continue
        if kind == 'period':
            periods.append({'observable': name, 'period_s': test.period, 'amplitude_arcsec': test.amplitude,
                            'significance_sigma': sigma, 'power': test.power})
        else:
            equivalents = _equivalents(frame_variables, key) if frame_variables else []
            ranges = _ranges(frame_variables, [key, *equivalents]) if frame_variables else (
                {} if tested is None or key == 'star' else {key: [float(np.min(tested)), float(np.max(tested))]})
            trends.append({'observable': name, 'variable': key, 'amplitude_arcsec': test.amplitude,
                           'significance_sigma': sigma, 'equivalent_variables': equivalents, 'ranges': ranges,
                           'shape': {'centres': test.centres.tolist(), 'values_arcsec': test.shape.tolist()}})
    trends.sort(key=_strongest_first)
    periods.sort(key=_strongest_first)
    diagnostics = Diagnostics(observables, trends, periods, count)
    for name, entry in observables.items():
        # The excess over the floor: chi-square of the rows in units of the floor, family-wise over the observables.
        probability = float(special.chdtrc(entry['rows'], entry.pop('chi2'))) * len(observables)
        entry['excess_sigma'] = max(0.0 - float(special.ndtri(min(probability, 1.0))), 0.0)
        entry['structure'] = [_finding_label(finding) for finding in distinct_findings(diagnostics.structured(name))]
        entry['explained'] = (not (entry['ratio'] > RATIO_LIMIT and entry['excess_sigma'] >= DETECTION_SIGMA)
                              and not entry['structure'])
    return diagnostics


def _strongest_first(finding):
    """Sort key: the most significant first; among findings past the float limit of a p-value (37 sigma, all
    alike) the larger shape first. Both to 9 digits, alike findings in the order they were tested (the sort is
    stable; two values either side of a 9th digit's rounding still part, about once in 1e4): collinear variables
    (time and temperature on the Waco star hop) find the same shape, and the last digits of a fit ordered them,
    'time (= temperature)' in one run and 'temperature (= time)' in the next."""
    return -float(f'{finding["significance_sigma"]:.9g}'), -float(f'{finding["amplitude_arcsec"]:.9g}')


def _finding_label(finding):
    if 'period_s' in finding:
        return f'period {finding["period_s"]:.4g} s'
    same = finding.get('equivalent_variables')
    return finding['variable'] + (f' (= {"/".join(same)})' if same else '')


#: Of variables the data cannot tell apart, the one named: the most direct physical quantity first.
NAMING_PREFERENCE = ('elevation', 'time', 'temperature', 'los_angle', 'slew_angle', 'detector_x', 'detector_y',
                     DETECTOR_FIELD, 'specific_force_los', 'specific_force_xel', 'specific_force_el', 'rate',
                     'rate_size', 'star')


def _preference(variable):
    return NAMING_PREFERENCE.index(variable) if variable in NAMING_PREFERENCE else len(NAMING_PREFERENCE)


def distinct_findings(findings: Iterable[Mapping[str, Any]]) -> list[Mapping[str, Any]]:
    """Findings strongest first, one per group of equivalent variables (named by NAMING_PREFERENCE).

    The star comes last: a star sits at one elevation and detector position, so it stands in for
    them; it is named only when nothing else explains the residual.

    Args:
        findings: trends and periods (Diagnostics.trends, Diagnostics.periods).

    Returns:
        The distinct findings, strongest first, the star's last.
    """
    by_key = {(f['observable'], f.get('variable')): f for f in findings}
    named, kept = set(), []
    order = sorted(findings, key=lambda f: (f.get('variable') == 'star', *_strongest_first(f)))
    for finding in order:
        if 'period_s' in finding:
            kept.append(finding)
            continue
        group = [finding['variable'], *finding.get('equivalent_variables', ())]
        if (finding['observable'], finding['variable']) in named:
            continue
        named.update((finding['observable'], variable) for variable in group)
        primary = min(group, key=_preference)
        kept.append(by_key.get((finding['observable'], primary), finding))
    return sorted(kept, key=lambda f: (f.get('variable') == 'star', *_strongest_first(f)))


def _split_masks(variables, centroids):
    """Complementary halves of the rows, by each variable's median and by camera; near-duplicates dropped."""
    masks = {}
    for key in ('elevation', 'time', 'temperature', 'specific_force_los'):
        values = variables[key]
        middle = np.median(values)
        lower = values <= middle if np.mean(values <= middle) < 1.0 - _MIN_SPLIT_FRACTION else values < middle
        if not _MIN_SPLIT_FRACTION <= np.mean(lower) <= 1.0 - _MIN_SPLIT_FRACTION:
            continue
        if any(abs(np.corrcoef(lower, other)[0, 1]) > 0.95 for other in masks.values()):
            continue
        masks[key] = lower
    if len(centroids.cameras) > 2:
        for index, camera in enumerate(centroids.cameras):
            masks[f'camera {camera}'] = centroids.camera_index == index
    return masks


def _split_step(fit, keep_rows, equations):
    """One Gauss-Newton step on a subset of the rows (prior rows kept): parameter values and sigmas."""
    gram, gradient, rss_after = equations
    gram = gram.copy()
    # A parameter the subset does not touch (another camera's term) is decoupled and gets no comparison.
    determined = np.diag(gram) > 0
    gram[~determined, ~determined] = 1.0
    # The whole fit's null directions are null in either half (its Gram is the halves' sum).
    inverse = NormalInverse.of(gram, fit.weighted_inverse.null_directions).matrix
    step = inverse @ gradient
    used = 2 * int(np.sum(keep_rows)) + len(fit.prior_residual)
    variance = rss_after(step) / max(used - gram.shape[0], 1)
    parameters = slice(fit.anchor_columns.shape[1], None)
    diagonal = np.diag(inverse)[parameters]
    sigma = np.sqrt(np.where(diagonal > 0, diagonal, np.nan) * variance)
    return fit.values + step[parameters], np.where(determined[parameters], sigma, np.nan)


def split_consistency(observations: Observations, fit: ModelFit, predictor: Predictor, *,
                      variables: Mapping[str, np.ndarray] | None = None) -> list[ConsistencyFinding]:
    """Fitted terms that change between halves of the data: [{param, split, values, sigmas, significance_sigma}].

    Args:
        observations: the bag's observations.
        fit: the fit whose free parameters are compared between halves.
        predictor: the bag's predictor.
        variables: the fit's row_variables where the caller has them (residual_diagnostics takes the same), or None.

    Returns:
        The terms that differ at DETECTION_SIGMA (family-wise), the most significant first.
    """
    if not fit.free:
        return []
    variables = row_variables(observations, fit, predictor) if variables is None else variables
    comparisons = []
    for split, lower in _split_masks(variables, observations.centroids).items():
        lower_equations, upper_equations = fit.split_normal_equations(np.repeat(lower, 2))
        first, first_sigma = _split_step(fit, lower, lower_equations)
        second, second_sigma = _split_step(fit, ~lower, upper_equations)
        for index, parameter in enumerate(fit.free):
            spread = np.hypot(first_sigma[index], second_sigma[index])
            if np.isfinite(spread) and spread > 0:
                comparisons.append((parameter.label, split, first[index], second[index], first_sigma[index],
                                    second_sigma[index], abs(first[index] - second[index]) / spread))
    count = len(comparisons)
    found = []
    for label, split, first, second, first_sigma, second_sigma, z in comparisons:
        sigma = sigma_of_probability(min(1.0, 2.0 * float(special.ndtr(-z)) * count))
        if sigma >= DETECTION_SIGMA:
            halves = ('this camera', 'the others') if split.startswith('camera') else ('lower half', 'upper half')
            found.append({'param': label, 'split': split, 'halves': halves, 'values': [float(first), float(second)],
                          'sigmas': [float(first_sigma), float(second_sigma)], 'significance_sigma': sigma})
    found.sort(key=lambda entry: -entry['significance_sigma'])
    return found

