"""Selective reading of an MCAP file through its message indexes, for bags dominated by one fast topic.

rosbags (and the mcap package) walk every record of every chunk in Python, so reading the
0.5 Hz calibration topics of an alignment bag costs as much as reading its 400 Hz gyro and
truth samples. The MCAP summary holds, per chunk and channel, a MessageIndex of (log time,
offset) pairs: with it the wanted records are sliced out of each decompressed chunk with
numpy, and the others are never touched. The summary is parsed with the mcap package; only
the bulk access is ours. A file without a summary or message indexes gives None, and the
caller reads it the general way.
"""

from __future__ import annotations

import mmap
import struct
import sys
import zlib
from pathlib import Path

import numpy as np
from mcap.exceptions import McapError
from mcap.reader import make_reader

if sys.version_info >= (3, 14):
    from compression import zstd
else:
    from backports import zstd

__all__ = ['INDEX_DAMAGE_ERRORS', 'check_summary_crc', 'first_damaged_chunk', 'indexed_records', 'last_log_time_ns']

#: What a damaged file raises here: summary parsing, record layout, zstd, the CRC check.
INDEX_DAMAGE_ERRORS = (McapError, struct.error, zstd.ZstdError, ValueError, IndexError)

_CHUNK_OPCODE = 0x06
_MESSAGE_INDEX_OPCODE = 0x07
_MESSAGE_OPCODE = 0x05
#: opcode (1) + record length (8).
_RECORD_HEAD = 9
#: channel id (2) + sequence (4) + log time (8) + publish time (8) before a message's data.
_MESSAGE_HEAD = 22
_FOOTER_OPCODE = 0x02
#: Footer record: opcode, length, summary start, summary offset start, summary CRC.
_FOOTER = struct.Struct('<BQQQI')
_MAGIC = b'\x89MCAP0\r\n'
#: Decompressed chunks (about 150 kB a second of a 400 Hz campaign) are cut in batches of at least this many bytes:
#: few enough numpy calls per message index, and small enough for the joined batch to stay in the processor's cache
#: (1-4 MiB read a star hop's observables in 2.6-2.9 s CPU, chunk by chunk 4.2 s, 32 MiB 3.6 s).
_BATCH_BYTES = 2 << 20


def indexed_records(mcap_path, topics, packed=None):
    """topic -> (log times ns, CDR payloads) in log-time order, read through the message indexes; None without them.

    Topics in ``packed`` (topic -> payload decoder or None) come back as a list of (log times ns, 2-D
    uint8 array of equal-length payloads) blocks instead, for bulk decoding without a Python object
    per message; with a decoder each block comes back as (log times ns, decoder(batch bytes, payload
    starts, payload length)), decoded as it is cut, so that only one batch of chunks is alive at a time
    (a star hop's gyro payloads are 0.8 GB) and only the bytes the decoder reads are gathered.
    """
    packed = packed or {}
    with open(Path(mcap_path), 'rb') as file, mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ) as data:
        summary = make_reader(file).get_summary()
        if summary is None or not summary.chunk_indexes:
            return None
        channel_topic = {channel.id: channel.topic for channel in summary.channels.values()
                         if channel.topic in topics}
        found = {topic: ([], []) for topic in topics if topic not in packed}
        blocks = {topic: [] for topic in packed}

        def cut(batch):
            records = b''.join(chunk_records for chunk_records, _ in batch)
            raw = np.frombuffer(records, dtype=np.uint8)
            log_ns, starts, ends, channels = (np.concatenate(column) for column in zip(*(index for _, index in batch)))
            for channel in np.unique(channels).tolist():
                topic, mine = channel_topic[channel], channels == channel
                if topic in blocks:
                    decode = packed[topic] or _rows
                    blocks[topic].extend((stamps, decode(raw, group_starts, length))
                                         for stamps, group_starts, length in
                                         _equal_length_groups(log_ns[mine], starts[mine], ends[mine]))
                else:
                    found[topic][0].append(log_ns[mine])
                    # Copies, not views: a view would keep the whole batch alive.
                    found[topic][1].extend(records[start:end]
                                           for start, end in zip(starts[mine].tolist(), ends[mine].tolist()))

        # Chunks are about 1 s of a campaign each: the per-message work is done once per batch of them.
        batch, batch_bytes = [], 0
        for number, chunk in enumerate(summary.chunk_indexes, 1):
            wanted = [channel for channel in chunk.message_index_offsets if channel in channel_topic]
            if not wanted:
                continue
            records = _chunk_records(data, chunk, f'{number} of {len(summary.chunk_indexes)}')
            log_ns, starts, ends, channels = _chunk_messages(data, chunk.message_index_offsets, wanted, records)
            batch.append((records, (log_ns, starts + batch_bytes, ends + batch_bytes, channels)))
            batch_bytes += len(records)
            if batch_bytes >= _BATCH_BYTES:
                cut(batch)
                batch, batch_bytes = [], 0
        if batch:
            cut(batch)
        _check_counts(summary, found, blocks, channel_topic)
    return {**{topic: _in_time_order(stamps, payloads) for topic, (stamps, payloads) in found.items()}, **blocks}


def _check_counts(summary, found, blocks, channel_topic):
    """Raise ValueError unless the messages read per topic are as many as the summary's statistics count
    (a damaged message index that lists too few would drop messages unnoticed)."""
    if summary.statistics is None:
        return
    expected = {}
    for channel, topic in channel_topic.items():
        expected[topic] = expected.get(topic, 0) + summary.statistics.channel_message_counts.get(channel, 0)
    read = {topic: sum(map(len, stamps)) for topic, (stamps, _) in found.items()}
    read.update({topic: sum(len(stamps) for stamps, _ in topic_blocks) for topic, topic_blocks in blocks.items()})
    for topic, count in expected.items():
        if read.get(topic, 0) != count:
            raise ValueError(f'the message indexes list {read.get(topic, 0)} messages on {topic}, '
                             f'the statistics {count}')


def last_log_time_ns(mcap_path, topic):
    """The latest log time of ``topic`` in the file, from its message indexes, or None without them.

    Only the chunk that holds it is decompressed and checked (CRC, and its index against its messages):
    a campaign's run reads its length back from its /clock this way, not by reading every chunk.
    """
    with open(Path(mcap_path), 'rb') as file, mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ) as data:
        summary = make_reader(file).get_summary()
        if summary is None or not summary.chunk_indexes:
            return None
        channels = {channel.id for channel in summary.channels.values() if channel.topic == topic}
        latest_ns, latest_chunk = None, None
        for number, chunk in enumerate(summary.chunk_indexes, 1):
            wanted = [channel for channel in chunk.message_index_offsets if channel in channels]
            if not wanted or (latest_ns is not None and chunk.message_end_time <= latest_ns):
                continue
            chunk_latest_ns = max(int(_message_index_pairs(data, chunk.message_index_offsets[channel], channel)[0::2]
                                      .max(initial=0)) for channel in wanted)
            if latest_ns is None or chunk_latest_ns > latest_ns:
                latest_ns, latest_chunk = chunk_latest_ns, (number, chunk, wanted)
        if latest_chunk is None:
            return None
        number, chunk, wanted = latest_chunk
        records = _chunk_records(data, chunk, f'{number} of {len(summary.chunk_indexes)}')
        log_ns = _chunk_messages(data, chunk.message_index_offsets, wanted, records)[0]
    return int(log_ns.max())


def first_damaged_chunk(mcap_path):
    """'chunk N of M (...) fails ...' for the first chunk whose size, zstd frame or CRC is wrong; None if all pass."""
    with open(Path(mcap_path), 'rb') as file, mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ) as data:
        chunks = make_reader(file).get_summary().chunk_indexes
        for number, chunk in enumerate(chunks, 1):
            try:
                _chunk_records(data, chunk, f'{number} of {len(chunks)}')
            except ValueError as err:
                return str(err)
    return None


def check_summary_crc(mcap_path):
    """Raise ValueError if the file's footer carries a summary CRC that its summary section fails."""
    if Path(mcap_path).stat().st_size == 0:  # mmap refuses an empty file
        raise ValueError('the file is empty')
    with open(Path(mcap_path), 'rb') as file, mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ) as data:
        footer = len(data) - len(_MAGIC) - _FOOTER.size
        if footer < 0 or data[footer] != _FOOTER_OPCODE:
            raise ValueError('no MCAP footer at the end of the file')
        _, _, summary_start, _, crc = _FOOTER.unpack_from(data, footer)
        if crc and summary_start and zlib.crc32(data[summary_start:footer + _FOOTER.size - 4]) != crc:
            raise ValueError(f'the summary section (byte {summary_start} on) fails its CRC check')


def _chunk_records(data, chunk, name):
    """The decompressed, CRC-checked records of one Chunk record; ``name`` ('3 of 17') for the error."""
    start = chunk.chunk_start_offset
    where = (f'chunk {name} (byte {start}, log times {chunk.message_start_time} to '
             f'{chunk.message_end_time} ns)')
    if data[start] != _CHUNK_OPCODE:
        raise ValueError(f'{where}: no chunk record there')
    head = start + _RECORD_HEAD
    uncompressed_size, crc, name_length = struct.unpack_from('<QII', data, head + 16)
    body = head + 32 + name_length
    (length,) = struct.unpack_from('<Q', data, body)
    compressed = data[body + 8:body + 8 + length]
    if chunk.compression == 'zstd':
        try:
            records = zstd.decompress(compressed)
        except zstd.ZstdError as err:
            raise ValueError(f'{where} fails to decompress ({err})') from err
    elif chunk.compression == '':
        records = bytes(compressed)
    else:
        raise ValueError(f'{where}: compression {chunk.compression!r} is not supported')
    if len(records) != uncompressed_size:
        raise ValueError(f'{where} decompresses to {len(records)} bytes, not {uncompressed_size}')
    if crc and zlib.crc32(records) != crc:
        raise ValueError(f'{where} fails its CRC check')
    return records


def _message_index_pairs(data, index_offset, channel):
    """The (log time, offset) pairs, flat, of the MessageIndex record of ``channel`` at byte ``index_offset``."""
    if data[index_offset] != _MESSAGE_INDEX_OPCODE:
        raise ValueError(f'no message index record at byte {index_offset}')
    indexed_channel, pairs_length = struct.unpack_from('<HI', data, index_offset + _RECORD_HEAD)
    if indexed_channel != channel:
        raise ValueError(f'message index at byte {index_offset} is for channel {indexed_channel}, not {channel}')
    return np.frombuffer(data, dtype='<u8', count=pairs_length // 8, offset=index_offset + _RECORD_HEAD + 6)


def _chunk_messages(data, index_offsets, channels, records):
    """(log times, payload starts, payload ends, channel) of the messages of ``channels`` in one chunk, from their
    MessageIndex records (channel by channel, each in its index's order)."""
    pairs = [_message_index_pairs(data, index_offsets[channel], channel) for channel in channels]
    counts = [len(channel_pairs) // 2 for channel_pairs in pairs]
    pairs = np.concatenate(pairs).astype(np.int64)
    log_ns, offsets = pairs[0::2], pairs[1::2]
    raw = np.frombuffer(records, dtype=np.uint8)
    if len(offsets) and (offsets.max() + _RECORD_HEAD + _MESSAGE_HEAD > len(raw)
                         or np.any(raw[offsets] != _MESSAGE_OPCODE)):
        raise ValueError('a message index points outside the message records of its chunk')
    # The message indexes carry no CRC: each (log time, offset) pair must name a message of its channel at
    # its log time in the CRC-checked chunk, or a damaged index would move or swap messages unnoticed.
    wanted = np.repeat(np.asarray(channels, dtype=np.int64), counts)
    record_channels = raw[offsets[:, None] + np.arange(_RECORD_HEAD, _RECORD_HEAD + 2)].copy().view('<u2')[:, 0]
    record_log_ns = raw[offsets[:, None] + np.arange(_RECORD_HEAD + 6, _RECORD_HEAD + 14)].copy().view('<u8')[:, 0]
    if np.any(record_channels != wanted) or np.any(record_log_ns.astype(np.int64) != log_ns):
        raise ValueError('a message index disagrees with the messages of its chunk (channel or log time)')
    # Each record's length: the 8 bytes after its opcode, gathered for all records at once.
    lengths = raw[offsets[:, None] + np.arange(1, _RECORD_HEAD)].copy().view('<u8')[:, 0].astype(np.int64)
    starts = offsets + _RECORD_HEAD + _MESSAGE_HEAD
    ends = offsets + _RECORD_HEAD + lengths
    if len(offsets) and ends.max() > len(raw):
        raise ValueError('a message record runs past the end of its chunk')
    return log_ns, starts, ends, wanted


def _equal_length_groups(log_ns, starts, ends):
    """(log times, payload starts, payload length) per payload length."""
    lengths = ends - starts
    return [(log_ns[lengths == length], starts[lengths == length], int(length)) for length in np.unique(lengths)]


def _rows(raw, starts, length):
    """Equal-length payloads at ``starts`` of a byte buffer as rows of a 2-D array, gathered at once."""
    # Row k of the window view is raw[k:k + length]: picking rows copies only the payloads.
    return np.lib.stride_tricks.sliding_window_view(raw, length)[starts]


def _in_time_order(stamp_blocks, payloads):
    """Chunks may overlap in time: a stable sort by log time, as a time-ordered reader returns them."""
    stamps = np.concatenate(stamp_blocks) if stamp_blocks else np.empty(0, dtype=np.int64)
    order = np.argsort(stamps, kind='stable')
    if np.all(order[1:] > order[:-1]):
        return stamps.tolist(), payloads
    return stamps[order].tolist(), [payloads[index] for index in order]
