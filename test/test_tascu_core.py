"""TASCU core: refuses commands beyond the drives, accepts and finishes those within (2.3, 6.3)."""

import numpy as np
import pytest

from sofia_ros import messages as m
from sofia_ros.errors import ConfigError
from sofia_ros.frames import dcm_from_rotation_angles
from sofia_ros.sim.tascu import TOPICS, TascuCore
from sofia_ros.units import RAD_PER_DEG


def _tascu_at(fd_angles_deg, cd_elevation_deg=32.0):
    tascu = TascuCore()
    positions = {'cd_elevation': cd_elevation_deg * RAD_PER_DEG,
                 **dict(zip(('fd_el', 'fd_xel', 'fd_los'), np.radians(fd_angles_deg)))}
    tascu.receive('/ta/joint_states', m.joint_state(0, positions))
    tascu.tick(100_000_000)
    return tascu


def _statuses(outputs):
    return [message.message for topic, message in outputs if topic == TOPICS['command_status'].name]


def test_move_beyond_the_fine_drive_travel_is_refused_with_the_reason():
    tascu = _tascu_at([0.0, 0.0, 2.0])
    tascu.receive(TOPICS['move_relative'].name, m.vector3_stamped(150_000_000, 'tarf', [0.0, 0.0, 1.5 * RAD_PER_DEG]))
    statuses = _statuses(tascu.tick(200_000_000))
    assert statuses == ['refused: fine drive LOS would reach +3.500 deg, beyond the +-3 deg travel; '
                        'command a smaller move or re-centre the fine drive first']


def test_move_within_the_travel_is_accepted_then_done():
    tascu = _tascu_at([0.0, 0.0, 0.0])
    # 1 deg at the 0.5 deg/s slew rate: accepted now, done after 2 s of sim time.
    tascu.receive(TOPICS['move_relative'].name, m.vector3_stamped(150_000_000, 'tarf', [0.0, 0.0, 1.0 * RAD_PER_DEG]))
    assert _statuses(tascu.tick(200_000_000)) == ['accepted']
    done_at = [k for k in range(3, 40) if _statuses(tascu.tick(k * 100_000_000)) == ['done']]
    assert done_at == [21]


def test_inertial_move_needing_the_coarse_drive_outside_its_range_is_refused():
    tascu = _tascu_at([0.0, 0.0, 0.0], cd_elevation_deg=60.0)
    target = dcm_from_rotation_angles(np.array([15.0 * RAD_PER_DEG, 0.0, 0.0])) @ tascu.commanded_from_inertial
    from sofia_ros.frames import quaternion_from_dcm

    tascu.receive(TOPICS['mtbs_inertial'].name, m.quaternion_stamped(150_000_000, 'irf', quaternion_from_dcm(target)))
    statuses = _statuses(tascu.tick(200_000_000))
    assert len(statuses) == 1 and statuses[0].startswith('refused: coarse drive elevation 75.000 deg is outside')


def test_unknown_or_bad_parameters_are_refused():
    tascu = TascuCore()
    with pytest.raises(ConfigError, match="tascu has no parameter 'alignment.gyro'"):
        tascu.set_parameter('alignment.gyro', [1.0] * 9)
    with pytest.raises(ConfigError, match='is not orthonormal'):
        tascu.set_parameter('alignment.tarf_from_gyrf', [2.0] + [0.0] * 8)
    with pytest.raises(ConfigError, match='outside 16.5-68.5 deg'):
        tascu.set_parameter('fbc.reference_elevation_deg', 80.0)


def test_quasi_static_fbc_turns_the_estimate_by_the_focal_plane_flexure_referenced_to_el0():
    # 3.4.1-3.4.2: the FBC modifies TARF:GYRF by the Table 3.2 image motion of the load change
    # since el0, so the servo moves the telescope and the image stays on the focal plane.
    from sofia_ros.flexure import gravity_load_tarf, referenced_focal_plane_rotation_arcsec
    from sofia_ros.units import RAD_PER_ARCSEC

    tascu = TascuCore()
    tascu.set_parameter('fbc.enabled', True)
    tascu.set_parameter('fbc.reference_elevation_deg', 30.0)
    force = -gravity_load_tarf(60.0)  # accelerometers at rest read f = -g (eq. 2.13)
    block = m.ImuBlock('gyrf', np.arange(1, 81, dtype=np.int64) * 2_500_000, np.zeros((80, 3)),
                       np.tile(force, (80, 1)))
    tascu.receive('/gyro_box/imu', block)
    tascu.tick(200_000_000)
    expected_arcsec = referenced_focal_plane_rotation_arcsec(gravity_load_tarf(60.0), gravity_load_tarf(30.0))
    expected = dcm_from_rotation_angles(np.r_[expected_arcsec, 0.0] * RAD_PER_ARCSEC)
    np.testing.assert_allclose(tascu._estimate(), expected, atol=1e-12)
    assert abs(expected_arcsec[1]) > 20.0  # about 25" in XEL between 30 and 60 deg
    tascu.set_parameter('fbc.enabled', False)
    np.testing.assert_allclose(tascu._estimate(), np.eye(3), atol=1e-15)


def _point(frame_id, x, y, z):
    from geometry_msgs.msg import PointStamped

    message = PointStamped()
    message.header.stamp.nanosec = 150_000_000
    message.header.frame_id = frame_id
    message.point.x, message.point.y, message.point.z = x, y, z
    return message


@pytest.mark.parametrize('topic, message, reason', [
    # Each killed the TASCU, and with it the run (a publisher outside the graph under --all-dds or --processes).
    ('move_relative', m.vector3_stamped(150_000_000, 'tarf', [float('nan'), 0.0, 0.0]), 'not a finite number'),
    ('move_relative', m.vector3_stamped(150_000_000, 'tarf', [0.0, float('inf'), 0.0]), 'not a finite number'),
    ('mtbs_centroid', _point('hipo', float('nan'), 10.0, 0.0), 'not a finite number'),
    ('mtbs_inertial', m.quaternion_stamped(150_000_000, 'irf', (0.0, 0.0, 0.0, 0.0)), 'unit norm'),
    ('track', _point('hipo', 10.0, 10.0, float('nan')), 'not a finite number'),
])
def test_a_malformed_command_is_refused_not_fatal(topic, message, reason):
    tascu = _tascu_at([0.0, 0.0, 0.0])
    tascu.receive(TOPICS[topic].name, message)
    [status] = _statuses(tascu.tick(200_000_000))
    assert status.startswith('refused: ') and reason in status


def test_a_boresight_that_is_not_two_finite_pixels_is_refused():
    # Accepted, [NaN, NaN] killed the TASCU at the next centring on that camera.
    with pytest.raises(ConfigError, match='two finite pixel coordinates'):
        TascuCore().set_parameter('boresight.hipo_px', [float('nan'), float('nan')])


def test_the_plant_refuses_a_coarse_drive_command_beyond_its_range():
    # 80 deg was slewed to; the node shell drops what a core refuses, with one warning.
    from sofia_ros.campaigns.alignment import default_scenario
    from sofia_ros.errors import SofiaError
    from sofia_ros.sim.plant import TOPICS as PLANT_TOPICS, PlantCore

    plant = PlantCore(default_scenario(), {})
    before = plant.cd_target_deg
    for elevation_deg in (80.0, float('nan')):
        with pytest.raises(SofiaError, match='outside 16.5-68.5 deg|NaN'):
            plant.receive(PLANT_TOPICS['cd_command'].name,
                          m.joint_state(0, {'cd_elevation': elevation_deg * RAD_PER_DEG}))
    assert plant.cd_target_deg == before
