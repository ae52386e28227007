"""Alignment algorithms 3.10-3.19 and the least-squares maneuver fit (3.3.2-3.3.3, Table 3.4)."""

import numpy as np
import pytest

from sofia_ros import frames
from sofia_ros.calibration import solvers
from sofia_ros.calibration.published import EQ_6_1 as A_EQ_6_1
from sofia_ros.calibration.published import TABLE_D2_A5 as A5
from sofia_ros.calibration.solvers import AXIS_VECTORS, Maneuver, fit_alignment
from sofia_ros.errors import InvalidArgumentError, NotOrthonormalError
from sofia_ros.units import ARCSEC_PER_RAD, RAD_PER_ARCSEC, RAD_PER_DEG

HIPO = frames.HIPO_2004
PHI = HIPO.rotation_deg * RAD_PER_DEG
L_RAD = 4.8 * 60 * RAD_PER_ARCSEC  # EL/XEL maneuver after LOS alignment (6.1)
L_PX = L_RAD / HIPO.scale_rad_per_px
# Pixel direction of the star for +EL and +XEL rotations under eqs. 3.5-3.6.
EL_MOTION = -np.array([np.sin(PHI), np.cos(PHI)])
XEL_MOTION = np.array([-np.cos(PHI), np.sin(PHI)])



def arcsec(value_rad):
    return np.asarray(value_rad) * ARCSEC_PER_RAD


def fly_gyro_maneuver(axis, angle_rad, start_px, a_true, a_est):
    """True HIPO end centroid: gyros turn about A_est^T e_k (3.20), star fixed in IRF (B.6, B.23, B.25)."""
    s_irf = frames.pixel_to_vector(start_px, HIPO)  # TARF = IRF at the start (C.1.2)
    gyro_axis = a_est.T @ AXIS_VECTORS[axis]
    q_gyro = frames.quaternion_from_dcm(a_true.T)  # A_GYRF,IRF = A_GYRF,TARF A_TARF,IRF
    turn = np.r_[gyro_axis * np.sin(angle_rad / 2), np.cos(angle_rad / 2)]  # GYRF1 w.r.t. GYRF0
    a_tarf_irf = a_true @ frames.dcm_from_quaternion(frames.quaternion_multiply(q_gyro, turn))
    return frames.vector_to_pixel(a_tarf_irf @ s_irf, HIPO)


def fly_imager_maneuver(axis, angle_rad, start_px, a_imager_tarf, detector):
    """True imager end centroid for a true TARF rotation about e_k (aligned gyros), star fixed in IRF."""
    s_irf = a_imager_tarf.T @ frames.pixel_to_vector(start_px, detector)
    turn = np.r_[AXIS_VECTORS[axis] * np.sin(angle_rad / 2), np.cos(angle_rad / 2)]
    return frames.vector_to_pixel(a_imager_tarf @ frames.dcm_from_quaternion(turn) @ s_irf, detector)


def misalignment(el_arcsec, xel_arcsec, los_arcsec):
    return frames.dcm_from_rotation_angles(np.array([el_arcsec, xel_arcsec, los_arcsec]) * RAD_PER_ARCSEC)


# --- Closed forms --------------------------------------------------------------

def test_los_misalignment_eq_3_10():
    """R from one star is the angular tilt of the LOS axis (eq. 3.10): 20' tilt, star at the flange centre."""
    a_true = misalignment(900.0, -700.0, 0.0)
    for angle in (np.radians(5.0), np.radians(-3.0)):
        end = fly_gyro_maneuver('los', angle, HIPO.center_px, a_true, np.eye(3))
        r_px = solvers.los_misalignment_px(HIPO.center_px, end, angle)
        assert r_px * HIPO.scale_arcsec_per_px == pytest.approx(np.hypot(900.0, 700.0), abs=0.5)


def test_turning_point_two_stars_eqs_3_11_3_12():
    """Eqs. 3.11-3.12 give the LOS turning point, which is TARF's LOS axis seen by HIPO (3.3.2)."""
    a_true = misalignment(400.0, 250.0, 1800.0)
    star1, star2 = HIPO.center_px + [-150.0, 80.0], HIPO.center_px + [200.0, 120.0]
    angle = np.radians(5.0)
    end1, end2 = (fly_gyro_maneuver('los', angle, s, a_true, np.eye(3)) for s in (star1, star2))
    turning_point = solvers.turning_point_two_stars_px(star1, end1, star2, end2)
    # The gyro LOS axis in TARF is the third column of A_TARF,GYRF (eq. 3.20).
    expected = frames.vector_to_pixel(a_true[:, 2], HIPO)
    np.testing.assert_allclose(turning_point, expected, atol=0.05)
    radius = np.linalg.norm(turning_point - star1)
    assert radius == pytest.approx(solvers.los_misalignment_px(star1, end1, angle), abs=0.05)


@pytest.mark.parametrize('angle', [np.radians(5.0), np.radians(-4.0), L_RAD, -L_RAD])
def test_candidate_axes_eqs_3_13_3_15(angle):
    """Both candidates carry s_b to s_e by the signed angle; g1 lies along s_b + s_e (eqs. 3.13-3.15)."""
    rng = np.random.default_rng(40)
    g_true = np.array([0.004, -0.003, 1.0]) / np.linalg.norm([0.004, -0.003, 1.0])
    s_b = frames.pixel_to_vector(HIPO.center_px + rng.uniform(-200, 200, 2), HIPO)
    s_e = solvers.passive_rotate(s_b, g_true, angle)
    g1, g2 = solvers.candidate_rotation_axes(s_b, s_e, angle)
    for g in (g1, g2):
        np.testing.assert_allclose(solvers.passive_rotate(s_b, g, angle), s_e, atol=1e-13)
    np.testing.assert_allclose(g1, g_true, atol=1e-9)
    # "Since the LOS axis is always pointing ... in the same direction as the pointing vectors": g1.
    np.testing.assert_allclose(solvers.select_rotation_axis(g1, g2, 'los'), g1, atol=0)
    assert g1 @ (s_b + s_e) > 0 > g2 @ (s_b + s_e)


def test_candidate_axes_match_printed_3_14_for_positive_angle():
    """For angle > 0 the candidates are exactly eqs. 3.13-3.15 as printed."""
    s_b = frames.pixel_to_vector([300.0, 700.0], HIPO)
    s_e = frames.pixel_to_vector([820.0, 260.0], HIPO)
    angle = 0.01
    x = np.arcsin(np.linalg.norm(s_e - s_b) / (np.linalg.norm(s_e + s_b) * np.tan(angle / 2)))
    bis = (s_e + s_b) / np.linalg.norm(s_e + s_b)
    nor = np.cross(s_e, s_b) / np.linalg.norm(np.cross(s_e, s_b))
    g1, g2 = solvers.candidate_rotation_axes(s_b, s_e, angle)
    np.testing.assert_allclose(g1, np.cos(x) * bis + np.sin(x) * nor, atol=1e-15)
    np.testing.assert_allclose(g2, -np.cos(x) * bis + np.sin(x) * nor, atol=1e-15)


def test_select_in_plane_axis_for_el():
    """EL/XEL: candidates differ in the sign of LOS, which cannot be told apart; drop LOS (3.3.2)."""
    gamma = 0.01  # out-of-plane tilt of the true EL axis (Fig. 3.19c)
    g_true = np.array([np.cos(gamma), 0.0, np.sin(gamma)])
    s_b = np.array([0.0, 0.0, 1.0])
    s_e = solvers.passive_rotate(s_b, g_true, L_RAD)
    g1, g2 = solvers.candidate_rotation_axes(s_b, s_e, L_RAD)
    assert g1[2] == pytest.approx(np.sin(gamma), abs=1e-9) and g2[2] == pytest.approx(-np.sin(gamma), abs=1e-9)
    np.testing.assert_allclose(g1, g_true, atol=1e-9)
    # The in-plane estimate is the chord normal, off the EL axis by ~L gamma / 2 (1.4").
    chosen = solvers.select_rotation_axis(g1, g2, 'el')
    assert chosen[2] == 0.0
    assert arcsec(np.arccos(chosen[0])) == pytest.approx(arcsec(L_RAD * gamma / 2), rel=0.01)


@pytest.mark.parametrize('beta_arcsec', [0.0, 234.0, -3600.0])
def test_in_plane_angles_eqs_3_16_3_17(beta_arcsec):
    """EL and XEL maneuvers both return the rotation about LOS of A_TARF,GYRF (corrected 3.16/3.17)."""
    a_true = misalignment(0.0, 0.0, beta_arcsec)
    for sign in (1.0, -1.0):
        start = HIPO.center_px - sign * EL_MOTION * L_PX / 2
        end = fly_gyro_maneuver('el', sign * L_RAD, start, a_true, np.eye(3))
        assert arcsec(solvers.el_misalignment_rad(start, end, PHI)) == pytest.approx(beta_arcsec, abs=0.01)
        start = HIPO.center_px - sign * XEL_MOTION * L_PX / 2
        end = fly_gyro_maneuver('xel', sign * L_RAD, start, a_true, np.eye(3))
        assert arcsec(solvers.xel_misalignment_rad(start, end, PHI)) == pytest.approx(beta_arcsec, abs=0.01)


def test_printed_3_16_3_17_do_not_vanish_when_aligned():
    """Slip: as printed, 3.16 gives 2 phi - 90 deg for an aligned EL move and 3.17 gives -90 deg for XEL."""
    start = HIPO.center_px - EL_MOTION * L_PX / 2
    d_el = fly_gyro_maneuver('el', L_RAD, start, np.eye(3), np.eye(3)) - start
    printed_3_16 = np.degrees(np.arctan(d_el[0] / d_el[1])) - (90 - HIPO.rotation_deg)
    assert printed_3_16 == pytest.approx(2 * HIPO.rotation_deg - 90, abs=1e-6)
    start = HIPO.center_px - XEL_MOTION * L_PX / 2
    d_xel = fly_gyro_maneuver('xel', L_RAD, start, np.eye(3), np.eye(3)) - start
    printed_3_17 = np.degrees(np.arctan(d_xel[1] / d_xel[0])) - (90 - HIPO.rotation_deg)
    assert printed_3_17 == pytest.approx(-90.0, abs=1e-6)


@pytest.mark.parametrize('beta', [0.0, 0.02, -0.3])
def test_dcm_from_w_and_beta_eqs_3_18_3_19(beta):
    """Rows u, v, w: orthonormal, right-handed, w kept, v1 = tan(beta) v2, v . w = 0 (eqs. 3.18-3.19)."""
    w = np.array([0.003, -0.005, 1.0]) / np.linalg.norm([0.003, -0.005, 1.0])
    a = solvers.dcm_from_w_and_beta(w, beta)
    np.testing.assert_allclose(a @ a.T, np.eye(3), atol=1e-15)
    assert np.linalg.det(a) == pytest.approx(1.0, abs=1e-15)
    np.testing.assert_allclose(a[2], w, atol=0)
    assert a[1, 0] == pytest.approx(np.tan(beta) * a[1, 1], abs=1e-15)
    # For w = e_w the transpose is a turn of +beta about LOS (A ~= I - [theta x]).
    np.testing.assert_allclose(frames.rotation_angles_from_dcm(solvers.dcm_from_w_and_beta([0, 0, 1], beta).T),
                               [0, 0, beta], atol=1e-15)


def test_eq_6_1_is_a5_corrected_by_tables_6_2_and_6_4():
    """Eq. 6.1 = A5 corrected by the #5 turning point (635.1, 499.7) px and beta = 3.9' (Tables 6.2, 6.4)."""
    los_axis = frames.pixel_to_vector([635.1, 499.7], HIPO)  # Table 6.2, #5 "Both"
    beta = np.mean([3.8, 4.0]) * 60 * RAD_PER_ARCSEC  # Table 6.4, #5 U and V
    with pytest.warns(UserWarning, match='re-orthonormalized'):
        corrected = solvers.gyro_alignment_from_axes(los_axis, beta, A5)
    with pytest.warns(UserWarning, match='re-orthonormalized'):
        published = frames.rotation_angles_from_dcm(A_EQ_6_1)
    # Agreement to ~1" pins HIPO's mirror/phi (3.5-3.6), the rows convention and A_true = M A_est.
    np.testing.assert_allclose(arcsec(frames.rotation_angles_from_dcm(corrected)), arcsec(published), atol=2.0)


def test_closed_form_sequence_converges():
    """Table 3.4 steps 2-3 with the closed forms, iterated twice as in 2004, reach < 1" (noise-free)."""
    a_true = misalignment(1000.0, 730.0, 3600.0)
    a_est = np.eye(3)
    for _ in range(2):
        start = HIPO.center_px + [20.0, -10.0]
        end = fly_gyro_maneuver('los', np.radians(5.0), start, a_true, a_est)
        s_b, s_e = frames.pixel_to_vector(np.vstack([start, end]), HIPO)
        g1, g2 = solvers.candidate_rotation_axes(s_b, s_e, np.radians(5.0))
        el_start = HIPO.center_px - EL_MOTION * L_PX / 2
        el_end = fly_gyro_maneuver('el', L_RAD, el_start, a_true, a_est)
        beta = solvers.el_misalignment_rad(el_start, el_end, PHI)
        a_est = solvers.gyro_alignment_from_axes(solvers.select_rotation_axis(g1, g2, 'los'), beta, a_est)
    assert np.max(np.abs(arcsec(frames.rotation_angles_from_dcm(a_est @ a_true.T)))) < 1.0


# --- Least-squares fit ------------------------------------------------------------

def table_3_4_maneuvers(a_true, a_est_los, a_est_elxel, rng, noise_px=0.0):
    """Six LOS (+-5 deg) then six EL and six XEL (+-4.8') maneuvers on HIPO (Table 3.4, 6.1)."""
    noise = lambda: rng.normal(0.0, noise_px, 2)  # noqa: E731
    records = []
    for i in range(6):
        sign = (-1.0) ** i
        start = HIPO.center_px + rng.uniform(-30, 30, 2)
        end = fly_gyro_maneuver('los', sign * np.radians(5.0), start, a_true, a_est_los)
        records.append(Maneuver('los', sign * np.radians(5.0), start + noise(), end + noise(), a_est_los))
    for i in range(6):
        sign = (-1.0) ** i
        for axis, motion in (('el', EL_MOTION), ('xel', XEL_MOTION)):
            start = HIPO.center_px - sign * motion * L_PX / 2 + rng.uniform(-30, 30, 2)
            end = fly_gyro_maneuver(axis, sign * L_RAD, start, a_true, a_est_elxel)
            records.append(Maneuver(axis, sign * L_RAD, start + noise(), end + noise(), a_est_elxel))
    return records


def test_fit_recovers_gyro_alignment_noise_free():
    """With exact centroids the fit returns A_true to 1e-4" from maneuvers flown under two matrices."""
    rng = np.random.default_rng(41)
    a_true = misalignment(1046.0, 745.0, 3360.0)
    records = table_3_4_maneuvers(a_true, np.eye(3), misalignment(1000.0, 700.0, 0.0), rng)
    fit = fit_alignment(records, sigma_c_px=1.0)
    np.testing.assert_allclose(fit.dcm @ fit.dcm.T, np.eye(3), atol=1e-12)
    np.testing.assert_allclose(arcsec(fit.angles_rad), [1046.0, 745.0, 3360.0], atol=1e-4)
    assert fit.n_maneuvers == 18 and fit.residuals_px.shape == (18, 4)
    assert np.max(np.abs(fit.residuals_px)) < 1e-6


def test_fit_los_only_solves_tilt_and_refuses_los_angle():
    """LOS maneuvers see the LOS axis only: solve_for=('el', 'xel') works, the angle about LOS is refused."""
    rng = np.random.default_rng(42)
    a_true = misalignment(900.0, -500.0, 0.0)
    records = table_3_4_maneuvers(a_true, np.eye(3), np.eye(3), rng)[:6]
    fit = fit_alignment(records, solve_for=('el', 'xel'), sigma_c_px=1.0)
    np.testing.assert_allclose(arcsec(fit.angles_rad), [900.0, -500.0, 0.0], atol=1e-4)
    assert fit.sigma_rad[2] == 0.0 and fit.solved_axes == ('el', 'xel')
    with pytest.raises(InvalidArgumentError, match='not all observable'):
        fit_alignment(records, sigma_c_px=1.0)
    aligned = table_3_4_maneuvers(np.eye(3), np.eye(3), np.eye(3), rng)[:6]
    with pytest.raises(InvalidArgumentError, match='not all observable'):
        fit_alignment(aligned, solve_for=('los',), sigma_c_px=1.0)


def with_drift(records, drift_px_per_s, duration_s, block):
    """The same maneuvers with a residual linear drift added to the end centroids (6.1)."""
    return [Maneuver(r.axis, r.angle_rad, r.start_px, r.end_px + np.asarray(drift_px_per_s) * duration_s,
                     r.active_alignment, duration_s, block) for r in records]


def test_fit_removes_a_residual_drift_per_block():
    """6.1: a time-linear residual drift, fitted per block, is recovered and removed exactly."""
    rng = np.random.default_rng(44)
    a_true = misalignment(1046.0, 745.0, 3360.0)
    records = table_3_4_maneuvers(a_true, np.eye(3), np.eye(3), rng)
    drifted = with_drift(records[:6], (0.02, -0.03), 15.0, 0) + with_drift(records[6:], (-0.01, 0.015), 12.0, 1)
    fit = fit_alignment(drifted, sigma_c_px=1.0, fit_drift=True)
    np.testing.assert_allclose(arcsec(fit.angles_rad), [1046.0, 745.0, 3360.0], atol=1e-3)
    np.testing.assert_allclose(fit.drift_px_per_s, [[0.02, -0.03], [-0.01, 0.015]], atol=1e-8)


def test_drift_needs_both_signs_in_a_block():
    rng = np.random.default_rng(45)
    records = table_3_4_maneuvers(misalignment(100.0, 50.0, 0.0), np.eye(3), np.eye(3), rng)[:6:2]
    one_sign = with_drift(records, (0.0, 0.0), 10.0, 0)
    with pytest.raises(InvalidArgumentError, match='both signs'):
        fit_alignment(one_sign, solve_for=('el', 'xel'), sigma_c_px=1.0, fit_drift=True)


def test_maneuver_duration_must_not_be_negative():
    with pytest.raises(InvalidArgumentError, match='duration_s must be >= 0'):
        Maneuver('el', 0.001, (500.0, 500.0), (510.0, 500.0), duration_s=-1.0)


def test_fit_estimates_centroid_sigma_from_residuals():
    """Without sigma_c_px the covariance is scaled by the residual variance, which recovers sigma_c."""
    rng = np.random.default_rng(43)
    records = table_3_4_maneuvers(misalignment(600.0, 300.0, 2000.0), np.eye(3), np.eye(3), rng, noise_px=0.8)
    fit = fit_alignment(records)
    # 36 - 3 = 33 degrees of freedom: the estimate scatters by ~12 %.
    assert fit.sigma_c_px == pytest.approx(0.8, rel=0.35)


def test_fit_imager_rotation_of_field_and_boresight():
    """FPI with aligned gyros: the fit gives A_FPIRF,TARF; its LOS column is the boresight of step 1 (3.8-3.9)."""
    rng = np.random.default_rng(44)
    a_fpi = misalignment(25.0, -40.0, 1800.0)  # 47" boresight offset, 0.5 deg rotation of field
    records = []
    for i in range(4):
        sign = (-1.0) ** i
        for axis, angle in (('los', np.radians(5.0)), ('el', L_RAD), ('xel', L_RAD)):
            start = frames.FPI.center_px + rng.uniform(-100, 100, 2)
            end = fly_imager_maneuver(axis, sign * angle, start, a_fpi, frames.FPI)
            records.append(Maneuver(axis, sign * angle, start, end))
    fit = fit_alignment(records, frames.FPI, sigma_c_px=1.0)
    np.testing.assert_allclose(arcsec(fit.angles_rad), [25.0, -40.0, 1800.0], atol=1e-4)
    # Step 1: a star on TARF's origin is seen at the LOS column; 3.8-3.9 rebuild w from it.
    w_in_fpi = fit.dcm[:, 2]
    np.testing.assert_allclose(frames.boresight_dcm(w_in_fpi)[2], a_fpi[:, 2], atol=1e-12)


def test_maneuver_from_vectors_matches_pixels():
    """A maneuver given by TARF pointing vectors is the same record as by HIPO centroids."""
    s_b, s_e = frames.pixel_to_vector([[300.0, 400.0], [700.0, 650.0]], HIPO)
    record = Maneuver.from_vectors('xel', L_RAD, s_b, s_e)
    np.testing.assert_allclose(record.start_px, [300.0, 400.0], atol=1e-9)
    np.testing.assert_allclose(record.end_px, [700.0, 650.0], atol=1e-9)
    np.testing.assert_allclose(record.axis_vector, [0, 1, 0])
    with pytest.raises(ValueError, match='read-only'):
        record.start_px[0] = 1.0


# --- Error paths -------------------------------------------------------------------

def test_closed_form_errors():
    with pytest.raises(InvalidArgumentError, match='non-zero rotation angle'):
        solvers.los_misalignment_px([0, 0], [1, 1], 0.0)
    with pytest.raises(InvalidArgumentError, match='NaN'):
        solvers.los_misalignment_px([np.nan, 0], [1, 1], 0.1)
    with pytest.raises(InvalidArgumentError, match='shape 2'):
        solvers.los_misalignment_px([0, 0, 0], [1, 1], 0.1)
    with pytest.raises(InvalidArgumentError, match='parallel chords'):
        solvers.turning_point_two_stars_px([0, 0], [1, 1], [5, 0], [6, 1])
    with pytest.raises(InvalidArgumentError, match='parallel to X'):
        solvers.turning_point_two_stars_px([0, 0], [1, 0], [5, 0], [5, 1])
    with pytest.raises(InvalidArgumentError, match='too small'):
        solvers.candidate_rotation_axes([0, 0, 1], [0.01, 0, 1], 1e-4)
    with pytest.raises(InvalidArgumentError, match='parallel'):
        solvers.candidate_rotation_axes([0, 0, 1], [0, 0, 1], 0.1)
    with pytest.raises(InvalidArgumentError, match='non-zero rotation angle'):
        solvers.candidate_rotation_axes([0, 0, 1], [0.01, 0, 1], 0.0)
    with pytest.raises(InvalidArgumentError, match="'el', 'xel' or 'los'"):
        solvers.select_rotation_axis([1, 0, 0], [1, 0, 0], 'az')
    with pytest.raises(InvalidArgumentError, match='dX = 0'):
        solvers.el_misalignment_rad([5, 0], [5, 9], PHI)
    with pytest.raises(InvalidArgumentError, match='dY = 0'):
        solvers.xel_misalignment_rad([0, 5], [9, 5], PHI)
    with pytest.raises(InvalidArgumentError, match='w3 > 0'):
        solvers.dcm_from_w_and_beta([1, 0, 0], 0.1)
    with pytest.raises(InvalidArgumentError, match='less than 90 deg'):
        solvers.dcm_from_w_and_beta([0, 0, 1], np.pi / 2)
    with pytest.raises(NotOrthonormalError, match='not orthonormal'):
        solvers.gyro_alignment_from_axes([0, 0, 1], 0.0, np.eye(3) * 2)


def test_fit_errors():
    good = Maneuver('los', 0.1, [500.0, 500.0], [510.0, 505.0])
    with pytest.raises(InvalidArgumentError, match="'el', 'xel', 'los' or a 3-vector"):
        Maneuver('az', 0.1, [0, 0], [1, 1])
    with pytest.raises(InvalidArgumentError, match='non-zero rotation angle'):
        Maneuver('el', 0.0, [0, 0], [1, 1])
    with pytest.raises(InvalidArgumentError, match='NaN'):
        Maneuver('el', 0.1, [np.nan, 0], [1, 1])
    with pytest.raises(InvalidArgumentError, match='non-zero 3-vector'):
        Maneuver([0, 0, 0], 0.1, [0, 0], [1, 1])
    with pytest.raises(InvalidArgumentError, match='shape 2'):
        Maneuver('el', 0.1, [0, 0], [[1, 1]])
    with pytest.raises(NotOrthonormalError, match='not orthonormal'):
        Maneuver('el', 0.1, [0, 0], [1, 1], np.ones((3, 3)))
    with pytest.raises(InvalidArgumentError, match='non-empty sequence'):
        fit_alignment([])
    with pytest.raises(InvalidArgumentError, match='non-empty sequence'):
        fit_alignment([good, 'not a maneuver'])
    with pytest.raises(InvalidArgumentError, match='solve_for'):
        fit_alignment([good], solve_for=('el', 'el'))
    with pytest.raises(InvalidArgumentError, match='pass sigma_c_px'):
        fit_alignment([good], solve_for=('el', 'xel'))
    with pytest.raises(InvalidArgumentError, match='must be > 0'):
        fit_alignment([good], solve_for=('el', 'xel'), sigma_c_px=0.0)
