"""Read a rosbag2 MCAP bag: topics, time-ordered messages, documents, Imu arrays."""

from __future__ import annotations

import struct
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import yaml
from rosbags.highlevel import AnyReader, AnyReaderError
from rosbags.rosbag2 import ReaderError

from sofia_ros.bag.imu import ImuArrays, decode_imu_blocks, decode_imu_cdr
from sofia_ros.bag.mcap_index import INDEX_DAMAGE_ERRORS, indexed_records
from sofia_ros.bag.msgtypes import (
    DOCUMENT_MSGTYPE,
    IMU_MSGTYPE,
    TYPESTORE,
    TopicInfo,
    decode_cdr,
)
from sofia_ros.errors import BagError, InvalidArgumentError

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

__all__ = ['BagReader']

# What reading a damaged MCAP file raises inside rosbags and decode_cdr: chunk and
# record parsing, zstd, CDR decoding.
_DAMAGE_ERRORS = (AnyReaderError, ReaderError, ZstdError, struct.error, EOFError, ValueError)


class BagReader:
    """Read one bag directory written by BagWriter or ros2 bag; use as a context manager.

    Messages come back as rosbags dataclasses with the ROS field names
    (``msg.angular_velocity.x``), decoded with the definitions stored in the
    bag, which AnyReader checks against their RIHS01 hashes.
    """

    def __init__(self, path: str | PathLike[str]) -> None:
        """Check that ``path`` is a closed rosbag2 bag directory in MCAP storage."""
        self.path = Path(path)
        _check_layout(self.path)
        self._reader = AnyReader([self.path], default_typestore=TYPESTORE)
        self._is_open = False

    def open(self) -> None:
        """Open the bag and read its index."""
        try:
            self._reader.open()
        except _DAMAGE_ERRORS as err:
            raise _damaged(self.path, err) from err
        self._is_open = True

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
    def topics(self) -> tuple[TopicInfo, ...]:
        """Every topic with its type and message count, sorted by name."""
        self._require_open()
        return tuple(
            TopicInfo(name, info.msgtype or '', info.msgcount)
            for name, info in sorted(self._reader.topics.items())
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
        self, *topics: str, raw: tuple[str, ...] = (), imu: tuple[str, ...] = ()
    ) -> dict[str, Any]:
        """One pass over ``topics``: topic -> (log stamps ns, messages); topics in ``raw`` keep CDR bytes,
        topics in ``imu`` come back as ImuArrays decoded in bulk.

        Read through the MCAP message indexes where the file has them (mcap_index), else record by record.
        """
        for topic in imu:
            if (msgtype := self.topic(topic).msgtype) != IMU_MSGTYPE:
                raise BagError(f'topic {topic} in bag {self.path} holds {msgtype}, not {IMU_MSGTYPE}')
        collected = self._indexed(topics, imu)
        if collected is None:
            collected = {topic: ([], []) for topic in topics}
            for connection, stamp_ns, data in self._raw(topics, None, None):
                collected[connection.topic][0].append(stamp_ns)
                collected[connection.topic][1].append(data)
        typestore = self._reader.typestore
        for topic in topics:
            try:
                if topic in imu:
                    records = collected[topic]
                    collected[topic] = (decode_imu_blocks(records) if isinstance(records, list)
                                        else decode_imu_cdr(*records))
                elif topic not in raw:
                    msgtype = self.topic(topic).msgtype
                    collected[topic] = (collected[topic][0],
                                        [decode_cdr(data, msgtype, typestore) for data in collected[topic][1]])
            except InvalidArgumentError as err:
                raise BagError(f'topic {topic} in bag {self.path}: {err}') from err
            except _DAMAGE_ERRORS as err:
                raise _damaged(self.path, err) from err
        return collected

    def document(self, topic: str) -> str:
        """Return the text of the last document (std_msgs/String) stored on ``topic``."""
        if (msgtype := self.topic(topic).msgtype) != DOCUMENT_MSGTYPE:
            raise BagError(
                f'topic {topic} in bag {self.path} holds {msgtype}, '
                f'not a {DOCUMENT_MSGTYPE} document'
            )
        texts = [message.data for _, _, message in self.messages(topic)]
        if not texts:
            raise BagError(f'topic {topic} in bag {self.path} holds no document')
        return texts[-1]

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

    def _indexed(self, topics: tuple[str, ...], packed: tuple[str, ...]) -> dict[str, Any] | None:
        """The raw records of ``topics`` read through the message indexes of a one-file bag, or None."""
        self._require_open()
        for topic in topics:
            self.topic(topic)
        files = list(self.path.glob('*.mcap'))
        if len(files) != 1:
            return None
        try:
            return indexed_records(files[0], topics, packed)
        except INDEX_DAMAGE_ERRORS as err:
            raise _damaged(self.path, err) from err

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
        return self._guarded(self._reader.messages(connections, start=start_ns, stop=stop_ns))

    def _guarded(self, records: RawRecords) -> RawRecords:
        """Pass ``records`` through, turning damage found while reading into BagError."""
        try:
            yield from records
        except _DAMAGE_ERRORS as err:
            raise _damaged(self.path, err) from err

    def _decoded(self, records: RawRecords) -> Iterator[tuple[str, int, Any]]:
        """Decode ``records`` into (topic, stamp_ns, message)."""
        typestore = self._reader.typestore
        for connection, stamp_ns, data in records:
            try:
                message = decode_cdr(data, connection.msgtype, typestore)
            except _DAMAGE_ERRORS as err:
                raise _damaged(self.path, err) from err
            yield connection.topic, stamp_ns, message

    def _connections(self, name: str) -> list[Connection]:
        """The rosbags connections of topic ``name``; raise BagError if the bag lacks it."""
        self.topic(name)
        return self._reader.topics[name].connections


def _check_layout(path: Path) -> None:
    """Raise BagError unless ``path`` is a closed rosbag2 directory in MCAP storage."""
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
    if not metadata_path.is_file():
        if _recoverable(path):
            raise BagError(
                f'bag {path} was not closed (no metadata.yaml; its writer stopped before '
                f'finishing); recover what it holds with `sofia recover {path}`'
            )
        raise BagError(
            f'{path} is not a rosbag2 bag directory (no metadata.yaml and no MCAP data to recover); '
            'pass a bag written by the recorder'
        )
    try:
        metadata = yaml.safe_load(metadata_path.read_text())
        storage = metadata['rosbag2_bagfile_information']['storage_identifier']
    except (OSError, UnicodeDecodeError, yaml.YAMLError, KeyError, TypeError) as err:
        first_line = str(err).strip().splitlines()[0] if str(err).strip() else ''
        hint = (f'rebuild the bag with `sofia recover {path}`' if _recoverable(path)
                else 'its .mcap holds nothing to recover')
        raise BagError(
            f'{metadata_path} is not rosbag2 metadata ({type(err).__name__}: {first_line}); {hint}'
        ) from err
    if storage != 'mcap':
        raise BagError(
            f'bag {path} uses {storage!r} storage, not MCAP; convert it with '
            f'`rosbags-convert --src {path} --dst NEW_DIR --dst-storage mcap`'
        )


def _recoverable(path: Path) -> bool:
    """Whether ``path`` holds exactly one .mcap with more than its magic (what recover_bag can read)."""
    files = list(path.glob('*.mcap'))
    return len(files) == 1 and files[0].stat().st_size > 8


def _damaged(path: Path, err: BaseException) -> BagError:
    """The BagError for a bag whose MCAP file is truncated or corrupt."""
    detail = str(err).strip().splitlines()[0] if str(err).strip() else ''
    hint = (f'salvage its complete chunks with `sofia recover {path}`' if _recoverable(path)
            else 'it holds nothing to recover')
    return BagError(f'bag {path} is truncated or corrupt ({type(err).__name__}: {detail}); {hint}')
