"""Where the atlas' tasks run: a plain loop, a Dask LocalCluster sized to the machine, or an existing scheduler.

Dask distributed is the engine: every task is one ``client.submit(run_task, ...)``, a few per worker
thread at a time (a million futures submitted at once filled the memory before the first ended); the scheduler
moves a dead worker's tasks to the others (its ``allowed-failures``, 3 by default, before it gives a
task up as KilledWorker: such a task gets no row, so the next run of the same grid tries it again).
Rows are stored as their futures finish, whatever the order.
"""

from __future__ import annotations

import logging
import os
import re
import socket
import struct
import sys
import time
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterable, Iterator, TextIO

from sofia_ros import interrupts
from sofia_ros.atlas.grid import AtlasTask
from sofia_ros.atlas.store import ResultStore
from sofia_ros.atlas.task import TaskSetup, run_task
from sofia_ros.errors import ConfigError, SchedulerUnreachableError

__all__ = ['Progress', 'RunCounts', 'SchedulerWatch', 'checked_scheduler_address', 'dask_client', 'probe_scheduler',
           'run_distributed', 'run_serial']

_ADDRESS = re.compile(r'^(tcp|tls)://([^\s/:]{1,253}):(\d{1,5})$')
#: A Dask scheduler greets a new connection with its handshake, a frame of a few hundred bytes
#: announced by two little-endian uint64: the bytes that follow and the number of frames.
_MAX_HANDSHAKE_BYTES = 1 << 20
_MAX_HANDSHAKE_FRAMES = 64
#: Futures in flight per worker thread (and at least this many): each worker has its next task at hand.
_IN_FLIGHT_PER_THREAD = 2
_MIN_IN_FLIGHT = 4
#: Seconds between progress lines while nothing finishes.
_PROGRESS_EVERY_S = 30.0
#: Seconds between looks at the finished futures (a task takes tens of seconds).
_POLL_S = 0.5
#: The longest wait for the scheduler's answer about its workers: a stopped scheduler (SIGSTOP, a frozen host)
#: kept its connection open and the atlas waited for ever, its progress lines stopped too.
SCHEDULER_REPLY_S = 60.0
#: How long the atlas waits with tasks to run and no worker at the scheduler before it gives up.
NO_WORKERS_S = 300.0


@dataclass(frozen=True)
class RunCounts:
    """What one invocation ran: rows stored, of them failed, keys found finished, tasks lost with their workers."""

    done: int
    failed: int
    skipped: int
    lost: int = 0


def checked_scheduler_address(address: str) -> str:
    """``tcp://HOST:PORT`` (or ``tls://``) as given; ConfigError for anything else."""
    match = _ADDRESS.match(address)
    if not match or not 0 < int(match[3]) < 65536:
        raise ConfigError(f'--scheduler {address!r} is not a scheduler address; give tcp://HOST:PORT with a port '
                          'in 1..65535 (dask scheduler prints it, port 8786 by default)')
    return address


def _unreachable(address: str, timeout_s: float, why: str) -> SchedulerUnreachableError:
    return SchedulerUnreachableError(
        f'cannot reach the Dask scheduler at {address} within {timeout_s:g} s ({why}); start it with '
        '`dask scheduler` (and workers with `dask worker`) or leave --scheduler out for a local cluster')


def _not_a_scheduler(address: str, timeout_s: float, what: str) -> SchedulerUnreachableError:
    return SchedulerUnreachableError(
        f'{address} {what} within {timeout_s:g} s: no Dask scheduler answers there (a web server such as the '
        'dashboard on 8787 does not; a busy one may need a longer --connect-timeout-s); give the address '
        '`dask scheduler` prints (port 8786 by default)')


def _receive(connection: socket.socket, count: int, deadline: float) -> bytes:
    data = b''
    while len(data) < count:
        connection.settimeout(max(deadline - time.monotonic(), 0.001))
        chunk = connection.recv(count - len(data))
        if not chunk:
            break
        data += chunk
    return data


def probe_scheduler(address: str, timeout_s: float) -> None:
    """SchedulerUnreachableError unless ``address`` accepts a connection and (tcp://) greets with a Dask handshake,
    all within ``timeout_s``.

    Dask's own timeout does not bound this: a server that accepts and stays silent, or an HTTP server
    (which waits for a request), held the Client past 60 s, and bytes of another protocol read as a
    frame length once asked for 3.07 EiB. Over tls:// the greeting comes after TLS', so only the
    connection is checked here.
    """
    match = _ADDRESS.match(checked_scheduler_address(address))
    deadline = time.monotonic() + timeout_s
    try:
        connection = socket.create_connection((match[2], int(match[3])), timeout=timeout_s)
    except (OSError, UnicodeError) as err:  # refused, timed out (no route), unknown host, a host idna cannot encode
        why = err.strerror if isinstance(err, OSError) and err.strerror else str(err) or type(err).__name__
        raise _unreachable(address, timeout_s, why) from err
    with connection:
        if match[1] != 'tcp':
            return
        try:
            greeting = _receive(connection, 16, deadline)
        except TimeoutError as err:
            raise _not_a_scheduler(address, timeout_s, 'accepted the connection but sent no Dask handshake') from err
        except OSError as err:  # reset
            raise _not_a_scheduler(address, timeout_s, 'closed the connection without a Dask handshake') from err
    if len(greeting) < 16:
        raise _not_a_scheduler(address, timeout_s, 'closed the connection without a Dask handshake')
    length, frames = struct.unpack('<QQ', greeting)
    if not (0 < length <= _MAX_HANDSHAKE_BYTES and 0 < frames <= _MAX_HANDSHAKE_FRAMES):
        raise _not_a_scheduler(address, timeout_s, 'answered with something other than a Dask handshake')


@contextmanager
def dask_client(scheduler: str | None = None, *, workers: int | None = None,
                connect_timeout_s: float = 10.0) -> Iterator[object]:
    """A Client of ``scheduler``, or of a LocalCluster (one single-threaded worker process per core).

    An unreachable scheduler is SchedulerUnreachableError naming the address after ``connect_timeout_s``.
    The cluster this starts is closed on the way out, also on an interrupt.
    """
    from distributed import Client, LocalCluster

    if scheduler is not None:
        probe_scheduler(scheduler, connect_timeout_s)
        try:
            client = Client(scheduler, timeout=f'{connect_timeout_s}s', set_as_default=False)
        except (OSError, TimeoutError) as err:  # it went away between the probe and the Client
            raise _unreachable(scheduler, connect_timeout_s, str(err) or type(err).__name__) from err
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


class _Missing:
    """The tasks whose keys the store lacks, one at a time (a grid is never a list here), counting the others."""

    def __init__(self, tasks: Iterable[AtlasTask], store: ResultStore):
        self._tasks = iter(tasks)
        self._finished = store.finished_keys()
        self.skipped = 0

    def __iter__(self) -> Iterator[AtlasTask]:
        for task in self._tasks:
            if task.key in self._finished:
                self.skipped += 1
            else:
                yield task


def run_serial(tasks: Iterable[AtlasTask], setup: TaskSetup, store: ResultStore,
               progress: Progress | None = None) -> RunCounts:
    """Run the missing tasks one after another in this process (the reference the Dask runs must match)."""
    missing = _Missing(tasks, store)
    done = failed = 0
    try:
        for task in missing:
            row = run_task(task, setup)
            interrupts.raise_if_requested()  # a campaign stopped by a signal is no result
            store.append(row)
            done += 1
            failed += row['error'] is not None
            if progress is not None:
                progress.finished(row, running=int(progress.done + 1 < progress.total))
    finally:
        store.flush()
    return RunCounts(done, failed, missing.skipped)


def run_distributed(tasks: Iterable[AtlasTask], setup: TaskSetup, store: ResultStore, client,
                    progress: Progress | None = None) -> RunCounts:
    """Submit the missing tasks to the cluster, a few per worker thread at a time, and store each row as its
    future finishes."""
    from distributed import as_completed

    missing = _Missing(tasks, store)
    waiting = iter(missing)
    pending: dict = {}  # future -> task
    done = failed = lost = 0
    arrivals = as_completed([], loop=client.loop)
    watch = SchedulerWatch(client)

    def submit_more() -> None:
        """Top the futures in flight up to a few per worker thread (asked each time: workers come and go)."""
        wanted = max(_MIN_IN_FLIGHT, _IN_FLIGHT_PER_THREAD * watch.threads())
        while len(pending) < wanted:
            task = next(waiting, None)
            if task is None:
                return
            future = client.submit(run_task, task, setup, key=f'atlas-{setup.run_id}-{task.key}', pure=False)
            pending[future] = task
            arrivals.add(future)

    try:
        submit_more()
        while pending:
            finished = arrivals.next_batch(block=False) if arrivals.has_ready() else []
            if not finished:
                time.sleep(_POLL_S)
                interrupts.raise_if_requested()
                if progress is not None and progress.due():
                    progress.show(watch.running(pending))
                continue
            for future in finished:
                task = pending.pop(future)
                if future.status == 'finished':
                    row = future.result()
                    store.append(row)
                    done += 1
                    failed += row['error'] is not None
                else:  # KilledWorker: the scheduler gave it up; not stored, so the next run tries it again
                    row = {'error': f'{task.key}: {future.exception()!r}'}
                    lost += 1
                future.release()
                submit_more()
                if progress is not None:
                    progress.finished(row, watch.running(pending))
    finally:
        store.flush()
        if pending and watch.answering:  # a cancel is a question too, with no bound of its own
            client.cancel(list(pending))
    return RunCounts(done, failed, missing.skipped, lost)


class SchedulerWatch:
    """The atlas' questions to the scheduler about its workers, each answered within SCHEDULER_REPLY_S, and how long
    it has had none; SchedulerUnreachableError in one line when it stops answering or stays without workers for
    NO_WORKERS_S. The rows stored so far are kept either way: the same atlas run again resumes."""

    def __init__(self, client) -> None:
        self.client = client
        self.address = getattr(client.scheduler, 'address', 'the scheduler')
        self.without_workers_since: float | None = None
        #: whether the scheduler answered the last question
        self.answering = True

    def _asked(self, method: str) -> dict:
        try:
            return self.client.sync(getattr(self.client.scheduler, method), callback_timeout=SCHEDULER_REPLY_S)
        except (TimeoutError, OSError) as err:  # asyncio's and distributed's timeouts are TimeoutError
            self.answering = False
            raise SchedulerUnreachableError(
                f'the Dask scheduler at {self.address} stopped answering (no reply within {SCHEDULER_REPLY_S:g} s); '
                'the rows stored so far are kept: run the same atlas again to resume') from err

    def _threads_by_worker(self) -> dict:
        threads = self._asked('ncores')
        if sum(threads.values()):
            self.without_workers_since = None
        elif self.without_workers_since is None:
            self.without_workers_since = time.monotonic()
        elif time.monotonic() - self.without_workers_since > NO_WORKERS_S:
            raise SchedulerUnreachableError(
                f'no Dask worker at the scheduler {self.address} for {NO_WORKERS_S:g} s; start one (dask worker '
                f'{self.address}) and run the same atlas again: it resumes')
        return threads

    def threads(self) -> int:
        """The worker threads at the scheduler now."""
        return sum(self._threads_by_worker().values())

    def running(self, pending) -> int:
        """How many of the pending tasks the workers are computing now (at most one per worker thread)."""
        keys = {future.key for future in pending}
        threads = self._threads_by_worker()
        return sum(min(sum(key in keys for key in processing), threads.get(worker, 1))
                   for worker, processing in self._asked('processing').items())
