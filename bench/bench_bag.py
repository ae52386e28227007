"""Bag I/O throughput for 400 Hz sensor_msgs/Imu: writes (raw CDR, message objects), reads, size.

Run: .venv/bin/python bench/bench_bag.py [--count N]

Recorded on the 2-core development VM (Python 3.11, rosbags 0.11.9, rclpy 9.1.2):

    sensor_msgs/Imu: 200,000 messages (8.3 min at 400 Hz), 324 B CDR
    write raw CDR (zstd)                    346,949 msg/s  bag 14.6 MB, 72.9 B/msg
    write raw CDR (uncompressed)            364,676 msg/s  bag 74.3 MB, 371.4 B/msg
    write Imu objects (zstd_objects)         50,405 msg/s
    read raw CDR (zstd)                     516,492 msg/s
    read messages (zstd)                    125,712 msg/s
    read imu_arrays (zstd)                  220,093 msg/s
    read raw CDR (uncompressed)             514,368 msg/s
    read messages (uncompressed)            125,590 msg/s
    read imu_arrays (uncompressed)          346,290 msg/s

Runs vary by about 20 %. Writing message objects costs serialize_message plus the
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

from sofia_ros.bag import BagReader, BagWriter, wire_cdr

TOPIC = '/gyro_box/imu'
PERIOD_NS = 2_500_000  # 400 Hz
# Distinct message objects built up front; the object benchmark cycles through them.
OBJECT_POOL_SIZE = 20_000


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
    print(f'{what:36s} {count / seconds:>10,.0f} msg/s  {extra}')


def bench_raw_writes(path: Path, payloads: list[bytes], compress: bool) -> None:
    """Write ``payloads`` as raw CDR into a new bag at ``path``; print rate and size."""
    start = time.perf_counter()
    with BagWriter(path, compress=compress) as bag:
        bag.add_topic(TOPIC, 'sensor_msgs/msg/Imu')
        for i, payload in enumerate(payloads):
            bag.write_raw(TOPIC, payload, i * PERIOD_NS)
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
    """Print write and read throughput and bag sizes."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--count', type=int, default=200_000, help='Imu messages per bag')
    count = parser.parse_args().count
    pool = imu_messages(OBJECT_POOL_SIZE, seed=1)
    payloads = [bytes(wire_cdr(pool[i % OBJECT_POOL_SIZE])) for i in range(count)]
    minutes = count * PERIOD_NS / 60e9
    print(f'sensor_msgs/Imu: {count:,} messages ({minutes:.1f} min at 400 Hz), {len(payloads[0])} B CDR')
    with tempfile.TemporaryDirectory() as tmp:
        zstd, plain = Path(tmp) / 'zstd', Path(tmp) / 'uncompressed'
        bench_raw_writes(zstd, payloads, compress=True)
        bench_raw_writes(plain, payloads, compress=False)
        bench_object_writes(Path(tmp) / 'zstd_objects', pool, count)
        bench_reads(zstd)
        bench_reads(plain)


if __name__ == '__main__':
    main()
