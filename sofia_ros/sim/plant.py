"""Truth plant core: the telescope's true attitude, coarse and fine drives, temperature (2.3, C.1).

The fine drive is torque controlled on the gyro loop: over each tick the telescope's
inertial body rate is the TASCU's fine-drive command of the previous tick, until a
fine-drive angle reaches its +-3 deg end stop. With the FD braked (gyro stability
tests, 5.2) the telescope is fixed to the Earth and senses eqs. 4.1-4.3. The coarse
drive slews the elevation axis at a fixed rate towards its commanded elevation. The temperature
is the scenario's drift, or where the truth has a thermal control, the lag behind the setpoint a
plan's temperature element commands (scenario.ThermalHistory).
"""

from __future__ import annotations

import numpy as np

from sofia_ros import messages as m
from sofia_ros import mount, topics
from sofia_ros.control.attitude import mean_rate_rad_per_s, propagate_dcm
from sofia_ros.frames import quaternion_from_dcm
from sofia_ros.scenario import ThermalHistory
from sofia_ros.sim.protocol import NodeCore
from sofia_ros.topics import CD_JOINT, DEFAULT_TICK_NS, FD_JOINTS
from sofia_ros.units import RAD_PER_DEG, STANDARD_GRAVITY_M_PER_S2
from sofia_ros.validate import finite_array

__all__ = ['PlantCore', 'TOPICS', 'thermal_command_of']

#: the topics this core reads and writes, by the short names its methods use (defined in sofia_ros.topics)
TOPICS = {
    'clock': topics.CLOCK, 'fd_command': topics.FD_COMMAND, 'cd_command': topics.CD_COMMAND,
    'truth_imu': topics.TRUTH_IMU, 'truth_joints': topics.TRUTH_JOINTS,
    'truth_temperature': topics.TRUTH_TEMPERATURE, 'joint_states': topics.JOINT_STATES,
    'thermal_command': topics.THERMAL_COMMAND,
}

#: Gravity in HRF (Z zenith).
_GRAVITY_HRF_M_PER_S2 = np.array([0.0, 0.0, -STANDARD_GRAVITY_M_PER_S2])


def thermal_command_of(message):
    """(start s, target deg C, rate deg C/h) of a topics.THERMAL_COMMAND message."""
    return (m.stamp_ns_of(message.header.stamp) / m.NS_PER_S, float(message.vector.x),
            float(message.vector.y) * 3600.0)


class PlantCore(NodeCore):
    """The true telescope on the ground."""

    name = 'plant'
    #: the calibration node's thermal commands of a tick arrive before the next one (ThermalHistory)
    upstream = (('clock', 0), ('tascu', 1), ('calibration', 1))

    def __init__(self, scenario, truth_effects, *, fd_braked=False, tick_ns=DEFAULT_TICK_NS,
                 cd_slew_rate_deg_per_s=0.5):
        super().__init__()
        self.scenario = scenario
        self.thermal = ThermalHistory(scenario)
        heading_error = truth_effects.get('heading_error', {}).get('heading_error_deg', 0.0)
        self.heading_deg = scenario.heading_deg + heading_error
        earth = truth_effects.get('earth_rotation')
        self.earth_rate_rad_per_s = earth['rate_deg_per_h'] * RAD_PER_DEG / 3600.0 if earth else 0.0
        self.fd_braked = fd_braked
        self.tick_s = tick_ns / m.NS_PER_S
        self.cd_slew_rate_deg_per_s = cd_slew_rate_deg_per_s
        self.elevation_deg = scenario.start_elevation_deg
        self.cd_target_deg = self.elevation_deg
        self.fine_drive_rad = np.zeros(3)
        self.rate_command_rad_per_s = np.zeros(3)
        self.last_stamp_ns = 0
        self.tarf_from_irf = mount.tarf_from_hrf_dcm(self.heading_deg, self.elevation_deg)
        # Computed once each: the heading never changes, the elevation only while the coarse drive slews, and a
        # tick needs the Earth's turn at its time twice (the telescope's move and the specific force).
        self._abrf_from_hrf = mount.abrf_from_hrf_dcm(self.heading_deg)
        self._cradle_from_hrf_at = (None, None)  # (elevation deg, A_ICRF,HRF)
        self._hrf_from_irf_at = (None, None)  # (elapsed s, A_HRF,IRF)

    def inputs(self):
        return (TOPICS['clock'], TOPICS['fd_command'], TOPICS['cd_command'], TOPICS['thermal_command'])

    def outputs(self):
        return tuple(TOPICS[key] for key in ('truth_imu', 'truth_joints', 'truth_temperature', 'joint_states'))

    def receive(self, topic, message):
        if topic == TOPICS['fd_command'].name:
            self.rate_command_rad_per_s = finite_array('fine drive rate command', m.vector_of(message), (3,))
        elif topic == TOPICS['cd_command'].name:
            target_deg = m.joint_positions_of(message)[CD_JOINT] / RAD_PER_DEG
            # The drive's own limits: a command beyond 16.5-68.5 deg (or NaN) is refused, not slewed to.
            mount.check_coarse_drive_elevation(target_deg)
            self.cd_target_deg = target_deg
        elif topic == TOPICS['thermal_command'].name:
            self.thermal.command(*thermal_command_of(message))

    def _hrf_from_irf(self, elapsed_s):
        if self._hrf_from_irf_at[0] != elapsed_s:
            self._hrf_from_irf_at = (elapsed_s, mount.hrf_from_irf_dcm(self.scenario.latitude_deg, elapsed_s,
                                                                       self.earth_rate_rad_per_s))
        return self._hrf_from_irf_at[1]

    def _cradle_from_hrf(self):
        if self._cradle_from_hrf_at[0] != self.elevation_deg:
            self._cradle_from_hrf_at = (self.elevation_deg,
                                        mount.icrf_from_abrf_dcm(self.elevation_deg) @ self._abrf_from_hrf)
        return self._cradle_from_hrf_at[1]

    def tick(self, stamp_ns):
        interval_s = (stamp_ns - self.last_stamp_ns) / m.NS_PER_S
        elapsed_s = stamp_ns / m.NS_PER_S
        before = self.tarf_from_irf
        if interval_s > 0.0:
            self._move_coarse_drive(interval_s)
            self._move_telescope(interval_s, elapsed_s)
        rate = mean_rate_rad_per_s(before, self.tarf_from_irf, interval_s) if interval_s > 0 else np.zeros(3)
        self.last_stamp_ns = stamp_ns
        return self._messages(stamp_ns, elapsed_s, rate)

    def _move_coarse_drive(self, interval_s):
        largest_step_deg = self.cd_slew_rate_deg_per_s * interval_s
        # np.clip's result without its dispatch: the difference first, so that a NaN stays NaN as there.
        self.elevation_deg += min(max(self.cd_target_deg - self.elevation_deg, -largest_step_deg), largest_step_deg)

    def _move_telescope(self, interval_s, elapsed_s):
        cradle_from_irf = self._cradle_from_hrf() @ self._hrf_from_irf(elapsed_s)
        if self.fd_braked:
            self.tarf_from_irf = mount.tarf_from_icrf_dcm(self.fine_drive_rad) @ cradle_from_irf
            return
        moved = propagate_dcm(self.tarf_from_irf, self.rate_command_rad_per_s, interval_s)
        angles = mount.fine_drive_angles_from_dcm(moved @ cradle_from_irf.T)
        limit = mount.FINE_DRIVE_LIMIT_DEG * RAD_PER_DEG
        if any(abs(angle) > limit for angle in angles.tolist()):
            # End stop: the fine drive cannot turn further; the telescope rides with the cradle there.
            angles = np.clip(angles, -limit, limit)
            moved = mount.tarf_from_icrf_dcm(angles) @ cradle_from_irf
        self.fine_drive_rad = angles
        self.tarf_from_irf = moved

    def specific_force_tarf_m_per_s2(self, elapsed_s):
        """Accelerometer specific force at rest, f = -g (eq. 2.13), in TARF."""
        return -(self.tarf_from_irf @ self._hrf_from_irf(elapsed_s).T @ _GRAVITY_HRF_M_PER_S2)

    def _messages(self, stamp_ns, elapsed_s, rate_rad_per_s):
        imu = m.Imu()
        imu.header.stamp = m.time_msg(stamp_ns)
        imu.header.frame_id = 'tarf'
        q = quaternion_from_dcm(self.tarf_from_irf)
        imu.orientation.x, imu.orientation.y, imu.orientation.z, imu.orientation.w = (float(v) for v in q)
        w, a = imu.angular_velocity, imu.linear_acceleration
        w.x, w.y, w.z = (float(v) for v in rate_rad_per_s)
        a.x, a.y, a.z = (float(v) for v in self.specific_force_tarf_m_per_s2(elapsed_s))
        positions = {CD_JOINT: self.elevation_deg * RAD_PER_DEG, **dict(zip(FD_JOINTS, self.fine_drive_rad))}
        # The encoders read the true angles: one message for both topics (its receivers only read it).
        joints = m.joint_state(stamp_ns, positions)
        temperature_c = self.thermal.temperature_c_at(elapsed_s)
        return [
            (TOPICS['truth_imu'].name, imu),
            (TOPICS['truth_joints'].name, joints),
            (TOPICS['truth_temperature'].name, m.temperature_msg(stamp_ns, 'tarf', temperature_c)),
            (TOPICS['joint_states'].name, joints),
        ]
