"""Bag I/O throughput for 400 Hz sensor_msgs/Imu: writes (raw CDR, message objects), reads, size;
before (rosbags' own MCAP writer: no CRCs, records in write order) and after (BagWriter: chunk, data and
summary CRCs, each chunk in log-time order, CRCs checked on reading), side by side in one run.

Run: .venv/bin/python bench/bench_bag.py [--count N]

Recorded on the 2-core development VM (Python 3.11, rosbags 0.11.9, rclpy 9.1.2), shared with other
work (load 4-12 during the run), one run:

    sensor_msgs/Imu: 200,000 messages (8.3 min at 400 Hz), 324 B CDR; best of 3, before and after alternating
    write raw CDR (before, zstd)                  111,528 msg/s  bag 14.6 MB, 72.9 B/msg
    write raw CDR (after, zstd)                   109,498 msg/s  bag 14.6 MB, 72.9 B/msg
    write raw CDR (before, uncompressed)          177,042 msg/s  bag 74.3 MB, 371.4 B/msg
    write raw CDR (after, uncompressed)           200,598 msg/s  bag 74.3 MB, 371.4 B/msg
    write Imu objects (after, zstd)                14,773 msg/s
    read raw CDR (before, zstd)                   176,815 msg/s
    read raw CDR (after, zstd)                    182,020 msg/s
    read messages (before, zstd)                   53,860 msg/s
    read messages (after, zstd)                    73,072 msg/s
    read imu_arrays (before, zstd)              1,089,846 msg/s
    read imu_arrays (after, zstd)                 982,749 msg/s
    read raw CDR (before, uncompressed)           318,719 msg/s
    read raw CDR (after, uncompressed)            311,499 msg/s
    read messages (before, uncompressed)           68,706 msg/s
    read messages (after, uncompressed)            69,627 msg/s
    read imu_arrays (before, uncompressed)        812,686 msg/s
    read imu_arrays (after, uncompressed)       1,194,007 msg/s

The new writer also moves every stamp to the campaign's UTC time (about 1 us per message) and
sorts each chunk; its bulk packing pays for that and the CRCs. Reading checks every chunk's CRC.
On a machine this loaded single runs vary by 20-50 %: the fastest of alternating repeats is kept.
Writing message objects costs serialize_message plus the typestore round trip of wire_cdr.
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

from results_file import Transcript, current_load, write_results

TOPIC = '/gyro_box/imu'
PERIOD_NS = 2_500_000  # 400 Hz
# Distinct message objects built up front; the object benchmark cycles through them.
OBJECT_POOL_SIZE = 20_000
#: 2004-09-03T04:32:51Z, the default alignment campaign's start: BagWriter adds it to every stamp.
WACO_2004_EPOCH_NS = 1_094_185_971 * 1_000_000_000
#: Every line printed, for bench/results/bag.txt.
TRANSCRIPT = Transcript()
say = TRANSCRIPT.say
#: Every measurement of the run: what, messages per second and (for a write) bag size, for bench/results/bag.json.
MEASUREMENTS: list[dict] = []


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
    """Print one result line in messages per second and keep its figures."""
    MEASUREMENTS.append({'what': what, 'messages': count, 'seconds': seconds, 'msg_per_s': count / seconds})
    say(f'{what:42s} {count / seconds:>10,.0f} msg/s  {extra}'.rstrip())


def best_seconds(run, repeats: int) -> float:
    """The shortest wall time of ``repeats`` calls of ``run(i)`` (the machine is shared: the fastest is the least disturbed)."""
    times = []
    for i in range(repeats):
        start = time.perf_counter()
        run(i)
        times.append(time.perf_counter() - start)
    return min(times)


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


def bench_writes(root: Path, payloads: list[bytes], compress: bool, repeats: int) -> dict[str, Path]:
    """Write ``payloads`` as raw CDR with the old and the new writer, alternating; print rates and sizes."""
    kind = 'zstd' if compress else 'uncompressed'
    seconds, paths = {}, {}
    for i in range(repeats):
        for name, writer in (('before', write_before), ('after', write_after)):
            paths[name] = root / f'{name}_{kind}_{i}'
            start = time.perf_counter()
            writer(paths[name], payloads, compress)
            seconds[name] = min(seconds.get(name, float('inf')), time.perf_counter() - start)
    for name in ('before', 'after'):
        size_bytes = sum(item.stat().st_size for item in paths[name].iterdir())
        size = f'bag {size_bytes / 1e6:.1f} MB, {size_bytes / len(payloads):.1f} B/msg'
        report(f'write raw CDR ({name}, {kind})', len(payloads), seconds[name], size)
        MEASUREMENTS[-1].update(bag_mb=size_bytes / 1e6, bytes_per_message=size_bytes / len(payloads))
    return paths


def bench_object_writes(root: Path, pool: list[Imu], count: int, repeats: int) -> None:
    """Write ``count`` Imu message objects into new bags; print the best rate."""
    def write(i):
        with BagWriter(root / f'objects_{i}', epoch_ns=WACO_2004_EPOCH_NS) as bag:
            bag.add_topic(TOPIC, 'sensor_msgs/msg/Imu')
            for k in range(count):
                bag.write_message(TOPIC, pool[k % len(pool)], k * PERIOD_NS)
    report('write Imu objects (after, zstd)', count, best_seconds(write, repeats))


def bench_reads(paths: dict[str, Path], kind: str, repeats: int) -> None:
    """Read the Imu topic of the old and the new writer's bag three ways, alternating; print the best rates."""
    ways = {
        'read raw CDR': lambda bag: sum(1 for _ in bag.raw_messages(TOPIC)),
        'read messages': lambda bag: sum(1 for _ in bag.messages(TOPIC)),
        'read imu_arrays': lambda bag: len(bag.imu_arrays(TOPIC).stamp_ns),
    }
    for way, read in ways.items():
        for name in ('before', 'after'):
            with BagReader(paths[name]) as bag:
                count = read(bag)
                seconds = best_seconds(lambda _: read(bag), repeats)
            report(f'{way} ({name}, {kind})', count, seconds)


def main() -> None:
    """Print write and read throughput and bag sizes, before and after."""
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--count', type=int, default=200_000, help='Imu messages per bag')
    parser.add_argument('--repeats', type=int, default=3, help='runs of each measurement; the fastest is kept')
    args = parser.parse_args()
    count, repeats = args.count, args.repeats
    load_before = current_load()
    pool = imu_messages(OBJECT_POOL_SIZE, seed=1)
    payloads = [bytes(wire_cdr(pool[i % OBJECT_POOL_SIZE])) for i in range(count)]
    minutes = count * PERIOD_NS / 60e9
    say(f'sensor_msgs/Imu: {count:,} messages ({minutes:.1f} min at 400 Hz), {len(payloads[0])} B CDR; '
        f'best of {repeats}, before and after alternating')
    with tempfile.TemporaryDirectory() as tmp:
        written = {kind: bench_writes(Path(tmp), payloads, compress, repeats)
                   for kind, compress in (('zstd', True), ('uncompressed', False))}
        bench_object_writes(Path(tmp), pool, min(count, 50_000), repeats)
        for kind, paths in written.items():
            bench_reads(paths, kind, repeats)
    write_results('bag', {'messages': count, 'repeats': repeats, 'cdr_bytes': len(payloads[0]),
                          'measurements': MEASUREMENTS}, TRANSCRIPT.lines, load_before=load_before)


if __name__ == '__main__':
    main()
