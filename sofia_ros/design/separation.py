"""How far data separate two explanations: the profiled information of a linear problem (docs/design.md).

A block of data (a bag, or one plan element of it) is summarized by its *profiled Gram matrix*
over the shared parameters (the model's fitted terms and every member's): the normal matrix of the
whitened problem with the block's own nuisance (its attitude anchors) eliminated by a Schur
complement. Blocks with nuisances of their own add: the information of an old bag plus a set of
new elements is the sum of their profiled Grams.

If A is true with size theta_A, fitting B instead leaves the non-centrality
lambda = |(I - P_[M,B]) J_A theta_A|^2 = theta_A^T (S_AA - S_A,R S_RR^-1 S_R,A) theta_A, R = [M, B],
and the expected BIC difference (compare's BIC n ln(RSS / n) + k ln n, whitened residuals of variance s^2, so
the true member's RSS is n s^2 and the rival's that plus lambda) is n ln(1 + lambda / (n s^2)) + (k_B - k_A)(ln n - 1):
the non-centrality through compare's logarithm, the chi-square expectation of the extra parameters and their BIC
penalty. Where lambda is small beside n s^2 that is lambda / s^2 + ...; where it is not, lambda / s^2 overstated
compare's delta-BIC 258-fold (a field rotation against the HIPO fiducials on four star-hop observations).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

from sofia_ros.errors import InvalidArgumentError

__all__ = ['Information', 'expected_delta_bic', 'fitted_values', 'noncentrality', 'profiled_gram', 'pseudo_inverse',
           'rss_drop', 'sigma_of']

#: Relative singular-value cut of the pseudo-inverses: columns a block cannot see (a camera it lacks) drop out.
_RCOND = 1e-10


def pseudo_inverse(matrix: np.ndarray) -> np.ndarray:
    """Pseudo-inverse of a symmetric positive semi-definite matrix, scaled to unit diagonal first (the columns'
    units differ by many orders: ppm, deg, px); columns the data do not see (zero diagonal) count zero."""
    if matrix.size == 0:
        return matrix.copy()
    scale = np.sqrt(np.maximum(np.diag(matrix), 0.0))
    inverse_scale = np.divide(1.0, scale, out=np.zeros_like(scale), where=scale > 0.0)
    normalized = matrix * np.outer(inverse_scale, inverse_scale)
    return np.linalg.pinv(normalized, rcond=_RCOND, hermitian=True) * np.outer(inverse_scale, inverse_scale)


def profiled_gram(nuisance_gram: np.ndarray, cross: np.ndarray, parameter_gram: np.ndarray) -> np.ndarray:
    """S = G_pp - G_np^T G_nn^+ G_np: the parameters' normal matrix with the nuisance eliminated (Schur complement).

    Args:
        nuisance_gram: G_nn (q, q), the nuisance columns' normal matrix (prior rows included).
        cross: G_np (q, p), nuisance against parameter columns.
        parameter_gram: G_pp (p, p).

    Returns:
        The profiled Gram matrix (p, p), symmetrized.
    """
    profiled = parameter_gram - cross.T @ pseudo_inverse(nuisance_gram) @ cross
    return (profiled + profiled.T) / 2.0


@dataclass(frozen=True)
class Information:
    """Profiled Gram matrix of a block over the shared parameter labels, its gradient and its row count."""

    labels: tuple
    gram: np.ndarray
    gradient: np.ndarray
    rows: int

    def __add__(self, other: Information) -> Information:
        if self.labels != other.labels:
            raise InvalidArgumentError('information blocks over different parameters cannot be added')
        return Information(self.labels, self.gram + other.gram, self.gradient + other.gradient, self.rows + other.rows)

    def index(self, labels: Sequence[str]) -> np.ndarray:
        """Column indices of ``labels``."""
        return np.array([self.labels.index(label) for label in labels], dtype=int)


def _conditional(gram: np.ndarray, target: np.ndarray, given: np.ndarray) -> np.ndarray:
    """S_tt - S_tg S_gg^+ S_gt: the information on ``target`` left once ``given`` is fitted too."""
    block = gram[np.ix_(target, target)]
    if given.size == 0:
        return block
    cross = gram[np.ix_(given, target)]
    return block - cross.T @ pseudo_inverse(gram[np.ix_(given, given)]) @ cross


def noncentrality(information: Information, true_labels: Sequence[str], true_values: np.ndarray,
                  rival_labels: Sequence[str], shared_labels: Sequence[str]) -> float:
    """|(I - P_[M,B]) J_A theta_A|^2 from profiled information: what fitting the rival leaves of the true signature.

    Args:
        information: the data's profiled information.
        true_labels: the true member's parameter labels (A).
        true_values: its size theta_A, in the labels' units.
        rival_labels: the rival member's labels (B).
        shared_labels: the model's fitted terms (M), fitted under either member.

    Returns:
        The non-centrality (units of the whitened noise variance).
    """
    left = _conditional(information.gram, information.index(true_labels),
                        information.index([*shared_labels, *rival_labels]))
    values = np.asarray(true_values, dtype=float)
    return float(max(values @ left @ values, 0.0))


def expected_delta_bic(noncentrality_value: float, true_count: int, rival_count: int, rows: int,
                       variance: float = 1.0) -> float:
    """Expected BIC(rival) - BIC(true) when the true member holds: n ln(1 + lambda / (n s^2)) + (k_B - k_A)(ln n - 1)
    (module docstring).

    Args:
        noncentrality_value: lambda (noncentrality).
        true_count: k_A, the true member's parameters.
        rival_count: k_B, the rival's.
        rows: n, the whitened rows the BIC counts.
        variance: s^2, the whitened residuals' variance (RSS / n of the fit).

    Returns:
        The expected delta-BIC in favour of the true member.
    """
    if rows <= 1 or variance <= 0.0:
        raise InvalidArgumentError(f'expected_delta_bic needs rows > 1 and a positive variance, got {rows}, {variance}')
    return rows * np.log1p(noncentrality_value / (rows * variance)) + (rival_count - true_count) * (np.log(rows) - 1.0)


def sigma_of(information: Information, labels: Sequence[str], variance: float = 1.0) -> np.ndarray:
    """1-sigma of each of ``labels`` fitted together (inf where the data do not determine one).

    Args:
        information: the data's profiled information.
        labels: the fitted parameters (the model's terms and one member's).
        variance: s^2, the whitened residuals' variance.

    Returns:
        Sigmas in the labels' units.
    """
    index = information.index(labels)
    covariance = pseudo_inverse(information.gram[np.ix_(index, index)])
    sigma = np.sqrt(variance * np.maximum(np.diag(covariance), 0.0))
    # A parameter the data do not see at all has no sigma.
    return np.where(np.diag(information.gram)[index] > 0.0, sigma, np.inf)


def fitted_values(information: Information, labels: Sequence[str]) -> np.ndarray:
    """The linearized least-squares values of ``labels`` from the information's gradient (J^T r profiled).

    Args:
        information: the data's profiled information with its gradient at the model's fit.
        labels: the fitted parameters (the model's terms and one member's).

    Returns:
        Values in the labels' units (the step from the model's fit).
    """
    index = information.index(labels)
    return pseudo_inverse(information.gram[np.ix_(index, index)]) @ information.gradient[index]


def rss_drop(information: Information, labels: Sequence[str]) -> float:
    """How much fitting ``labels`` lowers the whitened RSS from the model's fit: g^T S^+ g."""
    index = information.index(labels)
    gradient = information.gradient[index]
    return float(gradient @ pseudo_inverse(information.gram[np.ix_(index, index)]) @ gradient)
