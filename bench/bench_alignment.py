"""Real-time factor of the alignment campaign at one elevation, bag recorded (issue: >= 30x in one
process, >= 10x with every node in its own process), with peak memory, side by side in one run.

    .venv/bin/python bench/bench_alignment.py [--repetitions 6] [--modes direct executor processes]

Each mode runs the same truth (config/truth/nominal.yaml), seed and plan; wall time is measured
around the whole run (start-up included), peak memory is the largest resident set of this
process or of any node process.
"""

import argparse
import resource
import shutil
import tempfile
import time
from pathlib import Path

from sofia_ros.campaigns.alignment import run_alignment
from sofia_ros.config import load_effect_config
from sofia_ros.sim.calibration import AlignmentPlan


def peak_rss_mb():
    """Largest resident set (MB) of this process and of any finished child process."""
    own = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    children = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss
    return max(own, children) / 1024.0


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--repetitions', type=int, default=6)
    parser.add_argument('--modes', nargs='*', default=['direct', 'executor', 'processes'])
    parser.add_argument('--seed', type=int, default=1)
    args = parser.parse_args()
    truth = load_effect_config(Path(__file__).resolve().parents[1] / 'config/truth/nominal.yaml')
    plan = AlignmentPlan(repetitions=args.repetitions)
    folder = Path(tempfile.mkdtemp(prefix='bench_alignment_'))
    print(f'alignment campaign, nominal truth, seed {args.seed}, {args.repetitions} repetitions, bag recorded')
    print(f'{"mode":<10} {"sim s":>8} {"wall s":>8} {"x real time":>12} {"peak MB":>8} {"accepted":>9} {"bag MB":>7}')
    for mode in args.modes:
        start = time.perf_counter()
        run = run_alignment(truth, seed=args.seed, bag_path=folder / mode, plan=plan, mode=mode)
        wall_s = time.perf_counter() - start
        sim_s = run.summary['sim_seconds']
        bag_mb = sum(path.stat().st_size for path in (folder / mode).iterdir()) / 1e6
        print(f'{mode:<10} {sim_s:>8.1f} {wall_s:>8.1f} {sim_s / wall_s:>12.1f} {peak_rss_mb():>8.0f} '
              f'{str(run.summary["accepted"]):>9} {bag_mb:>7.1f}', flush=True)
    shutil.rmtree(folder)


if __name__ == '__main__':
    main()
