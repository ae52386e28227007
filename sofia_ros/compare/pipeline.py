"""One comparison for bags and measurement sets (docs/compare.md, "One pipeline for two sources").

A bag (compare.run.BagSource) and a measurement set (measurements.compare.SetSource) are two
sources of one problem: whitened residuals and parameter columns at a fit, a way to fit, a way to
linearize a candidate where it vanishes, observables judged against their floors, and what only
that source adds to the document. `run_comparison` runs the rest once for both:

1. The ledger: the fixed effects alone, then each fitted term of the model added in turn.
2. The judgement of the fit (the source's observables, structure and consistency).
3. Candidates: every catalogue effect not in the model (and the source's empirical shapes)
   linearized where it vanishes and ranked jointly with the model (analysis.ranking); the best
   few refitted in full (compare.competing.refit_order); candidates the model's fitted terms
   absorb, and collinear ones, named degenerate; competing sets.
4. The model's own terms questioned (compare.search.LinearizedModels): model_terms, the best
   change refitted in full, the equivalent models.
5. The contenders refitted and judged again, the preferred best, the verdict (compare.verdict).
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

import numpy as np
import scipy.sparse

from sofia_ros.analysis.ranking import (SIGNIFICANT_DELTA_BIC, CandidateTerm, RankedCandidate, competing_sets,
                                        degenerate_pairs, rank_candidates, whitened_bic)
from sofia_ros.compare.competing import competing_document, contenders, preferred_best, refit_order
from sofia_ros.compare.diagnostics import Diagnostics
from sofia_ros.compare.fit import FreeParameter, free_parameters, vanishing_values, with_values
from sofia_ros.compare.search import (LinearizedModels, equivalent_models, model_terms, rival_swaps, search_pool,
                                     structural_changes)
from sofia_ros.compare.records import CandidateEntry, LedgerRow
from sofia_ros.compare.verdict import after_member, judge
from sofia_ros.effects import CATALOGUE, NOISE_EFFECTS, get_effect, resolve_params
from sofia_ros.effects.empirical import empirical_parts, is_empirical
from sofia_ros.errors import FitError
from sofia_ros.forked import ForkedCall, forked_map
from sofia_ros.progress import Progress

__all__ = ['ABSORBED_FRACTION', 'CHECKED_CHANGES', 'Comparison', 'ComparisonSource', 'Judgement', 'LinearizedCandidate',
           'SourceFit', 'WhitenedFit', 'candidate_entry', 'run_comparison', 'switched_on', 'term_table']

#: A candidate whose columns one fitted effect reproduces to within this fraction of their norm is absorbed by it
#: (the pair is named degenerate). Looser than analysis.ranking's IN_BASE_SPAN_FRACTION: the columns are finite
#: differences of whole predictions, and an effect that one term absorbs only to 1e-4 still cannot be told from it.
ABSORBED_FRACTION = 1e-3
#: Changes of the model's own terms refitted in full, at most, until one is confirmed (_confirmed_change).
CHECKED_CHANGES = 3


class SourceFit(Protocol):
    """A fit of a source's model (compare.fit.ModelFit for a bag, the set's least-squares fit for a set)."""

    effects: dict
    free: tuple
    values: np.ndarray
    sigma: np.ndarray
    correlation: np.ndarray

    @property
    def bic(self) -> float:
        """BIC of the whole whitened problem at the fit (analysis.ranking.whitened_bic)."""


@dataclass(frozen=True, eq=False)
class WhitenedFit:
    """A fit without nuisance parameters (a measurement set's): effects at the fitted values, the fitted
    parameters with sigmas and correlation, the whitened residual and the parameters' columns at the fit."""

    effects: dict
    free: tuple
    values: np.ndarray
    sigma: np.ndarray
    correlation: np.ndarray
    whitened: np.ndarray
    jacobian: np.ndarray

    @property
    def bic(self) -> float:
        """BIC of the whitened residual with the fitted parameters (analysis.ranking.whitened_bic)."""
        return whitened_bic(float(self.whitened @ self.whitened), len(self.whitened), len(self.free))


@dataclass(frozen=True, eq=False)
class Judgement:
    """A fit judged by its source: every observable against its floor with its structure, and the fitted terms
    that change between halves of the data (empty where a source cannot split its data)."""

    diagnostics: Diagnostics
    consistency: list


@dataclass(frozen=True, eq=False)
class LinearizedCandidate:
    """A candidate linearized where it vanishes: its ranking term, the parameters a full refit frees and the
    effects of the fit with the candidate switched on at its start (``term`` None where only those are kept)."""

    term: CandidateTerm | None
    free: tuple
    effects: dict


class ComparisonSource(Protocol):
    """What a bag or a measurement set gives the one comparison (docs/compare.md, "One pipeline").

    ``model_source`` names the model file; ``noun`` ('campaign' or 'set') is how the texts name the
    source; ``observable_keys`` are the keys of an observable's judgement the verdict keeps;
    ``hidden_reason`` is why a candidate the ranking cannot see is hidden where the source knows one
    reason for all (a set's ranking has no expected sizes: only the fitted terms can hide one), else None.
    """

    model_source: str
    noun: str
    observable_keys: tuple
    hidden_reason: str | None

    def ledger_terms(self) -> list[str]:
        """The model's fitted effects the ledger adds one at a time, in the model's order.

        Returns:
            Effect names.
        """

    def ledger_start(self, previous: SourceFit | None, term: str | None) -> dict:
        """Where a ledger step starts.

        Args:
            previous: the fit of the step before (None for the first, the fixed effects alone).
            term: the fitted effect this step adds (None for the first).

        Returns:
            {effect: params} to fit from.
        """

    def given_start(self) -> tuple[dict, Any] | None:
        """The whole model at the values it was given, where the ledger's chain did not start its last step there
        (fitted terms given values of their own, e.g. a refit's written by `sofia model add`), with what fit() starts
        from there (a model the search reached: where the refit that proposed it ended); else None.

        Returns:
            ({effect: params}, fit()'s ``start`` or None), or None.
        """

    def start_of(self, fit: SourceFit) -> Any:
        """Where a fit ended, as a later fit of the same parameters starts from it (fit()'s ``start``): what the
        search's next model takes of a refit (compare.search.ReachedModel). None where fits take no start.

        Args:
            fit: a converged fit.

        Returns:
            The start, a few kB, or None.
        """

    def moved_start(self, fit: SourceFit, nuisance_change: np.ndarray) -> Any:
        """A start like ``fit`` (fit()'s ``start``) with its nuisance parameters (the Jacobian's first columns,
        ranking_problem) moved by ``nuisance_change``: where a candidate's refit starts (_refits).

        Args:
            fit: a converged fit.
            nuisance_change: the change of its nuisance parameters.

        Returns:
            The start.
        """

    def fit(self, effects: dict, free: tuple, start: SourceFit | None) -> SourceFit:
        """Fit ``free`` from ``effects``.

        Args:
            effects: {effect: params} at the starting values.
            free: FreeParameters to fit.
            start: a fit whose nuisance parameters (a bag's attitude anchors) the fit starts from, or None.

        Returns:
            The converged fit.

        Raises:
            FitError: the fit cannot proceed (a prediction is undefined at the start).
        """

    def chain_step(self, term: str | None, effects: dict, free: tuple, start: Any, *,
                   whole: bool = False) -> tuple[Any, LedgerRow]:
        """A step of the ledger's chain: fitted, or read back where the source keeps steps (compare.steps).

        Args:
            term: the fitted effect the step adds (None: the fixed effects alone).
            effects: {effect: params} at the starting values.
            free: FreeParameters to fit.
            start: the step before, or None.
            whole: the step's whole fit is wanted (the chain's last): fitted, and kept for the chains that go on.

        Returns:
            (the step, which the next starts from: a fit or what the source kept of one; its ledger row).
        """

    def ledger_row(self, term: str | None, fit: SourceFit) -> LedgerRow:
        """One row of the ledger.

        Args:
            term: the fitted effect the step added (None: the fixed effects alone).
            fit: the step's fit.

        Returns:
            The row of the JSON's ``ledger``.
        """

    def residual_rms(self, fit: SourceFit) -> dict:
        """The JSON's ``residual_rms_arcsec`` of a fit.

        Args:
            fit: the fit.

        Returns:
            {total, per part}.
        """

    def rms_after(self, fit: SourceFit) -> dict:
        """The total RMS of a fit as a candidate entry names it.

        Args:
            fit: the fit.

        Returns:
            {'rms_after_arcsec': ..., and 'rms_after_arcsec_per_s' where the source has rate observables}.
        """

    def ranking_problem(self, fit: SourceFit) -> tuple[np.ndarray, Any, int]:
        """The whitened linear problem at a fit.

        Args:
            fit: the fit.

        Returns:
            (residual, Jacobian with the nuisance columns first, number of nuisance columns).
        """

    def judge_fit(self, fit: SourceFit) -> Judgement:
        """Every observable of a fit against its floor, its structure, the terms that change between halves.

        Args:
            fit: the fit.

        Returns:
            The Judgement.
        """

    def beyond_floor(self, entry: Mapping) -> bool:
        """Whether an observable's RMS is beyond what its floor allows (the source's rule, docs/compare.md).

        Args:
            entry: the observable's judgement.

        Returns:
            True when the RMS alone leaves the observable unexplained.
        """

    def candidate_names(self, names: list[str], judgement: Judgement) -> list[str]:
        """The candidates to linearize: ``names`` and the source's own (a bag's empirical shapes).

        Args:
            names: the catalogue effects not in the model.
            judgement: the judgement of the model's fit.

        Returns:
            Effect names, ``names`` first and in their order (they are linearized before the judgement is in).
        """

    def linearize(self, fit: SourceFit, names: list[str]) -> tuple[list[LinearizedCandidate], dict[str, str]]:
        """Each candidate linearized where it vanishes.

        Args:
            fit: the model's fit.
            names: candidate effect names.

        Returns:
            (the LinearizedCandidates, {name: why this source cannot see it} for the others).
        """

    def shared_objects(self) -> tuple:
        """The large objects its fits and judgements refer to (a bag's predictor): a forked worker returns them by
        reference (sofia_ros.forked).

        Returns:
            The objects.
        """

    def extra_document(self, outcome: Comparison, progress: Progress) -> dict:
        """What only this source adds to the JSON document.

        Args:
            outcome: the comparison so far (its document holds the common keys).
            progress: where a phase of its own goes.

        Returns:
            {key: value} added to the document.
        """


@dataclass(frozen=True, eq=False)
class Comparison:
    """The outcome of run_comparison: the document and what plots, tables and the search need."""

    document: dict
    final_fit: Any
    best_fit: Any
    best_name: str | None
    judgement: Judgement
    #: where each refitted candidate's fit ended (ComparisonSource.start_of): a model the search reaches by adding
    #: it starts its whole fit there
    refit_starts: dict = dataclasses.field(default_factory=dict)


def switched_on(effects: Mapping, name: str) -> tuple[tuple, np.ndarray, dict]:
    """A candidate switched on where it vanishes: scaling parameters 0, shaping ones at their default.

    Args:
        effects: the fit's {effect: params}.
        name: the candidate effect.

    Returns:
        (its FreeParameters, their vanishing values, the effects with it switched on there).
    """
    free = free_parameters([name])
    start = vanishing_values(free)
    switched = {**effects, name: {**resolve_params(name, {}), **dict(zip((p.name for p in free), start))}}
    return free, start, switched


def _missing_names(model_effects: Iterable[str], candidate_names: Iterable[str] | None) -> list[str]:
    """The catalogue effects (or ``candidate_names``) not in the model, the noise terms aside."""
    present = set(model_effects)
    return [name for name in (candidate_names or CATALOGUE) if name not in present and name not in NOISE_EFFECTS]


def candidate_entry(name: str, params: Mapping, sigma: Mapping, rms_after: Mapping, delta_bic: float, *,
                    detectable: bool = True, refined: bool = False, seconds: float = 0.0,
                    reason: str | None = None) -> CandidateEntry:
    """One candidate of the JSON (docs/compare.md); an empirical one names its observable, variable and period.

    Args:
        name: the effect.
        params: {parameter: value}.
        sigma: {parameter: sigma} (inf where the data do not determine it).
        rms_after: the source's RMS keys with the candidate (rms_after_arcsec, rms_after_arcsec_per_s).
        delta_bic: the BIC's fall with the candidate.
        detectable: whether the source can see it.
        refined: whether it was refitted in full.
        seconds: wall time it took.
        reason: why it is not observable, where the source says.

    Returns:
        The entry.
    """
    spec = get_effect(name)
    units = {param.name: param.unit for param in spec.params}
    entry = {'effect': name, 'rms_after_arcsec': rms_after.get('rms_after_arcsec'), 'delta_bic': delta_bic,
             'params': dict(params), 'sigma': dict(sigma), 'units': {key: units[key] for key in params},
             'detectable': detectable, 'refined': refined, 'seconds': round(seconds, 3),
             'empirical': spec.family == 'empirical', 'observable': None, 'variable': None, 'period_s': None}
    if rms_after.get('rms_after_arcsec_per_s') is not None:
        entry['rms_after_arcsec_per_s'] = rms_after['rms_after_arcsec_per_s']
    if entry['empirical']:
        observable, variable, period_s = empirical_parts(name)
        entry.update(observable=observable, variable=variable, period_s=period_s)
    if reason:
        entry['reason'] = reason
    return entry


def term_table(fit: SourceFit) -> list[dict]:
    """The JSON's ``terms``: each fitted parameter with its unit, value and sigma.

    Args:
        fit: the model's fit.

    Returns:
        [{effect, param, unit, value, sigma}].
    """
    return [{'effect': p.effect, 'param': p.name, 'unit': p.unit, 'value': float(value), 'sigma': float(sigma)}
            for p, value, sigma in zip(fit.free, fit.values, fit.sigma)]


def _ledger(source: ComparisonSource, progress: Progress, jobs: int = 1) -> tuple[list, SourceFit]:
    """The fixed effects alone, then each fitted term switched on and fitted with those before it."""
    terms = source.ledger_terms()
    free_of = [free_parameters([term]) for term in terms]
    free_all = tuple(parameter for free in free_of for parameter in free)
    # The chain's earlier terms absorb what the later ones explain, and the last step can converge from there to
    # another minimum than the values the model was given: a refit's values for a gyro scale factor added last
    # reached BIC 1023 where the chain ended at 140018 (issue 25, multi-effect atlas). The lower of the two is the
    # fit. The fit from the given values depends on nothing the chain does: with --jobs it runs beside it.
    given = source.given_start()
    from_given = None if given is None else ForkedCall(lambda: _fit_or_none(source, *given, free_all), jobs=jobs,
                                                       shared=_shared(source, jobs))
    rows, fit, free = [], None, ()
    try:
        for step, term in enumerate([None, *terms]):
            progress.count('fitting the model, term', step, len(terms))
            if term is not None:
                free = free + free_of[step - 1]
            # The last step's whole fit is the comparison's.
            fit, row = source.chain_step(term, source.ledger_start(fit, term), free, fit, whole=step == len(terms))
            rows.append(row)
    except BaseException:
        if from_given is not None:
            from_given.cancel()
        raise
    if from_given is not None:
        given_fit = from_given.result()
        if given_fit is not None and given_fit.bic < fit.bic:
            fit = given_fit
            rows[-1] = source.ledger_row(terms[-1], fit)
    return rows, fit


def _shared(source: ComparisonSource, jobs: int) -> tuple:
    """What a forked worker returns by reference (ComparisonSource.shared_objects); nothing without workers."""
    return source.shared_objects() if jobs > 1 else ()


def _timed(function: Callable[[Any], Any], argument: Any) -> tuple[Any, float]:
    """function(argument) and the seconds it took."""
    started = time.perf_counter()
    return function(argument), time.perf_counter() - started


def _fit_or_none(source: ComparisonSource, effects: dict, start: Any, free: tuple) -> SourceFit | None:
    """source.fit from ``start``, or None where the values put stars off their detectors (FitError)."""
    try:
        return source.fit(effects, free, start)
    except FitError:
        return None


def _scaled(totals: Mapping, ratio: float) -> dict:
    """The RMS totals a linearized candidate leaves: each total scaled by sqrt(RSS after / RSS now)."""
    return {key: None if value is None else value * float(np.sqrt(ratio)) for key, value in totals.items()}


def _dense(matrix: Any) -> np.ndarray:
    return matrix.toarray() if scipy.sparse.issparse(matrix) else np.asarray(matrix)


def _absorbing_terms(jacobian: Any, nuisance: int, free: Sequence[FreeParameter],
                     candidates: Iterable[CandidateTerm]) -> dict[str, str]:
    """Candidate -> the single fitted effect whose columns alone reproduce the candidate's (ABSORBED_FRACTION)."""
    groups: dict[str, list[int]] = {}
    for index, parameter in enumerate(free):
        groups.setdefault(parameter.effect, []).append(nuisance + index)
    out = {}
    for term in candidates:
        columns = np.asarray(term.jacobian, dtype=float).reshape(jacobian.shape[0], -1)
        for effect, indices in groups.items():
            base = _dense(jacobian[:, indices])
            coefficients, *_ = np.linalg.lstsq(base, columns, rcond=None)
            outside = np.linalg.norm(columns - base @ coefficients, axis=0) / np.maximum(
                np.linalg.norm(columns, axis=0), 1e-300)
            if np.all(outside < ABSORBED_FRACTION):
                out[term.name] = effect
                break
    return out


def _refits(source: ComparisonSource, final: SourceFit, ranked: list[RankedCandidate],
            starts: Mapping[str, LinearizedCandidate], entries: dict, per_candidate_s: float,
            progress: Progress, nuisance: int, jobs: int = 1) -> dict:
    """The best few (compare.competing.refit_order) refitted in full from their linearized values, the model's
    terms and nuisance parameters (its first ``nuisance`` columns) moved as the linearized fit moves them beside
    the candidate (RankedCandidate.base_change), ``jobs`` at a time; their entries replaced. A refit that fails
    leaves the linearized entry standing."""
    order = refit_order(ranked)

    def refit(candidate: RankedCandidate) -> tuple[SourceFit, float] | None:
        started = time.perf_counter()
        start = starts[candidate.name]
        effects = {**start.effects, candidate.name: {**start.effects[candidate.name], **candidate.params}}
        free = final.free + start.free
        change = candidate.base_change
        trial = None
        if change is not None and np.all(np.isfinite(change)):
            moved = with_values(effects, final.free, final.values + change[nuisance:])
            trial = _fit_or_none(source, moved, source.moved_start(final, change[:nuisance]), free)
        # Where the moved start sends a star off its detector, the model's own values may not.
        if trial is None:
            trial = _fit_or_none(source, effects, final, free)
        return None if trial is None else (trial, time.perf_counter() - started)

    progress.count('refitting the best candidates', 0, len(order))
    outcomes = forked_map(refit, order, jobs=jobs, shared=_shared(source, jobs),
                          done=lambda count: progress.count('refitting the best candidates', count, len(order)))
    refits = {}
    for candidate, outcome in zip(order, outcomes):
        if outcome is None:
            continue
        trial, seconds = outcome
        extra = trial.free[len(final.free):]
        entries[candidate.name] = candidate_entry(
            candidate.name, {p.name: float(v) for p, v in zip(extra, trial.values[len(final.free):])},
            {p.name: float(s) for p, s in zip(extra, trial.sigma[len(final.free):])}, source.rms_after(trial),
            final.bic - trial.bic, refined=True, seconds=per_candidate_s + seconds)
        refits[candidate.name] = trial
    return refits


def _checked_change(source: ComparisonSource, change: dict, models: LinearizedModels, final: SourceFit,
                    starts: Mapping[str, LinearizedCandidate]) -> dict | None:
    """The proposed change refitted in full from its linearized values: its real delta-BIC against the model as it
    is, or None if the fit fails."""
    removed = set(change['term'].split(','))
    chosen = {p.effect for p in final.free} - removed | ({change['effect']} - {None})
    effects = {name: params for name, params in final.effects.items() if name not in removed}
    free = tuple(p for p in final.free if p.effect not in removed)
    if change['effect'] is not None:
        incoming = starts[change['effect']]
        effects[change['effect']] = dict(incoming.effects[change['effect']])
        free += incoming.free
    for name, values in models.values(chosen).items():
        effects[name] = {**effects[name], **values}
    try:
        trial = source.fit(effects, free, final)
    except FitError:
        return None
    return {**change, 'delta_bic': float(final.bic - trial.bic)}


def _confirmed_change(source: ComparisonSource, changes: Sequence[dict], swaps: Sequence[dict],
                      models: LinearizedModels, final: SourceFit,
                      starts: Mapping[str, LinearizedCandidate], jobs: int = 1) -> dict | None:
    """The changes the linearization calls significant, then the rival swaps (search.rival_swaps), refitted in full
    in that order until one lowers the BIC significantly: that one, else the best refitted (None if none was).
    At most CHECKED_CHANGES refits. A linearized gain is a guess where terms interact or an effect is far from
    where it was linearized: a one-for-one swap can lose what the two-for-one swap behind it wins. With ``jobs``
    above 1 the refits run that many at a time and are read in the same order: the answer is the same, a refit
    past the one that decides is wasted."""
    significant = [change for change in changes if change['expected_delta_bic'] >= SIGNIFICANT_DELTA_BIC]
    tried = {(change['term'], change['effect']) for change in significant}
    queue = (significant + [swap for swap in swaps if (swap['term'], swap['effect']) not in tried])[:CHECKED_CHANGES]
    best = None
    for first in range(0, len(queue), max(jobs, 1)):
        batch = queue[first:first + max(jobs, 1)]
        for checked in forked_map(lambda change: _checked_change(source, change, models, final, starts), batch,
                                  jobs=jobs, shared=_shared(source, jobs)):
            if checked is not None and (best is None or checked['delta_bic'] > best['delta_bic']):
                best = checked
            if best is not None and best['delta_bic'] >= SIGNIFICANT_DELTA_BIC:
                return best
    return best


def run_comparison(source: ComparisonSource, model_effects: Iterable[str], *,
                   candidate_names: Sequence[str] | None = None, started: float | None = None,
                   progress: Progress | None = None, jobs: int = 1) -> Comparison:
    """Compare a source's model with its data: ledger, ranking, refits, competing sets, model terms, verdict.

    Args:
        source: the bag or measurement set (ComparisonSource).
        model_effects: the model's effect names (not candidates).
        candidate_names: the candidates to try, or None for the catalogue (effects.CATALOGUE, plug-ins included).
        started: perf_counter at which the comparison began (the bag's reading counts), or None for now.
        progress: where the phases go (Progress), or None for nowhere.
        jobs: the most forked workers at a time for the fits that do not depend on each other (sofia_ros.forked):
            the fit from the model's given values beside the ledger's chain, the refits, the judgements of the
            contenders and the checked changes. The results are the same as with 1.

    Returns:
        The Comparison, its document complete with the source's own keys.

    Raises:
        FitError: the model's own fit fails.
    """
    started = time.perf_counter() if started is None else started
    progress = progress or Progress.silent()
    ledger, final = _ledger(source, progress, jobs)
    rms = source.residual_rms(final)
    totals = source.rms_after(final)

    progress.phase('residual diagnostics')
    catalogue = _missing_names(model_effects, candidate_names)
    # The judgement names the empirical shapes to try; the catalogue's candidates do not wait for it: with --jobs
    # they are linearized while a worker judges (in one process after it, their columns not held through it).
    early = catalogue if jobs > 1 else []
    judging = ForkedCall(lambda: _timed(source.judge_fit, final), jobs=jobs, shared=_shared(source, jobs))
    linear_started = time.perf_counter()
    try:
        linearized, unseen = source.linearize(final, early) if early else ([], {})
        linear_s = time.perf_counter() - linear_started
        judgement, diagnostics_s = judging.result()
    except BaseException:
        judging.cancel()
        raise
    names = source.candidate_names(catalogue, judgement)
    progress.phase(f'linearizing {len(names)} candidate effects')
    linear_started = time.perf_counter()
    more, more_unseen = source.linearize(final, names[len(early):])
    linearized, unseen = linearized + more, {**unseen, **more_unseen}
    terms = [candidate.term for candidate in linearized]
    residual, jacobian, nuisance = source.ranking_problem(final)
    # Ranked on every row at full weight: a model failure confined to one camera makes all its rows
    # "outliers", and the Huber weights that protect a bag's fit would hide that failure from the ranking.
    ranked = rank_candidates(residual, jacobian, terms, whitened_bic)
    per_candidate_s = (linear_s + time.perf_counter() - linear_started) / max(len(terms), 1)
    rss_base = float(residual @ residual)
    hidden = [candidate for candidate in ranked if not candidate.observable]
    absorbed = _absorbing_terms(jacobian, nuisance, final.free,
                                [term for term in terms if term.name in {c.name for c in hidden}])
    entries = {}
    for candidate in ranked:
        reason = None
        if not candidate.observable:
            by = absorbed.get(candidate.name)
            reason = f'absorbed by {by}: this {source.noun} cannot tell them apart' if by else source.hidden_reason
        entries[candidate.name] = candidate_entry(candidate.name, candidate.params, candidate.sigma,
                                                  _scaled(totals, candidate.rss_after / rss_base), candidate.delta_bic,
                                                  detectable=candidate.observable, seconds=per_candidate_s,
                                                  reason=reason)
    # Every model within reach, linearized over all the candidates before the refits (the search's pool, taken
    # after them, is a part of it): the candidates' columns and the fit's Jacobian (on a star hop about 190 and
    # 40 MB) have then served the ranking and the linearized models, and the refits, the checked change and the
    # judgements fit and hold more. Where each candidate starts is what those need of it.
    every_model = LinearizedModels.at_fit(residual, jacobian, final.free, final.values, nuisance, terms)
    starts = {candidate.term.name: dataclasses.replace(candidate, term=None) for candidate in linearized}
    del linearized, more, terms, jacobian
    refits = _refits(source, final, ranked, starts, entries, per_candidate_s, progress, nuisance, jobs)
    refit_starts = {name: start for name, fit in refits.items() if (start := source.start_of(fit)) is not None}
    scores = {candidate.name: entries[candidate.name]['delta_bic'] for candidate in ranked}
    for name, reason in unseen.items():
        entries[name] = candidate_entry(name, {}, {}, {}, 0.0, detectable=False, reason=reason)
    candidates = sorted(entries.values(), key=lambda entry: (not entry['detectable'], -entry['delta_bic']))
    # A candidate one fitted term absorbs alone is degenerate with it (e.g. heading_error ~ gyro_bias, 5.2.4).
    degenerate = sorted(set(degenerate_pairs(ranked, scores))
                        | {tuple(sorted((name, by))) for name, by in absorbed.items()})
    competing = competing_sets(ranked, scores, preferred=lambda name: not is_empirical(name))
    # Only the contenders are judged again: the other refits go before the model's own terms are refitted (a bag's,
    # released of its columns, still holds its residuals and weights: about 6 MB each on a star hop).
    refits = {name: refits[name] for name in contenders(refits, scores, competing)}

    progress.phase('alternative models')
    alternatives_started = time.perf_counter()
    fitted_now = frozenset(p.effect for p in final.free)
    models = every_model.restricted_to(search_pool(every_model.names, [entries[name] for name in scores]))
    del every_model
    own_terms = model_terms(models, fitted_now)
    change = _confirmed_change(source, structural_changes(models, fitted_now, CHECKED_CHANGES),
                               rival_swaps(models, fitted_now, own_terms), models, final, starts, jobs)
    alternatives_s = time.perf_counter() - alternatives_started

    progress.phase('diagnostics after the contenders')
    diagnostics_started = time.perf_counter()
    after = dict(zip(refits, forked_map(source.judge_fit, list(refits.values()), jobs=jobs,
                                        shared=_shared(source, jobs))))
    diagnostics_s += time.perf_counter() - diagnostics_started
    members = {name: after_member(judged.diagnostics, judged.consistency) for name, judged in after.items()}
    best_name = preferred_best(after, scores, members, competing)
    after_best = after.get(best_name)
    verdict = judge(judgement.diagnostics, judgement.consistency, candidates, degenerate, best_name,
                    None if after_best is None else (after_best.diagnostics, after_best.consistency),
                    competing=competing, members=members, change=change, rms_arcsec=totals.get('rms_after_arcsec'),
                    rms_arcsec_per_s=totals.get('rms_after_arcsec_per_s'),
                    significant_delta_bic=SIGNIFICANT_DELTA_BIC, model_source=source.model_source,
                    observable_keys=source.observable_keys, beyond_floor=source.beyond_floor,
                    measurements=final.whitened.size, fitted=[p.label for p in final.free],
                    unconstrained=[p.label for p, sigma in zip(final.free, final.sigma) if not np.isfinite(sigma)])
    document = {
        'model': source.model_source,
        'residual_rms_arcsec': rms,
        'terms': term_table(final),
        'correlation': {'params': [p.label for p in final.free], 'matrix': np.round(final.correlation, 4).tolist()},
        'ledger': ledger,
        'candidates': candidates,
        'degenerate': [list(pair) for pair in degenerate],
        'competing': competing_document(competing, members),
        'model_terms': own_terms,
        'model_change': change,
        'equivalent_models': equivalent_models(models, fitted_now),
        'unobservable': [c['effect'] for c in candidates if not c['detectable']],
        'significant_delta_bic': SIGNIFICANT_DELTA_BIC,
        'signature': judgement.diagnostics.as_document(),
        'verdict': verdict,
        'seconds': {'total': 0.0, 'per_candidate': round(per_candidate_s, 4), 'diagnostics': round(diagnostics_s, 3),
                    'model_terms': round(alternatives_s, 3)},
    }
    outcome = Comparison(document, final, refits.get(best_name), best_name, judgement, refit_starts)
    document.update(source.extra_document(outcome, progress))
    document['seconds']['total'] = round(time.perf_counter() - started, 3)
    return outcome

