"""The MCAP file of a bag, written with every CRC and with each chunk's records in log-time order.

A storage plugin for rosbags' rosbag2 ``Writer`` (which keeps writing ``metadata.yaml``, the
connections and their QoS): rosbags' own MCAP writer leaves the chunk CRCs at 0 and writes no
data-section or summary CRC, and the mcap package's writer, which computes them, halves the
write rate (bench/bench_bag.py). Here messages are buffered and packed in bulk: a chunk's
records are sorted by log time (stable, so equal times keep their write order), its
uncompressed records carry their CRC-32, the DataEnd record the CRC of everything before it
and the Footer the CRC of the summary, as the MCAP specification defines them.

``write_chunks(before_ns)`` writes the buffered messages logged before ``before_ns`` (all of
them without it) and hands the file to the OS; the rest stay buffered. Schemas and channels
go at the head of the next chunk written, so a reader of a cut file (recovery) meets each
channel before its messages.
"""

from __future__ import annotations

import bisect
import itertools
import operator
import struct
import sys
import zlib
from collections import defaultdict
from importlib.metadata import version
from typing import TYPE_CHECKING

import numpy as np
from rosbags.interfaces import MessageDefinitionFormat

if sys.version_info >= (3, 14):
    from compression import zstd
else:
    from backports import zstd

if TYPE_CHECKING:
    from pathlib import Path

    from rosbags.interfaces import Connection
    from rosbags.rosbag2.enums import CompressionMode

__all__ = ['CheckedMcapStorage', 'CHUNK_BYTES']

MAGIC = b'\x89MCAP0\r\n'
#: Uncompressed bytes after which a chunk is closed (rosbags and ros2 bag use 1 MiB too).
CHUNK_BYTES = 1 << 20

_HEADER, _FOOTER, _SCHEMA, _CHANNEL, _MESSAGE, _CHUNK, _MESSAGE_INDEX, _CHUNK_INDEX = range(1, 9)
_STATISTICS, _METADATA, _METADATA_INDEX, _SUMMARY_OFFSET, _DATA_END = 0x0B, 0x0C, 0x0D, 0x0E, 0x0F
_RECORD_HEAD = struct.Struct('<BQ')
# Message record: opcode, length, channel id, sequence, log time, publish time; the data follows.
_MESSAGE_HEAD = struct.Struct('<BQHIQQ')
_MESSAGE_FIELDS_BYTES = _MESSAGE_HEAD.size - _RECORD_HEAD.size
#: The same fields as a numpy record: the heads of a block of messages packed at once.
_MESSAGE_HEADS = np.dtype([('opcode', 'u1'), ('length', '<u8'), ('channel', '<u2'), ('sequence', '<u4'),
                           ('log_time', '<u8'), ('publish_time', '<u8')])
_U16, _U32, _U64 = struct.Struct('<H'), struct.Struct('<I'), struct.Struct('<Q')


def _record(opcode: int, body: bytes) -> bytes:
    return _RECORD_HEAD.pack(opcode, len(body)) + body


def _string(text: str) -> bytes:
    data = text.encode()
    return _U32.pack(len(data)) + data


def _string_map(mapping: dict[str, str]) -> bytes:
    body = b''.join(_string(key) + _string(value) for key, value in mapping.items())
    return _U32.pack(len(body)) + body


class CheckedMcapStorage:
    """rosbags StorageWriter of one ``<bag>/<bag>.mcap`` file with chunk, data and summary CRCs."""

    def __init__(self, path: Path, compression: CompressionMode) -> None:
        """Create the file and write its magic and header (``compression``: rosbags' mode; STORAGE is zstd)."""
        self.path = path / f'{path.name}.mcap'
        self._compression = 'zstd' if compression.name == 'STORAGE' else ''
        self._file = self.path.open('xb')
        self._data_crc = 0
        self._pending: list[tuple[int, int, bytes]] = []  # (log time, channel id, message record), in write order
        self._pending_records: list[bytes] = []  # schemas and channels for the head of the next chunk
        self._schemas: list[bytes] = []
        self._channels: list[bytes] = []
        self._schema_ids: dict[str, int] = {}
        self._chunk_indexes: list[bytes] = []
        self._counts: dict[int, int] = {}
        self._start_ns = 2**64 - 1
        self._end_ns = 0
        self._emit(MAGIC + _record(_HEADER, _string('ros2') + _string(f'sofia_ros, rosbags-{version("rosbags")}')))

    # --- the rosbags StorageWriter protocol ---------------------------------------------------------------
    def add_msgtype(self, connection: Connection) -> None:
        """Register the schema (message definition) of ``connection``'s type."""
        encoding = 'ros2msg' if connection.msgdef.format == MessageDefinitionFormat.MSG else 'ros2idl'
        schema_id = len(self._schemas) + 1
        self._schema_ids[connection.msgtype] = schema_id
        record = _record(_SCHEMA, _U16.pack(schema_id) + _string(connection.msgtype) + _string(encoding)
                         + _string(connection.msgdef.data))
        self._schemas.append(record)
        self._pending_records.append(record)

    def add_connection(self, connection: Connection, offered_qos_profiles: str) -> None:
        """Register a channel, its offered QoS profiles (YAML) in its metadata as rosbag2 keeps them."""
        serialization = getattr(connection.ext, 'serialization_format', 'cdr')
        record = _record(_CHANNEL, _U16.pack(connection.id) + _U16.pack(self._schema_ids[connection.msgtype])
                         + _string(connection.topic) + _string(serialization)
                         + _string_map({'offered_qos_profiles': offered_qos_profiles}))
        self._channels.append(record)
        self._pending_records.append(record)
        self._counts[connection.id] = 0

    def write(self, connection: Connection, timestamp: int, data: bytes | memoryview) -> None:
        """Buffer one message logged at ``timestamp`` ns, its record packed now."""
        head = _MESSAGE_HEAD.pack(_MESSAGE, _MESSAGE_FIELDS_BYTES + len(data), connection.id, 0, timestamp, timestamp)
        self._pending.append((timestamp, connection.id, head + data))
        self._counts[connection.id] += 1

    def write_block(self, connection: Connection, timestamps: np.ndarray, rows: np.ndarray) -> None:
        """Buffer messages logged at ``timestamps`` ns (int64), the rows of a 2-D uint8 array of equal-length CDR:
        write() of each in turn, their records packed at once."""
        count, length = rows.shape
        heads = np.zeros(count, dtype=_MESSAGE_HEADS)
        heads['opcode'] = _MESSAGE
        heads['length'] = _MESSAGE_FIELDS_BYTES + length
        heads['channel'] = connection.id
        heads['log_time'] = heads['publish_time'] = timestamps
        data = np.hstack([heads.view(np.uint8).reshape(count, _MESSAGE_HEAD.size), rows]).tobytes()
        size = _MESSAGE_HEAD.size + length
        records = [data[start:start + size] for start in range(0, len(data), size)]
        self._pending.extend(zip(timestamps.tolist(), itertools.repeat(connection.id), records))
        self._counts[connection.id] += count

    def close(self, version: int, metadata: str) -> None:
        """Write what is buffered, the rosbag2 metadata record, DataEnd, the summary and the footer."""
        del version  # the metadata text carries it
        self.write_chunks()
        metadata_start = self._file.tell()
        metadata_record = _record(_METADATA, _string('rosbag2') + _string_map({'serialized_metadata': metadata}))
        self._emit(metadata_record)
        self._emit(_record(_DATA_END, _U32.pack(self._data_crc)))
        summary_start = self._file.tell()
        groups = [
            (_SCHEMA, self._schemas),
            (_CHANNEL, self._channels),
            (_CHUNK_INDEX, self._chunk_indexes),
            (_METADATA_INDEX, [_record(_METADATA_INDEX, _U64.pack(metadata_start) + _U64.pack(len(metadata_record))
                                       + _string('rosbag2'))]),
            (_STATISTICS, [self._statistics()]),
        ]
        summary, offsets, position = [], [], summary_start
        for opcode, records in groups:
            if records:
                length = sum(map(len, records))
                offsets.append(_record(_SUMMARY_OFFSET, struct.pack('<BQQ', opcode, position, length)))
                summary.extend(records)
                position += length
        summary_offset_start = position
        summary.extend(offsets)
        footer_head = _RECORD_HEAD.pack(_FOOTER, 20) + struct.pack('<QQ', summary_start, summary_offset_start)
        summary_bytes = b''.join(summary)
        summary_crc = zlib.crc32(footer_head, zlib.crc32(summary_bytes))
        self._file.write(summary_bytes + footer_head + _U32.pack(summary_crc) + MAGIC)
        self._file.close()

    def abort(self) -> None:
        """Stop without a summary: the file keeps the chunks written so far."""
        self._file.close()

    # --- chunks -------------------------------------------------------------------------------------------
    def write_chunks(self, before_ns: int | None = None) -> None:
        """Write the buffered messages logged before ``before_ns`` (all if None) as chunks; flush the file."""
        self._pending.sort(key=operator.itemgetter(0))
        split = len(self._pending) if before_ns is None else bisect.bisect_left(
            self._pending, before_ns, key=operator.itemgetter(0))
        batch, self._pending = self._pending[:split], self._pending[split:]
        start = 0
        while start < len(batch):
            start = self._write_chunk(batch, start)
        self._file.flush()

    def _write_chunk(self, batch: list[tuple[int, int, bytes]], start: int) -> int:
        """Write the message records batch[start:k] as one chunk of at most about CHUNK_BYTES with its message indexes;
        return k."""
        parts = self._pending_records
        self._pending_records = []
        position = sum(map(len, parts))
        index: dict[int, list[int]] = defaultdict(list)
        end = start
        while end < len(batch) and (end == start or position < CHUNK_BYTES):
            log_ns, channel, record = batch[end]
            index[channel] += (log_ns, position)
            parts.append(record)
            position += len(record)
            end += 1
        records = b''.join(parts)
        first_ns, last_ns = batch[start][0], batch[end - 1][0]
        self._start_ns, self._end_ns = min(self._start_ns, first_ns), max(self._end_ns, last_ns)
        packed = zstd.compress(records) if self._compression else records
        chunk = _record(_CHUNK, struct.pack('<QQQI', first_ns, last_ns, len(records), zlib.crc32(records))
                        + _string(self._compression) + _U64.pack(len(packed)) + packed)
        chunk_start = self._file.tell()
        indexes, index_offsets = [], []
        offset = chunk_start + len(chunk)
        for channel in sorted(index):
            pairs = index[channel]
            record = _record(_MESSAGE_INDEX, _U16.pack(channel) + _U32.pack(8 * len(pairs))
                             + struct.pack(f'<{len(pairs)}Q', *pairs))
            index_offsets.append(_U16.pack(channel) + _U64.pack(offset))
            indexes.append(record)
            offset += len(record)
        self._emit(chunk + b''.join(indexes))
        offsets = b''.join(index_offsets)
        self._chunk_indexes.append(_record(_CHUNK_INDEX, struct.pack('<QQQQ', first_ns, last_ns, chunk_start, len(chunk))
                                           + _U32.pack(len(offsets)) + offsets + _U64.pack(offset - chunk_start - len(chunk))
                                           + _string(self._compression) + _U64.pack(len(packed))
                                           + _U64.pack(len(records))))
        return end

    def _statistics(self) -> bytes:
        counts = b''.join(_U16.pack(channel) + _U64.pack(count) for channel, count in sorted(self._counts.items()))
        start_ns = self._start_ns if self._chunk_indexes else 0
        return _record(_STATISTICS, _U64.pack(sum(self._counts.values())) + _U16.pack(len(self._schemas))
                       + struct.pack('<IIII', len(self._channels), 0, 1, len(self._chunk_indexes))
                       + _U64.pack(start_ns) + _U64.pack(self._end_ns) + _U32.pack(len(counts)) + counts)

    def _emit(self, data: bytes) -> None:
        """Append ``data`` to the data section, keeping its CRC."""
        self._data_crc = zlib.crc32(data, self._data_crc)
        self._file.write(data)
