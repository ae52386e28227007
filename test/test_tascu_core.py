"""TASCU core: refuses commands beyond the drives, accepts and finishes those within (2.3, 6.3)."""

import numpy as np
import pytest

from sofia_ros.errors import ConfigError
from sofia_ros.frames import dcm_from_rotation_angles
from sofia_ros.sim import messages as m
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
