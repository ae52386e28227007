"""Real-time factor of the alignment campaign in each mode, side by side in one run, as ratios against direct
mode, with CPU time, peak memory and the machine's load; the in-process graph once cold (the checkout not compiled yet) too.

    .venv/bin/python bench/bench_alignment.py [--repetitions 6] [--modes direct executor executor-dds processes] [--no-cold]

Each run is its own process (so peak memory and CPU are that run's own) with the same truth
(config/truth/nominal.yaml), seed and plan; wall time is measured around the whole run (start-up,
imports and DDS discovery included), CPU time is that of the run's process and of its node
processes. The cold run starts with the checkout's bytecode removed (sofia_ros/**/__pycache__), as the
first run after editing every module would: scripts/setup-venv compiles the installed packages and the
checkout, but an edited module is compiled again on import; the warm runs use the bytecode cache. The
machine is shared, so the ratios, measured in the same run, are the figures to compare; the load
average is printed beside every absolute time. Last, the bags of every run are compared topic by topic
(sofia_ros.bag.digest). About 6 min with the defaults on an idle 2-core machine.
"""

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

from sofia_ros.bag.digest import topic_digests
from sofia_ros.topics import STOP_DOCUMENT

from results_file import Transcript, current_load, write_results

ROOT = Path(__file__).resolve().parents[1]
#: Every line printed, for bench/results/alignment.txt.
TRANSCRIPT = Transcript()
say = TRANSCRIPT.say

_CHILD = r'''
import json, os, resource, sys, time
wall_start, cpu_start = time.perf_counter(), time.process_time()
from pathlib import Path
from sofia_ros.campaigns.alignment import run_alignment
from sofia_ros.config import load_effect_config
from sofia_ros.sim.calibration import AlignmentPlan
mode, repetitions, seed, bag = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), Path(sys.argv[4])
load_before = os.getloadavg()[0]
truth = load_effect_config(Path(sys.argv[5]) / 'config/truth/nominal.yaml')
run = run_alignment(truth, seed=seed, bag_path=bag, plan=AlignmentPlan(repetitions=repetitions), mode=mode)
children = resource.getrusage(resource.RUSAGE_CHILDREN)
own = resource.getrusage(resource.RUSAGE_SELF)
print(json.dumps({
    'sim_s': run.summary['sim_seconds'], 'wall_s': time.perf_counter() - wall_start,
    'cpu_s': time.process_time() - cpu_start + children.ru_utime + children.ru_stime,
    'peak_mb': max(own.ru_maxrss, children.ru_maxrss) / 1024.0, 'accepted': run.summary['accepted'],
    'bag_mb': sum(path.stat().st_size for path in bag.iterdir()) / 1e6,
    'load': (load_before + os.getloadavg()[0]) / 2.0}))
'''


def run_once(mode, repetitions, seed, folder, name, cold):
    """One campaign in a fresh process; its figures as a dict."""
    if cold:
        for cache in list((ROOT / 'sofia_ros').rglob('__pycache__')):
            shutil.rmtree(cache)
    result = subprocess.run([sys.executable, '-c', _CHILD, mode, str(repetitions), str(seed), str(folder / name),
                             str(ROOT)], capture_output=True, text=True, check=False)
    if result.returncode != 0:
        raise SystemExit(f'{name} failed (exit {result.returncode}):\n{result.stderr[-2000:]}')
    return json.loads(result.stdout.strip().splitlines()[-1])


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repetitions', type=int, default=6,
                        help='LOS/EL/XEL repetitions of the plan (6: the full campaign)')
    parser.add_argument('--modes', nargs='*', default=['direct', 'executor', 'executor-dds', 'processes'],
                        help='executor: messages handed over in the process; executor-dds: every one over DDS')
    parser.add_argument('--seed', type=int, default=1)
    parser.add_argument('--no-cold', action='store_true', help="skip the cold (the checkout's bytecode removed) executor run")
    args = parser.parse_args()
    load_before = current_load()
    # Direct mode first: every later line is a ratio to it; the cold run before the warm ones.
    runs = [(mode, False) for mode in sorted(args.modes, key=lambda mode: mode != 'direct')]
    if not args.no_cold and 'executor' in args.modes:
        runs.insert(runs.index(('executor', False)), ('executor', True))
    say(f'alignment campaign, nominal truth, seed {args.seed}, {args.repetitions} repetitions, bag recorded; '
        f'{os.cpu_count()} CPUs')
    say(f'{"run":<16} {"sim s":>7} {"wall s":>7} {"CPU s":>7} {"load":>5} {"x real":>7} {"x real CPU":>10} '
        f'{"wall/direct":>11} {"CPU/direct":>10} {"peak MB":>8} {"accepted":>8}')
    direct = None
    bags = {}
    rows = []
    with tempfile.TemporaryDirectory(prefix='bench_alignment_') as folder:
        for mode, cold in runs:
            name = f'{mode} (cold)' if cold else mode
            figures = run_once(mode, args.repetitions, args.seed, Path(folder), name.replace(' (cold)', '_cold'), cold)
            direct = figures if mode == 'direct' else direct
            ratios = (f'{figures["wall_s"] / direct["wall_s"]:>11.2f} {figures["cpu_s"] / direct["cpu_s"]:>10.2f}'
                      if direct else f'{"-":>11} {"-":>10}')
            say(f'{name:<16} {figures["sim_s"]:>7.1f} {figures["wall_s"]:>7.1f} {figures["cpu_s"]:>7.1f} '
                f'{figures["load"]:>5.1f} {figures["sim_s"] / figures["wall_s"]:>7.1f} '
                f'{figures["sim_s"] / figures["cpu_s"]:>10.1f} {ratios} {figures["peak_mb"]:>8.0f} '
                f'{str(figures["accepted"]):>8}')
            rows.append({'run': name, **figures,
                         'wall_over_direct': figures['wall_s'] / direct['wall_s'] if direct else None,
                         'cpu_over_direct': figures['cpu_s'] / direct['cpu_s'] if direct else None})
            bags[name] = topic_digests(Path(folder) / name.replace(' (cold)', '_cold'))
        # The modes' bags, topic by topic (type, QoS, count, log times, bytes); /result/stop is the live runs' own.
        differing = sorted({topic for digest in bags.values() for topic in digest if topic != STOP_DOCUMENT.name
                            and len({digest.get(topic) for digest in bags.values()}) > 1})
        say(f'bags of {", ".join(bags)}: ' + (f'differ in {", ".join(differing)}' if differing
                                               else 'identical on every topic'))
    say('wall/direct, CPU/direct: ratio to direct mode in this run (issue 14: executor <= 1.25; executor-dds: the '
        'same graph with every message over DDS, the old path); '
        'load: 1-min load average during the run; x real CPU: sim s per CPU s')
    write_results('alignment', {'arguments': vars(args), 'runs': rows, 'bags_differ_in': differing},
                  TRANSCRIPT.lines, load_before=load_before)


if __name__ == '__main__':
    main()
