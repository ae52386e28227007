"""TASCU core: the software under study (2.3, 3.4, 6.1-6.3).

Every tick it maps the gyro samples through A_TARF,GYRF (eq. 3.20), removes its drift
estimate, propagates TARF against IRF, applies the quasi-static flexible body
compensation referenced to el0 (3.4.2), runs the commanded moves and the servo, and
reports motion status. Alignment matrices and the FBC settings are parameters, set by
the calibration node. Commands beyond the drives' limits are refused with a reason.
"""

from __future__ import annotations

import numpy as np
from diagnostic_msgs.msg import DiagnosticStatus

from sofia_ros import graph_nodes, mount, topics
from sofia_ros import messages as m
from sofia_ros.control import servo, tracker
from sofia_ros.control.attitude import propagate_dcm, rotation_error_rad
from sofia_ros.errors import CommandRefusedError, ConfigError, InvalidArgumentError, SofiaError
from sofia_ros.flexure import focal_plane_telescope_rotation_arcsec, gravity_load_tarf
from sofia_ros.frames import dcm_from_quaternion, dcm_from_rotation_angles, quaternion_from_dcm
from sofia_ros.sensors.imager_model import CAMERAS
from sofia_ros.sim.plant import TOPICS as PLANT_TOPICS
from sofia_ros.sim.protocol import NodeCore
from sofia_ros.topics import CD_JOINT, FD_JOINTS, centroid_topic
from sofia_ros.topics import GYRO_IMU as IMU_TOPIC
from sofia_ros.units import RAD_PER_ARCSEC, RAD_PER_DEG
from sofia_ros.validate import orthonormal_dcm

__all__ = ['TascuCore', 'TOPICS', 'DEFAULT_BORESIGHT_PX']

#: the topics this core publishes and the commands it takes, by the short names its methods use
TOPICS = {
    'attitude': topics.TASCU_ATTITUDE, 'motion_status': topics.MOTION_STATUS, 'drift': topics.DRIFT_ESTIMATE,
    'command_status': topics.COMMAND_STATUS, 'move_relative': topics.MOVE_RELATIVE,
    'mtbs_centroid': topics.MTBS_CENTROID, 'mtbs_inertial': topics.MTBS_INERTIAL, 'track': topics.TRACK,
}
COMMAND_TOPICS = ('move_relative', 'mtbs_centroid', 'mtbs_inertial', 'track')
DEFAULT_BORESIGHT_PX = {'hipo': (559.0, 489.0), 'fpi': (511.5, 511.5), 'ffi': (511.5, 511.5), 'wfi': (511.5, 511.5)}
_FBC_TIME_CONSTANT_S = 1.0  # low-pass of the accelerations for the quasi-static FBC (< 3 Hz, Table 3.1)


def _command_numbers(message):
    """The numbers of a TASCU command (the vector, point or quaternion of a geometry_msgs *Stamped message)."""
    for field in ('vector', 'point', 'quaternion'):
        value = getattr(message, field, None)
        if value is not None:
            return [getattr(value, axis) for axis in ('x', 'y', 'z', 'w') if hasattr(value, axis)]
    return []


class TascuCore(NodeCore):
    """Alignment, FBC, attitude propagation, servo, motion status and tracker."""

    name = 'tascu'
    imu_block_input = IMU_TOPIC.name
    upstream = (('gyro_box', 0), *((camera, 0) for camera in graph_nodes.CAMERAS), ('calibration', 1))

    def __init__(self, settings=None):
        super().__init__()
        self.settings = settings or servo.ServoSettings()
        self.tarf_from_gyrf = np.eye(3)
        self.camera_from_tarf = {camera: np.eye(3) for camera in CAMERAS}
        self.boresight_px = {camera: np.array(px) for camera, px in DEFAULT_BORESIGHT_PX.items()}
        self.fbc_enabled = False
        self.fbc_reference_elevation_deg = 40.0
        self.gyro_from_inertial = None  # gyro-propagated TARF estimate (rigid), set by the first tick
        self.commanded_from_inertial = None
        self.drift_rad_per_s = np.zeros(3)
        self.filtered_force = None
        self.joint_positions = {}
        self.last_stamp_ns = None
        self.imu_blocks = []
        self.latest_centroids = {}
        self.command_inbox = []
        self.queue = []
        self.profile = None
        self.tracking = None
        self.status = servo.MotionStatus(self.settings)
        self.outbox = []

    # --- parameters (ROS parameters of the node) ---------------------------------------------
    def parameters(self):
        """name -> (value, description) of the settable parameters."""
        values = {
            'alignment.tarf_from_gyrf': (self.tarf_from_gyrf.ravel().tolist(),
                                         'A_TARF,GYRF row-major (eq. 3.20; rows are TARF axes in GYRF)'),
            'fbc.enabled': (self.fbc_enabled, 'quasi-static flexible body compensation on/off (3.4.1)'),
            'fbc.reference_elevation_deg': (self.fbc_reference_elevation_deg,
                                            'reference elevation el0 of the alignment, deg (3.4.2)'),
        }
        for camera in CAMERAS:
            values[f'alignment.{camera}_from_tarf'] = (self.camera_from_tarf[camera].ravel().tolist(),
                                                       f'A_{camera.upper()},TARF row-major (3.3.1, 3.3.3)')
            values[f'boresight.{camera}_px'] = (self.boresight_px[camera].tolist(),
                                                f'TARF origin in {camera.upper()} pixels (x, y)')
        return values

    def set_parameter(self, name, value):
        """Validate and apply one parameter; ConfigError with the reason otherwise."""
        try:
            if name == 'alignment.tarf_from_gyrf':
                self.tarf_from_gyrf = orthonormal_dcm(name, np.reshape(value, (3, 3)))
            elif name == 'fbc.enabled':
                self.fbc_enabled = bool(value)
            elif name == 'fbc.reference_elevation_deg':
                mount.check_coarse_drive_elevation(value)
                self.fbc_reference_elevation_deg = float(value)
            elif name.startswith('alignment.') and name.endswith('_from_tarf'):
                camera = name[len('alignment.'):-len('_from_tarf')]
                self.camera_from_tarf[self._camera(camera)] = orthonormal_dcm(name, np.reshape(value, (3, 3)))
            elif name.startswith('boresight.') and name.endswith('_px'):
                camera = name[len('boresight.'):-len('_px')]
                boresight = np.asarray(value, dtype=float).reshape(2)
                if not np.all(np.isfinite(boresight)):
                    # Accepted, a NaN boresight killed the TASCU at the next centring.
                    raise ConfigError('a boresight is two finite pixel coordinates')
                self.boresight_px[self._camera(camera)] = boresight
            else:
                raise ConfigError(f'tascu has no parameter {name!r}')
        except (ValueError, TypeError, SofiaError) as err:
            raise ConfigError(f'parameter {name}: {err}') from err

    @staticmethod
    def _camera(camera):
        if camera not in CAMERAS:
            raise ConfigError(f'unknown camera {camera!r}')
        return camera

    # --- lock-step core ------------------------------------------------------------------------
    def inputs(self):
        cameras = tuple(centroid_topic(camera) for camera in CAMERAS)
        return (IMU_TOPIC, PLANT_TOPICS['joint_states'], *cameras, *(TOPICS[key] for key in COMMAND_TOPICS))

    def outputs(self):
        return (TOPICS['attitude'], TOPICS['motion_status'], TOPICS['drift'], TOPICS['command_status'],
                PLANT_TOPICS['fd_command'], PLANT_TOPICS['cd_command'])

    def receive(self, topic, message):
        if topic == IMU_TOPIC.name:
            self.imu_blocks.append(message)
        elif topic == PLANT_TOPICS['joint_states'].name:
            self.joint_positions = m.joint_positions_of(message)
        elif topic.endswith('/centroids'):
            self.latest_centroids[message.header.frame_id] = message
            self._track_frame(message)
        else:
            kind = next(key for key in COMMAND_TOPICS if TOPICS[key].name == topic)
            self.command_inbox.append((m.stamp_ns_of(message.header.stamp), kind, message))

    def tick(self, stamp_ns):
        self.outbox = []
        interval_s = 0.0 if self.last_stamp_ns is None else (stamp_ns - self.last_stamp_ns) / m.NS_PER_S
        self.last_stamp_ns = stamp_ns
        self._propagate()
        estimate = self._estimate()
        if self.commanded_from_inertial is None:
            self.commanded_from_inertial = estimate.copy()
        for command in sorted(self.command_inbox, key=lambda item: (item[0], item[1])):
            self._accept(*command, estimate)
        self.command_inbox = []
        feedforward = self._advance_moves(interval_s, estimate)
        error = rotation_error_rad(estimate, self.commanded_from_inertial)
        rate = servo.servo_rate_rad_per_s(error, feedforward, self.settings)
        moving = self.profile is not None or bool(self.queue)
        state = self.status.update(moving, error, stamp_ns / m.NS_PER_S)
        self._finish_tracking(stamp_ns)
        error_arcsec = float(np.linalg.norm(error)) / RAD_PER_ARCSEC
        return [
            (TOPICS['attitude'].name, m.quaternion_stamped(stamp_ns, 'irf', quaternion_from_dcm(estimate))),
            (PLANT_TOPICS['fd_command'].name, m.vector3_stamped(stamp_ns, 'tarf', rate)),
            (TOPICS['motion_status'].name, m.status_msg('fd_motion', state, {
                'stamp_ns': stamp_ns, 'error_rss_arcsec': f'{error_arcsec:.4f}'})),
            *self.outbox,
        ]

    # --- attitude ------------------------------------------------------------------------------
    def _propagate(self):
        blocks, self.imu_blocks = self.imu_blocks, []
        for block in blocks:
            if len(block) == 0:
                continue
            if self.gyro_from_inertial is None:
                # IRF is TARF at start-up (C.1.2).
                self.gyro_from_inertial = np.eye(3)
                self._sample_ns = int(block.stamp_ns[1] - block.stamp_ns[0]) if len(block) > 1 else 2_500_000
            rates_tarf = block.angular_velocity_rad_per_s @ self.tarf_from_gyrf.T - self.drift_rad_per_s
            self.gyro_from_inertial = propagate_dcm(self.gyro_from_inertial, rates_tarf, self._sample_ns / m.NS_PER_S)
            self._filter_force(block)

    def _filter_force(self, block):
        force = block.linear_acceleration_m_per_s2 @ self.tarf_from_gyrf.T
        duration_s = len(block) * self._sample_ns / m.NS_PER_S
        mean = force.mean(axis=0)
        if self.filtered_force is None:
            self.filtered_force = mean
        else:
            weight = 1.0 - np.exp(-duration_s / _FBC_TIME_CONSTANT_S)
            self.filtered_force = self.filtered_force + weight * (mean - self.filtered_force)

    def _estimate(self):
        """TASCU's TARF against IRF: gyro propagation turned by the FBC's focal-plane rotation (3.4.1-3.4.2)."""
        if self.gyro_from_inertial is None:
            self.gyro_from_inertial = np.eye(3)
        if not self.fbc_enabled or self.filtered_force is None:
            return self.gyro_from_inertial
        load_change = -self.filtered_force - gravity_load_tarf(self.fbc_reference_elevation_deg)
        del_el, del_xel = focal_plane_telescope_rotation_arcsec(load_change)
        return dcm_from_rotation_angles(np.array([del_el, del_xel, 0.0]) * RAD_PER_ARCSEC) @ self.gyro_from_inertial

    # --- commands ------------------------------------------------------------------------------
    def _report(self, command_ns, kind, state, reason='', level=DiagnosticStatus.OK):
        self.outbox.append((TOPICS['command_status'].name, m.status_msg(
            kind, f'{state}: {reason}' if reason else state, {'command_stamp_ns': command_ns}, level=level)))

    def _accept(self, command_ns, kind, message, estimate):
        try:
            if not all(np.isfinite(value) for value in _command_numbers(message)):
                # A NaN or infinite command killed the TASCU, and with it the run.
                raise CommandRefusedError(f'{kind} holds a value that is not a finite number')
            if kind == 'move_relative':
                rotation = m.vector_of(message)
                self._check_fine_drive(rotation)
                self.queue.append((command_ns, kind, rotation, None))
            elif kind == 'mtbs_centroid':
                camera = self._camera(message.header.frame_id)
                rotation = tracker.centring_rotation_rad(camera, (message.point.x, message.point.y),
                                                         self.boresight_px[camera], self.camera_from_tarf[camera])
                self._check_fine_drive(rotation)
                self.queue.append((command_ns, kind, rotation, None))
            elif kind == 'mtbs_inertial':
                target = dcm_from_quaternion(m.quaternion_xyzw_of(message))
                rotation = rotation_error_rad(self.commanded_from_inertial, target)
                cd_target_deg = self._coarse_drive_target_deg(target, rotation[0])
                if cd_target_deg is None:
                    self._check_fine_drive(rotation)
                self.queue.append((command_ns, kind, rotation, cd_target_deg))
            else:
                camera = self._camera(message.header.frame_id)
                if message.point.z <= 0.0:
                    raise CommandRefusedError('track needs a positive duration in point.z (s)')
                self.tracking = {'command_ns': command_ns, 'camera': camera, 'pixel': (message.point.x, message.point.y),
                                 'until_ns': command_ns + m.seconds_to_ns(message.point.z), 'times': [], 'pixels': []}
        except (CommandRefusedError, ConfigError, InvalidArgumentError) as err:
            # InvalidArgumentError: a quaternion of zero norm, a rotation the frames refuse.
            self._report(command_ns, kind, 'refused', str(err), DiagnosticStatus.ERROR)
            return
        self._report(command_ns, kind, 'accepted')

    def _check_fine_drive(self, rotation_rad):
        current = np.array([self.joint_positions.get(joint, 0.0) for joint in FD_JOINTS])
        mount.check_fine_drive_angles(current + rotation_rad)

    def _coarse_drive_target_deg(self, target, el_rotation_rad):
        """CD elevation for a large inertial move: the one that leaves the fine drive's EL angle at zero.

        The fine-drive angles at the end are those of the target attitude against the cradle turned
        by the coarse drive (C.1.1, B.4); they, not the components of one large rotation vector,
        must lie within +-3 deg. None when the fine drive alone can make the move.
        """
        if abs(el_rotation_rad) <= mount.FINE_DRIVE_LIMIT_DEG * RAD_PER_DEG / 2.0:
            return None
        now_deg = self.joint_positions.get(CD_JOINT, 0.0) / RAD_PER_DEG
        fine_drive_now = np.array([self.joint_positions.get(joint, 0.0) for joint in FD_JOINTS])
        cradle_from_inertial = mount.tarf_from_icrf_dcm(fine_drive_now).T @ self.commanded_from_inertial

        def fine_drive_at(elevation_deg):
            turn = mount.icrf_from_abrf_dcm(elevation_deg) @ mount.icrf_from_abrf_dcm(now_deg).T
            return mount.fine_drive_angles_from_dcm(target @ (turn @ cradle_from_inertial).T)

        guess_deg = now_deg + el_rotation_rad / RAD_PER_DEG
        low, high = guess_deg - 10.0, guess_deg + 10.0
        if fine_drive_at(low)[0] * fine_drive_at(high)[0] > 0.0:
            raise CommandRefusedError(f'no coarse-drive elevation near {guess_deg:.1f} deg brings the target '
                                      'within the fine drive; command a smaller move')
        # Imported here: the coarse-drive solve alone needs scipy.optimize, and every node process imports this
        # module through sim.graph (0.25 s of each one's start).
        from scipy.optimize import brentq

        target_deg = brentq(lambda elevation_deg: fine_drive_at(elevation_deg)[0], low, high, xtol=1e-9)
        mount.check_coarse_drive_elevation(target_deg)
        mount.check_fine_drive_angles(fine_drive_at(target_deg))
        return target_deg

    def _advance_moves(self, interval_s, estimate):
        if self.profile is None and self.queue:
            command_ns, kind, rotation, cd_target_deg = self.queue.pop(0)
            rate = self.settings.slew_rate_rad_per_s
            if cd_target_deg is not None:
                self.outbox.append((PLANT_TOPICS['cd_command'].name, m.joint_state(
                    self.last_stamp_ns, {CD_JOINT: cd_target_deg * RAD_PER_DEG})))
            self.profile = (command_ns, kind, servo.MoveProfile(rotation, rate))
        if self.profile is None or interval_s <= 0.0:
            return np.zeros(3)
        command_ns, kind, profile = self.profile
        self.commanded_from_inertial, feedforward = profile.advance(self.commanded_from_inertial, interval_s)
        if profile.done:
            self.profile = None
            self._report(command_ns, kind, 'done')
        return feedforward

    # --- tracker -------------------------------------------------------------------------------
    def _track_frame(self, message):
        tracking = self.tracking
        if tracking is None or message.header.frame_id != tracking['camera']:
            return
        stars = m.centroids_of(message)
        if not stars:
            return
        target = np.asarray(tracking['pixel'])
        _, x_px, y_px = min(stars, key=lambda star: float(np.hypot(star[1] - target[0], star[2] - target[1])))
        tracking['times'].append(m.stamp_ns_of(message.header.stamp) / m.NS_PER_S)
        tracking['pixels'].append((x_px, y_px))
        tracking['pixel'] = (x_px, y_px)

    def _finish_tracking(self, stamp_ns):
        tracking = self.tracking
        if tracking is None or stamp_ns < tracking['until_ns']:
            return
        self.tracking = None
        if len(tracking['times']) < 3:
            self._report(tracking['command_ns'], 'track', 'refused', 'fewer than 3 frames of the star',
                         DiagnosticStatus.ERROR)
            return
        observed = tracker.drift_rate_from_centroids_rad_per_s(
            tracking['camera'], tracking['times'], tracking['pixels'], self.camera_from_tarf[tracking['camera']])
        self.drift_rad_per_s = self.drift_rad_per_s - observed
        self.outbox.append((TOPICS['drift'].name, m.vector3_stamped(stamp_ns, 'tarf', self.drift_rad_per_s)))
        self._report(tracking['command_ns'], 'track', 'done')
