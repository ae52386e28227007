"""Benchmark: `sofia atlas` throughput on Dask with 1 and 2 workers, and the overhead Dask adds per task.

The same N tasks (the minimal alignment campaign, two candidates, one effect at one size, seeds
1..N) run three ways in one go, side by side: a plain loop in this process (run_task, as
`--serial` does), then a LocalCluster of one worker, then of two. Printed: tasks per minute for
each, the 2-worker/1-worker scaling ratio, and the per-task overhead of the 1-worker cluster
against the loop, (T_dask1 - T_loop) / T_loop, with the cluster's start-up counted apart. Wall
times on a shared machine move with its load, so the CPU seconds of every task (the loop's own,
the workers' through psutil) and the load average are printed beside them. Target: overhead <= 5 %.

Run: .venv/bin/python bench/bench_atlas.py [--tasks N]
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sofia_ros.atlas.engine import dask_client, run_distributed  # noqa: E402
from sofia_ros.atlas.grid import grid_from_lists  # noqa: E402
from sofia_ros.atlas.store import ResultStore  # noqa: E402
from sofia_ros.atlas.task import TaskSetup, run_task  # noqa: E402

EFFECT = 'imager_rotation_of_field'


def _load():
    return '/'.join(f'{value:.1f}' for value in os.getloadavg())


def _worker_cpu_s(client):
    """CPU seconds (user + system) of every worker process so far."""
    def cpu():
        import psutil

        times = psutil.Process().cpu_times()
        return times.user + times.system

    return sum(client.run(cpu).values())


def _warm(client):
    """Import what a task imports, on every worker, before the clock starts (start-up is counted apart)."""
    def imports():
        import sofia_ros.campaigns.alignment  # noqa: F401
        import sofia_ros.compare.run  # noqa: F401

    client.run(imports)


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument('--tasks', type=int, default=6, help='tasks per way (default 6)')
    parser.add_argument('--out', default='/tmp', help='folder for the throw-away tables (default /tmp)')
    args = parser.parse_args()
    grid = grid_from_lists(effects=[EFFECT], sizes=[1.0], campaigns=['alignment:minimal'],
                           seeds=list(range(1, args.tasks + 1)), candidates=[EFFECT, 'timestamp_offset'])
    tasks = grid.tasks()
    setup = TaskSetup(grid.truth, grid.model, grid.candidates, None, 'bench')
    print(f'{len(tasks)} tasks: {EFFECT} x1 in alignment:minimal, seeds 1..{len(tasks)}; {os.cpu_count()} cores')

    import sofia_ros.campaigns.alignment  # noqa: F401  (the loop's imports, as _warm does for the workers)
    import sofia_ros.compare.run  # noqa: F401

    print(f'load before: {_load()}')
    started, cpu_started = time.perf_counter(), time.process_time()
    loop_rows = [run_task(task, setup) for task in tasks]
    loop_s, loop_cpu_s = time.perf_counter() - started, time.process_time() - cpu_started
    assert all(row['error'] is None for row in loop_rows), [row['error'] for row in loop_rows]
    print(f'plain loop: {loop_s:7.1f} s wall, {loop_cpu_s:6.1f} s CPU ({loop_cpu_s / len(tasks):.2f} s/task), '
          f'{60 * len(tasks) / loop_s:5.2f} tasks/min; load {_load()}')

    results = {}
    stamp = time.strftime('%Y%m%dT%H%M%S')
    for workers in (1, 2):
        started_up = time.perf_counter()
        with dask_client(None, workers=workers) as client:
            _warm(client)
            startup_s = time.perf_counter() - started_up
            store = ResultStore(Path(args.out) / f'bench-atlas-{stamp}-{workers}', grid.describe())
            cpu_before = _worker_cpu_s(client)
            started = time.perf_counter()
            run_distributed(tasks, setup, store, client)
            wall_s = time.perf_counter() - started
            cpu_s = _worker_cpu_s(client) - cpu_before
        rows = store.read().to_pylist()
        assert len(rows) == len(tasks) and all(row['error'] is None for row in rows)
        results[workers] = wall_s
        print(f'dask {workers} worker{"s" if workers > 1 else " "}: {wall_s:7.1f} s wall, {cpu_s:6.1f} s CPU in the '
              f'workers ({cpu_s / len(tasks):.2f} s/task), {60 * len(tasks) / wall_s:5.2f} tasks/min; cluster start-up '
              f'{startup_s:.1f} s apart; load {_load()}')
    print(f'scaling 2 workers / 1 worker: {results[1] / results[2]:.2f}x')
    print(f'Dask overhead per task, 1 worker against the plain loop: wall {100 * (results[1] - loop_s) / loop_s:+.1f} % '
          f'({(results[1] - loop_s) / len(tasks):+.2f} s/task; target <= 5 %)')


if __name__ == '__main__':
    main()
