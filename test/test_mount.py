"""Mount geometry: frames chain, gravity load, Earth rate and drive limits."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sofia_ros import mount
from sofia_ros.earth_rate import earth_rate_tarf_rad_per_s
from sofia_ros.errors import CommandRefusedError, InvalidArgumentError
from sofia_ros.flexure import gravity_load_tarf


def test_altaz_round_trip():
    vector = mount.unit_vector_hrf(31.65, 0.84)
    alt, az = mount.altaz_from_unit_vector_hrf(vector)
    assert alt == pytest.approx(31.65, abs=1e-12) and az == pytest.approx(0.84, abs=1e-12)


def test_telescope_looks_out_of_the_left_side_at_the_cd_elevation():
    # Heading east: the left side faces north, so LOS points at azimuth 0 and altitude = CD elevation.
    tarf_from_hrf = mount.tarf_from_hrf_dcm(90.0, 31.7)
    alt, az = mount.altaz_from_unit_vector_hrf(tarf_from_hrf[2])
    assert alt == pytest.approx(31.7, abs=1e-9)
    assert az == pytest.approx(0.0, abs=1e-9) or az == pytest.approx(360.0, abs=1e-9)


@pytest.mark.parametrize('elevation_deg', [20.0, 40.1077, 60.0])
def test_gravity_in_tarf_is_the_load_case_of_eq_3_24(elevation_deg):
    gravity_hrf = np.array([0.0, 0.0, -9.80665])
    gravity_tarf = mount.tarf_from_hrf_dcm(324.0, elevation_deg) @ gravity_hrf
    np.testing.assert_allclose(gravity_tarf, gravity_load_tarf(elevation_deg), atol=1e-12)


@pytest.mark.parametrize('heading_deg', [0.0, 90.0, 324.0, 327.2])
def test_braked_telescope_senses_the_earth_rate_of_eqs_4_1_to_4_3(heading_deg):
    # Independent route: differentiate the frame chain with time instead of using 4.1-4.3.
    latitude_deg, elevation_deg, step_s = 34.9368, 40.1077, 1.0
    tarf_from_hrf = mount.tarf_from_hrf_dcm(heading_deg, elevation_deg)
    before = tarf_from_hrf @ mount.hrf_from_irf_dcm(latitude_deg, 0.0)
    after = tarf_from_hrf @ mount.hrf_from_irf_dcm(latitude_deg, step_s)
    delta = after @ before.T  # A_TARF(t+dt),TARF(t): TARF turned by w dt
    rate = Rotation.from_matrix(delta.T).as_rotvec() / step_s
    np.testing.assert_allclose(rate, earth_rate_tarf_rad_per_s(latitude_deg, heading_deg, elevation_deg),
                               rtol=1e-9, atol=1e-16)


def test_fine_drive_angles_round_trip_and_match_b_4():
    angles = np.radians([1.2, -0.7, 2.5])
    matrix = mount.tarf_from_icrf_dcm(angles)
    np.testing.assert_allclose(mount.fine_drive_angles_from_dcm(matrix), angles, atol=1e-14)
    a, b, c = angles
    r1 = np.array([[1, 0, 0], [0, np.cos(a), np.sin(a)], [0, -np.sin(a), np.cos(a)]])
    r2 = np.array([[np.cos(b), 0, -np.sin(b)], [0, 1, 0], [np.sin(b), 0, np.cos(b)]])
    r3 = np.array([[np.cos(c), np.sin(c), 0], [-np.sin(c), np.cos(c), 0], [0, 0, 1]])
    np.testing.assert_allclose(matrix, r3 @ r2 @ r1, atol=1e-15)  # eq. B.4


def test_fine_drive_beyond_three_degrees_is_refused():
    with pytest.raises(CommandRefusedError, match=r'fine drive LOS would reach \+3.100 deg'):
        mount.check_fine_drive_angles(np.radians([0.0, 0.0, 3.1]))
    mount.check_fine_drive_angles(np.radians([2.9, -2.9, 3.0]))


def test_coarse_drive_outside_its_range_is_refused():
    with pytest.raises(CommandRefusedError, match='outside 16.5-68.5 deg'):
        mount.check_coarse_drive_elevation(70.0)
    with pytest.raises(CommandRefusedError, match='outside 16.5-68.5 deg'):
        mount.check_coarse_drive_elevation(16.0)
    mount.check_coarse_drive_elevation(16.5)


def test_fine_drive_angles_need_three_components():
    with pytest.raises(InvalidArgumentError, match='fine_drive_rad must have shape 3'):
        mount.tarf_from_icrf_dcm([0.0, 0.0])
