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


@pytest.mark.timeout(60)
def test_an_address_whose_connect_never_completes_is_one_line_within_the_timeout(tmp_path, capsys):
    """What an unroutable address does, on 127.0.0.1: a listener whose backlog is full drops the SYNs."""
    server = socket.socket()
    server.bind(('127.0.0.1', 0))
    server.listen(0)
    port = server.getsockname()[1]
    filling = [socket.create_connection(('127.0.0.1', port), timeout=5)]
    started = time.monotonic()
    try:
        line = _refused(['--out', str(tmp_path / 'atlas'), *FLAGS, '--scheduler', f'tcp://127.0.0.1:{port}',
                         '--connect-timeout-s', '1'], capsys)
    finally:
        for connection in filling:
            connection.close()
        server.close()
    assert time.monotonic() - started < 20.0
    assert f'cannot reach the Dask scheduler at tcp://127.0.0.1:{port} within 1 s (timed out)' in line
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


# --- generated bad input: every case exit 2, one line, no traceback, nothing written or changed --------------

BASE_GRID = {'effects': '[timestamp_offset]', 'sizes': '[1]', 'campaigns': '[alignment:minimal]', 'seeds': '2'}


def _bad_seeds():
    values = ['99999999999999', '1-99999999999', '0-4294967296', '4294967296', '9' * 5000, '1-20000', '10001',
              '5-3', 'x', '1,,x', '-1', '1e11', '1.5', '1-2-3', '1 2', '1-', ','.join(['1'] * 10001)]
    return [('seeds', value[:40], ['--effects', 'timestamp_offset', '--sizes', '1', f'--seeds={value}'], '--seeds')
            for value in values]


def _bad_sizes():
    values = ['-1', 'nan', 'inf', '-inf', 'big', '1e999', '1e9', ',', '0x10', '1;2',
              ','.join(str(size) for size in range(700))]  # 700 sizes x 20 seeds: more than 10000 tasks
    return [('sizes', value[:40], ['--effects', 'timestamp_offset', f'--sizes={value}', '--seeds', '20'], '')
            for value in values]


def _bad_grid_files():
    values = {'seeds': ['100000000000', '1e11', '"1-99999999999"', '-3', '[1, -1]', '[1.5]', 'true', '{a: 1}',
                        '20000', '[]', '4294967296', '"x"', '1.0e+11'],
              'sizes': ['[-1]', '[.nan]', '"1"', '[[1]]', '[1e999]', '[]', '[true]'],
              'effects': ['7', '[7]', '[seeing]', '[gyro_bias]'],
              'campaigns': ['[polar]', '[7]', '[alignment:tiny]']}
    cases = []
    for key, bad_values in values.items():
        for value in bad_values:
            text = ''.join(f'{name}: {value if name == key else good}\n' for name, good in BASE_GRID.items())
            cases.append(('grid', f'{key}: {value}', text.encode(), ''))
    whole = {'a list': b'- a list\n', 'empty': b'', 'not UTF-8': b'seeds: \xff\xfe\n', 'bad YAML': b'seeds: [\n',
             'duplicate key': b'seeds: 1\nseeds: 2\n', 'unknown key': b'seed: 1\n', 'directory': None,
             'missing': 'missing', 'device': Path('/dev/null')}
    return cases + [('grid', name, data, '') for name, data in whole.items()]


def _bad_parts():
    cases = [('part', f'truncated to {length}', ('truncate', length), 'is damaged')
             for length in (0, 1, 4, -1, -8, 0.5)]
    cases += [('part', f'a bit flipped in {column}', ('flip', column), 'is damaged')
              for column in ('key', 'seed', 'size', 'detected', 'top_delta_bic', 'verdict', 'error')]
    cases += [('part', 'not Parquet', ('replace', b'not parquet at all, PAR1'), 'is damaged'),
              ('part', 'a directory', ('directory', None), 'is a directory'),
              ('part', 'another grid', ('foreign', None), 'holds rows of grid'),
              ('part', 'no fingerprint', ('plain', None), 'holds rows of no atlas grid'),
              ('part', 'other columns', ('columns', None), 'is damaged')]
    return cases


def _bad_schedulers():
    addresses = ['tcp://127.0.0.1:0', 'tcp://127.0.0.1:70000', 'tcp://127.0.0.1', 'http://127.0.0.1:8786',
                 'tcp://127.0.0.1:8786/x']
    cases = [('scheduler', address, address, 'is not a scheduler address') for address in addresses]
    return cases + [('server', 'silent', 'silent', 'sent no Dask handshake'),
                    ('server', 'http', 'http', 'sent no Dask handshake'),
                    ('server', 'ssh banner', b'SSH-2.0-OpenSSH_9.6\r\n', 'something other than a Dask handshake'),
                    ('server', 'frame of 3 EiB', b'\xff' * 16, 'something other than a Dask handshake'),
                    ('server', 'closes at once', 'close', 'closed the connection without a Dask handshake'),
                    ('server', 'refused', 'refused', 'cannot reach the Dask scheduler')]


CASES = _bad_seeds() + _bad_sizes() + _bad_grid_files() + _bad_parts() + _bad_schedulers()


def _break_a_part(table, how, argument):
    grid = _stored(table)
    part = _parts(table)[-1]
    data = part.read_bytes()
    if how == 'truncate':
        length = int(len(data) * argument) if isinstance(argument, float) else argument % len(data)
        part.write_bytes(data[:length])
    elif how == 'flip':
        _flip_a_bit(part, argument)
    elif how == 'replace':
        part.write_bytes(argument)
    elif how == 'directory':
        part.unlink()
        part.mkdir()
    elif how == 'foreign':
        _stored(table.parent / 'other', {**GRID, 'seeds': [7]})
        (foreign,) = _parts(table.parent / 'other')
        shutil.move(foreign, table / foreign.name)
        shutil.rmtree(table.parent / 'other')
    elif how == 'plain':
        pq.write_table(pa.Table.from_pylist([_row(grid.tasks()[0])], schema=ROW_SCHEMA), part)
    else:
        pq.write_table(pa.table({'key': ['x']}).replace_schema_metadata(
            {b'sofia_atlas_grid': grid.fingerprint().encode()}), part)


@contextmanager
def _scheduler_address(value):
    if value == 'http':
        with _http_server() as port:
            yield f'tcp://127.0.0.1:{port}'
    elif value == 'refused':
        with _listening() as port:
            pass
        yield f'tcp://127.0.0.1:{port}'
    else:
        with _listening(reply=value if isinstance(value, bytes) else None, close=value == 'close') as port:
            yield f'tcp://127.0.0.1:{port}'


def test_there_are_at_least_50_generated_cases():
    assert len(CASES) >= 50


@pytest.mark.timeout(120)
@pytest.mark.parametrize('kind, name, value, message', CASES, ids=[f'{case[0]}-{case[1]}' for case in CASES])
def test_generated_bad_input_is_one_line_and_changes_nothing(tmp_path, capsys, kind, name, value, message):
    out = tmp_path / 'atlas'
    argv = ['--out', str(out), '--campaigns', 'alignment:minimal']
    if kind in ('seeds', 'sizes'):
        argv += value
    elif kind == 'grid':
        grid_file = tmp_path / 'grid.yaml'
        if isinstance(value, bytes):
            grid_file.write_bytes(value)
        elif value is None:
            grid_file.mkdir()
        elif isinstance(value, Path):
            grid_file = value
        argv = ['--out', str(out), '--grid', str(grid_file)]
    elif kind == 'part':
        _break_a_part(out / 'table', *value)
        argv = ['--out', str(out), *FLAGS, '--serial']
    elif kind == 'scheduler':
        argv = ['--out', str(out), *FLAGS, '--scheduler', value]
    before = _snapshot(out)
    if kind == 'server':
        with _scheduler_address(value) as address:
            line = _refused(['--out', str(out), *FLAGS, '--scheduler', address, '--connect-timeout-s', '0.5'], capsys)
    else:
        line = _refused(argv, capsys)
    assert message in line
    if kind == 'part':
        assert str(out / 'table' / 'part-') in line
    assert _snapshot(out) == before
    assert not list(tmp_path.glob('**/.part-*')) and not list(tmp_path.glob('**/sofia-atlas-*'))


def test_the_default_model_and_truth_are_found_outside_the_checkout(tmp_path, monkeypatch):
    # Run from another folder, the atlas found no config/model/nominal.yaml (the defaults are checkout paths).
    from sofia_ros.atlas.grid import grid_from_lists

    monkeypatch.chdir(tmp_path)
    grid = grid_from_lists(effects=['timestamp_offset'], sizes=[1.0], campaigns=['alignment:minimal'], seeds=[1])
    assert 'gyro_misalignment' in grid.model.fitted and grid.truth.effects


class _Scheduler:
    address = 'tcp://127.0.0.1:8786'
    ncores = 'ncores'
    processing = 'processing'


class _Client:
    """A client whose scheduler answers ``answers`` (method -> reply), or stops answering (None)."""

    scheduler = _Scheduler()

    def __init__(self, answers):
        self.answers, self.timeouts = answers, []

    def sync(self, method, callback_timeout):
        self.timeouts.append(callback_timeout)
        if self.answers is None:
            raise TimeoutError
        return self.answers[method]


def test_a_scheduler_that_stops_answering_is_one_line_not_a_wait_for_ever():
    # Stopped with SIGSTOP mid-run, it kept its connection: the atlas waited for ever, its progress lines stopped.
    from sofia_ros.atlas.engine import SCHEDULER_REPLY_S, SchedulerWatch
    from sofia_ros.errors import SchedulerUnreachableError

    client = _Client(None)
    with pytest.raises(SchedulerUnreachableError, match=r'tcp://127.0.0.1:8786 stopped answering \(no reply within '
                                                          r'60 s\); the rows stored so far are kept'):
        watch = SchedulerWatch(client)
        watch.running({})
    assert client.timeouts == [SCHEDULER_REPLY_S] and not watch.answering  # then no cancel is asked of it


def test_a_scheduler_without_workers_is_given_up_after_a_while(monkeypatch):
    from sofia_ros.atlas import engine
    from sofia_ros.errors import SchedulerUnreachableError

    watch = engine.SchedulerWatch(_Client({'ncores': {}, 'processing': {}}))
    assert watch.threads() == 0  # the first look starts the clock
    monkeypatch.setattr(engine, 'NO_WORKERS_S', 0.0)
    with pytest.raises(SchedulerUnreachableError, match=r'no Dask worker at the scheduler tcp://127.0.0.1:8786 .*'
                                                          r'start one \(dask worker tcp://127.0.0.1:8786\)'):
        watch.threads()
    watch = engine.SchedulerWatch(_Client({'ncores': {'w': 2}, 'processing': {'w': ['a', 'b', 'c']}}))
    assert watch.running({type('F', (), {'key': 'a'})(): None}) == 1
