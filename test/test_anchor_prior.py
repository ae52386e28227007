"""The anchors' gyro-noise prior (compare.prior): generalized least squares over ARW and RRW increments."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sofia_ros.compare.prior import anchor_prior
from sofia_ros.errors import BagError
from sofia_ros.sensors.gyro_noise import angle_increment_covariance_rad2

KNOTS_S = np.arange(0.0, 30.0 * 41, 30.0)
#: Table 5.1's ARW (0.00022 deg/sqrt(h)) and thirty times its K, in rad: the wander dominates after minutes.
ARW_RAD_PER_SQRT_S = 0.0132 / 206264.806
RRW_RAD_PER_S_SQRT_S = 30 * 0.00216 / 60.0 / 206264.806
#: The bias wanders from the record's middle (the fitted gyro_bias holds there).
MIDDLE_S = (KNOTS_S[0] + KNOTS_S[-1]) / 2.0


def _attitudes(count, seed=1):
    return Rotation.random(count, random_state=seed).as_matrix()


def test_the_prior_rows_are_the_tarf_increments_whitened_by_their_covariance():
    attitudes = _attitudes(len(KNOTS_S) - 1)
    prior = anchor_prior(KNOTS_S, attitudes, ARW_RAD_PER_SQRT_S, RRW_RAD_PER_S_SQRT_S)
    anchors = np.random.default_rng(2).normal(0.0, 1e-5, (len(KNOTS_S), 3))
    increments_tarf = np.einsum('kij,kj->ki', attitudes, np.diff(anchors, axis=0))
    expected = prior.whitening @ increments_tarf / prior.unit_rad
    np.testing.assert_allclose((prior.matrix @ anchors.ravel()).reshape(-1, 3), expected, rtol=1e-10, atol=1e-12)
    covariance = angle_increment_covariance_rad2(KNOTS_S, ARW_RAD_PER_SQRT_S, RRW_RAD_PER_S_SQRT_S, MIDDLE_S)
    whitened = prior.whitening @ covariance @ prior.whitening.T / prior.unit_rad**2
    np.testing.assert_allclose(whitened, np.eye(len(KNOTS_S) - 1), atol=1e-9)
    assert prior.unit_rad == pytest.approx(np.sqrt(ARW_RAD_PER_SQRT_S**2 * 30 + RRW_RAD_PER_S_SQRT_S**2 * 30**3 / 3))


def test_a_simulated_arw_and_rrw_walk_gives_unit_normal_uncorrelated_rows():
    """The innovations of 400 simulated walks: variance 1 within 10 % (4 sigma of the sample), lag-1 correlation < 0.05."""
    rng = np.random.default_rng(3)
    attitudes = _attitudes(len(KNOTS_S) - 1)
    prior = anchor_prior(KNOTS_S, attitudes, ARW_RAD_PER_SQRT_S, RRW_RAD_PER_S_SQRT_S)
    covariance = angle_increment_covariance_rad2(KNOTS_S, ARW_RAD_PER_SQRT_S, RRW_RAD_PER_S_SQRT_S, MIDDLE_S)
    factor = np.linalg.cholesky(covariance)
    rows, naive = [], []
    for _ in range(400):
        increments_tarf = factor @ rng.standard_normal((len(KNOTS_S) - 1, 3))
        irf = np.einsum('kji,kj->ki', attitudes, increments_tarf)
        anchors = np.concatenate([np.zeros((1, 3)), np.cumsum(irf, axis=0)])
        rows.append((prior.matrix @ anchors.ravel()).reshape(-1, 3))
        naive.append(increments_tarf / prior.unit_rad)
    rows, naive = np.concatenate(rows), np.concatenate(naive)
    assert np.var(rows) == pytest.approx(1.0, rel=0.1)
    lag = np.mean([np.corrcoef(block[:-1, 0], block[1:, 0])[0, 1] for block in np.split(rows, 400)])
    assert abs(lag) < 0.05
    # Read as independent increments (a bidiagonal prior), the same walks are far from unit normal.
    assert np.var(naive) > 3.0


def test_no_random_walk_at_all_is_one_clear_error():
    with pytest.raises(BagError, match='angle and rate random walk both zero'):
        anchor_prior(KNOTS_S, _attitudes(len(KNOTS_S) - 1), 0.0, 0.0)
