"""Calibration science: alignment solvers (3.3, eqs. 3.8-3.19), accuracies (3.5, eqs. 3.30-3.37), the boresight
series over elevation (Table 3.5, 6.2; boresights) and the maneuver records of /calibration/maneuvers."""

from sofia_ros.calibration.accuracy import (
    gamma_rad,
    propagated_sigma,
    sigma_beta_from_length_rad,
    sigma_beta_rad,
    sigma_gamma_rad,
    sigma_r_rad,
    standard_error_of_mean,
)
from sofia_ros.calibration.solvers import (
    AlignmentFit,
    Maneuver,
    candidate_rotation_axes,
    dcm_from_w_and_beta,
    el_misalignment_rad,
    fit_alignment,
    gyro_alignment_from_axes,
    los_misalignment_px,
    select_rotation_axis,
    turning_point_two_stars_px,
    xel_misalignment_rad,
)
from sofia_ros.frames import boresight_dcm

__all__ = [
    'AlignmentFit',
    'Maneuver',
    'boresight_dcm',
    'candidate_rotation_axes',
    'dcm_from_w_and_beta',
    'el_misalignment_rad',
    'fit_alignment',
    'gamma_rad',
    'gyro_alignment_from_axes',
    'los_misalignment_px',
    'propagated_sigma',
    'select_rotation_axis',
    'sigma_beta_from_length_rad',
    'sigma_beta_rad',
    'sigma_gamma_rad',
    'sigma_r_rad',
    'standard_error_of_mean',
    'turning_point_two_stars_px',
    'xel_misalignment_rad',
]
