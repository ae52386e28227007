"""Benchmark: the multi-effect atlas' kept bags searched again with the code of today, row by row against the grid.

`bench_multi_effect_atlas.py --keep-bags` keeps every truth's bag; the search changes after it, the bags do not.
This script searches each kept bag again (atlas.task.search_truth_bag: the atlas' own search and score, the grid's
model, candidates and rounds) and sets each row beside the grid's stored one: the score, the final model, the
rounds, the equivalents and the competing sets stated, and which of them changed. Rows are appended to
WORK/rows.jsonl as they finish, so a run that is stopped resumes where it stopped. Printed: the success rate per
campaign and k with the controls (atlas.report.truth_lines), every row that changed, and the CPU-s per search.
Written: bench/results/multi_effect_atlas_again_COMMIT.json (date, the commit whose code searched the rows, load,
every row old and new) and .txt.

Run: .venv/bin/python bench/bench_atlas_bags_again.py [--bags DIR] [--rows JSON] [--work DIR] [--limit N]
     [--workers W]
"""

from __future__ import annotations

import argparse
import datetime as dt
import json
import multiprocessing
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sofia_ros.atlas.grid import grid_from_file  # noqa: E402
from sofia_ros.atlas.report import summarize, truth_lines  # noqa: E402
from sofia_ros.atlas.task import TaskSetup, search_truth_bag  # noqa: E402
from results_file import machine_description  # noqa: E402

RESULTS = ROOT / 'bench' / 'results'
GRID = RESULTS / 'multi_effect_atlas.grid.yaml'
STORED_ROWS = RESULTS / 'multi_effect_atlas_fixed_columns.json'
#: what a search states: a row whose fields differ here from the stored row's is listed as changed
STATED_FIELDS = ('score', 'final_added', 'final_removed', 'verdict', 'rounds', 'equivalents', 'competing')


def _arguments():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--bags', default=str(Path(os.environ.get('TMPDIR', '/tmp'))
                                              / 'sofia-bench-multi-effect-atlas' / 'bags'),
                        help='the kept bags (bench_multi_effect_atlas.py --keep-bags --out DIR: DIR/bags)')
    parser.add_argument('--rows', default=str(STORED_ROWS), help='the grid\'s stored rows (a bench result JSON)')
    parser.add_argument('--work', default=str(Path(os.environ.get('TMPDIR', '/tmp')) / 'sofia-bench-atlas-again'),
                        help='where the new rows are appended (resumed when run again)')
    parser.add_argument('--limit', type=int, help='search at most this many bags (in key order)')
    parser.add_argument('--workers', type=int, default=1, help='searches side by side (default 1)')
    return parser.parse_args()


def _commit() -> str:
    return subprocess.run(['git', 'rev-parse', '--short', 'HEAD'], cwd=ROOT, capture_output=True,
                          text=True).stdout.strip()


def _search_again(job):
    """One kept bag searched again: the stored row with the new truth fields, the search's CPU-s and its error."""
    task, setup, bag_path, stored = job
    started = time.process_time()
    row = {**stored, 'run_id': setup.run_id}
    try:
        row.update(search_truth_bag(task, setup, Path(bag_path)), error=None)
    except Exception as err:  # one failed search is a row with its error, as in the atlas
        row['error'] = f'{type(err).__name__}: {err}'.splitlines()[0][:500]
    row['cpu_s'] = time.process_time() - started
    return row


def _jobs(args, stored: dict, done: set[str]) -> list:
    grid = grid_from_file(GRID)
    setup = TaskSetup(grid.truth, grid.model, grid.candidates, None, f'again-{_commit()}')
    jobs = []
    for task in grid.iter_tasks():
        bag_path = Path(args.bags) / task.key.replace('|', '_')
        if task.key in stored and task.key not in done and (bag_path / 'metadata.yaml').is_file():
            jobs.append((task, setup, str(bag_path), stored[task.key]))
    jobs.sort(key=lambda job: job[0].key)
    return jobs[:args.limit] if args.limit is not None else jobs


def _shown(path) -> str:
    """A path inside the repository as it is named there (bench/results/...), any other as given."""
    path = Path(path).resolve()
    return str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else str(path)


def _changes(old: dict, new: dict) -> list[str]:
    return [f'{field} {old[field]!r} -> {new[field]!r}' for field in STATED_FIELDS if old.get(field) != new.get(field)]


def _checked(args):
    """The arguments, or exit with one line naming what is missing and how to make it."""
    if not Path(args.rows).is_file():
        sys.exit(f'bench: no stored rows at {args.rows}; give --rows a bench_multi_effect_atlas.py result JSON')
    if not Path(args.bags).is_dir():
        sys.exit(f'bench: no kept bags at {args.bags}; run bench_multi_effect_atlas.py --keep-bags --out DIR '
                 'and give --bags DIR/bags')
    return args


def main():
    args = _checked(_arguments())
    work = Path(args.work)
    work.mkdir(parents=True, exist_ok=True)
    journal = work / 'rows.jsonl'
    finished = [json.loads(line) for line in journal.read_text().splitlines()] if journal.exists() else []
    stored_document = json.loads(Path(args.rows).read_text())
    stored = {row['key']: row for row in stored_document['rows']}
    jobs = _jobs(args, stored, {row['key'] for row in finished})
    load_before = os.getloadavg()
    started = time.time()
    print(f'searching {len(jobs)} kept bags again ({len(finished)} already in {journal})', flush=True)
    with multiprocessing.get_context('spawn').Pool(args.workers) as pool, journal.open('a') as out:
        for row in pool.imap_unordered(_search_again, jobs):
            finished.append(row)
            out.write(json.dumps(row) + '\n')
            out.flush()
            change = '; '.join(_changes(stored[row['key']], row)) or 'the same'
            print(f'  {row["key"]}: {row["score"]}, {row["cpu_s"]:.0f} CPU-s: {change}', flush=True)
    load_after = os.getloadavg()
    rows = sorted(finished, key=lambda row: row['key'])
    if not rows:
        sys.exit(f'bench: none of the grid\'s bags is under {args.bags}; nothing written')
    summary = summarize([row for row in rows if row['error'] is None])
    changed = [(row, _changes(stored[row['key']], row)) for row in rows]
    changed = [(row, change) for row, change in changed if change]
    cpu = [row['cpu_s'] for row in rows]
    # a resumed journal may hold rows searched by earlier code: the results are named by every commit that searched
    searched_by = '+'.join(sorted({row['run_id'].removeprefix('again-') for row in rows}))
    lines = [f'bench_atlas_bags_again {dt.datetime.now(dt.timezone.utc):%Y-%m-%d %H:%M} UTC, '
             f'searched by commit {searched_by}, '
             f'{args.workers} worker(s), load {load_before[0]:.1f} before, {load_after[0]:.1f} after; '
             f'{len(rows)} kept bags of {_shown(args.rows)} (commit {stored_document["commit"]}) searched again',
             f'search CPU-s: median {statistics.median(cpu):.0f}, max {max(cpu):.0f}, total {sum(cpu) / 60:.0f} min',
             *truth_lines(summary, screen=False),
             f'rows whose stated result changed against the stored grid: {len(changed)} of {len(rows)}',
             *(f'  {row["key"]}: {"; ".join(change)}' for row, change in changed),
             *(f'  failed: {row["key"]}: {row["error"]}' for row in rows if row['error'] is not None)]
    text = '\n'.join(lines) + '\n'
    print(text, end='')
    RESULTS.mkdir(exist_ok=True)
    name = f'multi_effect_atlas_again_{searched_by}'
    (RESULTS / f'{name}.txt').write_text(text)
    (RESULTS / f'{name}.json').write_text(json.dumps({
        'date': dt.datetime.now(dt.timezone.utc).isoformat(timespec='seconds'), 'commit': searched_by,
        'machine': machine_description(), 'workers': args.workers,
        'load_before': load_before, 'load_after': load_after, 'wall_s': round(time.time() - started, 1),
        'stored_rows': _shown(args.rows), 'changed': [row['key'] for row, _ in changed],
        'rows': [{'new': row, 'old': stored[row['key']]} for row in rows]}, indent=1) + '\n')


if __name__ == '__main__':
    main()
