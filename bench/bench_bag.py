"""Bag I/O throughput for 400 Hz sensor_msgs/Imu: writes (raw CDR, message objects), reads, size;
before (rosbags' own MCAP writer: no CRCs, records in write order) and after (BagWriter: chunk, data and
summary CRCs, each chunk in log-time order, CRCs checked on reading), side by side in one run.

Run: .venv/bin/python bench/bench_bag.py [--count N]

Recorded on the 2-core development VM (Python 3.11, rosbags 0.11.9, rclpy 9.1.2), one run:

    sensor_msgs/Imu: 200,000 messages (8.3 min at 400 Hz), 324 B CDR
    write raw CDR (before_zstd)                   131,072 msg/s  bag 14.6 MB, 72.9 B/msg
    write raw CDR (after_zstd)                    233,116 msg/s  bag 14.6 MB, 72.9 B/msg
    write raw CDR (before_uncompressed)           196,396 msg/s  bag 74.3 MB, 371.4 B/msg
    write raw CDR (after_uncompressed)            318,003 msg/s  bag 74.3 MB, 371.4 B/msg
    write Imu objects (after_zstd_objects)         17,064 msg/s
    read raw CDR (before_zstd)                    269,341 msg/s
    read messages (before_zstd)                    55,528 msg/s
    read imu_arrays (before_zstd)                 775,503 msg/s
    read raw CDR (after_zstd)                     223,816 msg/s
    read messages (after_zstd)                     60,442 msg/s
    read imu_arrays (after_zstd)                  853,599 msg/s
    read raw CDR (before_uncompressed)            336,088 msg/s
    read messages (before_uncompressed)            64,326 msg/s
    read imu_arrays (before_uncompressed)       1,231,601 msg/s
    read raw CDR (after_uncompressed)             314,605 msg/s
    read messages (after_uncompressed)             67,063 msg/s
    read imu_arrays (after_uncompressed)        1,076,391 msg/s

Runs vary by 20-50 % on the shared machine: compare the before and after lines of one run. Writing message objects costs serialize_message plus the
typestore round trip of wire_cdr (about 15 us per Imu).
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

import numpy as np
from builtin_interfaces.msg import Time
from sensor_msgs.msg import Imu

from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.rosbag2.enums import CompressionFormat, CompressionMode

from sofia_ros.bag import TYPESTORE, BagReader, BagWriter, wire_cdr
from sofia_ros.bag.writer import ROSBAG2_VERSION

TOPIC = '/gyro_box/imu'
PERIOD_NS = 2_500_000  # 400 Hz
# Distinct message objects built up front; the object benchmark cycles through them.
OBJECT_POOL_SIZE = 20_000
#: 2004-09-03T04:32:51Z, the default alignment campaign's start: BagWriter adds it to every stamp.
WACO_2004_EPOCH_NS = 1_094_185_971 * 1_000_000_000


def imu_messages(count: int, seed: int) -> list[Imu]:
    """Gyro-box-like Imu messages: Earth rate plus white noise, gravity plus noise."""
    rng = np.random.default_rng(seed)
    rates_rad_per_s = 7.29e-5 + 1e-6 * rng.standard_normal((count, 3))
    accel_m_per_s2 = np.array([0.0, 0.0, 9.81]) + 1e-3 * rng.standard_normal((count, 3))
    messages = []
    for i in range(count):
        message = Imu()
        stamp_ns = i * PERIOD_NS
        message.header.stamp = Time(sec=stamp_ns // 10**9, nanosec=stamp_ns % 10**9)
        message.header.frame_id = 'gyrf'
        message.orientation_covariance[0] = -1.0  # no orientation estimate (REP-145)
        gyro, accel = message.angular_velocity, message.linear_acceleration
        gyro.x, gyro.y, gyro.z = rates_rad_per_s[i]
        accel.x, accel.y, accel.z = accel_m_per_s2[i]
        messages.append(message)
    return messages


def report(what: str, count: int, seconds: float, extra: str = '') -> None:
    """Print one result line in messages per second."""
    print(f'{what:42s} {count / seconds:>10,.0f} msg/s  {extra}')


def write_before(path: Path, payloads: list[bytes], compress: bool) -> None:
    """The writer this package used before: rosbags' MCAP storage, its chunk closed every 1 s of log time."""
    writer = Writer(path, version=ROSBAG2_VERSION, storage_plugin=StoragePlugin.MCAP)
    if compress:
        writer.set_compression(CompressionMode.STORAGE, CompressionFormat.ZSTD)
    with writer:
        connection = writer.add_connection(TOPIC, 'sensor_msgs/msg/Imu', typestore=TYPESTORE)
        due_ns = 0
        for i, payload in enumerate(payloads):
            writer.write(connection, i * PERIOD_NS, payload)
            if i * PERIOD_NS >= due_ns:
                writer.storage.close_chunk()
                writer.storage.bio.flush()
                due_ns = i * PERIOD_NS + 1_000_000_000


def write_after(path: Path, payloads: list[bytes], compress: bool) -> None:
    """BagWriter as a campaign uses it: CRC-checked chunks in log-time order, stamps moved to the campaign's UTC."""
    with BagWriter(path, compress=compress, epoch_ns=WACO_2004_EPOCH_NS) as bag:
        bag.add_topic(TOPIC, 'sensor_msgs/msg/Imu')
        for i, payload in enumerate(payloads):
            bag.write_raw(TOPIC, payload, i * PERIOD_NS)


def bench_raw_writes(path: Path, payloads: list[bytes], compress: bool, writer) -> None:
    """Write ``payloads`` as raw CDR into a new bag at ``path``; print rate and size."""
    start = time.perf_counter()
    writer(path, payloads, compress)
    seconds = time.perf_counter() - start
    size_bytes = sum(item.stat().st_size for item in path.iterdir())
    size = f'bag {size_bytes / 1e6:.1f} MB, {size_bytes / len(payloads):.1f} B/msg'
    report(f'write raw CDR ({path.name})', len(payloads), seconds, size)


def bench_object_writes(path: Path, pool: list[Imu], count: int) -> None:
    """Write ``count`` Imu message objects into a new bag at ``path``; print the rate."""
    start = time.perf_counter()
    with BagWriter(path) as bag:
        bag.add_topic(TOPIC, 'sensor_msgs/msg/Imu')
        for i in range(count):
            bag.write_message(TOPIC, pool[i % len(pool)], i * PERIOD_NS)
    report(f'write Imu objects ({path.name})', count, time.perf_counter() - start)


def bench_reads(path: Path) -> None:
    """Read the Imu topic of bag ``path`` three ways; print the rates."""
    with BagReader(path) as bag:
        start = time.perf_counter()
        count = sum(1 for _ in bag.raw_messages(TOPIC))
        report(f'read raw CDR ({path.name})', count, time.perf_counter() - start)
        start = time.perf_counter()
        count = sum(1 for _ in bag.messages(TOPIC))
        report(f'read messages ({path.name})', count, time.perf_counter() - start)
        start = time.perf_counter()
        count = len(bag.imu_arrays(TOPIC).stamp_ns)
        report(f'read imu_arrays ({path.name})', count, time.perf_counter() - start)


def main() -> None:
    """Print write and read throughput and bag sizes, before and after."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--count', type=int, default=200_000, help='Imu messages per bag')
    count = parser.parse_args().count
    pool = imu_messages(OBJECT_POOL_SIZE, seed=1)
    payloads = [bytes(wire_cdr(pool[i % OBJECT_POOL_SIZE])) for i in range(count)]
    minutes = count * PERIOD_NS / 60e9
    print(f'sensor_msgs/Imu: {count:,} messages ({minutes:.1f} min at 400 Hz), {len(payloads[0])} B CDR')
    with tempfile.TemporaryDirectory() as tmp:
        bags = {}
        for compress, kind in ((True, 'zstd'), (False, 'uncompressed')):
            for name, writer in (('before', write_before), ('after', write_after)):
                bags[name, kind] = Path(tmp) / f'{name}_{kind}'
                bench_raw_writes(bags[name, kind], payloads, compress, writer)
        bench_object_writes(Path(tmp) / 'after_zstd_objects', pool, count)
        for kind in ('zstd', 'uncompressed'):
            for name in ('before', 'after'):
                bench_reads(bags[name, kind])


if __name__ == '__main__':
    main()
