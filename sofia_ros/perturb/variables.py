"""The recorded variables a shape is written in, one value per row of the perturbed observable.

Rows are the centroids of a camera (every star of every frame, at the frame's header stamp) or the
Imu samples of the gyro box (at their header stamps). Each variable is read from the bag only when
the shape uses it: the encoders (/ta/joint_states, interpolated), the gyro-box temperature (the last
/gyro_box/temperature at or before the row), the accelerometers (the Imu sample itself for gyro
rows, interpolated for camera rows) and the time since the campaign's start (start_utc of /config/scenario),
the time base `sofia compare` uses.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from sofia_ros import messages as m
from sofia_ros.errors import BagError
from sofia_ros.topics import CD_JOINT, FD_JOINTS, GYRO_IMU, GYRO_TEMPERATURE, JOINT_STATES
from sofia_ros.units import DEG_PER_RAD

if TYPE_CHECKING:
    from collections.abc import Iterable, Mapping

    from sofia_ros.bag import BagReader

__all__ = ['CAMERA_SHAPE_VARIABLES', 'GYRO_SHAPE_VARIABLES', 'Rows', 'row_variables']

SPECIFIC_FORCE_VARIABLES = ('specific_force_x_m_per_s2', 'specific_force_y_m_per_s2', 'specific_force_z_m_per_s2')
#: The variables of gyro rows (Imu samples).
GYRO_SHAPE_VARIABLES = ('time_s', 'elevation_deg', 'los_angle_deg', 'temperature_c', *SPECIFIC_FORCE_VARIABLES)
#: The variables of camera rows (one star in one frame).
CAMERA_SHAPE_VARIABLES = (*GYRO_SHAPE_VARIABLES, 'detector_x_px', 'detector_y_px', 'hip')
_JOINT_TOPIC = JOINT_STATES.name


@dataclass(frozen=True, eq=False)
class Rows:
    """The rows of one observable: each row's stamp and the variables the row carries itself."""

    #: (N,) int64 header stamp of each row, ns
    stamp_ns: np.ndarray
    #: variable name -> (N,) values recorded in the row itself (centroid and HIP, or specific force)
    own: Mapping[str, np.ndarray]


def row_variables(bag: BagReader, rows: Rows, names: Iterable[str]) -> dict[str, np.ndarray]:
    """The variables ``names`` (of CAMERA_SHAPE_VARIABLES or GYRO_SHAPE_VARIABLES) at every row, read from the open ``bag``."""
    names = set(names)
    values = {name: rows.own[name] for name in names if name in rows.own}
    origin_ns = int(rows.stamp_ns[0]) if len(rows.stamp_ns) else 0
    row_s = _seconds(rows.stamp_ns, origin_ns)
    if 'time_s' in names:
        values['time_s'] = _seconds(rows.stamp_ns, bag.campaign_epoch_ns())
    if names & {'elevation_deg', 'los_angle_deg'}:
        stamps_ns, joints = _stamped(bag, _JOINT_TOPIC, 'elevation_deg / los_angle_deg',
                                     m.joint_positions_of)
        joint_s = _seconds(stamps_ns, origin_ns)
        for name, joint in (('elevation_deg', CD_JOINT), ('los_angle_deg', FD_JOINTS[2])):
            if name in names:
                values[name] = np.interp(row_s, joint_s, [positions[joint] * DEG_PER_RAD for positions in joints])
    if 'temperature_c' in names:
        stamps_ns, temperatures = _stamped(bag, GYRO_TEMPERATURE.name, 'temperature_c', lambda msg: msg.temperature)
        previous = np.searchsorted(stamps_ns, rows.stamp_ns, side='right') - 1
        values['temperature_c'] = np.asarray(temperatures, dtype=float)[np.clip(previous, 0, None)]
    wanted_forces = [name for name in SPECIFIC_FORCE_VARIABLES if name in names and name not in values]
    if wanted_forces:
        _require(bag, GYRO_IMU.name, 'specific_force_*_m_per_s2')
        imu = bag.imu_arrays(GYRO_IMU.name)
        if len(imu.stamp_ns) == 0:
            raise BagError(f'{GYRO_IMU.name} in bag {bag.path} is empty; specific_force_*_m_per_s2 is read from it')
        imu_s = _seconds(imu.header_stamp_ns, origin_ns)
        for name in wanted_forces:
            axis = SPECIFIC_FORCE_VARIABLES.index(name)
            values[name] = np.interp(row_s, imu_s, imu.linear_acceleration_m_per_s2[:, axis])
    return values


def _seconds(stamp_ns: np.ndarray, origin_ns: int) -> np.ndarray:
    """Seconds from ``origin_ns``, the difference taken in integer ns (exact for absolute UTC stamps)."""
    return (np.asarray(stamp_ns, dtype=np.int64) - np.int64(origin_ns)) / m.NS_PER_S


def _stamped(bag: BagReader, topic: str, variable: str, value_of) -> tuple[np.ndarray, list]:
    """Header stamps (ns, in time order) and values of a topic's messages; BagError if it has none."""
    _require(bag, topic, variable)
    _, messages = bag.messages_by_topic(topic)[topic]
    if not messages:
        raise BagError(f'{topic} in bag {bag.path} is empty; {variable} is read from it')
    stamps_ns = np.array([m.stamp_ns_of(message.header.stamp) for message in messages], dtype=np.int64)
    order = np.argsort(stamps_ns, kind='stable')
    return stamps_ns[order], [value_of(messages[index]) for index in order]


def _require(bag: BagReader, topic: str, variable: str) -> None:
    """BagError naming the variable if the bag lacks ``topic``."""
    if topic not in {info.name for info in bag.topics}:
        raise BagError(f'bag {bag.path} lacks {topic}, which {variable} is read from; '
                       'write the shape without it or perturb a campaign bag recorded by `sofia run`')
