"""Ranking candidate terms of a least-squares model: delta-BIC, sigmas, correlation, degeneracy.

The machinery behind the candidate tables of `sofia compare` (pointing observables) and
`sofia noise` (log-Allan curve): a base model has been fitted, its residual ``r`` and
Jacobian ``J`` (d residual-reduction / d parameter) are known; each candidate term adds
columns ``J_c`` (and, when it is linearized away from "off", a shift ``s_c``: the change of
the prediction when the term is switched on at its starting values). Each candidate is
fitted jointly with the base terms in the linearized problem (Frisch-Waugh-Lovell: project
the base out once, then small solves), scored by the Bayesian information criterion of a
Gaussian likelihood with unknown variance, BIC = n ln(RSS/n) + k ln n (Schwarz 1978; the
celestial-pointing rule: keep a term while BIC falls by at least 6), and pairs of candidates
whose explained signatures coincide are named degenerate instead of ranked as a confident pick.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt
import scipy.linalg
import scipy.sparse
import scipy.sparse.linalg

from sofia_ros.errors import InvalidArgumentError

__all__ = [
    'SIGNIFICANT_DELTA_BIC',
    'normal_equations_fit',
    'normal_pseudo_inverse',
    'normal_solution',
    'row_bands',
    'LinearFit',
    'CandidateTerm',
    'RankedCandidate',
    'bic',
    'whitened_bic',
    'linear_fit',
    'rank_candidates',
    'degenerate_pairs',
    'CompetingSet',
    'competes',
    'competing_margin',
    'competing_sets',
    'shared_fraction',
    'shared_share',
    'COMPETING_DELTA_BIC',
    'COMPETING_FRACTION',
    'SHARED_FRACTION',
]

#: A candidate counts as detected when it lowers the BIC by at least this much (Kass & Raftery: "strong").
SIGNIFICANT_DELTA_BIC = 6.0
#: Explained signatures this collinear (cosine) cannot be told apart by the data.
DEGENERATE_COSINE = 0.98
#: Columns that keep less than this fraction of their norm outside the base span are the base's own (numerically:
#: finite-difference and linearized columns of one physical shape agree to about 1e-7, e.g. an axis-swap bias
#: against the gyro biases; what is left outside is rounding, and a fit to it gives any value).
IN_BASE_SPAN_FRACTION = 1e-6
#: The pseudo-inverse keeps the eigen-combinations of a column-scaled Gram matrix above this fraction of the largest:
#: ten times the bound of a Gram matrix's rounding at 600 columns (n eps of the largest, 1.3e-13; the null
#: combinations measured on star hops lie near 1e-16, a constructed 600-column one came out at 2e-15), so that what the data determine, however weakly, is kept. At 1e-10
#: (until 2026-11-28) the Waco 2004 star hop's model with the imagers' boresight offsets beside the HIPO clock offset
#: and the axis swap had two combinations at 1.7e-11 and 2.1e-11 of the largest (the gyro box's misalignment with the
#: offsets and the anchors) cut with its null one (1.2e-16, the EL gyro bias with the anchors): its fit took no step
#: along them and ended where it started, BIC 14885.7 from zero anchors and 14920.1 from a refit's anchors; both
#: starts now reach 14745.0 (docs/compare.md, "Weakly determined").
KEPT_EIGENVALUE_FRACTION = 1e-12
#: Rows of a sparse Jacobian with more than this fraction of non-zeros are multiplied as dense ones.
_DENSE_FRACTION = 0.125
#: Rows of a Gram matrix's product taken at a time: a few MB of a star hop's rows, however many they are.
GRAM_BAND_ROWS = 8192
#: The smallest Gram matrix whose condition the Lanczos method measures where the 1-norm bound fails: below it the
#: eigendecomposition costs less (0.02 ms at 20, 0.3 ms for Lanczos; 30-50 ms against a few at 600).
_LANCZOS_MIN_SIZE = 100
#: Two candidates compete when each would remove at least this share of the other's drop in RSS...
SHARED_FRACTION = 0.5
#: ...and their delta-BICs differ by less than this (the usual "strong evidence" line of Kass & Raftery)...
COMPETING_DELTA_BIC = 10.0
#: ...or by less than this fraction of the larger one: while the model still lacks effects, the residual is far
#: from white noise and the rows are not independent, so a BIC difference of a few per cent of the gain is decided
#: by what else is missing, not by the data's preference (issue 25: 228889 against 228670 on a star hop).
COMPETING_FRACTION = 0.1
#: The overlaps are measured among this many of the strongest significant candidates.
COMPETITOR_POOL = 10


def bic(rss: float, n: int, k: int) -> float:
    """Bayesian information criterion of a Gaussian fit with unknown variance: n ln(RSS/n) + k ln n.

    Args:
        rss: the residual sum of squares (a non-positive one counts as the smallest positive float).
        n: the number of residuals.
        k: the number of fitted parameters.

    Returns:
        The BIC.

    Raises:
        InvalidArgumentError: ``n`` is not positive.
    """
    if n <= 0:
        raise InvalidArgumentError(f'bic needs n > 0 samples, got {n}')
    return float(n * np.log(max(rss, np.finfo(float).tiny) / n) + k * np.log(n))


def whitened_bic(rss: float, n: int, k: int) -> float:
    """BIC of whitened residuals whose variance is at least 1, their noise floor: bic above the floor, RSS - n + k ln n below.

    The profile likelihood with the variance bounded below by the floor the residuals were whitened by: above it the
    fitted variance RSS/n (bic); below it the floor itself, and -2 ln L is the chi-square (less n, so that the two
    branches meet with their slope at RSS = n). Unbounded, a fit below its floor gained n ln(RSS/n) without limit:
    the 2004 short moves (nine distances at 0.2 of their stated 1.1") scored a gyro scale factor against swapped
    calibrations by 6 on one processor and 11 on another, from where an undetermined LOS scale factor stopped.

    Args:
        rss: the whitened residual sum of squares.
        n: the number of residuals.
        k: the number of fitted parameters.

    Returns:
        The BIC.

    Raises:
        InvalidArgumentError: ``n`` is not positive.
    """
    # Below the floor bic at RSS = n (k ln n) less what the fit is below it: one check of n, in bic.
    return bic(max(rss, n), n, k) - max(n - rss, 0.0)


@dataclass(frozen=True)
class LinearFit:
    """Least-squares step with a-posteriori sigmas and the correlation of the fitted terms."""

    names: tuple[str, ...]
    step: np.ndarray
    sigma: np.ndarray
    correlation: np.ndarray
    rss: float
    n: int


def _checked(residual, jacobian):
    residual = np.asarray(residual, dtype=float).ravel()
    if scipy.sparse.issparse(jacobian):
        jacobian = scipy.sparse.csr_matrix(jacobian, dtype=float)
        values = jacobian.data
    else:
        jacobian = np.asarray(jacobian, dtype=float)
        if jacobian.ndim == 1:
            jacobian = jacobian[:, np.newaxis]
        values = jacobian
    if jacobian.shape[0] != residual.size:
        raise InvalidArgumentError(f'jacobian has {jacobian.shape[0]} rows for {residual.size} residuals')
    if not (np.all(np.isfinite(residual)) and np.all(np.isfinite(values))):
        raise InvalidArgumentError('residual and jacobian must be finite')
    return residual, jacobian


def row_bands(count: int) -> Iterator[slice]:
    """The slices of GRAM_BAND_ROWS rows (the last one shorter) that cover ``count`` rows: where a product over every
    row is summed a band at a time, so that no copy of all the rows is made.

    Args:
        count: how many rows.

    Yields:
        Slices of consecutive rows, in order.
    """
    for start in range(0, count, GRAM_BAND_ROWS):
        yield slice(start, start + GRAM_BAND_ROWS)


def _gram(matrix):
    """matrix^T matrix as a dense array; of a sparse matrix, a band of rows at a time, the nearly dense ones through
    BLAS."""
    if not scipy.sparse.issparse(matrix):
        return matrix.T @ matrix
    # A sparse product costs the square of each row's non-zeros: cheap for the data rows (two anchor knots and a
    # few terms), not for dense prior rows (a GLS random-walk prior), which BLAS multiplies 2-3x faster. In bands:
    # the whole product copied the matrix twice (93 MB beside a star hop's candidates, 9 MB in bands, as fast).
    matrix = scipy.sparse.csr_matrix(matrix)
    heavy = np.diff(matrix.indptr) > _DENSE_FRACTION * matrix.shape[1]
    gram = np.zeros((matrix.shape[1], matrix.shape[1]))
    for rows in row_bands(matrix.shape[0]):
        band, band_heavy = matrix[rows], heavy[rows]
        if np.any(band_heavy):
            dense_rows = band[band_heavy].toarray()
            gram += dense_rows.T @ dense_rows
            band = band[~band_heavy]
        gram += (band.T @ band).toarray()
    return gram


@dataclass(frozen=True)
class NormalInverse:
    """Pseudo-inverse of a Gram matrix, column-scaled, and its null space: Cholesky where that is the inverse, else eigh."""

    matrix: np.ndarray
    unconstrained: np.ndarray
    #: (k, m) the combinations of the parameters (unscaled) that got no step, where there are any
    null_directions: np.ndarray | None = None

    @classmethod
    def of(cls, gram: np.ndarray, null_directions: np.ndarray | None = None) -> NormalInverse:
        """The pseudo-inverse of a Gram matrix J^T J and the parameters its null space touches.

        Where ``null_directions`` are known to lie in the null space (a Gram matrix of the same columns over more
        rows left them without a step: every row's part is positive semi-definite, so a part of the rows leaves
        them null too), the scaled Gram matrix with them added, S + Q Q^T (Q those directions made orthonormal),
        is inverted by Cholesky where every other eigen-combination is kept, and S^+ is that inverse less Q Q^T:
        the eigendecomposition's answer without it (on a star hop's split halves, 600 anchors and terms, 12 ms
        against 30-50). Where the part has null directions of its own, the eigendecomposition decides.

        Args:
            gram: (k, k) the symmetric positive semi-definite matrix.
            null_directions: (k, m) combinations of the parameters (unscaled, as ``null_directions`` holds them)
                in the Gram matrix's null space, or None.

        Returns:
            The NormalInverse.
        """
        diagonal = np.diag(gram).copy()
        norms = np.sqrt(np.where(diagonal > 0.0, diagonal, 1.0))
        scaled = gram / np.outer(norms, norms)
        if null_directions is not None and null_directions.size:
            known = _known_null_inverse(scaled, null_directions * norms[:, None])
            if known is not None:
                return cls._scaled_back(*known, norms)
        inverse = _well_conditioned_inverse(scaled)
        if inverse is not None:
            return cls(inverse / np.outer(norms, norms), np.zeros(len(gram), dtype=bool))
        eigenvalues, vectors = np.linalg.eigh(scaled)
        # Eigenvalues are squared singular values: a combination whose singular value is below the square root of
        # KEPT_EIGENVALUE_FRACTION of the largest (1e-6) is not determined by the data; it gets no step.
        keep = eigenvalues > eigenvalues.max(initial=0.0) * KEPT_EIGENVALUE_FRACTION
        return cls._scaled_back((vectors[:, keep] / eigenvalues[keep]) @ vectors[:, keep].T, vectors[:, ~keep], norms)

    @classmethod
    def _scaled_back(cls, inverse: np.ndarray, null: np.ndarray, norms: np.ndarray) -> NormalInverse:
        """From the column-scaled Gram matrix's pseudo-inverse and its null directions (scaled, orthonormal): a
        parameter a null direction touches is unconstrained."""
        return cls(inverse / np.outer(norms, norms), np.any(np.abs(null) > 1e-6, axis=1), null / norms[:, None])

    def covariance(self, variance: float) -> np.ndarray:
        """Scaled covariance with infinite variance (and undefined covariance) along unconstrained parameters.

        Args:
            variance: the residual variance s^2 the inverse is scaled by.

        Returns:
            (k, k) the covariance.
        """
        covariance = self.matrix * variance
        covariance[self.unconstrained, :] = np.nan
        covariance[:, self.unconstrained] = np.nan
        covariance[self.unconstrained, self.unconstrained] = np.inf
        return covariance


def normal_pseudo_inverse(gram: np.ndarray) -> np.ndarray:
    """Pseudo-inverse of a normal (Gram) matrix J^T J: Cholesky where that is the inverse, else eigh, combinations
    below KEPT_EIGENVALUE_FRACTION of the largest eigenvalue left without a step.

    Args:
        gram: (k, k) the symmetric positive semi-definite matrix J^T J.

    Returns:
        (k, k) its pseudo-inverse.
    """
    return NormalInverse.of(gram).matrix


def normal_solution(gram: np.ndarray, gradient: np.ndarray, null_directions: np.ndarray | None = None) -> np.ndarray:
    """G^+ g, as NormalInverse.of(G).matrix @ g gives it: by Cholesky of the column-scaled G (LAPACK potrf, potrs)
    where G is positive definite and its estimated condition (pocon) keeps every eigen-combination, else through
    NormalInverse. Without the inverse itself: a third of the cost where only the step is asked for.

    Where the columns are degenerate (a candidate collinear with the model's terms), the combinations a Gram matrix of
    the same columns left without a step (NormalInverse.null_directions) get none here either: G + N N^T, N those
    combinations column-scaled and made orthonormal, is positive definite, and its solution less its part along N is
    G^+ g where N is G's null space. The estimated reciprocal condition must exceed KEPT_EIGENVALUE_FRACTION with or
    without them: the 1-norm reciprocal condition is at most the eigenvalues' ratio (pocon estimates it to a small
    factor), so a step taken here keeps only combinations NormalInverse keeps. Where the estimate falls short on
    _LANCZOS_MIN_SIZE columns or more, Lanczos measures the smallest eigenvalue itself, as NormalInverse.of does
    (docs/compare.md, "The cut above the rounding": with the cut divided by the size, 1.7e-16 at 600 columns, this
    path gave a combination NormalInverse cuts a step up to 1e10 times too long).

    Args:
        gram: (k, k) the symmetric positive semi-definite matrix G = J^T J.
        gradient: (k,) g = J^T r.
        null_directions: (k, m) the combinations a Gram matrix of the same columns did not determine, or None.

    Returns:
        (k,) the step.
    """
    diagonal = np.diag(gram).copy()
    norms = np.sqrt(np.where(diagonal > 0.0, diagonal, 1.0))
    scaled = gram / np.outer(norms, norms)
    null = None
    if null_directions is not None and null_directions.size:
        null = np.linalg.qr(null_directions * norms[:, None])[0]
        scaled = scaled + null @ null.T
    if len(scaled):
        factor, info = scipy.linalg.lapack.dpotrf(scaled, lower=True)
        if info == 0:
            largest_bound = np.abs(scaled).sum(axis=0).max()
            reciprocal_condition, info = scipy.linalg.lapack.dpocon(factor, largest_bound, uplo='L')
            if info == 0 and (reciprocal_condition > KEPT_EIGENVALUE_FRACTION
                              or _lanczos_keeps_every_combination(largest_bound, _cholesky_solver(factor))):
                solution, info = scipy.linalg.lapack.dpotrs(factor, gradient / norms, lower=True)
                if info == 0:
                    if null is not None:
                        solution = solution - null @ (null.T @ solution)
                    return solution / norms
    return NormalInverse.of(gram).matrix @ gradient


def _known_null_inverse(scaled, null_scaled):
    """(S^+, Q) by Cholesky of S + Q Q^T (NormalInverse.of), Q the combinations of the known directions that S
    leaves null to rounding, orthonormal; None where there is none, or where another eigen-combination falls below
    KEPT_EIGENVALUE_FRACTION (the eigendecomposition decides those)."""
    basis = np.linalg.qr(null_scaled)[0]
    # Rotated to their own eigen-combinations in S (Rayleigh-Ritz), the known directions split into those null to
    # rounding (a degeneracy of the columns: gyro_bias.el with the anchors) and those merely weak in the rows that
    # found them (1e-11 of the largest in a whole star hop), which are no null directions of a part: taken for one,
    # they moved a split half's sigmas by 1e-3.
    rayleigh, rotation = np.linalg.eigh(basis.T @ scaled @ basis)
    null = basis @ rotation[:, rayleigh <= len(scaled) * np.finfo(float).eps * np.diag(scaled).max()]
    if null.shape[1] == 0:
        return None
    inverse = _well_conditioned_inverse(scaled + null @ null.T)
    return None if inverse is None else (inverse - null @ null.T, null)


def _well_conditioned_inverse(scaled):
    """Inverse of a positive definite scaled Gram matrix by Cholesky (LAPACK potrf, potri), or None unless every
    eigenvalue is above KEPT_EIGENVALUE_FRACTION of the largest (then the pseudo-inverse is this inverse)."""
    if len(scaled) == 0:
        return None
    factor, info = scipy.linalg.lapack.dpotrf(scaled, lower=True)
    if info != 0:
        return None  # not positive definite: rank-deficient or nearly so
    inverse, info = scipy.linalg.lapack.dpotri(factor, lower=True)
    if info != 0:
        return None
    inverse = np.tril(inverse) + np.tril(inverse, -1).T
    # lambda_max / lambda_min <= ||S||_1 ||S^-1||_1 (the 2-norm is below the 1-norm for symmetric matrices): a
    # bound computed from the inverse itself, so that the cheaper path is taken only where the eigen path keeps all.
    largest_bound = np.abs(scaled).sum(axis=0).max()
    if largest_bound * np.abs(inverse).sum(axis=0).max() * KEPT_EIGENVALUE_FRACTION < 1.0:
        return inverse
    return inverse if _lanczos_keeps_every_combination(largest_bound, inverse) else None


def _cholesky_solver(factor):
    """S^-1 as a linear operator, from S's lower Cholesky factor (LAPACK potrs)."""
    return scipy.sparse.linalg.LinearOperator(
        factor.shape, matvec=lambda vector: scipy.linalg.lapack.dpotrs(factor, vector, lower=True)[0],
        dtype=factor.dtype)


def _lanczos_keeps_every_combination(largest_bound, inverse):
    """Whether a positive definite scaled Gram matrix of largest eigenvalue at most ``largest_bound`` has every
    eigenvalue above KEPT_EIGENVALUE_FRACTION of it, its smallest measured by Lanczos on ``inverse`` (a matrix or an
    operator); False below _LANCZOS_MIN_SIZE, where the eigendecomposition costs less."""
    if inverse.shape[0] < _LANCZOS_MIN_SIZE:
        return False
    # A 1-norm condition can exceed the eigenvalues' ratio by up to the matrix's size (a star hop's split halves:
    # conditions of 1e8 bounded past 1e10; a model whose gyro misalignment is weak beside the imagers' offsets: 2e-11
    # estimated below 1e-12): the inverse's largest eigenvalue, 1 / lambda_min, itself, by Lanczos (a few ms where
    # the eigendecomposition costs 30-50), from a fixed start so that the same matrix decides alike.
    start = np.random.default_rng(0).standard_normal(inverse.shape[0])
    smallest_reciprocal = scipy.sparse.linalg.eigsh(inverse, k=1, which='LA', v0=start, return_eigenvectors=False)[0]
    return largest_bound * smallest_reciprocal * KEPT_EIGENVALUE_FRACTION < 1.0


def linear_fit(residual: npt.ArrayLike, jacobian: npt.ArrayLike | scipy.sparse.spmatrix,
               names: Iterable[str]) -> LinearFit:
    """Step minimizing |r - J step|^2 with covariance s^2 (J^T J)^+, s^2 = RSS/(n-k); J dense or sparse.

    Args:
        residual: (n,) the residual r.
        jacobian: (n, k) the columns J, dense or sparse ((n,) for one column).
        names: the k parameters' names.

    Returns:
        The step, its sigmas and correlation, the RSS after it and n.

    Raises:
        InvalidArgumentError: the shapes disagree, or a value is not finite.
    """
    residual, jacobian = _checked(residual, jacobian)
    names = tuple(names)
    if len(names) != jacobian.shape[1]:
        raise InvalidArgumentError(f'{len(names)} names for {jacobian.shape[1]} jacobian columns')
    n, k = jacobian.shape
    if k == 0:
        return LinearFit(names, np.zeros(0), np.zeros(0), np.zeros((0, 0)), float(residual @ residual), n)

    def rss_after(step):
        after = residual - jacobian @ step
        return float(after @ after)

    return normal_equations_fit(_gram(jacobian), jacobian.T @ residual, rss_after, names, n)


def normal_equations_fit(gram: np.ndarray, gradient: np.ndarray, rss_after: Callable[[np.ndarray], float],
                         names: Iterable[str], n: int, *, inverse: NormalInverse | None = None) -> LinearFit:
    """linear_fit from its normal equations G = J^T J, g = J^T r: step G^+ g, covariance s^2 G^+ with s^2 = RSS/(n-k),
    where rss_after(step) is |r - J step|^2 (for problems whose Gram matrix is cheaper assembled from its blocks).

    Args:
        gram: (k, k) G = J^T J.
        gradient: (k,) g = J^T r.
        rss_after: |r - J step|^2 of a step.
        names: the k parameters' names.
        n: the number of residuals.
        inverse: NormalInverse.of(gram) where the caller has it, else None (computed here).

    Returns:
        The step, its sigmas and correlation, the RSS after it and n.
    """
    names = tuple(names)
    k = len(names)
    inverse = NormalInverse.of(gram) if inverse is None else inverse
    step = inverse.matrix @ gradient
    rss = rss_after(step)
    covariance = inverse.covariance(rss / max(n - k, 1))
    sigma = np.sqrt(np.diag(covariance))
    with np.errstate(invalid='ignore', divide='ignore'):
        correlation = covariance / np.outer(sigma, sigma)
    return LinearFit(names, step, sigma, correlation, rss, n)


@dataclass(frozen=True)
class CandidateTerm:
    """A term not in the model: its parameter names, starting values, Jacobian columns and switch-on shift.

    ``reference`` is the size at which the effect is expected (e.g. the thesis' magnitudes), one
    value per parameter (0 for a parameter that shapes rather than scales): a candidate that
    could not reach significance even at that size is reported as not observable. None: no
    expected size (every candidate that has columns outside the base span is observable).
    """

    name: str
    param_names: tuple[str, ...]
    start: np.ndarray
    jacobian: np.ndarray
    shift: np.ndarray | None = None
    reference: np.ndarray | None = None


@dataclass(frozen=True)
class RankedCandidate:
    """One candidate fitted jointly with the model (linearized): parameters, sigmas, RSS, delta-BIC."""

    name: str
    params: dict[str, float]
    sigma: dict[str, float]
    rss_after: float
    delta_bic: float
    observable: bool = True
    degenerate_with: tuple[str, ...] = field(default_factory=tuple)
    #: Of the strongest significant candidates: the share of this one's drop in RSS each other one also removes.
    shared_with: dict[str, float] = field(default_factory=dict)
    #: The chi-square drop the term would bring at its reference size, against the bound it must reach.
    detectable_chi2: float | None = None
    detection_bound_chi2: float | None = None
    #: How the joint linearized fit moves the base terms (the base Jacobian's columns) beside the candidate's step,
    #: where the candidate was fitted: a refit starts there, not with the base where it was.
    base_change: np.ndarray | None = field(default=None, compare=False)

    @property
    def significant(self) -> bool:
        """Lowers the BIC by at least SIGNIFICANT_DELTA_BIC and can be told from the model's own terms."""
        return self.observable and self.delta_bic >= SIGNIFICANT_DELTA_BIC


def rank_candidates(residual: npt.ArrayLike, base_jacobian: npt.ArrayLike | scipy.sparse.spmatrix,
                    candidates: Iterable[CandidateTerm],
                    criterion: Callable[[float, int, int], float] = bic) -> list[RankedCandidate]:
    """Fit each CandidateTerm jointly with the base terms; return RankedCandidate best first (docs/compare.md, docs/noise.md).

    ``residual`` is measured minus predicted by the fitted base model, ``base_jacobian`` its
    columns (d prediction / d parameter), both already weighted. Observability is a question of
    significance, not of column norms: a candidate is observable when it lowers the BIC
    significantly, or when it would at its reference size (the chi-square drop
    |P_perp J_c reference|^2 reaching k ln n + SIGNIFICANT_DELTA_BIC); one that the base terms
    absorb completely is returned with ``observable=False`` and delta-BIC 0. Parameters the data
    do not determine get an infinite sigma while the others keep theirs (pseudo-inverse).
    Candidates whose explained signatures are collinear are listed in each other's ``degenerate_with``.

    Args:
        residual: (n,) measured minus predicted by the fitted base model, weighted.
        base_jacobian: (n, k) the base model's columns, weighted, dense or sparse.
        candidates: the terms not in the model.
        criterion: the BIC of (RSS, n, k): bic, or whitened_bic where the weights are the noise floor.

    Returns:
        One RankedCandidate per term: the observable ones first, then by delta-BIC, largest first.

    Raises:
        InvalidArgumentError: the shapes disagree, or a value is not finite.
    """
    residual, base_jacobian = _checked(residual, base_jacobian)
    n, k_base = base_jacobian.shape
    # Frisch-Waugh-Lovell through the base's normal equations: P x = J (J^T J)^+ J^T x.
    base_inverse = NormalInverse.of(_gram(base_jacobian)).matrix

    def base_coefficients(matrix):
        """(J^T J)^+ J^T x: what the base terms take of x; x less J times it is x projected out of the base."""
        return base_inverse @ (base_jacobian.T @ matrix)

    residual_coefficients = base_coefficients(residual)
    residual_perp = residual - base_jacobian @ residual_coefficients
    rss_base = float(residual_perp @ residual_perp)
    bic_base = criterion(rss_base, n, k_base)
    ranked, signatures = [], {}
    for term in candidates:
        columns = np.asarray(term.jacobian, dtype=float).reshape(n, -1)
        column_coefficients = base_coefficients(columns)
        columns_perp = columns - base_jacobian @ column_coefficients
        target_coefficients, target_perp = residual_coefficients, residual_perp
        if term.shift is not None:
            target = residual - np.asarray(term.shift, dtype=float)
            target_coefficients = base_coefficients(target)
            target_perp = target - base_jacobian @ target_coefficients
        outside = np.linalg.norm(columns_perp, axis=0) / np.maximum(np.linalg.norm(columns, axis=0), 1e-300)
        bound = len(term.param_names) * np.log(n) + SIGNIFICANT_DELTA_BIC
        inside = outside < IN_BASE_SPAN_FRACTION
        if np.all(inside):
            ranked.append(RankedCandidate(term.name, dict(zip(term.param_names, map(float, term.start))),
                                          {name: float('inf') for name in term.param_names}, rss_base, 0.0,
                                          observable=False, detectable_chi2=0.0, detection_bound_chi2=bound))
            continue
        # A parameter whose column is the base's own gets no step and an infinite sigma; the others are fitted.
        columns_perp[:, inside] = 0.0
        fit = linear_fit(target_perp, columns_perp, term.param_names)
        explained = residual_perp - (target_perp - columns_perp @ fit.step)
        signatures[term.name] = explained
        values = np.asarray(term.start, dtype=float) + fit.step
        delta = bic_base - criterion(fit.rss, n, k_base + len(term.param_names))
        # The base's share of the joint step (Frisch-Waugh-Lovell): less what the base terms take of the candidate's
        # change of the prediction, columns @ step + shift (the shift's share is the residual's less the target's).
        # Alone, a candidate nearly shared with the base terms (a field rotation beside the HIPO fiducials) moved the
        # Waco star hop's residuals by a thousand times their cost.
        base_change = target_coefficients - residual_coefficients - column_coefficients @ fit.step
        detectable = None
        if term.reference is not None:
            # In units of the fit's own scatter: the whitened rows are in units of their noise only when the model holds.
            scatter = rss_base / max(n - k_base, 1)
            signal = columns_perp @ np.asarray(term.reference, dtype=float)
            detectable = float(signal @ signal) / scatter
        observable = bool(np.any(np.isfinite(fit.sigma))) and (
            delta >= SIGNIFICANT_DELTA_BIC or detectable is None or detectable >= bound)
        ranked.append(RankedCandidate(term.name, dict(zip(term.param_names, map(float, values))),
                                      dict(zip(term.param_names, map(float, fit.sigma))), fit.rss, delta,
                                      observable=observable, detectable_chi2=detectable,
                                      detection_bound_chi2=bound, base_change=base_change))
    ranked = _with_degeneracies(ranked, signatures)
    ranked = _with_shared_fractions(ranked, signatures, residual_perp)
    return sorted(ranked, key=lambda candidate: (not candidate.observable, -candidate.delta_bic))


def shared_fraction(residual: np.ndarray, first: np.ndarray, second: np.ndarray) -> float:
    """The share of the smaller of two explained signatures' RSS drops that the other also removes (0: independent,
    1: either one explains all that both do): (d_a + d_b - d_ab) / min(d_a, d_b), d the drop of a fit to ``residual``.

    Args:
        residual: (n,) the residual both signatures are fitted to.
        first: (n,) the first explained signature.
        second: (n,) the second explained signature.

    Returns:
        The shared fraction in [0, 1]; 0 where a signature is zero.
    """
    gram = np.array([[first @ first, first @ second], [first @ second, second @ second]])
    if gram[0, 0] <= 0.0 or gram[1, 1] <= 0.0:
        return 0.0
    projection = np.array([residual @ first, residual @ second])
    drop_first, drop_second = projection[0]**2 / gram[0, 0], projection[1]**2 / gram[1, 1]
    drop_both = float(projection @ np.linalg.pinv(gram) @ projection)
    return shared_share(drop_first, drop_second, drop_both)


def shared_share(drop_first: float, drop_second: float, drop_both: float) -> float:
    """(d_a + d_b - d_ab) / min(d_a, d_b) of three RSS drops, clipped to [0, 1]; 0 where either drop is none.

    Args:
        drop_first: d_a, the RSS drop of the first term alone.
        drop_second: d_b, the RSS drop of the second term alone.
        drop_both: d_ab, the RSS drop of both together.

    Returns:
        The shared fraction in [0, 1].
    """
    smaller = min(drop_first, drop_second)
    if smaller <= 0.0:
        return 0.0
    return float(np.clip((drop_first + drop_second - drop_both) / smaller, 0.0, 1.0))


def _with_shared_fractions(ranked, signatures, residual_perp):
    """Fill ``shared_with`` among the COMPETITOR_POOL strongest significant candidates (symmetric)."""
    pool = sorted((c for c in ranked if c.significant and c.name in signatures), key=lambda c: -c.delta_bic)
    pool = [c.name for c in pool[:COMPETITOR_POOL]]
    shared = {name: {} for name in pool}
    for index, first in enumerate(pool):
        for second in pool[index + 1:]:
            fraction = shared_fraction(residual_perp, signatures[first], signatures[second])
            shared[first][second] = shared[second][first] = fraction
    return [dataclasses.replace(c, shared_with=shared[c.name]) if c.name in shared else c for c in ranked]


@dataclass(frozen=True)
class CompetingSet:
    """Candidates that explain the same residual about equally well: the data do not choose among them.

    ``effects`` is ordered as a user should consider them: the preferred kind first (physics before
    an empirical shape that mimics it), then by delta-BIC; ``shared_fraction`` is the smallest
    pairwise share of one's RSS drop the other also removes.
    """

    effects: tuple[str, ...]
    delta_bic: dict[str, float]
    shared_fraction: float
    margin: float


def competes(first_delta_bic: float, second_delta_bic: float, shared: float) -> bool:
    """Whether two candidates compete: shared >= SHARED_FRACTION, delta-BICs within competing_margin.

    Args:
        first_delta_bic: the first candidate's delta-BIC.
        second_delta_bic: the second candidate's delta-BIC.
        shared: their shared fraction (shared_fraction).

    Returns:
        Whether they compete.
    """
    return (shared >= SHARED_FRACTION
            and abs(first_delta_bic - second_delta_bic) < competing_margin(first_delta_bic, second_delta_bic))


def competing_margin(first_delta_bic: float, second_delta_bic: float) -> float:
    """The delta-BIC gap below which two overlapping candidates compete: COMPETING_DELTA_BIC or COMPETING_FRACTION.

    Args:
        first_delta_bic: the first candidate's delta-BIC.
        second_delta_bic: the second candidate's delta-BIC.

    Returns:
        The larger of COMPETING_DELTA_BIC and COMPETING_FRACTION of the larger delta-BIC.
    """
    return max(COMPETING_DELTA_BIC, COMPETING_FRACTION * max(first_delta_bic, second_delta_bic))


def competing_sets(ranked: Sequence[RankedCandidate], delta_bic_by_name: Mapping[str, float] | None = None,
                   preferred: Callable[[str], bool] = lambda name: True) -> list[CompetingSet]:
    """CompetingSets of significant candidates (connected by `competes`), strongest set first (docs/compare.md).

    ``delta_bic_by_name`` overrides the linearized delta-BIC (e.g. after a full refit);
    ``preferred(name)`` orders a set's members (True first): physics before empirical shapes.

    Args:
        ranked: the ranked candidates (rank_candidates).
        delta_bic_by_name: delta-BICs that replace the linearized ones, or None.
        preferred: whether a member's kind comes first.

    Returns:
        The competing sets, strongest first.
    """
    scores = {candidate.name: candidate.delta_bic for candidate in ranked}
    scores.update(delta_bic_by_name or {})
    by_name = {candidate.name: candidate for candidate in ranked}
    linked = {name: set() for name in by_name}
    for candidate in ranked:
        if not candidate.significant:
            continue
        for other, shared in candidate.shared_with.items():
            if scores[other] >= SIGNIFICANT_DELTA_BIC and competes(scores[candidate.name], scores[other], shared):
                linked[candidate.name].add(other)
                linked[other].add(candidate.name)
    sets, seen = [], set()
    for name in sorted(linked, key=lambda n: -scores[n]):
        if name in seen or not linked[name]:
            continue
        members, frontier = set(), [name]
        while frontier:
            current = frontier.pop()
            if current not in members:
                members.add(current)
                frontier.extend(linked[current] - members)
        seen |= members
        ordered = tuple(sorted(members, key=lambda n: (not preferred(n), -scores[n])))
        pairs = [by_name[a].shared_with[b] for a in ordered for b in linked[a] if a < b]
        top = max(scores[n] for n in members)
        sets.append(CompetingSet(ordered, {n: float(scores[n]) for n in ordered}, float(min(pairs)),
                                 float(competing_margin(top, top))))
    return sets


def _with_degeneracies(ranked, signatures):
    """Name, for every significant candidate, the others whose explained signature is collinear with its own."""
    unit = {}
    for candidate in ranked:
        norm = np.linalg.norm(signatures.get(candidate.name, 0.0))
        if candidate.significant and norm > 0:
            unit[candidate.name] = signatures[candidate.name] / norm
    names = list(unit)
    pairs = {name: [] for name in names}
    for index, first in enumerate(names):
        for second in names[index + 1:]:
            if abs(unit[first] @ unit[second]) >= DEGENERATE_COSINE:
                pairs[first].append(second)
                pairs[second].append(first)
    return [dataclasses.replace(c, degenerate_with=tuple(pairs.get(c.name, ()))) for c in ranked]


def degenerate_pairs(ranked: Iterable[RankedCandidate],
                     delta_bic_by_name: Mapping[str, float] | None = None) -> list[tuple[str, ...]]:
    """Pairs of collinear candidates whose delta-BIC differ by less than SIGNIFICANT_DELTA_BIC: not separable.

    ``delta_bic_by_name`` overrides the linearized delta-BIC (e.g. after a full refit).

    Args:
        ranked: the ranked candidates (rank_candidates).
        delta_bic_by_name: delta-BICs that replace the linearized ones, or None.

    Returns:
        The pairs, each sorted by name, in order.
    """
    scores = {candidate.name: candidate.delta_bic for candidate in ranked}
    scores.update(delta_bic_by_name or {})
    pairs = set()
    for candidate in ranked:
        for other in candidate.degenerate_with:
            if abs(scores[candidate.name] - scores[other]) < SIGNIFICANT_DELTA_BIC:
                pairs.add(tuple(sorted((candidate.name, other))))
    return sorted(pairs)
