"""Columnar decoding of the CDR messages of one topic: numpy arrays per field, no Python object per message.

Where each field of a message sits in its CDR depends only on its string lengths and sequence
counts (CDR aligns every primitive to its own size, counted from the end of the 4-byte
encapsulation header). The layout read off one message therefore holds for every message of the
same length whose length prefixes are the same bytes, and those rows decode as columns of a 2-D
byte array at once. Rows of other layouts form groups of their own, so any mix of layouts decodes.
rosbags' typestore supplies the message definitions; its per-message deserializer remains the
reference (test/test_bag.py compares the two).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from rosbags.interfaces import Nodetype

from sofia_ros.bag.timebase import NS_PER_S
from sofia_ros.errors import InvalidArgumentError

__all__ = ['MessageColumns', 'decode_columns', 'payload_blocks']

_ENCAPSULATION_CDR_LE = (0, 1)
#: The 4-byte encapsulation header before the CDR body, from whose start alignment counts.
_BODY = 4
_PRIMITIVES = {'bool': '?', 'byte': 'u1', 'char': 'u1', 'int8': 'i1', 'uint8': 'u1', 'int16': '<i2', 'uint16': '<u2',
               'int32': '<i4', 'uint32': '<u4', 'float32': '<f4', 'int64': '<i8', 'uint64': '<u8', 'float64': '<f8'}
_STRING = 'string'


@dataclass(frozen=True, eq=False)
class MessageColumns:
    """The messages of one topic as columns, in log-time order.

    A leaf field's path names the fields down to it, ``[]`` marking the elements of an array or
    sequence: 'header.stamp.sec', 'poses[].position.x', 'name[]'. ``values[path]`` runs over every
    occurrence of the leaf, message after message (strings as str); a sequence's own path holds its
    length at each occurrence. ``counts[path]`` is the number of occurrences in each message.
    """

    #: (N,) int64 log times.
    stamp_ns: np.ndarray
    values: dict
    counts: dict

    def __len__(self):
        return len(self.stamp_ns)

    def time_ns(self, path):
        """(N,) int64 ns of the builtin_interfaces/Time at ``path`` (e.g. 'header.stamp'), once per message."""
        return (self.per_message(f'{path}.sec').astype(np.int64) * NS_PER_S
                + self.per_message(f'{path}.nanosec').astype(np.int64))

    def per_message(self, path):
        """The values of a leaf occurring once in every message, (N,); InvalidArgumentError otherwise."""
        if np.any(self.counts[path] != 1):
            raise InvalidArgumentError(f'{path} does not occur once in every message')
        return self.values[path]


def payload_blocks(stamp_ns, payloads):
    """(log stamps ns, 2-D uint8 rows) per payload length of CDR ``payloads`` logged at ``stamp_ns``."""
    count = len(payloads)
    if len(stamp_ns) != count:
        raise InvalidArgumentError(f'got {len(stamp_ns)} stamps for {count} payloads')
    stamps = np.asarray(stamp_ns, dtype=np.int64)
    lengths = np.fromiter(map(len, payloads), dtype=np.int64, count=count)
    blocks = []
    for length in np.unique(lengths):
        rows = np.flatnonzero(lengths == length)
        # One length for the whole topic is the rule: then no payload is picked out.
        chosen = payloads if len(rows) == count else [payloads[row] for row in rows]
        blocks.append((stamps[rows], np.frombuffer(b''.join(chosen), dtype=np.uint8).reshape(-1, length)))
    return blocks


def decode_columns(blocks, msgtype, typestore):
    """MessageColumns of (log stamps ns, 2-D uint8 rows of equal-length little-endian CDR) blocks of ``msgtype``.

    The messages come out in log-time order (stable). ValueError where a payload is not the CDR of
    ``msgtype`` (too short for its own length prefixes).
    """
    kinds = _leaf_kinds(msgtype, typestore)
    stamps = np.concatenate([block_stamps for block_stamps, _ in blocks]) if blocks else np.empty(0, dtype=np.int64)
    order = np.argsort(stamps, kind='stable')
    # Each block's messages, numbered by their place in log-time order.
    place = np.empty(len(order), dtype=np.int64)
    place[order] = np.arange(len(order))
    numbers = np.split(place, np.cumsum([len(block_stamps) for block_stamps, _ in blocks])[:-1]) if blocks else []
    widths = sorted({rows.shape[1] for _, rows in blocks})
    groups = []  # (message numbers, leaf -> (rows, occurrences) values), one per layout
    for width in widths:
        rows = np.concatenate([rows for _, rows in blocks if rows.shape[1] == width])
        indices = np.concatenate([index for index, (_, rows) in zip(numbers, blocks) if rows.shape[1] == width])
        if np.any(rows[:, :2] != _ENCAPSULATION_CDR_LE):
            raise InvalidArgumentError(f'{msgtype} payloads are not little-endian CDR')
        while len(rows):
            leaves, prefixes = _layout(rows[0], msgtype, typestore)
            prefix_bytes = (_BODY + np.asarray(prefixes, dtype=np.int64)[:, None] + np.arange(4)).ravel()
            same = np.all(rows[:, prefix_bytes] == rows[0, prefix_bytes], axis=1)
            groups.append((indices[same], {path: _gathered(rows[same], runs, kinds[path])
                                           for path, runs in leaves.items()}))
            rows, indices = rows[~same], indices[~same]
    values, counts = {}, {}
    for path, kind in kinds.items():
        counts[path] = np.zeros(len(order), dtype=np.int64)
        for indices, leaves in groups:
            counts[path][indices] = leaves[path].shape[1] if path in leaves else 0
        starts = np.cumsum(counts[path]) - counts[path]
        values[path] = np.empty(int(counts[path].sum()), dtype=object if kind == _STRING else kind)
        for indices, leaves in groups:
            if path in leaves and leaves[path].size:
                values[path][starts[indices][:, None] + np.arange(leaves[path].shape[1])] = leaves[path]
    return MessageColumns(stamps[order], values, counts)


@lru_cache(maxsize=64)
def _leaf_kinds(msgtype, typestore):
    """Leaf path -> numpy dtype or 'string' of every leaf of ``msgtype`` (sequence lengths as uint32)."""
    kinds = {}

    def visit(path, desc):
        node, detail = desc
        if node == Nodetype.BASE:
            kinds[path] = _STRING if detail[0] == _STRING else _primitive(detail[0])
        elif node == Nodetype.NAME:
            for name, sub in typestore.fielddefs[detail][1]:
                visit(f'{path}.{name}' if path else name, sub)
        else:
            if node == Nodetype.SEQUENCE:
                kinds[path] = _PRIMITIVES['uint32']
            visit(f'{path}[]', detail[0])

    visit('', (Nodetype.NAME, msgtype))
    return kinds


def _primitive(name):
    if name not in _PRIMITIVES:
        raise InvalidArgumentError(f'CDR type {name} has no columnar decoding')
    return _PRIMITIVES[name]


def _layout(row, msgtype, typestore):
    """Where one message's leaves sit: leaf path -> [(body offset, count, string length)], and its length prefixes."""
    leaves, prefixes = {}, []
    body = row[_BODY:]

    def uint32_at(pos):
        if pos + 4 > len(body):
            raise ValueError(f'{msgtype} CDR of {len(row)} bytes ends inside a length prefix')
        return int(body[pos:pos + 4].view('<u4')[0])

    def visit(path, desc, pos):
        node, detail = desc
        if node == Nodetype.NAME:
            for name, sub in typestore.fielddefs[detail][1]:
                pos = visit(f'{path}.{name}' if path else name, sub, pos)
            return pos
        if node == Nodetype.BASE and detail[0] == _STRING:
            pos = _aligned(pos, 4)
            length = uint32_at(pos)  # counts the terminating NUL
            prefixes.append(pos)
            leaves.setdefault(path, []).append((pos + 4, 1, max(length - 1, 0)))
            return pos + 4 + length
        if node == Nodetype.BASE:
            return _run(leaves, path, detail[0], pos, 1, len(body), msgtype)
        sub, length = detail
        if node == Nodetype.SEQUENCE:
            pos = _aligned(pos, 4)
            length = uint32_at(pos)
            prefixes.append(pos)
            leaves.setdefault(path, []).append((pos, 1, None))
            pos += 4
        if sub[0] == Nodetype.BASE and sub[1][0] != _STRING:
            # Primitive elements: one run (a sequence of 10^5 floats is not walked element by element).
            return _run(leaves, f'{path}[]', sub[1][0], pos, length, len(body), msgtype) if length else pos
        for _ in range(length):
            pos = visit(f'{path}[]', sub, pos)
            if pos > len(body):
                raise ValueError(f'{msgtype} CDR of {len(row)} bytes is shorter than its sequences')
        return pos

    visit('', (Nodetype.NAME, msgtype), 0)
    return leaves, prefixes


def _run(leaves, path, type_name, pos, count, body_length, msgtype):
    """Record ``count`` primitives at their alignment; the position after them."""
    size = np.dtype(_primitive(type_name)).itemsize
    pos = _aligned(pos, size)
    if pos + count * size > body_length:
        raise ValueError(f'{msgtype} CDR of {body_length + _BODY} bytes ends inside {path}')
    leaves.setdefault(path, []).append((pos, count, None))
    return pos + count * size


def _aligned(pos, size):
    return (pos + size - 1) // size * size


def _gathered(rows, runs, kind):
    """(rows, occurrences) values of one leaf from its runs in the shared layout."""
    if kind == _STRING:
        return np.stack([_strings(rows[:, _BODY + pos:_BODY + pos + length]) for pos, _, length in runs], axis=1)
    size = np.dtype(kind).itemsize
    starts = np.concatenate([pos + size * np.arange(count) for pos, count, _ in runs]) + _BODY
    return np.ascontiguousarray(rows[:, starts[:, None] + np.arange(size)]).view(kind).reshape(len(rows), -1)


def _strings(characters):
    """str per row of a (rows, length) byte array, each distinct one decoded once."""
    if characters.shape[1] == 0:
        return np.full(len(characters), '', dtype=object)
    # One opaque record per row: np.unique then sorts rows as byte strings.
    records = np.ascontiguousarray(characters).view(f'V{characters.shape[1]}')[:, 0]
    distinct, inverse = np.unique(records, return_inverse=True)
    return np.array([bytes(value).decode() for value in distinct], dtype=object)[inverse.ravel()]
