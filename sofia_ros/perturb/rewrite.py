"""Copy an MCAP file record for record, replacing the payloads of one channel; every other record is kept.

The source's top-level records are walked in file order. A chunk holding the channel is
decompressed and checked, the channel's payloads (found through its MessageIndex record) are
replaced in place by new ones of the same length, and the chunk is compressed like the source and
written as a new Chunk record with its CRC; every other record of the chunk, and each message's
channel, sequence, log time and publish time, stay as they were, and so do its MessageIndex
records (no offset moves). A chunk without the channel keeps its compressed bytes; a CRC is added
if it had none. The data section's CRC is computed anew over the bytes written (the magic
included, as the mcap writer does). The summary (schemas, channels, statistics, chunk, metadata and attachment indexes,
summary offsets) and the footer follow with the moved offsets and a new summary CRC, so BagReader's
indexed read, rosbags and the mcap tools read the copy. Records are encoded by the ``mcap`` package
(mcap.records).

The ``mcap`` package's Writer would re-encode all 0.8 M messages of an alignment bag one Python call
at a time (about 10 s); copying records as bytes keeps a camera perturbation at 1-2 s and leaves
the file's chunk layout (one chunk per flush of the recorder) as it was.
"""

from __future__ import annotations

import io
import mmap
import struct
import sys
import zlib
from typing import TYPE_CHECKING

import lz4.frame
import numpy as np
from mcap.data_stream import ReadDataStream, RecordBuilder
from mcap.opcode import Opcode
from mcap.reader import make_reader
from mcap.records import AttachmentIndex, Chunk, ChunkIndex, Footer, MetadataIndex, SummaryOffset

from sofia_ros.bag.mcap_index import INDEX_DAMAGE_ERRORS
from sofia_ros.errors import BagError

if sys.version_info >= (3, 14):
    from compression import zstd
else:
    from backports import zstd

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from pathlib import Path

    from mcap.summary import Summary

    #: One chunk's payloads of the channel -> their new payloads, in record order.
    Replace = Callable[[list[memoryview]], list[bytes]]

__all__ = ['channel_id_of', 'channel_payloads', 'copy_mcap', 'read_summary']

_MAGIC = b'\x89MCAP0\r\n'
_RECORD_HEAD = struct.Struct('<BQ')
#: channel id, sequence, log time, publish time
_MESSAGE_HEAD = struct.Struct('<HIQQ')
_CHANNEL_ID = struct.Struct('<H')
#: Offset of uncompressed_crc in a Chunk record: after its head, start and end times and uncompressed size.
_CHUNK_CRC_AT = _RECORD_HEAD.size + 24
_COMPRESS = {'zstd': zstd.compress, 'lz4': lz4.frame.compress, '': bytes}
_DECOMPRESS = {'zstd': zstd.decompress, 'lz4': lz4.frame.decompress, '': bytes}
_DAMAGE = (*INDEX_DAMAGE_ERRORS, KeyError, OverflowError)


def read_summary(mcap_path: Path) -> Summary:
    """The MCAP summary of ``mcap_path``; BagError if the file has none or no chunk indexes."""
    try:
        with open(mcap_path, 'rb') as file:
            summary = make_reader(file).get_summary()
    except INDEX_DAMAGE_ERRORS as err:
        raise _damaged(mcap_path, err) from err
    if summary is None or not summary.chunk_indexes:
        raise BagError(f'{mcap_path} has no MCAP summary with chunk indexes; rebuild it with '
                       f'`sofia recover {mcap_path.parent}`, which writes one')
    return summary


def channel_id_of(summary: Summary, topic: str) -> int:
    """The one channel id of ``topic``; BagError if the file has none or several."""
    ids = [channel.id for channel in summary.channels.values() if channel.topic == topic]
    if len(ids) != 1:
        raise BagError(f'the MCAP file holds {len(ids)} channels of {topic}; sofia perturb needs exactly one')
    return ids[0]


def channel_payloads(mcap_path: Path, summary: Summary, channel_id: int) -> Iterator[list[memoryview]]:
    """Per chunk holding ``channel_id``, in file order: that channel's payloads in record order."""
    with open(mcap_path, 'rb') as file:
        data = _mapped(file)
        for chunk in sorted(summary.chunk_indexes, key=lambda index: index.chunk_start_offset):
            if channel_id in chunk.message_index_offsets:
                start = chunk.chunk_start_offset
                try:
                    records = _decompressed(_read(Chunk, data, start), start)
                    spans = _channel_messages(data, chunk.message_index_offsets[channel_id], channel_id, records)
                except _DAMAGE as err:
                    raise _damaged(mcap_path, err) from err
                yield [records[head + _MESSAGE_HEAD.size:end] for head, end in spans]


def copy_mcap(source: Path, target: Path, summary: Summary, channel_id: int, replace: Replace) -> None:
    """Write ``target`` as ``source`` with each chunk's payloads of ``channel_id`` replaced by equal-length ones."""
    holding = {chunk.chunk_start_offset: chunk.message_index_offsets[channel_id] for chunk in summary.chunk_indexes
               if channel_id in chunk.message_index_offsets}
    with open(source, 'rb') as file, open(target, 'wb') as out:
        try:
            _Copy(_mapped(file), out, holding, channel_id, replace).run()
        except _DAMAGE as err:
            raise _damaged(source, err) from err


def _damaged(mcap_path: Path, err: Exception) -> BagError:
    """The one line for a source MCAP file that fails a check while it is read or copied."""
    return BagError(f'{mcap_path} is truncated or corrupt ({type(err).__name__}: {err}); salvage it with '
                    f'`sofia recover {mcap_path.parent}`')


def _mapped(file: io.BufferedReader) -> mmap.mmap:
    """The file mapped read-only; left to the garbage collector to unmap, not closed in a with: a failure in the
    middle of a copy (a damaged record, a full disk, Ctrl-C) leaves views of it in the traceback's frames, and
    closing it then raised BufferError over the real error (exit 1)."""
    return mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ)


class _Copy:
    """One pass over the source's records, writing the target and remembering where each record moved."""

    def __init__(self, data: mmap.mmap, out: io.BufferedWriter, holding: dict[int, int], channel_id: int,
                 replace: Replace) -> None:
        self.data, self.out, self.channel_id, self.replace = data, out, channel_id, replace
        #: source offset of each chunk holding the channel -> offset of the channel's MessageIndex record
        self.holding = holding
        #: source offset -> target offset of every top-level record
        self.moved: dict[int, int] = {}
        #: source offset of each rebuilt chunk -> (record length, compressed size) in the target
        self.rebuilt: dict[int, tuple[int, int]] = {}
        #: CRC of the summary section written so far
        self.summary_crc = 0
        #: CRC of the data section (the leading magic and every record before DataEnd) written so far
        self.data_crc = zlib.crc32(_MAGIC)

    def run(self) -> None:
        """Copy every record, then the closing magic."""
        if self.data[:8] != _MAGIC:
            raise ValueError('the file does not start with the MCAP magic')
        self.out.write(_MAGIC)
        position, summary_start = len(_MAGIC), None
        while True:
            opcode, length = _RECORD_HEAD.unpack_from(self.data, position)
            end = position + _RECORD_HEAD.size + length
            self.moved[position] = self.out.tell()
            if opcode == Opcode.FOOTER:
                self._footer(position)
                break
            record = self._record(opcode, position, end)
            if summary_start is None and opcode == Opcode.DATA_END:
                record = _RECORD_HEAD.pack(opcode, 4) + struct.pack('<I', self.data_crc)
                summary_start = end
            elif summary_start is not None:
                self.summary_crc = zlib.crc32(record, self.summary_crc)
            else:
                self.data_crc = zlib.crc32(record, self.data_crc)
            self.out.write(record)
            position = end
        if self.data[end:] != _MAGIC:
            raise ValueError('the file does not end with the MCAP magic after its footer')
        self.out.write(_MAGIC)

    def _record(self, opcode: int, position: int, end: int) -> bytes | memoryview:
        """The target bytes of the top-level record at ``position``."""
        if opcode == Opcode.CHUNK:
            return self._chunk(position) if position in self.holding else self._with_crc(position, end)
        if opcode == Opcode.CHUNK_INDEX:
            index = _read(ChunkIndex, self.data, position)
            if index.chunk_start_offset in self.rebuilt:
                index.chunk_length, index.compressed_size = self.rebuilt[index.chunk_start_offset]
            index.chunk_start_offset = self.moved[index.chunk_start_offset]
            index.message_index_offsets = {channel: self.moved[offset]
                                           for channel, offset in index.message_index_offsets.items()}
            return _encoded(index)
        if opcode in (Opcode.METADATA_INDEX, Opcode.ATTACHMENT_INDEX):
            index = _read(MetadataIndex if opcode == Opcode.METADATA_INDEX else AttachmentIndex, self.data, position)
            index.offset = self.moved[index.offset]
            return _encoded(index)
        if opcode == Opcode.SUMMARY_OFFSET:
            summary_offset = _read(SummaryOffset, self.data, position)
            summary_offset.group_start = self.moved[summary_offset.group_start]
            return _encoded(summary_offset)
        return memoryview(self.data)[position:end]

    def _with_crc(self, position: int, end: int) -> bytes | memoryview:
        """The chunk at ``position`` as it is, its records checked against its size and CRC (a damaged chunk was
        copied into a perturbed bag at exit 0), the CRC filled in if the source left it 0."""
        records = _decompressed(_read(Chunk, self.data, position), position)
        raw = memoryview(self.data)[position:end]
        if struct.unpack_from('<I', raw, _CHUNK_CRC_AT)[0]:
            return raw
        record = bytearray(raw)
        struct.pack_into('<I', record, _CHUNK_CRC_AT, zlib.crc32(records))
        return record

    def _chunk(self, position: int) -> bytes:
        """The chunk at ``position`` with the new payloads, compressed like the source, with its CRC.

        The payloads keep their lengths, so every record keeps its offset and the chunk's
        MessageIndex records stay right as they are.
        """
        chunk = _read(Chunk, self.data, position)
        records = bytearray(_decompressed(chunk, position))
        spans = _channel_messages(self.data, self.holding[position], self.channel_id, records)
        view = memoryview(records)
        bodies = self.replace([view[head + _MESSAGE_HEAD.size:end] for head, end in spans])
        if len(bodies) != len(spans):
            raise RuntimeError(f'replace() returned {len(bodies)} payloads for {len(spans)}')
        for (head, end), body in zip(spans, bodies):
            if len(body) != end - head - _MESSAGE_HEAD.size:
                raise RuntimeError('a replaced payload changed its length; sofia perturb changes values only')
            view[head + _MESSAGE_HEAD.size:end] = body
        view.release()
        chunk.data = _COMPRESS[chunk.compression](bytes(records))
        chunk.uncompressed_crc = zlib.crc32(records)
        encoded = _encoded(chunk)
        self.rebuilt[position] = (len(encoded), len(chunk.data))
        return encoded

    def _footer(self, position: int) -> None:
        """The footer with the summary's new start and CRC (CRC over the summary and the footer's head)."""
        footer = _read(Footer, self.data, position)
        if footer.summary_start:
            footer.summary_start = self.moved[footer.summary_start]
        if footer.summary_offset_start:
            footer.summary_offset_start = self.moved[footer.summary_offset_start]
        if footer.summary_crc:
            footer.summary_crc = zlib.crc32(_encoded(footer)[:-4], self.summary_crc)
        self.out.write(_encoded(footer))


def _channel_messages(data: mmap.mmap, index_offset: int, channel_id: int, records: bytes) -> list[tuple[int, int]]:
    """(message head offset, payload end) of the channel's Message records in a chunk's decompressed ``records``,
    in record order, from the channel's MessageIndex record at ``index_offset`` of the file ``data``."""
    opcode, length = _RECORD_HEAD.unpack_from(data, index_offset)
    indexed_channel, pairs_bytes = struct.unpack_from('<HI', data, index_offset + _RECORD_HEAD.size)
    if opcode != Opcode.MESSAGE_INDEX or indexed_channel != channel_id or pairs_bytes + 6 != length:
        raise ValueError(f'no message index of channel {channel_id} at byte {index_offset}')
    pairs = np.frombuffer(data, dtype='<u8', count=pairs_bytes // 8, offset=index_offset + _RECORD_HEAD.size + 6)
    offsets = np.sort(pairs[1::2].astype(np.int64))
    raw = np.frombuffer(records, dtype=np.uint8)
    if len(offsets) == 0:
        return []
    if offsets.max() + _RECORD_HEAD.size + _CHANNEL_ID.size > len(raw):
        raise ValueError(f'the message index at byte {index_offset} points past the end of its chunk')
    # Each record's length and channel id, gathered for all records at once.
    lengths = raw[offsets[:, None] + np.arange(1, _RECORD_HEAD.size)].copy().view('<u8')[:, 0].astype(np.int64)
    channels = raw[offsets[:, None] + np.arange(_RECORD_HEAD.size, _RECORD_HEAD.size + 2)].copy().view('<u2')[:, 0]
    heads = offsets + _RECORD_HEAD.size
    ends = heads + lengths
    if np.any(raw[offsets] != Opcode.MESSAGE) or np.any(channels != channel_id) or ends.max() > len(raw):
        raise ValueError(f'the message index at byte {index_offset} points at no message of its channel')
    return list(zip(heads.tolist(), ends.tolist()))


def _decompressed(chunk: Chunk, position: int) -> bytes:
    """A chunk's records, size- and CRC-checked."""
    try:
        records = _DECOMPRESS[chunk.compression](chunk.data)
    except RuntimeError as err:  # what lz4.frame raises on damaged data
        raise ValueError(f'chunk at byte {position} does not decompress: {err}') from err
    if len(records) != chunk.uncompressed_size or (chunk.uncompressed_crc and
                                                   zlib.crc32(records) != chunk.uncompressed_crc):
        raise ValueError(f'chunk at byte {position} fails its size or CRC check')
    return records


def _read(record_type: type, data: bytes | mmap.mmap, position: int):
    """The record of ``record_type`` whose opcode is at ``position``."""
    length = _RECORD_HEAD.unpack_from(data, position)[1]
    body = position + _RECORD_HEAD.size
    return record_type.read(ReadDataStream(io.BytesIO(data[body:body + length])))


def _encoded(record) -> bytes:
    builder = RecordBuilder()
    record.write(builder)
    return builder.end()
