"""Independent pieces of one command run side by side in forked worker processes (`sofia compare --jobs`).

A comparison's refits, the judgements of its contenders and the fit from a model's given values
do not depend on each other. Each needs the bag's observations and the predictor's caches (about
700 MB on a star hop), which a forked worker shares with its parent page by page instead of
receiving them pickled: the worker calls the function it was forked with, and only its result
travels back, pickled through a file. It computes with the same code on the same arrays as the
parent would, so the results are those of a serial run (test/test_compare_jobs.py). A result
that refers to objects the worker was forked with (a fit refers to the bag's predictor) names
them in its pickle by reference (``shared``): the parent puts its own back instead of a copy.

Each worker is forked from the thread that asks for it, with no other thread of this module
running: concurrent.futures.ProcessPoolExecutor forks its later workers while its manager thread
runs, which can deadlock a child (cpython issue 90622).
"""

from __future__ import annotations

import ctypes
import os
import pickle
import select
import signal
import tempfile
from collections.abc import Callable, Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any, BinaryIO, Generic, TypeVar

from sofia_ros.errors import ForkedWorkerError
from sofia_ros.held_folders import held_folder, release_folder, remove_abandoned_folders

__all__ = ['ForkedCall', 'forked_map', 'usable_cores']

_T = TypeVar('_T')
_R = TypeVar('_R')


#: glibc's malloc_trim, where the C library has one (not on musl or macOS): see _return_free_heap.
_LIBC = ctypes.CDLL(None)
_MALLOC_TRIM = getattr(_LIBC, 'malloc_trim', None)
if _MALLOC_TRIM is not None:
    _MALLOC_TRIM.argtypes = [ctypes.c_size_t]
#: Linux's prctl (not on macOS): see _end_with_parent.
_PRCTL = getattr(_LIBC, 'prctl', None)
_PR_SET_PDEATHSIG = 1


def _return_free_heap() -> None:
    """Give the heap's free pages back to the system before a fork (glibc's malloc_trim(0)).

    A comparison frees hundreds of MB of columns that the heap keeps: a worker forked over them shares
    them with its parent, and each page it then allocates there is copied first. Returned, the Waco star
    hop's refits held 0.91 GB in parent and workers together, not 1.18 (proportional set sizes).
    """
    if _MALLOC_TRIM is not None:
        _MALLOC_TRIM(0)


def _end_with_parent(parent: int) -> None:
    """In a worker: be killed when the process that forked it ends. Its parent killed outright (SIGKILL, out of
    memory) cannot stop its workers, which then computed on for nothing; a design's flew on and kept its lock."""
    if _PRCTL is not None:
        _PRCTL(_PR_SET_PDEATHSIG, signal.SIGKILL, 0, 0, 0)
    if os.getppid() != parent:  # it ended before the request: nothing would signal
        os._exit(1)


#: The name of the temporary folders the workers' results go through.
_RESULTS_PREFIX = 'sofia-jobs-'


def _results_folder() -> tuple[Path, int]:
    """A held folder for the workers' results in the temporary directory (held_folders), those of a command killed
    outright removed first."""
    parent = Path(tempfile.gettempdir())
    remove_abandoned_folders(parent, f'{_RESULTS_PREFIX}*')
    return held_folder(parent, _RESULTS_PREFIX)


def usable_cores() -> int:
    """The CPU cores this process may run on (its affinity mask), at least 1."""
    return max(len(os.sched_getaffinity(0)), 1)


class _SharedPickler(pickle.Pickler):
    """Pickles the objects of ``shared`` by reference: their id, the same in a forked child as in its parent."""

    def __init__(self, file: BinaryIO, shared: Mapping[int, object]) -> None:
        super().__init__(file, protocol=pickle.HIGHEST_PROTOCOL)
        self.shared = shared

    def persistent_id(self, obj: object) -> int | None:
        return id(obj) if id(obj) in self.shared else None


class _SharedUnpickler(pickle.Unpickler):
    """Reads what _SharedPickler wrote, the parent's own objects in place of the references."""

    def __init__(self, file: BinaryIO, shared: Mapping[int, object]) -> None:
        super().__init__(file)
        self.shared = shared

    def persistent_load(self, pid: Any) -> object:
        return self.shared[pid]


class _Worker:
    """``function()`` in a child forked now; its outcome pickled to ``path``, ``shared`` by reference."""

    def __init__(self, function: Callable[[], Any], path: Path, shared: Mapping[int, object]) -> None:
        self.path = path
        self.shared = shared
        _return_free_heap()
        parent = os.getpid()
        self.pid = os.fork()
        if self.pid == 0:
            self._run_child(function, parent)
        self.pidfd = os.pidfd_open(self.pid)

    def _run_child(self, function: Callable[[], Any], parent: int) -> None:
        written = False
        try:
            _end_with_parent(parent)
            # Ctrl-C reaches the whole process group: the parent stops, the workers just end.
            signal.signal(signal.SIGINT, signal.SIG_DFL)
            try:
                outcome = (True, function())
            except Exception as err:  # noqa: BLE001  (raised again in the parent)
                outcome = (False, err)
            partial = self.path.with_suffix('.partial')
            try:
                with partial.open('wb') as file:
                    _SharedPickler(file, self.shared).dump(outcome)
            except (pickle.PicklingError, TypeError, AttributeError) as err:  # a lock, a local function, ...
                partial.write_bytes(pickle.dumps((False, ForkedWorkerError(
                    f'a --jobs worker could not return its result ({err}); rerun with --jobs 1'))))
            os.replace(partial, self.path)
            written = True
        finally:
            # Never back into the parent's code; 1: nothing written (the parent says so).
            os._exit(0 if written else 1)

    def wait(self) -> Any:
        """The function's value, or its exception raised here."""
        _, status = os.waitpid(self.pid, 0)
        os.close(self.pidfd)
        code = os.waitstatus_to_exitcode(status)
        if code < 0:
            raise ForkedWorkerError(f'a --jobs worker was killed by {signal.Signals(-code).name} before it returned '
                                    f'(out of memory?); rerun with --jobs 1')
        if code != 0 or not self.path.exists():
            raise ForkedWorkerError(f'a --jobs worker could not write its result into {self.path.parent} (a full '
                                    f'disk?); rerun with --jobs 1')
        with self.path.open('rb') as file:
            succeeded, value = _SharedUnpickler(file, self.shared).load()
        self.path.unlink()
        if not succeeded:
            raise value
        return value

    def kill(self) -> None:
        """End the worker at once and reap it."""
        try:
            os.kill(self.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        os.waitpid(self.pid, 0)
        os.close(self.pidfd)


def _by_id(shared: Iterable[object]) -> dict[int, object]:
    return {id(obj): obj for obj in shared}


def forked_map(function: Callable[[_T], _R], items: Sequence[_T], *, jobs: int, shared: Iterable[object] = (),
               done: Callable[[int], None] = lambda count: None, after: Mapping[int, int] | None = None) -> list[_R]:
    """``[function(item) for item in items]``, at most ``jobs`` at a time in forked workers; in this process when
    ``jobs`` is 1 or there is one item. The first exception ``function`` raises, in item order, is raised here
    once every item has run.

    Args:
        function: any callable, a closure too: each worker is forked with it.
        items: what it is called with, one worker each.
        jobs: the most workers at a time.
        shared: objects a result may refer to that the workers were forked with: returned by reference.
        done: called with the number of results in so far, after each one (progress).
        after: {index: earlier index}: an item that starts only once the earlier one has returned (a worker then
            reads what it wrote); one whose earlier item raised is not run, and that error is raised.

    Returns:
        The results in the order of ``items``.

    Raises:
        ForkedWorkerError: a worker died before it returned.
        ValueError: ``after`` names an item that is not earlier.
    """
    after = dict(after or {})
    if any(not 0 <= earlier < index < len(items) for index, earlier in after.items()):
        raise ValueError(f'forked_map: after must map items to earlier ones, got {after}')
    if jobs <= 1 or len(items) <= 1:
        results = []
        for item in items:
            results.append(function(item))
            done(len(results))
        return results
    directory, lock = _results_folder()
    shared_by_id = _by_id(shared)
    running: dict[int, tuple[int, _Worker]] = {}  # pidfd -> (index, worker)
    outcomes: dict[int, tuple[bool, Any]] = {}
    waiting = list(range(len(items)))
    try:
        while len(outcomes) < len(items):
            while len(running) < jobs and (index := _next_ready(waiting, after, outcomes)) is not None:
                waiting.remove(index)
                if index in after and not outcomes[after[index]][0]:
                    outcomes[index] = outcomes[after[index]]
                    done(len(outcomes))
                    continue
                item = items[index]
                worker = _Worker(lambda: function(item), directory / f'{index}.pickle', shared_by_id)
                running[worker.pidfd] = (index, worker)
            if not running:
                continue
            ready, _, _ = select.select(list(running), [], [])
            for pidfd in ready:
                index, worker = running.pop(pidfd)
                try:
                    outcomes[index] = (True, worker.wait())
                except ForkedWorkerError:
                    raise
                except Exception as err:  # noqa: BLE001  (raised in item order below)
                    outcomes[index] = (False, err)
                done(len(outcomes))
    except BaseException:
        # Ctrl-C, or a worker that died: the others are stopped, nothing of theirs is kept.
        for _, worker in running.values():
            worker.kill()
        raise
    finally:
        release_folder(directory, lock)
    for index in range(len(items)):
        succeeded, value = outcomes[index]
        if not succeeded:
            raise value
    return [outcomes[index][1] for index in range(len(items))]


def _next_ready(waiting: Sequence[int], after: Mapping[int, int], outcomes: Mapping[int, Any]) -> int | None:
    """The first waiting item whose earlier item (forked_map's ``after``) has returned, if any."""
    return next((index for index in waiting if index not in after or after[index] in outcomes), None)


class ForkedCall(Generic[_R]):
    """``function()`` started now in a forked worker, or run by :meth:`result` in this process when ``jobs`` is 1.

    The worker ends with the thread that made the call (_end_with_parent: the kernel ties it to the forking thread):
    take the result in the thread that made it.
    """

    def __init__(self, function: Callable[[], _R], *, jobs: int, shared: Iterable[object] = ()) -> None:
        self._function = function
        self._directory = None
        self._worker = None
        if jobs > 1:
            self._directory, self._lock = _results_folder()
            try:
                self._worker = _Worker(function, self._directory / 'result.pickle', _by_id(shared))
            except BaseException:
                release_folder(self._directory, self._lock)
                raise

    def result(self) -> _R:
        """The function's value, or the exception it raised, raised here."""
        if self._worker is None:
            return self._function()
        try:
            return self._worker.wait()
        finally:
            self._worker = None
            release_folder(self._directory, self._lock)

    def cancel(self) -> None:
        """Stop the worker: its result is not wanted (a failure or Ctrl-C while it ran)."""
        if self._worker is not None:
            self._worker.kill()
            self._worker = None
            release_folder(self._directory, self._lock)
