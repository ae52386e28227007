"""The time axis of a bag: campaign time (ns since the scenario's start) in the cores, UTC in the bag.

The node cores and the analysis count time from the campaign's start (sim ns from 0: exact in
int64, and small enough for float64 seconds in fits and periodograms). A bag carries the
campaign's own UTC time, as a recording of the real campaign would: BagWriter(epoch_ns=...) adds
the scenario's start to every log time and to every message stamp that leads its CDR (a Header
or a builtin_interfaces/Time first: Imu, PoseArray, JointState, Clock, ParameterEvent, ...), and
BagReader(campaign_time=True) takes it off again. These two are the only places that convert.
"""

from __future__ import annotations

import datetime as dt
import struct
from functools import cache

import numpy as np

from sofia_ros.errors import InvalidArgumentError

__all__ = ['NS_PER_S', 'epoch_ns_of', 'has_leading_stamp', 'leading_stamps_ns', 'shift_stamp', 'shift_stamps',
           'stamp_fields']

NS_PER_S = 1_000_000_000
_STAMP_TYPES = ('builtin_interfaces/msg/Time', 'std_msgs/msg/Header')
_STAMP = {0: struct.Struct('>iI'), 1: struct.Struct('<iI')}  # by the CDR encapsulation's endianness byte
_EPOCH = dt.datetime(1970, 1, 1, tzinfo=dt.timezone.utc)


def epoch_ns_of(utc: dt.datetime) -> int:
    """ns since the Unix epoch of an aware datetime, exact to the microsecond it carries."""
    delta = utc - _EPOCH
    return (delta.days * 86_400 + delta.seconds) * NS_PER_S + delta.microseconds * 1_000


@cache
def has_leading_stamp(msgtype: str) -> bool:
    """Whether ``msgtype``'s CDR starts with a stamp (sec int32, nanosec uint32 at bytes 4-12)."""
    # Imported here: the rest of this module is what every node process needs (messages.py), the type store
    # (rosbags, 0.1-0.2 CPU-s) only what reads or writes a bag.
    from sofia_ros.bag.msgtypes import TYPESTORE

    _, fields = TYPESTORE.fielddefs[msgtype]
    return bool(fields) and fields[0][1][1] in _STAMP_TYPES


def shift_stamp(data: bytes | memoryview, offset_ns: int) -> bytes:
    """CDR ``data`` whose leading stamp is moved by ``offset_ns``; the rest byte for byte."""
    stamp = _STAMP[data[1]]
    sec, nanosec = stamp.unpack_from(data, 4)
    offset_s, offset_nanosec = divmod(offset_ns, NS_PER_S)
    carry_s, nanosec = divmod(nanosec + offset_nanosec, NS_PER_S)
    try:
        moved = stamp.pack(sec + offset_s + carry_s, nanosec)
    except struct.error as err:  # a stamp on another clock (wall time) moved past 2038
        raise InvalidArgumentError(f'a stamp of {sec} s moved by {offset_ns} ns is beyond what int32 seconds hold '
                                   '(before 1901 or after 2038)') from err
    # Slices and concatenation: about half the time of a bytearray copy (400 Hz samples pass here).
    return bytes(data[:4]) + moved + bytes(data[12:])


def stamp_fields(stamps_ns: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(sec, nanosec) of stamps in ns as builtin_interfaces/Time holds them: little-endian int32 and uint32 arrays;
    InvalidArgumentError for a stamp its int32 seconds cannot hold (before 1901 or after 2038)."""
    sec, nanosec = np.divmod(np.asarray(stamps_ns, dtype=np.int64), NS_PER_S)
    if np.any((sec < -2**31) | (sec >= 2**31)):
        raise InvalidArgumentError('a stamp is beyond what builtin_interfaces/Time holds (int32 seconds: '
                                   '1901-12-13 to 2038-01-19 UTC)')
    return sec.astype('<i4'), nanosec.astype('<u4')


def leading_stamps_ns(rows: np.ndarray) -> np.ndarray:
    """The leading stamps (ns, int64) of equal-length little-endian CDR rows (2-D uint8) of a stamped type."""
    if not len(rows):
        return np.zeros(0, dtype=np.int64)
    if rows.shape[1] < 12 or np.any(rows[:, 1] != 1):
        raise ValueError('the payloads are not little-endian CDR with a leading stamp')
    return (np.ascontiguousarray(rows[:, 4:8]).view('<i4')[:, 0].astype(np.int64) * NS_PER_S
            + np.ascontiguousarray(rows[:, 8:12]).view('<u4')[:, 0])


def shift_stamps(rows: np.ndarray, offset_ns: int) -> np.ndarray:
    """Equal-length little-endian CDR rows (2-D uint8) with the leading stamps moved by ``offset_ns`` (shift_stamp)."""
    sec, nanosec = stamp_fields(leading_stamps_ns(rows) + offset_ns)
    shifted = rows.copy()
    shifted[:, 4:8] = sec.view(np.uint8).reshape(-1, 4)
    shifted[:, 8:12] = nanosec.view(np.uint8).reshape(-1, 4)
    return shifted
