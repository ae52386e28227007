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


#: Base types whose rclpy value the typestore's serializer does not take as it is (rclpy: bytes and str of 1),
#: or that are not checked here (wstring).
_RCLPY_ONLY_BASE_TYPES = frozenset({'byte', 'char', 'wstring'})
#: The one member the IDL gives a message without fields (std_msgs/Empty).
_EMPTY_MESSAGE_MEMBER = 'structure_needs_at_least_one_member'


@cache
def _direct_string_fields(msgtype: str) -> tuple[tuple[str, ...], ...] | None:
    """The attribute paths of the string fields of ``msgtype`` if the typestore serializes an rclpy message of it
    as it is (serializes_directly), else None."""
    fields = TYPESTORE.fielddefs[msgtype][1]
    if not fields or fields[0][0] == _EMPTY_MESSAGE_MEMBER:
        return None  # a message without fields: its placeholder member is on the wire, not in rclpy's class
    paths = []
    for name, (nodetype, spec) in fields:
        if nodetype == Nodetype.BASE:
            if spec[0] in _RCLPY_ONLY_BASE_TYPES or (spec[0] == 'string' and spec[1]):
                return None  # bounded strings: rclpy checks the bound, the typestore does not
            if spec[0] == 'string':
                paths.append((name,))
        elif nodetype == Nodetype.NAME:
            nested = _direct_string_fields(spec)
            if nested is None:
                return None
            paths.extend((name, *path) for path in nested)
        else:
            (element_type, element), bound = spec
            if nodetype == Nodetype.SEQUENCE and (bound or element_type != Nodetype.NAME):
                return None  # bounded sequences, and rclpy's array.array and lists of str
            if element_type == Nodetype.NAME:
                if _direct_string_fields(element) != ():
                    return None  # strings inside a sequence or an array: not checked here
            elif element[0] in _RCLPY_ONLY_BASE_TYPES | {'string'}:
                return None
    return tuple(paths)


def serializes_directly(msgtype: str) -> bool:
    """Whether the typestore serializes an rclpy message of ``msgtype`` as it is, reading its fields by name.

    So it does when every field, at any depth, is a number, bool, unbounded string, message, fixed-size
    array of numbers (numpy in rclpy) or unbounded sequence of messages without strings (a list); not for
    byte, char and wstring fields, bounded strings and sequences, sequences of numbers or strings (array.array
    and lists of str in rclpy), or a message without fields.
    """
    return _direct_string_fields(msgtype) is not None


def _has_nul(message: object, paths: tuple[tuple[str, ...], ...]) -> bool:
    """Whether a string field holds NUL: DDS carries such a string up to its first NUL, the typestore all of it."""
    for path in paths:
        value = message
        for name in path:
            value = getattr(value, name)
        if '\0' in value:
            return True
    return False


#: Element types of the sequences rclpy holds as array.array, and the numpy dtype the typestore takes them as.
_NUMBER_DTYPES = {
    'int8': np.int8, 'uint8': np.uint8, 'int16': np.int16, 'uint16': np.uint16, 'int32': np.int32,
    'uint32': np.uint32, 'int64': np.int64, 'uint64': np.uint64, 'float32': np.float32, 'float64': np.float64,
}
# How a field of an rclpy message the typestore does not take as it is gets there (_field_plan): as it is, or
# converted from what rclpy holds to what the typestore's own decoder would give.
_AS_IS, _STRING, _BYTE, _NUMBERS, _STRINGS, _MESSAGE, _MESSAGES = range(7)


@cache
def _field_plan(msgtype: str) -> tuple[tuple[str, int, Any], ...] | None:
    """(name, how, detail) of each field of ``msgtype`` for handing an rclpy message of it to the typestore's
    serializer with byte fields and unbounded sequences of numbers or strings converted (wire_cdr); None for a
    type with char, wstring, bool-, byte- or char-sequence fields, bounded strings or sequences, or no fields."""
    fields = TYPESTORE.fielddefs[msgtype][1]
    if not fields or fields[0][0] == _EMPTY_MESSAGE_MEMBER:
        return None
    plan = []
    for name, (nodetype, spec) in fields:
        if nodetype == Nodetype.BASE:
            if spec[0] in ('char', 'wstring') or (spec[0] == 'string' and spec[1]):
                return None
            plan.append((name, {'string': _STRING, 'byte': _BYTE}.get(spec[0], _AS_IS), None))
        elif nodetype == Nodetype.NAME:
            if _field_plan(spec) is None:
                return None
            plan.append((name, _MESSAGE, spec))
        else:
            (element_type, element), bound = spec
            if nodetype == Nodetype.SEQUENCE and bound:
                return None
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
                return None
    return tuple(plan)


class _NulInString(Exception):
    """A string field holds NUL: DDS carries such a string up to its first NUL, the typestore all of it."""


def _without_nul(text: str) -> str:
    if '\0' in text:
        raise _NulInString
    return text


def _typestore_value(message: object, msgtype: str) -> object:
    """An rclpy message of a type _field_plan takes, as the typestore's decoder gives it (sequences of numbers as
    numpy arrays, byte fields as int); _NulInString if a string in it holds NUL."""
    strings = _direct_string_fields(msgtype)
    if strings is not None:
        if _has_nul(message, strings):
            raise _NulInString
        return message
    values = {}
    for name, how, detail in _field_plan(msgtype):
        value = getattr(message, name)
        if how == _STRING:
            value = _without_nul(value)
        elif how == _BYTE:
            value = value[0]
        elif how == _NUMBERS:
            value = np.asarray(value, dtype=detail)
        elif how == _STRINGS:
            value = [_without_nul(item) for item in value]
        elif how == _MESSAGE:
            value = _typestore_value(value, detail)
        elif how == _MESSAGES:
            value = [_typestore_value(item, detail) for item in value]
        values[name] = value
    return TYPESTORE.types[msgtype](**values)


def wire_cdr(message: object) -> memoryview:
    """Serialize an rclpy message as a raw subscription receives it: exact length, zero padding."""
    msgtype = msgtype_of(type(message))
    strings = _direct_string_fields(msgtype)
    if strings is not None:
        if not _has_nul(message, strings):
            return TYPESTORE.serialize_cdr(message, msgtype, little_endian=True)
    elif _field_plan(msgtype) is not None:
        try:
            return TYPESTORE.serialize_cdr(_typestore_value(message, msgtype), msgtype, little_endian=True)
        except _NulInString:
            pass
    # Imported here: reading a bag (sofia compare) needs no rclpy, whose import costs about 60 MB.
    from rclpy.serialization import serialize_message

    # The rest (a type _field_plan refuses, a string holding NUL) round trip through rclpy: with rmw_fastrtps,
    # serialize_message sizes its buffer by an upper estimate and leaves padding uninitialised, so its bytes
    # can end in junk (e.g. a JointState with an empty float64[]) and differ from run to run; decoding and
    # serializing again with the typestore fixes both.
    value = decode_cdr(serialize_message(message), msgtype)
    return TYPESTORE.serialize_cdr(value, msgtype, little_endian=True)
