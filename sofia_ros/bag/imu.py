"""Bulk decoding of sensor_msgs/Imu CDR into numpy arrays (millions of gyro samples at once).

Imu CDR after the 4-byte encapsulation header: header.stamp (int32 sec, uint32
nanosec), header.frame_id (uint32 length counting the NUL, then the bytes),
padding to 8 bytes, then 37 float64: orientation (4), its covariance (9),
angular_velocity (3), its covariance (9), linear_acceleration (3), its
covariance (9). frame_id is the only variable-length field, so messages of one
length share one layout and decode as columns of a 2-D byte array.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from sofia_ros.errors import InvalidArgumentError

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = ['ImuArrays', 'decode_imu_cdr', 'decode_imu_blocks', 'decode_imu_payloads', 'decode_imu_rows',
           'merge_imu_blocks', 'with_angular_velocity']

_ENCAPSULATION_CDR_LE = (0, 1)
_DOUBLES_BYTES = 37 * 8
_ANGULAR_VELOCITY_OFFSET = (4 + 9) * 8
_LINEAR_ACCELERATION_OFFSET = (4 + 9 + 3 + 9) * 8
# Shortest Imu: with an empty frame_id (just its NUL) the doubles start at body offset 16.
_MIN_BYTES = 4 + 16 + _DOUBLES_BYTES


@dataclass(frozen=True, eq=False)
class ImuArrays:
    """Imu samples of one topic as arrays, one row per message in log-time order."""

    #: (N,) int64 log time of each message (receive time for a recorder).
    stamp_ns: np.ndarray
    #: (N,) int64 header.stamp, the sample time the sensor claims.
    header_stamp_ns: np.ndarray
    #: (N, 3) angular_velocity x, y, z in the message's frame_id.
    angular_velocity_rad_per_s: np.ndarray
    #: (N, 3) linear_acceleration x, y, z in the message's frame_id.
    linear_acceleration_m_per_s2: np.ndarray


def decode_imu_cdr(stamp_ns: Sequence[int], payloads: Sequence[bytes]) -> ImuArrays:
    """Decode little-endian Imu CDR ``payloads`` logged at ``stamp_ns`` into ImuArrays."""
    # Imported here: bag.columns needs rosbags, which a node process decoding its ImuBlocks (messages.py) does not.
    from sofia_ros.bag.columns import payload_blocks

    return decode_imu_blocks(payload_blocks(stamp_ns, payloads))


def decode_imu_blocks(blocks: Sequence[tuple[np.ndarray, np.ndarray]]) -> ImuArrays:
    """Decode (log stamps ns, 2-D uint8 rows of equal-length Imu CDR) blocks into ImuArrays in log-time order."""
    return merge_imu_blocks([(stamps, decode_imu_rows(rows)) for stamps, rows in blocks])


def merge_imu_blocks(blocks: Sequence[tuple[np.ndarray, tuple[np.ndarray, np.ndarray, np.ndarray]]]) -> ImuArrays:
    """ImuArrays in log-time order from (log stamps ns, decode_imu_rows of the block's rows) blocks."""
    decoded = [(stamps, *columns) for stamps, columns in blocks if len(stamps)]
    if not decoded:
        empty = np.empty((0, 3))
        return ImuArrays(np.empty(0, dtype=np.int64), np.empty(0, dtype=np.int64), empty, empty.copy())
    stamps, header_stamps, angular, linear = (np.concatenate(column) for column in zip(*decoded))
    order = np.argsort(stamps, kind='stable')
    if np.all(order[1:] > order[:-1]):  # already in time order (one chunk after another): no copies
        return ImuArrays(stamps, header_stamps, angular, linear)
    return ImuArrays(
        stamp_ns=stamps[order],
        header_stamp_ns=header_stamps[order],
        angular_velocity_rad_per_s=angular[order],
        linear_acceleration_m_per_s2=linear[order],
    )


def with_angular_velocity(block: np.ndarray, angular_velocity_rad_per_s: np.ndarray) -> np.ndarray:
    """Equal-length Imu CDR rows (2-D uint8) with angular_velocity set to the (rows, 3) values, every other byte kept."""
    start = _doubles_start(_row_bytes(block), block.shape[1]) + _ANGULAR_VELOCITY_OFFSET
    rates = np.ascontiguousarray(angular_velocity_rad_per_s, dtype='<f8')
    if rates.shape != (block.shape[0], 3):
        raise InvalidArgumentError(f'need {block.shape[0]} x 3 angular velocities, got {rates.shape}')
    rows = block.copy()
    rows[:, start:start + 24] = rates.view(np.uint8).reshape(-1, 24)
    return rows


def decode_imu_rows(block: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Header stamps (ns), angular velocities (N x 3), linear accelerations (N x 3) of equal-length rows, in row order."""
    return _decoded(_row_bytes(block), block.shape[1])


def _row_bytes(block):
    """bytes_at(offset, width) of 2-D rows: those bytes of every row."""
    return lambda offset, width: block[:, offset:offset + width]


def decode_imu_payloads(raw: np.ndarray, starts: np.ndarray, length: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """decode_imu_rows of the equal-length payloads at ``starts`` of the byte buffer ``raw``, gathering only the
    bytes decoded (a star hop's 0.8 GB of gyro payloads are not copied whole)."""
    return _decoded(lambda offset, width: np.lib.stride_tricks.sliding_window_view(raw, width)[starts + offset],
                    length)


def _decoded(bytes_at, length):
    """decode_imu_rows through ``bytes_at(offset, width)``: those bytes of every payload, (rows, width) uint8."""
    start = _doubles_start(bytes_at, length)

    def column(offset, dtype, count=1):
        return np.ascontiguousarray(bytes_at(offset, np.dtype(dtype).itemsize * count)).view(dtype)

    sec = column(4, '<i4')[:, 0].astype(np.int64)
    nanosec = column(8, '<u4')[:, 0].astype(np.int64)
    return (
        sec * 1_000_000_000 + nanosec,
        column(start + _ANGULAR_VELOCITY_OFFSET, '<f8', 3),
        column(start + _LINEAR_ACCELERATION_OFFSET, '<f8', 3),
    )


def _doubles_start(bytes_at, length: int) -> int:
    """Byte offset of the 37 doubles in equal-length Imu payloads; InvalidArgumentError if they are not Imu CDR."""
    if length < _MIN_BYTES:
        raise InvalidArgumentError(
            f'Imu payload of {length} bytes is shorter than the sensor_msgs/msg/Imu layout'
        )
    if np.any(bytes_at(0, 2) != _ENCAPSULATION_CDR_LE):
        raise InvalidArgumentError(
            'Imu payloads are not little-endian CDR; read them with messages()'
        )
    frame_id_bytes = np.ascontiguousarray(bytes_at(12, 4)).view('<u4')[:, 0].astype(np.int64)
    # Doubles align to 8 bytes counted from the end of the encapsulation header.
    doubles_at = 4 + (12 + frame_id_bytes + 7) // 8 * 8
    if np.any(doubles_at + _DOUBLES_BYTES != length):
        raise InvalidArgumentError(
            'Imu payload length does not match the sensor_msgs/msg/Imu layout'
        )
    return int(doubles_at[0])
