"""Rebuild a complete bag from one whose writer was killed, whose file was cut short or is damaged."""

from __future__ import annotations

import io
import shutil
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import zstandard
from mcap.exceptions import EndOfFile, McapError
from mcap.records import Channel, Footer, Message, Schema
from mcap.stream_reader import CRCValidationError, StreamReader

from sofia_ros.bag.reader import mcap_file_to_recover
from sofia_ros.bag.writer import BagWriter
from sofia_ros.config import safe_load_limited
from sofia_ros.errors import BagError, ConfigError, SofiaError
from sofia_ros.output_files import output_error

if TYPE_CHECKING:
    from os import PathLike

    from mcap.records import McapRecord

    from sofia_ros.bag.msgtypes import TopicInfo

__all__ = ['RECOVERED_SUFFIX', 'RecoveryReport', 'recover_bag']

#: Appended to the damaged bag's name to name the rebuilt bag by default.
RECOVERED_SUFFIX = '_recovered'
_MCAP_MAGIC = b'\x89MCAP0\r\n'
# What a cut or damaged record, or a chunk or data section failing its CRC, raises inside the mcap stream reader.
_DAMAGE_ERRORS = (McapError, CRCValidationError, zstandard.ZstdError, struct.error, UnicodeDecodeError)


@dataclass(frozen=True)
class RecoveryReport:
    """What recover_bag salvaged, and where and why reading the damaged file stopped."""

    source: Path
    bag: Path
    topics: tuple[TopicInfo, ...]
    last_stamp_ns: int | None
    reached_footer: bool
    stop_reason: str
    #: byte offsets of damaged records that were skipped (the intact chunks after them are kept)
    skipped_offsets: tuple[int, ...] = ()

    @property
    def message_count(self) -> int:
        """Messages salvaged over all topics."""
        return sum(info.count for info in self.topics)


def recover_bag(
    source: str | PathLike[str], destination: str | PathLike[str] | None = None
) -> RecoveryReport:
    """Copy every complete MCAP chunk of bag ``source`` into a new, closed bag ``destination``, and the side files
    beside it.

    ``source`` is left untouched; ``destination`` defaults to ``source`` + '_recovered'. It is
    complete or absent: a failure (a full disk, nothing to recover) removes what was begun.
    """
    source = Path(source)
    mcap_path = mcap_file_to_recover(source)
    if destination is None:
        destination = source.with_name(source.name + RECOVERED_SUFFIX)
    data = mcap_path.read_bytes()
    writer = BagWriter(destination)  # refuses an existing destination before anything is created
    created = _first_new_folder(writer.path)
    try:
        with writer:
            copier = _Copier(writer)
            # Channels first from an intact summary, so that a damaged first chunk (which carries them
            # in the data section) does not take the messages of the intact chunks after it along.
            for record in _summary_schemas_and_channels(data):
                copier.copy(record)
            stop_reason, skipped = _copy_records(data, copier)
            if not copier.topics:
                raise BagError(f'{mcap_path} holds no intact MCAP chunk ({stop_reason}); nothing to recover')
        _copy_side_files(source, writer.path)
    except BaseException as err:
        shutil.rmtree(created, ignore_errors=True)
        # The writer's own line for a full disk names the messages its bag keeps: here there is no bag left.
        cause = err if isinstance(err, OSError) else err.__cause__
        if isinstance(err, (OSError, SofiaError)) and isinstance(cause, OSError):
            raise output_error(writer.path, cause) from err
        raise
    return RecoveryReport(
        source=source,
        bag=writer.path,
        topics=writer.topics,
        last_stamp_ns=copier.last_stamp_ns,
        reached_footer=copier.reached_footer,
        stop_reason=stop_reason,
        skipped_offsets=tuple(skipped),
    )


def _copy_side_files(source: Path, bag: Path) -> None:
    """Copy the files a run writes beside its bag (truth.yaml, model.yaml, plan.yaml, summary.json, ...) as they
    are: every regular file of ``source`` but its MCAP files and metadata.yaml, which the rebuilt bag has anew."""
    for path in sorted(source.iterdir()):
        if path.is_file() and path.suffix != '.mcap' and path.name != 'metadata.yaml' and not (bag / path.name).exists():
            shutil.copy2(path, bag / path.name)


def _first_new_folder(path: Path) -> Path:
    """The outermost folder the writer creates for ``path`` (rosbags makes missing parents too)."""
    while not path.parent.exists() and path.parent != path.parent.parent:
        path = path.parent
    return path


_OPCODE_CHUNK = 0x06
_OPCODE_FOOTER = 0x02
#: Footer record: opcode, length, summary start, summary offset start, summary CRC.
_FOOTER = struct.Struct('<BQQQI')
_RECORD_HEAD = 9  # opcode (1 byte) + content length (uint64)


def _top_level_records(data, offset):
    """(offset, end) of each top-level record from ``offset`` while lengths stay inside the file."""
    while offset + _RECORD_HEAD <= len(data):
        length = struct.unpack_from('<Q', data, offset + 1)[0]
        end = offset + _RECORD_HEAD + length
        if end > len(data):
            return
        yield offset, end
        offset = end


def _next_chunk(data, offset):
    """Offset of the next top-level chunk record after ``offset`` that parses whole, or None."""
    position = data.find(bytes([_OPCODE_CHUNK]), offset + 1)
    while position != -1:
        if position + _RECORD_HEAD <= len(data):
            end = position + _RECORD_HEAD + struct.unpack_from('<Q', data, position + 1)[0]
            if end <= len(data) and _parse(data[position:end]) is not None:
                return position
        position = data.find(bytes([_OPCODE_CHUNK]), position + 1)
    return None


def _parse(record_bytes):
    """The records of one top-level record (a chunk yields what it holds), CRCs checked; None if damaged."""
    records = []
    try:
        for record in StreamReader(io.BytesIO(record_bytes), skip_magic=True, validate_crcs=True).records:
            records.append(record)
    except EndOfFile:
        # The reader reports the end of its input so; a record that yielded nothing was damaged.
        return records or None
    except _DAMAGE_ERRORS:
        return None
    return records


def _copy_records(data, copier):
    """Copy every intact top-level record; past a damaged one, or a length that runs past the end of the
    file, resynchronize on the next whole chunk (a damaged magic or header loses only itself).

    The search starts after the last intact record, not after the damaged one: a damaged length (of the
    header, a message index) makes the next record seem to start inside the chunk that really follows.
    Returns why reading ended and the byte offsets of the records skipped (0 for a damaged magic).
    """
    skipped = [] if data.startswith(_MCAP_MAGIC) else [0]
    offset, last_intact, stop_reason = len(_MCAP_MAGIC), 0, 'end of file'
    while offset is not None and offset < len(data):
        resume = None
        for start, end in _top_level_records(data, offset):
            records = _parse(data[start:end])
            if records is None:
                skipped.append(start)
                resume = _next_chunk(data, last_intact)
                break
            for record in records:
                copier.copy(record)
            offset, last_intact = end, start
        else:
            if offset >= len(data) or copier.reached_footer:
                break
            # A record running past the end: the file was cut there, or its length field is damaged.
            resume = _next_chunk(data, last_intact)
            if resume is None:
                stop_reason = f'file cut inside the record at byte {offset}'
                break
            skipped.append(offset)
        offset = resume
    return stop_reason, skipped


def _summary_schemas_and_channels(data):
    """The schema and channel records of the summary section if the footer and the summary's CRC are intact."""
    footer = len(data) - len(_MCAP_MAGIC) - _FOOTER.size
    if footer < len(_MCAP_MAGIC) or data[footer] != _OPCODE_FOOTER or not data.endswith(_MCAP_MAGIC):
        return []
    _, _, summary_start, _, crc = _FOOTER.unpack_from(data, footer)
    if not len(_MCAP_MAGIC) <= summary_start <= footer:
        return []
    if crc and zlib.crc32(data[summary_start:footer + _FOOTER.size - 4]) != crc:  # 0: written without a CRC
        return []
    return [record for record in _parse(data[summary_start:footer]) or () if isinstance(record, (Schema, Channel))]


class _Copier:
    """Copy schemas, channels and messages of an MCAP record stream into a BagWriter."""

    def __init__(self, writer: BagWriter) -> None:
        """Copy into ``writer``."""
        self.writer = writer
        self.last_stamp_ns: int | None = None
        self.reached_footer = False
        self._msgtypes: dict[int, str] = {}
        self._topics: dict[int, str] = {}

    @property
    def topics(self) -> tuple[str, ...]:
        """The topics copied so far."""
        return tuple(self._topics.values())

    def copy(self, record: McapRecord) -> None:
        """Copy one record; records other than schema, channel and message are rebuilt on close."""
        if isinstance(record, Message):
            if record.channel_id not in self._topics:
                return  # its channel was defined in a damaged record
            self.writer.write_raw(self._topics[record.channel_id], record.data, record.log_time)
            self.last_stamp_ns = max(record.log_time, self.last_stamp_ns or 0)
        elif isinstance(record, Schema):
            self._msgtypes[record.id] = record.name
        # The summary section repeats every channel; the first sighting registers it.
        elif isinstance(record, Channel) and record.id not in self._topics \
                and record.schema_id in self._msgtypes:
            msgtype = self._msgtypes[record.schema_id]
            self.writer.add_topic(record.topic, msgtype, latched=_is_latched(record))
            self._topics[record.id] = record.topic
        elif isinstance(record, Footer):
            self.reached_footer = True


def _is_latched(channel: Channel) -> bool:
    """Whether a channel was offered transient-local (rosbag2 keeps its QoS in channel metadata)."""
    text = channel.metadata.get('offered_qos_profiles', '')
    try:
        profiles = safe_load_limited(text, f'the QoS of channel {channel.topic}')
    except ConfigError as err:
        raise BagError(f'{err}; the channel metadata of this .mcap is damaged') from err
    return isinstance(profiles, list) and any(
        isinstance(profile, dict) and profile.get('durability') == 'transient_local' for profile in profiles)
