"""Alignment accuracy from the centroid error sigma_c (section 3.5, eqs. 3.30-3.37).

The centroid errors of X_B, Y_B, X_E, Y_E are random, uncorrelated and equal to
sigma_c (3.5). Angles and angular lengths are in rad, centroids in px.

Slip in eq. 3.35: as printed, ``gamma = arccos(1 - d/L)`` gives 90 deg when the
displacement d equals L (no out-of-plane misalignment). The displacement of a
rotation about an axis tilted by gamma out of the CCD plane is ``L cos(gamma)``,
so ``gamma = arccos(d/L)``; eq. 3.36 follows from this form, not from the printed one.
"""

from __future__ import annotations

import numpy as np

from sofia_ros.errors import InvalidArgumentError
from sofia_ros.validate import finite_array, finite_scalar, positive_scalar

__all__ = [
    'propagated_sigma',
    'sigma_r_rad',
    'sigma_beta_rad',
    'sigma_beta_from_length_rad',
    'gamma_rad',
    'sigma_gamma_rad',
    'standard_error_of_mean',
]


def _pixel(name, value):
    return finite_array(name, value, shape=(2,))


def _distance_px(start_px, end_px):
    return float(np.linalg.norm(_pixel('end_px', end_px) - _pixel('start_px', start_px)))


def propagated_sigma(function, start_px, end_px, sigma_c_px, covariance_px2=None, step_px=1e-4):
    """Sigma of q(X_B, Y_B, X_E, Y_E) by central differences and error propagation (eqs. 3.30-3.31)."""
    point = np.r_[_pixel('start_px', start_px), _pixel('end_px', end_px)]
    step = positive_scalar('step_px', step_px)
    if covariance_px2 is None:
        covariance = np.eye(4) * positive_scalar('sigma_c_px', sigma_c_px) ** 2
    else:
        covariance = finite_array('covariance_px2', covariance_px2, shape=(4, 4))
        if not np.allclose(covariance, covariance.T) or np.linalg.eigvalsh(covariance)[0] < -1e-12:
            raise InvalidArgumentError('covariance_px2 must be symmetric positive semi-definite (eq. 3.30)')
    gradient = np.empty(4)
    for i in range(4):
        delta = np.zeros(4)
        delta[i] = step
        high, low = point + delta, point - delta
        gradient[i] = (function(high[:2], high[2:]) - function(low[:2], low[2:])) / (2.0 * step)
    if not np.all(np.isfinite(gradient)):
        raise InvalidArgumentError('function is not finite near the centroids: cannot propagate (eq. 3.30)')
    return float(np.sqrt(max(gradient @ covariance @ gradient, 0.0)))


def _sine_half(angle_rad):
    sine = abs(np.sin(finite_scalar('rotation_angle_rad', angle_rad) / 2.0))
    if sine < 1e-12:
        raise InvalidArgumentError('rotation_angle_rad must be non-zero: sigma_R divides by sin(alpha/2)')
    return sine


def sigma_r_rad(sigma_c_rad, rotation_angle_rad):
    """Sigma of the LOS misalignment R for one LOS rotation (eq. 3.32)."""
    return np.sqrt(2.0) * positive_scalar('sigma_c_rad', sigma_c_rad) / (2.0 * _sine_half(rotation_angle_rad))


def sigma_beta_rad(sigma_c_px, start_px, end_px):
    """Sigma of the in-plane angle beta from the measured displacement (eq. 3.33)."""
    displacement = _distance_px(start_px, end_px)
    if displacement == 0.0:
        raise InvalidArgumentError('start_px and end_px coincide: sigma_beta divides by the displacement')
    return np.sqrt(2.0) * positive_scalar('sigma_c_px', sigma_c_px) / displacement


def sigma_beta_from_length_rad(sigma_c_rad, length_rad):
    """Sigma of the in-plane angle beta for an EL/XEL maneuver of length L (eq. 3.34)."""
    return np.sqrt(2.0) * positive_scalar('sigma_c_rad', sigma_c_rad) / positive_scalar('length_rad', length_rad)


def gamma_rad(start_px, end_px, length_px):
    """Out-of-plane angle |gamma| = arccos(d / L) of an EL/XEL axis (eq. 3.35, corrected: see module notes)."""
    displacement = _distance_px(start_px, end_px)
    ratio = displacement / positive_scalar('length_px', length_px)
    if ratio > 1.0:
        raise InvalidArgumentError(
            f'displacement {displacement:.6g} px exceeds the maneuver length L (eq. 3.35)')
    return float(np.arccos(ratio))


def sigma_gamma_rad(sigma_c_rad, length_rad):
    """Sigma of the out-of-plane angle gamma of an EL/XEL axis (eq. 3.36)."""
    sigma = positive_scalar('sigma_c_rad', sigma_c_rad)
    denominator = np.sqrt(2.0) * positive_scalar('length_rad', length_rad) - sigma
    if denominator <= 0.0:
        raise InvalidArgumentError('eq. 3.36 needs sqrt(2) L > sigma_c')
    return np.sqrt(sigma / denominator)


def standard_error_of_mean(sigma, n):
    """Standard error of the mean of n measurements of standard deviation sigma (eq. 3.37)."""
    count = finite_scalar('n', n)
    if count < 1 or count != int(count):
        raise InvalidArgumentError(f'n must be a positive integer, got {n}')
    return finite_scalar('sigma', sigma) / np.sqrt(count)
