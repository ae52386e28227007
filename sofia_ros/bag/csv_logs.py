"""Plain CSV logs <-> the campaign topics `sofia compare` reads: `sofia import` (and the export a test round-trips).

A directory of logs, one file per sensor, units in the column names, times in integer ns of the
logging clock (the bag's stamps):

- ``gyro.csv``: ``time_ns, el_rad_per_s, xel_rad_per_s, los_rad_per_s`` (GYRF rates, every sample;
  optional ``el_m_per_s2, xel_m_per_s2, los_m_per_s2``, the accelerometers)
- ``gyro_temperature.csv``: ``time_ns, temperature_c`` (gyro box, once per TASCU cycle)
- ``joints.csv``: ``time_ns, cd_elevation_rad, fd_el_rad, fd_xel_rad, fd_los_rad`` (encoders)
- ``attitude.csv``: ``time_ns, qx, qy, qz, qw`` (TASCU attitude, scalar last; only the first row is
  used, as a starting guess)
- ``centroids.csv``: ``camera, time_ns, hip, x_px, y_px`` (one row per star per frame; a frame with no
  star is one row with ``hip`` empty)
- ``motion_status.csv`` (optional): ``time_ns, state`` (transient / settled / locked)
- ``scenario.yaml``: the logbook (site, start UTC, heading: the /config/scenario document)
- ``calibration_result.yaml`` (optional): the star hop's hold windows (/calibration/result)

Floats are written with 17 significant digits, so an export and import reproduce the bag's values.

The import reads every log whole and checks it before it begins the bag (one line naming the file,
line and fix otherwise): times from the logbook's start_utc to before 2038, increasing in every log
(in the centroids', not decreasing within a camera, a frame's stars sharing one, each star once a frame);
rates, accelerations, joint angles and temperatures finite and within physical bounds; unit
quaternions; centroids on their camera's detector, of stars in the Hipparcos 2 catalogue; known
motion states; the logbook a scenario `sofia compare` can read. A bag it fails to finish is removed.
"""

from __future__ import annotations

import csv
import functools
import io
import math
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from sofia_ros import messages as m
from sofia_ros.bag import BagReader
from sofia_ros.bag.timebase import epoch_ns_of
from sofia_ros.bag.writer import BagWriter
from sofia_ros.config import MAX_CONFIG_BYTES, safe_load_limited
from sofia_ros.control.servo import LOCKED, SETTLED, TRANSIENT
from sofia_ros.errors import ConfigError, OutputError, UnknownStarError
from sofia_ros.frames import AXES, QUATERNION_NORM_TOLERANCE
from sofia_ros.graph_nodes import CAMERAS
from sofia_ros.input_files import read_text_capped
from sofia_ros.output_files import describe_os_error
from sofia_ros.scenario import scenario_from_document
from sofia_ros.sensors.imager_model import nominal_detector
from sofia_ros.sky.catalogue import star_by_hip
from sofia_ros.topics import (
    CALIBRATION_RESULT,
    CD_JOINT,
    CENTROIDS,
    FD_JOINTS,
    GYRO_IMU,
    GYRO_TEMPERATURE,
    JOINT_STATES,
    MOTION_STATUS,
    SCENARIO_DOCUMENT,
    TASCU_ATTITUDE,
)

__all__ = ['export_csv_logs', 'import_csv_logs', 'CSV_COLUMNS']

_JOINTS = (CD_JOINT, *FD_JOINTS)
CSV_COLUMNS = {
    'gyro.csv': ('time_ns', *(f'{axis}_rad_per_s' for axis in AXES)),
    'gyro_temperature.csv': ('time_ns', 'temperature_c'),
    'joints.csv': ('time_ns', *(f'{joint}_rad' for joint in _JOINTS)),
    'attitude.csv': ('time_ns', 'qx', 'qy', 'qz', 'qw'),
    'centroids.csv': ('camera', 'time_ns', 'hip', 'x_px', 'y_px'),
    'motion_status.csv': ('time_ns', 'state'),
}
_OPTIONAL = ('motion_status.csv',)
#: The first time a ROS stamp (builtin_interfaces/Time, int32 seconds) cannot hold: 2038-01-19 03:14:08 UTC.
_STAMP_LIMIT_NS = 2**31 * 1_000_000_000
_ACCELERATION = tuple(f'{axis}_m_per_s2' for axis in AXES)
_QUATERNION = ('qx', 'qy', 'qz', 'qw')
_MOTION_NAME = 'motion_status'
_MOTION_STATES = (TRANSIENT, SETTLED, LOCKED)
#: The keys `sofia compare` cannot do without (sofia_ros.scenario.scenario_from_document).
_SCENARIO_KEYS = ('latitude_deg', 'start_utc', 'heading_deg')
#: Largest CSV log read: a 10-hour flight of 400 Hz gyro rows as the export writes them (~130 bytes) is 1.9 GB.
_MAX_CSV_BYTES = 2 << 30
# Physical bounds (low, high, unit) of the logged values: beyond them a value is a logging fault, and
# NaN or infinity would only surface as a NaN fit in `sofia compare`.
#: the telescope turns at a few degrees per second at most; 10 rad/s is beyond any gyro's range
_RATE_BOUNDS = (-10.0, 10.0, 'rad/s')
#: an aircraft in flight stays within a few g; 200 m/s^2 (20 g) is beyond the gyro box's accelerometers
_ACCELERATION_BOUNDS = (-200.0, 200.0, 'm/s^2')
#: an encoder reads an angle within one turn
_JOINT_BOUNDS = (-2 * math.pi, 2 * math.pi, 'rad')
#: the gyro box of an aircraft, from a cold soak at altitude to a hot ramp
_TEMPERATURE_BOUNDS = (-100.0, 100.0, 'deg C')
#: each component of a unit quaternion (the norm is checked as well)
_QUATERNION_BOUNDS = (-1.0 - QUATERNION_NORM_TOLERANCE, 1.0 + QUATERNION_NORM_TOLERANCE, '')
#: how far off the chip a centroid may lie: one pixel, as the imager model selects its stars
_PIXEL_MARGIN_PX = 1.0
#: the highest Hipparcos number (HIP 1 to 120416; Hipparcos 2 leaves some unused)
_LAST_HIP = 120416


def _number(value):
    return repr(float(value))


def export_csv_logs(bag_path, directory):
    """Write the campaign topics of a bag as the CSV logs of this module (for round trips and users)."""
    directory = Path(directory)
    directory.mkdir(parents=True, exist_ok=False)
    with BagReader(bag_path) as bag:
        names = {topic.name for topic in bag.topics}
        cameras = [camera for camera in CAMERAS if CENTROIDS[camera].name in names]
        optional = [topic for topic in (MOTION_STATUS.name, CALIBRATION_RESULT.name) if topic in names]
        records = bag.messages_by_topic(GYRO_IMU.name, GYRO_TEMPERATURE.name, JOINT_STATES.name,
                                        TASCU_ATTITUDE.name, *optional,
                                        *(CENTROIDS[camera].name for camera in cameras), imu=(GYRO_IMU.name,))
        (directory / 'scenario.yaml').write_text(bag.document(SCENARIO_DOCUMENT.name))
    imu = records[GYRO_IMU.name]
    with open(directory / 'gyro.csv', 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(CSV_COLUMNS['gyro.csv'] + _ACCELERATION)
        for stamp, rate, force in zip(imu.header_stamp_ns.tolist(), imu.angular_velocity_rad_per_s.tolist(),
                                      imu.linear_acceleration_m_per_s2.tolist()):
            writer.writerow([stamp, *map(_number, rate), *map(_number, force)])

    def rows(name, topic, values_of):
        with open(directory / name, 'w', newline='') as stream:
            writer = csv.writer(stream)
            writer.writerow(CSV_COLUMNS[name])
            for log_ns, message in zip(*records[topic]):
                stamp = m.stamp_ns_of(message.header.stamp) if hasattr(message, 'header') else log_ns
                writer.writerow([stamp, *values_of(message)])

    rows('gyro_temperature.csv', GYRO_TEMPERATURE.name, lambda msg: [_number(msg.temperature)])
    rows('joints.csv', JOINT_STATES.name,
         lambda msg: [_number(m.joint_positions_of(msg)[joint]) for joint in _JOINTS])
    rows('attitude.csv', TASCU_ATTITUDE.name, lambda msg: map(_number, m.quaternion_xyzw_of(msg)))
    if MOTION_STATUS.name in records:
        rows('motion_status.csv', MOTION_STATUS.name, lambda msg: [msg.message])
    with open(directory / 'centroids.csv', 'w', newline='') as stream:
        writer = csv.writer(stream)
        writer.writerow(CSV_COLUMNS['centroids.csv'])
        for camera in cameras:
            for message in records[CENTROIDS[camera].name][1]:
                stamp = m.stamp_ns_of(message.header.stamp)
                stars = m.centroids_of(message)
                for hip, x_px, y_px in stars or [('', None, None)]:
                    writer.writerow([camera, stamp, hip, '' if x_px is None else _number(x_px),
                                     '' if y_px is None else _number(y_px)])
    if CALIBRATION_RESULT.name in records and records[CALIBRATION_RESULT.name][1]:
        (directory / 'calibration_result.yaml').write_text(records[CALIBRATION_RESULT.name][1][-1].data)
    return directory


@dataclass(frozen=True)
class _Table:
    """One CSV log read whole: its header, its rows (each as long as the header) and the file line of each."""

    path: Path
    header: tuple[str, ...]
    rows: list[list[str]]
    lines: list[int]

    def has(self, column: str) -> bool:
        return column in self.header

    def texts(self, column: str) -> list[str]:
        index = self.header.index(column)
        return [row[index] for row in self.rows]

    def line_error(self, row: int, problem: str) -> ConfigError:
        """The one-line refusal of row ``row`` (0 = the first after the header)."""
        return ConfigError(f'{self.path} line {self.lines[row]}: {problem}; correct or remove the row')

    def value_error(self, row: int, column: str, problem: str) -> ConfigError:
        """The refusal of one value, shown as the file has it (cut to 40 characters)."""
        text = self.rows[row][self.header.index(column)]
        shown = repr(text[:40]) + ('...' if len(text) > 40 else '')
        return self.line_error(row, f'{column} = {shown} {problem}')


@dataclass(frozen=True)
class _Logs:
    """Every log of a directory, checked whole and ready to write: nothing is written before all of them pass."""

    scenario: str
    gyro_stamps: np.ndarray
    rates: np.ndarray
    forces: np.ndarray
    temperature_stamps: list[int]
    temperatures: np.ndarray
    joint_stamps: list[int]
    joints: np.ndarray
    attitude_stamps: list[int]
    quaternions: np.ndarray
    motion: list[tuple[int, str]] | None
    frames: dict[str, list[tuple[int, list[_Centroid]]]]
    calibration_result: str | None


def import_csv_logs(directory, bag_path):
    """Write the CSV logs of ``directory`` into a new rosbag2 MCAP bag through BagWriter (public API only).

    Every log is read and checked first (ConfigError naming the file, line and fix), so a refused
    import begins no bag; a bag whose writing fails (a full disk, an interrupt) is removed, so the
    same ``bag_path`` can be given again.
    """
    directory = Path(directory)
    if not directory.is_dir():
        raise ConfigError(f'{directory} is not a directory of CSV logs; see `sofia import --help`')
    logs = _read_logs(directory)
    writer = BagWriter(bag_path)  # refuses an existing path before it creates anything
    try:
        with writer as bag:
            _write_logs(bag, logs)
    except OutputError as err:
        _remove_unfinished_bag(writer.path)
        cause = err.__cause__
        reason = describe_os_error(cause, filename=writer.path)[0] if isinstance(cause, OSError) else str(err)
        raise OutputError(f'cannot write bag {reason}; the unfinished bag was removed, so the import can be '
                          'run again', err.exit_code) from err
    except BaseException:
        _remove_unfinished_bag(writer.path)
        raise
    return Path(bag_path)


def _remove_unfinished_bag(path: Path) -> None:
    """Remove the bag directory an import began: a bag without metadata.yaml that only blocks a retry."""
    shutil.rmtree(path, ignore_errors=True)


def _read_logs(directory: Path) -> _Logs:
    """Read and check every log of ``directory``; ConfigError on the first problem met."""
    scenario, start_ns = _read_scenario(directory / 'scenario.yaml')
    tables = {}
    for name, columns in CSV_COLUMNS.items():
        path = directory / name
        if name in _OPTIONAL and not (path.exists() or path.is_symlink()):
            continue
        tables[name] = _read_table(path, columns, _ACCELERATION if name == 'gyro.csv' else ())
    stamps = {name: _times(table, start_ns) for name, table in tables.items()}
    # Time order, as the gyro's integration needs it: the other logs were sorted silently, a row written twice kept.
    for name in ('gyro.csv', 'gyro_temperature.csv', 'joints.csv', 'attitude.csv', 'motion_status.csv'):
        if name in tables:
            _require_increasing(tables[name], stamps[name])
    gyro = tables['gyro.csv']
    rates = np.column_stack([_numbers(gyro, f'{axis}_rad_per_s', _RATE_BOUNDS) for axis in AXES])
    forces = _accelerations(gyro)
    temperature = tables['gyro_temperature.csv']
    joints = tables['joints.csv']
    attitude = tables['attitude.csv']
    motion = tables.get('motion_status.csv')
    result = directory / 'calibration_result.yaml'
    return _Logs(
        scenario=scenario,
        gyro_stamps=np.array(stamps['gyro.csv'], dtype=np.int64), rates=rates, forces=forces,
        temperature_stamps=stamps['gyro_temperature.csv'],
        temperatures=_numbers(temperature, 'temperature_c', _TEMPERATURE_BOUNDS),
        joint_stamps=stamps['joints.csv'],
        joints=np.column_stack([_numbers(joints, f'{joint}_rad', _JOINT_BOUNDS) for joint in _JOINTS]),
        attitude_stamps=stamps['attitude.csv'], quaternions=_quaternions(attitude),
        motion=None if motion is None else list(zip(stamps['motion_status.csv'], _motion_states(motion))),
        frames=_frames(tables['centroids.csv'], stamps['centroids.csv']),
        calibration_result=_read_calibration_result(result) if result.exists() or result.is_symlink() else None,
    )


def _read_scenario(path: Path) -> tuple[str, int]:
    """The logbook's text and its start (ns since the Unix epoch), checked as `sofia compare` will read it."""
    text = read_text_capped(path, MAX_CONFIG_BYTES, 'scenario logbook (YAML)')
    fields = safe_load_limited(text, str(path))
    if not isinstance(fields, dict):
        raise ConfigError(f'{path}: the logbook must be a mapping ({", ".join(_SCENARIO_KEYS)}, ...), got '
                          f'{type(fields).__name__}; see `sofia import --help`')
    missing = [key for key in _SCENARIO_KEYS if key not in fields]
    if missing:
        raise ConfigError(f'{path}: the logbook lacks {missing[0]} (it needs {", ".join(_SCENARIO_KEYS)})')
    try:
        scenario = scenario_from_document(text)  # the keys' ranges and start_utc's timezone
    except ConfigError as err:
        raise ConfigError(f'{path}: {err}') from err
    return text, epoch_ns_of(scenario.start_utc)


def _read_calibration_result(path: Path) -> str:
    """The star hop's result document, checked to be a YAML mapping."""
    text = read_text_capped(path, MAX_CONFIG_BYTES, 'calibration result (YAML)')
    if not isinstance(safe_load_limited(text, str(path)), dict):
        raise ConfigError(f'{path}: not a calibration result (a YAML mapping with hold windows); remove it or '
                          'export it again')
    return text


def _read_table(path: Path, columns: tuple[str, ...], optional_columns: tuple[str, ...] = ()) -> _Table:
    """A CSV log read whole (a regular file under the size cap, UTF-8), its header and row lengths checked."""
    # Excel writes UTF-8 with a byte order mark, which would otherwise become part of the first column's name.
    text = read_text_capped(path, _MAX_CSV_BYTES, 'CSV log').removeprefix('\ufeff')
    reader = csv.reader(io.StringIO(text, newline=''))
    rows, lines = [], []
    try:
        header = tuple(next(reader, ()))
        for row in reader:
            if row:  # a blank line (a trailing one, say) holds no sample
                rows.append(row)
                lines.append(reader.line_num)
    except csv.Error as err:  # a field beyond csv.field_size_limit(), a stray quote
        raise ConfigError(f'{path} line {reader.line_num}: not a CSV row ({err}); fix the file') from err
    missing = [column for column in columns if column not in header]
    if missing:
        raise ConfigError(f'{path}: missing column {missing[0]!r} (needs {", ".join(columns)})')
    known = (*columns, *optional_columns)
    unknown = [column for column in header if column not in known]
    if unknown:
        raise ConfigError(f'{path}: unknown column {unknown[0]!r} (known: {", ".join(known)})')
    repeated = [column for index, column in enumerate(header) if column in header[:index]]
    if repeated:
        raise ConfigError(f'{path}: column {repeated[0]!r} appears twice in the header; keep one')
    if not rows:
        raise ConfigError(f'{path}: no rows; a log needs at least one line after the header')
    table = _Table(path, header, rows, lines)
    for row, values in enumerate(rows):
        if len(values) != len(header):
            raise table.line_error(row, f'{len(values)} values where the header has {len(header)} columns')
    return table


def _parsed(table: _Table, column: str, kind, what: str) -> list:
    """The column's values as ``kind`` (int or float); ConfigError naming the first that is not one."""
    values = []
    for row, text in enumerate(table.texts(column)):
        try:
            values.append(kind(text))
        except ValueError as err:  # int() also refuses over 4300 digits
            raise table.value_error(row, column, f'is not {what}') from err
    return values


def _times(table: _Table, start_ns: int) -> list[int]:
    """The time_ns column: whole ns from the logbook's start_utc to before 2038-01-19 (a ROS stamp's int32 s)."""
    stamps = _parsed(table, 'time_ns', int, 'a whole number of ns')
    for row, stamp in enumerate(stamps):
        if not start_ns <= stamp < _STAMP_LIMIT_NS:
            raise table.value_error(row, 'time_ns', 'must be ns since 1970-01-01 UTC, from the logbook\'s start_utc '
                                    f'({start_ns}) to before 2038-01-19 (what the int32 seconds of a ROS stamp hold)')
    return stamps


def _require_increasing(table: _Table, stamps: list[int]) -> None:
    """Refuse a sample whose time is not after the one before it (the gyro's integration needs time order)."""
    steps = np.diff(np.array(stamps, dtype=np.int64))
    if np.any(steps <= 0):
        row = int(np.argmax(steps <= 0)) + 1
        raise table.value_error(row, 'time_ns', 'is not after the row before it; time_ns must increase from row '
                                'to row')


def _numbers(table: _Table, column: str, bounds: tuple[float, float, str]) -> np.ndarray:
    """The column as floats inside ``bounds`` (low, high, unit); NaN and infinities are outside any."""
    low, high, unit = bounds
    values = np.array(_parsed(table, column, float, 'a number'), dtype=float)
    outside = ~((values >= low) & (values <= high))
    if np.any(outside):
        raise table.value_error(int(np.argmax(outside)), column,
                                f'is not a number in [{low:g}, {high:g}]{f" {unit}" if unit else ""}')
    return values


def _accelerations(gyro: _Table) -> np.ndarray:
    """The optional accelerometer columns of gyro.csv (all three or none), zero when absent."""
    given = [column for column in _ACCELERATION if gyro.has(column)]
    if not given:
        return np.zeros((len(gyro.rows), len(_ACCELERATION)))
    if len(given) < len(_ACCELERATION):
        missing = next(column for column in _ACCELERATION if column not in given)
        raise ConfigError(f'{gyro.path}: missing column {missing!r} (the accelerometers come as '
                          f'{", ".join(_ACCELERATION)} together, or not at all)')
    return np.column_stack([_numbers(gyro, column, _ACCELERATION_BOUNDS) for column in _ACCELERATION])


def _quaternions(attitude: _Table) -> np.ndarray:
    """The attitude rows as unit quaternions (scalar last), within frames.QUATERNION_NORM_TOLERANCE of |q| = 1."""
    quaternions = np.column_stack([_numbers(attitude, column, _QUATERNION_BOUNDS) for column in _QUATERNION])
    norms = np.sqrt(np.sum(quaternions**2, axis=1))
    off = np.abs(norms - 1.0) > QUATERNION_NORM_TOLERANCE
    if np.any(off):
        row = int(np.argmax(off))
        raise attitude.line_error(row, f'|q| = {norms[row]:.9g} is not a unit quaternion (qx, qy, qz, qw with '
                                  f'|q| within {QUATERNION_NORM_TOLERANCE:g} of 1)')
    return quaternions


def _motion_states(motion: _Table) -> list[str]:
    """The state column: each one of the TASCU's motion states."""
    states = motion.texts('state')
    for row, state in enumerate(states):
        if state not in _MOTION_STATES:
            raise motion.value_error(row, 'state', f'is not a motion state (known: {", ".join(_MOTION_STATES)})')
    return states


def _frames(centroids: _Table, stamps: list[int]) -> dict[str, list[tuple[int, list[_Centroid]]]]:
    """camera -> its frames in time order, each (stamp, stars); a row with hip empty is a frame without a star."""
    indices = [centroids.header.index(column) for column in ('camera', 'hip', 'x_px', 'y_px')]
    frames, latest = {}, {}
    for row, (stamp, values) in enumerate(zip(stamps, centroids.rows)):
        camera, hip, x_px, y_px = (values[index] for index in indices)
        if camera not in CAMERAS:
            raise centroids.value_error(row, 'camera', f'is not a camera (known: {", ".join(CAMERAS)})')
        if stamp < latest.get(camera, stamp):
            raise centroids.value_error(row, 'time_ns', f'is before the {camera} row before it; time_ns must not '
                                        'decrease within a camera (the stars of one frame share it)')
        latest[camera] = stamp
        stars = frames.setdefault((camera, stamp), [])
        if hip != '':
            star = _Centroid(_hip(centroids, row, hip), _pixel(centroids, row, 'x_px', x_px, camera),
                             _pixel(centroids, row, 'y_px', y_px, camera))
            if any(other.hip == star.hip for other in stars):
                raise centroids.value_error(row, 'hip', f'is in this {camera} frame twice; give each star of a frame '
                                            'one row')
            stars.append(star)
    by_camera = {}
    for (camera, stamp), stars in sorted(frames.items(), key=lambda item: item[0][1]):
        by_camera.setdefault(camera, []).append((stamp, stars))
    return by_camera


def _hip(centroids: _Table, row: int, text: str) -> int:
    """A HIP number of a star in the Hipparcos 2 catalogue (the one `sofia compare` places stars from)."""
    problem = f'is not a star of the Hipparcos 2 catalogue (HIP 1 to {_LAST_HIP}, some numbers unused)'
    try:
        hip = int(text)
    except ValueError as err:
        raise centroids.value_error(row, 'hip', problem) from err
    if not 1 <= hip <= _LAST_HIP:
        raise centroids.value_error(row, 'hip', problem)
    try:
        _catalogued_star(hip)
    except UnknownStarError as err:
        raise centroids.value_error(row, 'hip', problem) from err
    return hip


@functools.lru_cache(maxsize=None)
def _catalogued_star(hip: int):
    """star_by_hip, looked up once per star: a log names the same few stars in every frame."""
    return star_by_hip(hip)


def _pixel(centroids: _Table, row: int, column: str, text: str, camera: str) -> float:
    """A centroid coordinate on the camera's detector (one pixel of margin, as the imager model selects stars)."""
    detector = nominal_detector(camera)
    size = detector.width_px if column == 'x_px' else detector.height_px
    try:
        value = float(text)
    except ValueError as err:
        raise centroids.value_error(row, column, 'is not a number') from err
    if not -_PIXEL_MARGIN_PX <= value <= size + _PIXEL_MARGIN_PX:
        raise centroids.value_error(row, column, f'is not on the {camera} detector '
                                    f'([{-_PIXEL_MARGIN_PX:g}, {size + _PIXEL_MARGIN_PX:g}] px)')
    return value


def _write_logs(bag: BagWriter, logs: _Logs) -> None:
    """Write the checked logs, topic by topic."""
    first_ns = int(logs.gyro_stamps[0])
    bag.add_topic(SCENARIO_DOCUMENT.name, 'std_msgs/msg/String', latched=True)
    bag.write_document(SCENARIO_DOCUMENT.name, logs.scenario, first_ns)
    bag.add_topic(GYRO_IMU.name, GYRO_IMU.msgtype)
    bag.write_rows(GYRO_IMU.name, m.imu_block_rows(m.ImuBlock('gyrf', logs.gyro_stamps, logs.rates, logs.forces)),
                   logs.gyro_stamps)
    bag.add_topic(GYRO_TEMPERATURE.name, GYRO_TEMPERATURE.msgtype)
    for stamp, temperature in zip(logs.temperature_stamps, logs.temperatures.tolist()):
        bag.write_message(GYRO_TEMPERATURE.name, m.temperature_msg(stamp, 'gyrf', temperature), stamp)
    bag.add_topic(JOINT_STATES.name, JOINT_STATES.msgtype)
    for stamp, values in zip(logs.joint_stamps, logs.joints.tolist()):
        bag.write_message(JOINT_STATES.name, m.joint_state(stamp, dict(zip(_JOINTS, values))), stamp)
    bag.add_topic(TASCU_ATTITUDE.name, TASCU_ATTITUDE.msgtype)
    for stamp, quaternion in zip(logs.attitude_stamps, logs.quaternions.tolist()):
        bag.write_message(TASCU_ATTITUDE.name, m.quaternion_stamped(stamp, 'irf', quaternion), stamp)
    if logs.motion is not None:
        bag.add_topic(MOTION_STATUS.name, MOTION_STATUS.msgtype)
        for stamp, state in logs.motion:
            bag.write_message(MOTION_STATUS.name, m.status_msg(_MOTION_NAME, state), stamp)
    for camera in CAMERAS:
        if camera not in logs.frames:
            continue
        bag.add_topic(CENTROIDS[camera].name, 'geometry_msgs/msg/PoseArray')
        for stamp, stars in logs.frames[camera]:
            bag.write_message(CENTROIDS[camera].name, m.centroid_array(stamp, camera, stars), stamp)
    if logs.calibration_result is not None:
        bag.add_topic(CALIBRATION_RESULT.name, 'std_msgs/msg/String', latched=True)
        bag.write_message(CALIBRATION_RESULT.name, m.string_msg(logs.calibration_result), int(logs.gyro_stamps[-1]))


class _Centroid:
    """One star of a frame for messages.centroid_array."""

    __slots__ = ('hip', 'x_px', 'y_px')

    def __init__(self, hip, x_px, y_px):
        self.hip, self.x_px, self.y_px = hip, x_px, y_px
