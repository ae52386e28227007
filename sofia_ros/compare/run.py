"""`sofia compare BAG`: a bag as a source of the one comparison (compare.pipeline, docs/compare.md).

1. Read the observables (compare.observations) and the centroid noise floor (compare.floor).
2. The bag's problem: centroids whitened by each camera's noise, the attitude anchors under
   their gyro-noise prior as nuisance columns, the robust fit of compare.fit; the ledger starts
   with the fitted terms left out and adds each one at its given values.
3. The bag's judgement (compare.diagnostics): every camera axis and gyro axis against its own
   noise (RMS / floor and the excess test), trends and periods with family-wise significances,
   and the fitted terms refitted on halves of the data (a term that changes between them
   absorbs something else); empirical terms for the shapes it finds (effects.empirical).
4. Candidates linearized where they vanish, through the attitude derivative at the fit.
5. What only a bag adds: the signature's consistency, the camera tables, the anchors, and a
   star hop's hold analysis (compare.star_hop).
"""

from __future__ import annotations

import copy
import hashlib
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

from sofia_ros.analysis.ranking import CandidateTerm
from sofia_ros.compare.diagnostics import residual_diagnostics, row_variables, split_consistency
from sofia_ros.compare.fit import FitStart, ModelFit, WhitenedProblem, fit_model
from sofia_ros.compare.floor import angle_random_walk_rad_per_sqrt_s, centroid_noise_arcsec
from sofia_ros.compare.observations import content_key, read_observations, record_fields, step_store
from sofia_ros.compare.pipeline import Comparison, Judgement, LinearizedCandidate, run_comparison, switched_on
from sofia_ros.compare.predict import Predictor
from sofia_ros.compare.prior import anchor_prior
from sofia_ros.compare.star_hop import hold_windows, star_hop_analysis
from sofia_ros.compare.records import LedgerRow
from sofia_ros.compare.search import chain_effects, refit_start
from sofia_ros.compare.steps import ChainStep, StepStore, step_key
from sofia_ros.compare.verdict import BAG_OBSERVABLE_KEYS, beyond_bag_floor, empirical_candidate_names
from sofia_ros.config import EffectConfig
from sofia_ros.effects import get_effect, resolve_params
from sofia_ros.progress import Progress
from sofia_ros.sensors.gyro_noise import rrw_deg_per_h_sqrt_h_to_arcsec_per_s_sqrt_s
from sofia_ros.units import ARCSEC_PER_RAD

__all__ = ['BagSource', 'CompareResult', 'compare_bag', 'compare_observations']


@dataclass(frozen=True, eq=False)
class CompareResult:
    """The comparison: the JSON document of docs/compare.md plus what plots and tables need."""

    document: dict
    observations: Any
    final_fit: Any
    best_fit: Any
    best_name: str | None
    predictor: Any
    #: where each refitted candidate's fit ended (compare.pipeline.Comparison)
    refit_starts: dict = field(default_factory=dict)


def _hash_arrays(digest: Any, observations: Any) -> None:
    """Feed ``digest`` every field of the observations, their centroids and gyro samples, arrays by their bytes."""
    for name, value in record_fields(observations):
        if isinstance(value, np.ndarray):
            digest.update(f'{name} {value.dtype} {value.shape}\0'.encode())
            # The buffer itself: a copy of the gyro rates alone is 56 MB on a star hop.
            digest.update(np.ascontiguousarray(value).reshape(-1).view(np.uint8))
        elif name not in {'bag_path', 'scenario', 'centroids', 'gyro'}:
            digest.update(f'{name} {value!r}\0'.encode())


class BagSource:
    """A bag's observations as a source of the one comparison (compare.pipeline.ComparisonSource).

    Residuals are centroids whitened by each camera's noise; the attitude anchors, under their
    gyro-noise prior (compare.prior), are the nuisance columns of every fit.
    """

    noun = 'campaign'
    observable_keys = BAG_OBSERVABLE_KEYS
    hidden_reason = None
    #: RMS / floor above 1.2 with a 5-sigma excess (compare.diagnostics).
    beyond_floor = staticmethod(beyond_bag_floor)

    def __init__(self, observations: Any, model: EffectConfig, *, anchor_spacing_s: float = 30.0,
                 steps: StepStore | None = None) -> None:
        """Set up the bag's problem: noise floors, predictor, the anchors' prior.

        Args:
            observations: the bag's observations (compare.observations.read_observations).
            model: the model compared (EffectConfig).
            anchor_spacing_s: seconds between attitude anchors.
            steps: where the ledger's steps are kept (compare.steps), or None for this process's memory.
        """
        self.observations = observations
        self.steps = steps or StepStore()
        self.model = model
        self.model_source = model.source
        self.anchor_spacing_s = anchor_spacing_s
        centroids = observations.centroids
        self.noise_arcsec = centroid_noise_arcsec(centroids)
        self.counts = np.bincount(centroids.camera_index, minlength=len(centroids.cameras))
        self.predictor = Predictor(observations, anchor_spacing_s=anchor_spacing_s)
        self.effects = {name: dict(params) for name, params in model.effects.items()}
        # Where the ledger's chain starts each term: a model the search reached starts them where the model it came
        # from was given them (compare.search.ReachedModel), so that the chain reads that model's steps back.
        self.chain_effects = {name: dict(params) for name, params in chain_effects(model).items()}
        self.arw = angle_random_walk_rad_per_sqrt_s(observations.gyro)
        # Rate random walk from the model's noise terms, else Table 5.1 (gyro_noise defaults).
        rrw_deg_per_h_sqrt_h = self.effects.get('gyro_noise', resolve_params('gyro_noise', {}))['rrw_deg_per_h_sqrt_h']
        rrw = rrw_deg_per_h_sqrt_h_to_arcsec_per_s_sqrt_s(rrw_deg_per_h_sqrt_h) / ARCSEC_PER_RAD
        # The start attitude and the prior from the fixed effects alone, where the ledger's chain starts: a step
        # of the chain then depends on its own terms only, the same in every model that shares the chain so far.
        fixed = self.ledger_start(None, None)
        self.predictor.align_initial_attitude(fixed)
        knots = self.predictor.anchor_knots_s
        self.prior = anchor_prior(knots, self.predictor.attitudes(fixed, (knots[:-1] + knots[1:]) / 2.0),
                                  self.arw, rrw)

    def ledger_terms(self) -> list[str]:
        """The model's fitted effects in its order (ComparisonSource.ledger_terms).

        Returns:
            Effect names.
        """
        return [name for name in self.model.effects if name in self.model.fitted]

    def ledger_start(self, previous: ModelFit | None, term: str | None) -> dict:
        """The fixed effects alone first; then the fit so far with ``term`` at its given values (a model the search
        reached: where the model it came from was given them, compare.search.ReachedModel).

        Args:
            previous: the fit of the step before, or None.
            term: the fitted effect the step adds, or None.

        Returns:
            {effect: params}.
        """
        if previous is None:
            return {name: params for name, params in self.chain_effects.items() if name not in self.model.fitted}
        return {**previous.effects, term: self.chain_effects[term]}

    @cached_property
    def problem_digest(self) -> str:
        """A digest of what every fit of this bag shares: the observations, the noise floors, the start attitude,
        the anchors' knots and prior.

        Observations read through the observation cache stand by the bag's cache key (observations.content_key):
        the reader's version and every file of the bag by name, size, mtime and content or MCAP footer, the same
        key that lets the cache serve them for the bag, and they are read-only. Others are hashed whole (about
        100 MB on a star hop, 0.2 s). The step keys add the code (compare.steps.code_fingerprint), the reader's
        with it.
        """
        digest = hashlib.sha256(repr((self.observations.scenario, self.anchor_spacing_s)).encode())
        key = content_key(self.observations)
        if key is not None:
            digest.update(f'bag {key}\0'.encode())
        else:
            _hash_arrays(digest, self.observations)
        prior = self.prior.matrix.tocsr()
        for array in (self.noise_arcsec, self.predictor.initial_dcm, self.predictor.anchor_knots_s, prior.data,
                      prior.indices, prior.indptr, self.prior.whitening, np.array([self.prior.unit_rad])):
            digest.update(np.ascontiguousarray(array).tobytes())
        return digest.hexdigest()

    def chain_step(self, term: str | None, effects: dict, free: tuple, start: Any, *,
                   whole: bool = False) -> tuple[Any, LedgerRow]:
        """A step of the ledger's chain, read back where this bag, code and chain fitted it before (compare.steps),
        else fitted and kept; the chain's last (``whole``) is always fitted, and kept for the model's next round
        (ComparisonSource.chain_step).

        Args:
            term: the fitted effect the step adds, or None.
            effects: {effect: params} it starts from.
            free: FreeParameters to fit.
            start: the step before (a ModelFit or ChainStep), or None.
            whole: the step's whole fit is wanted.

        Returns:
            (the step, its ledger row).
        """
        key = step_key(self.problem_digest, effects, [p.label for p in free],
                       None if start is None else start.anchors_rad, [] if start is None else [p.label for p in start.free])
        kept = None if whole else self.steps.get(key, free)
        if kept is not None:
            return kept, kept.row
        # With its columns: the chain's last is the comparison's fit, judged and ranked at once.
        fit = self._fitted(effects, free, start)
        row = self.ledger_row(term, fit)
        # Copies: the step outlives this fit, whose effects and anchors its callers may change.
        self.steps.put(key, ChainStep(copy.deepcopy(fit.effects), tuple(free), np.array(fit.anchors_rad),
                                      float(fit.bic), copy.deepcopy(row)))
        return fit, row

    def given_start(self) -> tuple[dict, FitStart | None] | None:
        """The model at its given values where fitted terms carry values of their own and there are several (with
        one, the chain's last step starts there already); else None (ComparisonSource.given_start). A model the
        search reached starts where the refit that proposed it ended, its anchors too (compare.search.ReachedModel):
        the same parameters, already converged.

        Returns:
            ({effect: params}, the FitStart or None), or None.
        """
        terms = self.ledger_terms()
        if len(terms) < 2:
            return None
        refit = refit_start(self.model)
        if refit is not None:
            return refit.effects, refit
        given = any(self.effects[name] != resolve_params(name, {}) for name in terms)
        return (dict(self.effects), None) if given else None

    def start_of(self, fit: ModelFit) -> FitStart:
        """Where a fit ended, its anchors too (ComparisonSource.start_of).

        Args:
            fit: a converged fit.

        Returns:
            The FitStart.
        """
        return fit.start()

    def moved_start(self, fit: ModelFit, nuisance_change: np.ndarray) -> FitStart:
        """Where ``fit`` ended, its anchors moved by ``nuisance_change`` (ComparisonSource.moved_start).

        Args:
            fit: a converged fit.
            nuisance_change: (3K,) the anchors' change [rad].

        Returns:
            The FitStart.
        """
        start = fit.start()
        return FitStart(start.effects, start.free, start.anchors_rad + nuisance_change.reshape(start.anchors_rad.shape))

    def fit(self, effects: dict, free: tuple, start: ModelFit | None) -> ModelFit:
        """compare.fit.fit_model, its anchors (and the parameters it fitted) starting from ``start``'s; the fit
        released of its columns (ModelFit.released): the comparison holds its refits while it fits more, and asks
        for the columns of the few it judges again, which then take them anew.

        Args:
            effects: {effect: params} at the starting values.
            free: FreeParameters to fit.
            start: a fit whose anchors the fit starts from, or None.

        Returns:
            The ModelFit.

        Raises:
            FitError: the starting values put stars off their detectors.
        """
        return self._fitted(effects, free, start).released()

    def _fitted(self, effects: dict, free: tuple, start: Any) -> ModelFit:
        """fit_model from ``start``'s anchors, with the columns of its last iteration."""
        # A time shift the start has already fitted is in its basin: its grid (fit._profiled_values) is not run again.
        return fit_model(self.predictor, effects, free, self.noise_arcsec, self.prior,
                         anchors_rad=None if start is None else start.anchors_rad,
                         fitted=() if start is None else start.free)

    def ledger_row(self, term: str | None, fit: ModelFit) -> LedgerRow:
        """A row of the ledger: the term, the residual RMS per camera, the BIC.

        Args:
            term: the fitted effect the step added, or None.
            fit: the step's fit.

        Returns:
            {term, residual_rms_arcsec, bic}.
        """
        return {'term': term or 'fixed effects only (attitude anchors fitted)',
                'residual_rms_arcsec': self.residual_rms(fit), 'bic': fit.bic}

    def residual_rms(self, fit: ModelFit) -> dict:
        """Residual RMS ["] per camera and in total over both axes, every row counted (outliers are also listed).

        Args:
            fit: the fit.

        Returns:
            {total, camera: RMS}.
        """
        centroids = self.observations.centroids
        squares = np.sum(fit.residual_arcsec**2, axis=1)
        rms = {'total': float(np.sqrt(np.mean(squares) / 2.0))}
        for index, camera in enumerate(centroids.cameras):
            rows = centroids.camera_index == index
            if np.any(rows):
                rms[camera] = float(np.sqrt(np.mean(squares[rows]) / 2.0))
        return rms

    def rms_after(self, fit: ModelFit) -> dict:
        """The total RMS of a fit as a candidate entry names it.

        Args:
            fit: the fit.

        Returns:
            {'rms_after_arcsec': total}.
        """
        return {'rms_after_arcsec': self.residual_rms(fit)['total']}

    def ranking_problem(self, fit: ModelFit) -> tuple[np.ndarray, Any, int]:
        """The whitened rows and the anchors' prior rows, the Jacobian with the anchors first.

        Args:
            fit: the fit.

        Returns:
            (residual, Jacobian, number of anchor columns).
        """
        return fit.augmented_residual, fit.jacobian, fit.anchors_rad.size

    def judge_fit(self, fit: ModelFit) -> Judgement:
        """compare.diagnostics: residual_diagnostics and split_consistency.

        Args:
            fit: the fit.

        Returns:
            The Judgement.
        """
        # The rows' variables once for both (the specific forces and slew angles: 0.2 s a judgement on a star hop).
        variables = row_variables(self.observations, fit, self.predictor)
        return Judgement(residual_diagnostics(self.observations, fit, self.predictor, self.noise_arcsec, self.prior,
                                              variables=variables),
                         split_consistency(self.observations, fit, self.predictor, variables=variables))

    def candidate_names(self, names: list[str], judgement: Judgement) -> list[str]:
        """The catalogue's candidates and an empirical term for each shape the diagnostics found.

        Args:
            names: the catalogue effects not in the model, tried first.
            judgement: the diagnostics and consistency of the model's fit, whose findings name the shapes.

        Returns:
            ``names``, then the empirical terms not in the model (compare.verdict.empirical_candidate_names).
        """
        empirical = empirical_candidate_names(judgement.diagnostics, self.observations.centroids.cameras,
                                              judgement.consistency)
        return names + [name for name in empirical if name not in self.effects]

    def linearize(self, fit: ModelFit, names: Sequence[str]) -> tuple[list[LinearizedCandidate], dict[str, str]]:
        """Each candidate linearized where it vanishes; the attitude part through the derivative at the fit.

        Args:
            fit: the model's fit.
            names: candidate effect names.

        Returns:
            (LinearizedCandidates, {}: a bag leaves none out before the ranking).
        """
        problem = WhitenedProblem(self.predictor, self.noise_arcsec, self.prior)
        base = self.predictor.predict_px(fit.effects, fit.anchors_rad)
        # Shared by every candidate: the attitude derivative at the fit (each term starts where it vanishes).
        derivative = problem.irf_derivative(fit.effects, fit.anchors_rad, base)
        # The anchors' prior rows do not depend on any effect: zeros there.
        prior_rows = len(fit.prior_residual)
        out = []
        for name in names:
            free, start, switched = switched_on(fit.effects, name)
            if not free:
                continue
            spec = get_effect(name)
            at_start = self.predictor.predict_px(switched, fit.anchors_rad)
            columns = problem.parameter_columns(switched, free, start, fit.anchors_rad, at_start, derivative)
            shift = problem.scaled(at_start - base)
            # A term switched on where it vanishes moves no row (every catalogue term does): no shift to hold
            # (21 candidates' zero shifts were 44 MB of a star hop's linearization).
            shift = np.concatenate([shift, np.zeros(prior_rows)]) if np.any(shift) else None
            # The size the effect is expected at: its thesis magnitudes (shaping parameters do not scale it).
            reference = np.array([0.0 if spec.parameter(p.name).shape else float(spec.parameter(p.name).default)
                                  for p in free])
            if not np.any(reference):
                reference = None  # no expected size (empirical terms, plug-ins defaulting to zero)
            term = CandidateTerm(name, tuple(p.name for p in free), start,
                                 np.vstack([columns, np.zeros((prior_rows, len(free)))]),
                                 shift, reference)
            out.append(LinearizedCandidate(term, free, switched))
        return out, {}

    def shared_objects(self) -> tuple:
        """The predictor, the anchors' prior and the noise floors a fit refers to (ComparisonSource.shared_objects).

        Returns:
            The objects.
        """
        return self.predictor, self.prior, self.noise_arcsec, self.observations

    def extra_document(self, outcome: Comparison, progress: Progress) -> dict:
        """The bag's own keys: cameras, noise, outliers, consistency, anchors, and a star hop's holds.

        Args:
            outcome: the comparison so far.
            progress: where the star hop's phase goes.

        Returns:
            {key: value}.
        """
        centroids = self.observations.centroids
        final = outcome.final_fit
        extra = {
            'bag': str(self.observations.bag_path),
            'observations': {camera: int(count) for camera, count in zip(centroids.cameras, self.counts)},
            'noise_floor_arcsec': float(np.sqrt(np.sum(self.counts * self.noise_arcsec**2) / np.sum(self.counts))),
            'centroid_noise_arcsec': {camera: float(v) for camera, v in zip(centroids.cameras, self.noise_arcsec)},
            'outliers': int(np.sum(final.outlier)),
            'outliers_by_camera': {camera: int(np.sum(final.outlier & (centroids.camera_index == index)))
                                   for index, camera in enumerate(centroids.cameras)},
            'consistency': outcome.judgement.consistency,
            'anchor_spacing_s': self.anchor_spacing_s,
            'anchor_walk_sigma_arcsec': self.prior.unit_rad * ARCSEC_PER_RAD,
            'angle_random_walk_arcsec_per_sqrt_s': self.arw * ARCSEC_PER_RAD,
        }
        windows = hold_windows(self.observations.calibration_result) if self.observations.calibration_result else None
        if windows:
            progress.phase('star-hop hold analysis')
            fpi_noise_arcsec = (float(self.noise_arcsec[centroids.cameras.index('fpi')]) if 'fpi' in centroids.cameras
                                else None)
            extra['star_hop'] = star_hop_analysis(self.predictor, final.effects, windows,
                                                  fpi_noise_arcsec=fpi_noise_arcsec, arw_rad_per_sqrt_s=self.arw)
        return extra


def compare_bag(bag_path: Any, model: EffectConfig, *, anchor_spacing_s: float = 30.0,
                candidate_names: Sequence[str] | None = None, progress: Progress | None = None,
                jobs: int = 1) -> CompareResult:
    """Compare ``model`` with the bag.

    Args:
        bag_path: the bag directory.
        model: the model (EffectConfig).
        anchor_spacing_s: seconds between attitude anchors.
        candidate_names: the candidates to try, or None for the catalogue.
        progress: where the phases go, or None for nowhere.
        jobs: the most forked workers at a time (compare.pipeline.run_comparison).

    Returns:
        The CompareResult.
    """
    started = time.perf_counter()
    progress = progress or Progress.silent()
    progress.phase('reading the bag')
    observations = read_observations(bag_path)
    return compare_observations(observations, model, anchor_spacing_s=anchor_spacing_s,
                                candidate_names=candidate_names, started=started, progress=progress,
                                steps=step_store(bag_path), jobs=jobs)


def compare_observations(observations: Any, model: EffectConfig, *, anchor_spacing_s: float = 30.0,
                         candidate_names: Sequence[str] | None = None, started: float | None = None,
                         progress: Progress | None = None, steps: StepStore | None = None,
                         jobs: int = 1) -> CompareResult:
    """Compare ``model`` with observations already read (compare.observations) through compare.pipeline.

    Args:
        observations: the bag's observations.
        model: the model (EffectConfig).
        anchor_spacing_s: seconds between attitude anchors.
        candidate_names: the candidates to try, or None for the catalogue.
        started: perf_counter at which the comparison began, or None for now.
        progress: where the phases go, or None for nowhere.
        steps: where the ledger's steps are kept (compare.steps), or None for this process's memory.
        jobs: the most forked workers at a time (compare.pipeline.run_comparison).

    Returns:
        The CompareResult.
    """
    source = BagSource(observations, model, anchor_spacing_s=anchor_spacing_s, steps=steps)
    outcome = run_comparison(source, model.effects, candidate_names=candidate_names, started=started,
                             progress=progress, jobs=jobs)
    return CompareResult(outcome.document, observations, outcome.final_fit, outcome.best_fit, outcome.best_name,
                         source.predictor, outcome.refit_starts)
