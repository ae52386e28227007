"""`sofia compare SET.yaml --model M.yaml`: fit a model to a measurement set, rank what it lacks.

The loop of a bag comparison (compare.run) on reduced observables: the model's fitted terms are
fitted by Gauss-Newton on residuals whitened by each row's stated sigma (numeric Jacobian, steps of
compare.fit.free_parameters), the ledger adds one fitted term at a time, every catalogue effect not
in the model is linearized where it vanishes and ranked by delta-BIC with analysis.ranking (the
same code `sofia compare` and `sofia noise` use), the best few are refitted in full, collinear ones
are named degenerate. Effects that no table's kind can see are listed as not observable with the
kind's reason; effects a kind could see but this set cannot (columns vanish or the model's terms
absorb them) are listed with that reason.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.optimize import least_squares
from scipy.stats import chi2

from sofia_ros.analysis.ranking import (
    SIGNIFICANT_DELTA_BIC,
    CandidateTerm,
    bic,
    competing_sets,
    degenerate_pairs,
    linear_fit,
    rank_candidates,
)
from sofia_ros.analysis.structure import sigma_of_probability, trend_test
from sofia_ros.compare.competing import competing_document, competing_set_of, contenders, preferred_best, refit_order
from sofia_ros.compare.diagnostics import DETECTION_SIGMA, REPORT_SIGMA
from sofia_ros.compare.verdict import headline, next_step
from sofia_ros.compare.fit import free_parameters, vanishing_values
from sofia_ros.effects import CATALOGUE, NOISE_EFFECTS, resolve_params
from sofia_ros.errors import FitError
from sofia_ros.measurements.format import ALIGNMENT, DRIFT_EFFECTS, KINDS
from sofia_ros.measurements.predict import predict_table, star_geometry
from sofia_ros.noise.earth_rate import DEGENERATE_PAIR, earth_rate_table

__all__ = ['SetCompareResult', 'compare_measurement_set', 'EXPLAINED_QUANTILE']

#: An observable is explained when its chi-square (RMS/floor)^2 n lies below this quantile.
EXPLAINED_QUANTILE = 0.99
#: A candidate parameter whose effect at its thesis magnitude is below this fraction of the candidate's strongest
#: parameter's is not determined by the set (e.g. a LOS scale factor from moves about EL).
WEAK_COLUMN_FRACTION = 1e-2
#: Rate kinds: their residuals are in arcsec/s (= deg/h), the others in arcsec.
_RATE_KINDS = ('earth_rate',)
_ARCSEC_PER_UNIT = {'star_distance': 1.0, 'turning_point': 1.0, 'misalignment_angle': 60.0, 'earth_rate': 1.0}


@dataclass(frozen=True)
class SetCompareResult:
    """The JSON document, the set, the fits before and after the best candidate, per-table predictions."""

    document: dict
    measurement_set: object
    predicted: dict
    predicted_best: dict | None
    best_name: str | None


@dataclass(frozen=True)
class _Fit:
    effects: dict
    free: tuple
    values: np.ndarray
    sigma: np.ndarray
    correlation: np.ndarray
    whitened: np.ndarray
    jacobian: np.ndarray
    rss: float

    @property
    def bic(self):
        return bic(self.rss, len(self.whitened), len(self.free))


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
            shifted = _with_values(effects, free, values)
            shifted[parameter.effect] = {**shifted[parameter.effect], parameter.name: values[index] + parameter.step}
            columns[:, index] = (base - self.whitened(shifted)) / parameter.step
        return columns


def _with_values(effects, free, values):
    out = {name: dict(params) for name, params in effects.items()}
    for parameter, value in zip(free, values):
        out[parameter.effect][parameter.name] = float(value)
    return out


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
        solution = least_squares(lambda values: problem.whitened(_with_values(effects, free, values)), start,
                                 x_scale=steps * 1e3, diff_step=None, method='trf', max_nfev=200 * len(free))
        start = solution.x
    current = _with_values(effects, free, start)
    base = problem.whitened(current)
    if not np.all(np.isfinite(base)):
        raise FitError('the fit left the model undefined for this set (non-finite residuals)')
    jacobian = problem.columns(effects, free, start, base) if free else np.zeros((len(base), 0))
    final = linear_fit(base, jacobian, [p.label for p in free])
    return _Fit(current, tuple(free), start, final.sigma, final.correlation, base, jacobian, float(base @ base))


def _rms(problem, whitened, mask=None):
    residual = whitened * problem.sigma * problem.to_arcsec
    mask = np.ones(len(residual), bool) if mask is None else mask
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


def _blind_reason(name, kinds):
    reasons = []
    for kind in kinds:
        spec = KINDS[kind]
        if name in spec.sees:
            return None
        reasons.append(spec.blind.get(name, spec.default_blind_reason))
    return '; '.join(dict.fromkeys(reasons))


def _linearized_candidates(problem, fit, names):
    terms, vanished = [], {}
    for name in names:
        free = free_parameters([name])
        spec = CATALOGUE[name]
        start = vanishing_values(free)
        switched = {**fit.effects, name: {**resolve_params(name, {}), **dict(zip((p.name for p in free), start))}}
        at_start = problem.whitened(switched)
        columns = problem.columns(switched, free, start, at_start)
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
            absorbed = live & (outside < 1e-3)
            if np.any(absorbed) and not np.all(absorbed == live):
                live = live & ~absorbed
        kept = [p for p, keep in zip(free, live) if keep]
        terms.append((CandidateTerm(name, tuple(p.name for p in kept), start[live], columns[:, live],
                                    fit.whitened - at_start), kept, switched))
    return terms, vanished


def _absorbing_terms(fit, candidates):
    """Candidate -> the single fitted effect whose columns alone absorb the candidate's (analysis.ranking's test)."""
    out = {}
    groups = {}
    for index, parameter in enumerate(fit.free):
        groups.setdefault(parameter.effect, []).append(index)
    for name, term in candidates.items():
        columns = np.asarray(term.jacobian)
        for effect, indices in groups.items():
            base = fit.jacobian[:, indices]
            coefficients, *_ = np.linalg.lstsq(base, columns, rcond=None)
            outside = np.linalg.norm(columns - base @ coefficients, axis=0) / np.maximum(
                np.linalg.norm(columns, axis=0), 1e-300)
            if np.all(outside < 1e-3):
                out[name] = effect
                break
    return out


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


def _candidate_entry(name, params, sigma, rms_after, rms_after_rate, delta_bic, *, detectable=True, refined=False,
                     reason=None):
    units = {param.name: param.unit for param in CATALOGUE[name].params}
    entry = {'effect': name, 'rms_after_arcsec': rms_after, 'delta_bic': delta_bic, 'params': params, 'sigma': sigma,
             'units': {key: units[key] for key in params}, 'detectable': detectable, 'refined': refined,
             'empirical': False, 'observable': None, 'variable': None, 'period_s': None}
    if rms_after_rate is not None:
        entry['rms_after_arcsec_per_s'] = rms_after_rate
    if reason:
        entry['reason'] = reason
    return entry


def _term_table(fit):
    return [{'effect': p.effect, 'param': p.name, 'value': float(v),
             'sigma': None if not np.isfinite(s) else float(s), 'unit': p.unit}
            for p, v, s in zip(fit.free, fit.values, fit.sigma)]


def _signature(problem, whitened):
    """Trends of each observable's whitened residual against its own measured value (e.g. distance, Fig. 6.11).

    The same F-test and family-wise significance as a bag comparison (compare.diagnostics);
    with fewer than 30 rows only a straight line is tested (three cubic terms would eat the power).
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
    return {'trends': sorted(trends, key=lambda t: -t['significance_sigma']), 'periods': [], 'tests_run': count,
            'detection_sigma': DETECTION_SIGMA}


def _observable_status(problem, whitened, signature):
    """Per observable: RMS against the stated sigma, ratio, rows, structure, explained (chi-square quantile)."""
    observables = {}
    for name in dict.fromkeys(problem.observables):
        mask = np.array(problem.observables) == name
        kind = name.split('.')[0]
        n = int(mask.sum())
        scale = (problem.sigma * problem.to_arcsec)[mask]
        rms = float(np.sqrt(np.mean((whitened[mask] * scale) ** 2)))
        floor = float(np.sqrt(np.mean(scale ** 2)))
        ratio = rms / floor
        structure = [f'{t["variable"]}' for t in signature['trends']
                     if t['observable'] == name and t['significance_sigma'] >= DETECTION_SIGMA]
        explained = bool(ratio ** 2 * n <= chi2.ppf(EXPLAINED_QUANTILE, n)) and not structure
        suffix = 'arcsec_per_s' if kind in _RATE_KINDS else 'arcsec'
        observables[name] = {f'rms_{suffix}': rms, f'floor_{suffix}': floor, 'ratio': ratio, 'explained': explained,
                             'rows': n, 'structure': structure}
    return observables


def _after_member(problem, whitened):
    """What the set's comparison says with a candidate refitted in (compare.competing.AfterMember)."""
    observables = _observable_status(problem, whitened, _signature(problem, whitened))
    unexplained = [name for name, entry in observables.items() if not entry['explained']]
    return {'status': 'not explained' if unexplained else 'explained', 'unexplained': unexplained,
            'ratios': {name: entry['ratio'] for name, entry in observables.items()}}


def _verdict(problem, whitened, best, rivals, degenerate, model_source, signature):
    observables = _observable_status(problem, whitened, signature)
    failing = [name for name, entry in observables.items() if not entry['explained']]
    verdict = _judged_set(observables, failing, best, rivals, degenerate, model_source)
    return {**verdict, 'observables': observables, 'headline': headline(verdict['status'], verdict['next'])}


def _judged_set(observables, failing, best, rivals, degenerate, model_source):
    """Status, text and next step of a set's verdict (the bag's rule: compare.verdict)."""
    if not failing:
        return {'status': 'explained', 'next': next_step('none', model_source),
                'text': 'the model explains every observable of the set to its stated sigma; nothing to do'}
    if best is not None:
        tied = [pair for pair in degenerate if best['effect'] in pair]
        choice = ' or '.join(rivals.effects if rivals else tied[0] if tied else (best['effect'],))
        follows = [f'{name} follows {", ".join(observables[name]["structure"])}' for name in failing
                   if observables[name]['structure']]
        text = (f'missing effect {choice} ({", ".join(failing)} beyond the stated sigma'
                + ''.join(f'; {clause}' for clause in follows) + '); '
                + (f'the data cannot choose between them; taken first: {best["effect"]}' if tied or rivals else
                   f'add it with `sofia model add {best["effect"]} --model {model_source}`'))
        return {'status': 'missing_effect', 'text': text, 'next': next_step('add', model_source, effect=best['effect'])}
    return {'status': 'unexplained', 'next': next_step('plugin', model_source, kind='camera'),
            'text': f'{", ".join(failing)} beyond the stated sigma and no catalogue effect explains it'}


def compare_measurement_set(measurement_set, model, *, candidate_names=None):
    """Compare ``model`` (an EffectConfig) with a MeasurementSet; return the SetCompareResult."""
    started = time.perf_counter()
    problem = _Problem(measurement_set)
    kinds = tuple(dict.fromkeys(table.kind for table in measurement_set.tables))
    fitted = [name for name in model.effects if name in model.fitted]
    effects = _start_values(measurement_set, model.effects, fitted)
    # Fitted terms no kind of this set can see are left at their start and listed.
    blind_fitted = {name: _blind_reason(name, kinds) for name in fitted if _blind_reason(name, kinds)}
    if measurement_set.family != ALIGNMENT and any(table.kind == 'star_distance' and table.drift_removed
                                                   for table in measurement_set.tables):
        if all(table.drift_removed for table in measurement_set.tables):
            for name in set(fitted) & set(DRIFT_EFFECTS):
                blind_fitted[name] = 'the drift correction of this set (6.3-6.4) removed constant rate offsets'
    seen = [name for name in fitted if name not in blind_fitted]
    ledger_fit = _fit(problem, effects, ())
    angle, rate = _rms_table(problem, ledger_fit.whitened)
    ledger = [{'term': 'fixed effects only (fitted terms at their start)', 'residual_rms_arcsec': angle,
               'residual_rms_arcsec_per_s': rate}]
    for index in range(len(seen)):
        step = _fit(problem, effects, free_parameters(seen[:index + 1]))
        angle, rate = _rms_table(problem, step.whitened)
        ledger.append({'term': seen[index], 'residual_rms_arcsec': angle, 'residual_rms_arcsec_per_s': rate})
    final = step if seen else ledger_fit
    # Free parameters whose columns vanish are not determined by the set: shown as unconstrained.
    angle, rate = _rms_table(problem, final.whitened)
    names = [name for name in (candidate_names or CATALOGUE) if name not in model.effects and name not in NOISE_EFFECTS]
    blind = {name: _blind_reason(name, kinds) for name in names}
    for name in names:
        if not blind[name] and measurement_set.family != ALIGNMENT and name in DRIFT_EFFECTS and all(
                table.kind == 'star_distance' and table.drift_removed for table in measurement_set.tables):
            blind[name] = 'the drift correction of this set (6.3-6.4) removed constant rate offsets'
    terms, vanished = _linearized_candidates(problem, final, [name for name in names if not blind[name]])
    ranked = rank_candidates(final.whitened, final.jacobian, [term for term, _, _ in terms])
    rss_base = float(final.whitened @ final.whitened)
    entries = {}

    def scaled(total, rss_after):
        return None if total is None else total * float(np.sqrt(rss_after / rss_base))

    absorbed = _absorbing_terms(final, {term.name: term for term, _, _ in terms})
    for candidate in ranked:
        reason = None
        if not candidate.observable:
            by = absorbed.get(candidate.name)
            reason = (f'absorbed by {by}: this set cannot tell them apart' if by
                      else "absorbed by the model's fitted terms in this set")
        entries[candidate.name] = _candidate_entry(candidate.name, candidate.params, candidate.sigma,
                                                   scaled(angle.get('total'), candidate.rss_after),
                                                   scaled(rate.get('total'), candidate.rss_after),
                                                   candidate.delta_bic, detectable=candidate.observable,
                                                   reason=reason)
    by_name = {term.name: (kept, switched) for term, kept, switched in terms}
    refits = {}
    for candidate in refit_order(ranked):
        kept, switched = by_name[candidate.name]
        switched = {**switched, candidate.name: {**switched[candidate.name], **candidate.params}}
        try:
            trial = _fit(problem, switched, final.free + tuple(kept))
        except FitError:
            continue
        extra = trial.free[len(final.free):]
        trial_angle, trial_rate = _rms_table(problem, trial.whitened)
        entries[candidate.name] = _candidate_entry(
            candidate.name, {p.name: float(v) for p, v in zip(extra, trial.values[len(final.free):])},
            {p.name: (float(s) if np.isfinite(s) else None) for p, s in zip(extra, trial.sigma[len(final.free):])},
            trial_angle.get('total'), trial_rate.get('total'), final.bic - trial.bic, refined=True)
        refits[candidate.name] = trial
    for name, reason in {**{n: r for n, r in blind.items() if r}, **vanished}.items():
        entries[name] = _candidate_entry(name, {}, {}, None, None, 0.0, detectable=False, reason=reason)
    candidates = sorted(entries.values(), key=lambda entry: (not entry['detectable'], -entry['delta_bic']))
    ranked_names = {c.name for c in ranked}
    scores = {name: entry['delta_bic'] for name, entry in entries.items() if name in ranked_names}
    degenerate = degenerate_pairs(ranked, scores)
    # A candidate one fitted term absorbs alone is degenerate with it (e.g. heading_error ~ gyro_bias, 5.2.4).
    degenerate = sorted(set(degenerate) | {tuple(sorted((name, by))) for name, by in absorbed.items()
                                           if name in {c.name for c in ranked if not c.observable}})
    competing = competing_sets(ranked, scores)
    after = {name: _after_member(problem, refits[name].whitened) for name in contenders(refits, scores, competing)}
    best_name = preferred_best(after, scores, after)
    best_fit = refits.get(best_name)
    signature = _signature(problem, final.whitened)
    best = next((c for c in candidates if c['effect'] == best_name), None)
    if best is None:
        best = next((c for c in candidates if c['detectable'] and c['delta_bic'] >= SIGNIFICANT_DELTA_BIC), None)
    floors = _rms_table(problem, np.ones(len(problem.sigma)))
    document = {
        'measurement_set': measurement_set.source,
        'title': measurement_set.title,
        'model': model.source,
        'observations': {table.name: {'kind': table.kind, 'rows': len(table.rows),
                                      'drift_removed': table.drift_removed if table.kind == 'star_distance' else None}
                         for table in measurement_set.tables},
        'residual_rms_arcsec': angle,
        'noise_floor_arcsec': floors[0].get('total'),
        'terms': _term_table(final),
        'correlation': {'params': [p.label for p in final.free], 'matrix': np.round(final.correlation, 4).tolist()},
        'ledger': ledger,
        'candidates': candidates,
        'degenerate': [list(pair) for pair in degenerate],
        'competing': competing_document(competing, after),
        'unobservable': [c['effect'] for c in candidates if not c['detectable']],
        'not_observable_fitted_terms': blind_fitted,
        'significant_delta_bic': SIGNIFICANT_DELTA_BIC,
        'signature': signature,
        'verdict': _verdict(problem, final.whitened, best, competing_set_of(best and best['effect'], competing),
                            degenerate, model.source, signature),
        'rows': _rows(problem, final, best_fit),
        'earth_rate': _earth_rate_tables(measurement_set),
        'seconds': {'total': 0.0},
    }
    if rate:
        document['residual_rms_arcsec_per_s'] = rate
        document['noise_floor_arcsec_per_s'] = floors[1].get('total')
    document['seconds']['total'] = round(time.perf_counter() - started, 3)
    predicted = problem.predict(final.effects)
    return SetCompareResult(document, measurement_set, predicted,
                            problem.predict(best_fit.effects) if best_fit else None, best_name)


def _rows(problem, final, best_fit):
    """Per measured value: table, observable, measured, sigma, residual now and after the best candidate."""
    out = []
    after = None if best_fit is None else best_fit.whitened * problem.sigma
    residual = final.whitened * problem.sigma
    labels = [getattr(row, 'move', '') or getattr(row, 'label', '') or getattr(row, 'matrix', '')
              for table in problem.tables for row in table.rows for _ in range(len(table.observable_names())
                                                                                 // len(table.rows))]
    for index, observable in enumerate(problem.observables):
        out.append({'table': problem.table_of[index], 'observable': observable, 'label': labels[index],
                    'measured': float(problem.measured[index]), 'sigma': float(problem.sigma[index]),
                    'residual': float(residual[index]),
                    'residual_after_best': None if after is None else float(after[index])})
    return out
