"""Read a rosbag2 MCAP bag: topics, time-ordered messages, documents, Imu arrays."""

from __future__ import annotations

import datetime as dt
import struct
import sys
from dataclasses import dataclass
from pathlib import Path, PurePath
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml
from mcap.reader import make_reader
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.interfaces import QosDurability
from rosbags.rosbag2 import ReaderError

from sofia_ros.bag.columns import decode_columns, payload_blocks
from sofia_ros.bag.imu import ImuArrays, decode_imu_cdr, decode_imu_payloads, merge_imu_blocks
from sofia_ros.bag.mcap_index import (
    INDEX_DAMAGE_ERRORS,
    check_summary_crc,
    first_damaged_chunk,
    indexed_records,
    last_log_time_ns,
)
from sofia_ros.bag.msgtypes import (
    DOCUMENT_MSGTYPE,
    IMU_MSGTYPE,
    TYPESTORE,
    TopicInfo,
    decode_cdr,
)
from sofia_ros.bag.timebase import epoch_ns_of, has_leading_stamp, shift_stamp, shift_stamps
from sofia_ros.config import MAX_CONFIG_BYTES, safe_load_limited
from sofia_ros.errors import BagError, ConfigError, InvalidArgumentError
from sofia_ros.input_files import read_text_capped, require_regular_file
from sofia_ros.topics import SCENARIO_DOCUMENT

# The zstd module rosbags decompresses chunks with.
if sys.version_info >= (3, 14):
    from compression.zstd import ZstdError
else:
    from backports.zstd import ZstdError

if TYPE_CHECKING:
    from collections.abc import Iterator
    from os import PathLike
    from types import TracebackType

    from rosbags.interfaces import Connection

    RawRecords = Iterator[tuple[Connection, int, bytes]]

__all__ = ['BagReader', 'mcap_file_to_recover']

# What reading a damaged MCAP file raises inside rosbags and decode_cdr: chunk and
# record parsing, zstd, CDR decoding.
_DAMAGE_ERRORS = (AnyReaderError, ReaderError, ZstdError, struct.error, EOFError, ValueError)


class BagReader:
    """Read one bag directory written by BagWriter or ros2 bag; use as a context manager.

    Messages come back as rosbags dataclasses with the ROS field names
    (``msg.angular_velocity.x``), decoded with the definitions stored in the
    bag, which AnyReader checks against their RIHS01 hashes. Chunks are read
    only after their CRC passes; the summary's CRC is checked on opening.

    Times are the bag's own (UTC ns for a campaign's bag) unless ``campaign_time``:
    then log times, ``start_ns``/``stop_ns`` and every leading message stamp
    (a Header or a Time first in the message) count ns from the campaign's start,
    the ``start_utc`` of its /config/scenario, as the cores and the analysis do
    (sofia_ros.bag.timebase).
    """

    def __init__(self, path: str | PathLike[str], *, campaign_time: bool = False) -> None:
        """Check that ``path`` is a closed rosbag2 bag directory in MCAP storage."""
        self.path = Path(path)
        self._metadata = _read_metadata(self.path)
        self._reader = AnyReader([self.path], default_typestore=TYPESTORE)
        self._campaign_time = campaign_time
        self._origin_ns: int | None = None if campaign_time else 0
        self._is_open = False

    def open(self) -> None:
        """Open the bag and read its index, after checking its files against metadata.yaml."""
        files = self._metadata.files
        try:
            if not self._metadata.file_compressed:
                for file in files:
                    check_summary_crc(file)
                _check_metadata_against_mcap(self.path, self._metadata)
            self._reader.open()
        except (*_DAMAGE_ERRORS, *INDEX_DAMAGE_ERRORS) as err:
            raise _damaged(self.path, files, err) from err
        self._is_open = True
        _warn_of_unlisted_files(self.path, files)

    @property
    def origin_ns(self) -> int:
        """ns subtracted from the bag's times: the campaign's start with campaign_time, else 0.

        Looked up when first needed, so that a bag lacking /config/scenario can still be listed.
        """
        if self._origin_ns is None:
            epoch_ns = self.campaign_epoch_ns()
            if self._reader.start_time < epoch_ns:
                raise BagError(
                    f'bag {self.path} starts {(epoch_ns - self._reader.start_time) / 1e9:.0f} s before its campaign '
                    f'start ({SCENARIO_DOCUMENT.name}): it was recorded with times from 0, not in UTC; '
                    're-record it with `sofia run`'
                )
            self._origin_ns = epoch_ns
        return self._origin_ns

    def campaign_epoch_ns(self) -> int:
        """The campaign's start (start_utc of /config/scenario) in ns since the Unix epoch."""
        self._require_open()
        if SCENARIO_DOCUMENT.name not in self._reader.topics:
            raise BagError(f'bag {self.path} has no {SCENARIO_DOCUMENT.name} to take the campaign start from; '
                           'record it with `sofia run`')
        text = self.document(SCENARIO_DOCUMENT.name)
        try:
            start_utc = dt.datetime.fromisoformat(str(yaml.safe_load(text)['start_utc']))
            if start_utc.tzinfo is None:
                raise ValueError('start_utc has no timezone')
        except (yaml.YAMLError, TypeError, KeyError, ValueError) as err:
            raise BagError(
                f'bag {self.path} has no campaign start ({SCENARIO_DOCUMENT.name} with an aware start_utc: '
                f'{type(err).__name__} {err}); record it with `sofia run`'
            ) from err
        return epoch_ns_of(start_utc)

    def close(self) -> None:
        """Close the bag."""
        if self._is_open:
            self._is_open = False
            self._reader.close()

    def __enter__(self) -> BagReader:
        """Open the bag."""
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc_value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        """Close the bag."""
        self.close()

    @property
    def listed_topic_counts(self) -> dict[str, int]:
        """Topic -> message count as metadata.yaml lists them, without opening the bag (its files unchecked)."""
        return dict(self._metadata.topic_counts)

    @property
    def topics(self) -> tuple[TopicInfo, ...]:
        """Every topic with its type and message count, sorted by name."""
        self._require_open()
        return tuple(
            TopicInfo(name, info.msgtype or '', info.msgcount)
            for name, info in sorted(self._reader.topics.items())
        )

    def latched_topics(self) -> frozenset[str]:
        """Topics whose recorded offered QoS is transient-local (documents, /clock): a replay re-latches them."""
        return frozenset(
            name for name, info in self._reader.topics.items()
            for connection in info.connections
            if any(qos.durability == QosDurability.TRANSIENT_LOCAL
                   for qos in getattr(connection.ext, 'offered_qos_profiles', ()))
        )

    def topic(self, name: str) -> TopicInfo:
        """Return the TopicInfo of ``name``; raise BagError if the bag lacks it."""
        for info in self.topics:
            if info.name == name:
                return info
        names = ', '.join(info.name for info in self.topics) or 'none'
        raise BagError(f'topic {name} is not in bag {self.path}; pick one of: {names}')

    def messages(
        self, *topics: str, start_ns: int | None = None, stop_ns: int | None = None
    ) -> Iterator[tuple[str, int, Any]]:
        """Iterate (topic, stamp_ns, message) in log-time order over ``topics`` (all if none)."""
        return self._decoded(self._raw(topics, start_ns, stop_ns))

    def raw_messages(
        self, *topics: str, start_ns: int | None = None, stop_ns: int | None = None
    ) -> Iterator[tuple[str, int, bytes]]:
        """Iterate (topic, stamp_ns, CDR bytes) in log-time order, e.g. to re-publish them."""
        records = self._raw(topics, start_ns, stop_ns)
        return ((connection.topic, stamp_ns, data) for connection, stamp_ns, data in records)

    def messages_by_topic(
        self, *topics: str, raw: tuple[str, ...] = (), imu: tuple[str, ...] = (), columns: tuple[str, ...] = ()
    ) -> dict[str, Any]:
        """One pass over ``topics``: topic -> (log stamps ns, messages); topics in ``raw`` keep CDR bytes,
        topics in ``imu`` come back as ImuArrays decoded in bulk, topics in ``columns`` as MessageColumns
        (bag.columns: every field an array, without a Python object per message).

        Read through the MCAP message indexes where the file has them (mcap_index), else record by record.
        """
        for topic in imu:
            if (msgtype := self.topic(topic).msgtype) != IMU_MSGTYPE:
                raise BagError(f'topic {topic} in bag {self.path} holds {msgtype}, not {IMU_MSGTYPE}')
        tables = tuple(topic for topic in columns if topic in topics)
        collected = self._indexed(topics, {**{topic: None for topic in tables},
                                           **{topic: decode_imu_payloads for topic in imu}})
        if collected is None:
            # _raw gives campaign time already.
            collected = {topic: ([], []) for topic in topics}
            for connection, stamp_ns, data in self._raw(topics, None, None):
                collected[connection.topic][0].append(stamp_ns)
                collected[connection.topic][1].append(data)
            for topic in tables:
                collected[topic] = payload_blocks(*collected[topic])
        else:
            for topic in topics:
                if topic in tables:
                    msgtype = self.topic(topic).msgtype
                    collected[topic] = [self._block_to_campaign_time(msgtype, stamps, rows)
                                        for stamps, rows in collected[topic]]
                elif topic not in imu:
                    collected[topic] = self._to_campaign_time(self.topic(topic).msgtype, *collected[topic])
        typestore = self._reader.typestore
        for topic in topics:
            try:
                if topic in imu:
                    records = collected[topic]
                    if isinstance(records, list):  # blocks read through the indexes: the bag's own times
                        collected[topic] = self._imu_to_campaign_time(merge_imu_blocks(records))
                    else:  # records of _raw: in campaign time already
                        collected[topic] = decode_imu_cdr(*records)
                elif topic in tables:
                    collected[topic] = decode_columns(collected[topic], self.topic(topic).msgtype, typestore)
                elif topic not in raw:
                    msgtype = self.topic(topic).msgtype
                    collected[topic] = (collected[topic][0],
                                        [decode_cdr(data, msgtype, typestore) for data in collected[topic][1]])
            except InvalidArgumentError as err:
                raise BagError(f'topic {topic} in bag {self.path}: {err}') from err
            except _DAMAGE_ERRORS as err:
                raise _damaged(self.path, self._metadata.files, err) from err
        return collected

    def document(self, topic: str) -> str:
        """Return the text of the last document (std_msgs/String) stored on ``topic``."""
        if (msgtype := self.topic(topic).msgtype) != DOCUMENT_MSGTYPE:
            raise BagError(
                f'topic {topic} in bag {self.path} holds {msgtype}, '
                f'not a {DOCUMENT_MSGTYPE} document'
            )
        # Read without times, so that campaign_epoch_ns can read the scenario before the origin is known.
        self._require_open()
        records = self._guarded(self._reader.messages(self._connections(topic)), 0)
        try:
            texts = [decode_cdr(data, DOCUMENT_MSGTYPE).data for _, _, data in records]
        except _DAMAGE_ERRORS as err:
            raise _damaged(self.path, self._metadata.files, err) from err
        if not texts:
            raise BagError(f'topic {topic} in bag {self.path} holds no document')
        return texts[-1]

    def check_chunks(self) -> None:
        """Check every chunk of the bag's MCAP files (size, zstd frame, CRC) before any is used: a reader that acts
        on each message as it comes (`sofia replay`) would otherwise have acted on those before a damaged chunk.

        Raises:
            BagError: a chunk fails, named with `sofia recover`.
        """
        self._require_open()
        for mcap_file in self._metadata.files:
            try:
                damage = first_damaged_chunk(mcap_file)
            except (*INDEX_DAMAGE_ERRORS, OSError) as err:
                raise _damaged(self.path, self._metadata.files, err) from err
            if damage is not None:
                raise _damaged(self.path, self._metadata.files, ValueError(damage))

    def last_log_time_ns(self, topic: str) -> int | None:
        """The log time of the last message on ``topic`` (None if it has none), without reading the other chunks."""
        self._require_open()
        if self.topic(topic).count == 0:
            return None
        if (mcap_file := self._indexable_file()) is not None:
            try:
                latest_ns = last_log_time_ns(mcap_file, topic)
            except INDEX_DAMAGE_ERRORS as err:
                raise _damaged(self.path, self._metadata.files, err) from err
            if latest_ns is not None:
                return latest_ns - self.origin_ns
        stamps_ns = self.messages_by_topic(topic, raw=(topic,))[topic][0]
        return int(stamps_ns[-1]) if len(stamps_ns) else None

    def imu_arrays(
        self, topic: str, *, start_ns: int | None = None, stop_ns: int | None = None
    ) -> ImuArrays:
        """Return the sensor_msgs/Imu samples of ``topic`` (log times in [start_ns, stop_ns)) as arrays."""
        imu = self.messages_by_topic(topic, imu=(topic,))[topic]
        keep = np.ones(len(imu.stamp_ns), dtype=bool)
        if start_ns is not None:
            keep &= imu.stamp_ns >= start_ns
        if stop_ns is not None:
            keep &= imu.stamp_ns < stop_ns
        if keep.all():
            return imu
        return ImuArrays(imu.stamp_ns[keep], imu.header_stamp_ns[keep], imu.angular_velocity_rad_per_s[keep],
                         imu.linear_acceleration_m_per_s2[keep])

    def _indexed(self, topics: tuple[str, ...], packed: dict[str, Any]) -> dict[str, Any] | None:
        """The raw records of ``topics`` read through the message indexes of a one-file bag, or None."""
        self._require_open()
        for topic in topics:
            self.topic(topic)
        files = self._metadata.files
        if (mcap_file := self._indexable_file()) is None:
            return None
        try:
            return indexed_records(mcap_file, topics, packed)
        except InvalidArgumentError as err:  # payloads that are not Imu CDR, found while decoding them
            decoded = [topic for topic, decode in packed.items() if decode is not None]
            raise BagError(f'topic {", ".join(decoded)} in bag {self.path}: {err}') from err
        except INDEX_DAMAGE_ERRORS as err:
            raise _damaged(self.path, files, err) from err

    def _indexable_file(self) -> Path | None:
        """The bag's MCAP file when its message indexes can be read in place (one file, not file-compressed)."""
        files = self._metadata.files
        return files[0] if len(files) == 1 and not self._metadata.file_compressed else None

    def _require_open(self) -> None:
        """Raise unless the bag is open."""
        if not self._is_open:
            raise BagError(f'bag {self.path} is not open; use it inside `with BagReader(...)`')

    def _raw(
        self, topics: tuple[str, ...], start_ns: int | None, stop_ns: int | None
    ) -> RawRecords:
        """Iterate (connection, stamp_ns, bytes) of ``topics`` (all if empty) in log-time order."""
        # Checked now, not at the first next(), so a wrong topic fails where it is asked for.
        self._require_open()
        names = topics or tuple(info.name for info in self.topics)
        connections = [conn for name in names for conn in self._connections(name)]
        origin_ns = self.origin_ns
        start_ns = None if start_ns is None else start_ns + origin_ns
        stop_ns = None if stop_ns is None else stop_ns + origin_ns
        return self._guarded(self._reader.messages(connections, start=start_ns, stop=stop_ns), origin_ns)

    def _guarded(self, records: RawRecords, origin_ns: int) -> RawRecords:
        """Pass ``records`` through moved back by ``origin_ns``, turning damage found while reading into BagError."""
        try:
            for connection, stamp_ns, data in records:
                if origin_ns and has_leading_stamp(connection.msgtype):
                    data = shift_stamp(data, -origin_ns)
                yield connection, stamp_ns - origin_ns, data
        except _DAMAGE_ERRORS as err:
            raise _damaged(self.path, self._metadata.files, err) from err

    def _to_campaign_time(self, msgtype: str, stamps_ns: list[int], payloads: list) -> tuple[list[int], list]:
        """Log times and CDR payloads of one topic moved to campaign time."""
        if not self.origin_ns:
            return stamps_ns, payloads
        if has_leading_stamp(msgtype):
            payloads = [shift_stamp(data, -self.origin_ns) for data in payloads]
        return [stamp_ns - self.origin_ns for stamp_ns in stamps_ns], payloads

    def _imu_to_campaign_time(self, arrays: ImuArrays) -> ImuArrays:
        """Imu arrays read in the bag's time moved to campaign time (log times and header stamps)."""
        if not self.origin_ns:
            return arrays
        return ImuArrays(arrays.stamp_ns - self.origin_ns, arrays.header_stamp_ns - self.origin_ns,
                         arrays.angular_velocity_rad_per_s, arrays.linear_acceleration_m_per_s2)

    def _block_to_campaign_time(self, msgtype: str, stamps_ns: np.ndarray, rows: np.ndarray) -> tuple:
        """Log times and equal-length CDR rows of one topic moved to campaign time."""
        if not self.origin_ns:
            return stamps_ns, rows
        try:
            shifted = shift_stamps(rows, -self.origin_ns) if has_leading_stamp(msgtype) else rows
            return stamps_ns - self.origin_ns, shifted
        except ValueError as err:
            raise BagError(f'{msgtype} in bag {self.path}: {err}') from err

    def _decoded(self, records: RawRecords) -> Iterator[tuple[str, int, Any]]:
        """Decode ``records`` into (topic, stamp_ns, message)."""
        typestore = self._reader.typestore
        for connection, stamp_ns, data in records:
            try:
                message = decode_cdr(data, connection.msgtype, typestore)
            except _DAMAGE_ERRORS as err:
                raise _damaged(self.path, self._metadata.files, err) from err
            yield connection.topic, stamp_ns, message

    def _connections(self, name: str) -> list[Connection]:
        """The rosbags connections of topic ``name``; raise BagError if the bag lacks it."""
        self.topic(name)
        return self._reader.topics[name].connections


@dataclass(frozen=True)
class _Metadata:
    """What metadata.yaml says a bag holds: its MCAP files and what they should hold together."""

    #: the files of relative_file_paths, in the bag directory, each a regular file
    files: tuple[Path, ...]
    #: topic -> messages it lists (topics_with_message_count)
    topic_counts: dict[str, int]
    message_count: int
    start_ns: int
    duration_ns: int
    #: file names of its per-file `files:` section (empty when it has none)
    described_files: tuple[str, ...]
    #: whether each file is zstd-compressed whole (ros2 bag's file compression): then rosbags unpacks
    #: it, and the MCAP-level checks and indexes of this module do not apply
    file_compressed: bool


def _read_metadata(path: Path) -> _Metadata:
    """Check that ``path`` is a closed rosbag2 directory in MCAP storage; what its metadata.yaml lists."""
    _check_bag_directory(path)
    metadata_path = path / 'metadata.yaml'
    try:
        info = _rosbag2_information(metadata_path)
        storage = info['storage_identifier']
        if storage == 'mcap':
            listed_names = _listed_file_names(info)
            topic_counts: dict[str, int] = {}
            for item in info['topics_with_message_count']:
                name = item['topic_metadata']['name']
                topic_counts[name] = topic_counts.get(name, 0) + _count(item['message_count'])
            message_count = _count(info['message_count'])
            start_ns = _count(info['starting_time']['nanoseconds_since_epoch'])
            duration_ns = _count(info['duration']['nanoseconds'])
            described = tuple(PurePath(str(entry['path'])).name for entry in info.get('files') or ())
            file_compressed = str(info.get('compression_mode') or '').lower() == 'file'
    except (ConfigError, KeyError, TypeError, AttributeError, ValueError) as err:
        detail = str(err).strip().splitlines()[0] if str(err).strip() else ''
        raise BagError(
            f'{metadata_path} is not rosbag2 metadata ({type(err).__name__}: {detail}); {_recover_hint(path)}'
        ) from err
    if storage != 'mcap':
        raise BagError(
            f'bag {path} uses {storage!r} storage, not MCAP; convert it with '
            f'`rosbags-convert --src {path} --dst NEW_DIR --dst-storage mcap`'
        )
    return _Metadata(_listed_files(path, listed_names), topic_counts, message_count, start_ns, duration_ns,
                     described, file_compressed)


def _check_bag_directory(path: Path) -> None:
    """Raise BagError unless ``path`` is a directory holding a metadata.yaml (or a link to one)."""
    if not path.exists():
        raise BagError(
            f'bag {path} does not exist; pass a bag directory (metadata.yaml + .mcap) under bags/'
        )
    if not path.is_dir():
        raise BagError(
            f'{path} is a file, not a rosbag2 bag directory; '
            'pass the directory holding metadata.yaml and the .mcap file'
        )
    metadata_path = path / 'metadata.yaml'
    if not metadata_path.exists() and not metadata_path.is_symlink():
        if _recoverable(path):
            raise BagError(
                f'bag {path} was not closed (no metadata.yaml: its writer is still recording, or stopped before '
                f'finishing); once no run writes it, recover what it holds with `sofia recover {path}`'
            )
        raise BagError(
            f'{path} is not a rosbag2 bag directory (no metadata.yaml and no MCAP data to recover); '
            'pass a bag written by the recorder'
        )


def _rosbag2_information(metadata_path: Path) -> dict[str, Any]:
    """The rosbag2_bagfile_information mapping of a metadata.yaml, read capped (ConfigError, KeyError otherwise)."""
    text = read_text_capped(metadata_path, MAX_CONFIG_BYTES, 'rosbag2 metadata.yaml')
    try:
        document = safe_load_limited(text, str(metadata_path))
    except yaml.YAMLError as err:  # PyYAML refuses control characters already when the loader is made
        raise ConfigError(f'{metadata_path}: not YAML text ({str(err).splitlines()[0]})') from err
    if not isinstance(document, dict) or not isinstance(document.get('rosbag2_bagfile_information'), dict):
        raise KeyError('rosbag2_bagfile_information')
    return document['rosbag2_bagfile_information']


def _listed_file_names(info: dict[str, Any]) -> tuple[str, ...]:
    """The file names of relative_file_paths, as rosbags opens them (the name inside the bag directory)."""
    paths = info['relative_file_paths']
    if not isinstance(paths, list) or not paths or not all(isinstance(name, str) for name in paths):
        raise TypeError(f'relative_file_paths is {paths!r}, not a list of file names')
    return tuple(PurePath(name).name for name in paths)


def _count(value: object) -> int:
    """A count or a time in ns from metadata.yaml: an int >= 0 (TypeError, ValueError otherwise)."""
    if type(value) is not int:  # noqa: E721  (bool is not a count)
        raise TypeError(f'{value!r} is not a whole number')
    if value < 0:
        raise ValueError(f'{value} is negative')
    return value


def _listed_files(path: Path, names: tuple[str, ...]) -> tuple[Path, ...]:
    """The regular files of ``names`` in bag directory ``path``; BagError naming one that is missing or not a file.

    Only these are read: an unlisted .mcap beside them (a copy, another run's file) is not part of the bag.
    """
    files = []
    for name in names:
        file = path / name
        if not file.exists() and not file.is_symlink():
            present = ', '.join(sorted(other.name for other in path.glob('*.mcap'))) or 'none'
            raise BagError(
                f'bag {path}: its metadata.yaml lists {name}, which is not in the bag (.mcap files there: '
                f'{present}); restore the file, or if the metadata.yaml belongs to another recording rebuild the '
                f'bag from its .mcap with `sofia recover {path}` (writes {path}_recovered)'
            )
        try:
            files.append(require_regular_file(file, 'MCAP file'))
        except ConfigError as err:
            raise BagError(f'bag {path}: {err}; {_recover_hint(path)}') from err
    return tuple(files)


def _check_metadata_against_mcap(path: Path, metadata: _Metadata) -> None:
    """Raise BagError when metadata.yaml does not describe its MCAP files (a metadata.yaml of another run).

    Its topics, message counts, start and duration are what rosbags reports, and its per-topic counts
    what the analysis trusts: checked against the MCAP summaries' statistics. A file written without
    statistics has nothing to check against.
    """
    file_counts: dict[str, int] = {}
    starts, ends = [], []
    for file in metadata.files:
        with file.open('rb') as stream:
            summary = make_reader(stream).get_summary()
        if summary is None or summary.statistics is None:
            return
        statistics = summary.statistics
        for channel_id, count in statistics.channel_message_counts.items():
            channel = summary.channels.get(channel_id)
            topic = channel.topic if channel else f'channel {channel_id}'
            file_counts[topic] = file_counts.get(topic, 0) + count
        if statistics.message_count:
            starts.append(statistics.message_start_time)
            ends.append(statistics.message_end_time)
    names = ', '.join(file.name for file in metadata.files)
    mismatch = _first_mismatch(metadata, file_counts, starts, ends)
    if mismatch:
        raise BagError(
            f'bag {path}: metadata.yaml does not match {names}: {mismatch} (a metadata.yaml of another '
            f'recording?); rebuild the bag from its .mcap with `sofia recover {path}` (writes {path}_recovered)'
        )


def _first_mismatch(metadata: _Metadata, file_counts: dict[str, int], starts: list[int], ends: list[int]) -> str:
    """What metadata.yaml says that the MCAP statistics contradict first ('' if nothing)."""
    described = set(metadata.described_files) - {file.name for file in metadata.files}
    if described:
        return f'its files: section describes {", ".join(sorted(described))}, which relative_file_paths does not list'
    listed = {topic: count for topic, count in metadata.topic_counts.items() if count}
    held = {topic: count for topic, count in file_counts.items() if count}
    for topic in sorted(set(listed) | set(held)):
        if listed.get(topic, 0) != held.get(topic, 0):
            return f'it lists {listed.get(topic, 0)} messages on {topic}, the MCAP file(s) hold {held.get(topic, 0)}'
    if metadata.message_count != sum(held.values()):
        return f'it lists {metadata.message_count} messages, the MCAP file(s) hold {sum(held.values())}'
    if starts:
        start_ns, duration_ns = min(starts), max(ends) - min(starts)
        if metadata.start_ns != start_ns:
            return f'its starting time is {metadata.start_ns} ns, the first message is logged at {start_ns} ns'
        if metadata.duration_ns != duration_ns:
            return f'its duration is {metadata.duration_ns} ns, the messages span {duration_ns} ns'
    return ''


#: Bags whose unlisted .mcap files were already pointed out by this process (a command may open a bag twice).
_WARNED_OF_UNLISTED: set[Path] = set()


def _warn_of_unlisted_files(path: Path, files: tuple[Path, ...]) -> None:
    """One line on stderr when the bag directory holds .mcap files its metadata.yaml does not list."""
    unlisted = sorted(other.name for other in path.glob('*.mcap') if other not in files)
    if unlisted and path.resolve() not in _WARNED_OF_UNLISTED:
        _WARNED_OF_UNLISTED.add(path.resolve())
        print(f'sofia: warning: bag {path} holds {", ".join(unlisted)}, which its metadata.yaml does not list: '
              f'read only {", ".join(file.name for file in files)}; move the other file(s) out of the bag',
              file=sys.stderr)


def mcap_file_to_recover(source: Path) -> Path:
    """The one MCAP file of bag directory ``source`` that `sofia recover` reads; BagError naming why not.

    The file metadata.yaml lists when it can be read and lists one file that is there (a stray
    .mcap beside it is not the bag's), else the one .mcap file of the directory.
    """
    if not source.is_dir():
        raise BagError(f'bag {source} is not a directory; pass the bag directory holding the .mcap')
    candidates = [source / name for name in _readable_listing(source) if (source / name).exists()]
    if not candidates:
        candidates = sorted(source.glob('*.mcap'))
    if not candidates:
        raise BagError(f'bag {source} holds 0 .mcap files; nothing to recover there')
    if len(candidates) > 1:
        names = ', '.join(file.name for file in candidates)
        raise BagError(f'bag {source} holds {len(candidates)} .mcap files to recover ({names}), and its '
                       'metadata.yaml (if any) does not name one of them; move all but one out and recover one '
                       'file at a time')
    try:
        return require_regular_file(candidates[0], 'MCAP file')
    except ConfigError as err:
        raise BagError(f'bag {source}: {err}; nothing to recover there') from err


def _readable_listing(source: Path) -> tuple[str, ...]:
    """The file names a bag's metadata.yaml lists, or none if it is missing or unreadable."""
    try:
        return _listed_file_names(_rosbag2_information(source / 'metadata.yaml'))
    except (ConfigError, KeyError, TypeError, AttributeError):
        return ()


def _recoverable(path: Path) -> bool:
    """Whether ``path`` holds an MCAP file for `sofia recover` with more than its magic."""
    try:
        return mcap_file_to_recover(path).stat().st_size > 8
    except (BagError, OSError):
        return False


def _recover_hint(path: Path) -> str:
    """How to rebuild a bag whose metadata cannot be used, or that there is nothing to rebuild it from."""
    if _recoverable(path):
        return f'rebuild the bag with `sofia recover {path}`'
    return 'its .mcap holds nothing to recover'


def _damaged(path: Path, files: tuple[Path, ...], err: BaseException) -> BagError:
    """The BagError for a bag whose MCAP file is truncated or corrupt, naming the first damaged chunk if any."""
    if len(files) == 1 and 'chunk' not in str(err):
        try:
            chunk = first_damaged_chunk(files[0])
        except (*INDEX_DAMAGE_ERRORS, OSError, AttributeError):
            chunk = None
        if chunk is not None:
            err = ValueError(chunk)
    detail = str(err).strip().splitlines()[0] if str(err).strip() else ''
    hint = (f'salvage its complete chunks with `sofia recover {path}`' if _recoverable(path)
            else 'it holds nothing to recover')
    return BagError(f'bag {path} is truncated or corrupt ({type(err).__name__}: {detail}); {hint}')
