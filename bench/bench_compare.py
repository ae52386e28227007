"""Benchmark: `sofia compare` on full-size campaign bags, with the whole catalogue and the diagnostics on.

The bags are the default alignment campaign of `scripts/run-main` (nominal truth, seed 1, 6
repetitions, direct mode), made in a temporary directory unless bags are given, and optionally
the 17-observation star hop (`sofia run star-hop --truth config/truth/nominal.yaml --seed 1
--direct --bag B`). Each comparison runs as `sofia compare BAG --model config/model/nominal.yaml`
in its own process, as a user runs it: printed are its wall time, its CPU time (user + system, all
threads) and its peak memory, with the machine's load beside them, against the targets of issue 14
(alignment <= 5 s, star hop <= 20 s, <= 1 GB); then the parts the comparison reports itself. The old
comparison path is gone (no dead code for a bench), so there is no old-vs-new ratio here. Beside it,
the observables' topics read through the MCAP message indexes against the same topics record by
record through rosbags (what `read_observations` did before), measured in one run, as a ratio.

Run: .venv/bin/python bench/bench_compare.py [ALIGNMENT_BAG [STAR_HOP_BAG]]
"""

from __future__ import annotations

import json
import os
import subprocess
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
from sofia_ros.config import load_effect_config  # noqa: E402

MODEL = ROOT / 'config' / 'model' / 'nominal.yaml'
#: Issue 14's targets: wall seconds per campaign on the 2-core machine, and peak memory.
TARGET_S = {'alignment': 5.0, 'star-hop': 20.0}
TARGET_MEMORY_MB = 1024.0


def _load():
    return f'load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores'


def read_record_by_record(bag_path, topics):
    """The observables' topics through rosbags, one record at a time, Imu decoded in bulk as before."""
    with BagReader(bag_path) as bag:
        imu = decode_imu_cdr(*zip(*((stamp, data) for _, stamp, data in bag.raw_messages(topics[0]))))
        others = [message for _, _, message in bag.messages(*topics[1:])]
    return imu, others


def compare_in_a_process(bag, json_path):
    """`sofia compare` in its own process: (wall s, CPU s of user + system, peak RSS MB, load before)."""
    load = _load()
    started = time.perf_counter()
    process = subprocess.Popen([sys.executable, '-m', 'sofia_ros.cli', 'compare', str(bag), '--model', str(MODEL),
                                '--json', str(json_path)], stdout=subprocess.DEVNULL)
    _, status, usage = os.wait4(process.pid, 0)
    wall_s = time.perf_counter() - started
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode != 0:
        raise SystemExit(f'sofia compare {bag} failed with exit code {process.returncode}')
    return wall_s, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024.0, load


def bench_reading(bag):
    with BagReader(bag) as reader:
        topics = ('/gyro_box/imu', *(info.name for info in reader.topics
                                     if info.name.endswith('/centroids') or info.name in (
                                         '/gyro_box/temperature', '/ta/joint_states', '/tascu/attitude',
                                         '/tascu/motion_status', '/calibration/result')))
    # Each reading twice, alternating, the faster kept: the first call also pays imports and caches.
    read_s, rosbags_s = float('inf'), float('inf')
    for _ in range(2):
        started = time.perf_counter()
        read_observations(bag)
        read_s = min(read_s, time.perf_counter() - started)
        started = time.perf_counter()
        read_record_by_record(bag, topics)
        rosbags_s = min(rosbags_s, time.perf_counter() - started)
    print(f'  reading the bag alone: {read_s:.2f} s through the message indexes; the same topics record by record '
          f'through rosbags: {rosbags_s:.2f} s ({rosbags_s / read_s:.1f}x; {_load()})')


def bench_compare(campaign, bag, folder):
    json_path = Path(folder) / f'{campaign}.json'
    wall_s, cpu_s, peak_mb, load = compare_in_a_process(bag, json_path)
    document = json.loads(json_path.read_text())
    print(f'{campaign}: {sum(document["observations"].values())} centroids, {len(document["candidates"])} candidates')
    print(f'  sofia compare: {wall_s:.2f} s wall, {cpu_s:.2f} s CPU (target <= {TARGET_S[campaign]:g} s wall; '
          f'{load} before, {_load()} after); peak memory {peak_mb:.0f} MB (target <= {TARGET_MEMORY_MB:.0f} MB)')
    seconds = document['seconds']
    print(f'  inside it (wall): comparison {seconds["total"]:.2f} s, of which diagnostics {seconds["diagnostics"]:.2f} s, '
          f'{seconds["per_candidate"] * 1000:.0f} ms per linearized candidate')
    for candidate in document['candidates']:
        if candidate['refined']:
            print(f'  refit {candidate["effect"]:<28} {candidate["seconds"]:6.3f} s  dBIC {candidate["delta_bic"]:9.1f}')
    bench_reading(bag)


def main():
    with tempfile.TemporaryDirectory(prefix='bench_compare_') as folder:
        if len(sys.argv) > 1:
            bags = dict(zip(('alignment', 'star-hop'), map(Path, sys.argv[1:3])))
        else:
            bags = {'alignment': Path(folder) / 'alignment'}
            started = time.perf_counter()
            run_alignment(load_effect_config(ROOT / 'config/truth/nominal.yaml'), seed=1, bag_path=bags['alignment'],
                          mode='direct')
            print(f'campaign (direct mode) recorded in {time.perf_counter() - started:.1f} s: {bags["alignment"]}')
        for campaign, bag in bags.items():
            bench_compare(campaign, bag, folder)


if __name__ == '__main__':
    main()
