"""Where the atlas' tasks run: a plain loop, a Dask LocalCluster sized to the machine, or an existing scheduler.

Dask distributed is the engine: every task is one ``client.submit(run_task, ...)``; the scheduler
moves a dead worker's tasks to the others (its ``allowed-failures``, 3 by default, before it gives a
task up as KilledWorker: such a task gets no row, so the next run of the same grid tries it again).
Rows are stored as their futures finish, whatever the order.
"""

from __future__ import annotations

import logging
import os
import re
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator, TextIO

from sofia_ros import interrupts
from sofia_ros.atlas.grid import AtlasTask
from sofia_ros.atlas.store import ResultStore
from sofia_ros.atlas.task import TaskSetup, run_task
from sofia_ros.errors import ConfigError, SchedulerUnreachableError

__all__ = ['Progress', 'RunCounts', 'checked_scheduler_address', 'dask_client', 'run_distributed', 'run_serial']

_ADDRESS = re.compile(r'^(tcp|tls)://[^\s/:]+:\d{1,5}$')
#: Seconds between progress lines while nothing finishes.
_PROGRESS_EVERY_S = 30.0
#: Seconds between looks at the finished futures (a task takes tens of seconds).
_POLL_S = 0.5


@dataclass(frozen=True)
class RunCounts:
    """What one invocation ran: rows stored, of them failed, keys found finished, tasks lost with their workers."""

    done: int
    failed: int
    skipped: int
    lost: int = 0


def checked_scheduler_address(address: str) -> str:
    """``tcp://HOST:PORT`` (or ``tls://``) as given; ConfigError for anything else."""
    if not _ADDRESS.match(address):
        raise ConfigError(f'--scheduler {address!r} is not a scheduler address; give tcp://HOST:PORT '
                          '(dask scheduler prints it, port 8786 by default)')
    return address


@contextmanager
def dask_client(scheduler: str | None = None, *, workers: int | None = None,
                connect_timeout_s: float = 10.0) -> Iterator[object]:
    """A Client of ``scheduler``, or of a LocalCluster (one single-threaded worker process per core).

    An unreachable scheduler is SchedulerUnreachableError naming the address after ``connect_timeout_s``.
    The cluster this starts is closed on the way out, also on an interrupt.
    """
    from distributed import Client, LocalCluster

    if scheduler is not None:
        address = checked_scheduler_address(scheduler)
        try:
            client = Client(address, timeout=f'{connect_timeout_s}s', set_as_default=False)
        except (OSError, TimeoutError) as err:
            raise SchedulerUnreachableError(
                f'cannot reach the Dask scheduler at {address} within {connect_timeout_s:g} s; start it with '
                '`dask scheduler` (and workers with `dask worker`) or leave --scheduler out for a local cluster'
            ) from err
        try:
            yield client
        finally:
            client.close()
        return
    # One single-threaded worker per core: a campaign is CPU-bound Python (the GIL) and keeps
    # module state (signal requests) that threads would share.
    cluster = LocalCluster(n_workers=workers or os.cpu_count() or 1, threads_per_worker=1, processes=True,
                           host='127.0.0.1', dashboard_address='127.0.0.1:0', silence_logs=logging.ERROR)
    try:
        client = Client(cluster, set_as_default=False)
        try:
            yield client
        finally:
            client.close()
    finally:
        cluster.close()


def dashboard_address(client) -> str | None:
    """The scheduler's dashboard (HTTP) address, or None when it serves none."""
    if 'dashboard' not in client.scheduler_info().get('services', {}):
        return None
    return client.dashboard_link


class Progress:
    """One line per finished task (and every 30 s): done, failed, running, waiting, ETA, dashboard."""

    def __init__(self, total: int, stream: TextIO | None = None, dashboard: str | None = None):
        self.total = total
        self.stream = stream if stream is not None else sys.stderr
        self.dashboard = dashboard
        self.started = time.monotonic()
        self.done = self.failed = 0
        self._last_line = 0.0

    def finished(self, row: dict, running: int) -> None:
        """Count one stored row and print the line."""
        self.done += 1
        self.failed += row['error'] is not None
        self.show(running)

    def due(self) -> bool:
        """No line for 30 s: time for one."""
        return time.monotonic() - self._last_line >= _PROGRESS_EVERY_S

    def show(self, running: int) -> None:
        """Print the progress line."""
        now = time.monotonic()
        self._last_line = now
        elapsed = now - self.started
        waiting = max(self.total - self.done - running, 0)
        eta = (f'ETA {_clock(elapsed / self.done * (self.total - self.done))}' if self.done else 'ETA unknown')
        where = f'; dashboard {self.dashboard}' if self.dashboard else ''
        self.stream.write(f'atlas: {self.done}/{self.total} done, {self.failed} failed, {running} running, '
                          f'{waiting} waiting; {_clock(elapsed)} elapsed, {eta}{where}\n')
        self.stream.flush()


def _clock(seconds: float) -> str:
    seconds = int(round(seconds))
    return f'{seconds // 3600}:{seconds // 60 % 60:02d}:{seconds % 60:02d}'


def _missing(tasks: list[AtlasTask], store: ResultStore) -> list[AtlasTask]:
    finished = store.finished_keys()
    return [task for task in tasks if task.key not in finished]


def run_serial(tasks: list[AtlasTask], setup: TaskSetup, store: ResultStore, progress: Progress | None = None) -> RunCounts:
    """Run the missing tasks one after another in this process (the reference the Dask runs must match)."""
    todo = _missing(tasks, store)
    failed = 0
    try:
        for index, task in enumerate(todo):
            row = run_task(task, setup)
            interrupts.raise_if_requested()  # a campaign stopped by a signal is no result
            store.append(row)
            failed += row['error'] is not None
            if progress is not None:
                progress.finished(row, running=int(index + 1 < len(todo)))
    finally:
        store.flush()
    return RunCounts(len(todo), failed, len(tasks) - len(todo))


def run_distributed(tasks: list[AtlasTask], setup: TaskSetup, store: ResultStore, client,
                    progress: Progress | None = None) -> RunCounts:
    """Submit the missing tasks to the cluster and store each row as its future finishes."""
    from distributed import as_completed

    todo = _missing(tasks, store)
    futures = {client.submit(run_task, task, setup, key=f'atlas-{setup.run_id}-{task.key}', pure=False): task
               for task in todo}
    pending, failed, lost = set(futures), 0, 0
    arrivals = as_completed(futures, loop=client.loop)
    try:
        while pending:
            finished = arrivals.next_batch(block=False) if arrivals.has_ready() else []
            if not finished:
                time.sleep(_POLL_S)
                interrupts.raise_if_requested()
                if progress is not None and progress.due():
                    progress.show(_running(client, pending))
                continue
            for future in finished:
                pending.discard(future)
                if future.status == 'finished':
                    row = future.result()
                    store.append(row)
                    failed += row['error'] is not None
                else:  # KilledWorker: the scheduler gave it up; not stored, so the next run tries it again
                    row = {'error': f'{futures[future].key}: {future.exception()!r}'}
                    lost += 1
                future.release()
                if progress is not None:
                    progress.finished(row, _running(client, pending))
    finally:
        store.flush()
        if pending:
            client.cancel(list(pending))
    return RunCounts(len(todo) - lost, failed, len(tasks) - len(todo), lost)


def _running(client, pending) -> int:
    """How many of the pending tasks the workers are computing now (at most one per worker thread)."""
    keys = {future.key for future in pending}
    threads = client.nthreads()
    return sum(min(sum(key in keys for key in processing), threads.get(worker, 1))
               for worker, processing in client.processing().items())
