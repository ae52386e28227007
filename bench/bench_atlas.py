"""Benchmark: `sofia atlas` throughput on Dask with 1 and 2 workers, and the overhead Dask adds per task.

The same N tasks (the minimal alignment campaign, two candidates, one effect at one size, seeds
1..N) run side by side in one go. Overhead: each task runs in a plain loop in this process
(run_task, as `--serial` does) and, right after it, alone on a one-worker LocalCluster, so the
machine's load hits both alike; printed are the Dask round trip against the loop's time, and the
round trip against the task's own wall time inside the worker (what Dask adds around it: submit,
pickling, scheduling, the result's way back). Throughput: all N tasks through run_distributed on a
LocalCluster of one worker, then of two: tasks per minute and the 2/1 scaling ratio. Wall times on a
shared machine move with its load, so CPU seconds (this process's, the workers' through psutil) and
the load average are printed beside them. Target: overhead <= 5 %. Written: bench/results/atlas.{json,txt}.

Run: .venv/bin/python bench/bench_atlas.py [--tasks N]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from sofia_ros.atlas.engine import dask_client, run_distributed  # noqa: E402
from sofia_ros.atlas.grid import grid_from_lists  # noqa: E402
from sofia_ros.atlas.store import ResultStore  # noqa: E402
from sofia_ros.atlas.task import TaskSetup, run_task  # noqa: E402
from results_file import Transcript, current_load, write_results  # noqa: E402

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
    args = parser.parse_args()
    transcript = Transcript()
    load_before = current_load()
    grid = grid_from_lists(effects=[EFFECT], sizes=[1.0], campaigns=['alignment:minimal'],
                           seeds=list(range(1, args.tasks + 1)), candidates=[EFFECT, 'timestamp_offset'])
    tasks = grid.tasks()
    setup = TaskSetup(grid.truth, grid.model, grid.candidates, None, 'bench')
    transcript.say(f'{len(tasks)} tasks: {EFFECT} x1 in alignment:minimal, seeds 1..{len(tasks)}; '
                   f'{os.cpu_count()} cores')

    import sofia_ros.campaigns.alignment  # noqa: F401  (the loop's imports, as _warm does for the workers)
    import sofia_ros.compare.run  # noqa: F401

    transcript.say(f'load before: {_load()}')
    loop_s, dask_s, inside_s, loop_cpu_s = [], [], [], 0.0
    with dask_client(None, workers=1) as client:
        _warm(client)
        for task in tasks:
            started, cpu_started = time.perf_counter(), time.process_time()
            row = run_task(task, setup)
            loop_s.append(time.perf_counter() - started)
            loop_cpu_s += time.process_time() - cpu_started
            assert row['error'] is None, row['error']
            started = time.perf_counter()
            row = client.submit(run_task, task, setup, pure=False).result()
            dask_s.append(time.perf_counter() - started)
            inside_s.append(row['wall_s'])
            assert row['error'] is None, row['error']
            transcript.say(f'  seed {task.seed}: loop {loop_s[-1]:6.1f} s, dask round trip {dask_s[-1]:6.1f} s '
                           f'({row["wall_s"]:.1f} s inside the worker); load {_load()}')
    transcript.say(f'overhead, paired: dask round trips {sum(dask_s):.1f} s against the loop\'s {sum(loop_s):.1f} s '
                   f'({100 * (sum(dask_s) - sum(loop_s)) / sum(loop_s):+.1f} %, load-dependent); '
                   f'what Dask adds around a task: '
                   f'{sum(dask_s) - sum(inside_s):.2f} s in {len(tasks)} tasks, '
                   f'{100 * (sum(dask_s) - sum(inside_s)) / sum(inside_s):.2f} % of their time (target <= 5 %); '
                   f'loop CPU {loop_cpu_s / len(tasks):.2f} s/task')
    transcript.say(f'plain loop: {60 * len(tasks) / sum(loop_s):5.2f} tasks/min')

    results = {}
    folder = tempfile.TemporaryDirectory(prefix='bench_atlas_')
    for workers in (1, 2):
        started_up = time.perf_counter()
        with dask_client(None, workers=workers) as client:
            _warm(client)
            startup_s = time.perf_counter() - started_up
            store = ResultStore(Path(folder.name) / f'table-{workers}', grid.describe())
            cpu_before = _worker_cpu_s(client)
            started = time.perf_counter()
            run_distributed(tasks, setup, store, client)
            wall_s = time.perf_counter() - started
            cpu_s = _worker_cpu_s(client) - cpu_before
        rows = store.read().to_pylist()
        assert len(rows) == len(tasks) and all(row['error'] is None for row in rows)
        results[workers] = wall_s
        transcript.say(f'dask {workers} worker{"s" if workers > 1 else " "}: {wall_s:7.1f} s wall, {cpu_s:6.1f} s CPU '
                       f'in the workers ({cpu_s / len(tasks):.2f} s/task), {60 * len(tasks) / wall_s:5.2f} tasks/min; '
                       f'cluster start-up {startup_s:.1f} s apart; load {_load()}')
    folder.cleanup()
    transcript.say(f'scaling 2 workers / 1 worker: {results[1] / results[2]:.2f}x (2 cores shared with other jobs: '
                   f'load {_load()})')
    write_results('atlas', {'tasks': len(tasks), 'loop_s': loop_s, 'dask_round_trip_s': dask_s,
                            'inside_worker_s': inside_s, 'loop_cpu_s_per_task': loop_cpu_s / len(tasks),
                            'dask_overhead_fraction': (sum(dask_s) - sum(inside_s)) / sum(inside_s),
                            'wall_s_by_workers': results, 'scaling_2_over_1': results[1] / results[2]},
                  transcript.lines, load_before=load_before)


if __name__ == '__main__':
    main()
