"""`sofia compare --jobs`: independent fits in forked workers, the same answers as one process (issue 27)."""

from __future__ import annotations

import os
import signal
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest

from sofia_ros.compare.run import compare_bag
from sofia_ros.config import parse_effect_config
from sofia_ros.errors import ForkedWorkerError
from sofia_ros.forked import ForkedCall, forked_map

ROOT = Path(__file__).resolve().parents[1]


def test_results_come_back_in_item_order_from_other_processes_and_leave_no_file(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, 'tempdir', str(tmp_path))
    results = forked_map(lambda n: (n * n, os.getpid()), list(range(5)), jobs=2)
    assert [square for square, _ in results] == [0, 1, 4, 9, 16]
    assert os.getpid() not in {pid for _, pid in results} and len({pid for _, pid in results}) == 5
    assert not list(tmp_path.iterdir())


def test_one_job_runs_in_this_process():
    assert forked_map(lambda n: os.getpid(), [1, 2, 3], jobs=1) == [os.getpid()] * 3


def test_the_first_error_in_item_order_is_raised_here():
    def fail_on_odd(n):
        if n % 2:
            raise ValueError(f'item {n} is odd')
        return n

    with pytest.raises(ValueError, match='item 1 is odd'):
        forked_map(fail_on_odd, [0, 1, 2, 3], jobs=2)


def test_an_item_after_another_starts_once_that_one_has_returned(tmp_path):
    """Item 2 reads what item 0 wrote; item 1 runs beside item 0 meanwhile (design's library flights: the steps'
    flights after the probe of the campaign's end, beside the first flight)."""
    def work(n):
        started = time.monotonic()
        if n == 0:
            time.sleep(0.5)
            (tmp_path / 'zero').write_text('written by item 0')
        return started, time.monotonic(), (tmp_path / 'zero').read_text() if n == 2 else None

    (zero_start, zero_end, _), (one_start, _, _), (two_start, _, read) = forked_map(work, [0, 1, 2], jobs=2,
                                                                                     after={2: 0})
    assert read == 'written by item 0' and two_start >= zero_end
    assert one_start < zero_end  # not held back: it waits for nothing
    assert forked_map(work, [0, 1, 2], jobs=1, after={2: 0})[2][2] == 'written by item 0'


def test_an_item_waiting_for_another_does_not_hold_back_a_later_one():
    def work(n):
        started = time.monotonic()
        time.sleep(0.5 if n == 0 else 0.0)
        return started, time.monotonic()

    (_, zero_end), (one_start, _), (two_start, _), _ = forked_map(work, [0, 1, 2, 3], jobs=2, after={1: 0})
    assert two_start < zero_end <= one_start


def test_an_item_after_one_that_failed_is_not_run_and_that_error_is_raised(tmp_path):
    def work(n):
        (tmp_path / str(n)).touch()
        if n == 0:
            raise ValueError('item 0 failed')
        return n

    with pytest.raises(ValueError, match='item 0 failed'):
        forked_map(work, [0, 1, 2], jobs=2, after={2: 0})
    assert sorted(path.name for path in tmp_path.iterdir()) == ['0', '1']


@pytest.mark.parametrize('after', [{1: 1}, {0: 1}, {1: 3}, {3: 0}])
def test_an_item_after_no_earlier_item_is_refused(after):
    with pytest.raises(ValueError, match='after must map items to earlier ones'):
        forked_map(lambda n: n, [0, 1, 2], jobs=2, after=after)


def _running(pid):
    """Whether process ``pid`` runs (a zombie that no one has reaped yet has ended)."""
    try:
        return Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0] != 'Z'
    except FileNotFoundError:
        return False


@pytest.mark.timeout(120)
def test_the_workers_of_a_process_killed_outright_end_with_it(tmp_path, monkeypatch):
    """SIGKILL (or the kernel out of memory) gives the parent no time to stop its workers: they end with it, and the
    next command's workers remove the folder their results would have gone through."""
    import subprocess
    import sys

    jobs = tmp_path / 'tmp'
    jobs.mkdir()
    monkeypatch.setattr(tempfile, 'tempdir', str(jobs))

    script = (f'import os, time\n'
              f'from sofia_ros.forked import forked_map\n'
              f'def work(n):\n'
              f'    path = os.path.join({str(tmp_path)!r}, f"worker{{n}}")\n'
              f'    with open(path + ".new", "w") as file:\n'
              f'        file.write(str(os.getpid()))\n'
              f'    os.replace(path + ".new", path)\n'
              f'    time.sleep(60)\n'
              f'forked_map(work, [0, 1], jobs=2)\n')
    parent = subprocess.Popen([sys.executable, '-c', script], env={**os.environ, 'TMPDIR': str(jobs)})
    try:
        deadline = time.monotonic() + 60.0
        while len(list(tmp_path.glob('worker?'))) < 2:
            assert parent.poll() is None and time.monotonic() < deadline
            time.sleep(0.05)
        workers = [int(path.read_text()) for path in tmp_path.glob('worker?')]
        assert all(_running(pid) for pid in workers)
    finally:
        parent.kill()
        parent.wait()
    deadline = time.monotonic() + 10.0
    while any(_running(pid) for pid in workers):
        assert time.monotonic() < deadline, 'a worker outlived its parent'
        time.sleep(0.05)
    assert [path.name[:len('sofia-jobs-')] for path in jobs.iterdir()] == ['sofia-jobs-']
    assert forked_map(lambda n: n, [0, 1], jobs=2) == [0, 1]
    assert not list(jobs.iterdir())


def test_a_worker_that_is_killed_is_one_clear_error():
    def die(n):
        os.kill(os.getpid(), signal.SIGKILL)

    with pytest.raises(ForkedWorkerError, match=r'a --jobs worker was killed by SIGKILL .*rerun with --jobs 1'):
        forked_map(die, [0, 1], jobs=2)


def test_a_result_that_does_not_pickle_is_one_clear_error():
    with pytest.raises(ForkedWorkerError, match=r'could not return its result .*rerun with --jobs 1'):
        forked_map(lambda n: (lambda: n), [0, 1], jobs=2)


def test_a_worker_that_cannot_write_its_result_is_one_clear_error(tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, 'tempdir', str(tmp_path))

    def fill_the_disk(n):
        # The result's file cannot be written, as on a full disk (a directory in its place: root ignores modes).
        for folder in tmp_path.glob('sofia-jobs-*'):
            (folder / f'{n}.partial').mkdir(exist_ok=True)
        return n

    with pytest.raises(ForkedWorkerError, match=r'could not write its result into .*\(a full disk\?\); rerun with '
                                                r'--jobs 1'):
        forked_map(fill_the_disk, [0, 1], jobs=2)


def test_shared_objects_come_back_as_the_parents_own_not_copies():
    table = np.arange(1_000_000.0)
    results = forked_map(lambda n: {'n': n, 'table': table}, [0, 1], jobs=2, shared=[table])
    assert all(result['table'] is table for result in results)


def _children():
    return Path(f'/proc/{os.getpid()}/task/{os.getpid()}/children').read_text().split()


def test_an_interruption_stops_every_worker_and_leaves_no_process():
    def interrupt(count):
        raise KeyboardInterrupt

    before = _children()
    started = time.monotonic()
    with pytest.raises(KeyboardInterrupt):
        # The first item returns at once; Ctrl-C then (here raised by the progress callback) stops the two asleep.
        forked_map(lambda n: time.sleep(30.0 * n), [0, 1, 2], jobs=3, done=interrupt)
    assert time.monotonic() - started < 20.0
    assert _children() == before


def test_a_forked_call_runs_beside_this_process_and_can_be_cancelled():
    call = ForkedCall(lambda: os.getpid(), jobs=2)
    assert call.result() != os.getpid()
    assert ForkedCall(lambda: os.getpid(), jobs=1).result() == os.getpid()
    sleeper = ForkedCall(lambda: time.sleep(30.0), jobs=2)
    started = time.monotonic()
    sleeper.cancel()
    assert time.monotonic() - started < 5.0


def _without_timings(document):
    if isinstance(document, dict):
        return {key: _without_timings(value) for key, value in document.items() if key != 'seconds'}
    if isinstance(document, list):
        return [_without_timings(value) for value in document]
    return document


@pytest.mark.timeout(300)
def test_a_comparison_with_two_jobs_is_the_comparison_with_one(campaign_bags):
    # A hidden scale factor: refits, contenders judged again and checked changes; a timestamp offset the model gives
    # a value of its own: the fit from the given values runs beside the ledger's chain.
    bag = campaign_bags.reduced_alignment(effect='gyro_scale_factor')
    given = '  timestamp_offset: {offset_s: 0.002, fit: true}\n'
    text = (ROOT / 'config' / 'model' / 'nominal.yaml').read_text() + given
    model = parse_effect_config(text, 'model')
    serial = compare_bag(bag, model, jobs=1)
    forked = compare_bag(bag, model, jobs=2)
    assert any(entry.get('refined') for entry in serial.document['candidates'])
    assert _without_timings(forked.document) == _without_timings(serial.document)
    assert forked.best_name == serial.best_name
    assert forked.best_fit is None or forked.best_fit.jacobian_point.predictor is forked.predictor


@pytest.mark.parametrize('jobs', ['0', '65', 'two'])
def test_a_jobs_count_out_of_range_is_one_line_and_exit_2(jobs, tmp_path, capsys):
    from sofia_ros.cli import main

    code = main(['compare', str(tmp_path), '--model', str(ROOT / 'config' / 'model' / 'nominal.yaml'), '--jobs', jobs])
    err = capsys.readouterr().err
    assert code == 2
    assert err.count('\n') == 1 and 'argument --jobs:' in err and '(worker processes)' in err
