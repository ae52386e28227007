"""Benchmark: `sofia compare` on full-size campaign bags, with the whole catalogue and the diagnostics on.

The bags are the default alignment campaign of `scripts/run-main` (nominal truth, seed 1, 6
repetitions, direct mode), made in a temporary directory unless bags are given, and optionally
the 17-observation star hop (`sofia run star-hop --truth config/truth/nominal.yaml --seed 1
--direct --bag B`). Each comparison runs as `sofia compare BAG --model config/model/nominal.yaml`
in its own process, as a user runs it: printed are its wall time, its CPU time (user + system, all
threads) and its peak memory, with the machine's load beside them, against the targets of issue 14
(alignment <= 5 s, star hop <= 20 s, <= 1 GB); then the parts the comparison reports itself. With
``--baseline CHECKOUT`` (another checkout of the repository, e.g. ``git worktree add /tmp/base main``)
the same comparison also runs from that checkout, alternating with this one ``--rounds`` times, and
the ratios are printed (the faster round of each kept): before and after under the same load. The
two JSON outputs are then checked to agree: the same verdict, candidates and degenerate pairs, every
fitted term within 1e-3 of its sigma. Beside it, the observables' topics read through the MCAP
message indexes against the same topics record by record through rosbags (what `read_observations`
did before), measured in one run, as a ratio.

Run: .venv/bin/python bench/bench_compare.py [ALIGNMENT_BAG [STAR_HOP_BAG]] [--baseline CHECKOUT [--rounds N]]
"""

from __future__ import annotations

import argparse
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

from results_file import Transcript, current_load, write_results  # noqa: E402

#: Every line printed, for bench/results/compare.txt.
TRANSCRIPT = Transcript()
say = TRANSCRIPT.say

MODEL = ROOT / 'config' / 'model' / 'nominal.yaml'
#: Issue 14's targets: wall seconds per campaign on the 2-core machine, and peak memory.
TARGET_S = {'alignment': 5.0, 'star-hop': 20.0}
TARGET_MEMORY_MB = 1024.0
#: A fitted value of the baseline and of this checkout may differ by this fraction of its sigma (numerical noise).
AGREEMENT_SIGMA = 1e-3


def _load():
    return f'load average {os.getloadavg()[0]:.2f} on {os.cpu_count()} cores'


def read_record_by_record(bag_path, topics):
    """The observables' topics through rosbags, one record at a time, Imu decoded in bulk as before."""
    with BagReader(bag_path) as bag:
        imu = decode_imu_cdr(*zip(*((stamp, data) for _, stamp, data in bag.raw_messages(topics[0]))))
        others = [message for _, _, message in bag.messages(*topics[1:])]
    return imu, others


def compare_in_a_process(bag, json_path, checkout=ROOT):
    """`sofia compare` of ``checkout`` in its own process: (wall s, CPU s of user + system, peak MB, load before)."""
    load = _load()
    started = time.perf_counter()
    # Run from the checkout: `python -m` puts the working directory first on sys.path, before PYTHONPATH.
    process = subprocess.Popen([sys.executable, '-m', 'sofia_ros.cli', 'compare', str(Path(bag).resolve()), '--model',
                                str(MODEL), '--json', str(json_path)], stdout=subprocess.DEVNULL, cwd=checkout,
                               env={**os.environ, 'PYTHONPATH': str(checkout)})
    _, status, usage = os.wait4(process.pid, 0)
    wall_s = time.perf_counter() - started
    process.returncode = os.waitstatus_to_exitcode(status)
    if process.returncode != 0:
        raise SystemExit(f'sofia compare {bag} ({checkout}) failed with exit code {process.returncode}')
    return wall_s, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024.0, load


def disagreements(before, after):
    """What differs between two compare documents beyond numerical noise (verdict, candidates, terms), as lines."""
    lines = []
    verdicts = [(document['verdict']['status'], document['verdict']['text']) for document in (before, after)]
    if verdicts[0] != verdicts[1]:
        lines.append(f'verdict {before["verdict"]["status"]!r} became {after["verdict"]["status"]!r}')
    for key in ('degenerate', 'unobservable'):
        if before[key] != after[key]:
            lines.append(f'{key}: {before[key]} became {after[key]}')
    if [c['effect'] for c in before['candidates']] != [c['effect'] for c in after['candidates']]:
        lines.append('the candidates are ranked differently')
    for old, new in zip(before['terms'], after['terms']):
        shift = abs(new['value'] - old['value']) / old['sigma']
        if shift > AGREEMENT_SIGMA:
            lines.append(f'{old["effect"]}.{old["param"]} moved by {shift:.2g} sigma')
    return lines


def bench_reading(bag):
    """Print and return the wall time of reading the observables through the indexes and record by record."""
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
    say(f'  reading the bag alone: {read_s:.2f} s through the message indexes; the same topics record by record '
        f'through rosbags: {rosbags_s:.2f} s ({rosbags_s / read_s:.1f}x; {_load()})')
    return {'indexed_s': read_s, 'record_by_record_s': rosbags_s, 'speed_up': rosbags_s / read_s,
            'load': current_load()}


def bench_compare(campaign, bag, folder, baseline=None, rounds=1):
    """Print and return the figures of `sofia compare` on ``bag`` (and of ``baseline``'s, alternating)."""
    json_path = Path(folder) / f'{campaign}.json'
    runs = {}  # checkout -> the fastest (wall s, CPU s, peak MB, load) of its rounds
    for _ in range(rounds):
        for checkout in ([baseline] if baseline else []) + [ROOT]:
            path = json_path.with_suffix('.baseline.json') if checkout == baseline else json_path
            figures = compare_in_a_process(bag, path, checkout)
            runs[checkout] = min(runs.get(checkout, figures), figures)
    document = json.loads(json_path.read_text())
    say(f'{campaign}: {sum(document["observations"].values())} centroids, {len(document["candidates"])} candidates')
    wall_s, cpu_s, peak_mb, load = runs[ROOT]
    figures = {'campaign': campaign, 'centroids': sum(document['observations'].values()),
               'candidates': len(document['candidates']), 'wall_s': wall_s, 'cpu_s': cpu_s, 'peak_mb': peak_mb,
               'load_before': load, 'load_after': _load(), 'target_wall_s': TARGET_S[campaign],
               'target_memory_mb': TARGET_MEMORY_MB}
    say(f'  sofia compare: {wall_s:.2f} s wall, {cpu_s:.2f} s CPU (target <= {TARGET_S[campaign]:g} s wall; '
        f'{load} before, {_load()} after); peak memory {peak_mb:.0f} MB (target <= {TARGET_MEMORY_MB:.0f} MB)')
    if baseline:
        old_wall_s, old_cpu_s, old_peak_mb, old_load = runs[baseline]
        say(f'  baseline {baseline}: {old_wall_s:.2f} s wall, {old_cpu_s:.2f} s CPU, {old_peak_mb:.0f} MB '
            f'({old_load} before); this checkout is {old_wall_s / wall_s:.2f}x faster in wall time, '
            f'{old_cpu_s / cpu_s:.2f}x in CPU time, {old_peak_mb / peak_mb:.2f}x in memory (best of {rounds})')
        lines = disagreements(json.loads(json_path.with_suffix('.baseline.json').read_text()), document)
        figures['baseline'] = {'checkout': str(baseline), 'wall_s': old_wall_s, 'cpu_s': old_cpu_s,
                               'peak_mb': old_peak_mb, 'load_before': old_load, 'rounds': rounds,
                               'disagreements': lines}
        say('  results: ' + ('; '.join(lines) if lines else f'the same verdict and candidates, every fitted term '
                                                             f'within {AGREEMENT_SIGMA:g} sigma of the baseline'))
    seconds = document['seconds']
    say(f'  inside it (wall): comparison {seconds["total"]:.2f} s, of which diagnostics {seconds["diagnostics"]:.2f} s, '
        f'{seconds["per_candidate"] * 1000:.0f} ms per linearized candidate')
    for candidate in document['candidates']:
        if candidate['refined']:
            say(f'  refit {candidate["effect"]:<28} {candidate["seconds"]:6.3f} s  dBIC {candidate["delta_bic"]:9.1f}')
    figures['seconds'] = seconds
    figures['refits'] = [{'effect': candidate['effect'], 'seconds': candidate['seconds'],
                          'delta_bic': candidate['delta_bic']} for candidate in document['candidates']
                         if candidate['refined']]
    figures['reading'] = bench_reading(bag)
    return figures


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('bags', nargs='*', type=Path, help='the alignment bag and, optionally, the star-hop bag')
    parser.add_argument('--baseline', type=Path, help='another checkout of the repository to compare against')
    parser.add_argument('--rounds', type=int, default=1, help='runs of each checkout, alternating; the fastest kept')
    args = parser.parse_args()
    load_before = current_load()
    results = {'bags': [str(bag) for bag in args.bags]}
    with tempfile.TemporaryDirectory(prefix='bench_compare_') as folder:
        if args.bags:
            bags = dict(zip(('alignment', 'star-hop'), args.bags))
        else:
            bags = {'alignment': Path(folder) / 'alignment'}
            started = time.perf_counter()
            run_alignment(load_effect_config(ROOT / 'config/truth/nominal.yaml'), seed=1, bag_path=bags['alignment'],
                          mode='direct')
            results['record_s'] = time.perf_counter() - started
            say(f'campaign (direct mode) recorded in {results["record_s"]:.1f} s: {bags["alignment"]}')
        results['campaigns'] = [bench_compare(campaign, bag, folder, args.baseline and args.baseline.resolve(),
                                              args.rounds) for campaign, bag in bags.items()]
    write_results('compare', results, TRANSCRIPT.lines, load_before=load_before)


if __name__ == '__main__':
    main()
