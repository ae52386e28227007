"""`sofia atlas` refusals: parts of another grid or damaged, grids too large to expand, addresses that are no
Dask scheduler, and Ctrl-C; each one line on stderr, exit 2 (130 for Ctrl-C), nothing left behind.

Every server here listens on 127.0.0.1 only. The tables are written by ResultStore from made-up rows; only
the local-cluster interrupt runs (part of) a real campaign.
"""

import http.server
import os
import shutil
import signal
import socket
import tempfile
import threading
import time
from contextlib import contextmanager
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest

from sofia_ros import interrupts
from sofia_ros.atlas import engine
from sofia_ros.atlas.engine import RunCounts, run_distributed
from sofia_ros.atlas.grid import FORCED_MAX_TASKS, grid_from_lists, seeds_of_text
from sofia_ros.atlas.store import ROW_SCHEMA, ResultStore
from sofia_ros.atlas.task import ROW_FIELDS, TaskSetup
from sofia_ros.campaigns.recording import finish_run
from sofia_ros.cli import main
from sofia_ros.errors import ConfigError

GRID = dict(effects=['timestamp_offset'], sizes=[1.0], campaigns=['alignment:minimal'], seeds=[1, 2])
FLAGS = ['--effects', 'timestamp_offset', '--sizes', '1', '--campaigns', 'alignment:minimal', '--seeds', '1,2']


def _row(task, **fields):
    row = {name: None for name in ROW_FIELDS}
    row.update(key=task.key, effect=task.effect, size=task.size, campaign=task.campaign, variant=task.variant,
               seed=task.seed, detected=True, top_candidate=task.effect, top_delta_bic=40.0, verdict='explained')
    row.update(fields)
    return row


def _stored(table, grid_lists=GRID, **fields):
    """A table of ``grid_lists`` with one made-up row per task, one part file per row; the grid."""
    grid = grid_from_lists(**grid_lists)
    store = ResultStore(table, grid.describe(), flush_s=3600.0)
    for task in grid.tasks():
        store.append(_row(task, **fields))
        store.flush()
    return grid


def _parts(table):
    return sorted(Path(table).glob('part-*.parquet'))


def _snapshot(root):
    """Every file below ``root`` with its bytes: what a refused command must leave as it was."""
    root = Path(root)
    if not root.exists():
        return None
    return {str(path.relative_to(root)): (path.read_bytes() if path.is_file() else None)
            for path in sorted(root.rglob('*'))}


def _refused(argv, capsys, code=2):
    """Run `sofia atlas ARGV`; assert the exit code and one `sofia: error:` line (`sofia: interrupted` for 130)."""
    got = main(['atlas', *argv])
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert 'Traceback' not in captured.err, captured.err
    start = 'sofia: error: ' if code == 2 else 'sofia: interrupted by '
    assert got == code and len(lines) == 1 and lines[0].startswith(start), (got, captured.err)
    return lines[0]


# --- 1. a part of another grid is refused, not merged --------------------------------------------------------

def test_a_part_copied_from_another_run_is_refused_not_merged(tmp_path, capsys):
    table = tmp_path / 'atlas' / 'table'
    _stored(table)
    _stored(tmp_path / 'other' / 'table', {**GRID, 'seeds': [3]})
    (foreign,) = _parts(tmp_path / 'other' / 'table')
    shutil.copy(foreign, table / foreign.name)
    before = _snapshot(tmp_path / 'atlas')
    # was: 3 rows and "2/2 detected" at exit 0 for a grid of 2 tasks
    line = _refused(['--out', str(tmp_path / 'atlas'), *FLAGS, '--serial'], capsys)
    assert f'{table / foreign.name} holds rows of grid ' in line and f'move it out of {table}' in line
    assert _snapshot(tmp_path / 'atlas') == before
    # moved out, the table is the grid's own two rows again
    (table / foreign.name).unlink()
    assert len(ResultStore(table, grid_from_lists(**GRID).describe()).read()) == 2


def test_a_part_without_a_grid_fingerprint_is_refused(tmp_path):
    table = tmp_path / 'table'
    grid = _stored(table)
    pq.write_table(pa.Table.from_pylist([_row(grid.tasks()[0])], schema=ROW_SCHEMA), table / 'part-plain.parquet')
    with pytest.raises(ConfigError, match=r'part-plain.parquet holds rows of no atlas grid'):
        ResultStore(table, grid.describe())


# --- 2. sizes are checked before anything is expanded ------------------------------------------------------

def test_huge_seed_counts_are_refused_before_they_are_expanded(tmp_path, capsys):
    started = time.monotonic()
    for seeds in ('99999999999999', '1-99999999999', '9' * 5000):
        line = _refused(['--out', str(tmp_path / 'atlas'), '--campaigns', 'alignment:minimal', f'--seeds={seeds}'],
                        capsys)
        assert 'is beyond the largest seed 4294967295' in line
    assert time.monotonic() - started < 30.0  # was: the list expanded until the memory ran out
    grid_file = tmp_path / 'grid.yaml'
    grid_file.write_text('effects: [timestamp_offset]\nsizes: [1]\ncampaigns: [alignment:minimal]\n'
                         'seeds: 100000000000\n')
    assert 'is beyond the largest seed' in _refused(['--out', str(tmp_path / 'atlas'), '--grid', str(grid_file)],
                                                    capsys)
    assert not (tmp_path / 'atlas').exists()


def test_more_than_10000_tasks_need_force(tmp_path, capsys):
    argv = ['--out', str(tmp_path / 'atlas'), '--effects', 'timestamp_offset', '--sizes', '1',
            '--campaigns', 'alignment:minimal', '--seeds', '20000']
    line = _refused(argv, capsys)
    assert '20000 seeds are more than the 10000 tasks an atlas may have (--force allows up to 1000000)' in line
    with _listening() as port:  # --force passes the grid; the run stops at the address that is no scheduler
        line = _refused([*argv, '--force', '--scheduler', f'tcp://127.0.0.1:{port}', '--connect-timeout-s', '0.5'],
                        capsys)
    assert 'no Dask scheduler answers there' in line
    assert len(seeds_of_text(str(FORCED_MAX_TASKS), '--seeds', FORCED_MAX_TASKS)) == FORCED_MAX_TASKS
    with pytest.raises(ConfigError, match=r'more than the 1000000 .* even with --force'):
        seeds_of_text(f'1-{FORCED_MAX_TASKS + 1}', '--seeds', FORCED_MAX_TASKS)
    assert not (tmp_path / 'atlas').exists()


def _stand_in_task(task, setup):
    """What run_task returns, at once."""
    row = {name: None for name in ROW_FIELDS}
    row.update(key=task.key, effect=task.effect, size=task.size, campaign=task.campaign, variant=task.variant,
               seed=task.seed, run_id=setup.run_id, wall_s=0.0)
    return row


class _CountingStore(ResultStore):
    """Notes, at each stored row, how many tasks the engine had taken from the grid by then."""

    def __init__(self, *args, taken, **kwargs):
        super().__init__(*args, **kwargs)
        self.taken, self.taken_at_row = taken, []

    def append(self, row):
        self.taken_at_row.append(len(self.taken))
        return super().append(row)


@pytest.mark.timeout(120)
def test_tasks_go_to_the_cluster_a_few_at_a_time(tmp_path, monkeypatch):
    from distributed import Client, LocalCluster

    grid = grid_from_lists(**{**GRID, 'seeds': list(range(1, 31))})
    taken = []

    def tasks():
        for task in grid.iter_tasks():
            taken.append(task)
            yield task

    store = _CountingStore(tmp_path / 'table', grid.describe(), taken=taken)
    monkeypatch.setattr(engine, 'run_task', _stand_in_task)
    with LocalCluster(n_workers=1, threads_per_worker=1, processes=False, dashboard_address=None) as cluster, \
            Client(cluster, set_as_default=False) as client:
        counts = run_distributed(tasks(), TaskSetup(grid.truth, grid.model, None, None, 'batches'), store, client)
    assert counts == RunCounts(30, 0, 0)
    # one worker thread: at most 4 futures in flight (was: all 30 submitted before the first row)
    assert all(count <= stored + 4 for stored, count in enumerate(store.taken_at_row)), store.taken_at_row
    assert len(store.read()) == 30


# --- 3. an address that is no scheduler: one line within the timeout ---------------------------------------

@contextmanager
def _listening(reply=None, close=False):
    """A TCP server on 127.0.0.1: accepts and stays silent, sends ``reply`` at once, or closes; its port."""
    server = socket.socket()
    server.bind(('127.0.0.1', 0))
    server.listen(16)
    server.settimeout(0.2)
    held, stop = [], threading.Event()

    def serve():
        while not stop.is_set():
            try:
                connection, _ = server.accept()
            except OSError:
                continue
            if reply:
                connection.sendall(reply)
            if close:
                connection.close()
            else:
                held.append(connection)

    thread = threading.Thread(target=serve, daemon=True)
    thread.start()
    try:
        yield server.getsockname()[1]
    finally:
        stop.set()
        thread.join(timeout=5)
        for connection in held:
            connection.close()
        server.close()


@contextmanager
def _http_server():
    """A tiny HTTP server on 127.0.0.1 (it answers requests, as the dashboard does); its port."""
    server = http.server.ThreadingHTTPServer(('127.0.0.1', 0), http.server.BaseHTTPRequestHandler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        yield server.server_address[1]
    finally:
        server.shutdown()
        server.server_close()
        thread.join(timeout=5)


@pytest.mark.timeout(60)
@pytest.mark.parametrize('server', ['silent', 'http'])
def test_a_server_that_is_no_scheduler_is_one_line_within_the_timeout(tmp_path, capsys, server):
    started = time.monotonic()
    with (_listening() if server == 'silent' else _http_server()) as port:
        line = _refused(['--out', str(tmp_path / 'atlas'), *FLAGS, '--scheduler', f'tcp://127.0.0.1:{port}',
                         '--connect-timeout-s', '1'], capsys)
    # was: a TimeoutError traceback, or no end past 60 s
    assert time.monotonic() - started < 20.0
    assert f'tcp://127.0.0.1:{port} accepted the connection but sent no Dask handshake within 1 s' in line
    assert not (tmp_path / 'atlas').exists()


# --- 4. a damaged part: one line naming it and the fix -----------------------------------------------------

def _flip_a_bit(part, column):
    """Flip a bit in the last byte of ``column``'s data (its page checksum covers it; the old parts had none)."""
    chunk = pq.read_metadata(part).row_group(0).column(ROW_SCHEMA.get_field_index(column))
    at = (chunk.dictionary_page_offset or chunk.data_page_offset) + chunk.total_compressed_size - 1
    data = part.read_bytes()
    part.write_bytes(data[:at] + bytes([data[at] ^ 0x04]) + data[at + 1:])


def _damage(part, how):
    data = part.read_bytes()
    if how == 'zero bytes':
        part.write_bytes(b'')
    elif how == 'truncated':
        part.write_bytes(data[:len(data) // 2])
    else:
        _flip_a_bit(part, 'seed')  # was: read as another seed, at exit 0


@pytest.mark.parametrize('how', ['zero bytes', 'truncated', 'bit flipped'])
def test_a_damaged_part_is_one_line_and_deleting_it_reruns_its_tasks(tmp_path, capsys, how):
    table = tmp_path / 'atlas' / 'table'
    grid = _stored(table)
    intact, damaged = _parts(table)
    kept = set(pq.read_table(intact).column('key').to_pylist())
    _damage(damaged, how)
    before = _snapshot(tmp_path / 'atlas')
    line = _refused(['--out', str(tmp_path / 'atlas'), *FLAGS, '--serial'], capsys)
    assert f'{damaged} is damaged' in line and 'delete it and run the same command again' in line
    assert _snapshot(tmp_path / 'atlas') == before
    damaged.unlink()  # the fix the line gives: the resumed atlas lacks (and so runs) the damaged part's task
    assert ResultStore(table, grid.describe()).finished_keys() == kept and len(kept) == 1


# --- 5. Ctrl-C --------------------------------------------------------------------------------------------

class _InterruptedCampaign:
    """A campaign that records a little, is stopped by SIGINT and says so the way a real one does."""

    name = 'alignment'

    def plan(self, variant):
        return object()

    def run(self, truth, *, bag_path, **options):
        Path(bag_path).mkdir(parents=True)
        (Path(bag_path) / 'bag_0.mcap').write_bytes(b'\0' * 1024)
        with interrupts.graceful():
            os.kill(os.getpid(), signal.SIGINT)
            finish_run(bag_path, {'sim_seconds': 1.0})


def test_ctrl_c_in_a_serial_atlas_names_the_table_not_a_deleted_bag(tmp_path, capsys, monkeypatch):
    scratch = tmp_path / 'tmp'
    scratch.mkdir()
    monkeypatch.setattr(tempfile, 'tempdir', str(scratch))
    monkeypatch.setattr('sofia_ros.atlas.task.campaign_named', lambda name: _InterruptedCampaign())
    line = _refused(['--out', str(tmp_path / 'atlas'), *FLAGS, '--serial'], capsys, code=130)
    # was: "...; /tmp/sofia-atlas-*/bag holds the run up to then", a bag the task had deleted
    assert line == (f'sofia: interrupted by SIGINT; {tmp_path / "atlas" / "table"} keeps the 0 of 2 tasks '
                    'finished; run the same command again to run the other 2')
    assert list(scratch.iterdir()) == []


@pytest.mark.timeout(300)
def test_ctrl_c_on_the_local_cluster_leaves_no_bag_in_tmp(tmp_path, capsys, monkeypatch):
    """One real task on one worker, interrupted once its bag is being written."""
    scratch = tmp_path / 'tmp'
    scratch.mkdir()
    monkeypatch.setenv('TMPDIR', str(scratch))  # the workers' temporary directory too
    monkeypatch.setattr(tempfile, 'tempdir', None)

    def interrupt_once_a_bag_is_written():
        deadline = time.monotonic() + 240
        while time.monotonic() < deadline and not any(scratch.glob('**/sofia-atlas-*/**/*.mcap')):
            time.sleep(0.1)
        os.kill(os.getpid(), signal.SIGINT)

    watcher = threading.Thread(target=interrupt_once_a_bag_is_written, daemon=True)
    watcher.start()
    code = main(['atlas', '--out', str(tmp_path / 'atlas'), '--effects', 'timestamp_offset', '--sizes', '1',
                 '--campaigns', 'alignment:minimal', '--seeds', '1', '--candidates', 'timestamp_offset',
                 '--workers', '1'])
    watcher.join(timeout=5)
    err = capsys.readouterr().err
    assert code == 130 and 'Traceback' not in err, err
    assert err.strip().splitlines()[-1].startswith('sofia: interrupted by SIGINT; ')
    # was: the worker, killed with the cluster, left its task's bag in /tmp
    assert not list(scratch.glob('**/sofia-atlas-*')), list(scratch.rglob('*'))
