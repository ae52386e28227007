"""The profiled information of a bag, and of each plan element in it, with compare's own predictor (docs/design.md).

The model is fitted to the bag as `sofia compare` fits it (compare.run.BagSource); every member
of the competing set is switched on where it vanishes (compare.pipeline.switched_on) and its
columns are the predictor's forward differences at the fit (compare.fit.WhitenedProblem), the
same columns the comparison ranks its candidates with. The attitude anchors, under their
gyro-noise prior, are the nuisance each block eliminates.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Mapping, NamedTuple, Sequence

import numpy as np

from sofia_ros.compare.fit import FreeParameter, ModelFit, WhitenedProblem, anchor_gram, free_parameters
from sofia_ros.compare.pipeline import switched_on
from sofia_ros.compare.run import BagSource
from sofia_ros.config import EffectConfig
from sofia_ros.design.separation import Information, profiled_gram, pseudo_inverse

__all__ = ['BagColumns', 'ModelOnBag', 'bag_columns', 'element_windows', 'fit_model_on_bag', 'fitted_model_effects',
           'member_labels']


def member_labels(member: Sequence[str]) -> tuple:
    """The fitted parameter labels (effect.parameter) of a member: one effect or several fitted together."""
    return tuple(parameter.label for parameter in free_parameters(list(member)))


@dataclass(frozen=True, eq=False)
class BagColumns:
    """A bag's whitened problem at the model's fit: anchor columns with the prior's Gram, parameter columns.

    ``parameter_columns`` are over ``labels`` (the model's fitted terms, then each member's);
    ``row_times_s`` gives each whitened data row's time (two rows, x and y, per centroid); ``rss`` and ``rows``
    are the model's fit's whitened RSS and row count (the anchors' prior rows included, as compare's BIC counts).
    """

    labels: tuple
    shared_labels: tuple
    anchor_columns: object
    prior_gram: np.ndarray
    parameter_columns: np.ndarray
    residual: np.ndarray
    prior_gradient: np.ndarray
    row_times_s: np.ndarray
    rss: float
    rows: int

    def information(self, start_s: float = -np.inf, end_s: float = np.inf) -> Information:
        """The profiled information of the rows in [start_s, end_s) (the whole bag by default).

        Args:
            start_s: the window's start (sim time, s).
            end_s: its end.

        Returns:
            The Information over ``labels``; its gradient is J^T r at the model's fit.
        """
        # Every row at full weight, as compare ranks candidates: the base fit's Huber weights would hide the very
        # rows (all of HIPO's, say) whose residual a member explains.
        weights = ((self.row_times_s >= start_s) & (self.row_times_s < end_s)).astype(float)
        anchors = self.anchor_columns
        weighted_columns = self.parameter_columns * weights[:, None]
        nuisance_gram = anchor_gram(anchors, weights) + self.prior_gram
        cross = np.asarray(anchors.T @ weighted_columns)
        gram = profiled_gram(nuisance_gram, cross, self.parameter_columns.T @ weighted_columns)
        nuisance_gradient = anchors.T @ (weights * self.residual) + self.prior_gradient
        gradient = weighted_columns.T @ self.residual
        # The gradient profiled like the Gram matrix: what the anchors cannot absorb of J^T r.
        gradient = gradient - cross.T @ pseudo_inverse(nuisance_gram) @ nuisance_gradient
        return Information(self.labels, gram, gradient, int(np.count_nonzero(weights)))


class ModelOnBag(NamedTuple):
    """The model fitted to a bag as compare fits it: the bag's BagSource, the fitted terms, the fit."""

    source: BagSource
    shared: list
    fit: ModelFit


def fit_model_on_bag(observations: object, model: EffectConfig, *, anchor_spacing_s: float = 30.0) -> ModelOnBag:
    """Fit ``model``'s terms to the observations (compare.run.BagSource.fit from zero anchors).

    Raises:
        FitError: the model's own fit fails.
    """
    source = BagSource(observations, model, anchor_spacing_s=anchor_spacing_s)
    shared = free_parameters(source.ledger_terms())
    return ModelOnBag(source, shared, source.fit(source.effects, shared, None))


def fitted_model_effects(on_bag: ModelOnBag) -> dict:
    """{effect: {parameter: value}} of a model fitted to a bag (fit_model_on_bag)."""
    return {name: dict(params) for name, params in on_bag.fit.effects.items()}


def bag_columns(observations: object, model: EffectConfig, members: Sequence[Sequence[str]], *,
                anchor_spacing_s: float = 30.0, on_bag: ModelOnBag | None = None) -> BagColumns:
    """Fit ``model`` to the observations and linearize every member of the competing set there.

    Args:
        observations: a bag's observations (compare.observations.read_observations).
        model: the model (its fitted terms are the shared parameters).
        members: each member's effect names.
        anchor_spacing_s: seconds between attitude anchors (compare's --anchor-s).
        on_bag: the model already fitted to these observations (fit_model_on_bag), or None: fitted here.

    Returns:
        The BagColumns.

    Raises:
        FitError: the model's own fit fails.
    """
    if on_bag is None:
        on_bag = fit_model_on_bag(observations, model, anchor_spacing_s=anchor_spacing_s)
    source, shared, fit = on_bag
    effects, free = dict(fit.effects), list(shared)
    for name in dict.fromkeys(name for member in members for name in member):
        if name in effects:
            continue
        added, _, switched = switched_on(effects, name)
        effects, free = switched, free + list(added)
    values = np.array([effects[parameter.effect][parameter.name] for parameter in free], dtype=float)
    problem = WhitenedProblem(source.predictor, source.noise_arcsec, source.prior)
    predicted = source.predictor.predict_px(effects, fit.anchors_rad)
    derivative = problem.irf_derivative(effects, fit.anchors_rad, predicted)
    columns = problem.parameter_columns(effects, tuple(free), values, fit.anchors_rad, predicted, derivative)
    anchors = problem.anchor_columns(effects, derivative)
    times = np.repeat(source.predictor.row_times_s(effects), 2)  # x and y of each centroid
    augmented = fit.augmented_residual
    return BagColumns(_labels(free), _labels(shared), anchors, source.prior.gram, columns, fit.whitened,
                      source.prior.matrix.T @ fit.prior_residual, times, float(augmented @ augmented), len(augmented))


def _labels(free: Sequence[FreeParameter]) -> tuple:
    return tuple(parameter.label for parameter in free)


def element_windows(calibration: Mapping) -> list:
    """(index, kind, start_s, end_s) of each flown plan element in a calibration result (docs/plans.md).

    An alignment element records its window (start_s, end_s); a star hop's hold records only its hold window, and
    its flight starts where the hold before it ended (the star hop flies its elements back to back after the last
    observation): the slew, acquisition and placement are part of what it costs and of what it measures.
    """
    previous_end = max((float(entry['hold_end_s']) for entry in calibration.get('observations') or []), default=None)
    windows = []
    for entry in calibration.get('elements') or []:
        if 'skipped' in entry:  # not flown: no star in reach, or the TASCU refused its star or placement
            continue
        end = float(entry['end_s'] if 'end_s' in entry else entry['hold_end_s'])
        if 'start_s' in entry:
            start = float(entry['start_s'])
        else:  # a star hop's hold; the first of a record without observations starts with its hold
            start = previous_end if previous_end is not None else float(entry['hold_start_s'])
        windows.append((int(entry['index']), str(entry['kind']), start, end))
        previous_end = end
    return windows
