"""Angular distances (4.36-4.38), short-move corrections (6.7-6.8) and refraction (6.2)."""

import numpy as np
import pytest

from sofia_ros.errors import InvalidArgumentError
from scipy.spatial.transform import Rotation

from sofia_ros.frames import FPI, dcm_from_euler123, pixel_to_vector
from sofia_ros.sky.distances import (
    FPI_SCALE_ARCSEC_PER_PX,
    angular_distance_arcsec,
    attitude_change_euler_arcsec,
    angular_distance_cosine_rule_arcsec,
    refraction_adjusted_distance_arcsec,
    short_move_euler_arcsec,
    spherical_sum_arcsec,
)
from sofia_ros.units import ARCSEC_PER_RAD, RAD_PER_ARCSEC, RAD_PER_DEG

# Table D.6: short moves, gyro Euler angles EL, XEL corrected for the centroid displacement
# and their "Spherical Sum EL and XEL" [arcsec].
TABLE_D_6 = {
    '2-3': (101150.7, -4334.8, 101236.0),
    '3-4': (-100679.4, 11139.4, 101244.3),
    '6-7': (28825.7, -2471.9, 28930.8),
    '8-9': (69194.4, -4919.8, 69362.5),
    '10-11': (100920.2, -7118.1, 101150.6),
    '11-12': (-68879.3, 8362.6, 69366.2),
    '13-14': (68528.7, -10932.5, 69363.4),
    '15-16': (31984.7, -1948.7, 32043.5),
    '16-17': (90226.7, -4217.9, 90318.8),
}


@pytest.mark.parametrize('move', list(TABLE_D_6))
def test_table_d_6_spherical_sum(move):
    # Eq. 4.38 reproduces every listed distance within 0.072" (measured; table rounds to 0.1").
    el_arcsec, xel_arcsec, distance_arcsec = TABLE_D_6[move]
    assert spherical_sum_arcsec(el_arcsec, xel_arcsec) == pytest.approx(distance_arcsec, abs=0.1)


def test_spherical_sum_is_eq_4_38_as_printed():
    rng = np.random.default_rng(7)
    el_arcsec, xel_arcsec = rng.uniform(-150000.0, 150000.0, (2, 200))
    printed = np.arccos(np.cos(el_arcsec * RAD_PER_ARCSEC) * np.cos(xel_arcsec * RAD_PER_ARCSEC))
    np.testing.assert_allclose(spherical_sum_arcsec(el_arcsec, xel_arcsec),
                               printed * ARCSEC_PER_RAD, atol=1e-4)


def test_spherical_sum_stays_accurate_for_small_angles():
    # arccos(cos EL cos XEL) loses all digits below ~0.01"; the haversine form keeps them.
    assert spherical_sum_arcsec(3e-4, 4e-4) == pytest.approx(5e-4, rel=1e-9)


def test_vector_form_equals_eq_4_37_and_eq_4_36():
    rng = np.random.default_rng(3)
    alt1, alt2 = rng.uniform(-10.0, 90.0, (2, 500))
    az1, az2 = rng.uniform(0.0, 360.0, (2, 500))
    vector = angular_distance_arcsec(alt1, az1, alt2, az2)
    # 4.37 as printed, and 4.36 written with 90 deg - Alt (zenith distances).
    z1, z2 = (90.0 - alt1) * RAD_PER_DEG, (90.0 - alt2) * RAD_PER_DEG
    eq_4_36 = np.arccos(np.clip(np.cos((az1 - az2) * RAD_PER_DEG) * np.sin(z1) * np.sin(z2)
                                + np.cos(z1) * np.cos(z2), -1, 1)) * ARCSEC_PER_RAD
    separated = vector > 3600.0  # the cosine rule is only well conditioned away from 0
    np.testing.assert_allclose(vector[separated],
                               angular_distance_cosine_rule_arcsec(alt1, az1, alt2, az2)[separated],
                               atol=1e-5)
    np.testing.assert_allclose(vector[separated], eq_4_36[separated], atol=1e-5)


def test_vector_form_is_robust_for_close_stars():
    # Two stars 0.01" apart in altitude: exact answer 0.01".
    assert angular_distance_arcsec(45.0, 10.0, 45.0 + 0.01 / 3600.0, 10.0) == pytest.approx(0.01, rel=1e-6)
    # Same for a pure azimuth step at altitude 60 deg: 0.02" of azimuth is 0.01" on the sky.
    assert angular_distance_arcsec(60.0, 0.0, 60.0, 0.02 / 3600.0) == pytest.approx(0.01, rel=1e-6)


def test_distance_is_symmetric_and_wraps_azimuth():
    assert angular_distance_arcsec(31.65, 0.84, 59.77, 0.06) == pytest.approx(
        angular_distance_arcsec(59.77, 360.06, 31.65, 0.84), abs=1e-7)


def test_refraction_adjusted_distance_applies_eq_6_2():
    # Two stars on one vertical circle: refraction lifts both, so the distance shrinks by R2 - R1.
    adjusted = refraction_adjusted_distance_arcsec(60.0, 0.0, 30.0, 30.0, 0.0, 90.0)
    assert adjusted == pytest.approx(30.0 * 3600.0 - 60.0, abs=1e-7)
    # Table D.3 #1 values give the sign and size of the effect: 101252.8" -> 101196.3".
    change = (refraction_adjusted_distance_arcsec(59.77, 0.06, 31.8, 31.65, 0.84, 88.3)
              - angular_distance_arcsec(59.77, 0.06, 31.65, 0.84))
    assert change == pytest.approx(101196.3 - 101252.8, abs=0.2)


def test_short_move_correction_eq_6_7_6_8():
    # Table D.5, move 2-3: star at (510.20, 546.20) px before and (437.20, 588.40) px after.
    el_arcsec, xel_arcsec = short_move_euler_arcsec(100000.0, -4000.0, (510.20, 546.20),
                                                    (437.20, 588.40))
    assert FPI_SCALE_ARCSEC_PER_PX == 0.55
    assert el_arcsec == pytest.approx(100000.0 + 0.55 * (546.20 - 588.40), abs=1e-9)  # 6.7
    assert xel_arcsec == pytest.approx(-4000.0 + 0.55 * (437.20 - 510.20), abs=1e-9)  # 6.8


@pytest.mark.parametrize('move', list(TABLE_D_6))
def test_attitude_change_gives_el_xel_los_with_los_last(move):
    # Two attitudes a Table D.6 move apart (LOS 1000"): B.24 then B.11-B.13 give the angles back,
    # and eq. 4.38 the listed distance whatever the LOS.
    el_arcsec, xel_arcsec, distance_arcsec = TABLE_D_6[move]
    first = Rotation.from_rotvec([0.4, -1.0, 0.3]).as_matrix()
    second = dcm_from_euler123(np.array([el_arcsec, xel_arcsec, 1000.0]) * RAD_PER_ARCSEC) @ first
    angles = attitude_change_euler_arcsec(first, second)
    assert angles == pytest.approx([el_arcsec, xel_arcsec, 1000.0], abs=1e-6)
    assert spherical_sum_arcsec(*angles[:2]) == pytest.approx(distance_arcsec, abs=0.1)


def test_short_move_correction_is_first_order_and_star_two_must_sit_at_the_boresight():
    # The reduced star hop's Beta Cep -> Alpha Cep short move: EL 28640", XEL -4013", LOS 2490".
    angles_arcsec = np.array([28640.2, -4012.6, 2490.0])
    change = dcm_from_euler123(angles_arcsec * RAD_PER_ARCSEC)
    centre = FPI.center_px

    def error_arcsec(before_px, after_px, swapped=False):
        first = pixel_to_vector(before_px, FPI)
        second = change.T @ pixel_to_vector(after_px, FPI)
        exact = np.arctan2(np.linalg.norm(np.cross(first, second)), first @ second) * ARCSEC_PER_RAD
        pixels = (after_px, before_px) if swapped else (before_px, after_px)
        return float(spherical_sum_arcsec(*short_move_euler_arcsec(*angles_arcsec[:2], *pixels))) - exact

    offset = np.array([-378.0, 0.0])  # 208" along the column, as the first star stood after the park
    # Star 1 off the boresight: eqs. 6.7-6.8 leave 0.28" (of order offset x XEL x (1 - cos EL));
    # the correction with the opposite sign would leave 29".
    assert error_arcsec(centre + offset, centre) == pytest.approx(0.28, abs=0.01)
    assert abs(error_arcsec(centre + offset, centre, swapped=True)) > 25.0
    # Star 2 off the boresight: its offset turns with the LOS angle (2490" x 208" = 2.5").
    assert abs(error_arcsec(centre, centre + offset)) > 2.4


def test_bad_input_raises():
    with pytest.raises(InvalidArgumentError, match='altitude2_deg contains NaN'):
        angular_distance_arcsec(30.0, 0.0, float('nan'), 0.0)
    with pytest.raises(InvalidArgumentError, match='xel_arcsec contains NaN'):
        spherical_sum_arcsec(1.0, float('nan'))
    with pytest.raises(InvalidArgumentError, match='pixel_after_px must have shape 2'):
        short_move_euler_arcsec(0.0, 0.0, (1.0, 2.0), (1.0, 2.0, 3.0))
    with pytest.raises(InvalidArgumentError, match='scale_arcsec_per_px must be > 0'):
        short_move_euler_arcsec(0.0, 0.0, (1.0, 2.0), (1.0, 2.0), scale_arcsec_per_px=0.0)


def test_attitude_change_euler_of_a_stack_is_row_by_row():
    """attitude_change_euler_arcsec on (N, 3, 3) stacks gives each pair's angles (4.3.3), to 1e-9"."""
    from scipy.spatial.transform import Rotation

    from sofia_ros.sky.distances import attitude_change_euler_arcsec as change

    first = Rotation.random(5, random_state=1).as_matrix()
    second = Rotation.random(5, random_state=2).as_matrix()
    stacked = change(first, second)
    for index in range(5):
        np.testing.assert_allclose(stacked[index], change(first[index], second[index]), atol=1e-9)
