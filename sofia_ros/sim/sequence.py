"""The calibration node's sequence machinery, shared by the alignment sequence and the star hop.

A sequence is a generator that waits one tick at every ``yield``; its steps command the TASCU
(move_relative, mtbs_centroid, mtbs_inertial, track) and wait for its answer and for *locked*,
collect the tracked star's centroids, push parameters to the TASCU and acquire a catalogue star
through the wide fields (6.1-6.4). Subclasses write ``_run``, the sequence itself.
"""

from __future__ import annotations

import datetime as dt
from dataclasses import MISSING, fields
from typing import Any, Mapping

import numpy as np
import yaml
from diagnostic_msgs.msg import DiagnosticStatus
from geometry_msgs.msg import PointStamped

from sofia_ros import messages as m
from sofia_ros import mount
from sofia_ros.config import safe_load_limited
from sofia_ros.control.tracker import centring_rotation_rad
from sofia_ros.errors import CalibrationAbort, ConfigError, InvalidArgumentError, SofiaError, UnknownStarError
from sofia_ros.frames import dcm_from_quaternion, dcm_from_rotation_angles, quaternion_from_dcm
from sofia_ros.graph_nodes import CAMERAS
from sofia_ros.sensors.imager_model import nominal_detector
from sofia_ros.sim.protocol import SET_PARAMETERS, NodeCore, ParameterRequest, ParameterResult
from sofia_ros.sim.tascu import TOPICS as TASCU_TOPICS
from sofia_ros.sky import TELESCOPE_MIN_ELEVATION_DEG, WACO_2004_WEATHER, observed_place
from sofia_ros.topics import (
    CALIBRATION_MANEUVERS,
    CALIBRATION_PROGRESS,
    CALIBRATION_RESULT,
    FD_JOINTS,
    JOINT_STATES,
    THERMAL_COMMAND,
    centroid_topic,
)
from sofia_ros.plan_limits import MAX_ELEMENT_S, PLAN_LIMITS
from sofia_ros.units import RAD_PER_DEG
from sofia_ros.validate import finite_array, finite_scalar, number_text_hint

__all__ = ['SequenceCore', 'TOPICS', 'OBSERVING_ELEVATIONS_DEG', 'PLAN_FILE_NAME', 'plan_document', 'plan_text',
           'elements_from_yaml', 'elements_to_yaml',
           'elements_budget_s', 'observing_elevation', 'fine_drive_los', 'hold_duration', 'detector_offset',
           'thermal_target', 'thermal_rate', 'check_plan_limits']

#: the topics the calibration node publishes besides the TASCU's commands, by the short names its methods use
TOPICS = {'progress': CALIBRATION_PROGRESS, 'result': CALIBRATION_RESULT, 'maneuvers': CALIBRATION_MANEUVERS,
          'thermal': THERMAL_COMMAND}
#: the plan beside a recorded bag, like truth.yaml
PLAN_FILE_NAME = 'plan.yaml'
_KEPT_FRAMES = 200
_RECENTRE_LOS_DEG = 1.0
#: The elevations a plan may observe at: the door drive's range, outside which the telescope vignettes (1.2).
OBSERVING_ELEVATIONS_DEG = (TELESCOPE_MIN_ELEVATION_DEG, 60.0)
#: A detector position a plan asks for keeps this share of the half-field free to the edge (a star there is lost).
_DETECTOR_EDGE_MARGIN = 0.1
#: Moves that place a star on a detector position: the first on the nominal geometry, the others correct it.
_PLACEMENT_MOVES = 3


# --- plan elements: what a plan appends to its campaign's sequence (docs/plans.md) --------------------
def _number(name: str, value: Any) -> float:
    """``value`` as a finite float; a YAML true or false, or text, is not a number here (finite_scalar would take
    '40' and even Arabic-Indic digits)."""
    if isinstance(value, str):
        raise InvalidArgumentError(f'{name} must be a number, got the text {value!r:.40}{number_text_hint(value)}')
    if isinstance(value, bool):
        raise InvalidArgumentError(f'{name} must be a number, got {value}')
    return finite_scalar(name, value)


def observing_elevation(name: str, value: Any) -> float:
    """``value`` as an elevation in the observing range (1.2: 20-60 deg); InvalidArgumentError otherwise."""
    elevation_deg = _number(name, value)
    low, high = OBSERVING_ELEVATIONS_DEG
    if not low <= elevation_deg <= high:
        raise InvalidArgumentError(f'{name} is {elevation_deg:g} deg, outside the {low:g}-{high:g} deg elevations '
                                   'the telescope observes at (its door drive, 1.2)')
    return elevation_deg


def fine_drive_los(name: str, value: Any) -> float:
    """``value`` as a fine-drive LOS angle within its +-3 deg travel (mount); InvalidArgumentError otherwise."""
    angle_deg = _number(name, value)
    if abs(angle_deg) > mount.FINE_DRIVE_LIMIT_DEG:
        raise InvalidArgumentError(f'{name} is {angle_deg:g} deg, outside the fine drive\'s '
                                   f'+-{mount.FINE_DRIVE_LIMIT_DEG:g} deg LOS travel')
    return angle_deg


def hold_duration(name: str, value: Any) -> float:
    """``value`` as a hold length in s, in (0, MAX_ELEMENT_S]; InvalidArgumentError otherwise."""
    duration_s = _number(name, value)
    if not 0.0 < duration_s <= MAX_ELEMENT_S:
        raise InvalidArgumentError(f'{name} must be > 0 and <= {MAX_ELEMENT_S:g} s, got {duration_s:g}')
    return duration_s


def check_plan_limits(plan: Any) -> None:
    """InvalidArgumentError naming the first field of ``plan`` outside its PLAN_LIMITS range."""
    for name, (low, high, unit) in PLAN_LIMITS.items():
        if not hasattr(plan, name):
            continue
        value = getattr(plan, name)
        if not (low < value <= high if low == 0.0 else low <= value <= high):
            span = f'> 0 and <= {high:g}' if low == 0.0 else f'{low:g}-{high:g}'
            raise InvalidArgumentError(f'{name} must be {span} {unit}, got {value:g}')


def thermal_target(name: str, value: Any) -> float:
    """``value`` as a temperature setpoint in deg C (a number; the truth's control says which it reaches)."""
    return _number(name, value)


def thermal_rate(name: str, value: Any) -> float | None:
    """``value`` as a setpoint rate in deg C/h, > 0 (None: the truth's largest); InvalidArgumentError otherwise."""
    if value is None:
        return None
    rate_c_per_h = _number(name, value)
    if rate_c_per_h <= 0.0:
        raise InvalidArgumentError(f'{name} must be > 0 C/h (the setpoint moves toward target_c at it), '
                                   f'got {rate_c_per_h:g}')
    return rate_c_per_h


def detector_offset(camera: Any, offset_arcsec: Any) -> tuple[float, float]:
    """The offset of a star placed off ``camera``'s detector centre, arcsec along its x and y pixel axes.

    InvalidArgumentError for an unknown camera or a position off the detector (or within 10 % of its edge).
    """
    if camera not in CAMERAS:
        raise InvalidArgumentError(f'camera {camera!r} is not one of {", ".join(CAMERAS)}')
    offset = finite_array('detector_offset_arcsec', offset_arcsec, shape=(2,))
    detector = nominal_detector(camera)
    half_field_arcsec = (1.0 - _DETECTOR_EDGE_MARGIN) * detector.scale_arcsec_per_px * np.array(
        [detector.width_px, detector.height_px]) / 2.0
    if np.any(np.abs(offset) > half_field_arcsec):
        raise InvalidArgumentError(
            f'detector_offset_arcsec {offset.tolist()} leaves the {camera.upper()} field; keep |x| <= '
            f'{half_field_arcsec[0]:.0f}" and |y| <= {half_field_arcsec[1]:.0f}"')
    return float(offset[0]), float(offset[1])


def elements_from_yaml(text: str, kinds: Mapping[str, type], campaign: str) -> tuple:
    """The plan elements of YAML ``text`` (a list of ``{kind: {field: value}}``), each a ``kinds`` dataclass.

    InvalidArgumentError names an unknown kind or field and whatever the element itself refuses.
    """
    try:
        document = safe_load_limited(text, 'plan elements') if text.strip() else []
    except ConfigError as err:
        raise InvalidArgumentError(str(err)) from err
    if not isinstance(document, list):
        raise InvalidArgumentError(f'elements must be a list of {{kind: {{field: value}}}}, got {document!r:.60}')
    return tuple(_element(entry, kinds, campaign, index) for index, entry in enumerate(document, 1))


def _element(entry: Any, kinds: Mapping[str, type], campaign: str, index: int) -> Any:
    if not isinstance(entry, dict) or len(entry) != 1:
        raise InvalidArgumentError(f'element {index} must be one {{kind: {{field: value}}}} mapping, got {entry!r:.60}')
    ((kind, values),) = entry.items()
    if kind not in kinds:
        raise InvalidArgumentError(f'element {index}: unknown maneuver {kind!r} for the {campaign} campaign; '
                                   f'use one of {", ".join(kinds)} (docs/plans.md)')
    element_type = kinds[kind]
    names = [spec.name for spec in fields(element_type)]
    required = [spec.name for spec in fields(element_type) if spec.default is MISSING]
    if not isinstance(values, dict):
        raise InvalidArgumentError(f'element {index} ({kind}) must map its fields ({", ".join(names)}), '
                                   f'got {values!r:.60}')
    unknown = sorted(map(str, set(values) - set(names)))
    if unknown:
        raise InvalidArgumentError(f'element {index} ({kind}): unknown field {", ".join(unknown)}; '
                                   f'{kind} takes {", ".join(names)}')
    try:
        return element_type(**values)
    except TypeError as err:  # a required field left out
        raise InvalidArgumentError(f'element {index} ({kind}) needs {", ".join(required)}') from err
    except (InvalidArgumentError, UnknownStarError) as err:
        raise InvalidArgumentError(f'element {index} ({kind}): {err}') from err


def elements_to_yaml(elements: tuple) -> str:
    """The YAML text of plan elements (one flow line; empty for none): what elements_from_yaml reads back."""
    if not elements:
        return ''
    document = [{element.kind: {spec.name: _plain(getattr(element, spec.name)) for spec in fields(element)
                                if getattr(element, spec.name) is not None}} for element in elements]
    return yaml.safe_dump(document, default_flow_style=True, sort_keys=False, width=1 << 16).strip()


# --- plan files (docs/plans.md; read and checked by campaigns.plan_files) ----------------------------
def plan_document(plan: Any) -> dict[str, Any]:
    """The plan as a plan file's mapping: its campaign, every field, its elements."""
    document: dict[str, Any] = {'campaign': plan.campaign}
    for spec in fields(plan):
        if spec.name != 'elements_yaml':
            document[spec.name] = _plain(getattr(plan, spec.name))
    if plan.elements_yaml:
        document['elements'] = yaml.safe_load(plan.elements_yaml)
    return document


def _plain(value: Any) -> Any:
    """``value`` with its tuples (rows too) as YAML lists."""
    return [_plain(item) for item in value] if isinstance(value, tuple) else value


def plan_text(plan: Any) -> str:
    """The plan file of ``plan`` (every field spelled out): what campaigns.plan_files reads back as ``plan``."""
    document = plan_document(plan)
    elements = document.pop('elements', None)
    text = yaml.safe_dump(document, sort_keys=False, default_flow_style=None, width=100)
    if elements:
        # One element per line, each as the maneuver mapping a user would write.
        lines = [f'  - {yaml.safe_dump(element, default_flow_style=True, width=1 << 16).strip()}'
                 for element in elements]
        text += 'elements:\n' + '\n'.join(lines) + '\n'
    return text


def elements_budget_s(elements: tuple, timeout_s: float) -> float:
    """Sim time to allow for flying ``elements``: their holds plus ten waits of ``timeout_s`` each (a cap only)."""
    return sum(getattr(element, 'duration_s', 0.0) + 10.0 * timeout_s for element in elements)


class SequenceCore(NodeCore):
    """The calibration node: runs ``_run`` one tick at a time and publishes its result; the steps it is made of."""

    name = 'calibration'
    upstream = (('tascu', 0), *((camera, 0) for camera in CAMERAS))
    ends_run = True
    parameter_targets = ('tascu',)

    def __init__(self, plan, scenario):
        super().__init__()
        self.plan = plan
        self.scenario = scenario
        self.attitude = None
        self.stamp_ns = 0
        self.status = None
        self.command_status = {}
        self.frames = {camera: [] for camera in CAMERAS}
        self.joints = {}
        self.parameter_result = None
        self.outbox = []
        self.active_alignment = np.eye(3)
        self.star_hip = None
        self.record = {}
        self._sequence = self._run()

    def _run(self):
        """The sequence: a generator that yields once per tick it waits."""
        raise NotImplementedError

    def inputs(self):
        cameras = tuple(centroid_topic(camera) for camera in CAMERAS)
        return (TASCU_TOPICS['motion_status'], TASCU_TOPICS['command_status'], JOINT_STATES,
                TASCU_TOPICS['attitude'], *cameras)

    def outputs(self):
        return (TASCU_TOPICS['move_relative'], TASCU_TOPICS['mtbs_centroid'], TASCU_TOPICS['mtbs_inertial'],
                TASCU_TOPICS['track'], TOPICS['progress'], TOPICS['result'], TOPICS['maneuvers'], TOPICS['thermal'])

    def receive(self, topic, message):
        if topic == TASCU_TOPICS['motion_status'].name:
            self.status = message.message
        elif topic == TASCU_TOPICS['command_status'].name:
            self.command_status[int(m.status_values_of(message)['command_stamp_ns'])] = message.message
        elif topic == JOINT_STATES.name:
            self.joints = m.joint_positions_of(message)
        elif topic == TASCU_TOPICS['attitude'].name:
            self.attitude = message
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

    # --- steps every sequence is made of ---------------------------------------------------
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

    def _recentre_los(self, threshold_deg=_RECENTRE_LOS_DEG):
        """Turn the fine drive's LOS back to zero beyond a threshold: an inertial hold walks it at Earth rate."""
        fd_los_deg = self.joints.get(FD_JOINTS[2], 0.0) / RAD_PER_DEG
        if abs(fd_los_deg) > threshold_deg:
            yield from self._move(np.array([0.0, 0.0, -fd_los_deg * RAD_PER_DEG]))

    def _set_alignment(self, dcm):
        yield from self._push({'alignment.tarf_from_gyrf': np.asarray(dcm).ravel().tolist()})
        self.active_alignment = np.asarray(dcm)

    def _star_direction_irf(self, star):
        """The star's direction in the TASCU's IRF (TARF at start-up) from the catalogue and the nominal mount."""
        elapsed_s = self.stamp_ns / m.NS_PER_S
        utc = self.scenario.start_utc + dt.timedelta(seconds=elapsed_s)
        place = observed_place(star, self.scenario.site, utc, WACO_2004_WEATHER,
                               min_altitude_deg=TELESCOPE_MIN_ELEVATION_DEG)
        s_hrf = mount.unit_vector_hrf(place.apparent_altitude_deg, place.azimuth_deg)
        tarf0_from_hrf0 = mount.tarf_from_hrf_dcm(self.scenario.heading_deg, self.scenario.start_elevation_deg)
        return tarf0_from_hrf0 @ mount.hrf_from_irf_dcm(self.scenario.latitude_deg, elapsed_s).T @ s_hrf

    def _point_at(self, star):
        """MTBS_INERTIAL: turn the LOS onto the star, the coarse drive taking large elevation changes (6.3)."""
        estimate = dcm_from_quaternion(m.quaternion_xyzw_of(self.attitude))
        star_tarf = estimate @ self._star_direction_irf(star)
        axis = np.cross([0.0, 0.0, 1.0], star_tarf)
        rotation = axis / np.linalg.norm(axis) * np.arctan2(np.linalg.norm(axis), star_tarf[2])
        target = dcm_from_rotation_angles(rotation) @ estimate
        yield from self._command('mtbs_inertial', m.quaternion_stamped(0, 'irf', quaternion_from_dcm(target)))
        yield from self._locked()

    def _until(self, elapsed_s):
        """Wait until sim time ``elapsed_s`` (no timeout: the plan sets the pace)."""
        while self.stamp_ns < m.seconds_to_ns(elapsed_s):
            yield

    def _hold_for(self, duration_s):
        """Hold the star (the TASCU keeps the attitude) ``duration_s`` while every camera records; (start, end) s.

        The Earth's turn walks the fine drive while the TASCU holds (about 6 deg of LOS in 25 minutes): a drive held
        at its end stop on two joint readings running is pushed there, the telescope rides with the cradle and the
        star is lost, so the sequence ends there with the reason, not with a later step's timeout.
        """
        start_s = self.stamp_ns / m.NS_PER_S
        at_stop_before = ()
        while self.stamp_ns < m.seconds_to_ns(start_s + duration_s):
            at_stop = tuple(axis for axis, joint in zip(('EL', 'XEL', 'LOS'), FD_JOINTS)
                            if abs(self.joints.get(joint, 0.0)) >= mount.FINE_DRIVE_LIMIT_DEG * RAD_PER_DEG * (1 - 1e-9))
            pushed = [axis for axis in at_stop if axis in at_stop_before]
            if pushed:
                held_s = self.stamp_ns / m.NS_PER_S - start_s
                raise CalibrationAbort(
                    f'a hold of {duration_s:g} s: the Earth\'s turn drove the fine drive\'s {pushed[0]} to its '
                    f'+-{mount.FINE_DRIVE_LIMIT_DEG:g} deg end stop after {held_s:.0f} s, where the TASCU cannot hold '
                    'the star; hold shorter there, or start the hold at a LOS angle on the other side of zero')
            at_stop_before = at_stop
            yield
        return start_s, self.stamp_ns / m.NS_PER_S

    def _command_temperature(self, target_c, rate_c_per_h):
        """Set the truth's thermal control to slew to ``target_c`` at ``rate_c_per_h`` (None: its largest) from now on;
        the record of it: command time, target and rate."""
        control = self.scenario.thermal_control if self.scenario is not None else None
        if control is None:  # the campaign's config builder refuses such a plan before the run
            raise CalibrationAbort("a temperature element needs a truth with scenario.thermal_control")
        rate_c_per_h = control.max_rate_c_per_h if rate_c_per_h is None else rate_c_per_h
        self.outbox.append((TOPICS['thermal'].name,
                            m.vector3_stamped(self.stamp_ns, 'tarf', (target_c, rate_c_per_h / 3600.0, 0.0))))
        return {'target_c': target_c, 'rate_c_per_h': rate_c_per_h, 'command_s': self.stamp_ns / m.NS_PER_S}

    def _place_on_detector(self, camera, offset_arcsec):
        """Move the tracked star to ``offset_arcsec`` (x, y) from ``camera``'s centre; its pixel there.

        The first move uses the nominal detector and alignment; the others take out what the true ones
        (and the TASCU's own model) leave, as the star is seen on the detector.
        """
        detector = nominal_detector(camera)
        target_px = np.asarray(detector.center_px) + np.asarray(offset_arcsec) / detector.scale_arcsec_per_px
        for _ in range(_PLACEMENT_MOVES):
            pixel, _ = yield from self._star_frames(camera, 1)
            yield from self._move(centring_rotation_rad(camera, pixel, target_px, np.eye(3)))
        pixel, _ = yield from self._star_frames(camera, 1)
        return pixel

    def _acquire(self, hip):
        """Star into HIPO through the wide fields: FFI centring first, then HIPO (6.2, 6.3)."""
        self.star_hip = hip
        for camera in ('ffi', 'hipo'):
            pixel, _ = yield from self._star_frames(camera, 1)
            yield from self._command('mtbs_centroid', self._point_message(camera, pixel))
            yield from self._locked()
