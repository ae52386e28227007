"""Camera cores: the FPI, FFI and WFI trackers and HIPO, frames on a fixed schedule (2.4.3, 3.2, 6.1-6.3).

Each exposure is rendered at its midpoint with the telescope attitude interpolated
between the plant's tick attitudes; the centroids of every star on the chip are
published as one PoseArray (x = column, y = row in px, z = HIP number). The temperature at the
midpoint is the plant's (scenario.ThermalHistory, fed the same thermal commands).
"""

from __future__ import annotations

from sofia_ros import messages as m
from sofia_ros.errors import ConfigError
from sofia_ros.frames import dcm_from_quaternion
from sofia_ros.rotation_kernels import slerp_quaternion
from sofia_ros.scenario import ThermalHistory
from sofia_ros.sensors.imager_model import CAMERAS, ImagerTruth, Scene
from sofia_ros.sim.plant import TOPICS as PLANT_TOPICS
from sofia_ros.sim.plant import thermal_command_of
from sofia_ros.sim.protocol import NodeCore
from sofia_ros.topics import CD_JOINT, FD_JOINTS, centroid_topic
from sofia_ros.units import DEG_PER_RAD

__all__ = ['CameraCore', 'DEFAULT_TIMING_S']

#: (frame period, exposure) in s: HIPO 0.5 s exposures on Polaris (6.1), imagers 2 s (6.2).
DEFAULT_TIMING_S = {'hipo': (1.0, 0.5), 'fpi': (2.0, 2.0), 'ffi': (2.0, 2.0), 'wfi': (2.0, 2.0)}


class CameraCore(NodeCore):
    """Truth to centroids for one camera."""

    #: the plant's tick first; the calibration node's thermal commands of a tick before the next one
    upstream = (('plant', 0), ('calibration', 1))

    def __init__(self, camera, scenario, truth_effects, *, seed=0, frame_period_s=None, exposure_s=None):
        super().__init__()
        if camera not in CAMERAS:
            raise ConfigError(f'camera must be one of {", ".join(CAMERAS)}, got {camera!r}')
        self.name = camera
        period_s, default_exposure_s = DEFAULT_TIMING_S[camera]
        self.frame_period_ns = m.seconds_to_ns(frame_period_s or period_s)
        self.exposure_ns = m.seconds_to_ns(exposure_s or default_exposure_s)
        self.truth = ImagerTruth(camera, truth_effects, Scene(scenario.site, scenario.start_utc),
                                 exposure_s=self.exposure_ns / m.NS_PER_S, seed=seed)
        self.topic = centroid_topic(camera)
        self.thermal = ThermalHistory(scenario)
        self.previous = None  # (stamp_ns, truth Imu, truth JointState) of the last tick
        self.pending = {}

    def inputs(self):
        return (PLANT_TOPICS['truth_imu'], PLANT_TOPICS['truth_joints'], PLANT_TOPICS['thermal_command'])

    def outputs(self):
        return (self.topic,)

    def receive(self, topic, message):
        if topic == PLANT_TOPICS['thermal_command'].name:
            self.thermal.command(*thermal_command_of(message))
            return
        self.pending[topic] = message

    def tick(self, stamp_ns):
        imu = self.pending.pop(PLANT_TOPICS['truth_imu'].name, None)
        joints = self.pending.pop(PLANT_TOPICS['truth_joints'].name, None)
        if imu is None or joints is None:
            return []
        previous, self.previous = self.previous, (stamp_ns, imu, joints)
        if previous is None:
            return []
        midpoints_ns = self._midpoints_ns(previous[0], stamp_ns)
        if not midpoints_ns:
            return []  # most ticks: the truth is read only around an exposure's midpoint
        previous, current = _truth_state(*previous), _truth_state(stamp_ns, imu, joints)
        outputs = []
        for midpoint_ns in midpoints_ns:
            fraction = (midpoint_ns - previous[0]) / (stamp_ns - previous[0])
            quaternion = slerp_quaternion(previous[1], current[1], fraction)
            elevation_deg, force, los_deg = (previous[i] + fraction * (current[i] - previous[i]) for i in (2, 3, 4))
            opening_s = (midpoint_ns - self.exposure_ns // 2) / m.NS_PER_S
            centroids = self.truth.centroids(opening_s, dcm_from_quaternion(quaternion), elevation_deg,
                                             temperature_c=self.thermal.temperature_c_at(midpoint_ns / m.NS_PER_S),
                                             specific_force_tarf_m_per_s2=force, los_angle_deg=los_deg)
            stamp = centroids[0].stamp_s if centroids else midpoint_ns / m.NS_PER_S
            if stamp < 0.0:
                # A clock behind the TASCU's (timestamp_offset < 0) stamps the first frames before the campaign's
                # start, where the bag's time begins: they are not sent (a run with -0.4 s stopped on them).
                continue
            outputs.append((self.topic.name, m.centroid_array(m.seconds_to_ns(stamp), self.name, centroids)))
        return outputs

    def _midpoints_ns(self, after_ns, until_ns):
        """Exposure midpoints in (after_ns, until_ns]: exposures start at multiples of the frame period."""
        half_ns = self.exposure_ns // 2
        first = -(-(after_ns + 1 - half_ns) // self.frame_period_ns)
        last = (until_ns - half_ns) // self.frame_period_ns
        return [index * self.frame_period_ns + half_ns for index in range(max(first, 0), last + 1)]


def _truth_state(stamp_ns, imu, joints):
    """(stamp_ns, attitude quaternion xyzw, elevation deg, specific force, LOS deg) of a tick's truth messages."""
    positions = m.joint_positions_of(joints)
    return (stamp_ns, m.quaternion_xyzw_of(imu.orientation), positions[CD_JOINT] * DEG_PER_RAD,
            m.vector_of(imu.linear_acceleration), positions[FD_JOINTS[2]] * DEG_PER_RAD)
