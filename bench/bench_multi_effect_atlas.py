"""Benchmark: the multi-effect atlas of issue 25 — the search on truths with several effects hidden, and controls.

bench/multi_effect_atlas.yaml is the grid (truths of k = 2-3 effects drawn at random from each campaign's visible
catalogue effects, controls with none, each searched from the nominal model); the options override its counts.
The effective grid is written to bench/results/multi_effect_atlas.grid.yaml and run by `sofia atlas --grid` on a
LocalCluster (--workers); the atlas directory (--out) is resumed when run again with the same grid. With
--time-limit-s the atlas is interrupted (SIGINT, its rows kept) after that long and the rows finished are
reported as such. Printed: the success rate per campaign and k, the controls' rate, the pairs most often
confused, and every truth not ended right with its final model. Written: bench/results/multi_effect_atlas.json
(date, commit, workers, load, the grid, rates, confusions, every row) and .txt (what was printed).

Run: .venv/bin/python bench/bench_multi_effect_atlas.py [--campaigns alignment:reduced] [--truths N] [--controls M]
     [--k 2,3] [--rounds R] [--draw-seed S] [--workers W] [--time-limit-s T] [--out DIR] [--keep-bags]
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import os
import signal
import statistics
import subprocess
import sys
import threading
import time
from dataclasses import asdict
from pathlib import Path

import pyarrow.parquet as pq
import yaml

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sofia_ros.atlas.report import miss_line, summarize, truth_lines  # noqa: E402
from results_file import machine_description  # noqa: E402

GRID = ROOT / 'bench' / 'multi_effect_atlas.yaml'
RESULTS = ROOT / 'bench' / 'results'


def _arguments():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--campaigns', help='comma-separated CAMPAIGN:VARIANT (default: the grid file\'s)')
    parser.add_argument('--truths', type=int, help='truths drawn per campaign (default: the grid file\'s)')
    parser.add_argument('--controls', type=int, help='controls per campaign (default: the grid file\'s)')
    parser.add_argument('--k', help='effects per drawn truth, cycled, e.g. 2,3 (default: the grid file\'s)')
    parser.add_argument('--rounds', type=int, help='search rounds per truth (default: the grid file\'s)')
    parser.add_argument('--draw-seed', type=int, help='seed of the draws (default: the grid file\'s)')
    parser.add_argument('--workers', type=int, default=1, help='LocalCluster workers (default 1: a shared machine)')
    parser.add_argument('--time-limit-s', type=float, help='interrupt the atlas after this long and report what ran')
    parser.add_argument('--out', default=str(Path(os.environ.get('TMPDIR', '/tmp')) / 'sofia-bench-multi-effect-atlas'),
                        help='the atlas directory (resumed when the grid is the same)')
    parser.add_argument('--keep-bags', action='store_true',
                        help='keep every bag under OUT/bags, to search them again with later code')
    return parser.parse_args()


def _effective_grid(args) -> dict:
    grid = yaml.safe_load(GRID.read_text())
    if args.campaigns:
        grid['campaigns'] = [part.strip() for part in args.campaigns.split(',') if part.strip()]
    if args.truths is not None:
        grid['draws']['count'] = args.truths
    if args.k:
        grid['draws']['k'] = [int(part) for part in args.k.split(',')]
    if args.draw_seed is not None:
        grid['draws']['seed'] = args.draw_seed
    if args.controls is not None:
        grid['controls'] = args.controls
    if args.rounds is not None:
        grid['search_rounds'] = args.rounds
    return grid


def _run_atlas(grid_path: Path, args) -> tuple[int, list[str]]:
    """`sofia atlas --grid` in its own session; SIGINT after --time-limit-s. Its exit code and output lines."""
    argv = [str(Path(sys.executable).parent / 'sofia'), 'atlas', '--grid', str(grid_path), '--out', args.out,
            '--workers', str(args.workers)] + (['--keep-bags'] if args.keep_bags else [])
    process = subprocess.Popen(argv, cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                               start_new_session=True)
    lines = []

    def read():
        for line in process.stdout:
            lines.append(line.rstrip('\n'))
            print(f'  | {lines[-1]}', flush=True)

    reader = threading.Thread(target=read, daemon=True)
    reader.start()
    try:
        process.wait(timeout=args.time_limit_s)
    except subprocess.TimeoutExpired:
        process.send_signal(signal.SIGINT)  # the atlas keeps its rows and exits 130
        process.wait()
    reader.join(timeout=10)
    return process.returncode, lines


def _commit() -> str:
    return subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=ROOT, capture_output=True,
                          text=True).stdout.strip()


def main():
    args = _arguments()
    grid = _effective_grid(args)
    RESULTS.mkdir(exist_ok=True)
    grid_path = RESULTS / 'multi_effect_atlas.grid.yaml'
    grid_path.write_text('# bench/multi_effect_atlas.yaml with the options of bench/bench_multi_effect_atlas.py\n'
                         + yaml.safe_dump(grid, sort_keys=False))
    load_before = os.getloadavg()
    started = time.time()
    code, output = _run_atlas(grid_path, args)
    wall_s = time.time() - started
    load_after = os.getloadavg()
    if code not in (0, 130):
        sys.exit(f'bench: sofia atlas ended with exit code {code}:\n' + '\n'.join(output[-5:]))
    if not (Path(args.out) / 'table').is_dir():
        sys.exit(f'bench: no task finished before the atlas ended (exit code {code})')
    rows = pq.read_table(Path(args.out) / 'table').to_pylist()
    summary = summarize(rows)
    truth_rows = [row for row in rows if row['truth_effects'] is not None and row['error'] is None]
    failed = [row for row in rows if row['error'] is not None]
    planned = sum(len(grid['campaigns']) * count for count in (grid['draws']['count'], grid['controls']))
    walls = [row['wall_s'] for row in truth_rows if row['k']]
    lines = [f'bench_multi_effect_atlas {dt.datetime.now(dt.timezone.utc):%Y-%m-%d %H:%M} UTC, commit {_commit()}, '
             f'{args.workers} worker(s), load {load_before[0]:.1f} before, {load_after[0]:.1f} after, '
             f'{wall_s / 60:.0f} min',
             f'grid: {grid["campaigns"]}, {grid["draws"]["count"]} truths (k {grid["draws"]["k"]}, draw seed '
             f'{grid["draws"]["seed"]}) and {grid["controls"]} controls per campaign, search {grid["search_rounds"]} '
             f'rounds from the nominal model',
             f'finished: {len(truth_rows)} of {planned} tasks, {len(failed)} failed'
             + (' (interrupted at the time limit)' if code == 130 else '')]
    if walls:
        lines.append(f'task wall time (campaign + search), truths: median {statistics.median(walls):.0f} s, '
                     f'max {max(walls):.0f} s')
    lines += truth_lines(summary, screen=False)
    lines += [f'  failed: {row["key"]}: {row["error"]}' for row in failed]
    text = '\n'.join(lines) + '\n'
    print(text, end='')
    (RESULTS / 'multi_effect_atlas.txt').write_text(text)
    (RESULTS / 'multi_effect_atlas.json').write_text(json.dumps({
        'date': dt.datetime.now(dt.timezone.utc).isoformat(timespec='seconds'), 'commit': _commit(),
        'machine': machine_description(), 'workers': args.workers,
        'load_before': load_before, 'load_after': load_after, 'wall_s': round(wall_s, 1),
        'interrupted': code == 130, 'grid': grid, 'planned_tasks': planned,
        'rates': [asdict(rate) for rate in summary.truth_rates],
        'confused': [asdict(item) for item in summary.truth_confused],
        'not_right': [miss_line(row) for row in summary.truth_misses],
        'rows': sorted(truth_rows + failed, key=lambda row: row['key'])}, indent=1) + '\n')


if __name__ == '__main__':
    main()
