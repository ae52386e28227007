"""What a campaign bag measured, as arrays for `sofia compare` (no /truth topic is read).

Per camera frame and star: the centroid, its stamp, the coarse-drive elevation, the fine-drive
LOS angle, the gyro-box temperature and the TASCU motion status at that time; the 400 Hz gyro
samples with the temperature of their tick; the TASCU's first attitude (a starting guess only)
and the scenario (site and epoch, as the logbook records them).

`sofia compare` reads them through a cache of decoded observations (compare.cache) made active with
``observation_cache``; without one (the library, the tests) ``read_observations`` decodes the bag.
"""

from __future__ import annotations

import dataclasses
import weakref
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from os import PathLike
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from sofia_ros import messages as m
from sofia_ros.bag import BagReader
from sofia_ros.compare.predict import tick_means
from sofia_ros.compare.steps import StepStore
from sofia_ros.errors import BagError, ConfigError
from sofia_ros.frames import dcm_from_quaternion
from sofia_ros.scenario import Scenario, scenario_from_document
from sofia_ros.sensors.gyro_noise import within_tick_rate_sigma_rad_per_s
from sofia_ros.sensors.imager_model import CAMERAS, nominal_detector
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
from sofia_ros.units import DEG_PER_RAD

__all__ = ['MOTION_STATES', 'READER_VERSION', 'Centroids', 'GyroSamples', 'ObservationSource', 'Observations',
           'content_key', 'decode_observations', 'keyed', 'observation_cache', 'read_observations', 'record_fields',
           'step_store']

#: The version of what decode_observations returns. Bump it whenever the decoding or the dataclasses below
#: change: caches of decoded observations (compare.cache) written by another version are then decoded again.
READER_VERSION = 2

#: TASCU motion states (6.3), coded by index in Centroids.motion_code.
MOTION_STATES = ('transient', 'settled', 'locked')
REQUIRED_TOPICS = (GYRO_IMU.name, GYRO_TEMPERATURE.name, JOINT_STATES.name,
                   TASCU_ATTITUDE.name, SCENARIO_DOCUMENT.name)


@dataclass(frozen=True, eq=False)
class Centroids:
    """One row per star per frame, sorted by camera then stamp."""

    cameras: tuple
    camera_index: np.ndarray
    hip: np.ndarray
    measured_px: np.ndarray
    stamp_s: np.ndarray
    frame_index: np.ndarray
    elevation_deg: np.ndarray
    fd_los_deg: np.ndarray
    temperature_c: np.ndarray
    motion_code: np.ndarray

    def __len__(self):
        return len(self.hip)

    def arcsec_per_px(self) -> np.ndarray:
        """Nominal image scale of each row's camera (Table 2.6, 3.3.1).

        Returns:
            One scale per row, in arcsec per pixel.
        """
        scales = np.array([nominal_detector(camera).scale_arcsec_per_px for camera in self.cameras])
        return scales[self.camera_index]


@dataclass(frozen=True, eq=False)
class GyroSamples:
    """The 400 Hz GYRF samples' times and white rate noise, the ticks they belong to, and per tick their mean rate,
    mean time, count, temperature and specific force.

    The samples' rates are not kept: beyond the tick means, the angle random walk alone read them (55 MB of a
    star hop's 86 MB of observations, held by every compare and shared with its workers).
    """

    time_s: np.ndarray
    #: The rates' white noise per axis, from sample-to-sample differences within ticks (sensors.gyro_noise).
    within_tick_rate_sigma_rad_per_s: np.ndarray
    within_tick_difference_count: int
    tick_end_s: np.ndarray
    tick_temperature_c: np.ndarray
    tick_start_index: np.ndarray
    sample_period_s: float
    tick_mean_rates_gyrf_rad_per_s: np.ndarray
    tick_mean_time_s: np.ndarray
    tick_sample_count: np.ndarray
    #: Mean accelerometer specific force per tick, in the gyro box's axes (m/s^2).
    tick_mean_specific_force_m_per_s2: np.ndarray


@dataclass(frozen=True, eq=False)
class Observations:
    """Everything `sofia compare` reads from one bag."""

    bag_path: Path
    scenario: Scenario
    centroids: Centroids
    gyro: GyroSamples
    initial_time_s: float
    initial_tarf_from_irf: np.ndarray
    move_start_s: np.ndarray
    calibration_result: str | None = None


#: Observations whose content a bag's cache key stands for (compare.cache.bag_key), by object: a field would travel
#: into a copy with other arrays (dataclasses.replace), and the copy would pass for the bag it no longer is.
_CONTENT_KEYS: weakref.WeakKeyDictionary[Observations, str] = weakref.WeakKeyDictionary()


def record_fields(observations: Observations) -> Iterator[tuple[str, Any]]:
    """Every field of the observations, of their centroids and of their gyro samples: (name, value).

    Args:
        observations: the observations.

    Yields:
        (field name, value), the records in that order.
    """
    for record in (observations, observations.centroids, observations.gyro):
        for field in dataclasses.fields(record):
            yield field.name, getattr(record, field.name)


def keyed(observations: Observations, key: str) -> Observations:
    """Record ``observations`` as the decoding of the bag whose cache key is ``key``; their arrays become read-only
    (the key stands for their content, which must then not change).

    Args:
        observations: the observations decoded from the bag, or read from its cache file under ``key``.
        key: the bag's cache key (compare.cache.bag_key).

    Returns:
        ``observations``.
    """
    for _, value in record_fields(observations):
        if isinstance(value, np.ndarray):
            value.flags.writeable = False
    _CONTENT_KEYS[observations] = key
    return observations


def content_key(observations: Observations) -> str | None:
    """The cache key of the bag these observations are the decoding of (keyed), or None.

    Args:
        observations: the observations.

    Returns:
        The key, or None for observations not read through the cache (decoded by the library, made by a test).
    """
    return _CONTENT_KEYS.get(observations)


def _motion_series(table):
    """Log times (s) and MOTION_STATES codes of the TASCU's motion status messages that name a motion state."""
    messages = table.per_message('message')
    codes = np.select([messages == state for state in MOTION_STATES], range(len(MOTION_STATES)), -1)
    known = codes >= 0
    return table.stamp_ns[known] / m.NS_PER_S, codes[known].astype(np.int8)


def _joint_deg(joints, name):
    """Each JointState's position of joint ``name`` in deg; BagError unless every message has it once."""
    per_message = np.repeat(np.arange(len(joints)), joints.counts['name[]'])
    at = np.flatnonzero(joints.values['name[]'] == name)
    if (not np.array_equal(joints.counts['name[]'], joints.counts['position[]'])
            or not np.array_equal(per_message[at], np.arange(len(joints)))):
        raise BagError(f'{JOINT_STATES.name} does not give joint {name} a position in every message; '
                       'the bag is damaged')
    return joints.values['position[]'][at] * DEG_PER_RAD


def _centroid_rows(tables):
    """One row per star per frame, camera by camera: camera index, HIP, x and y (px), stamp (s), frame number."""
    stars = np.concatenate([table.per_message('poses') for table in tables]).astype(np.int64)
    cameras = np.concatenate([np.full(len(table), index) for index, table in enumerate(tables)])
    stamps_s = np.concatenate([table.time_ns('header.stamp') for table in tables]) / m.NS_PER_S

    def poses(field):
        return np.concatenate([table.values[f'poses[].position.{field}'] for table in tables])

    # position.z carries the HIP number (messages.centroid_array).
    return {'camera': np.repeat(cameras, stars), 'hip': np.rint(poses('z')), 'x': poses('x'), 'y': poses('y'),
            'stamp': np.repeat(stamps_s, stars), 'frame': np.repeat(np.arange(len(stars)), stars)}


def _gyro_samples(imu, temperature):
    time_s = imu.header_stamp_ns / m.NS_PER_S
    if len(time_s) < 2 or np.any(np.diff(time_s) <= 0):
        raise BagError(f'{GYRO_IMU.name} holds {len(time_s)} samples out of time order; the bag is damaged')
    tick_end_s, temperatures = temperature.time_ns('header.stamp') / m.NS_PER_S, temperature.per_message('temperature')
    if len(tick_end_s) == 0:
        raise BagError(f'{GYRO_TEMPERATURE.name} is empty; `sofia compare` needs the gyro-box tick stamps')
    # A sample in (t_k-1, t_k] belongs to tick k, whose temperature the box used (sim.gyro_box).
    tick = np.minimum(np.searchsorted(tick_end_s, time_s, side='left'), len(tick_end_s) - 1)
    keep = time_s <= tick_end_s[-1]
    tick, time_s = tick[keep], time_s[keep]
    starts = np.searchsorted(tick, np.arange(len(tick_end_s)), side='left')
    period_s = float(np.median(np.diff(time_s)))
    rates = imu.angular_velocity_rad_per_s[keep]
    counts = np.diff(np.append(starts, len(time_s)))
    rate_sigma, difference_count = within_tick_rate_sigma_rad_per_s(time_s, rates, tick_end_s)
    return GyroSamples(time_s, rate_sigma, difference_count, tick_end_s, temperatures, starts, period_s,
                       tick_means(rates, starts), tick_means(time_s[:, None], starts)[:, 0], counts,
                       tick_means(imu.linear_acceleration_m_per_s2[keep], starts))


def _at(stamps_s, series_s, values, what):
    if len(series_s) == 0:
        raise BagError(f'the bag has no {what} samples')
    return np.interp(stamps_s, series_s, values)


class ObservationSource(Protocol):
    """Where read_observations takes a bag's observations from when not decoding it itself (compare.cache)."""

    def read(self, bag_path: Path, decode: Callable[[Path], Observations]) -> Observations:
        """The observations of a bag, decoded only where the source has none for the bag as it is.

        Args:
            bag_path: the bag directory.
            decode: decodes the bag (decode_observations).

        Returns:
            The bag's Observations.
        """


    def step_store(self, bag_path: Path) -> StepStore:
        """Where the ledger's steps of a bag the source has read are kept (compare.steps).

        Args:
            bag_path: the bag directory, as read.

        Returns:
            The StepStore.
        """


_ACTIVE_SOURCE: ContextVar[ObservationSource | None] = ContextVar('observation_source', default=None)


@contextmanager
def observation_cache(source: ObservationSource | None) -> Iterator[None]:
    """Within the block, read_observations reads through ``source``.

    A context rather than an argument: `sofia compare` reaches read_observations through compare.run's
    compare_bag, which the cache need not know about.

    Args:
        source: where the observations come from (compare.cache.ObservationCache), or None to decode every time.

    Yields:
        Nothing; the block runs with ``source`` active.
    """
    token = _ACTIVE_SOURCE.set(source)
    try:
        yield
    finally:
        _ACTIVE_SOURCE.reset(token)


def step_store(bag_path: str | PathLike[str]) -> StepStore:
    """Where the ledger's steps of a bag are kept: beside its cached observations where an observation cache is
    active, else in this process's memory (compare.steps).

    Args:
        bag_path: the bag directory, as read.

    Returns:
        The StepStore.
    """
    source = _ACTIVE_SOURCE.get()
    return StepStore() if source is None else source.step_store(Path(bag_path))


def read_observations(bag_path: str | PathLike[str]) -> Observations:
    """The observables of a campaign bag, through the active observation_cache if there is one, else decoded.

    Args:
        bag_path: the bag directory.

    Returns:
        The bag's Observations.
    """
    source = _ACTIVE_SOURCE.get()
    if source is None:
        return decode_observations(Path(bag_path))
    return source.read(Path(bag_path), decode_observations)


def decode_observations(bag_path: str | PathLike[str]) -> Observations:
    """The observables of a campaign bag, decoded from its messages.

    Args:
        bag_path: the bag directory.

    Returns:
        The bag's Observations.

    Raises:
        BagError: the bag cannot be read, lacks a topic compare needs (named, with how to get it) or holds
            no usable star or attitude.
    """
    bag_path = Path(bag_path)
    try:
        # Campaign time: stamps in s since the scenario's start (float64 keeps them exact to the ns).
        with BagReader(bag_path, campaign_time=True) as bag:
            names = {topic.name for topic in bag.topics}
            missing = [topic for topic in REQUIRED_TOPICS if topic not in names]
            if missing:
                raise BagError(f'{bag_path} lacks {", ".join(missing)}; `sofia compare` needs a campaign bag '
                               'recorded by `sofia run alignment` (or star-hop)')
            cameras = tuple(camera for camera in CAMERAS if CENTROIDS[camera].name in names)
            if not cameras:
                raise BagError(f'{bag_path} has no /<camera>/centroids topic; nothing to compare')
            scenario = scenario_from_document(bag.document(SCENARIO_DOCUMENT.name))
            camera_topics = [CENTROIDS[camera].name for camera in cameras]
            tables = (GYRO_TEMPERATURE.name, JOINT_STATES.name, *camera_topics,
                      *(topic for topic in (MOTION_STATUS.name,) if topic in names))
            results = [topic for topic in (CALIBRATION_RESULT.name,) if topic in names]
            records = bag.messages_by_topic(GYRO_IMU.name, *tables, *results, imu=(GYRO_IMU.name,), columns=tables)
            # Only the TASCU's first attitude is used (a starting guess): not every tick's decoded.
            first_attitude = next(bag.messages(TASCU_ATTITUDE.name), None)
    except ConfigError as err:
        raise BagError(f'{bag_path}: {err}') from err
    rows = _centroid_rows([records[topic] for topic in camera_topics])
    gyro = _gyro_samples(records[GYRO_IMU.name], records[GYRO_TEMPERATURE.name])
    joints = records[JOINT_STATES.name]
    joint_s = joints.time_ns('header.stamp') / m.NS_PER_S
    if MOTION_STATUS.name in records:
        motion_s, motion_codes = _motion_series(records[MOTION_STATUS.name])
    else:
        motion_s, motion_codes = np.empty(0), np.empty(0, dtype=np.int8)
    if len(rows['hip']) == 0:
        raise BagError(f'{bag_path}: the cameras recorded no star; nothing to compare')
    if first_attitude is None:
        raise BagError(f'{bag_path}: {TASCU_ATTITUDE.name} is empty; the TASCU never ran')
    attitude = first_attitude[2]
    initial_time_s = m.stamp_ns_of(attitude.header.stamp) / m.NS_PER_S
    # Frames must lie where the gyros cover them: after the first attitude, before the last tick.
    keep = (rows['stamp'] > initial_time_s) & (rows['stamp'] < gyro.tick_end_s[-1])
    rows = {key: values[keep] for key, values in rows.items()}
    stamps = rows['stamp']
    elevation_deg = _at(stamps, joint_s, _joint_deg(joints, CD_JOINT), 'joint-state')
    fd_los_deg = _at(stamps, joint_s, _joint_deg(joints, FD_JOINTS[2]), 'joint-state')
    temperature_c = _at(stamps, gyro.tick_end_s, gyro.tick_temperature_c, 'temperature')
    if len(motion_s):
        motion_code = motion_codes[np.clip(np.searchsorted(motion_s, stamps, side='right') - 1, 0, None)]
    else:
        motion_code = np.full(len(stamps), MOTION_STATES.index('transient'), dtype=np.int8)
    centroids = Centroids(cameras, rows['camera'].astype(int), rows['hip'].astype(np.int64),
                          np.column_stack([rows['x'], rows['y']]), stamps, rows['frame'].astype(int),
                          elevation_deg, fd_los_deg, temperature_c, motion_code)
    transient = motion_codes == MOTION_STATES.index('transient')
    move_start_s = motion_s[transient & ~np.concatenate([[False], transient[:-1]])]
    results = records.get(CALIBRATION_RESULT.name, ([], []))[1]
    return Observations(bag_path, scenario, centroids, gyro, initial_time_s,
                        dcm_from_quaternion(m.quaternion_xyzw_of(attitude.quaternion)),
                        move_start_s, results[-1].data if results else None)
