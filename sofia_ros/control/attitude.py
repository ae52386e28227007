"""Attitude propagation of TARF against IRF from gyro rates (2.3, eq. 3.20)."""

from __future__ import annotations

import numpy as np

from sofia_ros.rotation_kernels import (
    compose_quaternions,
    matrices_from_quaternions,
    quaternions_from_rotvecs,
    rotvec_from_matrix,
)
from sofia_ros.validate import finite_array, positive_scalar

__all__ = [
    'propagate_dcm',
    'rotation_error_rad',
    'mean_rate_rad_per_s',
]


def propagate_dcm(frame_from_inertial, rates_rad_per_s, sample_time_s):
    """A_TARF,IRF after body rates held for one sample each, composed exactly (eqs. 3.20, B.23)."""
    rates = finite_array('rates_rad_per_s', rates_rad_per_s)
    if rates.ndim == 1:
        rates = rates[np.newaxis]
    dt = positive_scalar('sample_time_s', sample_time_s)
    steps = quaternions_from_rotvecs(rates * dt)
    # Pairwise tree product, latest on the left: log2(N) vectorized compositions.
    while len(steps) > 1:
        if len(steps) % 2:
            steps = np.concatenate([steps, [[0.0, 0.0, 0.0, 1.0]]])
        steps = compose_quaternions(steps[1::2], steps[0::2])
    # A body turned actively by R has A_new = R^T A_old in the passive convention of B.3.
    return matrices_from_quaternions(steps[0]).T @ frame_from_inertial


def rotation_error_rad(estimated_from_inertial, commanded_from_inertial):
    """Small rotation angles (about TARF EL, XEL, LOS) that take the estimate onto the command (B.19-B.22)."""
    delta = commanded_from_inertial @ estimated_from_inertial.T
    return rotvec_from_matrix(delta.T)


def mean_rate_rad_per_s(before_from_inertial, after_from_inertial, interval_s):
    """Constant body rate (rad/s, in the body frame) that turns one attitude into the next (B.24)."""
    return rotation_error_rad(before_from_inertial, after_from_inertial) / positive_scalar('interval_s', interval_s)
