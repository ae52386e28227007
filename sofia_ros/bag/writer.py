"""Write a rosbag2 bag in MCAP storage from raw CDR bytes or rclpy message objects."""

from __future__ import annotations

import operator
import shutil
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import StoragePlugin, Writer, WriterError
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode
from std_msgs.msg import String

from sofia_ros.bag.mcap_storage import CheckedMcapStorage
from sofia_ros.bag.msgtypes import (
    DOCUMENT_MSGTYPE,
    TYPESTORE,
    TopicInfo,
    checked_msgtype,
    msgtype_of,
    wire_cdr,
)
from sofia_ros.bag.timebase import has_leading_stamp, shift_stamp, shift_stamps
from sofia_ros.errors import BagError, InvalidArgumentError, OutputError
from sofia_ros.output_files import describe_os_error, output_error

if TYPE_CHECKING:
    from os import PathLike
    from types import TracebackType

    from rosbags.interfaces import Connection

__all__ = ['BagWriter', 'LATCHED_QOS', 'ROSBAG2_VERSION', 'STREAM_QOS']

#: rosbag2 metadata version written (the one Jazzy and later read natively).
ROSBAG2_VERSION = 9
_NO_TIME = QosTime(0, 0)
#: Offered QoS of latched topics (the documents, /clock, a case's subsystem status): `ros2 bag play`
#: re-offers them transient-local, so a node that starts late still receives the last one.
LATCHED_QOS = Qos(
    history=QosHistory.KEEP_LAST,
    depth=1,
    reliability=QosReliability.RELIABLE,
    durability=QosDurability.TRANSIENT_LOCAL,
    deadline=_NO_TIME,
    lifespan=_NO_TIME,
    liveliness=QosLiveliness.AUTOMATIC,
    liveliness_lease_duration=_NO_TIME,
    avoid_ros_namespace_conventions=False,
)
#: Offered QoS of every other topic: what the graph's data publishers offer one another over DDS (nodes.sync.DATA_QOS).
STREAM_QOS = Qos(
    history=QosHistory.KEEP_ALL,
    depth=1000,
    reliability=QosReliability.RELIABLE,
    durability=QosDurability.VOLATILE,
    deadline=_NO_TIME,
    lifespan=_NO_TIME,
    liveliness=QosLiveliness.AUTOMATIC,
    liveliness_lease_duration=_NO_TIME,
    avoid_ros_namespace_conventions=False,
)


class _CountingMcapStorage(CheckedMcapStorage):
    """The CRC-checked MCAP storage, counting the messages whose chunks the file has handed to the OS: what a
    bag cut short by a full disk keeps (``sofia recover`` restores them)."""

    messages_on_disk = 0

    def _write_chunk(self, batch: list[tuple[int, int, bytes]], start: int) -> int:
        """CheckedMcapStorage._write_chunk, the chunk then flushed: its messages count once the OS has it whole."""
        end = super()._write_chunk(batch, start)
        self._file.flush()
        self.messages_on_disk += end - start
        return end


class _Rosbag2Writer(Writer):
    """rosbags' rosbag2 writer (metadata.yaml, connections, QoS) over the CRC-checked MCAP storage."""

    STORAGE_PLUGINS = {StoragePlugin.MCAP: _CountingMcapStorage}

    def write(self, connection: Connection, timestamp: int, data: bytes | memoryview) -> None:
        """rosbags' write without its linear search of the connection list (each 400 Hz sample passes here).

        BagWriter hands over only connections it added; per-message compression (which
        BagWriter never asks for) still goes through rosbags' own write.
        """
        if self.compression_mode == CompressionMode.MESSAGE or not self.storage:
            super().write(connection, timestamp, data)
            return
        self.storage.write(connection, timestamp, data)
        self.counts[connection.id] += 1
        if timestamp < self.min_timestamp:
            self.min_timestamp = timestamp
        if timestamp > self.max_timestamp:
            self.max_timestamp = timestamp

    def write_block(self, connection: Connection, timestamps: np.ndarray, rows: np.ndarray) -> None:
        """write() of each (timestamp, row) of a non-empty block (int64 ns, the rows of a 2-D uint8 array of CDR) in
        turn, the per-message bookkeeping done once."""
        if self.compression_mode == CompressionMode.MESSAGE or not self.storage:
            for timestamp, row in zip(timestamps.tolist(), rows):
                self.write(connection, timestamp, row.tobytes())
            return
        self.storage.write_block(connection, timestamps, rows)
        self.counts[connection.id] += len(timestamps)
        self.min_timestamp = min(self.min_timestamp, int(timestamps.min()))
        self.max_timestamp = max(self.max_timestamp, int(timestamps.max()))


class BagWriter:
    """Write one new bag directory; use as a context manager.

    Messages are buffered; :meth:`flush` writes them as MCAP chunks, each sorted by log
    time, and hands them to the OS, so a killed process loses only what was written
    after the last flush. The writer flushes by itself whenever a message's log time
    passes the previous flush by ``flush_period_ns``: then every buffered message
    logged before that message goes out, and that message and any later one wait, so
    that the chunks of a lock-step run (whose ticks write their own stamps only) follow
    each other in time without overlap. Counting log time, not wall time, keeps the
    chunk layout, and so the bag's bytes, the same each time a seeded run is repeated.

    ``epoch_ns`` (ns since the Unix epoch; the scenario's start) is added to every log
    time and every leading message stamp written (sofia_ros.bag.timebase): callers write
    campaign time, the bag holds UTC.

    Only :meth:`close` writes ``metadata.yaml``; leaving the ``with`` block by an
    exception aborts instead, so a bag that was not closed never looks complete.
    The disk filling up (or any OSError writing the file) aborts the bag at once and
    raises OutputError (exit code 3 for a full disk) naming how many messages it
    keeps; a bag that cannot even be created is removed. Not thread-safe: call it
    from one thread (or under one lock).
    """

    def __init__(
        self,
        path: str | PathLike[str],
        *,
        compress: bool = True,
        flush_period_ns: int = 1_000_000_000,
        epoch_ns: int = 0,
    ) -> None:
        """Prepare a writer for the new bag directory ``path`` (zstd chunks if ``compress``)."""
        self.path = Path(path)
        self._flush_period_ns = _checked_ns('flush_period_ns', flush_period_ns, minimum=1)
        self.epoch_ns = _checked_ns('epoch_ns', epoch_ns)
        try:
            self._writer = _Rosbag2Writer(
                self.path, version=ROSBAG2_VERSION, storage_plugin=StoragePlugin.MCAP
            )
        except WriterError as err:
            raise BagError(
                f'bag {self.path} already exists; pass a new directory or remove it'
            ) from err
        if compress:
            self._writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
        self._connections: dict[str, Connection] = {}
        self._flush_due_ns = self.epoch_ns
        self._is_open = False

    def open(self) -> None:
        """Create the bag directory and its MCAP file."""
        try:
            self._writer.open()
        except WriterError as err:
            raise BagError(f'cannot create bag {self.path}: {err}') from err
        except OSError as err:
            self._remove_unstarted_bag()
            raise output_error(self.path, err) from err
        self._is_open = True
        # The MCAP magic and header reach the disk at once, so a killed run leaves a
        # file that recover_bag() recognises as MCAP.
        try:
            self._writer.storage.write_chunks()
        except OSError as err:
            self._stop_writing()
            self._remove_unstarted_bag()
            raise output_error(self.path, err) from err

    def add_topic(self, topic: str, msgtype: str, *, latched: bool = False) -> None:
        """Register ``topic`` of type ``msgtype`` ('pkg/msg/Name') with its offered QoS: LATCHED_QOS or STREAM_QOS."""
        self._require_open()
        if not isinstance(topic, str) or not topic.startswith('/'):
            raise InvalidArgumentError(
                f'topic must be an absolute name like /gyro_box/imu, got {topic!r}'
            )
        if topic in self._connections:
            raise InvalidArgumentError(f'topic {topic} was already added to bag {self.path}')
        self._connections[topic] = self._writer.add_connection(
            topic,
            checked_msgtype(msgtype),
            typestore=TYPESTORE,
            offered_qos_profiles=(LATCHED_QOS if latched else STREAM_QOS,),
        )

    def write_raw(self, topic: str, data: bytes | bytearray | memoryview, stamp_ns: int) -> None:
        """Write one serialized CDR message, as from a raw subscription, logged at ``stamp_ns``."""
        # Checked here because rosbags indexes the message before it copies the bytes.
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise InvalidArgumentError(
                f'data must be serialized CDR bytes, got {type(data).__name__}'
            )
        self._write(self._connection(topic), data, stamp_ns)

    def write_rows(self, topic: str, rows: np.ndarray, stamps_ns: np.ndarray, *, utc_stamps: bool = False) -> None:
        """Write equal-length little-endian CDR messages, the rows of a 2-D uint8 array, logged at ``stamps_ns``:
        what write_raw of each row in turn writes, with the per-message work done once for the block.

        With ``utc_stamps`` the rows' leading stamps are UTC already (built with this writer's epoch_ns, e.g.
        messages.imu_block_rows(block, bag.epoch_ns)), so only the log times are moved.
        """
        connection = self._connection(topic)
        rows, stamps = np.asarray(rows), np.asarray(stamps_ns)
        if rows.dtype != np.uint8 or rows.ndim != 2:
            raise InvalidArgumentError(f'rows must be a 2-D uint8 array of CDR messages, got {rows.dtype} '
                                       f'with shape {rows.shape}')
        if stamps.shape != (len(rows),) or not np.issubdtype(stamps.dtype, np.integer) or np.any(stamps < 0):
            raise InvalidArgumentError(f'stamps_ns must be {len(rows)} integer ns >= 0, one per row, got '
                                       f'{stamps.dtype} with shape {stamps.shape}')
        if self.epoch_ns and len(rows) and not utc_stamps and has_leading_stamp(connection.msgtype):
            try:
                rows = shift_stamps(rows, self.epoch_ns)
            except ValueError as err:
                raise InvalidArgumentError(f'rows of {topic}: {err}') from err
        if not len(rows):
            return
        log_ns = stamps.astype(np.int64) + self.epoch_ns
        start = 0
        while start < len(log_ns):
            # As write_raw row by row: the rows up to the first that reaches the next flush go in, then the flush.
            due = np.flatnonzero(log_ns[start:] >= self._flush_due_ns)
            end = start + int(due[0]) + 1 if len(due) else len(log_ns)
            self._writer.write_block(connection, log_ns[start:end], rows[start:end])
            if len(due):
                self._flush_before(int(log_ns[end - 1]))
            start = end

    def write_message(self, topic: str, message: object, stamp_ns: int) -> None:
        """Write an rclpy message of the topic's type, as wire CDR, logged at ``stamp_ns``."""
        connection = self._connection(topic)
        msgtype = msgtype_of(type(message))
        if msgtype != connection.msgtype:
            raise InvalidArgumentError(f'topic {topic} holds {connection.msgtype}, got a {msgtype}')
        self._write(connection, wire_cdr(message), stamp_ns)

    def write_document(self, topic: str, text: str, stamp_ns: int) -> None:
        """Store a text document (e.g. truth.yaml) as a latched std_msgs/msg/String on ``topic``."""
        if not isinstance(text, str):
            raise InvalidArgumentError(f'document text must be str, got {type(text).__name__}')
        if topic not in self._connections:
            self.add_topic(topic, DOCUMENT_MSGTYPE, latched=True)
        self.write_message(topic, String(data=text), stamp_ns)

    @property
    def topics(self) -> tuple[TopicInfo, ...]:
        """Every added topic with its type and the messages written so far, sorted by name."""
        return tuple(
            TopicInfo(topic, conn.msgtype, self._writer.counts[conn.id])
            for topic, conn in sorted(self._connections.items())
        )

    def flush(self) -> None:
        """Hand every message written so far to the OS (survives the process being killed)."""
        self._require_open()
        self._write_chunks()

    def close(self) -> None:
        """Finish the MCAP summary and write metadata.yaml; the bag is then complete."""
        if not self._is_open:
            return
        try:
            self._writer.close()
        except WriterError as err:
            self._is_open = False
            raise BagError(f'cannot finish bag {self.path}: {err}') from err
        except OSError as err:
            # rosbags writes metadata.yaml through a temporary file that a full disk leaves behind.
            self.path.joinpath('metadata.yaml.tmp').unlink(missing_ok=True)
            raise self._cut_short(err) from err
        self._is_open = False

    def abort(self) -> None:
        """Flush and stop without metadata.yaml: the bag stays incomplete but recoverable."""
        if not self._is_open:
            return
        try:
            self.flush()
        finally:
            self._stop_writing()

    def __enter__(self) -> BagWriter:
        """Open the bag."""
        self.open()
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc_value: BaseException | None,
        traceback: TracebackType | None,
    ) -> None:
        """Close the bag, or abort it if the block raised."""
        if exc_type is None:
            self.close()
        else:
            self.abort()

    def _require_open(self) -> None:
        """Raise unless the bag is open for writing."""
        if not self._is_open:
            raise BagError(
                f'bag {self.path} is not open for writing; use it inside `with BagWriter(...)`'
            )

    def _write_chunks(self, before_ns: int | None = None) -> None:
        """Hand the buffered messages logged before ``before_ns`` (all if None) to the OS; OutputError if it fails."""
        try:
            self._writer.storage.write_chunks(before_ns)
        except OSError as err:
            raise self._cut_short(err) from err

    def _cut_short(self, err: OSError) -> OutputError:
        """Stop writing after ``err`` (a full disk, say) and the one-line error that says what the bag keeps."""
        storage = self._writer.storage
        # No storage left: rosbags closed the MCAP file whole, and writing metadata.yaml failed.
        kept = storage.messages_on_disk if storage is not None else sum(self._writer.counts.values())
        self._stop_writing()
        line, exit_code = describe_os_error(err, filename=self.path)
        # "at least": the chunk being written may have reached the disk whole, only its index cut short.
        return OutputError(f'cannot write bag {line}; at least {kept} messages kept: `sofia recover {self.path}` '
                           'restores them', exit_code)

    def _stop_writing(self) -> None:
        """Close the file without a summary; what it could not write any more is dropped."""
        self._is_open = False
        try:
            self._writer.abort()
        except OSError:
            pass  # closing flushes the buffer the disk refused; the file is closed all the same

    def _remove_unstarted_bag(self) -> None:
        """Remove the bag directory a failed open() created (it did not exist: rosbags refuses one that does)."""
        shutil.rmtree(self.path, ignore_errors=True)

    def _connection(self, topic: str) -> Connection:
        """Return the connection of an added topic."""
        self._require_open()
        try:
            return self._connections[topic]
        except KeyError as err:
            raise InvalidArgumentError(
                f'topic {topic} is not in bag {self.path}; call add_topic({topic!r}, msgtype) first'
            ) from err

    def _write(self, connection: Connection, data: bytes | memoryview, stamp_ns: int) -> None:
        """Write one message and flush when its log time reaches the next flush."""
        if type(stamp_ns) is not int or stamp_ns < 0:  # noqa: E721  (the common case checked cheaply)
            stamp_ns = _checked_ns('stamp_ns', stamp_ns)
        stamp_ns += self.epoch_ns
        if self.epoch_ns and has_leading_stamp(connection.msgtype):
            data = shift_stamp(data, self.epoch_ns)
        self._writer.write(connection, stamp_ns, data)
        if stamp_ns >= self._flush_due_ns:
            self._flush_before(stamp_ns)

    def _flush_before(self, stamp_ns: int) -> None:
        """Write out every buffered message logged before ``stamp_ns``; the next flush is a period later."""
        self._write_chunks(stamp_ns)
        self._flush_due_ns = stamp_ns + self._flush_period_ns


def _checked_ns(name: str, value: int, minimum: int = 0) -> int:
    """Return ``value`` as an int >= ``minimum`` (numpy integers accepted); raise otherwise."""
    try:
        number = operator.index(value)
    except TypeError as err:
        raise InvalidArgumentError(
            f'{name} must be an integer number of ns, got {type(value).__name__}'
        ) from err
    if number < minimum:
        raise InvalidArgumentError(f'{name} must be >= {minimum}, got {number}')
    return number
