"""Benchmark: the atlas' pull table for every visible catalogue effect, judged (issue 25, "Honest fitted values").

Each grid file (default: DEFAULT_GRIDS, the alignment's: the visible effects of
sofia_ros.atlas.grid.VISIBLE_EFFECTS at 0.5x and 1x their defaults, 5 seeds, and the borderline cells at 10 seeds;
bench/pulls_star_hop_reduced.yaml, 90 star hops, only when given with --grid) is run with
`sofia atlas --grid G --out OUT/<grid> --workers W` (a resumable table: run it again to finish an interrupted grid),
then its rows are read and the atlas' own "Fit bias and scatter against the reported sigma" table
(sofia_ros.atlas.stats.fit_calibration) is printed with a verdict per cell (effect, campaign variant, size,
reference parameter):

- PASS: |mean pull| <= 1 and pull scatter <= 2 (issue 25's must-show);
- FAIL: either bound broken;
- UNCONSTRAINED: no fitted value of the cell has a sigma (null in compare's JSON, inf in memory): compare's own
  statement that the data do not determine the parameter (docs/compare.md, `candidates[].sigma`; printed
  `unconstrained` by `sofia compare`); such a parameter is exempt;
- FEW: fewer than 2 finite pulls (no scatter to judge).

The atlas keeps one parameter per effect (its reference parameter: the first scaling one with a non-zero
default, docs/atlas.md `param`), so "every parameter" is every effect's reference parameter.

Run: .venv/bin/python bench/bench_pulls.py [--grid G.yaml ...] [--out DIR] [--workers 1] [--no-run]
The table is written to bench/results/pulls.{json,txt} (date, commit, workers, load).
"""

from __future__ import annotations

import argparse
import dataclasses
import datetime as dt
import json
import math
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import pyarrow.parquet as pq

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sofia_ros.atlas.grid import grid_from_file  # noqa: E402
from sofia_ros.atlas.stats import Calibration, fit_calibration  # noqa: E402

#: Issue 25's bounds on an honest pull: its mean within 1, its scatter within 2.
MAX_ABS_PULL_MEAN = 1.0
MAX_PULL_SCATTER = 2.0
#: The grids run without --grid: the alignment's (a star hop's grid takes hours: give it with --grid).
DEFAULT_GRIDS = ('pulls_alignment_minimal.yaml', 'pulls_ten_seeds.yaml', 'pulls_gyro_ten_seeds.yaml')
UNCONSTRAINED_SOURCE = ('compare gives no sigma for any fitted value of the cell (null in its JSON, inf in memory; '
                        'docs/compare.md candidates[].sigma: "null for a parameter the data do not determine")')


def _load() -> str:
    return '/'.join(f'{value:.1f}' for value in os.getloadavg())


def _commit() -> str:
    return subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=ROOT, capture_output=True,
                          text=True).stdout.strip()


def run_atlas(grid: Path, out: Path, workers: int) -> float:
    """`sofia atlas --grid` into ``out`` (resumed when it holds part of the table); its wall seconds."""
    started = time.perf_counter()
    subprocess.run([sys.executable, '-m', 'sofia_ros.cli', 'atlas', '--grid', str(grid), '--out', str(out),
                    '--workers', str(workers)], cwd=ROOT, check=True)
    return time.perf_counter() - started


def verdict(cell: Calibration) -> str:
    """PASS, FAIL, UNCONSTRAINED (no sigma at all: compare says the data do not determine it) or FEW."""
    if cell.unconstrained == cell.count:
        return 'UNCONSTRAINED'
    if not math.isfinite(cell.pull_std):
        return 'FEW'
    honest = abs(cell.pull_mean) <= MAX_ABS_PULL_MEAN and cell.pull_std <= MAX_PULL_SCATTER
    return 'PASS' if honest else 'FAIL'


def judged_cells(rows: list[dict]) -> list[dict]:
    """fit_calibration's cells (the atlas' pull table), each with its verdict."""
    return [{**dataclasses.asdict(cell), 'verdict': verdict(cell)} for cell in fit_calibration(rows)]


def missing_cells(rows: list[dict]) -> list[str]:
    """Rows with no fitted value (the hidden effect not among compare's candidates) or an error."""
    return [f'{row["key"]}: {row["error"] or "no fitted value"}' for row in rows
            if row['truth_effects'] is None and row['size'] > 0 and (row['error'] or row['fitted_value'] is None)]


def table_lines(cells: list[dict]) -> list[str]:
    lines = [f'{"effect.param":48s} {"campaign":20s} {"size":>4s} {"n":>2s} {"true":>10s} {"bias":>10s} '
             f'{"scatter":>10s} {"sigma":>10s} {"pull":>16s}  verdict']
    for cell in cells:
        pull = f'{cell["pull_mean"]:+.2f}+-{cell["pull_std"]:.2f}'
        note = f' ({cell["unconstrained"]} without sigma)' if cell['unconstrained'] else ''
        lines.append(f'{cell["effect"] + "." + cell["param"]:48s} {cell["campaign"]:20s} {cell["size"]:4g} '
                     f'{cell["count"]:2d} {cell["true_value"]:10.4g} {cell["bias"]:+10.3g} {cell["scatter"]:10.3g} '
                     f'{cell["median_sigma"]:10.3g} {pull:>16s}  {cell["verdict"]}{note}')
    return lines


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--grid', type=Path, action='append',
                        help=f'grid file (repeatable; default {", ".join(DEFAULT_GRIDS)} in bench/)')
    parser.add_argument('--out', type=Path, default=Path('/tmp/bench_pulls'),
                        help='where the atlas tables go, one folder per grid (default /tmp/bench_pulls)')
    parser.add_argument('--workers', type=int, default=1, help='Dask workers (default 1: a shared machine)')
    parser.add_argument('--no-run', action='store_true', help='judge the tables already in --out')
    parser.add_argument('--note', action='append', default=[], metavar='GRID=TEXT',
                        help='what code ran a grid (e.g. a patch not in the commit), by its file stem; repeatable')
    args = parser.parse_args()
    grids = args.grid or [ROOT / 'bench' / name for name in DEFAULT_GRIDS]
    notes = dict(note.split('=', 1) for note in args.note)
    load_before, started = _load(), dt.datetime.now(dt.timezone.utc)
    report, lines = {'date': started.isoformat(timespec='seconds'), 'commit': _commit(), 'workers': args.workers,
                     'load_before': load_before, 'machine': f'{platform.node()}, {os.cpu_count()} cores',
                     'bounds': {'abs_pull_mean': MAX_ABS_PULL_MEAN, 'pull_scatter': MAX_PULL_SCATTER},
                     'unconstrained_source': UNCONSTRAINED_SOURCE, 'grids': []}, []
    for grid in grids:
        out = args.out / grid.stem
        wall_s = None if args.no_run else run_atlas(grid, out, args.workers)
        rows = pq.read_table(out / 'table').to_pylist()
        tasks = len(grid_from_file(grid).tasks())
        cells = judged_cells(rows)
        note = notes.get(grid.stem, f'commit {report["commit"]}')
        report['grids'].append({'grid': str(grid.relative_to(ROOT) if grid.is_absolute() else grid), 'code': note,
                                'rows': len(rows), 'tasks': tasks, 'wall_s': wall_s, 'cells': cells,
                                'missing': missing_cells(rows)})
        lines += [f'grid {grid.name} ({note}): {len(rows)} of {tasks} tasks'
                  + (f', {wall_s:.0f} s' if wall_s else ''),
                  *table_lines(cells), *(f'  no pull: {text}' for text in missing_cells(rows)), '']
    verdicts = [cell['verdict'] for entry in report['grids'] for cell in entry['cells']]
    report['load_after'] = _load()
    summary = (f'{verdicts.count("PASS")} PASS, {verdicts.count("FAIL")} FAIL, '
               f'{verdicts.count("UNCONSTRAINED")} UNCONSTRAINED, {verdicts.count("FEW")} FEW '
               f'(PASS: |mean pull| <= {MAX_ABS_PULL_MEAN:g} and scatter <= {MAX_PULL_SCATTER:g}; '
               f'UNCONSTRAINED: {UNCONSTRAINED_SOURCE})')
    header = (f'# sofia atlas pull table, {report["date"]}, commit {report["commit"]}, {args.workers} worker(s), '
              f'load {load_before} -> {report["load_after"]}, {report["machine"]}')
    text = '\n'.join([header, '', *lines, summary]) + '\n'
    print(text, end='')
    results = ROOT / 'bench' / 'results'
    results.mkdir(exist_ok=True)
    (results / 'pulls.json').write_text(json.dumps(report, indent=1) + '\n')
    (results / 'pulls.txt').write_text(text)


if __name__ == '__main__':
    main()
