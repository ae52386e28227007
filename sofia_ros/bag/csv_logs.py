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
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from sofia_ros import messages as m
from sofia_ros.bag import BagReader
from sofia_ros.bag.writer import BagWriter
from sofia_ros.errors import ConfigError
from sofia_ros.frames import AXES
from sofia_ros.graph_nodes import CAMERAS
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
_MOTION_NAME = 'motion_status'


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


def _read_csv(path, columns, optional_columns=()):
    """Rows of a CSV log as dicts; ConfigError names the file, line and problem."""
    try:
        with open(path, newline='') as stream:
            reader = csv.DictReader(stream)
            header = reader.fieldnames or []
            missing = [column for column in columns if column not in header]
            if missing:
                raise ConfigError(f'{path}: missing column {missing[0]!r} (needs {", ".join(columns)})')
            unknown = [column for column in header if column not in columns and column not in optional_columns]
            if unknown:
                raise ConfigError(f'{path}: unknown column {unknown[0]!r} (known: '
                                  f'{", ".join((*columns, *optional_columns))})')
            rows = list(reader)
    except OSError as err:
        raise ConfigError(f'cannot read {path}: {err.strerror}; check the directory') from err
    if not rows:
        raise ConfigError(f'{path}: no rows; a log needs at least one line after the header')
    return rows


def _parsed(path, rows, column, kind):
    try:
        return [kind(row[column]) for row in rows]
    except (TypeError, ValueError) as err:
        line = next(index for index, row in enumerate(rows, start=2) if not _parses(row[column], kind))
        raise ConfigError(f'{path} line {line}: {column} = {rows[line - 2][column]!r} is not a '
                          f'{"number" if kind is float else "whole number of ns"}') from err


def _parses(value, kind):
    try:
        kind(value)
    except (TypeError, ValueError):
        return False
    return True


def import_csv_logs(directory, bag_path):
    """Write the CSV logs of ``directory`` into a new rosbag2 MCAP bag through BagWriter (public API only)."""
    directory = Path(directory)
    if not directory.is_dir():
        raise ConfigError(f'{directory} is not a directory of CSV logs; see `sofia import --help`')
    scenario_path = directory / 'scenario.yaml'
    try:
        scenario = scenario_path.read_text()
    except OSError as err:
        raise ConfigError(f'cannot read {scenario_path}: {err.strerror}; the logbook (site, start, heading) '
                          'is needed') from err
    tables = {}
    for name, columns in CSV_COLUMNS.items():
        path = directory / name
        if name in _OPTIONAL and not path.exists():
            continue
        tables[name] = _read_csv(path, columns, _ACCELERATION if name == 'gyro.csv' else ())
    gyro = tables['gyro.csv']
    stamps = np.array(_parsed(directory / 'gyro.csv', gyro, 'time_ns', int), dtype=np.int64)
    if np.any(np.diff(stamps) <= 0):
        raise ConfigError(f'{directory / "gyro.csv"}: time_ns must increase from row to row')
    if stamps[0] < 0 or stamps[-1] >= _STAMP_LIMIT_NS:
        raise ConfigError(f'{directory / "gyro.csv"}: time_ns must be ns since 1970-01-01 UTC, before 2038-01-19 '
                          '(what the int32 seconds of a ROS stamp hold)')
    rates = np.column_stack([_parsed(directory / 'gyro.csv', gyro, f'{axis}_rad_per_s', float) for axis in AXES])
    forces = (np.column_stack([_parsed(directory / 'gyro.csv', gyro, column, float) for column in _ACCELERATION])
              if _ACCELERATION[0] in gyro[0] else np.zeros_like(rates))
    first_ns = int(stamps[0])
    result = directory / 'calibration_result.yaml'
    with BagWriter(bag_path) as bag:
        bag.add_topic(SCENARIO_DOCUMENT.name, 'std_msgs/msg/String', latched=True)
        bag.write_document(SCENARIO_DOCUMENT.name, scenario, first_ns)
        bag.add_topic(GYRO_IMU.name, GYRO_IMU.msgtype)
        bag.write_rows(GYRO_IMU.name, m.imu_block_rows(m.ImuBlock('gyrf', stamps, rates, forces)), stamps)
        _write_rows(bag, directory, tables)
        if result.exists():
            bag.add_topic(CALIBRATION_RESULT.name, 'std_msgs/msg/String', latched=True)
            bag.write_message(CALIBRATION_RESULT.name, m.string_msg(result.read_text()), int(stamps[-1]))
    return Path(bag_path)


def _write_rows(bag, directory, tables):
    def each(name):
        rows = tables[name]
        times = _parsed(directory / name, rows, 'time_ns', int)
        return zip(times, rows)

    def floats(name, row, columns):
        try:
            return [float(row[column]) for column in columns]
        except ValueError as err:
            raise ConfigError(f'{directory / name}: a value of {", ".join(columns)} is not a number') from err

    bag.add_topic(GYRO_TEMPERATURE.name, GYRO_TEMPERATURE.msgtype)
    for stamp, row in each('gyro_temperature.csv'):
        bag.write_message(GYRO_TEMPERATURE.name,
                          m.temperature_msg(stamp, 'gyrf', floats('gyro_temperature.csv', row, ['temperature_c'])[0]),
                          stamp)
    topic = JOINT_STATES
    bag.add_topic(topic.name, topic.msgtype)
    for stamp, row in each('joints.csv'):
        values = floats('joints.csv', row, [f'{joint}_rad' for joint in _JOINTS])
        bag.write_message(topic.name, m.joint_state(stamp, dict(zip(_JOINTS, values))), stamp)
    topic = TASCU_ATTITUDE
    bag.add_topic(topic.name, topic.msgtype)
    for stamp, row in each('attitude.csv'):
        bag.write_message(topic.name, m.quaternion_stamped(stamp, 'irf', floats('attitude.csv', row,
                                                                                ('qx', 'qy', 'qz', 'qw'))), stamp)
    if 'motion_status.csv' in tables:
        topic = MOTION_STATUS
        bag.add_topic(topic.name, topic.msgtype)
        for stamp, row in each('motion_status.csv'):
            bag.write_message(topic.name, m.status_msg(_MOTION_NAME, row['state']), stamp)
    frames = {}
    for stamp, row in each('centroids.csv'):
        camera = row['camera']
        if camera not in CAMERAS:
            raise ConfigError(f'{directory / "centroids.csv"}: unknown camera {camera!r} (known: {", ".join(CAMERAS)})')
        stars = frames.setdefault((camera, stamp), [])
        if row['hip'] != '':
            x_px, y_px = floats('centroids.csv', row, ('x_px', 'y_px'))
            stars.append(_Centroid(int(row['hip']), x_px, y_px))
    for camera in CAMERAS:
        keys = sorted(key for key in frames if key[0] == camera)
        if not keys:
            continue
        bag.add_topic(CENTROIDS[camera].name, 'geometry_msgs/msg/PoseArray')
        for _, stamp in keys:
            bag.write_message(CENTROIDS[camera].name, m.centroid_array(stamp, camera, frames[(camera, stamp)]), stamp)


class _Centroid:
    """One star of a frame for messages.centroid_array."""

    __slots__ = ('hip', 'x_px', 'y_px')

    def __init__(self, hip, x_px, y_px):
        self.hip, self.x_px, self.y_px = hip, x_px, y_px


