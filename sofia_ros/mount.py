"""Mount geometry on the ground: horizon, aircraft bulkhead, inner cradle, TARF and the inertial frame.

DCMs follow eq. B.3: ``A_BF,RF`` has the BF axes as rows, ``r_BF = A_BF,RF r_RF``.

* HRF (C.4.2): X north, Y west, Z zenith; azimuth from north through east.
* ABRF (C.3.2): U forward (towards the cabin), V out of the left side, W up;
  the aircraft is level with true heading ``heading_deg``.
* ICRF (C.1.1): U along the coarse-drive (EL) axis = ABRF U; W at the CD
  elevation out of the left side; V = W x U. At 90 deg, V = left and W = zenith.
* TARF relative to ICRF: the fine-drive angles, an Euler 1-2-3 sequence
  (EL, XEL, LOS) as in eq. B.4, each limited to +-3 deg.
* IRF: inertially fixed, equal to HRF at the epoch ``t0``; HRF turns east about
  the polar axis at Earth's rate (section 4.1).

With these definitions the gravity load in TARF is (0, g cos el, -g sin el), the
load case of eqs. 3.24/3.28, and a braked telescope senses eqs. 4.1-4.3.
"""

from __future__ import annotations

import numpy as np

from sofia_ros.errors import CommandRefusedError
from sofia_ros.rotation_kernels import is_proper_orthonormal, matrices_from_rotvecs, scipy_rotation
from sofia_ros.units import EARTH_RATE_RAD_PER_S, RAD_PER_DEG
from sofia_ros.validate import finite_array, finite_scalar

__all__ = [
    'FINE_DRIVE_LIMIT_DEG',
    'COARSE_DRIVE_LIMITS_DEG',
    'unit_vector_hrf',
    'altaz_from_unit_vector_hrf',
    'abrf_from_hrf_dcm',
    'icrf_from_abrf_dcm',
    'tarf_from_icrf_dcm',
    'fine_drive_angles_from_dcm',
    'earth_axis_hrf',
    'hrf_from_irf_dcm',
    'tarf_from_hrf_dcm',
    'check_fine_drive_angles',
    'check_coarse_drive_elevation',
]

FINE_DRIVE_LIMIT_DEG = 3.0
#: Beyond this |sin(beta)| (near the 1-2-3 gimbal lock) fine_drive_angles_from_dcm leaves the angles to scipy.
_CLOSED_FORM_MAX_SIN_BETA = 0.99
#: Round-off allowance so that exactly +-3 deg (or 16.5/68.5 deg) passes after rad/deg conversions.
_LIMIT_SLACK_DEG = 1e-9
COARSE_DRIVE_LIMITS_DEG = (16.5, 68.5)


def unit_vector_hrf(altitude_deg, azimuth_deg):
    """Unit vector in HRF (north, west, zenith) from altitude and azimuth (C.4.2)."""
    alt = finite_array('altitude_deg', altitude_deg) * RAD_PER_DEG
    az = finite_array('azimuth_deg', azimuth_deg) * RAD_PER_DEG
    return np.stack([np.cos(alt) * np.cos(az), -np.cos(alt) * np.sin(az), np.sin(alt)], axis=-1)


def altaz_from_unit_vector_hrf(vector_hrf):
    """Altitude and azimuth in degrees (north through east) of an HRF direction (C.4.2)."""
    vector = finite_array('vector_hrf', vector_hrf)
    vector = vector / np.linalg.norm(vector, axis=-1, keepdims=True)
    altitude_deg = np.degrees(np.arcsin(np.clip(vector[..., 2], -1.0, 1.0)))
    azimuth_deg = np.degrees(np.arctan2(-vector[..., 1], vector[..., 0])) % 360.0
    return altitude_deg, azimuth_deg


def abrf_from_hrf_dcm(heading_deg):
    """A_ABRF,HRF for a level aircraft: rows forward, left, up in HRF (C.3.2)."""
    heading = finite_scalar('heading_deg', heading_deg) * RAD_PER_DEG
    forward = [np.cos(heading), -np.sin(heading), 0.0]
    left = [np.sin(heading), np.cos(heading), 0.0]
    return np.array([forward, left, [0.0, 0.0, 1.0]])


def icrf_from_abrf_dcm(elevation_deg):
    """A_ICRF,ABRF at coarse-drive elevation: W up the left side, V = W x U (C.1.1)."""
    el = finite_scalar('elevation_deg', elevation_deg) * RAD_PER_DEG
    return np.array([
        [1.0, 0.0, 0.0],
        [0.0, np.sin(el), -np.cos(el)],
        [0.0, np.cos(el), np.sin(el)],
    ])


def tarf_from_icrf_dcm(fine_drive_rad):
    """A_TARF,ICRF from fine-drive angles (EL, XEL, LOS) as the 1-2-3 sequence of eq. B.4."""
    alpha, beta, gamma = finite_array('fine_drive_rad', fine_drive_rad, shape=(3,)).tolist()
    # The passive product R3(gamma) R2(beta) R1(alpha) of B.4 written out (scipy's intrinsic 'XYZ'
    # active rotation, transposed, to 1e-16; test_mount.py).
    ca, sa, cb, sb, cg, sg = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta), np.cos(gamma), np.sin(gamma)
    return np.array([
        [cg * cb, cg * sb * sa + sg * ca, -cg * sb * ca + sg * sa],
        [-sg * cb, -sg * sb * sa + cg * ca, sg * sb * ca + cg * sa],
        [sb, -cb * sa, cb * ca],
    ])


def fine_drive_angles_from_dcm(tarf_from_icrf):
    """Fine-drive angles (EL, XEL, LOS) in rad from A_TARF,ICRF (inverse of eq. B.4)."""
    matrix = finite_array('tarf_from_icrf', tarf_from_icrf, shape=(3, 3))
    if abs(matrix[2, 0]) < _CLOSED_FORM_MAX_SIN_BETA and is_proper_orthonormal(matrix):
        # Rows of eq. B.4 written out (tarf_from_icrf_dcm): sin(beta) = A31, tan(alpha) = -A32/A33,
        # tan(gamma) = -A21/A11; the same angles as scipy's as_euler('XYZ') to 1e-15 (test_mount.py).
        return np.array([np.arctan2(-matrix[2, 1], matrix[2, 2]), np.arcsin(matrix[2, 0]),
                         np.arctan2(-matrix[1, 0], matrix[0, 0])])
    return scipy_rotation().from_matrix(matrix.T).as_euler('XYZ')


def earth_axis_hrf(latitude_deg):
    """Earth's rotation axis in HRF (north, west, zenith) at a latitude (section 4.1)."""
    lat = finite_scalar('latitude_deg', latitude_deg) * RAD_PER_DEG
    return np.array([np.cos(lat), 0.0, np.sin(lat)])


def hrf_from_irf_dcm(latitude_deg, elapsed_s, earth_rate_rad_per_s=EARTH_RATE_RAD_PER_S):
    """A_HRF(t),IRF: the horizon frame turned east about the polar axis since the epoch (section 4.1)."""
    elapsed = finite_array('elapsed_s', elapsed_s)
    rotvec = np.multiply.outer(elapsed * earth_rate_rad_per_s, earth_axis_hrf(latitude_deg))
    # The HRF axes are the IRF axes actively turned by the Earth; coordinates transform with the transpose.
    return np.swapaxes(matrices_from_rotvecs(rotvec), -1, -2)


def tarf_from_hrf_dcm(heading_deg, elevation_deg, fine_drive_rad=(0.0, 0.0, 0.0)):
    """A_TARF,HRF = A_TARF,ICRF A_ICRF,ABRF A_ABRF,HRF for a level aircraft (C.1-C.3)."""
    return tarf_from_icrf_dcm(fine_drive_rad) @ icrf_from_abrf_dcm(elevation_deg) @ abrf_from_hrf_dcm(heading_deg)


def check_fine_drive_angles(fine_drive_rad):
    """Refuse fine-drive angles beyond +-3 deg (2.3, 3.1)."""
    angles_deg = np.degrees(finite_array('fine_drive_rad', fine_drive_rad, shape=(3,)))
    for axis, angle_deg in zip(('EL', 'XEL', 'LOS'), angles_deg):
        if abs(angle_deg) > FINE_DRIVE_LIMIT_DEG + _LIMIT_SLACK_DEG:
            raise CommandRefusedError(
                f'fine drive {axis} would reach {angle_deg:+.3f} deg, beyond the +-{FINE_DRIVE_LIMIT_DEG:g} deg '
                'travel; command a smaller move or re-centre the fine drive first'
            )


def check_coarse_drive_elevation(elevation_deg):
    """Refuse coarse-drive elevations outside 16.5-68.5 deg."""
    elevation = finite_scalar('elevation_deg', elevation_deg)
    low, high = COARSE_DRIVE_LIMITS_DEG
    if not low - _LIMIT_SLACK_DEG <= elevation <= high + _LIMIT_SLACK_DEG:
        raise CommandRefusedError(
            f'coarse drive elevation {elevation:.3f} deg is outside {low:g}-{high:g} deg; '
            'choose a target within the coarse-drive range'
        )
