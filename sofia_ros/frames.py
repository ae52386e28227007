"""Attitude representations (App. B) and pixel <-> pointing vector geometry (3.2-3.9).

Conventions (each pinned by a test in test/test_frames.py):

* DCM: ``A_BF,RF`` has the BF axes, expressed in RF, as ROWS, so
  ``r_BF = A_BF,RF r_RF`` (eq. B.3) and ``omega_TARF = A_TARF,GYRF omega_GYRF``
  (eq. 3.20). Eq. 3.1 prints the body axes as columns; Table D.1 records that
  matrix #1 was implemented the wrong way round and its inverse became #2.
* Small rotation angles theta (rad) about the RF axes u, v, w (B.19-B.22):
  ``A ~= I - [theta x]``, i.e. A12 = +theta_w, A13 = -theta_v, A23 = +theta_u.
* Quaternions are scalar-last, ``q = (q1, q2, q3, q4)`` with q4 real (B.5-B.6),
  and are the same four numbers as scipy's; the attitude DCM of B.9 is the
  TRANSPOSE of ``Rotation.from_quat(q).as_matrix()``.
* B.25 composes left to right, ``r_RF3,RF1 = p_RF2,RF1 (x) q_RF3,RF2``; numerically
  this is the Hamilton product, scipy's ``Rotation(p) * Rotation(q)``, and
  ``DCM(r) = DCM(q) @ DCM(p)`` (B.23).
* The attitude change from q1 to q2 (both of one frame w.r.t. the same reference,
  4.3.3) is ``dq = q1^-1 (x) q2`` with ``DCM(dq) = A2 A1^T`` (B.24); it is
  expressed in the frame at q1.
* Euler 1-2-3 (B.4): ``A = R3(gamma) R2(beta) R1(alpha)`` with the passive
  single-axis matrices of B.4, i.e. scipy's intrinsic 'XYZ' sequence transposed.
* Detectors: pixel offsets are rotated by ``rotation_deg`` and, for HIPO, mirrored
  (v flipped); the result is a gnomonic projection with scale S (eqs. 3.2-3.7).
  HIPO's frame is TARF itself (eqs. 3.5-3.7); an imager's is its XYIRF (3.2-3.4).

Slips in App. B: B.13 as printed has the wrong sign (from B.4, tan gamma = -A21/A11
= +2(q4 q3 - q1 q2)/(q4^2 + q1^2 - q2^2 - q3^2)); B.14-B.16 are garbled (B.15
printed twice, the gamma formula labelled B.14); the consistent set is B.14 for
beta, B.15 for alpha and the formula labelled "B.14" for gamma. Printed arctan(a/b)
is read as arctan2(a, b). The functions below use scipy; the tests check every
printed formula against them.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sofia_ros.errors import InvalidArgumentError, NotOrthonormalError
from sofia_ros.rotation_kernels import (
    canonical_quaternion,
    matrices_from_quaternions,
    matrices_from_rotvecs,
    quaternion_from_matrix,
    scipy_rotation,
)
from sofia_ros.units import ARCSEC_PER_RAD, RAD_PER_ARCSEC, RAD_PER_DEG
from sofia_ros.validate import finite_array, finite_scalar, orthonormal_dcm, positive_scalar, unit_vector

__all__ = [
    'AXES',
    'QUATERNION_NORM_TOLERANCE',
    'dcm_from_quaternion',
    'quaternion_from_dcm',
    'quaternion_multiply',
    'quaternion_inverse',
    'quaternion_difference',
    'dcm_from_euler123',
    'euler123_from_dcm',
    'euler123_from_dcms',
    'euler123_from_quaternion',
    'euler123_from_axis_angle',
    'axis_angle_from_quaternion',
    'rotation_angles_from_quaternion',
    'dcm_from_rotation_angles',
    'rotation_angles_from_dcm',
    'DetectorGeometry',
    'HIPO_SCALE_RAD_PER_PX',
    'HIPO_2004',
    'HIPO_2008',
    'FPI',
    'FFI',
    'WFI',
    'IMAGER_SCALE_SECTION_331_ARCSEC_PER_PX',
    'pixel_to_vector',
    'vector_to_pixel',
    'boresight_dcm',
]

#: The TARF axes, in the order of every rotation-angle and rate 3-vector (B.19-B.22).
AXES = ('el', 'xel', 'los')
#: Largest | |q| - 1 | accepted before a quaternion is normalized.
QUATERNION_NORM_TOLERANCE = 1e-6
#: Below this the rotation angle is taken as zero and a rotation axis is undefined.
_ZERO_ANGLE_RAD = 1e-12


def _rotation_from_quaternion(q):
    """scipy Rotation of a scalar-last unit quaternion (B.5)."""
    quaternion = finite_array('quaternion', q, shape=(4,))
    norm = float(np.linalg.norm(quaternion))
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise InvalidArgumentError(f'quaternion must have unit norm (B.5), got |q| = {norm:.9g}')
    return scipy_rotation().from_quat(quaternion / norm)


def _rotation_from_dcm(a):
    """scipy Rotation whose active matrix is the transpose of attitude DCM ``a``."""
    return scipy_rotation().from_matrix(orthonormal_dcm('dcm', a).T)


def dcm_from_quaternion(q):
    """Attitude DCM from a scalar-last quaternion (eq. B.9)."""
    quaternion = finite_array('quaternion', q, shape=(4,))
    norm = float(np.sqrt(quaternion @ quaternion))
    if abs(norm - 1.0) > QUATERNION_NORM_TOLERANCE:
        raise InvalidArgumentError(f'quaternion must have unit norm (B.5), got |q| = {norm:.9g}')
    return matrices_from_quaternions(quaternion / norm).T


def quaternion_from_dcm(a):
    """Scalar-last quaternion with q4 >= 0 from an attitude DCM (eq. B.10)."""
    return canonical_quaternion(quaternion_from_matrix(orthonormal_dcm('dcm', a).T))


def quaternion_multiply(p, q):
    """Left-to-right product r_RF3,RF1 = p_RF2,RF1 (x) q_RF3,RF2 (eq. B.25)."""
    return (_rotation_from_quaternion(p) * _rotation_from_quaternion(q)).as_quat()


def quaternion_inverse(q):
    """Inverse quaternion (eq. B.7)."""
    return _rotation_from_quaternion(q).inv().as_quat()


def quaternion_difference(q1, q2):
    """Attitude change dq = q1^-1 (x) q2 from q1 to q2, DCM(dq) = A2 A1^T (eqs. B.24, B.26)."""
    return (_rotation_from_quaternion(q1).inv() * _rotation_from_quaternion(q2)).as_quat()


def dcm_from_euler123(angles_rad):
    """DCM A = R3(gamma) R2(beta) R1(alpha) from Euler 1-2-3 angles (alpha, beta, gamma) (eq. B.4)."""
    angles = finite_array('angles_rad', angles_rad, shape=(3,))
    return scipy_rotation().from_euler('XYZ', angles).as_matrix().T


def euler123_from_dcm(a):
    """Euler 1-2-3 angles (alpha, beta, gamma) in rad of an attitude DCM (inverse of eq. B.4)."""
    return _rotation_from_dcm(a).as_euler('XYZ')


def euler123_from_dcms(a):
    """Euler 1-2-3 angles (N, 3) in rad of a stack of attitude DCMs (N, 3, 3) (inverse of eq. B.4)."""
    stack = finite_array('dcms', a)
    if stack.ndim != 3 or stack.shape[1:] != (3, 3):
        raise InvalidArgumentError(f'dcms must have shape Nx3x3, got {stack.shape}')
    if np.max(np.abs(stack @ np.swapaxes(stack, -1, -2) - np.eye(3)), initial=0.0) > 1e-6:
        raise NotOrthonormalError('dcms must be orthonormal to 1e-6')
    return scipy_rotation().from_matrix(np.swapaxes(stack, -1, -2)).as_euler('XYZ')


def euler123_from_quaternion(q):
    """Euler 1-2-3 angles (alpha, beta, gamma) in rad from a quaternion (eqs. B.11-B.13)."""
    return _rotation_from_quaternion(q).as_euler('XYZ')


def euler123_from_axis_angle(axis, angle_rad):
    """Euler 1-2-3 angles (alpha, beta, gamma) in rad from rotation axis and angle (eqs. B.14-B.16)."""
    rotation_vector = unit_vector('axis', axis) * finite_scalar('angle_rad', angle_rad)
    return scipy_rotation().from_rotvec(rotation_vector).as_euler('XYZ')


def axis_angle_from_quaternion(q):
    """Unit rotation axis and angle in [0, pi] rad from a quaternion (eqs. B.17-B.18)."""
    rotation_vector = _rotation_from_quaternion(q).as_rotvec()
    angle = float(np.linalg.norm(rotation_vector))
    if angle < _ZERO_ANGLE_RAD:
        raise InvalidArgumentError('rotation angle is zero: the rotation axis (eq. B.17) is undefined')
    return rotation_vector / angle, angle


def rotation_angles_from_quaternion(q):
    """Simultaneous rotation angles (theta_u, theta_v, theta_w) in rad from a quaternion (eqs. B.19-B.22)."""
    return _rotation_from_quaternion(q).as_rotvec()


def dcm_from_rotation_angles(theta_rad):
    """Attitude DCM of simultaneous rotation angles about u, v, w; A ~= I - [theta x] (eqs. B.19-B.22)."""
    return matrices_from_rotvecs(finite_array('theta_rad', theta_rad, shape=(3,))).T


def rotation_angles_from_dcm(a):
    """Simultaneous rotation angles (theta_u, theta_v, theta_w) in rad of an attitude DCM (eqs. B.19-B.22)."""
    return _rotation_from_dcm(a).as_rotvec()


@dataclass(frozen=True)
class DetectorGeometry:
    """Pixel layout of an imager or HIPO: centre, scale, rotation and mirror (3.3.1, Table 2.6)."""

    name: str
    width_px: int
    height_px: int
    center_x_px: float
    center_y_px: float
    scale_arcsec_per_px: float
    rotation_deg: float = 0.0
    mirrored: bool = False

    def __post_init__(self):
        if self.width_px <= 0 or self.height_px <= 0:
            raise InvalidArgumentError(f'{self.name}: detector size must be > 0 px')
        positive_scalar(f'{self.name}.scale_arcsec_per_px', self.scale_arcsec_per_px)
        finite_array(f'{self.name} centre and rotation',
                     [self.center_x_px, self.center_y_px, self.rotation_deg])

    @property
    def scale_rad_per_px(self):
        """Image scale S in rad/px (eqs. 3.2-3.6)."""
        return self.scale_arcsec_per_px * RAD_PER_ARCSEC

    @property
    def center_px(self):
        """Boresight (X0, Y0) in px."""
        return np.array([self.center_x_px, self.center_y_px])

    def _plane_matrix(self):
        """2x2 map from pixel offsets (X - X0, Y - Y0) to focal-plane (u, v) directions."""
        angle = self.rotation_deg * RAD_PER_DEG
        cos, sin = np.cos(angle), np.sin(angle)
        flip = -1.0 if self.mirrored else 1.0
        return np.array([[cos, -sin], [flip * sin, flip * cos]])


#: HIPO image scale S (3.3.1): 1.5853e-6 rad/px = 0.327 arcsec/px.
HIPO_SCALE_RAD_PER_PX = 1.5853e-6
#: HIPO in 2004: flange centre (559, 489) px, phi = 40.181 deg (3.3.1); image mirrored (eqs. 3.5-3.6).
HIPO_2004 = DetectorGeometry('hipo', 1152, 1030, 559.0, 489.0,
                             HIPO_SCALE_RAD_PER_PX * ARCSEC_PER_RAD, 40.181, True)
#: HIPO fiducials re-measured in 2008: (542.8, 480.2) px, phi = 39.81 deg (3.3.1 footnote).
HIPO_2008 = DetectorGeometry('hipo', 1152, 1030, 542.8, 480.2,
                             HIPO_SCALE_RAD_PER_PX * ARCSEC_PER_RAD, 39.81, True)
# Imager scales as measured by DLR (Table 2.6); centre 511.5/511.5 for 1x1 binning (3.3.1).
FPI = DetectorGeometry('fpi', 1024, 1024, 511.5, 511.5, 0.55)
FFI = DetectorGeometry('ffi', 1024, 1024, 511.5, 511.5, 4.07)
WFI = DetectorGeometry('wfi', 1024, 1024, 511.5, 511.5, 20.36)
#: The scales quoted in 3.3.1, which differ from Table 2.6 for the WFI (21.39) and FPI (0.554).
IMAGER_SCALE_SECTION_331_ARCSEC_PER_PX = {'wfi': 21.39, 'ffi': 4.07, 'fpi': 0.554}


def _points(name, value, width):
    """``value`` as an array of shape (width,) or (N, width)."""
    array = finite_array(name, value)
    if array.ndim not in (1, 2) or array.shape[-1] != width:
        raise InvalidArgumentError(f'{name} must have shape {width} or Nx{width}, got {array.shape}')
    return array


def pixel_to_vector(pixel_xy, detector):
    """Unit pointing vector(s) in the detector frame from centroid(s) (X, Y) in px (eqs. 3.2-3.7)."""
    pixels = _points('pixel_xy', pixel_xy, 2)
    plane = (pixels - detector.center_px) @ detector._plane_matrix().T
    scale = detector.scale_rad_per_px
    k = 1.0 / np.sqrt(np.sum(plane**2, axis=-1, keepdims=True) + 1.0 / scale**2)
    # w = k / S equals eq. 3.4/3.7 but keeps full precision near the boresight.
    return np.concatenate([plane * k, k / scale], axis=-1)


def vector_to_pixel(vector, detector):
    """Centroid(s) (X, Y) in px of pointing vector(s) in the detector frame (inverse of eqs. 3.2-3.7)."""
    vectors = _points('vector', vector, 3)
    w = vectors[..., 2:]
    if np.any(w <= 0.0):
        raise InvalidArgumentError('vector must point into the detector hemisphere (w > 0)')
    # Column by column: a broadcast (N, 2) / (N, 1) and an (N, 2) @ (2, 2) product cost 3x more on a star hop's rows.
    # The plane matrix is orthogonal (a rotation, mirrored or not): its inverse is its transpose.
    w_scaled = w[..., 0] * detector.scale_rad_per_px
    u, v = vectors[..., 0] / w_scaled, vectors[..., 1] / w_scaled
    (a, b), (c, d) = detector._plane_matrix().T.tolist()
    pixels = np.empty((*w_scaled.shape, 2))
    pixels[..., 0] = u * a + v * c + detector.center_x_px
    pixels[..., 1] = u * b + v * d + detector.center_y_px
    return pixels


def boresight_dcm(w):
    """A_TARF,XYIRF with rows u, v, w from TARF's w-axis measured in the imager, u2 = 0 (eqs. 3.8-3.9)."""
    w_axis = unit_vector('w', w)
    w1, _, w3 = w_axis
    if w3 <= 0.0:
        raise InvalidArgumentError('w must be less than 90 deg from the imager w-axis (w3 > 0, eq. 3.8)')
    u1 = np.sqrt(w3**2 / (w1**2 + w3**2))
    u_axis = np.array([u1, 0.0, -u1 * w1 / w3])
    return np.vstack([u_axis, np.cross(w_axis, u_axis), w_axis])
