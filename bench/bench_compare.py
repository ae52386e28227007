"""Benchmark: `sofia compare` on a full-size alignment-campaign bag with the whole catalogue as candidates.

The bag is the default campaign of `scripts/run-main` (nominal truth, seed 1, 6 repetitions,
direct mode), made in a temporary directory unless a bag is given. Printed: wall time of the
comparison (reading the bag, the ledger fits, the diagnostics of every observable, every
candidate, the refits), its parts, and the time per candidate, with the machine's load beside
it. Target: <= 10 s wall on the 2-core machine. Beside it, the same topics read record by
record through rosbags (what `read_observations` did before it read through the MCAP message
indexes).

Run: .venv/bin/python bench/bench_compare.py [BAG]
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sofia_ros.bag import BagReader  # noqa: E402
from sofia_ros.bag.imu import decode_imu_cdr  # noqa: E402
from sofia_ros.campaigns.alignment import run_alignment  # noqa: E402
from sofia_ros.compare.observations import read_observations  # noqa: E402
from sofia_ros.compare.run import compare_bag  # noqa: E402
from sofia_ros.config import load_effect_config  # noqa: E402


def read_record_by_record(bag_path, topics):
    """The observables' topics through rosbags, one record at a time, Imu decoded in bulk as before."""
    with BagReader(bag_path) as bag:
        imu = decode_imu_cdr(*zip(*((stamp, data) for _, stamp, data in bag.raw_messages(topics[0]))))
        others = [message for _, _, message in bag.messages(*topics[1:])]
    return imu, others


def main():
    with tempfile.TemporaryDirectory(prefix='bench_compare_') as folder:
        if len(sys.argv) > 1:
            bag = Path(sys.argv[1])
        else:
            bag = Path(folder) / 'alignment'
            started = time.perf_counter()
            run_alignment(load_effect_config(ROOT / 'config/truth/nominal.yaml'), seed=1, bag_path=bag, mode='direct')
            print(f'campaign (direct mode) recorded in {time.perf_counter() - started:.1f} s: {bag}')
        model = load_effect_config(ROOT / 'config/model/nominal.yaml')
        with BagReader(bag) as reader:
            topics = ('/gyro_box/imu', *(info.name for info in reader.topics
                                         if info.name.endswith('/centroids') or info.name in (
                                             '/gyro_box/temperature', '/ta/joint_states', '/tascu/attitude',
                                             '/tascu/motion_status', '/calibration/result')))
        # Each reading twice, alternating, the faster kept: the first call also pays imports and caches.
        read_s, rosbags_s = float('inf'), float('inf')
        for _ in range(2):
            started = time.perf_counter()
            observations = read_observations(bag)
            read_s = min(read_s, time.perf_counter() - started)
            started = time.perf_counter()
            read_record_by_record(bag, topics)
            rosbags_s = min(rosbags_s, time.perf_counter() - started)
        started = time.perf_counter()
        document = compare_bag(bag, model).document
        total_s = time.perf_counter() - started
    candidates = document['candidates']
    print(f'centroids: {sum(document["observations"].values())}, gyro samples: {len(observations.gyro.time_s)}')
    print(f'reading the bag alone: {read_s:.2f} s through the message indexes; the same topics record by record '
          f'through rosbags: {rosbags_s:.2f} s ({rosbags_s / read_s:.1f}x)')
    print(f'sofia compare, whole: {total_s:.2f} s wall (target <= 10 s; load average {os.getloadavg()[0]:.2f} on '
          f'{os.cpu_count()} cores); diagnostics {document["seconds"]["diagnostics"]:.2f} s; {len(candidates)} '
          f'candidates, {document["seconds"]["per_candidate"] * 1000:.0f} ms each linearized')
    for candidate in candidates:
        print(f'  {candidate["effect"]:<28} {candidate["seconds"]:6.3f} s  '
              f'{"refit" if candidate["refined"] else "linear"}  dBIC {candidate["delta_bic"]:9.1f}')
    print(f'residual RMS {document["residual_rms_arcsec"]["total"]:.3f}", floor {document["noise_floor_arcsec"]:.3f}"')


if __name__ == '__main__':
    main()
