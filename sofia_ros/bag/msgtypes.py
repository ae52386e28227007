"""Message types of bags: the installed ROS 2 distro's definitions, and the topic record.

The rclpy 9.x wheels this package runs on are ROS 2 Kilted. rosbags ships the
Kilted definitions of common_interfaces as a typestore whose RIHS01 type hashes
equal the ones the installed interface packages publish (share/<pkg>/msg/*.json;
test/test_bag.py pins this). Taking the typestore, rather than parsing .msg files
under share/, keeps bag I/O independent of AMENT_PREFIX_PATH and install layout.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING, Any

import numpy as np
from rclpy.serialization import serialize_message
from rosbags.interfaces import Nodetype
from rosbags.typesys import Stores, get_typestore

from sofia_ros.errors import InvalidArgumentError

if TYPE_CHECKING:
    from rosbags.typesys.store import Typestore

__all__ = [
    'DOCUMENT_MSGTYPE',
    'IMU_MSGTYPE',
    'ROS_DISTRO',
    'TYPESTORE',
    'TopicInfo',
    'checked_msgtype',
    'decode_cdr',
    'msgtype_of',
    'serializes_directly',
    'wire_cdr',
]

#: The ROS 2 distribution whose message definitions the bags carry.
ROS_DISTRO = 'kilted'
#: rosbags typestore with that distribution's message definitions.
TYPESTORE = get_typestore(Stores.ROS2_KILTED)
#: Message type of text documents (truth.yaml, model.yaml, results) stored in a bag.
DOCUMENT_MSGTYPE = 'std_msgs/msg/String'
#: Message type of the gyro box samples that BagReader.imu_arrays decodes in bulk.
IMU_MSGTYPE = 'sensor_msgs/msg/Imu'


@dataclass(frozen=True)
class TopicInfo:
    """A topic of a bag: name, ROS type ('pkg/msg/Name') and number of messages."""

    name: str
    msgtype: str
    count: int


def checked_msgtype(msgtype: str) -> str:
    """Return ``msgtype`` ('pkg/msg/Name') if the typestore defines it; raise otherwise."""
    if msgtype not in TYPESTORE.fielddefs:
        raise InvalidArgumentError(
            f'unknown message type {msgtype!r}: give a common_interfaces type of ROS 2 '
            f'{ROS_DISTRO} as pkg/msg/Name, e.g. sensor_msgs/msg/Imu'
        )
    return msgtype


@cache
def msgtype_of(message_class: type) -> str:
    """Return the ROS type string ('pkg/msg/Name') of an rclpy message class."""
    # rosidl generates each message class in module pkg.msg._snake_name.
    parts = message_class.__module__.split('.')
    if len(parts) != 3 or parts[1] != 'msg':
        raise InvalidArgumentError(f'{message_class.__name__} is not an rclpy message class')
    return f'{parts[0]}/msg/{message_class.__name__}'


def decode_cdr(data: bytes | memoryview, msgtype: str, typestore: Typestore = TYPESTORE) -> Any:
    """Decode CDR ``data`` of ``msgtype`` into a rosbags message, ignoring bytes after its end."""
    # rosbags' deserialize_cdr rejects more than 3 trailing bytes; DDS and ros2 bag
    # ignore them, and bags written from rclpy.serialization can carry them.
    view = memoryview(data)
    if len(view) < 4 or view[0] != 0 or view[1] not in (0, 1):
        raise ValueError(f'{msgtype} data does not start with a CDR encapsulation header')
    msgdef = typestore.get_msgdef(msgtype)
    decode = msgdef.deserialize_cdr_le if view[1] else msgdef.deserialize_cdr_be
    message, _ = decode(view[4:], 0, msgdef.cls, typestore)
    return message


#: Base types whose rclpy value the typestore's serializer does not take as it is (rclpy: str of 1 for char),
#: or that are not checked here (wstring).
_RCLPY_ONLY_BASE_TYPES = frozenset({'char', 'wstring'})
#: The one member the IDL gives a message without fields (std_msgs/Empty).
_EMPTY_MESSAGE_MEMBER = 'structure_needs_at_least_one_member'
#: Element types of the sequences rclpy holds as array.array, and the numpy dtype the typestore takes them as.
_NUMBER_DTYPES = {
    'int8': np.int8, 'uint8': np.uint8, 'int16': np.int16, 'uint16': np.uint16, 'int32': np.int32,
    'uint32': np.uint32, 'int64': np.int64, 'uint64': np.uint64, 'float32': np.float32, 'float64': np.float64,
}

# How each field of an rclpy message reaches the typestore's serializer (_field_plan): taken as it is, or
# converted from what rclpy holds to what the typestore's own decoder would give.
_AS_IS, _STRING, _BYTE, _NUMBERS, _STRINGS, _MESSAGE, _MESSAGES = range(7)


@cache
def _field_plan(msgtype: str) -> tuple[tuple[str, int, Any], ...] | None:
    """(name, how, detail) of each field of ``msgtype`` as the typestore serializes it from an rclpy message
    (see serializes_directly), or None for a type it cannot take."""
    fields = TYPESTORE.fielddefs[msgtype][1]
    if not fields or fields[0][0] == _EMPTY_MESSAGE_MEMBER:
        return None  # a message without fields: its placeholder member is on the wire, not in rclpy's class
    plan = []
    for name, (nodetype, spec) in fields:
        if nodetype == Nodetype.BASE:
            if spec[0] in _RCLPY_ONLY_BASE_TYPES or (spec[0] == 'string' and spec[1]):
                return None  # bounded strings: rclpy checks the bound, the typestore does not
            how = {'string': _STRING, 'byte': _BYTE}.get(spec[0], _AS_IS)
            plan.append((name, how, None))
        elif nodetype == Nodetype.NAME:
            nested = _field_plan(spec)
            if nested is None:
                return None
            plan.append((name, _MESSAGE, spec))
        else:
            (element_type, element), bound = spec
            if nodetype == Nodetype.SEQUENCE and bound:
                return None  # bounded sequences: rclpy checks the bound, the typestore does not
            if element_type == Nodetype.NAME:
                if _field_plan(element) is None:
                    return None
                plan.append((name, _MESSAGES, element))
            elif element[0] == 'string' and not element[1]:
                plan.append((name, _STRINGS, None))
            elif nodetype == Nodetype.ARRAY and element[0] in _NUMBER_DTYPES:
                plan.append((name, _AS_IS, None))  # rclpy holds a fixed-size array of numbers as numpy
            elif nodetype == Nodetype.SEQUENCE and element[0] in _NUMBER_DTYPES:
                plan.append((name, _NUMBERS, _NUMBER_DTYPES[element[0]]))
            else:
                return None  # bool, byte and char sequences and arrays, bounded strings inside them
    return tuple(plan)


@cache
def serializes_directly(msgtype: str) -> bool:
    """Whether the typestore serializes an rclpy message of ``msgtype`` as it is, reading its fields by name.

    So it does when every field, at any depth, is a number, bool, unbounded string, message, fixed-size
    array of numbers (numpy in rclpy) or unbounded sequence of messages so made (a list). Byte fields and
    unbounded sequences of numbers or strings (bytes of 1, array.array and lists of str in rclpy) are converted
    first (wire_cdr); char and wstring fields, bounded strings and sequences, sequences of bool, byte or char,
    and a message without fields go the round trip's way.
    """
    plan = _field_plan(msgtype)
    return plan is not None and all(
        how in (_AS_IS, _STRING) or (how == _MESSAGE and serializes_directly(detail))
        or (how == _MESSAGES and serializes_directly(detail)) for _, how, detail in plan)


class _NulInString(Exception):
    """A string field holds NUL: DDS carries such a string up to its first NUL, the typestore all of it."""


def _checked_string(text: str) -> str:
    if '\0' in text:
        raise _NulInString
    return text


def _typestore_value(message: object, msgtype: str) -> object:
    """An rclpy message of a type _field_plan takes, as the typestore's decoder gives it: sequences of numbers as
    numpy arrays, byte fields as int; _NulInString if a string holds NUL."""
    if serializes_directly(msgtype):
        _check_strings(message, msgtype)
        return message
    values = {}
    for name, how, detail in _field_plan(msgtype):
        value = getattr(message, name)
        if how == _STRING:
            value = _checked_string(value)
        elif how == _BYTE:
            value = value[0]
        elif how == _NUMBERS:
            value = np.asarray(value, dtype=detail)
        elif how == _STRINGS:
            value = [_checked_string(item) for item in value]
        elif how == _MESSAGE:
            value = _typestore_value(value, detail)
        elif how == _MESSAGES:
            value = [_typestore_value(item, detail) for item in value]
        values[name] = value
    return TYPESTORE.types[msgtype](**values)


def _check_strings(message: object, msgtype: str) -> None:
    """_NulInString if a string field of a message the typestore takes as it is holds NUL."""
    for name, how, detail in _field_plan(msgtype):
        if how == _STRING:
            _checked_string(getattr(message, name))
        elif how == _MESSAGE:
            _check_strings(getattr(message, name), detail)
        elif how == _MESSAGES:
            for item in getattr(message, name):
                _check_strings(item, detail)


def wire_cdr(message: object) -> memoryview:
    """Serialize an rclpy message as a raw subscription receives it: exact length, zero padding."""
    msgtype = msgtype_of(type(message))
    if _field_plan(msgtype) is not None:
        try:
            return TYPESTORE.serialize_cdr(_typestore_value(message, msgtype), msgtype, little_endian=True)
        except _NulInString:
            pass
    # The rest (a type _field_plan refuses, a string holding NUL) round trip through rclpy: with rmw_fastrtps,
    # serialize_message sizes its buffer by an upper estimate and leaves padding uninitialised, so its bytes
    # can end in junk (e.g. a JointState with an empty float64[]) and differ from run to run; decoding and
    # serializing again with the typestore fixes both.
    value = decode_cdr(serialize_message(message), msgtype)
    return TYPESTORE.serialize_cdr(value, msgtype, little_endian=True)
