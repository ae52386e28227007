"""Attitude conventions (App. B, Table D.2, eq. 6.1) and pixel geometry (eqs. 3.2-3.9)."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sofia_ros import frames
from sofia_ros.calibration.published import EQ_6_1 as A_EQ_6_1
from sofia_ros.calibration.published import TABLE_D2_A1 as A1
from sofia_ros.calibration.published import TABLE_D2_A2 as A2
from sofia_ros.calibration.published import TABLE_D2_A5 as A5
from sofia_ros.errors import InvalidArgumentError, NotOrthonormalError
from sofia_ros.units import ARCSEC_PER_RAD, RAD_PER_ARCSEC


DETECTORS = [frames.HIPO_2004, frames.HIPO_2008, frames.FPI, frames.FFI, frames.WFI]


def random_quaternions(count, seed):
    return Rotation.random(count, random_state=seed).as_quat(canonical=True)


def arcsec(value_rad):
    return np.asarray(value_rad) * ARCSEC_PER_RAD


# --- DCM convention: Table D.1/D.2 and eq. 6.1 --------------------------------

def test_table_d2_matrix_2_is_matrix_1_inverted():
    """Table D.1: "inverting matrix #1 produces matrix #2" - A2 = A1^T pins the rows convention."""
    # The published digits agree to 4.5e-8 (0.009"), not 1e-9: A2[0,2] repeats -A1[0,2]
    # where A1^T has A1[2,0]; A1 itself is orthonormal to 4e-12, A2 only to 9e-8.
    np.testing.assert_allclose(A2, A1.T, rtol=0, atol=5e-8)
    theta_1 = frames.rotation_angles_from_dcm(A1)
    with pytest.warns(UserWarning, match='re-orthonormalized'):
        theta_2 = frames.rotation_angles_from_dcm(A2)
    np.testing.assert_allclose(arcsec(theta_2), -arcsec(theta_1), atol=1e-3)
    # Under the rows convention the corrected #2 tilts LOS the same way as #5 (Table D.2):
    # both turn positively about EL (~1176" and ~1046") and XEL (~566" and ~745").
    with pytest.warns(UserWarning, match='re-orthonormalized'):
        theta_5 = frames.rotation_angles_from_dcm(A5)
    assert np.all(theta_2[:2] > 0) and np.all(theta_5[:2] > 0) and np.all(theta_1[:2] < 0)


def test_eq_6_1_small_rotation_angles():
    """Eq. 6.1 read as A ~= I - [theta x]: about EL ~1035", XEL ~718", LOS ~3595" (docs/conventions.md: 1030/730/3590)."""
    # Single elements (A23 = +theta_u, A13 = -theta_v, A12 = +theta_w) include second-order terms.
    assert arcsec(A_EQ_6_1[1, 2]) == pytest.approx(1035.1, abs=0.1)
    assert arcsec(-A_EQ_6_1[0, 2]) == pytest.approx(718.5, abs=0.1)
    assert arcsec(A_EQ_6_1[0, 1]) == pytest.approx(3595.5, abs=0.1)
    with pytest.warns(UserWarning, match='re-orthonormalized'):
        theta = arcsec(frames.rotation_angles_from_dcm(A_EQ_6_1))
    # Exact rotation vector: 1027.8", 727.5", 3593.9".
    np.testing.assert_allclose(theta, [1027.8, 727.5, 3593.9], atol=0.1)
    np.testing.assert_allclose(theta, [1030.0, 730.0, 3590.0], atol=10.0)
    # "LOS misaligned by about 20 arcmin" is the tilt, "EL/XEL by about 1 deg" the turn about LOS.
    assert np.hypot(theta[0], theta[1]) / 60 == pytest.approx(21.0, abs=0.5)
    assert theta[2] / 3600 == pytest.approx(1.0, abs=0.01)


def test_published_matrices_are_orthonormal_to_1e5_only():
    """A5 (Table D.2) and eq. 6.1 depart from orthonormality by ~9e-6: re-orthonormalized with a warning."""
    for matrix in (A5, A_EQ_6_1):
        assert np.max(np.abs(matrix @ matrix.T - np.eye(3))) == pytest.approx(9.0e-6, abs=0.1e-6)
        with pytest.warns(UserWarning, match='re-orthonormalized'):
            quaternion = frames.quaternion_from_dcm(matrix)
        np.testing.assert_allclose(frames.dcm_from_quaternion(quaternion), matrix, atol=1e-5)


def test_small_rotation_sign_convention():
    """A ~= I - [theta x]: A12 = +theta_w, A13 = -theta_v, A23 = +theta_u (B.19-B.22, B.9)."""
    theta = np.array([3.0, -5.0, 7.0]) * RAD_PER_ARCSEC
    matrix = frames.dcm_from_rotation_angles(theta)
    # Second-order terms are ~theta^2 ~ 1e-4 arcsec here.
    assert arcsec(matrix[0, 1]) == pytest.approx(7.0, abs=1e-4)
    assert arcsec(matrix[0, 2]) == pytest.approx(5.0, abs=1e-4)
    assert arcsec(matrix[1, 2]) == pytest.approx(3.0, abs=1e-4)
    np.testing.assert_allclose(frames.rotation_angles_from_dcm(matrix), theta, atol=1e-15)


def test_rows_are_body_axes_in_reference_frame():
    """Eq. B.3: r_BF = A_BF,RF r_RF, so A applied to its own row i gives the unit vector e_i."""
    matrix = frames.dcm_from_quaternion(random_quaternions(1, 3)[0])
    np.testing.assert_allclose(matrix @ matrix.T, np.eye(3), atol=1e-15)
    for i in range(3):
        np.testing.assert_allclose(matrix @ matrix[i], np.eye(3)[i], atol=1e-15)


# --- Quaternions (B.5-B.10, B.24-B.26) ----------------------------------------

def printed_b9(q):
    q1, q2, q3, q4 = q
    return np.array([
        [q4**2 + q1**2 - q2**2 - q3**2, 2 * (q1 * q2 + q4 * q3), 2 * (q1 * q3 - q4 * q2)],
        [2 * (q1 * q2 - q4 * q3), q4**2 - q1**2 + q2**2 - q3**2, 2 * (q2 * q3 + q4 * q1)],
        [2 * (q1 * q3 + q4 * q2), 2 * (q2 * q3 - q4 * q1), q4**2 - q1**2 - q2**2 + q3**2],
    ])


def printed_b25(p, q):
    p1, p2, p3, p4 = p
    q1, q2, q3, q4 = q
    return np.array([
        p1 * q4 + p2 * q3 - p3 * q2 + p4 * q1,
        -p1 * q3 + p2 * q4 + p3 * q1 + p4 * q2,
        p1 * q2 - p2 * q1 + p3 * q4 + p4 * q3,
        -p1 * q1 - p2 * q2 - p3 * q3 + p4 * q4,
    ])


@pytest.mark.parametrize('q', random_quaternions(20, 1))
def test_b9_dcm_is_transpose_of_scipy(q):
    """Eq. B.9 as printed equals dcm_from_quaternion and the transpose of scipy's as_matrix."""
    np.testing.assert_allclose(frames.dcm_from_quaternion(q), printed_b9(q), atol=1e-15)
    np.testing.assert_allclose(Rotation.from_quat(q).as_matrix().T, printed_b9(q), atol=1e-15)


@pytest.mark.parametrize('q', random_quaternions(20, 2))
def test_b10_quaternion_from_dcm(q):
    """Eq. B.10 (positive root) as printed reproduces quaternion_from_dcm, q4 >= 0."""
    a = printed_b9(q)
    q4 = 0.5 * np.sqrt(1 + a[0, 0] + a[1, 1] + a[2, 2])
    printed = np.array([(a[1, 2] - a[2, 1]) / (4 * q4), (a[2, 0] - a[0, 2]) / (4 * q4),
                        (a[0, 1] - a[1, 0]) / (4 * q4), q4])
    np.testing.assert_allclose(frames.quaternion_from_dcm(a), printed, atol=1e-12)
    np.testing.assert_allclose(frames.quaternion_from_dcm(a), q, atol=1e-12)


def test_b8_sign_and_b7_inverse():
    """Eq. B.8: q and -q give one DCM; eq. B.7: the inverse negates the vector part and transposes the DCM."""
    q = random_quaternions(1, 4)[0]
    np.testing.assert_allclose(frames.dcm_from_quaternion(-q), frames.dcm_from_quaternion(q), atol=1e-15)
    np.testing.assert_allclose(frames.quaternion_inverse(q), [-q[0], -q[1], -q[2], q[3]], atol=1e-15)
    np.testing.assert_allclose(frames.dcm_from_quaternion(frames.quaternion_inverse(q)),
                               frames.dcm_from_quaternion(q).T, atol=1e-15)


@pytest.mark.parametrize('seed', range(10))
def test_b25_product_left_to_right(seed):
    """Eq. B.25 as printed = quaternion_multiply = scipy Rotation(p)*Rotation(q), DCM(r) = DCM(q) DCM(p) (B.23)."""
    p, q = random_quaternions(2, 10 + seed)
    r = frames.quaternion_multiply(p, q)
    np.testing.assert_allclose(r, printed_b25(p, q), atol=1e-15)
    np.testing.assert_allclose(r, (Rotation.from_quat(p) * Rotation.from_quat(q)).as_quat(), atol=1e-15)
    np.testing.assert_allclose(frames.dcm_from_quaternion(r),
                               frames.dcm_from_quaternion(q) @ frames.dcm_from_quaternion(p), atol=1e-14)


def test_attitude_difference_b24_b26():
    """dq = q1^-1 (x) q2 has DCM A2 A1^T (B.24) and q1 (x) dq = q2; B.26 recovers p = r (x) q^-1."""
    q1, q2 = random_quaternions(2, 21)
    dq = frames.quaternion_difference(q1, q2)
    a1, a2 = frames.dcm_from_quaternion(q1), frames.dcm_from_quaternion(q2)
    np.testing.assert_allclose(frames.dcm_from_quaternion(dq), a2 @ a1.T, atol=1e-14)
    np.testing.assert_allclose(frames.dcm_from_quaternion(frames.quaternion_multiply(q1, dq)), a2, atol=1e-14)
    p = frames.quaternion_multiply(q2, frames.quaternion_inverse(dq))
    np.testing.assert_allclose(frames.dcm_from_quaternion(p), a1, atol=1e-14)


# --- Euler 1-2-3, axis/angle, simultaneous angles (B.4, B.11-B.22) ----------

def printed_b4(alpha, beta, gamma):
    ca, sa, cb, sb, cg, sg = np.cos(alpha), np.sin(alpha), np.cos(beta), np.sin(beta), np.cos(gamma), np.sin(gamma)
    r3 = np.array([[cg, sg, 0], [-sg, cg, 0], [0, 0, 1]])
    r2 = np.array([[cb, 0, -sb], [0, 1, 0], [sb, 0, cb]])
    r1 = np.array([[1, 0, 0], [0, ca, sa], [0, -sa, ca]])
    return r3 @ r2 @ r1


@pytest.mark.parametrize('q', random_quaternions(20, 5))
def test_euler123_representations_agree(q):
    """B.4 printed, from DCM, from quaternion (B.11-B.13) and from axis/angle (B.14-B.16) agree."""
    angles = frames.euler123_from_quaternion(q)
    a = frames.dcm_from_quaternion(q)
    np.testing.assert_allclose(printed_b4(*angles), a, atol=1e-14)
    np.testing.assert_allclose(frames.dcm_from_euler123(angles), a, atol=1e-14)
    np.testing.assert_allclose(frames.euler123_from_dcm(a), angles, atol=1e-12)
    axis, angle = frames.axis_angle_from_quaternion(q)
    np.testing.assert_allclose(frames.euler123_from_axis_angle(axis, angle), angles, atol=1e-12)


@pytest.mark.parametrize('q', random_quaternions(20, 6))
def test_b11_b13_printed_with_gamma_sign_slip(q):
    """B.11 and B.12 as printed match; B.13 as printed has the wrong sign of gamma."""
    q1, q2, q3, q4 = q
    alpha, beta, gamma = frames.euler123_from_quaternion(q)
    # Printed arctan(num/den) read quadrant-correctly as arctan2(num, den).
    assert alpha == pytest.approx(np.arctan2(2 * (q4 * q1 - q2 * q3), q4**2 - q1**2 - q2**2 + q3**2), abs=1e-12)
    assert beta == pytest.approx(np.arcsin(2 * (q4 * q2 + q1 * q3)), abs=1e-12)
    printed_gamma = -np.arctan2(2 * (q4 * q3 - q1 * q2), q4**2 + q1**2 - q2**2 - q3**2)
    # From B.4, tan(gamma) = -A21/A11 = +2(q4 q3 - q1 q2)/A11: B.13's leading minus is a slip.
    assert gamma == pytest.approx(-printed_gamma, abs=1e-12)


@pytest.mark.parametrize('q', random_quaternions(20, 7))
def test_b14_b16_from_axis_angle(q):
    """The consistent set of the garbled B.14-B.16 (beta, alpha, gamma) matches euler123_from_axis_angle."""
    (ru, rv, rw), phi = frames.axis_angle_from_quaternion(q)
    c, s = np.cos(phi), np.sin(phi)
    printed = [
        -np.arctan2(rv * rw * (1 - c) - ru * s, c + rw**2 * (1 - c)),  # B.15
        np.arcsin(rv * s + ru * rw * (1 - c)),  # B.14
        -np.arctan2(ru * rv * (1 - c) - rw * s, c + ru**2 * (1 - c)),  # B.16 (printed under "B.14")
    ]
    np.testing.assert_allclose(frames.euler123_from_axis_angle([ru, rv, rw], phi), printed, atol=1e-12)


@pytest.mark.parametrize('q', random_quaternions(20, 8))
def test_b17_b22_axis_angle_and_simultaneous_angles(q):
    """Eqs. B.17-B.18 (axis, angle) and B.19-B.22 (theta = q_vec theta / sin(theta/2)) as printed."""
    theta = 2 * np.arccos(q[3])
    axis, angle = frames.axis_angle_from_quaternion(q)
    assert angle == pytest.approx(theta, abs=1e-12)
    np.testing.assert_allclose(axis, q[:3] / np.sin(theta / 2), atol=1e-12)
    angles = frames.rotation_angles_from_quaternion(q)
    np.testing.assert_allclose(angles, q[:3] * theta / np.sin(theta / 2), atol=1e-12)
    assert np.linalg.norm(angles) == pytest.approx(theta, abs=1e-12)
    np.testing.assert_allclose(frames.dcm_from_rotation_angles(angles), frames.dcm_from_quaternion(q), atol=1e-14)


# --- Pixel <-> pointing vector (eqs. 3.2-3.9) --------------------------------

def test_detector_constants():
    """HIPO: S = 1.5853e-6 rad/px = 0.327"/px, 1152x1030 (3.3.1); imager scales from Table 2.6."""
    assert frames.HIPO_2004.scale_arcsec_per_px == pytest.approx(0.327, abs=5e-4)
    assert frames.HIPO_2004.scale_rad_per_px == pytest.approx(1.5853e-6, rel=1e-12)
    assert (frames.HIPO_2004.width_px, frames.HIPO_2004.height_px) == (1152, 1030)
    assert (frames.HIPO_2004.center_x_px, frames.HIPO_2004.center_y_px, frames.HIPO_2004.rotation_deg) == (559, 489, 40.181)
    assert (frames.HIPO_2008.center_x_px, frames.HIPO_2008.center_y_px, frames.HIPO_2008.rotation_deg) == (542.8, 480.2, 39.81)
    assert [d.scale_arcsec_per_px for d in (frames.WFI, frames.FFI, frames.FPI)] == [20.36, 4.07, 0.55]
    assert frames.IMAGER_SCALE_SECTION_331_ARCSEC_PER_PX == {'wfi': 21.39, 'ffi': 4.07, 'fpi': 0.554}
    assert all(d.center_px.tolist() == [511.5, 511.5] for d in (frames.FPI, frames.FFI, frames.WFI))


def test_hipo_matches_printed_eqs_3_5_to_3_7():
    """HIPO pixel -> TARF vector equals eqs. 3.5-3.7 as printed (2004 fiducials)."""
    rng = np.random.default_rng(30)
    pixels = rng.uniform([1, 1], [1152, 1030], size=(50, 2))
    x0, y0, s = 559.0, 489.0, 1.5853e-6
    phi = np.radians(40.181)
    x, y = pixels.T
    norm = np.sqrt((x - x0) ** 2 + (y - y0) ** 2 + 1 / s**2)
    u = ((y0 - y) * np.sin(phi) - (x0 - x) * np.cos(phi)) / norm
    v = ((y0 - y) * np.cos(phi) + (x0 - x) * np.sin(phi)) / norm
    printed = np.stack([u, v, np.sqrt(1 - u**2 - v**2)], axis=1)
    np.testing.assert_allclose(frames.pixel_to_vector(pixels, frames.HIPO_2004), printed, atol=1e-15)


@pytest.mark.parametrize('detector', [frames.FPI, frames.FFI, frames.WFI])
def test_imagers_match_printed_eqs_3_2_to_3_4(detector):
    """Imager pixel -> XYIRF vector equals eqs. 3.2-3.4 as printed (centre 511.5/511.5)."""
    pixels = np.array([[0.0, 0.0], [1023.0, 17.0], [511.5, 900.0]])
    s = detector.scale_arcsec_per_px * RAD_PER_ARCSEC
    x, y = pixels.T
    norm = np.sqrt((x - 511.5) ** 2 + (y - 511.5) ** 2 + 1 / s**2)
    u, v = (x - 511.5) / norm, (y - 511.5) / norm
    printed = np.stack([u, v, np.sqrt(1 - u**2 - v**2)], axis=1)
    np.testing.assert_allclose(frames.pixel_to_vector(pixels, detector), printed, atol=1e-15)


@pytest.mark.parametrize('detector', DETECTORS, ids=lambda d: f'{d.name}-{d.center_x_px}')
def test_pixel_vector_round_trip(detector):
    """Pixel -> vector -> pixel to 1e-6 px, also far off the chip (turning points, Table 6.2)."""
    rng = np.random.default_rng(31)
    pixels = rng.uniform(-3000, 4000, size=(200, 2))
    back = frames.vector_to_pixel(frames.pixel_to_vector(pixels, detector), detector)
    np.testing.assert_allclose(back, pixels, rtol=0, atol=1e-6)
    single = frames.vector_to_pixel(frames.pixel_to_vector(pixels[0], detector), detector)
    assert single.shape == (2,)
    np.testing.assert_allclose(single, pixels[0], atol=1e-6)


@pytest.mark.parametrize('detector', DETECTORS, ids=lambda d: f'{d.name}-{d.center_x_px}')
def test_centre_and_scale(detector):
    """The boresight maps to w = (0, 0, 1); one pixel off-centre has tan(angle) = S (gnomonic, eqs. 3.2-3.7)."""
    np.testing.assert_allclose(frames.pixel_to_vector(detector.center_px, detector), [0, 0, 1], atol=0)
    offset = frames.pixel_to_vector(detector.center_px + [0.0, 1.0], detector)
    assert arcsec(np.hypot(offset[0], offset[1]) / offset[2]) == pytest.approx(
        detector.scale_arcsec_per_px, rel=1e-12)


def test_boresight_dcm_eqs_3_8_3_9():
    """A_TARF,XYIRF from TARF's w-axis in the imager: rows u, v, w with u2 = 0; A w = e_w."""
    w = frames.pixel_to_vector([640.0, 400.0], frames.FFI)
    a = frames.boresight_dcm(w)
    assert a[0, 1] == 0.0
    np.testing.assert_allclose(a @ a.T, np.eye(3), atol=1e-15)
    assert np.linalg.det(a) == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(a @ w, [0, 0, 1], atol=1e-15)
    np.testing.assert_allclose(frames.boresight_dcm([0, 0, 1]), np.eye(3), atol=0)


# --- Error paths ---------------------------------------------------------------

def test_quaternion_errors():
    with pytest.raises(InvalidArgumentError, match='NaN'):
        frames.dcm_from_quaternion([np.nan, 0, 0, 1])
    with pytest.raises(InvalidArgumentError, match='shape 4'):
        frames.dcm_from_quaternion([0, 0, 1])
    with pytest.raises(InvalidArgumentError, match='unit norm'):
        frames.quaternion_multiply([0, 0, 0, 1.1], [0, 0, 0, 1])
    with pytest.raises(InvalidArgumentError, match='axis .* undefined'):
        frames.axis_angle_from_quaternion([0, 0, 0, 1])
    with pytest.raises(InvalidArgumentError, match='non-zero 3-vector'):
        frames.euler123_from_axis_angle([0, 0, 0], 0.1)


def test_dcm_errors():
    with pytest.raises(NotOrthonormalError, match='not orthonormal'):
        frames.rotation_angles_from_dcm(np.eye(3) * 1.01)
    with pytest.raises(NotOrthonormalError, match='reflection'):
        frames.euler123_from_dcm(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(InvalidArgumentError, match='shape 3x3'):
        frames.quaternion_from_dcm(np.eye(2))
    with pytest.raises(InvalidArgumentError, match='NaN'):
        frames.dcm_from_euler123([0.0, np.inf, 0.0])


def test_pixel_geometry_errors():
    with pytest.raises(InvalidArgumentError, match='shape 2 or Nx2'):
        frames.pixel_to_vector([1.0, 2.0, 3.0], frames.FPI)
    with pytest.raises(InvalidArgumentError, match='NaN'):
        frames.pixel_to_vector([np.nan, 2.0], frames.FPI)
    with pytest.raises(InvalidArgumentError, match='w > 0'):
        frames.vector_to_pixel([0.0, 0.1, -1.0], frames.HIPO_2004)
    with pytest.raises(InvalidArgumentError, match='must be > 0'):
        frames.DetectorGeometry('bad', 10, 10, 5.0, 5.0, 0.0)
    with pytest.raises(InvalidArgumentError, match='size must be > 0'):
        frames.DetectorGeometry('bad', 0, 10, 5.0, 5.0, 1.0)
    with pytest.raises(InvalidArgumentError, match='centre and rotation contains NaN'):
        frames.DetectorGeometry('bad', 10, 10, np.nan, 5.0, 1.0)
    with pytest.raises(InvalidArgumentError, match='w3 > 0'):
        frames.boresight_dcm([1.0, 0.0, 0.0])
    with pytest.raises(InvalidArgumentError, match='non-zero 3-vector'):
        frames.boresight_dcm([0.0, 0.0, 0.0])


def test_rotation_kernels_match_scipy_to_1e_12():
    # The per-tick hot paths use plain-numpy kernels; they must give scipy's answers.
    from scipy.spatial.transform import Slerp

    from sofia_ros import rotation_kernels as k
    from sofia_ros.control.attitude import propagate_dcm, rotation_error_rad
    from sofia_ros.mount import fine_drive_angles_from_dcm, hrf_from_irf_dcm, tarf_from_icrf_dcm
    rng = np.random.default_rng(7)
    for scale in (1e-9, 1e-4, 1e-2, 1.0, 3.0):
        rotvecs = rng.normal(size=(33, 3)) * scale
        quaternions = Rotation.from_rotvec(rotvecs).as_quat()
        np.testing.assert_allclose(k.quaternions_from_rotvecs(rotvecs), quaternions, rtol=0, atol=1e-12)
        np.testing.assert_allclose(k.matrices_from_quaternions(quaternions),
                                   Rotation.from_quat(quaternions).as_matrix(), rtol=0, atol=1e-12)
        np.testing.assert_allclose(k.matrices_from_rotvecs(rotvecs), Rotation.from_rotvec(rotvecs).as_matrix(),
                                   rtol=0, atol=1e-12)
        np.testing.assert_allclose(frames.dcm_from_rotation_angles(rotvecs[0]),
                                   Rotation.from_rotvec(rotvecs[0]).as_matrix().T, rtol=0, atol=1e-12)
        composed = (Rotation.from_quat(quaternions[1:]) * Rotation.from_quat(quaternions[:-1])).as_quat()
        np.testing.assert_allclose(k.compose_quaternions(quaternions[1:], quaternions[:-1]), composed,
                                   rtol=0, atol=1e-12)
        for first, second in zip(quaternions, quaternions[1:]):
            matrix = Rotation.from_quat(first).as_matrix()
            np.testing.assert_allclose(k.quaternion_from_matrix(matrix), Rotation.from_matrix(matrix).as_quat(),
                                       rtol=0, atol=1e-12)
            np.testing.assert_allclose(k.rotvec_from_quaternion(-first), Rotation.from_quat(-first).as_rotvec(),
                                       rtol=0, atol=1e-12)
            np.testing.assert_allclose(k.rotvec_from_matrix(matrix), Rotation.from_matrix(matrix).as_rotvec(),
                                       rtol=0, atol=1e-12)
            np.testing.assert_allclose(k.slerp_quaternion(first, second, 0.3),
                                       Slerp([0.0, 1.0], Rotation.from_quat([first, second]))(0.3).as_quat(),
                                       rtol=0, atol=1e-12)
            np.testing.assert_allclose(frames.quaternion_from_dcm(matrix.T),
                                       Rotation.from_matrix(matrix).as_quat(canonical=True), rtol=0, atol=1e-12)
            np.testing.assert_allclose(frames.dcm_from_quaternion(first), matrix.T, rtol=0, atol=1e-12)
    # A matrix that is not quite orthonormal (a long propagation) is orthonormalized first, as scipy does.
    for departure in (1e-11, 1e-7, 1e-4):
        skewed = Rotation.from_rotvec([0.1, 0.2, 0.3]).as_matrix() + departure * rng.normal(size=(3, 3))
        np.testing.assert_allclose(k.quaternion_from_matrix(skewed), Rotation.from_matrix(skewed).as_quat(),
                                   rtol=0, atol=1e-12)
    with pytest.raises(ValueError, match='Non-positive determinant'):
        k.quaternion_from_matrix(-np.eye(3))
    angles = np.array([0.02, -0.05, 0.04])
    dcm = Rotation.from_euler('XYZ', angles).as_matrix().T
    np.testing.assert_allclose(tarf_from_icrf_dcm(angles), dcm, rtol=0, atol=1e-12)
    np.testing.assert_allclose(fine_drive_angles_from_dcm(dcm), angles, rtol=0, atol=1e-12)
    elapsed_s = np.array([0.0, 10.0, 3600.0])
    from sofia_ros.mount import EARTH_RATE_RAD_PER_S, earth_axis_hrf
    expected = np.swapaxes(Rotation.from_rotvec(np.multiply.outer(elapsed_s * EARTH_RATE_RAD_PER_S,
                                                                  earth_axis_hrf(31.5))).as_matrix(), -1, -2)
    np.testing.assert_allclose(hrf_from_irf_dcm(31.5, elapsed_s), expected, rtol=0, atol=1e-12)
    rates = rng.normal(size=(80, 3)) * 1e-3
    start = Rotation.from_rotvec([0.3, -0.2, 1.0]).as_matrix()
    steps = Rotation.from_rotvec(rates * 0.0025)
    total = Rotation.identity()
    for step in steps:
        total = step * total
    moved = propagate_dcm(start, rates, 0.0025)
    np.testing.assert_allclose(moved, total.as_matrix().T @ start, rtol=0, atol=1e-12)
    np.testing.assert_allclose(rotation_error_rad(start, moved),
                               Rotation.from_matrix((moved @ start.T).T).as_rotvec(), rtol=0, atol=1e-12)


def test_a_node_process_imports_no_scipy():
    # scipy.spatial's import (about 0.4 CPU-s) was a third of a node's start-up, and a graph starts ten of them. A
    # process that builds the graph's cores, as each node does, and ticks them for 20 s of flight imports no scipy;
    # the calibration node imports scipy.optimize (and with it scipy.spatial) when it first fits, and only then.
    code = """if True:
        import sys
        import sofia_ros.nodes.executables, sofia_ros.nodes.shell, sofia_ros.nodes.clock_node, sofia_ros.nodes.recorder_node
        from sofia_ros.campaigns.graph_params import GRAPH_PARAMETERS, graph_config_from_parameters
        from sofia_ros.sim.graph import build_cores
        from sofia_ros.sim.runner import LockstepRunner
        values = {name: default for name, (default, _) in GRAPH_PARAMETERS.items()}
        config = graph_config_from_parameters({**values, 'truth_file': 'config/truth/nominal.yaml'})
        runner = LockstepRunner(build_cores(config), tick_ns=config.tick_ns)
        for _ in range(100):
            runner.step()
        print(sorted(name for name in sys.modules if name.split('.')[0] == 'scipy'))
    """
    result = subprocess.run([sys.executable, '-c', code], capture_output=True, text=True, timeout=120,
                            cwd=Path(__file__).resolve().parents[1])
    assert result.returncode == 0, result.stderr
    assert result.stdout.strip() == '[]'
