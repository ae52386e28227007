"""Fitting a model's free terms to a bag's centroids: robust Gauss-Newton with attitude anchors.

Residuals are measured minus predicted centroids in arcsec (nominal image scale), whitened by
each camera's centroid noise (compare.floor). Free parameters are the numeric parameters of
every model effect marked ``fit: true``, in their physical units; their Jacobian columns are
forward differences of the prediction, the anchors' columns follow from the prediction's
derivative with respect to a rotation of IRF. Huber weights (k = 3 sigma) keep a bad
centroid from steering the fit; rows beyond 5 sigma are flagged as outliers and reported.

The anchors are not free: between knots they may add only what the gyro noise allows (4.2.3):
angle random walk N (measured from the bag's own samples) and rate random walk K (from the
model's gyro_noise), whose bias wander correlates the increments of a long record
(compare.prior: generalized least squares). These prior rows keep a gap without stars (a long
slew) from freeing the attitude, which is what lets a star hop measure the gyros across its
moves (6.3).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse

from sofia_ros.analysis.ranking import NormalInverse, normal_equations_fit, normal_solution, row_bands, whitened_bic
from sofia_ros.compare.predict import inverse_right_jacobians
from sofia_ros.effects import get_effect
from sofia_ros.errors import FitError, InvalidArgumentError

if TYPE_CHECKING:
    from sofia_ros.compare.predict import Predictor
    from sofia_ros.compare.prior import AnchorPrior

__all__ = ['FitStart', 'FreeParameter', 'ModelFit', 'WhitenedProblem', 'free_parameters', 'fit_model',
           'anchor_gram', 'normal_equations', 'vanishing_values', 'with_values', 'OUTLIER_SIGMA']

HUBER_K = 3.0
OUTLIER_SIGMA = 5.0
_MAX_ITERATIONS = 12
#: The smallest share of an iteration's step a fit tries (halving from 1: seven times) before it stops where it is.
_SMALLEST_STEP_SHARE = 2.0**-7
#: A share of a step is taken where it lowers the cost by this fraction of what the linearized problem promises
#: (_lowers_cost), Armijo's sufficient decrease.
_SUFFICIENT_DECREASE = 0.25
#: The relative rounding of a fit's cost at a trial point, each row predicted anew: a converged fit's trials
#: scatter by 2e-13 of it.
_COST_ROUNDING = 1e-12
#: A fit has converged when no parameter's step exceeds this fraction of its sigma, and no anchor moves 1e-8 rad or
#: the whole step lowers the linearized cost by less than a step of this fraction of a sigma would (_is_converged).
_STEP_TOLERANCE_SIGMA = 1e-2
#: An iteration's linearized Huber problem is solved until its step is below this fraction of a sigma (and no
#: anchor moves 1e-10 rad), or two steps in turn lower its cost by less than a step of this fraction of a sigma
#: would, in at most _INNER_STEPS steps (linearized_huber_step).
_INNER_TOLERANCE_SIGMA = 1e-3
_INNER_STEPS = 24
#: Newton's curvature keeps this share of the re-weighted one: a parameter seen only by rows beyond k (a HIPO
#: detector-field shape on a model that lacks the HIPO clock offset) has none of its own.
_NEWTON_DAMPING = 1e-3
_IRF_STEP_RAD = 1e-6
#: A time shift's grid (catalogue family 'timing'): this many defaults either side of zero, 1/20 of a default apart.
_PROFILE_REACH = 3.0
_PROFILE_STEP = 0.05


@dataclass(frozen=True)
class FreeParameter:
    """One fitted number: effect, parameter, unit and the finite-difference step in that unit."""

    effect: str
    name: str
    unit: str
    step: float

    @property
    def label(self) -> str:
        """effect.parameter, as tables print it."""
        return f'{self.effect}.{self.name}'


def vanishing_values(free: Sequence[FreeParameter]) -> np.ndarray:
    """Where each free parameter switches its effect off: 0 for a scaling parameter, the default for a shaping one.

    Args:
        free: the parameters.

    Returns:
        One value per parameter, in its unit.
    """
    values = []
    for parameter in free:
        spec = get_effect(parameter.effect).parameter(parameter.name)
        values.append(spec.default if spec.shape else 0.0)
    return np.array(values, dtype=float)


def free_parameters(effect_names: Iterable[str]) -> tuple[FreeParameter, ...]:
    """The numeric parameters of effects, in catalogue order, with steps 1e-3 of their scale.

    Args:
        effect_names: catalogue, plug-in or empirical effect names.

    Returns:
        Their FreeParameters, effect by effect.
    """
    parameters = []
    for name in effect_names:
        for param in get_effect(name).params:
            if isinstance(param.default, float):
                parameters.append(FreeParameter(name, param.name, param.unit, 1e-3 * max(abs(param.default), 1.0)))
    return tuple(parameters)


def normal_equations(anchor_columns: scipy.sparse.csr_matrix, parameter_columns: np.ndarray, anchor_prior: AnchorPrior,
                     whitened: np.ndarray, weights: np.ndarray, prior_residual: np.ndarray,
                     rows: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, Callable[[np.ndarray], float]]:
    """Gram matrix J^T W J and gradient J^T W r of the weighted problem (data rows weighted by ``weights``, then the
    anchors' prior rows at weight 1) from its blocks, and a function giving the weighted RSS after a step.

    The blocks: the sparse anchor columns (two knots per row), the dense parameter columns and the prior's constant
    Gram matrix (compare.prior). Stacking them into one sparse Jacobian to multiply it by itself costs several
    times more: the parameter columns are dense, and so nearly are the GLS prior's rows.

    Args:
        anchor_columns: whitened d data rows / d anchors (2N, 3K), sparse.
        parameter_columns: whitened d data rows / d free parameters (2N, P).
        anchor_prior: the anchors' prior (its matrix and Gram matrix).
        whitened: the data rows' whitened residuals (2N).
        weights: each data row's weight (2N), e.g. the Huber weights.
        prior_residual: the prior rows' residuals (3(K-1)).
        rows: the data rows taken (ascending indices), the others as if weighted 0; None: every row.

    Returns:
        The Gram matrix (3K + P square), the gradient (3K + P) and rss_after(step), the weighted RSS after a step.
    """
    prior = anchor_prior.matrix
    gram = _data_gram(anchor_columns, parameter_columns, weights, rows)
    gram[:anchor_columns.shape[1], :anchor_columns.shape[1]] += anchor_prior.gram
    if rows is not None:
        # The other rows at weight 0, not a copy of the taken rows' columns (half a star hop's: 50 MB per judgement).
        taken = np.zeros_like(weights)
        taken[rows] = weights[rows]
        weights = taken
    weighted = weights * whitened
    gradient = np.concatenate([anchor_columns.T @ weighted + prior.T @ prior_residual,
                               parameter_columns.T @ weighted])
    return gram, gradient, _rss_after(anchor_columns, parameter_columns, prior, whitened, weights, prior_residual)


def _data_gram(anchor_columns, parameter_columns, weights, rows=None):
    """J^T W J of the data rows alone, W the rows' ``weights``, over the data rows ``rows`` (ascending indices) or
    all (None): a new array.

    The parameter columns are weighted a band of rows at a time: all at once, their weighted copy was the largest
    array of a star-hop refit's worker at its peak (32 MB; in bands 49 -> 20 MB at the peak of this function, 5 %
    slower). Of a subset of the rows, a band of it at a time too: the bands and the sums are those of the subset's
    copy, which took 56 MB of a star-hop judgement's 208 MB peak (split_normal_equations)."""
    count = parameter_columns.shape[1]
    cross = np.zeros((anchor_columns.shape[1], count))
    parameter_gram = np.zeros((count, count))
    bands = row_bands(len(weights)) if rows is None else (rows[band] for band in row_bands(len(rows)))
    for band in bands:
        weighted = parameter_columns[band] * weights[band, None]
        parameter_gram += parameter_columns[band].T @ weighted
        cross += anchor_columns[band].T @ weighted
    anchors = anchor_gram(anchor_columns, weights) if rows is None else anchor_gram(anchor_columns[rows], weights[rows])
    return np.block([[anchors, cross], [cross.T, parameter_gram]])


def _columns_weighted(parameter_columns, weights):
    """Whether each column has a non-zero in a row of non-zero weight, a band of rows at a time."""
    found = np.zeros(parameter_columns.shape[1], dtype=bool)
    for band in row_bands(len(weights)):
        found |= np.any((parameter_columns[band] != 0.0) & (weights[band, None] != 0.0), axis=0)
    return found


def anchor_gram(anchor_columns: scipy.sparse.csr_matrix, weights: np.ndarray) -> np.ndarray:
    """A^T diag(weights) A of anchor columns (WhitenedProblem.anchor_columns: each row's six non-zeros are the
    columns of its two knots, 3k to 3k + 5), dense.

    Each row adds its 6 x 6 outer product at its first knot k, so the Gram matrix is block tridiagonal: the rows
    are grouped by k (a stable counting sort) and each group's block is one small product. A general sparse
    product took 20-40 ms for a star hop's 247k rows and 195 knots, this 8-12 ms; it serves every Gram matrix of a
    fit. Any other sparsity goes through the general product.

    Args:
        anchor_columns: (2N, 3K) CSR.
        weights: (2N,) each row's weight.

    Returns:
        The (3K, 3K) Gram matrix.
    """
    rows, width = anchor_columns.shape
    if not _two_knots_a_row(anchor_columns):
        return (anchor_columns.T @ scipy.sparse.diags(weights) @ anchor_columns).toarray()
    first_knot = anchor_columns.indices[::6] // 3
    order = np.argsort(first_knot.astype(np.uint16 if width // 3 <= np.iinfo(np.uint16).max else np.int64),
                       kind='stable')
    bounds = np.concatenate([[0], np.cumsum(np.bincount(first_knot, minlength=width // 3))])
    values = anchor_columns.data.reshape(rows, 6)[order].T  # (6, 2N): each knot's rows side by side
    sorted_weights = weights[order]
    gram = np.zeros((width, width))
    for knot in np.flatnonzero(np.diff(bounds)):
        own = slice(bounds[knot], bounds[knot + 1])
        gram[3 * knot:3 * knot + 6, 3 * knot:3 * knot + 6] += values[:, own] @ (values[:, own] * sorted_weights[own]).T
    return gram


def _two_knots_a_row(columns):
    """Whether each row of a CSR matrix has six non-zeros in columns 3k to 3k + 5 (sorted, no duplicates: canonical)."""
    rows = columns.shape[0]
    if columns.nnz != 6 * rows or not np.array_equal(columns.indptr, np.arange(0, 6 * rows + 1, 6)):
        return False
    first, last = columns.indices[::6], columns.indices[5::6]
    return bool(columns.has_canonical_format and np.all(last - first == 5) and np.all(first % 3 == 0))


def _rss_after(anchor_columns, parameter_columns, prior, whitened, weights, prior_residual):
    """rss_after(step) of normal_equations: the weighted RSS of the data rows and the prior rows after a step."""
    anchor_count = anchor_columns.shape[1]

    def rss_after(step):
        data = whitened - anchor_columns @ step[:anchor_count] - parameter_columns @ step[anchor_count:]
        after_prior = prior_residual - prior @ step[:anchor_count]
        return float(weights @ data**2 + after_prior @ after_prior)

    return rss_after


def camera_variance_ratios(whitened: np.ndarray, weights: np.ndarray, row_camera: np.ndarray,
                           camera_count: int) -> np.ndarray:
    """Each camera's weighted mean square whitened residual: the square of its real noise over its floor.

    Args:
        whitened: the data rows' whitened residuals (2N).
        weights: their Huber weights (2N).
        row_camera: each data row's camera index (2N).
        camera_count: the number of cameras.

    Returns:
        (camera_count,) the ratios (1 where a camera's floor is its noise).
    """
    squares = np.bincount(row_camera, weights * whitened**2, camera_count)
    return squares / np.maximum(np.bincount(row_camera, minlength=camera_count), 1)


def camera_sandwich_covariance(anchor_columns: scipy.sparse.csr_matrix, parameter_columns: np.ndarray,
                               anchor_prior: AnchorPrior, whitened: np.ndarray, weights: np.ndarray,
                               prior_residual: np.ndarray, row_camera: np.ndarray,
                               camera_count: int, *, inverse: NormalInverse | None = None,
                               ) -> tuple[np.ndarray, np.ndarray]:
    """Sigma and correlation of the free parameters with each camera's rows at their own residual variance.

    The floors (compare.floor) can be off by a different factor for each camera: on the minimal alignment the
    imagers' come out 1.3-1.6 times their residual scatter and HIPO's right, and one s^2 = RSS / (n - k), set by
    the WFI's rows, then shrinks HIPO's sigmas by 1.3 (issue 25, the pull table's hipo_fiducial_error). The
    covariance of the estimate actually made is the sandwich G^+ (J^T W S W J + P) G^+, G = J^T W J + P, S each
    row's camera ratio (camera_variance_ratios), P the anchors' prior.

    Args:
        anchor_columns: whitened d data rows / d anchors (2N, 3K), sparse.
        parameter_columns: whitened d data rows / d free parameters (2N, P).
        anchor_prior: the anchors' prior.
        whitened: the data rows' whitened residuals (2N).
        weights: their Huber weights (2N).
        prior_residual: the prior rows' residuals.
        row_camera: each data row's camera index (2N).
        camera_count: the number of cameras.
        inverse: the NormalInverse of G where the caller has it, else None (computed here).

    Returns:
        (P,) the sigmas (inf for a parameter the data do not determine) and (P, P) the correlation.
    """
    if inverse is None:
        gram = normal_equations(anchor_columns, parameter_columns, anchor_prior, whitened, weights, prior_residual)[0]
        inverse = NormalInverse.of(gram)
    ratios = camera_variance_ratios(whitened, weights, row_camera, camera_count)
    meat = normal_equations(anchor_columns, parameter_columns, anchor_prior, whitened,
                            weights**2 * ratios[row_camera], prior_residual)[0]
    parameters = slice(anchor_columns.shape[1], None)
    bread = inverse.matrix[parameters]
    covariance = bread @ meat @ bread.T
    unconstrained = inverse.unconstrained[parameters]
    sigma = np.sqrt(np.diag(covariance))
    sigma[unconstrained] = np.inf
    with np.errstate(invalid='ignore', divide='ignore'):
        correlation = covariance / np.outer(sigma, sigma)
    correlation[unconstrained, :] = np.nan
    correlation[:, unconstrained] = np.nan
    return sigma, correlation


@dataclass(frozen=True, eq=False)
class JacobianPoint:
    """Where a fit took its Jacobian (its last iteration's start) and what it takes it with: a few kB."""

    predictor: Predictor
    sigma_arcsec: np.ndarray
    anchor_prior: AnchorPrior
    #: the model at ``values``, as that iteration had it
    effects: dict
    free: tuple
    values: np.ndarray
    anchors_rad: np.ndarray

    def columns(self) -> tuple[scipy.sparse.csr_matrix, np.ndarray]:
        """The anchor and parameter columns at this point, computed as fit_model's iteration computed them.

        Returns:
            (anchor columns (2N, 3K), parameter columns (2N, P)), whitened.
        """
        problem = WhitenedProblem(self.predictor, self.sigma_arcsec, self.anchor_prior)
        predicted = self.predictor.predict_px(self.effects, self.anchors_rad)
        derivative = problem.irf_derivative(self.effects, self.anchors_rad, predicted)
        return (problem.anchor_columns(self.effects, derivative),
                problem.parameter_columns(self.effects, self.free, self.values, self.anchors_rad, predicted,
                                          derivative))


@dataclass(frozen=True, eq=False)
class ModelFit:
    """A converged fit: effects with fitted values, sigmas, correlation, anchors, residuals, weights.

    Its Jacobian is kept in blocks (``anchor_columns``, ``parameter_columns``, the prior): ``normal_equations``
    weights them without assembling it; ``jacobian`` assembles it (sparse, each time) for what needs its columns. A fit
    ``released`` holds no columns (about 55 MB on a star hop) and takes them again at its ``jacobian_point``
    where they are asked for: the comparison keeps several refits while it fits others, and judges few.
    """

    effects: dict
    free: tuple
    values: np.ndarray
    sigma: np.ndarray
    correlation: np.ndarray
    anchors_rad: np.ndarray
    residual_arcsec: np.ndarray
    whitened: np.ndarray
    prior_residual: np.ndarray
    anchor_prior: AnchorPrior
    weights: np.ndarray
    outlier: np.ndarray
    iterations: int
    jacobian_point: JacobianPoint

    @cached_property
    def _columns(self) -> tuple[scipy.sparse.csr_matrix, np.ndarray]:
        return self.jacobian_point.columns()

    @property
    def anchor_columns(self) -> scipy.sparse.csr_matrix:
        """Whitened d data rows / d anchors (2N, 3K), sparse."""
        return self._columns[0]

    @property
    def parameter_columns(self) -> np.ndarray:
        """Whitened d data rows / d free parameters (2N, P)."""
        return self._columns[1]

    def released(self) -> ModelFit:
        """This fit without its columns: they are taken again at its Jacobian point where asked for.

        Returns:
            A ModelFit of the same values that holds no columns.
        """
        return dataclasses.replace(self)

    @property
    def parameter_count(self) -> int:
        """Fitted numbers including the anchors."""
        return self.anchors_rad.size + len(self.free)

    @property
    def augmented_residual(self) -> np.ndarray:
        """Whitened data rows followed by the anchors' gyro-noise prior rows (what the Jacobian's rows are)."""
        return np.concatenate([self.whitened, self.prior_residual])

    @property
    def jacobian(self) -> scipy.sparse.csr_matrix:
        """d augmented residual / d (anchors, parameters), whitened, sparse: data rows, then the prior's rows.
        Assembled anew (about 40 MB on a star hop): the comparison drops it once it has ranked the candidates."""
        prior = self.anchor_prior.matrix
        data = scipy.sparse.hstack([self.anchor_columns, scipy.sparse.csr_matrix(self.parameter_columns)])
        prior_rows = scipy.sparse.hstack([prior, scipy.sparse.csr_matrix((prior.shape[0], self.parameter_columns.shape[1]))])
        return scipy.sparse.vstack([data, prior_rows], format='csr')

    @cached_property
    def weighted_normal_equations(self) -> tuple[np.ndarray, np.ndarray, Callable[[np.ndarray], float]]:
        """normal_equations at the fit's own Huber weights (``weights``): what its covariance, the prior rows'
        covariance and the split halves start from, computed once (fit_model keeps those of its covariance).
        Shared: callers copy before they change them."""
        return self.normal_equations(self.weights)

    @cached_property
    def weighted_inverse(self) -> NormalInverse:
        """The NormalInverse of weighted_normal_equations' Gram matrix (fit_model keeps its covariance's)."""
        return NormalInverse.of(self.weighted_normal_equations[0])

    def split_normal_equations(self, rows: np.ndarray) -> tuple[tuple[np.ndarray, np.ndarray, Callable],
                                                                    tuple[np.ndarray, np.ndarray, Callable]]:
        """normal_equations of the data rows in ``rows`` and of the others, each at the fit's Huber weights (the
        prior rows in both). Their Gram matrices and gradients are sums over the data rows plus the prior's part:
        the smaller half's are taken over its own rows alone (a product over every row with the others weighted 0
        costs the whole), the larger half's are the whole (weighted_normal_equations) less the smaller's, plus the
        prior's part (equal to rounding, about 1e-16 of the whole's entries).

        Args:
            rows: (2N,) bool, the data rows of the first half.

        Returns:
            (gram, gradient, rss_after) of the rows in ``rows``, then of the others.
        """
        first_weights, second_weights = self.weights * rows, self.weights * ~rows
        smaller_is_first = np.count_nonzero(rows) <= rows.size - np.count_nonzero(rows)
        own = np.flatnonzero(rows if smaller_is_first else ~rows)
        direct = normal_equations(self.anchor_columns, self.parameter_columns, self.anchor_prior, self.whitened,
                                  self.weights, self.prior_residual, own)
        whole_gram, whole_gradient, _ = self.weighted_normal_equations
        anchors = self.anchor_columns.shape[1]
        gram = whole_gram - direct[0]
        gram[:anchors, :anchors] += self.anchor_prior.gram
        gradient = whole_gradient - direct[1]
        gradient[:anchors] += self.anchor_prior.matrix.T @ self.prior_residual
        derived_weights = second_weights if smaller_is_first else first_weights
        # A parameter with no weighted row in the larger half (another camera's term) has exact zeros there, which
        # the difference leaves as rounding: the split test reads a zero diagonal as a parameter the half lacks.
        absent = anchors + np.flatnonzero(~_columns_weighted(self.parameter_columns, derived_weights))
        gram[absent, :] = 0.0
        gram[:, absent] = 0.0
        gradient[absent] = 0.0
        derived = (gram, gradient, _rss_after(self.anchor_columns, self.parameter_columns, self.anchor_prior.matrix,
                                              self.whitened, derived_weights, self.prior_residual))
        return (direct, derived) if smaller_is_first else (derived, direct)

    def normal_equations(self, data_weights: np.ndarray) -> tuple[np.ndarray, np.ndarray,
                                                                    Callable[[np.ndarray], float]]:
        """normal_equations of this fit's residuals with the data rows weighted by ``data_weights``.

        Args:
            data_weights: each data row's weight (2N).

        Returns:
            The Gram matrix, the gradient and rss_after(step) (normal_equations).
        """
        return normal_equations(self.anchor_columns, self.parameter_columns, self.anchor_prior, self.whitened,
                                data_weights, self.prior_residual)

    @property
    def bic(self) -> float:
        """BIC of the whitened residual and the anchor prior, every row at full weight (analysis.ranking.whitened_bic)."""
        residual = self.augmented_residual
        return whitened_bic(float(residual @ residual), len(residual), self.parameter_count)

    def start(self) -> FitStart:
        """Where this fit ended, as a later fit of the same parameters may start from it (a few kB).

        Returns:
            The FitStart.
        """
        return FitStart({name: dict(params) for name, params in self.effects.items()}, self.free,
                        np.array(self.anchors_rad))


@dataclass(frozen=True, eq=False)
class FitStart:
    """Where a converged fit ended: its effects at the fitted values, the parameters it fitted and its anchors (K, 3)
    [rad]. fit_model started there (``anchors_rad``, ``fitted`` = ``free``) is already converged: it confirms the
    point in an iteration, where a start from the given values alone takes several and a time shift's grid."""

    effects: dict
    free: tuple
    anchors_rad: np.ndarray


def with_values(effects: Mapping[str, Mapping[str, Any]], free: Sequence[FreeParameter],
                values: Sequence[float]) -> dict[str, dict[str, Any]]:
    """A copy of ``effects`` with the free parameters set to ``values``.

    Args:
        effects: effect name -> parameters.
        free: the parameters to set.
        values: their values, one per parameter.

    Returns:
        The new effects (the input is not changed).
    """
    updated = {name: dict(params) for name, params in effects.items()}
    for parameter, value in zip(free, values):
        updated[parameter.effect][parameter.name] = float(value)
    return updated


class WhitenedProblem:
    """Whitened residuals and Jacobians of one predictor for one set of free parameters."""

    def __init__(self, predictor, sigma_arcsec, anchor_prior):
        centroids = predictor.observations.centroids
        self.predictor = predictor
        self.arcsec_per_px = centroids.arcsec_per_px()[:, None]
        self.row_sigma = np.asarray(sigma_arcsec)[centroids.camera_index][:, None]
        self.anchor_prior = anchor_prior
        self.prior = anchor_prior.matrix

    def whiten(self, predicted_px: np.ndarray) -> np.ndarray:
        """(measured - predicted) in units of each camera's noise, flattened (x, y per row).

        Args:
            predicted_px: predicted centroids (N, 2) [px].

        Returns:
            The whitened residuals (2N).
        """
        measured = self.predictor.observations.centroids.measured_px
        return ((measured - predicted_px) * self.arcsec_per_px / self.row_sigma).ravel()

    def whiten_rows(self, predicted_px: np.ndarray, rows: slice | np.ndarray) -> np.ndarray:
        """whiten of some rows only: (measured - predicted) of ``rows`` in units of their camera's noise.

        Args:
            predicted_px: predicted centroids of the rows (n, 2) [px].
            rows: the rows (Predictor.camera_rows).

        Returns:
            The whitened residuals (2n).
        """
        measured = self.predictor.observations.centroids.measured_px[rows]
        return ((measured - predicted_px) * self.arcsec_per_px[rows] / self.row_sigma[rows]).ravel()

    def scaled(self, delta_px: np.ndarray) -> np.ndarray:
        """A change of predicted pixels in units of each camera's noise, flattened like the residuals.

        Args:
            delta_px: a change of the predicted centroids (N, 2) [px].

        Returns:
            The change in units of noise (2N).
        """
        return (delta_px * self.arcsec_per_px / self.row_sigma).ravel()

    def irf_derivative(self, effects: Mapping[str, Any], anchors: np.ndarray, predicted: np.ndarray) -> np.ndarray:
        """Whitened d prediction / d IRF rotation (N, 2, 3), forward differences (units of noise per rad).

        Args:
            effects: the model at the current values.
            anchors: the anchor rotations (K, 3) [rad].
            predicted: the prediction there (N, 2) [px].

        Returns:
            The derivative (N, 2, 3).
        """
        derivative = self.predictor.irf_derivative_px(effects, anchors, predicted, _IRF_STEP_RAD)
        return derivative * (self.arcsec_per_px / self.row_sigma)[:, :, None]

    def anchor_columns(self, effects: Mapping[str, Any], derivative: np.ndarray) -> scipy.sparse.csr_matrix:
        """Sparse d prediction / d anchor knot rotations: the derivative against an IRF rotation (irf_derivative),
        times the hat-function weights of the two knots around each row (six non-zeros per residual).

        Args:
            effects: the model (its row times).
            derivative: irf_derivative (N, 2, 3).

        Returns:
            The columns (2N, 3K), CSR.
        """
        times = self.predictor.row_times_s(effects)
        index, fraction = self.predictor.anchor_weights(times)
        weights = np.stack([1.0 - fraction, fraction], axis=1)  # (N, 2 knots)
        data = (derivative[:, :, None, :] * weights[:, None, :, None]).reshape(2 * len(times), 6)
        knot_columns = 3 * np.stack([index, index + 1], axis=1)[:, :, None] + np.arange(3)  # (N, 2 knots, 3)
        columns = np.repeat(knot_columns.reshape(len(times), 6), 2, axis=0)
        return scipy.sparse.csr_matrix((data.ravel(), columns.ravel(), np.arange(0, data.size + 1, 6)),
                                       shape=(2 * len(times), 3 * self.predictor.anchor_count))

    def parameter_columns(self, effects: Mapping[str, Any], free: Sequence[FreeParameter], values: np.ndarray,
                          anchors: np.ndarray, predicted: np.ndarray, derivative: np.ndarray) -> np.ndarray:
        """Forward-difference columns d prediction / d free parameter at values, whitened (units of noise per unit).

        A step that keeps the row times and star places is split, to first order, into what it does
        to the gyro attitude and what it does to the camera models. The attitude part comes from the
        attitude change the step makes, linearized over the ticks (Predictor.attitude_changes_irf),
        through ``derivative`` (irf_derivative): the gyro track is not propagated again for each
        step. The camera part projects the rows of the cameras whose model the step changes again,
        from the TARF directions of ``effects`` (Predictor.reprojected_px). Other steps predict anew, a time shift
        only the cameras whose rows it moves (moved_rows_change).

        Args:
            effects: the model at ``values``.
            free: the free parameters.
            values: their values.
            anchors: the anchor rotations (K, 3) [rad].
            predicted: the prediction at ``values`` (N, 2) [px].
            derivative: irf_derivative there (N, 2, 3).

        Returns:
            The columns (2N, P), in units of noise per parameter unit.
        """
        columns = np.empty((predicted.size, len(free)))
        predictor = self.predictor
        stepped_effects, reaches = [], []
        for index, parameter in enumerate(free):
            stepped = values.copy()
            stepped[index] += parameter.step
            stepped_effects.append(with_values(effects, free, stepped))
            reaches.append(predictor.parameter_reach(effects, parameter, stepped_effects[-1]))
        moving_attitude = [moved for moved, (_, attitude, _) in zip(stepped_effects, reaches) if attitude]
        changes = predictor.attitude_changes_irf(effects, moving_attitude, predictor.row_times_s(effects))
        if moving_attitude:
            # A step's attitude change c composes with each row's anchor rotation a: R(a) R(c) = R(a + J_r(a)^-1 c)
            # to first order (J_r the right Jacobian of SO(3)), and ``derivative`` is against a change of a. Taken
            # as a change of a itself, c was off by |a| (anchors of 0.5 deg on the Waco star hop: columns 0.8 % off).
            row_anchors = predictor.anchor_rotations_rad(anchors, predictor.row_times_s(effects))
            derivative = derivative @ inverse_right_jacobians(row_anchors)
        in_tarf = None
        for index, (parameter, moved_effects, (moves_rows, attitude, cameras)) in enumerate(
                zip(free, stepped_effects, reaches)):
            if moves_rows:
                change = self.moved_rows_change(effects, parameter, moved_effects, anchors, predicted)
                columns[:, index] = self.scaled(change) / parameter.step
                continue
            column = np.einsum('nai,ni->na', derivative, next(changes)).ravel() if attitude else np.zeros(predicted.size)
            if cameras:
                in_tarf = predictor.tarf_directions(effects, anchors) if in_tarf is None else in_tarf
                column += self.scaled(predictor.reprojected_px(moved_effects, cameras, in_tarf, predicted) - predicted)
            columns[:, index] = column / parameter.step
        return columns

    def moved_rows_change(self, effects: Mapping[str, Any], parameter: FreeParameter,
                          moved_effects: Mapping[str, Any], anchors: np.ndarray, predicted: np.ndarray) -> np.ndarray:
        """The change of the prediction (N, 2) [px] under a step that moves row times or star places. A time shift
        (family 'timing') moves only some cameras' rows, and a row's prediction depends on its own time: only those
        cameras are predicted again (a HIPO clock offset: 1800 of the Waco star hop's 123k rows). Any other step
        predicts every row.

        Args:
            effects: the model at the current values.
            parameter: the parameter stepped.
            moved_effects: ``effects`` with it stepped.
            anchors: the anchor rotations (K, 3) [rad].
            predicted: the prediction under ``effects`` (N, 2) [px].

        Returns:
            The change (N, 2) [px].
        """
        predictor = self.predictor
        if get_effect(parameter.effect).family != 'timing':
            return predictor.predict_px(moved_effects, anchors) - predicted
        change = np.zeros_like(predicted)
        for camera in _cameras_moved_in_time(predictor, effects, moved_effects):
            rows = predictor.camera_rows(int(camera))
            change[rows] = predictor.predict_camera_px(moved_effects, int(camera), anchors) - predicted[rows]
        return change


def _huber_weights(whitened):
    magnitude = np.abs(whitened)
    return np.where(magnitude <= HUBER_K, 1.0, HUBER_K / np.maximum(magnitude, 1e-300))


def huber_line_minimum(residual: np.ndarray, change: np.ndarray, prior_residual: np.ndarray,
                       prior_change: np.ndarray) -> float:
    """The t >= 0 minimizing sum rho(r - t q) + |p - t q_p|^2 / 2 (Huber's rho, k = HUBER_K, as _robust_cost): the
    least cost along a step of the linearized problem. The cost is convex and piecewise quadratic in t, its
    derivative piecewise linear and rising: Newton's steps on the derivative, kept inside a bracket of its sign.

    Args:
        residual: the whitened data residuals r at t = 0.
        change: what a whole step (t = 1) takes from them, q.
        prior_residual: the prior rows' residuals p at t = 0.
        prior_change: what a whole step takes from them, q_p.

    Returns:
        The minimizing t (0 where the step does not lower the cost).
    """
    prior_curvature = float(prior_change @ prior_change)
    prior_slope = float(prior_residual @ prior_change)
    change_squared = change * change
    # One buffer for every trial: a star hop's 250k rows, each pass over them counts (about 150 searches a compare).
    moved, psi = np.empty_like(residual), np.empty_like(residual)

    def slope_and_curvature(t):
        np.multiply(change, -t, out=moved)
        np.add(moved, residual, out=moved)
        # psi(r) of the Huber cost is r clipped to k; a row is inside k where clipping leaves it.
        np.clip(moved, -HUBER_K, HUBER_K, out=psi)
        slope = -float(psi @ change) - prior_slope + t * prior_curvature
        return slope, float(np.sum(change_squared, where=psi == moved)) + prior_curvature

    low, high = 0.0, np.inf
    if slope_and_curvature(0.0)[0] >= 0.0:
        return 0.0
    t = 1.0
    for _ in range(60):
        slope, curvature = slope_and_curvature(t)
        if slope == 0.0:
            return t
        if slope < 0.0:
            low = t
        else:
            high = t
        newton = t - slope / curvature if curvature > 0.0 else np.inf
        if low < newton < high:
            following = newton
        else:
            following = 2.0 * low if np.isinf(high) else 0.5 * (low + high)
        if abs(following - t) <= 1e-9 * max(abs(t), 1.0) or high - low <= 1e-6 * low:
            return following
        t = following
    return low


def linearized_huber_step(anchor_columns: scipy.sparse.csr_matrix, parameter_columns: np.ndarray,
                          anchor_prior: AnchorPrior, whitened: np.ndarray, prior_residual: np.ndarray,
                          names: Sequence[str], rows: int, null_directions: np.ndarray | None = None,
                          ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, float]:
    """The step minimizing the Huber cost of an iteration's linearized problem (its columns held), the sigmas of
    its first re-weighted solve, and how much the step lowers that cost.

    One Gauss-Newton step, re-weighted (curvature psi(r)/r) or Newton's (psi'), creeps where many rows lie beyond
    k: a step-limited fraction of the way an iteration, each iteration predicting every row again and taking
    every column again (the Waco star hop's HIPO detector-field shapes without the HIPO clock offset: 12
    iterations, still 2 sigma a step). The linearized problem costs a product of its columns a step: its own
    minimum, taken by the two steps in turn, each to its least cost along it (huber_line_minimum), is reached
    in a few such steps, and the iterations are left to the prediction's non-linearity. Newton's curvature keeps
    _NEWTON_DAMPING of the re-weighted one, for the parameters only rows beyond k see. Two steps in turn that lower
    the cost by less than half the square of _INNER_TOLERANCE_SIGMA (what a step of that fraction of a sigma does
    to a quadratic cost) end it: near a combination the solves leave out (a refit's imager field rotations beside
    the HIPO fiducials and the gyro misalignment) the two steps take turns at it, each lowering the cost by 5e-8,
    up to _INNER_STEPS.

    Args:
        anchor_columns: whitened d data rows / d anchors (2N, 3K), sparse.
        parameter_columns: whitened d data rows / d free parameters (2N, P).
        anchor_prior: the anchors' prior.
        whitened: the data rows' whitened residuals (2N).
        prior_residual: the prior rows' residuals.
        names: the 3K + P parameters' names.
        rows: the number of rows (data and prior).
        null_directions: the combinations the previous iteration's columns left undetermined (NormalInverse.of), or
            None.

    Returns:
        The step (3K + P), the sigmas of the re-weighted solve at its start (3K + P), which judge convergence, the
        combinations these columns leave undetermined (None: none), and the Huber cost (with the prior rows') the
        step removes from the linearized problem.
    """
    prior = anchor_prior.matrix
    anchor_count = anchor_columns.shape[1]
    unit_gram = []

    def gram_of(weights):
        """The Gram matrix at data weights: where few rows weigh other than 1 (those beyond k: 6 % on a star hop),
        the Gram matrix of unit weights corrected by those rows alone."""
        beyond = np.flatnonzero(weights != 1.0)
        if 2 * beyond.size > weights.size:
            gram = _data_gram(anchor_columns, parameter_columns, weights)
        else:
            if not unit_gram:
                unit_gram.append(_data_gram(anchor_columns, parameter_columns, np.ones(weights.size)))
            gram = unit_gram[0] + _data_gram(anchor_columns, parameter_columns, weights - 1.0, beyond)
        gram[:anchor_count, :anchor_count] += anchor_prior.gram
        return gram

    def gradient_of(residual, huber, after_prior):
        weighted_residual = huber * residual
        return np.concatenate([anchor_columns.T @ weighted_residual + prior.T @ after_prior,
                               parameter_columns.T @ weighted_residual])

    # The sigmas the fit's convergence is judged by: the re-weighted step's, where every parameter has a curvature.
    huber = _huber_weights(whitened)
    gram = gram_of(huber)
    # A degeneracy of the model's terms (gyro_bias.el with the anchors) is one of the columns, at every iteration.
    inverse = NormalInverse.of(gram, null_directions)
    sigma = normal_equations_fit(gram, gradient_of(whitened, huber, prior_residual),
                                 _rss_after(anchor_columns, parameter_columns, prior, whitened, huber, prior_residual),
                                 names, rows, inverse=inverse).sigma
    total = np.zeros(anchor_count + parameter_columns.shape[1])
    residual, after_prior = whitened, prior_residual
    start_cost = cost = _cost_with_prior(whitened, prior_residual)
    negligible_drop, last_drop = 0.5 * _INNER_TOLERANCE_SIGMA**2, np.inf
    for number in range(_INNER_STEPS):
        huber = _huber_weights(residual)
        # Newton's step first: where the rows beyond k stay beyond, it is the minimum itself.
        curvature = np.where(huber == 1.0, 1.0, _NEWTON_DAMPING * huber) if number % 2 == 0 else huber
        # A candidate degenerate with the model's terms leaves the same combinations undetermined at any weights.
        direction = normal_solution(gram_of(curvature), gradient_of(residual, huber, after_prior),
                                    inverse.null_directions)
        change = anchor_columns @ direction[:anchor_count] + parameter_columns @ direction[anchor_count:]
        prior_change = prior @ direction[:anchor_count]
        length = huber_line_minimum(residual, change, after_prior, prior_change)
        step = length * direction
        total += step
        residual, after_prior = residual - length * change, after_prior - length * prior_change
        after_cost = _cost_with_prior(residual, after_prior)
        drop, cost = cost - after_cost, after_cost
        if _step_is_small(step[anchor_count:], step[:anchor_count], sigma[anchor_count:], _INNER_TOLERANCE_SIGMA,
                          1e-10) or max(drop, last_drop) < negligible_drop:
            break
        last_drop = drop
    return total, sigma, inverse.null_directions, start_cost - cost


def _step_is_small(parameter_step, anchor_step, sigma, tolerance_sigma, anchor_tolerance_rad):
    """Whether no parameter steps beyond ``tolerance_sigma`` of its (finite) sigma and no anchor beyond the tolerance."""
    bound = tolerance_sigma * np.where(np.isfinite(sigma), sigma, np.inf)
    return bool(np.all(np.abs(parameter_step) <= bound)
                and np.max(np.abs(anchor_step), initial=0.0) < anchor_tolerance_rad)


def _is_converged(parameter_step, anchor_step, sigma, linearized_drop):
    """Whether an iteration's step leaves a fit converged: no parameter steps beyond _STEP_TOLERANCE_SIGMA of its
    sigma, and no anchor beyond 1e-8 rad or the step lowers the linearized cost by less than half the square of
    _STEP_TOLERANCE_SIGMA. For a quadratic cost that drop is half the squared length of the step in sigmas along its
    own direction: the minimum is within that fraction of a sigma in every combination, the anchors' too. Anchors a
    model's terms nearly share a combination with (boresight offsets, a field rotation, the gyro misalignment) crept
    1e-7 rad an iteration, lowering the cost by 1e-7, to the 12-iteration cap (a refit on the Waco star hop: 6 of its
    10 s)."""
    anchor_tolerance_rad = np.inf if linearized_drop < 0.5 * _STEP_TOLERANCE_SIGMA**2 else 1e-8
    return _step_is_small(parameter_step, anchor_step, sigma, _STEP_TOLERANCE_SIGMA, anchor_tolerance_rad)


def _lowers_cost(trial_cost, current_cost, share, linearized_drop):
    """Whether a share s of an iteration's step lowers the cost enough to be taken: by _SUFFICIENT_DECREASE of the
    least the linearized problem promises there, s D (its cost is convex, D the drop at the whole step); where D is
    within the cost's rounding (_COST_ROUNDING), by not raising it beyond that. A share that merely does not raise
    the cost can be the mirror image of the minimum along the step, as far past it as the start is short of it:
    taken, the next step came back as long, and a fit whose steps overshot 64-fold went to and fro to the cap. A
    promise that is not a number promises nothing."""
    rounding = _COST_ROUNDING * abs(current_cost)
    if not np.isfinite(linearized_drop) or linearized_drop <= rounding:
        return trial_cost <= current_cost + rounding
    return current_cost - trial_cost >= _SUFFICIENT_DECREASE * share * linearized_drop


def _robust_cost(whitened):
    """Huber cost of whitened residuals: quadratic inside k, linear beyond."""
    magnitude = np.abs(whitened)
    return float(np.sum(np.where(magnitude <= HUBER_K, 0.5 * magnitude**2, HUBER_K * magnitude - 0.5 * HUBER_K**2)))


def _cost_with_prior(whitened, prior_residual):
    """The fit's cost: the data rows' Huber cost and the prior rows' half square."""
    return _robust_cost(whitened) + 0.5 * float(prior_residual @ prior_residual)


def _try_predicted(problem, effects, free, values, anchors):
    """Predicted pixels at a trial point, or None where the model sends a star off a detector."""
    try:
        return problem.predictor.predict_px(with_values(effects, free, values), anchors)
    except InvalidArgumentError:
        return None


def _cameras_moved_in_time(predictor, effects, other_effects):
    """Indices of the cameras some of whose row times differ between two effect sets (a clock offset's)."""
    moved = predictor.row_times_s(effects) != predictor.row_times_s(other_effects)
    return np.unique(predictor.observations.centroids.camera_index[moved])


def _cameras_moved(problem, effects, free, values, index, grid):
    """Indices of the cameras whose row times the time shift ``free[index]`` moves across ``grid``."""
    trials = [values.copy(), values.copy()]
    trials[0][index], trials[1][index] = grid.min(), grid.max()
    return _cameras_moved_in_time(problem.predictor, *(with_values(effects, free, trial) for trial in trials))


def _shift_cost(problem, effects, free, values, anchors, cameras):
    """Robust cost of the rows of ``cameras`` at a trial point; inf where the model sends a star off a detector."""
    trial = with_values(effects, free, values)
    cost = 0.0
    for camera in cameras:
        try:
            predicted = problem.predictor.predict_camera_px(trial, int(camera), anchors)
        except InvalidArgumentError:
            return np.inf
        cost += _robust_cost(problem.whiten_rows(predicted, problem.predictor.camera_rows(int(camera))))
    return cost


def _profiled_values(problem, effects, free, values, anchors, fitted=frozenset()):
    """``values`` with each time shift (family 'timing') at the least robust cost of a grid, anchors and the other
    values held, where that beats its start. A clock offset moves rows across the telescope's moves, so the cost in
    it has a local minimum every few tenths of a second: Gauss-Newton from where it vanishes stopped at 0.05 s for a
    1 s HIPO clock offset (issue 25: pull -574). Only the rows the shift moves change, so only their cameras are
    predicted (on the Waco star hop HIPO's 1800 rows of 123k)."""
    values = values.copy()
    for index, parameter in enumerate(free):
        spec = get_effect(parameter.effect)
        if spec.family != 'timing' or parameter in fitted:
            continue
        scale = abs(spec.parameter(parameter.name).default) or 1.0
        grid = np.concatenate([[values[index]], scale * np.arange(-_PROFILE_REACH, _PROFILE_REACH + _PROFILE_STEP / 2,
                                                                     _PROFILE_STEP)])
        cameras = _cameras_moved(problem, effects, free, values, index, grid)
        costs = []
        for value in grid:
            trial = values.copy()
            trial[index] = value
            costs.append(_shift_cost(problem, effects, free, trial, anchors, cameras))
        values[index] = grid[int(np.argmin(costs))]
    return values


def fit_model(predictor: Predictor, effects: Mapping[str, Mapping[str, Any]], free: Sequence[FreeParameter],
              sigma_arcsec: Sequence[float], anchor_prior: AnchorPrior, *, anchors_rad: np.ndarray | None = None,
              fitted: Collection[FreeParameter] = ()) -> ModelFit:
    """Robust Gauss-Newton over the anchors (under their gyro-noise prior, compare.prior) and the free parameters.

    Starts from the effects' given values, a time shift from the best of a grid (_profiled_values) unless it is
    one of ``fitted``, the parameters a previous fit already converged at these values. Each iteration takes the
    columns at its point and steps to the least Huber cost of that linearized problem (linearized_huber_step); a
    step that does not lower the cost by a quarter of what the linearized problem promises (_lowers_cost), or sends
    a star off its detector, is halved, down to 1/128 of it, and a fit that cannot improve stops where it is. Each
    iteration first tries twice the share its predecessor took (a trust region's memory, at most the whole step).
    It has converged when no parameter steps beyond 1 % of its sigma and either no anchor beyond 1e-8 rad or the
    step's linearized drop is below that of a 1 %-of-sigma step (_is_converged).

    Args:
        predictor: the bag's Predictor.
        effects: the model at its starting values.
        free: the parameters to fit.
        sigma_arcsec: each camera's centroid noise ["].
        anchor_prior: the anchors' gyro-noise prior.
        anchors_rad: starting anchors (K, 3) [rad]; None: zero.
        fitted: parameters a previous fit already converged at these values.

    Returns:
        The ModelFit.

    Raises:
        FitError: the starting values put stars off their detectors.
    """
    problem = WhitenedProblem(predictor, sigma_arcsec, anchor_prior)
    free = tuple(free)
    values = np.array([effects[p.effect][p.name] for p in free], dtype=float)
    anchors = np.zeros((predictor.anchor_count, 3)) if anchors_rad is None else np.array(anchors_rad)
    values = _profiled_values(problem, effects, free, values, anchors, frozenset(fitted))

    def cost(whitened_rows, trial_anchors):
        return _cost_with_prior(whitened_rows, problem.prior @ trial_anchors.ravel())

    predicted = _try_predicted(problem, effects, free, values, anchors)
    if predicted is None:
        raise FitError('the model\'s starting values put stars off their detectors; give closer values')
    whitened = problem.whiten(predicted)
    names = [''] * (anchors.size + len(free))
    rows = whitened.size + problem.prior.shape[0]
    null_directions, start_scale = None, 1.0
    for iteration in range(1, _MAX_ITERATIONS + 1):
        # The last iteration's columns go before this one's are taken (both held, a star hop's refit took 50 MB more).
        derivative = columns = anchor_columns = None
        current = with_values(effects, free, values)
        jacobian_at = (current, free, values, anchors)
        derivative = problem.irf_derivative(current, anchors, predicted)
        columns = problem.parameter_columns(current, free, values, anchors, predicted, derivative)
        anchor_columns = problem.anchor_columns(current, derivative)
        current_cost = cost(whitened, anchors)
        step, step_sigma, null_directions, linearized_drop = linearized_huber_step(
            anchor_columns, columns, anchor_prior, whitened, -(problem.prior @ anchors.ravel()), names, rows,
            null_directions)
        anchor_step, parameter_step = step[:anchors.size].reshape(anchors.shape), step[anchors.size:]
        # The step's largest fraction (1, 1/2, ...) that lowers the cost enough and sends no star off a detector:
        # the prediction is not linear. Where the model's terms nearly share a combination (the imagers' offsets,
        # field rotations and the HIPO fiducials), its linearized step overshoots alike iteration after iteration:
        # a refit on the Waco star hop took 1/32-1/64 of it in each of 12 iterations, 72 predictions, 17 s. From
        # twice the last share it converged in 6 (18 predictions, 9.7 s).
        scale, trial = start_scale, None
        while scale >= _SMALLEST_STEP_SHARE:
            trial = _try_predicted(problem, effects, free, values + scale * parameter_step,
                                   anchors + scale * anchor_step)
            if trial is not None and _lowers_cost(cost(problem.whiten(trial), anchors + scale * anchor_step),
                                                  current_cost, scale, linearized_drop):
                break
            scale, trial = scale / 2.0, None
        if trial is None:
            break
        start_scale = min(1.0, 2.0 * scale)
        anchors, values, predicted = anchors + scale * anchor_step, values + scale * parameter_step, trial
        whitened = problem.whiten(predicted)
        # Converged where the linearized problem's minimum is this close, whatever share of the way was taken.
        if _is_converged(parameter_step, anchor_step, step_sigma[anchors.size:], linearized_drop):
            break
    # Converged steps are below 1 % of a sigma: the last Jacobian serves for the covariance.
    current = with_values(effects, free, values)
    weights = _huber_weights(whitened)
    prior_residual = -(problem.prior @ anchors.ravel())
    centroids = predictor.observations.centroids
    equations = normal_equations(anchor_columns, columns, anchor_prior, whitened, weights, prior_residual)
    inverse = NormalInverse.of(equations[0], null_directions)
    sigma, correlation = camera_sandwich_covariance(anchor_columns, columns, anchor_prior, whitened, weights,
                                                    prior_residual, np.repeat(centroids.camera_index, 2),
                                                    len(centroids.cameras), inverse=inverse)
    residual_arcsec = whitened.reshape(-1, 2) * problem.row_sigma
    outlier = np.any(np.abs(whitened.reshape(-1, 2)) > OUTLIER_SIGMA, axis=1)
    fit = ModelFit(current, free, values, sigma, correlation, anchors, residual_arcsec, whitened, prior_residual,
                   anchor_prior, weights, outlier, iteration,
                   JacobianPoint(predictor, np.asarray(sigma_arcsec), anchor_prior, *jacobian_at))
    # The columns of the last iteration: released() drops them, and they are taken again the same where asked for.
    fit.__dict__['_columns'] = (anchor_columns, columns)
    # The covariance's normal equations are the fit's own at its weights (the diagnostics ask for them again).
    fit.__dict__['weighted_normal_equations'] = equations
    fit.__dict__['weighted_inverse'] = inverse
    return fit
