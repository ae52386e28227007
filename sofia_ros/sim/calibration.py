"""Calibration node core: the Table 3.4 alignment sequence as practised in 6.1 and 6.4.

Drift estimation on the tracked star, LOS rotations about a star at the flange centre
(maneuver 2), EL/XEL rotations across HIPO's field (maneuver 3), each repeated with
several frames before and after and selected by motion status; the least-squares
solver of 3.3.2 on all maneuvers at once; the new A_TARF,GYRF pushed to the TASCU as
a parameter; a verification block that either accepts the matrix or starts another
iteration (Table D.1). Boresights of the imagers at the reference elevation
(maneuver 1) and their rotations of field (maneuver 4) follow. The sequence is a
generator that waits one tick at every ``yield``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
import yaml
from scipy.spatial.transform import Rotation
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PointStamped

from sofia_ros.calibration.accuracy import sigma_beta_from_length_rad, sigma_r_rad
from sofia_ros.calibration.solvers import Maneuver, fit_alignment
from sofia_ros.errors import InvalidArgumentError, SofiaError
from sofia_ros.sensors.imager_model import nominal_detector
from sofia_ros.sim import messages as m
from sofia_ros.sim.camera import centroid_topic
from sofia_ros.sim.plant import FD_JOINTS
from sofia_ros.sim.plant import TOPICS as PLANT_TOPICS
from sofia_ros.sim.protocol import SET_PARAMETERS, NodeCore, ParameterRequest, ParameterResult, TopicSpec
from sofia_ros.sim.tascu import TOPICS as TASCU_TOPICS
from sofia_ros.units import ARCSEC_PER_RAD, RAD_PER_DEG

__all__ = ['AlignmentPlan', 'CalibrationCore', 'TOPICS', 'maneuver_record', 'maneuver_from_record']

TOPICS = {
    'progress': TopicSpec('/calibration/progress', 'diagnostic_msgs/msg/DiagnosticStatus',
                          'calibration step, iteration and the latest fitted angles'),
    'result': TopicSpec('/calibration/result', 'std_msgs/msg/String',
                        'accepted alignment matrices and their accuracy, YAML'),
    'maneuvers': TopicSpec('/calibration/maneuvers', 'std_msgs/msg/String',
                           'each fit: the maneuvers it used (axis, angle, centroids, active matrix, block), YAML'),
}
IMAGERS = ('fpi', 'ffi', 'wfi')
_FD_MARGIN_DEG = 2.9
_KEPT_FRAMES = 200
_RECENTRE_LOS_DEG = 1.0
_MIN_REPETITIONS_FOR_DRIFT_FIT = 4


class CalibrationAbort(SofiaError):
    """The sequence cannot go on; the reason says why."""


@dataclass(frozen=True)
class AlignmentPlan:
    """Size of the alignment campaign (6.1: six repetitions, three frames, 5 deg LOS, 4.8' EL/XEL)."""

    repetitions: int = 6
    frames_per_position: int = 3
    los_angle_deg: float = 5.0
    elxel_length_arcmin: float = 4.8
    drift_track_s: float = 60.0
    verification_repetitions: int = 2
    max_iterations: int = 3
    timeout_s: float = 120.0

    def __post_init__(self):
        if self.repetitions < 2 or self.frames_per_position < 1 or self.verification_repetitions < 1:
            raise InvalidArgumentError('plan needs >= 2 repetitions, >= 1 frame and >= 1 verification repetition')
        if not 0.0 < self.los_angle_deg <= 2 * _FD_MARGIN_DEG - 0.5:
            raise InvalidArgumentError(f'los_angle_deg must be in (0, {2 * _FD_MARGIN_DEG - 0.5}] to fit the '
                                       f'+-3 deg fine drive, got {self.los_angle_deg}')


class CalibrationCore(NodeCore):
    """Commands the maneuvers, solves the DCMs, pushes them to the TASCU, verifies."""

    name = 'calibration'
    upstream = (('tascu', 0), ('hipo', 0), ('fpi', 0), ('ffi', 0), ('wfi', 0))

    def __init__(self, plan=None):
        super().__init__()
        self.plan = plan or AlignmentPlan()
        self.stamp_ns = 0
        self.status = None
        self.command_status = {}
        self.frames = {camera: [] for camera in ('hipo', *IMAGERS)}
        self.joints = {}
        self.parameter_result = None
        self.outbox = []
        self.active_alignment = np.eye(3)
        self.star_hip = None
        self.block = 0
        self.record = {'iterations': []}
        self._sequence = self._run()

    def inputs(self):
        cameras = tuple(centroid_topic(camera) for camera in ('hipo', *IMAGERS))
        return (TASCU_TOPICS['motion_status'], TASCU_TOPICS['command_status'], PLANT_TOPICS['joint_states'],
                *cameras)

    def outputs(self):
        return (TASCU_TOPICS['move_relative'], TASCU_TOPICS['mtbs_centroid'], TASCU_TOPICS['track'],
                TOPICS['progress'], TOPICS['result'], TOPICS['maneuvers'])

    def receive(self, topic, message):
        if topic == TASCU_TOPICS['motion_status'].name:
            self.status = message.message
        elif topic == TASCU_TOPICS['command_status'].name:
            self.command_status[int(m.status_values_of(message)['command_stamp_ns'])] = message.message
        elif topic == PLANT_TOPICS['joint_states'].name:
            self.joints = m.joint_positions_of(message)
        elif topic == SET_PARAMETERS:
            self.parameter_result = message
        elif topic.endswith('/centroids'):
            frames = self.frames[message.header.frame_id]
            frames.append((m.stamp_ns_of(message.header.stamp), m.centroids_of(message)))
            del frames[:-_KEPT_FRAMES]

    def tick(self, stamp_ns):
        self.stamp_ns = stamp_ns
        self.outbox = []
        if self.outcome.finished or self.outcome.failed:
            return []
        try:
            next(self._sequence)
        except StopIteration:
            self.outcome.finished = True
        except SofiaError as err:
            self.outcome.failed, self.outcome.reason = True, str(err)
            self._progress('failed', {'reason': str(err)}, DiagnosticStatus.ERROR)
            self.outbox.append((TOPICS['result'].name, m.string_msg(yaml.safe_dump(
                {'accepted': False, 'reason': str(err), **self.record}, sort_keys=False))))
        return self.outbox

    # --- small steps ------------------------------------------------------------------------
    def _progress(self, step, values=None, level=DiagnosticStatus.OK):
        self.outbox.append((TOPICS['progress'].name, m.status_msg('calibration', step, values, level)))

    def _wait(self, predicate, what):
        deadline_ns = self.stamp_ns + m.seconds_to_ns(self.plan.timeout_s)
        while not predicate():
            if self.stamp_ns >= deadline_ns:
                raise CalibrationAbort(f'timed out after {self.plan.timeout_s:g} s waiting for {what}')
            yield

    def _locked(self):
        yield from self._wait(lambda: self.status == 'locked', 'the TASCU to report locked')

    def _command(self, kind, message):
        command_ns = self.stamp_ns + len(self.outbox)  # unique even for two commands in one tick
        message.header.stamp = m.time_msg(command_ns)
        self.outbox.append((TASCU_TOPICS[kind].name, message))
        yield from self._wait(lambda: command_ns in self.command_status, f'the TASCU to answer {kind}')
        yield from self._wait(lambda: not self.command_status[command_ns].startswith('accepted'),
                              f'{kind} to finish')
        answer = self.command_status[command_ns]
        if answer.startswith('refused'):
            raise CalibrationAbort(f'TASCU refused {kind}: {answer[len("refused: "):]}')

    def _move(self, rotation_rad):
        yield from self._command('move_relative', m.vector3_stamped(0, 'tarf', rotation_rad))
        yield from self._locked()

    def _point_message(self, camera, pixel, z=0.0):
        msg = PointStamped()
        msg.header.frame_id = camera
        msg.point.x, msg.point.y, msg.point.z = float(pixel[0]), float(pixel[1]), float(z)
        return msg

    def _star_frames(self, camera, count):
        """Mean centroid of the tracked star over the next ``count`` frames after now."""
        # Whole exposures after the lock: the longest (imagers, 2 s) started at most 1 s before its midpoint.
        since_ns = self.stamp_ns + m.NS_PER_S
        frames = self.frames[camera]
        yield from self._wait(
            lambda: sum(1 for stamp, stars in frames if stamp > since_ns and self._find(stars)) >= count,
            f'{count} {camera.upper()} frames with HIP {self.star_hip}')
        found = [(stamp, self._find(stars)) for stamp, stars in frames if stamp > since_ns and self._find(stars)]
        found = found[:count]
        frames.clear()
        pixels = np.array([pixel for _, pixel in found])
        return pixels.mean(axis=0), float(np.mean([stamp for stamp, _ in found])) / m.NS_PER_S

    def _find(self, stars):
        return next(((x, y) for hip, x, y in stars if hip == self.star_hip), None)

    def _push(self, values):
        self.parameter_result = None
        self.outbox.append((SET_PARAMETERS, ParameterRequest('tascu', values)))
        yield from self._wait(lambda: isinstance(self.parameter_result, ParameterResult), 'the parameter service')
        if not self.parameter_result.successful:
            raise CalibrationAbort(f'TASCU refused parameters: {self.parameter_result.reasons}')

    # --- the sequence -----------------------------------------------------------------------
    def _run(self):
        self._progress('acquire')
        yield from self._locked()
        yield from self._wait(lambda: any(stars for _, stars in self.frames['hipo']), 'a star in HIPO')
        _, stars = next(frame for frame in self.frames['hipo'] if frame[1])
        centre = nominal_detector('hipo').center_px
        self.star_hip, x_px, y_px = min(stars, key=lambda s: np.hypot(s[1] - centre[0], s[2] - centre[1]))
        yield from self._centre_star()
        yield from self._define_imager_boresights()
        for iteration in range(1, self.plan.max_iterations + 1):
            accepted = yield from self._iteration(iteration)
            if accepted:
                break
        else:
            raise CalibrationAbort(f'no alignment accepted after {self.plan.max_iterations} iterations')
        yield from self._imager_rotation_of_field()
        self._progress('finished')
        self.outbox.append((TOPICS['result'].name, m.string_msg(yaml.safe_dump(self.result(), sort_keys=False))))

    def _centre_star(self):
        # An inertial hold walks the fine drive at Earth rate, mostly about LOS here: turn it back first.
        fd_los_deg = self.joints.get(FD_JOINTS[2], 0.0) / RAD_PER_DEG
        if abs(fd_los_deg) > _RECENTRE_LOS_DEG:
            yield from self._move(np.array([0.0, 0.0, -fd_los_deg * RAD_PER_DEG]))
        pixel, _ = yield from self._star_frames('hipo', 1)
        yield from self._command('mtbs_centroid', self._point_message('hipo', pixel))
        yield from self._locked()

    def _define_imager_boresights(self):
        """Maneuver 1 of Table 3.4: where the star at TARF's origin appears in each imager."""
        self._progress('boresight')
        boresights = {}
        for camera in IMAGERS:
            pixel, _ = yield from self._star_frames(camera, self.plan.frames_per_position)
            boresights[f'boresight.{camera}_px'] = [float(pixel[0]), float(pixel[1])]
        yield from self._push(boresights)
        self.record['boresight_px'] = {key.split('.')[1][:-3]: value for key, value in boresights.items()}

    def _estimate_drift(self):
        self.block += 1  # maneuvers after one drift estimation share one residual drift (6.1)
        self._progress('drift')
        yield from self._centre_star()
        pixel, _ = yield from self._star_frames('hipo', 1)
        yield from self._command('track', self._point_message('hipo', pixel, self.plan.drift_track_s))
        yield from self._centre_star()

    def _maneuver(self, axis, angle_rad, camera='hipo'):
        start, start_s = yield from self._star_frames(camera, self.plan.frames_per_position)
        rotation = np.zeros(3)
        rotation['el xel los'.split().index(axis)] = angle_rad
        yield from self._move(rotation)
        end, end_s = yield from self._star_frames(camera, self.plan.frames_per_position)
        # On an imager the gyros are already aligned: the fit then gives A_XYIRF,TARF (3.3.3).
        active = self.active_alignment if camera == 'hipo' else np.eye(3)
        return Maneuver(axis, angle_rad, start, end, active, end_s - start_s, self.block)

    def _los_block(self, repetitions):
        """LOS rotations alternating in sign, keeping the fine drive inside its travel (6.1)."""
        angle_rad = self.plan.los_angle_deg * RAD_PER_DEG
        maneuvers = []
        for _ in range(repetitions):
            fd_los_deg = self.joints.get(FD_JOINTS[2], 0.0) / RAD_PER_DEG
            sign = -1.0 if fd_los_deg > 0.0 else 1.0
            if abs(fd_los_deg + sign * self.plan.los_angle_deg) > _FD_MARGIN_DEG:
                # Pre-position (not measured) so the rotation runs across the travel, from -+half to +-half.
                half_deg = self.plan.los_angle_deg / 2.0
                yield from self._move(np.array([0.0, 0.0, (-sign * half_deg - fd_los_deg) * RAD_PER_DEG]))
            maneuvers.append((yield from self._maneuver('los', sign * angle_rad)))
        return maneuvers

    def _elxel_block(self, repetitions, camera='hipo'):
        """EL and XEL rotations of L across the field, alternating in sign (maneuver 3, 6.1)."""
        length_rad = self.plan.elxel_length_arcmin / 60.0 * RAD_PER_DEG
        maneuvers = []
        for index, axis in enumerate(('el', 'xel')):
            yield from self._centre_star()
            offset = np.zeros(3)
            offset[index] = -length_rad / 2.0
            yield from self._move(offset)
            for repetition in range(repetitions):
                sign = 1.0 if repetition % 2 == 0 else -1.0
                maneuvers.append((yield from self._maneuver(axis, sign * length_rad, camera)))
        yield from self._centre_star()
        return maneuvers

    def _iteration(self, iteration):
        self._progress('iteration', {'iteration': iteration})
        yield from self._estimate_drift()
        los = yield from self._los_block(self.plan.repetitions)
        tilt = self._fit('los_tilt', los, solve_for=('el', 'xel'))
        yield from self._set_alignment(tilt.dcm)
        yield from self._estimate_drift()
        elxel = yield from self._elxel_block(self.plan.repetitions)
        full = self._fit('gyro_alignment', los + elxel)
        yield from self._set_alignment(full.dcm)
        self._progress('verify', {'iteration': iteration})
        yield from self._estimate_drift()
        check = (yield from self._los_block(2 * self.plan.verification_repetitions)) + \
                (yield from self._elxel_block(2 * self.plan.verification_repetitions))
        verification = self._fit('verification', check, fit_drift=False)
        correction = _small_angles(verification.dcm, full.dcm)
        accepted = bool(np.all(np.abs(correction) <= 3.0 * verification.sigma_rad))
        self.record['iterations'].append({
            'iteration': iteration,
            'los_maneuvers': len(los), 'elxel_maneuvers': len(elxel),
            'fitted_alignment': full.dcm.tolist(),
            'fitted_sigma_arcsec': (full.sigma_rad * ARCSEC_PER_RAD).tolist(),
            'centroid_sigma_px': full.sigma_c_px,
            'residual_drift_fitted': self._fit_drift,
            'residual_drift_px_per_s': full.drift_px_per_s.tolist(),
            'verification_correction_arcsec': (correction * ARCSEC_PER_RAD).tolist(),
            'verification_sigma_arcsec': (verification.sigma_rad * ARCSEC_PER_RAD).tolist(),
            'accepted': accepted,
        })
        self.final_fit = full
        if not accepted:
            yield from self._set_alignment(verification.dcm)
        return accepted

    def _fit(self, purpose, maneuvers, *, solve_for=('el', 'xel', 'los'), fit_drift=None, camera='hipo'):
        """Solve (3.3.2) and publish the inputs so that the fit can be repeated offline from the bag."""
        fit_drift = self._fit_drift if fit_drift is None else fit_drift
        self.outbox.append((TOPICS['maneuvers'].name, m.string_msg(yaml.safe_dump({
            'purpose': purpose, 'camera': camera, 'solve_for': list(solve_for), 'fit_drift': fit_drift,
            'maneuvers': [maneuver_record(maneuver) for maneuver in maneuvers]}, sort_keys=False))))
        return fit_alignment(maneuvers, nominal_detector(camera), solve_for=solve_for, fit_drift=fit_drift,
                             initial_dcm=np.eye(3) if camera != 'hipo' else None)

    @property
    def _fit_drift(self):
        """Fit the residual drift (6.1) when every block has enough maneuvers to spare the unknowns."""
        return self.plan.repetitions >= _MIN_REPETITIONS_FOR_DRIFT_FIT

    def _set_alignment(self, dcm):
        yield from self._push({'alignment.tarf_from_gyrf': np.asarray(dcm).ravel().tolist()})
        self.active_alignment = np.asarray(dcm)

    def _imager_rotation_of_field(self):
        """Maneuver 4 of Table 3.4: EL/XEL rotations seen in each imager give A_XYIRF,TARF."""
        self._progress('rotation_of_field')
        self.record['imagers'] = {}
        updates = {}
        for camera in IMAGERS:
            maneuvers = yield from self._elxel_block(self.plan.verification_repetitions, camera)
            fit = self._fit(f'rotation_of_field_{camera}', maneuvers, solve_for=('los',), fit_drift=False,
                            camera=camera)
            updates[f'alignment.{camera}_from_tarf'] = fit.dcm.ravel().tolist()
            self.record['imagers'][camera] = {
                'rotation_of_field_arcsec': float(fit.angles_rad[2] * ARCSEC_PER_RAD),
                'sigma_arcsec': float(fit.sigma_rad[2] * ARCSEC_PER_RAD),
            }
        yield from self._push(updates)

    def result(self):
        """The accepted alignment and its predicted accuracy (3.32, 3.34, 3.37) as a plain mapping."""
        fit = self.final_fit
        los_count = self.record['iterations'][-1]['los_maneuvers']
        elxel_count = self.record['iterations'][-1]['elxel_maneuvers']
        sigma_c_rad = fit.sigma_c_px * nominal_detector('hipo').scale_rad_per_px
        sigma_r = sigma_r_rad(sigma_c_rad, self.plan.los_angle_deg * RAD_PER_DEG) / np.sqrt(los_count)
        sigma_beta = sigma_beta_from_length_rad(
            sigma_c_rad, self.plan.elxel_length_arcmin / 60.0 * RAD_PER_DEG) / np.sqrt(elxel_count)
        return {
            'accepted': True,
            'tarf_from_gyrf': np.asarray(self.active_alignment).tolist(),
            'predicted_sigma_arcsec': {'el': float(sigma_r * ARCSEC_PER_RAD), 'xel': float(sigma_r * ARCSEC_PER_RAD),
                                       'los': float(sigma_beta * ARCSEC_PER_RAD)},
            'plan': asdict(self.plan),
            **self.record,
        }


def maneuver_record(maneuver):
    """A Maneuver as plain YAML-able values (the /calibration/maneuvers record)."""
    return {'axis': maneuver.axis, 'angle_rad': float(maneuver.angle_rad),
            'start_px': [float(v) for v in maneuver.start_px], 'end_px': [float(v) for v in maneuver.end_px],
            'active_alignment': np.asarray(maneuver.active_alignment).tolist(),
            'duration_s': float(maneuver.duration_s), 'block': int(maneuver.block)}


def maneuver_from_record(record):
    """Inverse of maneuver_record."""
    return Maneuver(record['axis'], record['angle_rad'], record['start_px'], record['end_px'],
                    np.asarray(record['active_alignment']), record['duration_s'], record['block'])


def _small_angles(dcm, reference):
    """Rotation angles (EL, XEL, LOS) that turn ``reference`` into ``dcm`` (B.19-B.22)."""
    return Rotation.from_matrix((dcm @ reference.T).T).as_rotvec()
