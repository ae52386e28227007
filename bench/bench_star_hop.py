"""Benchmark: the 17-observation star hop of Table D.3 (23:22:16 to 00:57:03 CDT, about 96 min of sky).

Runs the campaign with 60 s holds, nominal truth, bag recorded, every node in one process under
an rclpy executor (messages handed over in the process; executor-dds: every one over DDS), the same
cores in one loop without DDS, and every node in its own process (DDS, as `ros2 run` starts them;
wall time includes their start-up). Printed: sim time, wall time, real-time factor, observations
flown. Targets (issue 6): <= 5 min wall in one process, <= 10 min with one process per node.

Run: .venv/bin/python bench/bench_star_hop.py [executor|executor-dds|direct|processes ...]
"""

from __future__ import annotations

import sys
import tempfile
import time
from pathlib import Path

#: mode -> wall-time target in s (issue 6)
TARGET_WALL_S = {'executor': 300.0, 'processes': 600.0}
ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sofia_ros.campaigns.star_hop import run_star_hop  # noqa: E402
from sofia_ros.config import load_effect_config  # noqa: E402

from results_file import Transcript, current_load, write_results  # noqa: E402

#: Every line printed, for bench/results/star_hop.txt.
TRANSCRIPT = Transcript()
say = TRANSCRIPT.say


def main():
    modes = sys.argv[1:] or ['executor', 'executor-dds', 'direct', 'processes']
    truth = load_effect_config(ROOT / 'config/truth/nominal.yaml')
    load_before = current_load()
    runs = []
    for mode in modes:
        with tempfile.TemporaryDirectory(prefix='bench_star_hop_') as folder:
            started = time.perf_counter()
            summary = run_star_hop(truth, seed=1, bag_path=Path(folder) / 'bag', mode=mode)
            wall_s = time.perf_counter() - started
            size_mb = sum(p.stat().st_size for p in (Path(folder) / 'bag').iterdir()) / 1e6
        say(f'{mode:>12}: {summary["sim_seconds"]:7.1f} s sim in {wall_s:6.1f} s wall '
            f'({summary["sim_seconds"] / wall_s:5.1f}x), {summary["observations"]} observations, '
            f'finished {summary["finished"]}, bag {size_mb:.0f} MB'
            + (f'  (target <= {TARGET_WALL_S[mode]:.0f} s)' if mode in TARGET_WALL_S else ''))
        runs.append({'mode': mode, 'sim_s': summary['sim_seconds'], 'wall_s': wall_s,
                     'real_time_factor': summary['sim_seconds'] / wall_s, 'observations': summary['observations'],
                     'finished': summary['finished'], 'bag_mb': size_mb, 'target_wall_s': TARGET_WALL_S.get(mode)})
    write_results('star_hop', {'runs': runs}, TRANSCRIPT.lines, load_before=load_before)


if __name__ == '__main__':
    main()
