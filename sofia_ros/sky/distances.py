"""Angular distances between stars: from horizontal coordinates (4.36-4.37), from TA Euler
angles of an attitude change (4.3.3, 4.38), corrected for the centroid offsets of short moves
(6.7-6.8) and for refraction (6.2).

The printed cosine formulas lose precision for small separations (cos d is flat near 0), so
the functions evaluate the same quantities in forms that are well conditioned at every
distance; the tests check them against the printed forms.
"""

from __future__ import annotations

import numpy as np

from sofia_ros.frames import euler123_from_dcm, euler123_from_dcms
from sofia_ros.sky.refraction import apparent_altitude_deg
from sofia_ros.units import ARCSEC_PER_RAD, RAD_PER_ARCSEC, RAD_PER_DEG
from sofia_ros.validate import finite_array, positive_scalar

__all__ = [
    'FPI_SCALE_ARCSEC_PER_PX',
    'angular_distance_arcsec',
    'angular_distance_cosine_rule_arcsec',
    'attitude_change_euler_arcsec',
    'spherical_sum_arcsec',
    'short_move_euler_arcsec',
    'refraction_adjusted_distance_arcsec',
    'place_distance_arcsec',
]

#: FPI image scale used in eqs. 6.7-6.8.
FPI_SCALE_ARCSEC_PER_PX = 0.55


def _horizontal_unit_vectors(altitude_deg, azimuth_deg, star):
    """Unit vectors of the horizontal frame (App. C.4.2: x North, y completes, z zenith)."""
    altitude_rad = finite_array(f'altitude{star}_deg', altitude_deg) * RAD_PER_DEG
    azimuth_rad = finite_array(f'azimuth{star}_deg', azimuth_deg) * RAD_PER_DEG
    # Only the angle between two vectors is used, so the handedness of y does not matter.
    return np.stack([np.cos(altitude_rad) * np.cos(azimuth_rad),
                     np.cos(altitude_rad) * np.sin(azimuth_rad),
                     np.sin(altitude_rad) * np.ones_like(azimuth_rad)], axis=-1)


def angular_distance_arcsec(altitude1_deg, azimuth1_deg, altitude2_deg, azimuth2_deg):
    """Angular distance of two stars from Alt/Az (eqs. 4.36/4.37, as atan2(|a x b|, a . b))."""
    first = _horizontal_unit_vectors(altitude1_deg, azimuth1_deg, 1)
    second = _horizontal_unit_vectors(altitude2_deg, azimuth2_deg, 2)
    sine = np.linalg.norm(np.cross(first, second), axis=-1)
    cosine = np.sum(first * second, axis=-1)
    return np.arctan2(sine, cosine) * ARCSEC_PER_RAD


def angular_distance_cosine_rule_arcsec(altitude1_deg, azimuth1_deg, altitude2_deg, azimuth2_deg):
    """Angular distance of two stars from Alt/Az by the law of cosines as printed (eq. 4.37)."""
    altitude1 = finite_array('altitude1_deg', altitude1_deg) * RAD_PER_DEG
    altitude2 = finite_array('altitude2_deg', altitude2_deg) * RAD_PER_DEG
    delta_azimuth = (finite_array('azimuth1_deg', azimuth1_deg)
                     - finite_array('azimuth2_deg', azimuth2_deg)) * RAD_PER_DEG
    cosine = (np.cos(delta_azimuth) * np.cos(altitude1) * np.cos(altitude2)
              + np.sin(altitude1) * np.sin(altitude2))
    return np.arccos(np.clip(cosine, -1.0, 1.0)) * ARCSEC_PER_RAD


def attitude_change_euler_arcsec(first_dcm, second_dcm):
    """EL, XEL, LOS ["] of the attitude change from A1 to A2, LOS the last rotation (4.3.3: B.24, B.11-B.13)."""
    # DCM(dq) = A2 A1^T (B.24); Euler 1-2-3 = EL, XEL, LOS about the axes of the first attitude.
    first, second = np.asarray(first_dcm, dtype=float), np.asarray(second_dcm, dtype=float)
    if first.ndim == 3 or second.ndim == 3:
        # A stack of attitude pairs (N, 3, 3): the same angles, row by row.
        return euler123_from_dcms(second @ np.swapaxes(first, -1, -2)) * ARCSEC_PER_RAD
    return euler123_from_dcm(second @ first.T) * ARCSEC_PER_RAD


def spherical_sum_arcsec(el_arcsec, xel_arcsec):
    """Distance from the EL and XEL Euler angles of an attitude change, cos d = cos EL cos XEL (eq. 4.38)."""
    # With h(x) = sin^2(x/2): h(d) = h(EL) + h(XEL) - 2 h(EL) h(XEL), the same identity
    # without the cancellation of arccos near zero.
    half_el = np.sin(finite_array('el_arcsec', el_arcsec) * RAD_PER_ARCSEC / 2.0) ** 2
    half_xel = np.sin(finite_array('xel_arcsec', xel_arcsec) * RAD_PER_ARCSEC / 2.0) ** 2
    haversine = half_el + half_xel - 2.0 * half_el * half_xel
    return 2.0 * np.arcsin(np.sqrt(np.clip(haversine, 0.0, 1.0))) * ARCSEC_PER_RAD


def short_move_euler_arcsec(el_arcsec, xel_arcsec, pixel_before_px, pixel_after_px,
                            scale_arcsec_per_px=FPI_SCALE_ARCSEC_PER_PX):
    """EL, XEL of a short move corrected by the star's FPI pixels before and after it (eqs. 6.7-6.8)."""
    # Pixels are (X, Y) = (column, row): EL + s (Y1 - Y2), XEL + s (X2 - X1).
    scale = positive_scalar('scale_arcsec_per_px', scale_arcsec_per_px)
    x1, y1 = finite_array('pixel_before_px', pixel_before_px, shape=(2,))
    x2, y2 = finite_array('pixel_after_px', pixel_after_px, shape=(2,))
    el_short = finite_array('el_arcsec', el_arcsec) + scale * (y1 - y2)
    xel_short = finite_array('xel_arcsec', xel_arcsec) + scale * (x2 - x1)
    return el_short, xel_short


def refraction_adjusted_distance_arcsec(altitude1_deg, azimuth1_deg, refraction1_arcsec,
                                        altitude2_deg, azimuth2_deg, refraction2_arcsec):
    """Distance of two stars after raising each by its refraction (eq. 6.2, then 4.37)."""
    return angular_distance_arcsec(apparent_altitude_deg(altitude1_deg, refraction1_arcsec),
                                   azimuth1_deg,
                                   apparent_altitude_deg(altitude2_deg, refraction2_arcsec),
                                   azimuth2_deg)


def place_distance_arcsec(first, second, *, refracted=True):
    """Distance of two ObservedPlace records, refracted (6.2 + 4.37) or catalogue (4.37)."""
    if refracted:
        return float(angular_distance_arcsec(first.apparent_altitude_deg, first.azimuth_deg,
                                             second.apparent_altitude_deg, second.azimuth_deg))
    return float(angular_distance_arcsec(first.altitude_deg, first.azimuth_deg,
                                         second.altitude_deg, second.azimuth_deg))
