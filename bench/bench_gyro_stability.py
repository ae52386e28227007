"""A 4 h TC-1 gyro stability run at 400 Hz, simulated and recorded (issue target: <= 10 min wall).

    .venv/bin/python bench/bench_gyro_stability.py [--hours 4] [--case TC-1]
"""

import argparse
import resource
import shutil
import tempfile
import time
from pathlib import Path

from sofia_ros.campaigns.gyro_stability import run_gyro_stability
from sofia_ros.config import load_effect_config

from results_file import Transcript, current_load, write_results

#: Every line printed, for bench/results/gyro_stability.txt.
TRANSCRIPT = Transcript()
say = TRANSCRIPT.say


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--hours', type=float, default=4.0)
    parser.add_argument('--case', default='TC-1')
    args = parser.parse_args()
    truth = load_effect_config(Path(__file__).resolve().parents[1] / 'config/truth/nominal.yaml')
    folder = Path(tempfile.mkdtemp(prefix='bench_gyro_'))
    load_before = current_load()
    start = time.perf_counter()
    summary = run_gyro_stability(truth, case=args.case, hours=args.hours, seed=1, bag_path=folder / 'bag')
    wall_s = time.perf_counter() - start
    size_mb = sum(path.stat().st_size for path in (folder / 'bag').iterdir()) / 1e6
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0
    say(f'{args.case}, {args.hours:g} h at 400 Hz: {summary["samples_per_axis"]:,} samples per axis, '
        f'simulated and recorded in {wall_s:.1f} s wall ({summary["sim_seconds"] / wall_s:.0f}x real time), '
        f'bag {size_mb:.0f} MB, peak memory {peak_mb:.0f} MB')
    shutil.rmtree(folder)
    write_results('gyro_stability', {
        'case': args.case, 'hours': args.hours, 'samples_per_axis': summary['samples_per_axis'], 'wall_s': wall_s,
        'real_time_factor': summary['sim_seconds'] / wall_s, 'bag_mb': size_mb, 'peak_mb': peak_mb,
    }, TRANSCRIPT.lines, load_before=load_before)


if __name__ == '__main__':
    main()
