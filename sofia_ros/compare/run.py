"""`sofia compare`: fit a model to a bag, keep the ledger, rank the missing effects (docs/compare.md).

1. Read the observables (compare.observations) and the centroid noise floor (compare.floor).
2. Fit the model: first with its fitted terms at their given values (anchors only), then adding
   each fitted term in turn - the ledger of residual RMS per camera, like a pointing-model fit.
3. Diagnostics (compare.diagnostics): every camera axis and gyro axis against its own noise,
   trends and periods with family-wise significances, and the fitted terms refitted on halves
   of the data (a term that changes between them absorbs something else).
4. Candidates: every catalogue effect not in the model, and an empirical term for each shape
   the diagnostics found (effects.empirical), is linearized where it vanishes and fitted
   jointly with the model (analysis.ranking); the best few are refitted in full and judged
   again. Effects the campaign cannot see are listed as unobservable, collinear ones as degenerate.
5. The verdict (compare.verdict): explained only when every observable is.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from sofia_ros.analysis.ranking import (SIGNIFICANT_DELTA_BIC, CandidateTerm, competing_sets, degenerate_pairs,
                                        rank_candidates)
from sofia_ros.compare.fit import WhitenedProblem, fit_model, free_parameters, vanishing_values
from sofia_ros.compare.floor import angle_random_walk_rad_per_sqrt_s, centroid_noise_arcsec
from sofia_ros.compare.observations import read_observations
from sofia_ros.compare.predict import Predictor
from sofia_ros.compare.prior import anchor_prior
from sofia_ros.compare.diagnostics import residual_diagnostics, split_consistency
from sofia_ros.compare.competing import competing_document, contenders, preferred_best, refit_order
from sofia_ros.compare.verdict import after_member, empirical_candidate_names, judge
from sofia_ros.compare.search import LinearizedModels, equivalent_models, model_terms, search_pool, structural_change
from sofia_ros.compare.star_hop import hold_windows, star_hop_analysis
from sofia_ros.effects import CATALOGUE, NOISE_EFFECTS, get_effect, resolve_params
from sofia_ros.effects.empirical import empirical_parts, is_empirical
from sofia_ros.errors import FitError
from sofia_ros.progress import Progress
from sofia_ros.sensors.gyro_noise import rrw_deg_per_h_sqrt_h_to_arcsec_per_s_sqrt_s
from sofia_ros.units import ARCSEC_PER_RAD

__all__ = ['CompareResult', 'compare_bag', 'compare_observations']



@dataclass(frozen=True, eq=False)
class CompareResult:
    """The comparison: the JSON document of docs/compare.md plus what plots and tables need."""

    document: dict
    observations: object
    final_fit: object
    best_fit: object
    best_name: str | None
    predictor: object
    candidate_terms: tuple = ()


def _rms_by_camera(fit, centroids):
    """Residual RMS ["] per camera and in total over both axes, every row counted (outliers are also listed)."""
    squares = np.sum(fit.residual_arcsec**2, axis=1)
    rms = {'total': float(np.sqrt(np.mean(squares) / 2.0))}
    for index, camera in enumerate(centroids.cameras):
        rows = centroids.camera_index == index
        if np.any(rows):
            rms[camera] = float(np.sqrt(np.mean(squares[rows]) / 2.0))
    return rms


def _outliers_by_camera(fit, centroids):
    """Rows beyond OUTLIER_SIGMA per camera (Huber-weighted in the fit, never dropped)."""
    return {camera: int(np.sum(fit.outlier & (centroids.camera_index == index)))
            for index, camera in enumerate(centroids.cameras)}


def _term_table(fit):
    return [{'effect': p.effect, 'param': p.name, 'unit': p.unit, 'value': float(value), 'sigma': float(sigma)}
            for p, value, sigma in zip(fit.free, fit.values, fit.sigma)]


def _linearized_candidates(predictor, fit, noise_arcsec, prior, names):
    """CandidateTerms linearized where each effect vanishes: scaling parameters 0, shaping ones at default."""
    problem = WhitenedProblem(predictor, noise_arcsec, prior)
    base = predictor.predict_px(fit.effects, fit.anchors_rad)
    # Shared by every candidate: the attitude derivative at the fit (each term starts where it vanishes).
    derivative = problem.irf_derivative(fit.effects, fit.anchors_rad, base)
    terms = []
    for name in names:
        free = free_parameters([name])
        if not free:
            continue
        spec = get_effect(name)
        start = vanishing_values(free)
        switched = {**fit.effects, name: {**resolve_params(name, {}), **dict(zip((p.name for p in free), start))}}
        at_start = predictor.predict_px(switched, fit.anchors_rad)
        columns = problem.parameter_columns(switched, free, start, fit.anchors_rad, at_start, derivative)
        shift = problem.scaled(at_start - base)
        # The anchors' prior rows do not depend on any effect: zeros there.
        prior_rows = len(fit.prior_residual)
        # The size the effect is expected at: its thesis magnitudes (shaping parameters do not scale it).
        reference = np.array([0.0 if spec.parameter(p.name).shape else float(spec.parameter(p.name).default)
                              for p in free])
        if not np.any(reference):
            reference = None  # no expected size (empirical terms, plug-ins defaulting to zero)
        terms.append(CandidateTerm(name, tuple(p.name for p in free), start,
                                   np.vstack([columns, np.zeros((prior_rows, len(free)))]),
                                   np.concatenate([shift, np.zeros(prior_rows)]), reference))
    return terms


def _candidate_entry(name, params, sigma, rms_after, delta_bic, *, detectable=True, refined=False, seconds=0.0):
    """One candidate of the JSON (docs/compare.md); an empirical one names its observable, variable and period."""
    spec = get_effect(name)
    units = {param.name: param.unit for param in spec.params}
    entry = {'effect': name, 'rms_after_arcsec': rms_after, 'delta_bic': delta_bic, 'params': params, 'sigma': sigma,
             'units': {key: units[key] for key in params}, 'detectable': detectable, 'refined': refined,
             'seconds': round(seconds, 3), 'empirical': spec.family == 'empirical', 'observable': None,
             'variable': None, 'period_s': None}
    if entry['empirical']:
        observable, variable, period_s = empirical_parts(name)
        entry.update(observable=observable, variable=variable, period_s=period_s)
    return entry


def _checked_change(change, models, predictor, final, noise_arcsec, prior):
    """The proposed change refitted in full from its linearized values: its real delta-BIC against the model as it
    is, or None if the fit fails."""
    if change is None or change['expected_delta_bic'] < SIGNIFICANT_DELTA_BIC:
        return None  # a change the linearization already calls insignificant is not worth a full fit
    removed = set(change['term'].split(','))
    chosen = {p.effect for p in final.free} - removed | ({change['effect']} - {None})
    linearized = models.values(chosen)
    effects = {name: params for name, params in final.effects.items() if name not in removed}
    free = tuple(p for p in final.free if p.effect not in removed)
    if change['effect'] is not None:
        effects[change['effect']] = resolve_params(change['effect'], {})
        free += free_parameters([change['effect']])
    for name, values in linearized.items():
        effects[name] = {**effects[name], **values}
    try:
        trial = fit_model(predictor, effects, free, noise_arcsec, prior, anchors_rad=final.anchors_rad)
    except FitError:
        return None
    return {**change, 'delta_bic': float(final.bic - trial.bic)}


def compare_bag(bag_path, model, *, anchor_spacing_s=30.0, candidate_names=None, progress=None):
    """Compare ``model`` (an EffectConfig) with the bag; return the CompareResult."""
    started = time.perf_counter()
    progress = progress or Progress.silent()
    progress.phase('reading the bag')
    return compare_observations(read_observations(bag_path), model, anchor_spacing_s=anchor_spacing_s,
                                candidate_names=candidate_names, started=started, progress=progress)


def compare_observations(observations, model, *, anchor_spacing_s=30.0, candidate_names=None, started=None,
                         progress=None):
    """Compare ``model`` with observations already read (compare.observations); return the CompareResult."""
    started = time.perf_counter() if started is None else started
    progress = progress or Progress.silent()
    centroids = observations.centroids
    noise_arcsec = centroid_noise_arcsec(centroids)
    counts = np.bincount(centroids.camera_index, minlength=len(centroids.cameras))
    floor_arcsec = float(np.sqrt(np.sum(counts * noise_arcsec**2) / np.sum(counts)))
    predictor = Predictor(observations, anchor_spacing_s=anchor_spacing_s)
    effects = {name: dict(params) for name, params in model.effects.items()}
    arw = angle_random_walk_rad_per_sqrt_s(observations.gyro)
    # Rate random walk from the model's noise terms, else Table 5.1 (gyro_noise defaults).
    rrw_deg_per_h_sqrt_h = effects.get('gyro_noise', resolve_params('gyro_noise', {}))['rrw_deg_per_h_sqrt_h']
    rrw = rrw_deg_per_h_sqrt_h_to_arcsec_per_s_sqrt_s(rrw_deg_per_h_sqrt_h) / ARCSEC_PER_RAD
    predictor.align_initial_attitude(effects)
    knots = predictor.anchor_knots_s
    prior = anchor_prior(knots, predictor.attitudes(effects, (knots[:-1] + knots[1:]) / 2.0), arw, rrw)
    fitted_order = [name for name in model.effects if name in model.fitted]

    # The ledger, as a pointing-model fit prints it: the fixed effects alone, then each fitted term
    # switched on (at its given values) and fitted together with those before it.
    ledger, fit, free = [], None, ()
    for step, step_name in enumerate([None, *fitted_order]):
        progress.count('fitting the model, term', step, len(fitted_order))
        if step_name is None:
            start = {name: params for name, params in effects.items() if name not in model.fitted}
        else:
            free = free + free_parameters([step_name])
            start = {**fit.effects, step_name: effects[step_name]}
        fit = fit_model(predictor, start, free, noise_arcsec, prior,
                        anchors_rad=None if fit is None else fit.anchors_rad)
        ledger.append({'term': step_name or 'fixed effects only (attitude anchors fitted)',
                       'residual_rms_arcsec': _rms_by_camera(fit, centroids), 'bic': fit.bic})
    final = fit
    rms = _rms_by_camera(final, centroids)

    progress.phase('residual diagnostics')
    diagnostics_started = time.perf_counter()
    diagnostics = residual_diagnostics(observations, final, predictor, noise_arcsec, prior)
    consistency = split_consistency(observations, final, predictor)
    diagnostics_s = time.perf_counter() - diagnostics_started
    names = [name for name in (candidate_names or CATALOGUE) if name not in effects and name not in NOISE_EFFECTS]
    names += [name for name in empirical_candidate_names(diagnostics, observations.centroids.cameras, consistency)
              if name not in effects]
    progress.phase(f'linearizing {len(names)} candidate effects')
    linear_started = time.perf_counter()
    terms = _linearized_candidates(predictor, final, noise_arcsec, prior, names)
    # Ranked on every row at full weight: a model failure confined to one camera makes all its rows
    # "outliers", and the Huber weights that protect the fit would hide that failure from the ranking.
    ranked = rank_candidates(final.augmented_residual, final.jacobian, terms)
    per_candidate_s = (time.perf_counter() - linear_started) / max(len(terms), 1)
    rss_base = float(final.augmented_residual @ final.augmented_residual)
    entries = {}
    for candidate in ranked:
        rms_after = rms['total'] * float(np.sqrt(candidate.rss_after / rss_base))
        entries[candidate.name] = _candidate_entry(candidate.name, candidate.params, candidate.sigma, rms_after,
                                                   candidate.delta_bic, detectable=candidate.observable,
                                                   seconds=per_candidate_s)
    refits = {}
    order = refit_order(ranked)
    for done, candidate in enumerate(order):
        progress.count('refitting the best candidates', done, len(order))
        refine_started = time.perf_counter()
        trial_effects = {**final.effects, candidate.name: dict(resolve_params(candidate.name, {}), **candidate.params)}
        try:
            trial = fit_model(predictor, trial_effects, final.free + free_parameters([candidate.name]), noise_arcsec,
                              prior, anchors_rad=final.anchors_rad)
        except FitError:
            continue  # the linearized entry stands
        extra = trial.free[len(final.free):]
        entries[candidate.name] = _candidate_entry(
            candidate.name, {p.name: float(v) for p, v in zip(extra, trial.values[len(final.free):])},
            {p.name: float(s) for p, s in zip(extra, trial.sigma[len(final.free):])},
            _rms_by_camera(trial, centroids)['total'], final.bic - trial.bic, refined=True,
            seconds=per_candidate_s + time.perf_counter() - refine_started)
        refits[candidate.name] = trial
    candidates = sorted(entries.values(), key=lambda entry: (not entry['detectable'], -entry['delta_bic']))
    scores = {name: entry['delta_bic'] for name, entry in entries.items()}
    degenerate = degenerate_pairs(ranked, scores)
    competing = competing_sets(ranked, scores, preferred=lambda name: not is_empirical(name))
    progress.phase('alternative models')
    alternatives_started = time.perf_counter()
    fitted_now = frozenset(p.effect for p in final.free)
    models = LinearizedModels.at_fit(final.augmented_residual, final.jacobian, final.free, final.values,
                                     final.anchors_rad.size, search_pool(terms, list(entries.values())))
    change = _checked_change(structural_change(models, fitted_now), models, predictor, final, noise_arcsec, prior)
    alternatives_s = time.perf_counter() - alternatives_started
    progress.phase('diagnostics after the contenders')
    diagnostics_started = time.perf_counter()
    after = {name: (residual_diagnostics(observations, refits[name], predictor, noise_arcsec, prior),
                    split_consistency(observations, refits[name], predictor))
             for name in contenders(refits, scores, competing)}
    diagnostics_s += time.perf_counter() - diagnostics_started
    members = {name: after_member(*pair) for name, pair in after.items()}
    best_name = preferred_best(after, scores, members)
    best_fit = refits.get(best_name)
    after_best = after.get(best_name)
    document = {
        'bag': str(observations.bag_path),
        'model': model.source,
        'observations': {camera: int(count) for camera, count in zip(centroids.cameras, counts)},
        'residual_rms_arcsec': rms,
        'noise_floor_arcsec': floor_arcsec,
        'centroid_noise_arcsec': {camera: float(v) for camera, v in zip(centroids.cameras, noise_arcsec)},
        'outliers': int(np.sum(final.outlier)),
        'outliers_by_camera': _outliers_by_camera(final, centroids),
        'terms': _term_table(final),
        'correlation': {'params': [p.label for p in final.free], 'matrix': np.round(final.correlation, 4).tolist()},
        'ledger': ledger,
        'candidates': candidates,
        'degenerate': [list(pair) for pair in degenerate],
        'competing': competing_document(competing, members),
        'model_terms': model_terms(models, fitted_now),
        'model_change': change,
        'equivalent_models': equivalent_models(models, fitted_now),
        'unobservable': [c['effect'] for c in candidates if not c['detectable']],
        'significant_delta_bic': SIGNIFICANT_DELTA_BIC,
        'signature': diagnostics.as_document(),
        'consistency': consistency,
        'verdict': judge(diagnostics, consistency, candidates, degenerate, best_name, after_best,
                         competing=competing, members=members, change=change,
                         rms_arcsec=rms['total'], significant_delta_bic=SIGNIFICANT_DELTA_BIC, model_source=model.source),
        'anchor_spacing_s': anchor_spacing_s,
        'anchor_walk_sigma_arcsec': prior.unit_rad * ARCSEC_PER_RAD,
        'angle_random_walk_arcsec_per_sqrt_s': arw * ARCSEC_PER_RAD,
        'seconds': {'total': 0.0, 'per_candidate': round(per_candidate_s, 4), 'diagnostics': round(diagnostics_s, 3),
                    'model_terms': round(alternatives_s, 3)},
    }
    windows = hold_windows(observations.calibration_result) if observations.calibration_result else None
    if windows:
        progress.phase('star-hop hold analysis')
        fpi_noise_arcsec = float(noise_arcsec[centroids.cameras.index('fpi')]) if 'fpi' in centroids.cameras else None
        document['star_hop'] = star_hop_analysis(predictor, final.effects, windows, fpi_noise_arcsec=fpi_noise_arcsec,
                                                 arw_rad_per_sqrt_s=arw)
    document['seconds']['total'] = round(time.perf_counter() - started, 3)
    return CompareResult(document, observations, final, best_fit, best_name, predictor, tuple(terms))

