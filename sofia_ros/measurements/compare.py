"""`sofia compare SET.yaml --model M.yaml`: a measurement set as a source of the one comparison (compare.pipeline).

The ledger, ranking, refits, competing sets, model terms and verdict are those of a bag
(compare.pipeline.run_comparison). What a set brings is its problem: reduced observables whose
residuals are whitened by each row's stated sigma, fitted by trust-region least squares with a
numeric Jacobian (steps of compare.fit.free_parameters); the model's fitted terms of a reduced set
start at zero; each observable judged by the chi-square of its stated sigmas (its 0.99 quantile)
and a trend against its own measured value. Effects that no table's kind can see are listed as
not observable with the kind's reason; effects a kind could see but this set cannot (columns
vanish or the model's terms absorb them) are listed with that reason.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import chi2

from sofia_ros.analysis.ranking import CandidateTerm, linear_fit
from sofia_ros.analysis.structure import sigma_of_probability, trend_test
from sofia_ros.compare.diagnostics import DETECTION_SIGMA, REPORT_SIGMA, Diagnostics
from sofia_ros.compare.fit import with_values
from sofia_ros.compare.records import LedgerRow
from sofia_ros.compare.pipeline import (ABSORBED_FRACTION, Comparison, Judgement, LinearizedCandidate, WhitenedFit,
                                        run_comparison, switched_on)
from sofia_ros.config import EffectConfig
from sofia_ros.effects import CATALOGUE
from sofia_ros.errors import FitError
from sofia_ros.measurements.format import ALIGNMENT, DRIFT_EFFECTS, KINDS, MeasurementSet
from sofia_ros.measurements.predict import predict_table, star_geometry
from sofia_ros.noise.earth_rate import DEGENERATE_PAIR, earth_rate_table
from sofia_ros.progress import Progress

__all__ = ['SetCompareResult', 'SetSource', 'compare_measurement_set', 'EXPLAINED_QUANTILE']

#: An observable is explained when its chi-square (RMS/floor)^2 n lies below this quantile.
EXPLAINED_QUANTILE = 0.99
#: A candidate parameter whose effect at its thesis magnitude is below this fraction of the candidate's strongest
#: parameter's is not determined by the set (e.g. a LOS scale factor from moves about EL).
WEAK_COLUMN_FRACTION = 1e-2
#: Rate kinds: their residuals are in arcsec/s (= deg/h), the others in arcsec.
_RATE_KINDS = ('earth_rate',)
_ARCSEC_PER_UNIT = {'star_distance': 1.0, 'turning_point': 1.0, 'misalignment_angle': 60.0, 'earth_rate': 1.0}
_DRIFT_REMOVED = 'the drift correction of this set (6.3-6.4) removed constant rate offsets'


@dataclass(frozen=True)
class SetCompareResult:
    """The JSON document, the set, the fits before and after the best candidate, per-table predictions."""

    document: dict
    measurement_set: MeasurementSet
    predicted: dict
    predicted_best: dict | None
    best_name: str | None
    final_fit: Any = None
    #: a set's fits take no start (compare.pipeline.ComparisonSource.start_of): none is kept
    refit_starts: dict = field(default_factory=dict)


class _Problem:
    """Whitened residuals of a set under effects: (measured - predicted) / sigma, table by table."""

    def __init__(self, measurement_set):
        self.set = measurement_set
        self.tables = measurement_set.tables
        self.geometry = {table.name: star_geometry(measurement_set, table) if table.kind == 'star_distance' else None
                         for table in self.tables}
        self.measured = np.concatenate([table.measured() for table in self.tables])
        self.sigma = np.concatenate([table.sigma() for table in self.tables])
        self.observables = [name for table in self.tables for name in table.observable_names()]
        self.kinds = [table.kind for table in self.tables for _ in table.observable_names()]
        self.table_of = [table.name for table in self.tables for _ in table.observable_names()]
        self.to_arcsec = np.array([_ARCSEC_PER_UNIT[kind] for kind in self.kinds])

    def predict(self, effects):
        return {table.name: predict_table(self.set, table, effects, self.geometry[table.name]) for table in self.tables}

    def whitened(self, effects):
        predicted = np.concatenate(list(self.predict(effects).values()))
        return (self.measured - predicted) / self.sigma

    def columns(self, effects, free, values, base):
        """d whitened prediction / d parameter (the ranking's convention: residual reduction per unit)."""
        columns = np.empty((len(base), len(free)))
        for index, parameter in enumerate(free):
            shifted = with_values(effects, free, values)
            shifted[parameter.effect] = {**shifted[parameter.effect], parameter.name: values[index] + parameter.step}
            columns[:, index] = (base - self.whitened(shifted)) / parameter.step
        return columns


def _start_values(measurement_set, effects, fitted):
    """Fitted terms of a reduced set start at zero (errors the reduction left); alignment sets at the model's values."""
    effects = {name: dict(params) for name, params in effects.items()}
    if measurement_set.family != ALIGNMENT:
        for name in fitted:
            spec = CATALOGUE[name]
            for parameter in spec.params:
                if isinstance(parameter.default, float) and not parameter.shape:
                    effects[name][parameter.name] = 0.0
    return effects


def _fit(problem, effects, free):
    """Trust-region least squares on the whitened residuals; sigmas from analysis.ranking.linear_fit."""
    start = np.array([effects[p.effect][p.name] for p in free], dtype=float)
    if free:
        steps = np.array([p.step for p in free])
        solution = least_squares(lambda values: problem.whitened(with_values(effects, free, values)), start,
                                 x_scale=steps * 1e3, diff_step=None, method='trf', max_nfev=200 * len(free))
        start = solution.x
    current = with_values(effects, free, start)
    base = problem.whitened(current)
    if not np.all(np.isfinite(base)):
        raise FitError('the fit left the model undefined for this set (non-finite residuals)')
    jacobian = problem.columns(effects, free, start, base) if free else np.zeros((len(base), 0))
    final = linear_fit(base, jacobian, [p.label for p in free])
    return WhitenedFit(current, tuple(free), start, final.sigma, final.correlation, base, jacobian)


def _rms(problem, whitened, mask):
    residual = whitened * problem.sigma * problem.to_arcsec
    return float(np.sqrt(np.mean(residual[mask] ** 2))) if np.any(mask) else None


def _rms_table(problem, whitened):
    """residual_rms_arcsec {total, <kind>} (angle kinds) and residual_rms_arcsec_per_s (rate kinds)."""
    kinds = np.array(problem.kinds)
    angle = ~np.isin(kinds, _RATE_KINDS)
    out_angle, out_rate = {}, {}
    if np.any(angle):
        out_angle['total'] = _rms(problem, whitened, angle)
    if np.any(~angle):
        out_rate['total'] = _rms(problem, whitened, ~angle)
    for kind in dict.fromkeys(problem.kinds):
        target = out_rate if kind in _RATE_KINDS else out_angle
        target[kind] = _rms(problem, whitened, kinds == kind)
    return out_angle, out_rate


def _earth_rate_tables(measurement_set):
    """Table 5.7 of each earth_rate table: theory at the stated heading and at the least-squares heading (5.2.4)."""
    out = {}
    for table in measurement_set.tables:
        if table.kind != 'earth_rate':
            continue
        mean = np.mean([row.rate_tarf_deg_per_h for row in table.rows], axis=0)
        summary = earth_rate_table(mean, table.latitude_deg, table.heading_deg, table.elevation_deg)
        summary['degenerate_pair'] = list(DEGENERATE_PAIR)
        out[table.name] = summary
    return out


def _signature(problem, whitened):
    """Trends of each observable's whitened residual against its own measured value (e.g. distance, Fig. 6.11).

    The same F-test and family-wise significance as a bag comparison (compare.diagnostics);
    with fewer than 30 rows only a straight line is tested (three cubic terms would eat the power).
    Returns (trends, tests run).
    """
    observables = np.array(problem.observables)
    tests = []
    for name in dict.fromkeys(problem.observables):
        mask = observables == name
        degree = 1 if mask.sum() < 30 else 3
        tests.append((name, trend_test(problem.measured[mask], whitened[mask], degree=degree),
                      float(np.mean((problem.sigma * problem.to_arcsec)[mask]))))
    count = sum(1 for _, test, _ in tests if test is not None)
    trends = []
    for name, test, scale in tests:
        if test is None:
            continue
        sigma = sigma_of_probability(min(1.0, test.p_value * count))
        if sigma >= REPORT_SIGMA:
            variable = 'distance' if name.startswith('star_distance') else 'measured value'
            trends.append({'observable': name, 'variable': variable, 'amplitude_arcsec': test.amplitude * scale,
                           'significance_sigma': sigma, 'equivalent_variables': []})
    return sorted(trends, key=lambda t: -t['significance_sigma']), count


def _beyond_stated_sigma(entry):
    """The set's rule for the RMS of an observable: its chi-square (RMS/floor)^2 n beyond the EXPLAINED_QUANTILE."""
    return bool(entry['ratio'] ** 2 * entry['rows'] > chi2.ppf(EXPLAINED_QUANTILE, entry['rows']))


def _observable_status(problem, whitened, trends):
    """Per observable: RMS against the stated sigma, ratio, rows, structure, explained (chi-square quantile)."""
    observables = {}
    names = np.array(problem.observables)
    for name in dict.fromkeys(problem.observables):
        mask = names == name
        scale = (problem.sigma * problem.to_arcsec)[mask]
        rms = float(np.sqrt(np.mean((whitened[mask] * scale) ** 2)))
        floor = float(np.sqrt(np.mean(scale ** 2)))
        suffix = 'arcsec_per_s' if name.split('.')[0] in _RATE_KINDS else 'arcsec'
        entry = {f'rms_{suffix}': rms, f'floor_{suffix}': floor, 'ratio': rms / floor, 'rows': int(mask.sum()),
                 'structure': [t['variable'] for t in trends
                               if t['observable'] == name and t['significance_sigma'] >= DETECTION_SIGMA]}
        entry['explained'] = not _beyond_stated_sigma(entry) and not entry['structure']
        observables[name] = entry
    return observables


class SetSource:
    """A measurement set as a source of the one comparison (compare.pipeline.ComparisonSource).

    Residuals are the reduced observables whitened by each row's stated sigma; no nuisance columns.
    """

    noun = 'set'
    observable_keys = ('rms_arcsec', 'floor_arcsec', 'rms_arcsec_per_s', 'floor_arcsec_per_s', 'ratio', 'explained',
                       'rows', 'structure')
    # A set's ranking has no expected sizes: a candidate it cannot see is one the fitted terms absorb.
    hidden_reason = "absorbed by the model's fitted terms in this set"
    #: The chi-square (RMS/floor)^2 n beyond its EXPLAINED_QUANTILE.
    beyond_floor = staticmethod(_beyond_stated_sigma)

    def __init__(self, measurement_set: MeasurementSet, model: EffectConfig) -> None:
        """Set up the set's problem, where its fitted terms start, and what its kinds cannot see.

        Args:
            measurement_set: the set (measurements.validate.load_measurement_set).
            model: the model compared (EffectConfig).
        """
        self.measurement_set = measurement_set
        self.problem = _Problem(measurement_set)
        self.model_source = model.source
        self.kinds = tuple(dict.fromkeys(table.kind for table in measurement_set.tables))
        self.drift_removed = measurement_set.family != ALIGNMENT and all(
            table.kind == 'star_distance' and table.drift_removed for table in measurement_set.tables)
        self.fitted = [name for name in model.effects if name in model.fitted]
        self.start_effects = _start_values(measurement_set, model.effects, self.fitted)
        # Fitted terms no kind of this set can see are left at their start and listed.
        self.blind_fitted = {name: reason for name in self.fitted if (reason := self.blind_reason(name))}

    def blind_reason(self, name: str) -> str | None:
        """Why no table of this set can see an effect (its kind's reason, or the drift correction), or None.

        Args:
            name: the effect.

        Returns:
            The reason, or None when a table can see it.
        """
        reasons = []
        for kind in self.kinds:
            spec = KINDS[kind]
            if name in spec.sees:
                return _DRIFT_REMOVED if self.drift_removed and name in DRIFT_EFFECTS else None
            reasons.append(spec.blind.get(name, spec.default_blind_reason))
        return '; '.join(dict.fromkeys(reasons))

    def ledger_terms(self) -> list[str]:
        """The model's fitted effects some table of the set can see, in the model's order.

        Returns:
            Effect names.
        """
        return [name for name in self.fitted if name not in self.blind_fitted]

    def ledger_start(self, previous: Any, term: str | None) -> dict:
        """Every step starts from the model's start values (fitted terms of a reduced set at zero).

        Args:
            previous: the fit of the step before (not used: a set's fit is cheap and starts afresh).
            term: the fitted effect the step adds (not used).

        Returns:
            {effect: params}.
        """
        return self.start_effects

    def given_start(self) -> None:
        """None: every step of a set's ledger starts from the model's start values already.

        Returns:
            None.
        """
        return None

    def start_of(self, fit: Any) -> None:
        """None: a set's fits take no start (ComparisonSource.start_of).

        Args:
            fit: a converged fit.

        Returns:
            None.
        """
        return None

    def moved_start(self, fit: Any, nuisance_change: np.ndarray) -> None:
        """None: a set's fits take no start and have no nuisance parameters (ComparisonSource.moved_start).

        Args:
            fit: a converged fit.
            nuisance_change: empty.

        Returns:
            None.
        """
        return None

    def fit(self, effects: dict, free: tuple, start: Any) -> Any:
        """Trust-region least squares on the whitened residuals.

        Args:
            effects: {effect: params} at the starting values.
            free: FreeParameters to fit.
            start: not used (a set has no nuisance parameters).

        Returns:
            The fit.

        Raises:
            FitError: the fit leaves the model undefined for the set.
        """
        return _fit(self.problem, effects, free)

    def chain_step(self, term: str | None, effects: dict, free: tuple, start: Any, *,
                   whole: bool = False) -> tuple[Any, LedgerRow]:
        """A step of the ledger's chain, fitted: a set's fit takes milliseconds, none is kept.

        Args:
            term: the fitted effect the step adds, or None.
            effects: {effect: params} at the starting values.
            free: FreeParameters to fit.
            start: not used.
            whole: not used (every step is a whole fit).

        Returns:
            (the fit, its ledger row).
        """
        fit = self.fit(effects, free, start)
        return fit, self.ledger_row(term, fit)

    def ledger_row(self, term: str | None, fit: Any) -> LedgerRow:
        """A row of the ledger: the term, the residual RMS of the angle and the rate kinds, the BIC.

        Args:
            term: the fitted effect the step added, or None.
            fit: the step's fit.

        Returns:
            {term, residual_rms_arcsec, residual_rms_arcsec_per_s, bic}.
        """
        angle, rate = _rms_table(self.problem, fit.whitened)
        return {'term': term or 'fixed effects only (fitted terms at their start)', 'residual_rms_arcsec': angle,
                'residual_rms_arcsec_per_s': rate, 'bic': fit.bic}

    def residual_rms(self, fit: Any) -> dict:
        """{total, <kind>} over the angle kinds (arcsec).

        Args:
            fit: the fit.

        Returns:
            The RMS table.
        """
        return _rms_table(self.problem, fit.whitened)[0]

    def rms_after(self, fit: Any) -> dict:
        """The totals of the angle kinds and of the rate kinds.

        Args:
            fit: the fit.

        Returns:
            {'rms_after_arcsec': ..., 'rms_after_arcsec_per_s': ...} (None where the set has none).
        """
        angle, rate = _rms_table(self.problem, fit.whitened)
        return {'rms_after_arcsec': angle.get('total'), 'rms_after_arcsec_per_s': rate.get('total')}

    def ranking_problem(self, fit: Any) -> tuple[np.ndarray, Any, int]:
        """The whitened rows and the fitted terms' columns; no nuisance columns.

        Args:
            fit: the fit.

        Returns:
            (residual, Jacobian, 0).
        """
        return fit.whitened, fit.jacobian, 0

    def judge_fit(self, fit: Any) -> Judgement:
        """Each observable by the chi-square of its stated sigmas and a trend against its measured value.

        Args:
            fit: the fit.

        Returns:
            The Judgement (no consistency: a set is not split into halves).
        """
        trends, count = _signature(self.problem, fit.whitened)
        return Judgement(Diagnostics(_observable_status(self.problem, fit.whitened, trends), trends, [], count), [])

    def candidate_names(self, names: list[str], judgement: Judgement) -> list[str]:
        """The catalogue's candidates alone (a set has no empirical shapes).

        Args:
            names: the catalogue effects not in the model.
            judgement: the judgement of the model's fit (not used).

        Returns:
            Effect names.
        """
        return names

    def linearize(self, fit: Any, names: Sequence[str]) -> tuple[list[LinearizedCandidate], dict[str, str]]:
        """Each candidate a table can see linearized where it vanishes, its weak or absorbed parameters left out.

        Args:
            fit: the model's fit.
            names: candidate effect names.

        Returns:
            (LinearizedCandidates, {name: why the set cannot see it}).
        """
        blind = {name: reason for name in names if (reason := self.blind_reason(name))}
        out, vanished = [], {}
        for name in names:
            if name in blind:
                continue
            free, start, switched = switched_on(fit.effects, name)
            spec = CATALOGUE[name]
            at_start = self.problem.whitened(switched)
            columns = self.problem.columns(switched, free, start, at_start)
            norms = np.linalg.norm(columns, axis=0)
            # Compared at the thesis' magnitude of each parameter (its default), so that units do not matter.
            magnitude = np.array([abs(spec.parameter(p.name).default) or 1e3 * p.step for p in free])
            effect = norms * magnitude
            live = (effect > WEAK_COLUMN_FRACTION * effect.max(initial=0.0)) & (norms > 1e-9 * np.sqrt(len(at_start)))
            if not np.any(live):
                vanished[name] = 'no prediction of this set changes with it'
                continue
            # A parameter the model's fitted terms absorb alone (e.g. the swap's bias difference against gyro_bias)
            # is left at its start; the rest of the effect is still ranked.
            if fit.jacobian.shape[1]:
                coefficients, *_ = np.linalg.lstsq(fit.jacobian, columns, rcond=None)
                outside = np.linalg.norm(columns - fit.jacobian @ coefficients, axis=0) / np.maximum(norms, 1e-300)
                absorbed = live & (outside < ABSORBED_FRACTION)
                if np.any(absorbed) and not np.all(absorbed == live):
                    live = live & ~absorbed
            kept = tuple(p for p, keep in zip(free, live) if keep)
            term = CandidateTerm(name, tuple(p.name for p in kept), start[live], columns[:, live],
                                 fit.whitened - at_start)
            out.append(LinearizedCandidate(term, kept, switched))
        return out, {**blind, **vanished}

    def shared_objects(self) -> tuple:
        """Nothing: a set is compared in one process, its fits take milliseconds (ComparisonSource.shared_objects).

        Returns:
            ().
        """
        return ()

    def extra_document(self, outcome: Comparison, progress: Progress) -> dict:
        """The set's own keys: its tables, floors, blind fitted terms, rows, Earth-rate tables.

        Args:
            outcome: the comparison so far.
            progress: not used (a set has no phase of its own).

        Returns:
            {key: value}.
        """
        measurement_set = self.measurement_set
        angle_floor, rate_floor = _rms_table(self.problem, np.ones(len(self.problem.sigma)))
        extra = {
            'measurement_set': measurement_set.source,
            'title': measurement_set.title,
            'observations': {table.name: {'kind': table.kind, 'rows': len(table.rows),
                                          'drift_removed': table.drift_removed if table.kind == 'star_distance'
                                          else None}
                             for table in measurement_set.tables},
            'noise_floor_arcsec': angle_floor.get('total'),
            'not_observable_fitted_terms': self.blind_fitted,
            'rows': self.rows(outcome.final_fit, outcome.best_fit),
            'earth_rate': _earth_rate_tables(measurement_set),
        }
        rate = _rms_table(self.problem, outcome.final_fit.whitened)[1]
        if rate:
            extra['residual_rms_arcsec_per_s'] = rate
            extra['noise_floor_arcsec_per_s'] = rate_floor.get('total')
        return extra

    def rows(self, final: Any, best_fit: Any) -> list[dict]:
        """Per measured value: table, observable, measured, sigma, residual now and after the best candidate.

        Args:
            final: the model's fit.
            best_fit: the fit with the best candidate, or None.

        Returns:
            The JSON's ``rows``.
        """
        problem = self.problem
        after = None if best_fit is None else best_fit.whitened * problem.sigma
        residual = final.whitened * problem.sigma
        labels = [getattr(row, 'move', '') or getattr(row, 'label', '') or getattr(row, 'matrix', '')
                  for table in problem.tables for row in table.rows
                  for _ in range(len(table.observable_names()) // len(table.rows))]
        return [{'table': problem.table_of[index], 'observable': observable, 'label': labels[index],
                 'measured': float(problem.measured[index]), 'sigma': float(problem.sigma[index]),
                 'residual': float(residual[index]),
                 'residual_after_best': None if after is None else float(after[index])}
                for index, observable in enumerate(problem.observables)]

    def predict(self, fit: Any) -> dict:
        """Per table, the predictions of a fit's effects.

        Args:
            fit: the fit.

        Returns:
            {table name: predicted values}.
        """
        return self.problem.predict(fit.effects)


def compare_measurement_set(measurement_set: MeasurementSet, model: EffectConfig, *,
                            candidate_names: Sequence[str] | None = None) -> SetCompareResult:
    """Compare ``model`` with a measurement set through compare.pipeline.

    Args:
        measurement_set: the set.
        model: the model (EffectConfig).
        candidate_names: the candidates to try, or None for the catalogue.

    Returns:
        The SetCompareResult.
    """
    started = time.perf_counter()
    source = SetSource(measurement_set, model)
    outcome = run_comparison(source, model.effects, candidate_names=candidate_names, started=started)
    return SetCompareResult(outcome.document, measurement_set, source.predict(outcome.final_fit),
                            source.predict(outcome.best_fit) if outcome.best_fit else None, outcome.best_name,
                            outcome.final_fit)
