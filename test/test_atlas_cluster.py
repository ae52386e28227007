"""`sofia atlas` with real campaigns: serial, a LocalCluster, a scheduler with two workers (one killed), and a resume.

One tiny grid (2 effects x 2 sizes x 1 seed, the minimal alignment campaign, two candidates) is run
serially once per module; every other run must give the same rows. Four tasks (each a campaign and a
compare) still give every path: a resume with rows stored and rows missing, and both workers computing
after the first row is stored, so a worker can be killed mid-task. Every cluster and subprocess runs
on 127.0.0.1 with a timeout and is torn down.
"""

import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pyarrow.parquet as pq
import pytest

from sofia_ros.atlas.engine import RunCounts, dask_client, run_distributed
from sofia_ros.atlas.grid import grid_from_lists
from sofia_ros.atlas.store import ResultStore
from sofia_ros.atlas.task import ROW_FIELDS, TaskSetup

EFFECTS = ('timestamp_offset', 'imager_rotation_of_field')
GRID = dict(effects=list(EFFECTS), sizes=[0.5, 2.0], campaigns=['alignment:minimal'], seeds=[1],
            candidates=list(EFFECTS))
#: What a row measures; who ran it and how long it took differ between runs.
MEASURED = [name for name in ROW_FIELDS if name not in ('wall_s', 'run_id')]
DASK = str(Path(sys.executable).parent / 'dask')
REPOSITORY = Path(__file__).resolve().parent.parent


def _flags(grid=GRID):
    return ['--effects', ','.join(grid['effects']), '--sizes', ','.join(f'{s:g}' for s in grid['sizes']),
            '--campaigns', ','.join(grid['campaigns']), '--seeds', ','.join(map(str, grid['seeds'])),
            '--candidates', ','.join(grid['candidates'])]


def _rows_by_key(table_path):
    rows = pq.read_table(table_path).to_pylist()
    keys = [row['key'] for row in rows]
    assert len(keys) == len(set(keys)), 'a task was stored twice'
    return {row['key']: row for row in rows}


def _assert_same_rows(rows, reference):
    assert set(rows) == set(reference)
    for key, row in rows.items():
        for name in MEASURED:
            ours, theirs = row[name], reference[key][name]
            if isinstance(theirs, float):
                assert ours is not None and math.isclose(ours, theirs, rel_tol=1e-9, abs_tol=1e-12), (key, name)
            else:
                assert ours == theirs, (key, name)


class _Process:
    """A subprocess in its own session (so its whole group is signalled), its output collected by a thread."""

    def __init__(self, argv, **kwargs):
        self.lines = []
        self.popen = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                      start_new_session=True, cwd=REPOSITORY, **kwargs)
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self):
        for line in self.popen.stdout:
            self.lines.append(line.rstrip('\n'))

    def wait_for(self, predicate, timeout_s):
        """The first output line for which ``predicate`` holds; fails after ``timeout_s`` or if the process ends."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            for line in list(self.lines):
                if predicate(line):
                    return line
            if self.popen.poll() is not None and not self._reader.is_alive():
                break
            time.sleep(0.2)
        raise AssertionError(f'no such line within {timeout_s} s; output:\n' + '\n'.join(self.lines[-30:]))

    def finish(self, timeout_s):
        code = self.popen.wait(timeout=timeout_s)
        self._reader.join(timeout=5)
        return code

    def kill(self, signum=signal.SIGKILL):
        if self.popen.poll() is None:
            try:
                os.killpg(self.popen.pid, signum)
            except ProcessLookupError:
                pass
            self.popen.wait(timeout=30)


def _progress(line, at_least_done=0, running=None):
    if not line.startswith('atlas: ') or ' done, ' not in line:
        return False
    done = int(line.split()[1].split('/')[0])
    return done >= at_least_done and (running is None or f', {running} running,' in line)


@pytest.fixture(scope='module')
def grid():
    return grid_from_lists(**GRID)


@pytest.fixture(scope='module')
def resumed(tmp_path_factory):
    """The tiny grid run serially by `sofia atlas --serial`, interrupted (SIGINT) after its first row and resumed.

    Its rows are the reference every Dask run must match: (rows before the interrupt, all rows, the
    second run's output).
    """
    out = tmp_path_factory.mktemp('serial') / 'atlas'
    argv = [sys.executable, '-m', 'sofia_ros.cli', 'atlas', '--serial', '--out', str(out), *_flags()]
    first = _Process(argv)
    try:
        first.wait_for(lambda line: _progress(line, at_least_done=1), 400)
        first.popen.send_signal(signal.SIGINT)
        assert first.finish(120) == 130, '\n'.join(first.lines)
    finally:
        first.kill()
    before = _rows_by_key(out / 'table')
    second = _Process(argv)
    try:
        assert second.finish(500) == 0, '\n'.join(second.lines)
    finally:
        second.kill()
    return before, _rows_by_key(out / 'table'), second.lines


@pytest.fixture(scope='module')
def serial_rows(resumed):
    rows = resumed[1]
    assert all(row['error'] is None for row in rows.values()), [row['error'] for row in rows.values()]
    return rows


@pytest.mark.timeout(900)
def test_an_interrupted_atlas_resumes_with_only_the_missing_tasks(resumed):
    before, rows, output = resumed
    assert 1 <= len(before) < 4
    assert f'{len(before)} already in' in output[0] and f'running {4 - len(before)} on serial' in output[0]
    first_run = {row['run_id'] for row in before.values()}
    assert len(first_run) == 1 and len(rows) == 4
    rerun = {key for key, row in rows.items() if row['run_id'] not in first_run}
    assert rerun == set(rows) - set(before)  # only the missing tasks ran ...
    assert all(rows[key]['run_id'] in first_run for key in before)  # ... and no finished one twice


def test_the_serial_rows_measure_what_they_say(serial_rows):
    for row in serial_rows.values():
        assert row['campaign'] == 'alignment' and row['measurements'] == 2  # minimal: 2 repetitions x 1 frame
        assert row['param'] in ('offset_s', 'fpi_deg') and row['true_value'] == row['size'] * {
            'offset_s': 1.0, 'fpi_deg': 0.5}[row['param']]
        assert row['verdict'] in ('explained', 'missing_effect', 'unexplained')
        assert row['rms_over_floor'] > 0 and row['misalignment_los_arcsec'] is not None
    # a rotated FPI field is named and measured back at its hidden size (0.25 and 1 deg)
    for key, row in serial_rows.items():
        if row['effect'] == 'imager_rotation_of_field':
            assert row['detected'] and row['effect_delta_bic'] > 6.0, key
            assert abs(row['fitted_value'] - row['true_value']) < 4 * row['fitted_sigma'], key


@pytest.mark.timeout(600)
def test_a_local_cluster_gives_the_rows_of_the_serial_run(grid, serial_rows, tmp_path):
    # One task per worker, one of each effect: the other two would run the same path again.
    tasks = [task for task in grid.tasks() if task.size == GRID['sizes'][0]]
    assert len(tasks) == 2 and {task.effect for task in tasks} == set(EFFECTS)
    store = ResultStore(tmp_path / 'table', grid.describe())
    with dask_client(None, workers=2) as client:
        counts = run_distributed(tasks, TaskSetup(grid.truth, grid.model, grid.candidates, None, 'local'),
                                 store, client)
    assert counts == RunCounts(2, 0, 0)
    rows = _rows_by_key(tmp_path / 'table')
    assert len(rows) == 2
    _assert_same_rows(rows, {key: serial_rows[key] for key in rows})


@pytest.fixture
def scheduler(tmp_path):
    """A `dask scheduler` on 127.0.0.1 (its own process); its address."""
    scheduler_file = tmp_path / 'scheduler.json'
    process = _Process([DASK, 'scheduler', '--host', '127.0.0.1', '--port', '0', '--no-dashboard',
                        '--scheduler-file', str(scheduler_file)])
    try:
        deadline = time.monotonic() + 60
        while not scheduler_file.exists() and time.monotonic() < deadline:
            assert process.popen.poll() is None, '\n'.join(process.lines)
            time.sleep(0.2)
        yield json.loads(scheduler_file.read_text())['address'], process
    finally:
        process.kill(signal.SIGTERM)


@pytest.mark.timeout(600)
def test_a_scheduler_with_two_workers_one_killed_mid_run_retries_and_completes(scheduler, serial_rows, tmp_path):
    address, scheduler_process = scheduler
    assert address.startswith('tcp://127.0.0.1:')
    workers = [_Process([DASK, 'worker', address, '--nthreads', '1', '--nworkers', '1', '--host', '127.0.0.1',
                         '--no-dashboard', '--death-timeout', '60', '--name', f'worker-{index}'])
               for index in range(2)]
    atlas = None
    try:
        for worker in workers:
            worker.wait_for(lambda line: 'Registered to' in line, 120)
        atlas = _Process([sys.executable, '-m', 'sofia_ros.cli', 'atlas', '--scheduler', address,
                          '--out', str(tmp_path / 'atlas'), *_flags()])
        # both workers computing and a row stored: kill worker 0 and its nanny, mid-task
        atlas.wait_for(lambda line: _progress(line, at_least_done=1, running=2), 300)
        workers[0].kill()
        assert atlas.finish(400) == 0, '\n'.join(atlas.lines)
        # the scheduler saw worker 0 go while both workers were computing ('2 running'): its task ran again elsewhere
        assert any('Remove worker' in line and 'name: worker-0' in line for line in scheduler_process.lines)
        rows = _rows_by_key(tmp_path / 'atlas' / 'table')
        assert all(row['error'] is None for row in rows.values())
        _assert_same_rows(rows, serial_rows)
        assert atlas.lines[0].startswith(f'atlas: 4 tasks (2 effects x 2 sizes x 1 campaigns x 1 seeds), 0 already')
    finally:
        for process in ([atlas] if atlas else []) + workers:
            process.kill()
