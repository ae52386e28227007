"""The attitude anchors' prior: what the gyro noise lets the anchors add between knots (4.2.3).

The anchors correct the model's gyro attitude at knots 30 s apart; between two knots they may add
only what the gyros' own noise could have done. Angle random walk N makes the increments white;
rate random walk K wanders the bias, so the increments of intervals far apart are correlated
(sensors.gyro_noise.angle_increment_covariance_rad2), wandering away from the record's middle, where
the fitted gyro_bias holds. The prior is generalized least squares: each
interval's increment is turned into TARF axes (the gyros are fixed there, and their noise is the
same on every axis) and the increments of one axis are whitened by the Cholesky factor of their
covariance, so every prior row is a unit normal under the null. Treating the increments as
independent, as a bidiagonal prior does, makes a long record's bias wander look like a missing
effect: a trend with time, and biases that differ between halves.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import numpy.typing as npt
import scipy.linalg
import scipy.sparse

from sofia_ros.compare.floor import anchor_walk_sigma_rad
from sofia_ros.errors import BagError
from sofia_ros.sensors.gyro_noise import angle_increment_covariance_rad2

__all__ = ['AnchorPrior', 'anchor_prior']


@dataclass(frozen=True, eq=False)
class AnchorPrior:
    """The whitened prior rows over the anchors and what the diagnostics need to read them.

    ``matrix`` (3(K-1), 3K): row 3k + j is the innovation of interval k on TARF axis j, a unit
    normal under the null. ``whitening`` (K-1, K-1): per axis, TARF increments in units of
    ``unit_rad`` to innovations in the same units (the identity where ARW dominates).
    ``unit_rad``: one interval's own scatter, sqrt(N^2 dt + K^2 dt^3 / 3), the unit the gyro
    observables are shown in.
    """

    matrix: scipy.sparse.csr_matrix
    whitening: np.ndarray
    unit_rad: float
    knots_s: np.ndarray

    @cached_property
    def gram(self) -> np.ndarray:
        """matrix^T matrix, dense: the prior's constant block of every fit's normal equations (compare.fit)."""
        return (self.matrix.T @ self.matrix).toarray()

    @property
    def middle_s(self) -> np.ndarray:
        """Each anchor interval's middle (s)."""
        return (self.knots_s[:-1] + self.knots_s[1:]) / 2.0


def anchor_prior(knots_s: npt.ArrayLike, tarf_from_irf: np.ndarray, arw_rad_per_sqrt_s: float,
                 rrw_rad_per_s_sqrt_s: float) -> AnchorPrior:
    """The GLS prior of the anchors at ``knots_s`` under ARW and RRW, with the attitudes at the intervals' middles.

    Args:
        knots_s: the anchor knots (s), ascending.
        tarf_from_irf: (K-1, 3, 3) the TARF-from-IRF rotation at each interval's middle.
        arw_rad_per_sqrt_s: the gyros' angle random walk N (rad/sqrt(s)).
        rrw_rad_per_s_sqrt_s: the gyros' rate random walk K (rad/s/sqrt(s)).

    Returns:
        The whitened prior rows, their whitening, unit and knots.

    Raises:
        BagError: the gyro noise allows the anchors no movement (N and K both zero).
    """
    knots = np.asarray(knots_s, dtype=float)
    intervals = len(knots) - 1
    if intervals < 1:
        return AnchorPrior(scipy.sparse.csr_matrix((0, 3 * len(knots))), np.zeros((0, 0)), 1.0, knots)
    unit_rad = anchor_walk_sigma_rad(arw_rad_per_sqrt_s, rrw_rad_per_s_sqrt_s, float(np.median(np.diff(knots))))
    if not unit_rad > 0.0:
        raise BagError('the gyro noise allows the anchors no movement (angle and rate random walk both zero); '
                       'give the model\'s gyro_noise a rate random walk')
    # The bias wanders away from the record's middle both ways: the fitted gyro_bias is the bias there, and two
    # halves of the record each see it across half the record, not one of them across all of it.
    middle_s = (knots[0] + knots[-1]) / 2.0
    covariance = angle_increment_covariance_rad2(knots, arw_rad_per_sqrt_s, rrw_rad_per_s_sqrt_s,
                                                 reference_s=middle_s) / unit_rad**2
    factor = scipy.linalg.cholesky(covariance, lower=True)
    whitening = scipy.linalg.solve_triangular(factor, np.eye(intervals), lower=True)
    # Increments in TARF: row 3k + j of R D is sum_i A_k[j, i] (a_k+1,i - a_k,i).
    rows = np.repeat(np.arange(3 * intervals), 6)
    knot = np.repeat(np.arange(intervals), 3)
    columns = (np.stack([3 * (knot + 1), 3 * knot], axis=1)[:, :, None] + np.arange(3)).reshape(-1, 6)
    values = np.concatenate([tarf_from_irf.reshape(-1, 3), -tarf_from_irf.reshape(-1, 3)], axis=1)
    increments = scipy.sparse.csr_matrix((values.ravel(), (rows, columns.ravel())),
                                         shape=(3 * intervals, 3 * len(knots)))
    matrix = scipy.sparse.kron(scipy.sparse.csr_matrix(whitening), scipy.sparse.identity(3)) @ increments / unit_rad
    return AnchorPrior(scipy.sparse.csr_matrix(matrix), whitening, unit_rad, knots)
