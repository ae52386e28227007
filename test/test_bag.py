"""Bag I/O: both write paths, three readers agreeing, damage, and recovery after SIGKILL."""

from __future__ import annotations

import array
import dataclasses
import json
import os
import shutil
import signal
import subprocess
import sys
import struct
import textwrap
import zlib
from pathlib import Path

import numpy as np
import pytest
import yaml
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import (
    Point,
    Pose,
    PoseArray,
    Quaternion,
    QuaternionStamped,
    Vector3,
    Vector3Stamped,
)
from mcap.reader import make_reader
from mcap.records import Chunk, Message
from mcap.stream_reader import StreamReader
from mcap_ros2.decoder import DecoderFactory
from rclpy.serialization import serialize_message
from rosbags.highlevel import AnyReader
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState, Temperature
from std_msgs.msg import Header, String

from sofia_ros.bag import TYPESTORE, BagReader, BagWriter, recover_bag, wire_cdr
from sofia_ros.bag.columns import decode_columns, payload_blocks
from sofia_ros.bag.imu import decode_imu_cdr
from sofia_ros.bag.msgtypes import msgtype_of
from sofia_ros.errors import BagError, InvalidArgumentError

MESSAGES_PER_TYPE = 3
STAMP0_NS = 1_700_000_000_000_000_000
IMU_PERIOD_NS = 2_500_000  # 400 Hz
MSGTYPES = (
    'sensor_msgs/msg/Imu',
    'rosgraph_msgs/msg/Clock',
    'geometry_msgs/msg/PoseArray',
    'geometry_msgs/msg/QuaternionStamped',
    'geometry_msgs/msg/Vector3Stamped',
    'sensor_msgs/msg/JointState',
    'sensor_msgs/msg/Temperature',
    'diagnostic_msgs/msg/DiagnosticStatus',
    'std_msgs/msg/String',
)


def header(i: int, frame_id: str = 'tarf') -> Header:
    """A header whose stamp and frame depend on ``i``."""
    return Header(stamp=Time(sec=1000 + i, nanosec=123 + i), frame_id=frame_id)


def imu(i: int, frame_id: str = 'gyrf') -> Imu:
    """An Imu with every vector and covariance filled."""
    return Imu(
        header=header(i, frame_id),
        orientation=Quaternion(x=0.1 * i, y=0.2, z=0.3, w=0.9),
        orientation_covariance=[float(i + k) for k in range(9)],
        angular_velocity=Vector3(x=1e-5 * (i + 1), y=-2e-5 * i, z=7.29e-5),
        angular_velocity_covariance=[1e-12 * k for k in range(9)],
        linear_acceleration=Vector3(x=0.01 * i, y=-0.02, z=9.81),
        linear_acceleration_covariance=[-1.0] + [0.0] * 8,
    )


def sample(msgtype: str, i: int) -> object:
    """Message number ``i`` of type ``msgtype`` with distinctive values."""
    if msgtype == 'sensor_msgs/msg/Imu':
        return imu(i)
    if msgtype == 'rosgraph_msgs/msg/Clock':
        return Clock(clock=Time(sec=i, nanosec=IMU_PERIOD_NS * i))
    if msgtype == 'geometry_msgs/msg/PoseArray':
        poses = [Pose(position=Point(x=float(k), y=0.5 * i, z=-1.0)) for k in range(i + 1)]
        return PoseArray(header=header(i, 'fpi'), poses=poses)
    if msgtype == 'geometry_msgs/msg/QuaternionStamped':
        return QuaternionStamped(header=header(i), quaternion=Quaternion(x=0.0, y=0.6, z=0.0, w=0.8))
    if msgtype == 'geometry_msgs/msg/Vector3Stamped':
        return Vector3Stamped(header=header(i, 'hipo'), vector=Vector3(x=1.5 * i, y=-2.0, z=1e-9))
    if msgtype == 'sensor_msgs/msg/JointState':
        # effort stays an empty float64[]: the case serialize_message pads with junk.
        return JointState(
            header=header(i), name=['el', 'xel', 'los'], position=[0.1 * i, 0.2, 0.3], velocity=[1.0, 2.0, 3.0]
        )
    if msgtype == 'sensor_msgs/msg/Temperature':
        return Temperature(header=header(i), temperature=22.8 + i, variance=0.01)
    if msgtype == 'diagnostic_msgs/msg/DiagnosticStatus':
        return DiagnosticStatus(
            level=DiagnosticStatus.WARN,
            name=f'gyro_box {i}',
            message='bias drift',
            hardware_id='fog-3',
            values=[KeyValue(key='axis', value='los'), KeyValue(key='i', value=str(i))],
        )
    return String(data=f'effects:\n  seeing: {{}}  # Δ {i}″\n')


def plain(value: object) -> object:
    """Nested lists/dicts of a message from rclpy, rosbags or mcap_ros2, for comparing values."""
    if isinstance(value, bytes) and len(value) == 1:
        return value[0]  # rclpy gives a `byte` field as bytes, the others as int
    if isinstance(value, (list, tuple, array.array, np.ndarray)):
        return [plain(item) for item in value]
    if hasattr(value, 'get_fields_and_field_types'):
        names = list(value.get_fields_and_field_types())
    elif dataclasses.is_dataclass(value):
        # rosbags also lists the constants (UPPER_CASE) and __msgtype__ as fields.
        names = [f.name for f in dataclasses.fields(value) if f.name.islower() and f.name[0] != '_']
    elif hasattr(value, '__slots__'):
        names = list(value.__slots__)
    else:
        return value
    return {name: plain(getattr(value, name)) for name in names}


def topic_name(kind: str, msgtype: str) -> str:
    """Topic on which the tests write ``msgtype`` through the ``kind`` path ('raw' or 'obj')."""
    return f'/{kind}/{msgtype.split("/")[-1].lower()}'


def metadata_topics(path: Path) -> dict[str, dict]:
    """topics_with_message_count of a bag's metadata.yaml, by topic name."""
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    return {item['topic_metadata']['name']: item for item in info['topics_with_message_count']}


@pytest.fixture(scope='module')
def round_trip(tmp_path_factory):
    """A closed bag with every type written through both paths, and what went to each topic."""
    path = tmp_path_factory.mktemp('bags') / 'round_trip'
    written: dict[str, list[tuple[int, object]]] = {}
    with BagWriter(path) as bag:
        for msgtype in MSGTYPES:
            for kind in ('raw', 'obj'):
                bag.add_topic(topic_name(kind, msgtype), msgtype)
        for i in range(MESSAGES_PER_TYPE):
            for n, msgtype in enumerate(MSGTYPES):
                message = sample(msgtype, i)
                raw_stamp_ns = STAMP0_NS + 1_000_000 * i + n
                # The object path runs backwards within each round; readers must sort.
                obj_stamp_ns = raw_stamp_ns + 500_000 - 2 * n
                # wire_cdr(message) is what a raw subscription hands the recorder.
                bag.write_raw(topic_name('raw', msgtype), wire_cdr(message), raw_stamp_ns)
                bag.write_message(topic_name('obj', msgtype), message, obj_stamp_ns)
                for kind, stamp_ns in (('raw', raw_stamp_ns), ('obj', obj_stamp_ns)):
                    written.setdefault(topic_name(kind, msgtype), []).append((stamp_ns, plain(message)))
        writer_topics = bag.topics
    return path, written, writer_topics


def test_typestore_hashes_equal_the_installed_interface_packages():
    """The definitions written into bags are those of the installed distro (RIHS01 per type)."""
    prefixes = [sys.prefix, *os.environ.get('AMENT_PREFIX_PATH', '').split(os.pathsep)]
    roots = [Path(prefix) / 'share' for prefix in prefixes if prefix]
    checked = 0
    for msgtype in MSGTYPES:
        descriptions = [root / f'{msgtype}.json' for root in roots if (root / f'{msgtype}.json').is_file()]
        if descriptions:
            hashes = json.loads(descriptions[0].read_text())['type_hashes']
            installed = next(item['hash_string'] for item in hashes if item['type_name'] == msgtype)
            assert TYPESTORE.hash_rihs01(msgtype) == installed, msgtype
            checked += 1
    if not checked:
        pytest.skip('no installed type descriptions (share/<pkg>/msg/*.json) found')
    assert checked == len(MSGTYPES)


def test_msgtype_of_names_rclpy_classes_only():
    assert msgtype_of(Imu) == 'sensor_msgs/msg/Imu'
    assert msgtype_of(DiagnosticStatus) == 'diagnostic_msgs/msg/DiagnosticStatus'
    with pytest.raises(InvalidArgumentError, match='dict is not an rclpy message class'):
        msgtype_of(dict)


def test_wire_cdr_is_exact_and_deterministic():
    """serialize_message sizes by an estimate and leaves junk; wire_cdr gives what DDS carries."""
    message = JointState(name=['el'], position=[0.5])  # velocity and effort empty float64[]
    assert len(serialize_message(message)) > len(wire_cdr(message))
    assert bytes(wire_cdr(message)) == bytes(wire_cdr(JointState(name=['el'], position=[0.5])))
    decoded = TYPESTORE.deserialize_cdr(wire_cdr(message), 'sensor_msgs/msg/JointState')
    assert plain(decoded) == plain(message)


def test_wire_cdr_serializes_directly_only_what_gives_the_round_trips_bytes():
    """Types the typestore serializes as rclpy holds them take one step; the bytes are the round trip's."""
    from sofia_ros.bag.msgtypes import decode_cdr, serializes_directly

    direct = {msgtype for msgtype in MSGTYPES if serializes_directly(msgtype)}
    # byte fields (DiagnosticStatus.level) and float64[] sequences (JointState) go the round trip's way.
    assert direct == set(MSGTYPES) - {'sensor_msgs/msg/JointState', 'diagnostic_msgs/msg/DiagnosticStatus'}
    for msgtype in MSGTYPES:
        for i in range(MESSAGES_PER_TYPE):
            message = sample(msgtype, i)
            round_trip = TYPESTORE.serialize_cdr(decode_cdr(serialize_message(message), msgtype), msgtype,
                                                 little_endian=True)
            assert bytes(wire_cdr(message)) == bytes(round_trip), (msgtype, i)
    # Edge cases: no poses, a message without fields (rclpy has no member where the wire has one), NUL in a
    # string (DDS carries it up to the NUL), also inside a sequence; sequences of other numbers, and empty ones.
    from std_msgs.msg import Empty, Float32MultiArray, UInt8MultiArray

    assert not serializes_directly('std_msgs/msg/Empty')
    for message in (PoseArray(header=header(0, '')), Empty(), String(data='a\0b'), imu(1, 'gy\0rf'),
                    JointState(name=['el\0x'], position=[0.5]), JointState(),
                    DiagnosticStatus(values=[KeyValue(key='k', value='v\0w')]),
                    UInt8MultiArray(data=[0, 7, 255]), Float32MultiArray(data=[1.5, -2.25e-30])):
        msgtype = msgtype_of(type(message))
        round_trip = TYPESTORE.serialize_cdr(decode_cdr(serialize_message(message), msgtype), msgtype,
                                             little_endian=True)
        assert bytes(wire_cdr(message)) == bytes(round_trip), message


def test_write_rows_writes_the_file_write_raw_writes_row_by_row(tmp_path):
    """A block of 400 Hz samples in one call: the same MCAP file, flushes inside the block and UTC stamps included,
    whether the writer moves the rows' stamps to UTC or they are built in UTC (the lock-step runner's)."""
    from sofia_ros import messages as m

    rng = np.random.default_rng(5)
    stamps_ns = np.arange(1000, dtype=np.int64) * IMU_PERIOD_NS  # 2.5 s: flushes at 1 s and 2 s of the block
    block = m.ImuBlock('gyrf', stamps_ns, rng.normal(size=(1000, 3)), rng.normal(size=(1000, 3)))
    files = []
    for name in ('rows', 'raw', 'utc'):
        with BagWriter(tmp_path / name / 'bag', epoch_ns=STAMP0_NS) as bag:
            bag.add_topic('/gyro_box/imu', 'sensor_msgs/msg/Imu')
            if name == 'rows':
                bag.write_rows('/gyro_box/imu', m.imu_block_rows(block), stamps_ns)
            elif name == 'utc':
                bag.write_rows('/gyro_box/imu', m.imu_block_rows(block, STAMP0_NS), stamps_ns, utc_stamps=True)
            else:
                for data, stamp_ns in zip(m.imu_block_cdr(block), stamps_ns.tolist()):
                    bag.write_raw('/gyro_box/imu', data, stamp_ns)
        files.append((tmp_path / name / 'bag' / 'bag.mcap').read_bytes())
    assert files[0] == files[1] == files[2]
    with BagReader(tmp_path / 'rows' / 'bag') as bag:
        imu_arrays = bag.imu_arrays('/gyro_box/imu')
    np.testing.assert_array_equal(imu_arrays.header_stamp_ns, STAMP0_NS + stamps_ns)
    np.testing.assert_array_equal(imu_arrays.angular_velocity_rad_per_s, block.angular_velocity_rad_per_s)


def test_write_rows_of_an_empty_sample_block_writes_nothing(tmp_path):
    """A tick without gyro samples (a tick shorter than 2.5 ms) reaches the recorder as an empty block."""
    from sofia_ros import messages as m
    from sofia_ros.bag.timebase import leading_stamps_ns

    rows = m.sample_rows_of_block_cdr(m.sample_block_cdr([]))
    assert rows.shape == (0, 0) and leading_stamps_ns(rows).shape == (0,)
    with BagWriter(tmp_path / 'bag', epoch_ns=STAMP0_NS) as bag:
        bag.add_topic('/gyro_box/imu', 'sensor_msgs/msg/Imu')
        bag.write_rows('/gyro_box/imu', rows, leading_stamps_ns(rows))
        assert bag.topics[0].count == 0


def test_stamps_builtin_interfaces_time_cannot_hold_are_refused():
    from sofia_ros import messages as m

    after_2038_ns = np.array([2**31 * 10**9], dtype=np.int64)
    block = m.ImuBlock('gyrf', after_2038_ns, np.zeros((1, 3)), np.zeros((1, 3)))
    with pytest.raises(InvalidArgumentError, match=r'beyond what builtin_interfaces/Time holds .*2038-01-19'):
        m.imu_block_rows(block)


def test_write_rows_refuses_an_epoch_that_moves_stamps_past_2038(tmp_path):
    from sofia_ros import messages as m

    rows = m.imu_block_rows(m.ImuBlock('gyrf', np.array([0], dtype=np.int64), np.zeros((1, 3)), np.zeros((1, 3))))
    with BagWriter(tmp_path / 'bag', epoch_ns=2**31 * 10**9) as bag:
        bag.add_topic('/gyro_box/imu', 'sensor_msgs/msg/Imu')
        with pytest.raises(InvalidArgumentError, match='rows of /gyro_box/imu: a stamp is beyond what'):
            bag.write_rows('/gyro_box/imu', rows, np.array([0]))


@pytest.mark.parametrize('rows, stamps_ns, message', [
    (np.zeros((2, 40), dtype=np.int16), [0, 1], 'rows must be a 2-D uint8 array of CDR messages, got int16'),
    (np.zeros(40, dtype=np.uint8), [0], r'rows must be a 2-D uint8 array of CDR messages, got uint8 with shape \(40,\)'),
    (np.zeros((2, 40), dtype=np.uint8), [0], r'stamps_ns must be 2 integer ns >= 0, one per row'),
    (np.zeros((2, 40), dtype=np.uint8), [0.0, 1.0], r'stamps_ns must be 2 integer ns >= 0, one per row, got float64'),
    (np.zeros((2, 40), dtype=np.uint8), [0, -1], r'stamps_ns must be 2 integer ns >= 0'),
    (np.zeros((2, 40), dtype=np.uint8), [0, 1], 'rows of /gyro_box/imu: the payloads are not little-endian CDR'),
    (np.ones((2, 8), dtype=np.uint8), [0, 1], 'rows of /gyro_box/imu: the payloads are not little-endian CDR'),
])
def test_write_rows_refuses_what_is_not_a_block_of_cdr(tmp_path, rows, stamps_ns, message):
    with BagWriter(tmp_path / 'bag', epoch_ns=STAMP0_NS) as bag:
        bag.add_topic('/gyro_box/imu', 'sensor_msgs/msg/Imu')
        with pytest.raises(InvalidArgumentError, match=message):
            bag.write_rows('/gyro_box/imu', rows, np.array(stamps_ns))
        with pytest.raises(InvalidArgumentError, match='topic /other is not in bag'):
            bag.write_rows('/other', np.zeros((1, 40), dtype=np.uint8), np.array([0]))


def test_both_write_paths_give_byte_identical_bags(tmp_path):
    """A seeded run reproduces its bag bit for bit; message objects and raw CDR store the same bytes."""
    for name in ('a', 'b'):
        with BagWriter(tmp_path / name / 'run', flush_period_ns=2) as bag:
            for msgtype in MSGTYPES:
                bag.add_topic(topic_name('obj', msgtype), msgtype)
                bag.add_topic(topic_name('raw', msgtype), msgtype)
                for i in range(MESSAGES_PER_TYPE):
                    bag.write_message(topic_name('obj', msgtype), sample(msgtype, i), i)
                    bag.write_raw(topic_name('raw', msgtype), wire_cdr(sample(msgtype, i)), i)
    first, second = (tmp_path / name / 'run' / 'run.mcap' for name in ('a', 'b'))
    assert first.read_bytes() == second.read_bytes()
    with BagReader(tmp_path / 'a' / 'run') as bag:
        for msgtype in MSGTYPES:
            obj = [data for _, _, data in bag.raw_messages(topic_name('obj', msgtype))]
            raw = [data for _, _, data in bag.raw_messages(topic_name('raw', msgtype))]
            assert obj == raw, msgtype


def test_metadata_lists_mcap_storage_and_counts(round_trip):
    path, written, writer_topics = round_trip
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['storage_identifier'] == 'mcap'
    assert info['relative_file_paths'] == ['round_trip.mcap']
    assert (path / 'round_trip.mcap').is_file()
    counts = {name: item['message_count'] for name, item in metadata_topics(path).items()}
    assert counts == {topic: len(messages) for topic, messages in written.items()}
    assert {info.name: info.count for info in writer_topics} == counts
    assert info['message_count'] == len(MSGTYPES) * 2 * MESSAGES_PER_TYPE
    # Read without opening the bag: what the open reader counts in the MCAP file.
    listed = BagReader(path).listed_topic_counts
    with BagReader(path) as reader:
        assert listed == counts == {topic.name: topic.count for topic in reader.topics}



def test_the_last_log_time_of_a_topic_is_its_last_message_read_in_full(round_trip):
    path, written, _ = round_trip
    with BagReader(path) as reader:
        for topic in written:
            stamps_ns = reader.messages_by_topic(topic, raw=(topic,))[topic][0]
            assert reader.last_log_time_ns(topic) == stamps_ns[-1], topic


def test_the_last_log_time_from_a_damaged_chunk_is_one_line_naming_it(round_trip, tmp_path):
    # Only the chunk that holds the topic's last message is read: it must still pass its CRC.
    path = Path(shutil.copytree(round_trip[0], tmp_path / 'bag'))
    mcap_file = path / 'round_trip.mcap'
    with mcap_file.open('rb') as stream:
        chunks = make_reader(stream).get_summary().chunk_indexes
    last = chunks[-1]
    data = bytearray(mcap_file.read_bytes())
    data[last.chunk_start_offset + last.chunk_length - 20] ^= 0x10
    mcap_file.write_bytes(bytes(data))
    damaged = rf'chunk {len(chunks)} of {len(chunks)} .* fails'
    with BagReader(path) as reader, pytest.raises(BagError, match=damaged) as caught:
        for topic in round_trip[1]:  # those whose last message is in the last chunk read it
            reader.last_log_time_ns(topic)
    assert '\n' not in str(caught.value)


def test_bag_reader_gives_back_what_was_written_in_time_order(round_trip):
    path, written, _ = round_trip
    with BagReader(path) as bag:
        assert {(t.name, t.msgtype, t.count) for t in bag.topics} == {
            (topic_name(kind, msgtype), msgtype, MESSAGES_PER_TYPE)
            for msgtype in MSGTYPES
            for kind in ('raw', 'obj')
        }
        records = list(bag.messages())
        imu_topics = {topic for topic, _, _ in bag.messages('/raw/imu', '/obj/imu')}
    assert imu_topics == {'/raw/imu', '/obj/imu'}
    stamps_ns = [stamp_ns for _, stamp_ns, _ in records]
    assert stamps_ns == sorted(stamps_ns)
    read: dict[str, list[tuple[int, object]]] = {}
    for topic, stamp_ns, message in records:
        read.setdefault(topic, []).append((stamp_ns, plain(message)))
    assert read == {topic: sorted(messages) for topic, messages in written.items()}


def _every_topic(bag, view):
    """The names of every topic of ``bag``, all of them read through the message indexes as ``view`` ('raw' or
    'columns'), and the same decoded message by message."""
    names = tuple(info.name for info in bag.topics)
    return names, bag.messages_by_topic(*names, **{view: names}), bag.messages_by_topic(*names)


def test_reading_through_the_message_indexes_equals_reading_record_by_record(round_trip):
    path, _, _ = round_trip
    with BagReader(path) as bag:
        names, by_index, decoded = _every_topic(bag, 'raw')
        record_by_record: dict[str, tuple[list, list, list]] = {name: ([], [], []) for name in names}
        for topic, stamp_ns, data in bag.raw_messages():
            record_by_record[topic][0].append(stamp_ns)
            record_by_record[topic][1].append(bytes(data))
        for topic, _, message in bag.messages():
            record_by_record[topic][2].append(plain(message))
    for name in names:
        stamps, payloads, messages = record_by_record[name]
        assert by_index[name][0] == stamps and decoded[name][0] == stamps
        assert [bytes(payload) for payload in by_index[name][1]] == payloads
        assert [plain(message) for message in decoded[name][1]] == messages


def test_a_chunk_that_fails_its_crc_raises_bag_error(round_trip, tmp_path):
    path, _, _ = round_trip
    damaged = shutil.copytree(path, tmp_path / 'crc')
    mcap_file = damaged / 'round_trip.mcap'
    with mcap_file.open('rb') as stream:
        chunks = make_reader(stream).get_summary().chunk_indexes
    # The chunk record's uncompressed_crc field follows its opcode, length, two times and size.
    crc_at = chunks[-1].chunk_start_offset + 1 + 8 + 8 + 8 + 8
    data = bytearray(mcap_file.read_bytes())
    data[crc_at:crc_at + 4] = bytes(a ^ 0xFF for a in data[crc_at:crc_at + 4])
    mcap_file.write_bytes(bytes(data))
    named = (rf'is truncated or corrupt \(ValueError: chunk {len(chunks)} of {len(chunks)} \(byte '
             rf'{chunks[-1].chunk_start_offset}, log times \d+ to \d+ ns\) fails its CRC check\); salvage')
    with BagReader(damaged) as bag:
        with pytest.raises(BagError, match=named):
            bag.messages_by_topic(*(info.name for info in bag.topics))
        # Record by record (rosbags checks the CRC too), the error names the same chunk.
        with pytest.raises(BagError, match=named):
            list(bag.messages())


def test_a_flipped_byte_in_a_chunk_names_the_chunk(tmp_path):
    path = tmp_path / 'flip'
    with BagWriter(path, compress=False, flush_period_ns=IMU_PERIOD_NS * 100) as bag:
        bag.add_topic('/gyro_box/imu', 'sensor_msgs/msg/Imu')
        for i in range(1000):
            bag.write_message('/gyro_box/imu', imu(i), STAMP0_NS + IMU_PERIOD_NS * i)
    mcap_file = path / 'flip.mcap'
    with mcap_file.open('rb') as stream:
        chunks = make_reader(stream).get_summary().chunk_indexes
    assert len(chunks) == 10
    # One bit of an angular velocity inside the fourth chunk's (uncompressed) records.
    flip_at = chunks[3].chunk_start_offset + chunks[3].chunk_length - 100
    data = bytearray(mcap_file.read_bytes())
    data[flip_at] ^= 0x01
    mcap_file.write_bytes(bytes(data))
    with BagReader(path) as bag:
        with pytest.raises(BagError, match=rf'\(ValueError: chunk 4 of 10 \(byte {chunks[3].chunk_start_offset}, '
                                           r'log times \d+ to \d+ ns\) fails its CRC check\)') as caught:
            bag.imu_arrays('/gyro_box/imu')
    assert '\n' not in str(caught.value)
    # Recovery copies every intact chunk, the six after the damaged one too, and names the one it skipped.
    report = recover_bag(path)
    assert report.message_count == 900
    assert report.skipped_offsets == (chunks[3].chunk_start_offset,)


def test_every_crc_of_the_file_is_written_and_right(round_trip):
    path, _, _ = round_trip
    data = (path / 'round_trip.mcap').read_bytes()
    footer_at = len(data) - 8 - (1 + 8 + 20)
    assert data[footer_at] == 0x02
    summary_start, summary_offset_start, summary_crc = struct.unpack_from('<QQI', data, footer_at + 9)
    assert summary_crc == zlib.crc32(data[summary_start:footer_at + 9 + 16])
    # DataEnd is the data section's last record; its CRC covers every byte before it.
    data_end_at = summary_start - (1 + 8 + 4)
    assert data[data_end_at] == 0x0F
    (data_crc,) = struct.unpack_from('<I', data, data_end_at + 9)
    assert data_crc == zlib.crc32(data[:data_end_at])
    with (path / 'round_trip.mcap').open('rb') as stream:
        records = list(StreamReader(stream, validate_crcs=True, emit_chunks=True).records)
    chunks = [record for record in records if isinstance(record, Chunk)]
    assert chunks and all(chunk.uncompressed_crc != 0 for chunk in chunks)


def test_records_are_in_log_time_order_within_and_across_chunks(round_trip):
    path, written, _ = round_trip
    with (path / 'round_trip.mcap').open('rb') as stream:
        records = list(StreamReader(stream, validate_crcs=True).records)
    log_ns = [record.log_time for record in records if isinstance(record, Message)]
    # The fixture writes the object path backwards within each round.
    assert len(log_ns) == sum(map(len, written.values()))
    assert log_ns == sorted(log_ns)


def test_a_periodic_flush_keeps_later_messages_for_the_next_chunk(tmp_path):
    # A lock-step tick writes its latest stamp first and its earlier samples after it (the clock, then the
    # 400 Hz gyro samples): the chunks still follow each other in time.
    path = tmp_path / 'ticks'
    tick_ns = 200_000_000
    with BagWriter(path, flush_period_ns=tick_ns) as bag:
        bag.add_topic('/clock', 'rosgraph_msgs/msg/Clock')
        bag.add_topic('/gyro_box/imu', 'sensor_msgs/msg/Imu')
        for tick in range(1, 11):
            bag.write_message('/clock', sample('rosgraph_msgs/msg/Clock', tick), tick * tick_ns)
            for k in range(79, -1, -1):  # the samples of (previous tick, tick]
                bag.write_message('/gyro_box/imu', imu(k), tick * tick_ns - k * IMU_PERIOD_NS)
    with (path / 'ticks.mcap').open('rb') as stream:
        chunks = make_reader(stream).get_summary().chunk_indexes
    assert len(chunks) == 10
    assert all(before.message_end_time < after.message_start_time for before, after in zip(chunks, chunks[1:]))


def test_anyreader_and_mcap_ros2_decode_the_same_values(round_trip):
    path, written, _ = round_trip
    with AnyReader([path], default_typestore=TYPESTORE) as reader:
        rosbags_values = {
            (conn.topic, stamp_ns): plain(reader.deserialize(data, conn.msgtype))
            for conn, stamp_ns, data in reader.messages()
        }
    with (path / 'round_trip.mcap').open('rb') as stream:
        mcap = make_reader(stream, decoder_factories=[DecoderFactory()])
        assert mcap.get_summary() is not None  # closed: summary and footer present
        mcap_values = {
            (channel.topic, message.log_time): plain(decoded)
            for _, channel, message, decoded in mcap.iter_decoded_messages()
        }
    expected = {
        (topic, stamp_ns): value for topic, messages in written.items() for stamp_ns, value in messages
    }
    assert rosbags_values == expected
    assert mcap_values == expected


def test_imu_arrays_match_per_message_decoding(tmp_path):
    path = tmp_path / 'imu'
    frames = ['g', 'gyrf', 'gyro_box_frame', 'gyrf']  # three CDR lengths in one topic
    with BagWriter(path) as bag:
        bag.add_topic('/gyro_box/imu', 'sensor_msgs/msg/Imu')
        for i in range(40):
            bag.write_message('/gyro_box/imu', imu(i, frames[i % len(frames)]), IMU_PERIOD_NS * i)
    with BagReader(path) as bag:
        arrays = bag.imu_arrays('/gyro_box/imu')
        messages = [message for _, _, message in bag.messages('/gyro_box/imu')]
        window = bag.imu_arrays('/gyro_box/imu', start_ns=IMU_PERIOD_NS * 10, stop_ns=IMU_PERIOD_NS * 20)
    np.testing.assert_array_equal(arrays.stamp_ns, IMU_PERIOD_NS * np.arange(40))
    np.testing.assert_array_equal(
        arrays.header_stamp_ns, [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in messages]
    )
    gyro = [[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for m in messages]
    accel = [[m.linear_acceleration.x, m.linear_acceleration.y, m.linear_acceleration.z] for m in messages]
    np.testing.assert_array_equal(arrays.angular_velocity_rad_per_s, gyro)
    np.testing.assert_array_equal(arrays.linear_acceleration_m_per_s2, accel)
    np.testing.assert_array_equal(window.stamp_ns, IMU_PERIOD_NS * np.arange(10, 20))


def column_leaves(value: object, path: str, sequences: dict) -> list[tuple[str, object]]:
    """(leaf path, value) of a plain() message in field order, as bag.columns names them; a sequence also its length."""
    if isinstance(value, dict):
        return [leaf for name, item in value.items()
                for leaf in column_leaves(item, f'{path}.{name}' if path else name, sequences)]
    if isinstance(value, list):
        items = [leaf for item in value for leaf in column_leaves(item, f'{path}[]', sequences)]
        return [(path, len(value)), *items] if path in sequences else items
    return [(path, value)]


def test_columns_match_per_message_decoding(round_trip):
    path, written, _ = round_trip
    with BagReader(path) as bag:
        names, columns, decoded = _every_topic(bag, 'columns')
    for name in names:
        stamps, messages = decoded[name]
        table = columns[name]
        np.testing.assert_array_equal(table.stamp_ns, stamps)
        expected: dict[str, list] = {leaf: [] for leaf in table.values}
        counts: dict[str, list] = {leaf: [] for leaf in table.values}
        for message in messages:
            leaves = column_leaves(plain(message), '', table.values)
            for leaf in table.values:
                found = [value for where, value in leaves if where == leaf]
                expected[leaf].extend(found)
                counts[leaf].append(len(found))
        for leaf in table.values:
            assert table.values[leaf].tolist() == expected[leaf], (name, leaf)
            assert table.counts[leaf].tolist() == counts[leaf], (name, leaf)
    poses = columns[topic_name('raw', 'geometry_msgs/msg/PoseArray')]
    assert poses.counts['poses[].position.x'].tolist() == [1, 2, 3]  # three layouts in one topic
    np.testing.assert_array_equal(poses.time_ns('header.stamp'), [(1000 + i) * 10**9 + 123 + i for i in range(3)])


def test_columns_reject_payloads_that_are_not_their_type():
    good = bytes(wire_cdr(sample('sensor_msgs/msg/JointState', 1)))
    with pytest.raises(ValueError, match='ends inside'):
        decode_columns(payload_blocks([0], [good[:30]]), 'sensor_msgs/msg/JointState', TYPESTORE)
    with pytest.raises(InvalidArgumentError, match='not little-endian CDR'):
        decode_columns(payload_blocks([0], [b'\x00\x00' + good[2:]]), 'sensor_msgs/msg/JointState', TYPESTORE)


def test_imu_decoding_rejects_payloads_that_are_not_imu():
    good = bytes(wire_cdr(imu(0)))
    with pytest.raises(InvalidArgumentError, match='does not match the sensor_msgs/msg/Imu layout'):
        decode_imu_cdr([0], [good[:-8]])
    with pytest.raises(InvalidArgumentError, match='not little-endian CDR'):
        decode_imu_cdr([0], [b'\x00\x00' + good[2:]])


def test_documents_are_latched_strings_read_back_by_topic(tmp_path):
    path = tmp_path / 'docs'
    with BagWriter(path) as bag:
        bag.write_document('/config/truth', 'effects:\n  gyro_bias: {}\n', 0)
        bag.write_document('/result/summary', 'accepted: false\n', 5)
        bag.write_document('/result/summary', 'accepted: true\n', 9)
        bag.add_topic('/clock', 'rosgraph_msgs/msg/Clock')
    topics = metadata_topics(path)
    assert topics['/config/truth']['topic_metadata']['offered_qos_profiles'][0]['durability'] == (
        'transient_local'
    )
    clock_qos = topics['/clock']['topic_metadata']['offered_qos_profiles']
    assert [(qos['durability'], qos['reliability']) for qos in clock_qos] == [('volatile', 'reliable')]
    # The MCAP channels carry the same profiles, as ros2 bag play reads them.
    with (path / 'docs.mcap').open('rb') as stream:
        channels = {channel.topic: channel for channel in make_reader(stream).get_summary().channels.values()}
    for topic in ('/config/truth', '/result/summary', '/clock'):
        qos = yaml.safe_load(channels[topic].metadata['offered_qos_profiles'])
        assert qos == topics[topic]['topic_metadata']['offered_qos_profiles']
    with BagReader(path) as bag:
        assert bag.document('/config/truth') == 'effects:\n  gyro_bias: {}\n'
        assert bag.document('/result/summary') == 'accepted: true\n'
        with pytest.raises(BagError, match='holds rosgraph_msgs/msg/Clock, not a std_msgs/msg/String'):
            bag.document('/clock')


def test_absent_topic_raises_bag_error(round_trip):
    path, _, _ = round_trip
    with BagReader(path) as bag:
        with pytest.raises(BagError, match=r'topic /gyro_box/imu is not in bag .*; pick one of: /obj/clock'):
            bag.messages('/gyro_box/imu')
        with pytest.raises(BagError, match='holds sensor_msgs/msg/Temperature, not sensor_msgs/msg/Imu'):
            bag.imu_arrays('/raw/temperature')
    with pytest.raises(BagError, match=r'is not open; use it inside `with BagReader'):
        bag.topics


def test_missing_bag_raises_bag_error(tmp_path):
    with pytest.raises(BagError, match=r'bag .*nope does not exist; pass a bag directory'):
        BagReader(tmp_path / 'nope')


def test_directory_without_metadata_is_not_a_bag(tmp_path):
    with pytest.raises(BagError,
                       match=r'is not a rosbag2 bag directory \(no metadata.yaml and no MCAP data to recover\)'):
        BagReader(tmp_path)


def test_mcap_file_instead_of_directory_is_named(round_trip):
    path, _, _ = round_trip
    with pytest.raises(BagError, match='is a file, not a rosbag2 bag directory'):
        BagReader(path / 'round_trip.mcap')


def test_non_mcap_storage_is_named(tmp_path):
    path = tmp_path / 'sqlite'
    path.mkdir()
    metadata = {'rosbag2_bagfile_information': {'version': 5, 'storage_identifier': 'sqlite3'}}
    (path / 'metadata.yaml').write_text(yaml.safe_dump(metadata))
    with pytest.raises(BagError, match=r"uses 'sqlite3' storage, not MCAP; convert it with `rosbags-"):
        BagReader(path)


def test_truncated_bag_raises_bag_error_and_recovers_its_head(round_trip, tmp_path):
    path, _, _ = round_trip
    damaged = shutil.copytree(path, tmp_path / 'cut')
    mcap_file = damaged / 'round_trip.mcap'
    data = mcap_file.read_bytes()
    mcap_file.write_bytes(data[: len(data) // 2])
    with pytest.raises(BagError, match=r'bag .*cut is truncated or corrupt .*sofia recover'):
        BagReader(damaged).open()
    report = recover_bag(damaged)
    assert report.bag == tmp_path / 'cut_recovered'
    assert not report.reached_footer
    assert report.stop_reason.startswith('file cut inside the record at byte')
    with BagReader(report.bag) as bag:
        assert sum(info.count for info in bag.topics) == report.message_count > 0


def test_corrupt_chunk_raises_bag_error(round_trip, tmp_path):
    path, _, _ = round_trip
    damaged = shutil.copytree(path, tmp_path / 'corrupt')
    mcap_file = damaged / 'round_trip.mcap'
    with mcap_file.open('rb') as stream:
        last_chunk = make_reader(stream).get_summary().chunk_indexes[-1]
    # Zero the zstd frame header of the last chunk's data (after the chunk record's fields).
    data_at = last_chunk.chunk_start_offset + 1 + 8 + 8 + 8 + 8 + 4 + 4 + len(last_chunk.compression) + 8
    data = bytearray(mcap_file.read_bytes())
    data[data_at:data_at + 8] = bytes(8)
    mcap_file.write_bytes(bytes(data))
    named = r'is truncated or corrupt \(ValueError: chunk 1 of 1 \(byte \d+, log times \d+ to \d+ ns\) fails to decompress'
    with pytest.raises(BagError, match=named):
        with BagReader(damaged) as bag:
            list(bag.messages())
    with pytest.raises(BagError, match=named):
        with BagReader(damaged) as bag:
            bag.messages_by_topic(*(info.name for info in bag.topics))


def test_corrupt_message_raises_bag_error(tmp_path):
    path = tmp_path / 'junk'
    with BagWriter(path) as bag:
        bag.add_topic('/gyro_box/imu', 'sensor_msgs/msg/Imu')
        bag.write_raw('/gyro_box/imu', b'\x00\x01\x00\x00' + b'junk', 0)
    with BagReader(path) as bag:
        with pytest.raises(BagError, match=r'is truncated or corrupt \(error: unpack_from'):
            list(bag.messages())
        with pytest.raises(BagError, match='topic /gyro_box/imu in bag .*: Imu payload of 8 bytes is shorter'):
            bag.imu_arrays('/gyro_box/imu')


def test_writer_rejects_misuse(tmp_path):
    with BagWriter(tmp_path / 'misuse') as bag:
        bag.add_topic('/clock', 'rosgraph_msgs/msg/Clock')
        with pytest.raises(InvalidArgumentError, match='unknown message type'):
            bag.add_topic('/x', 'sofia_msgs/msg/Nope')
        with pytest.raises(InvalidArgumentError, match='must be an absolute name'):
            bag.add_topic('clock', 'rosgraph_msgs/msg/Clock')
        with pytest.raises(InvalidArgumentError, match='already added'):
            bag.add_topic('/clock', 'rosgraph_msgs/msg/Clock')
        with pytest.raises(InvalidArgumentError, match='holds rosgraph_msgs/msg/Clock, got a sensor_msgs'):
            bag.write_message('/clock', imu(0), 0)
        with pytest.raises(InvalidArgumentError, match='call add_topic'):
            bag.write_raw('/imu', b'\x00\x01\x00\x00', 0)
        with pytest.raises(InvalidArgumentError, match='stamp_ns must be >= 0'):
            bag.write_message('/clock', Clock(), -1)
        with pytest.raises(InvalidArgumentError, match='stamp_ns must be an integer'):
            bag.write_message('/clock', Clock(), 1.5)
        with pytest.raises(InvalidArgumentError, match='serialized CDR bytes'):
            bag.write_raw('/clock', Clock(), 0)
        bag.write_message('/clock', Clock(), np.int64(7))
    with pytest.raises(BagError, match='not open for writing'):
        bag.write_message('/clock', Clock(), 8)
    with pytest.raises(BagError, match='already exists'):
        BagWriter(tmp_path / 'misuse')
    with BagReader(tmp_path / 'misuse') as reader:
        assert reader.topic('/clock').count == 1


def test_exception_in_with_block_leaves_an_incomplete_but_recoverable_bag(tmp_path):
    path = tmp_path / 'failed_run'
    with pytest.raises(RuntimeError, match='physics bug'):
        with BagWriter(path, flush_period_ns=10**18) as bag:
            bag.add_topic('/clock', 'rosgraph_msgs/msg/Clock')
            for i in range(5):
                bag.write_message('/clock', Clock(clock=Time(sec=i)), i)
            raise RuntimeError('physics bug')
    assert not (path / 'metadata.yaml').exists()
    with pytest.raises(BagError, match=r'was not closed .*sofia recover'):
        BagReader(path)
    report = recover_bag(path)
    assert [(info.name, info.count) for info in report.topics] == [('/clock', 5)]


KILLED_WRITER = textwrap.dedent(
    """
    import sys, time
    from sensor_msgs.msg import Imu
    from sofia_ros.bag import BagWriter, wire_cdr

    root, count, flushed = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
    message = Imu()
    message.header.frame_id = 'gyrf'
    # Bag 'explicit': flushed by hand after `flushed` messages; the rest stay in the chunk buffer.
    explicit = BagWriter(root + '/explicit', flush_period_ns=10**18)
    explicit.open()
    explicit.add_topic('/gyro_box/imu', 'sensor_msgs/msg/Imu')
    explicit.write_document('/config/truth', 'effects: {}\\n', 0)
    for i in range(count):
        message.angular_velocity.x = float(i)
        explicit.write_raw('/gyro_box/imu', wire_cdr(message), 2_500_000 * (i + 1))
        if i + 1 == flushed:
            explicit.flush()
    # Bag 'periodic': 400 Hz for 5 s of log time, flushed by the writer every 1 s of it.
    periodic = BagWriter(root + '/periodic', flush_period_ns=1_000_000_000)
    periodic.open()
    periodic.add_topic('/gyro_box/imu', 'sensor_msgs/msg/Imu')
    for i in range(count):
        periodic.write_message('/gyro_box/imu', message, 2_500_000 * i)
    print('ready', flush=True)
    time.sleep(60)
    """
)


def test_sigkilled_writer_leaves_an_unclosed_bag_that_recovers_up_to_the_last_flush(tmp_path):
    count, flushed = 2000, 1700
    child = subprocess.Popen(
        [sys.executable, '-c', KILLED_WRITER, str(tmp_path), str(count), str(flushed)],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert child.stdout.readline().strip() == 'ready'
        os.kill(child.pid, signal.SIGKILL)
    finally:
        child.kill()
        child.wait(timeout=10)
        child.stdout.close()
    assert child.returncode == -signal.SIGKILL

    explicit = tmp_path / 'explicit'
    # What the readers report: no metadata.yaml, and an MCAP file without its summary.
    assert sorted(item.name for item in explicit.iterdir()) == ['explicit.mcap']
    with pytest.raises(BagError, match=r'bag .*explicit was not closed \(no metadata.yaml'):
        BagReader(explicit)
    with pytest.raises(FileNotFoundError):
        AnyReader([explicit]).open()

    report = recover_bag(explicit)
    assert not report.reached_footer
    assert {info.name: info.count for info in report.topics} == {
        '/config/truth': 1,
        '/gyro_box/imu': flushed,
    }
    assert report.last_stamp_ns == IMU_PERIOD_NS * flushed
    with BagReader(report.bag) as bag:
        assert bag.document('/config/truth') == 'effects: {}\n'
        arrays = bag.imu_arrays('/gyro_box/imu')
    np.testing.assert_array_equal(arrays.angular_velocity_rad_per_s[:, 0], np.arange(flushed))
    with (report.bag / f'{report.bag.name}.mcap').open('rb') as stream:
        summary = make_reader(stream, decoder_factories=[DecoderFactory()]).get_summary()
    assert summary.statistics.message_count == flushed + 1

    # Flushes at log times 0, 1, 2, 3 and 4 s, each writing what was logged before it: the messages
    # before 4 s (1600) survive.
    periodic = recover_bag(tmp_path / 'periodic', tmp_path / 'periodic_fixed')
    assert periodic.bag == tmp_path / 'periodic_fixed'
    assert periodic.message_count == 1600
    assert periodic.last_stamp_ns == 4_000_000_000 - IMU_PERIOD_NS


def test_a_damaged_summary_fails_its_crc_on_opening(round_trip, tmp_path):
    path, _, _ = round_trip
    damaged = shutil.copytree(path, tmp_path / 'summary')
    mcap_file = damaged / 'round_trip.mcap'
    data = bytearray(mcap_file.read_bytes())
    # The footer (opcode, length, summary start, ...) ends 8 bytes of magic before the end.
    (summary_start,) = struct.unpack_from('<Q', data, len(data) - 8 - 29 + 9)
    # The first summary record is a schema: one byte of its name changes.
    data[summary_start + 1 + 8 + 2 + 4] ^= 0x20
    mcap_file.write_bytes(bytes(data))
    with pytest.raises(BagError, match=rf'\(ValueError: the summary section \(byte {summary_start} on\) fails its '
                                       r'CRC check\); salvage'):
        BagReader(damaged).open()


SCENARIO = 'latitude_deg: 31.638\nstart_utc: 2004-09-03T04:22:16+00:00\nheading_deg: 0.0\n'
# 2004-09-03T04:22:16Z in ns since the Unix epoch.
START_NS = 1_094_185_336 * 1_000_000_000


def test_a_campaign_bag_holds_utc_and_reads_back_in_campaign_time(tmp_path):
    path = tmp_path / 'utc'
    with BagWriter(path, epoch_ns=START_NS) as bag:
        bag.write_document('/config/scenario', SCENARIO, 0)
        bag.add_topic('/clock', 'rosgraph_msgs/msg/Clock')
        bag.add_topic('/gyro_box/imu', 'sensor_msgs/msg/Imu')
        bag.add_topic('/status', 'diagnostic_msgs/msg/DiagnosticStatus')
        for i in range(3):
            bag.write_message('/clock', Clock(clock=Time(sec=i, nanosec=200_000_000)), i * 10**9 + 200_000_000)
            bag.write_message('/gyro_box/imu', imu(i), (1000 + i) * 10**9 + 123 + i)
            bag.write_message('/status', sample('diagnostic_msgs/msg/DiagnosticStatus', i), i * 10**9)
    info = yaml.safe_load((path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['starting_time']['nanoseconds_since_epoch'] == START_NS
    assert info['duration']['nanoseconds'] == 1002 * 10**9 + 125
    with BagReader(path) as bag:
        clock = [(stamp_ns, message.clock.sec, message.clock.nanosec) for _, stamp_ns, message in bag.messages('/clock')]
        utc = bag.imu_arrays('/gyro_box/imu')
    assert clock[1] == (START_NS + 1_200_000_000, 1_094_185_337, 200_000_000)
    np.testing.assert_array_equal(utc.header_stamp_ns, START_NS + np.array([1000, 1001, 1002]) * 10**9
                                  + np.array([123, 124, 125]))
    with BagReader(path, campaign_time=True) as bag:
        assert bag.origin_ns == START_NS
        clock = [(stamp_ns, message.clock.sec, message.clock.nanosec) for _, stamp_ns, message in bag.messages('/clock')]
        by_topic = bag.messages_by_topic('/clock', '/status', '/gyro_box/imu', raw=('/status',), imu=('/gyro_box/imu',))
        window = [stamp_ns for _, stamp_ns, _ in bag.messages('/clock', start_ns=10**9, stop_ns=2 * 10**9)]
    assert clock == [(i * 10**9 + 200_000_000, i, 200_000_000) for i in range(3)]
    assert by_topic['/clock'][0] == [i * 10**9 + 200_000_000 for i in range(3)]
    assert [message.clock.sec for message in by_topic['/clock'][1]] == [0, 1, 2]
    assert by_topic['/status'][0] == [0, 10**9, 2 * 10**9]
    assert [bytes(data) for data in by_topic['/status'][1]] == [
        bytes(wire_cdr(sample('diagnostic_msgs/msg/DiagnosticStatus', i))) for i in range(3)]
    imu_arrays = by_topic['/gyro_box/imu']
    np.testing.assert_array_equal(imu_arrays.stamp_ns, imu_arrays.header_stamp_ns)
    np.testing.assert_array_equal(imu_arrays.header_stamp_ns, [1000 * 10**9 + 123, 1001 * 10**9 + 124, 1002 * 10**9 + 125])
    assert window == [1_200_000_000]


def test_campaign_time_needs_the_scenario_start(tmp_path):
    path = tmp_path / 'no_scenario'
    with BagWriter(path) as bag:
        bag.write_document('/config/truth', 'effects: {}\n', 0)
    with BagReader(path, campaign_time=True) as bag:
        # Listing and documents need no time axis; times do.
        assert bag.document('/config/truth') == 'effects: {}\n'
        with pytest.raises(BagError, match=r'no_scenario has no /config/scenario to take the campaign start from; '
                                           r'record it with `sofia run`'):
            bag.messages('/config/truth')
    with BagWriter(tmp_path / 'naive') as bag:
        bag.write_document('/config/scenario', 'start_utc: 2004-09-03T04:22:16\n', 0)
    with BagReader(tmp_path / 'naive', campaign_time=True) as bag:
        with pytest.raises(BagError, match=r'has no campaign start .*ValueError start_utc has no timezone'):
            bag.messages_by_topic('/config/scenario')


def test_campaign_time_refuses_a_bag_recorded_from_time_zero(tmp_path):
    path = tmp_path / 'from_zero'
    with BagWriter(path) as bag:  # no epoch: times from 0, as bags were written before they carried UTC
        bag.write_document('/config/scenario', SCENARIO, 0)
    with BagReader(path, campaign_time=True) as bag:
        with pytest.raises(BagError, match=r'from_zero starts 1094185336 s before its campaign start '
                                           r'\(/config/scenario\): it was recorded with times from 0, not in UTC; '
                                           r're-record it with `sofia run`'):
            bag.messages('/config/scenario')


def test_the_writer_refuses_a_negative_epoch(tmp_path):
    with pytest.raises(InvalidArgumentError, match='epoch_ns must be >= 0, got -1'):
        BagWriter(tmp_path / 'bag', epoch_ns=-1)
