"""Two graphs on one machine, signals in every mode, SIGKILL and `sofia recover` (issue 13)."""

import io
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import pytest

from graph_startup import STARTUP_RERUNS
from sofia_ros.bag import BagReader
from sofia_ros.cli import main
from sofia_ros.errors import ConfigError, DomainBusyError
from sofia_ros.nodes.domain import claim_ros_domain, domain_lock_path, release_ros_domain
from sofia_ros.topics import DEFAULT_TICK_NS

ROOT = Path(__file__).resolve().parents[1]
TRUTH = str(ROOT / 'config' / 'truth' / 'nominal.yaml')
SOFIA = [sys.executable, '-m', 'sofia_ros.cli']
HOLD_LOCK = ('import sys, time; from sofia_ros.nodes.domain import claim_ros_domain; '
             'claim = claim_ros_domain(); print(claim.domain_id, flush=True); time.sleep(float(sys.argv[1]))')


@pytest.fixture
def held_domain():
    """Another process holding the domain lock of this session's ROS_DOMAIN_ID, as a running graph does."""
    holder = subprocess.Popen([sys.executable, '-c', HOLD_LOCK, '60'], stdout=subprocess.PIPE, text=True)
    try:
        domain_id = int(holder.stdout.readline())
        yield domain_id
    finally:
        holder.kill()
        holder.wait()


def test_a_second_run_in_a_held_exported_domain_is_refused_at_once(held_domain, tmp_path, capsys, monkeypatch):
    monkeypatch.setenv('ROS_DOMAIN_ID', str(held_domain))
    start = time.monotonic()
    code = main(['run', 'alignment', '--truth', TRUTH, '--bag', str(tmp_path / 'bag'), '--max-sim-s', '10'])
    err = capsys.readouterr().err
    assert code == 2
    assert time.monotonic() - start < 10.0
    assert err.count('\n') == 1 and f'ROS_DOMAIN_ID={held_domain} is in use' in err and 'Traceback' not in err
    assert not (tmp_path / 'bag').exists()


@pytest.mark.timeout(420)
def test_two_concurrent_runs_in_one_exported_domain_the_second_is_refused(tmp_path, capsys):
    # The first run is also the executor mode's SIGTERM case of the signal test below.
    first, first_bag = _start_run(tmp_path, MODES['executor'])
    children = _children(first.pid)
    try:
        start = time.monotonic()
        code = main(['run', 'alignment', '--truth', TRUTH, '--bag', str(tmp_path / 'second'), '--max-sim-s', '10'])
        err = capsys.readouterr().err
        assert code == 2 and time.monotonic() - start < 10.0
        assert err.count('\n') == 1 and f'ROS_DOMAIN_ID={os.environ["ROS_DOMAIN_ID"]} is in use' in err
        assert not (tmp_path / 'second').exists()
    finally:
        first.send_signal(signal.SIGTERM)
        _, first_err = first.communicate(timeout=120)
    _assert_closed_by_signal(first, first_err, first_bag, children, 'executor', signal.SIGTERM)


def test_claiming_a_held_domain_raises_domain_busy(held_domain, monkeypatch):
    monkeypatch.setenv('ROS_DOMAIN_ID', str(held_domain))
    with pytest.raises(DomainBusyError, match=f'ROS_DOMAIN_ID={held_domain} is in use by another sofia run'):
        claim_ros_domain()


def test_a_run_with_a_temporary_directory_of_its_own_sees_the_domains_held_under_another(held_domain, tmp_path,
                                                                                         monkeypatch):
    # The holder claimed its domain with the session's TMPDIR; a run whose TMPDIR is elsewhere (a batch job's) is
    # on the same machine's DDS, and must be refused the same domain.
    monkeypatch.setenv('ROS_DOMAIN_ID', str(held_domain))
    monkeypatch.setenv('TMPDIR', str(tmp_path))
    monkeypatch.setattr(tempfile, 'tempdir', str(tmp_path))
    with pytest.raises(DomainBusyError, match=f'ROS_DOMAIN_ID={held_domain} is in use by another sofia run'):
        claim_ros_domain()


def test_without_a_domain_a_free_one_is_picked_and_given_back(held_domain, monkeypatch):
    monkeypatch.delenv('ROS_DOMAIN_ID')
    claim = claim_ros_domain()
    try:
        assert claim.domain_id != held_domain
        assert os.environ['ROS_DOMAIN_ID'] == str(claim.domain_id)
        assert domain_lock_path(claim.domain_id).exists()
    finally:
        release_ros_domain(claim)
    assert 'ROS_DOMAIN_ID' not in os.environ


def test_a_malformed_domain_id_is_a_config_error(monkeypatch):
    monkeypatch.setenv('ROS_DOMAIN_ID', 'seven')
    with pytest.raises(ConfigError, match="ROS_DOMAIN_ID must be an integer 0-232, got 'seven'"):
        claim_ros_domain()


def _children(pid):
    """Every descendant pid of ``pid`` (Linux /proc)."""
    found, queue = [], [pid]
    while queue:
        parent = queue.pop()
        for task in Path(f'/proc/{parent}/task').glob('*'):
            try:
                kids = [int(k) for k in (task / 'children').read_text().split()]
            except OSError:
                continue
            found += kids
            queue += kids
    return found


def _alive(pid):
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    state = Path(f'/proc/{pid}/stat').read_text().rsplit(')', 1)[1].split()[0] if Path(f'/proc/{pid}').exists() else 'X'
    return state not in ('Z', 'X')


def _recorded_samples(bag, topic='/gyro_box/imu'):
    """Messages of ``topic`` in the chunks the recorder has written so far (the file is still open: read to its cut)."""
    from mcap.records import Channel, Message
    from mcap.stream_reader import StreamReader

    files = list(bag.glob('*.mcap'))
    if not files:
        return 0
    channels, count = {}, 0
    try:
        for record in StreamReader(io.BytesIO(files[0].read_bytes())).records:
            if isinstance(record, Channel):
                channels[record.id] = record.topic
            elif isinstance(record, Message) and channels.get(record.channel_id) == topic:
                count += 1
    except Exception:  # noqa: BLE001  (a record cut where the writer is: what came before it counts)
        pass
    return count


def _start_run(tmp_path, campaign_args, startup_s=240.0):
    """Start `sofia run` and return once the bag holds the first second of gyro samples (the run is ticking; the
    documents it writes first do not count: under load the nodes may still be starting then)."""
    bag = tmp_path / 'bag'
    process = subprocess.Popen([*SOFIA, 'run', *campaign_args, '--truth', TRUTH, '--bag', str(bag)],
                               stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, cwd=tmp_path)
    deadline = time.monotonic() + startup_s
    try:
        while _recorded_samples(bag) <= 400 and process.poll() is None and time.monotonic() < deadline:
            time.sleep(0.5)
    except BaseException:
        # Never leave a run behind: it would hold this session's ROS domain.
        process.send_signal(signal.SIGTERM)
        process.communicate(timeout=120)
        raise
    if _recorded_samples(bag) <= 400:
        process.send_signal(signal.SIGTERM)
        _, err = process.communicate(timeout=120)
        raise AssertionError(f'the run did not start recording within {startup_s:g} s '
                             f'(exit code {process.returncode}): {err[-2000:]}')
    time.sleep(1.0)
    return process, bag


MODES = {
    'direct': ['alignment', '--direct', '--max-sim-s', '3000'],
    'executor': ['alignment', '--max-sim-s', '3000'],
    'processes': ['alignment', '--processes', '--max-sim-s', '3000'],
    'gyro-stability': ['gyro-stability', '--case', 'TC-1', '--hours', '2'],
    'star-hop direct': ['star-hop', '--direct', '--observations', '1-2', '--hold-s', '600'],
}


#: Each mode once, each signal in more than one mode: SIGINT and SIGTERM take the same path
#: (sofia_ros.interrupts' one handler; rclpy's own handlers are off), only the number differs. The
#: executor's SIGTERM is the two-runs test's first run.
SIGNAL_CASES = [('direct', signal.SIGTERM), ('executor', signal.SIGINT), ('processes', signal.SIGTERM),
                ('gyro-stability', signal.SIGINT), ('star-hop direct', signal.SIGINT)]


@pytest.mark.timeout(420)
@STARTUP_RERUNS
@pytest.mark.parametrize('mode, signum', SIGNAL_CASES,
                         ids=[f'{mode}-{signal.Signals(signum).name}' for mode, signum in SIGNAL_CASES])
def test_a_signal_closes_the_bag_writes_the_summary_and_exits_128_plus_signal(mode, signum, tmp_path):
    process, bag = _start_run(tmp_path, MODES[mode])
    children = _children(process.pid)
    process.send_signal(signum)
    _, err = process.communicate(timeout=120)
    _assert_closed_by_signal(process, err, bag, children, mode, signum)


def _assert_closed_by_signal(process, err, bag, children, mode, signum):
    """The run stopped by ``signum``: exit 128 + signum, one line, the bag closed with its summary, no node left."""
    name = signal.Signals(signum).name
    assert process.returncode == 128 + signum, err
    assert 'Traceback' not in err
    # stderr also holds the progress lines (and the star hop's re-orthonormalization warning, one line)
    sofia_lines = [line for line in err.splitlines() if line.startswith('sofia') and
                   not line.startswith('sofia: warning: alignment.tarf_from_gyrf re-orthonormalized')]
    assert len(sofia_lines) == 1 and sofia_lines[0].startswith(f'sofia: interrupted by {name} at sim ')
    assert err.splitlines()[-1] == sofia_lines[0]
    summary = json.loads((bag / 'summary.json').read_text())
    assert summary['stopped'] == 'interrupted' and summary['reason'] == f'interrupted by {name}'
    assert (bag / 'metadata.yaml').exists()
    with BagReader(bag) as reader:
        assert reader.topic('/gyro_box/imu').count > 400
    time.sleep(0.5)
    assert not [pid for pid in children if _alive(pid)], 'a node outlived the run'
    if mode == 'processes':
        assert not [line for line in err.splitlines() if 'sofia_graph_' in line]


@pytest.mark.timeout(300)
def test_sigkill_leaves_a_bag_that_sofia_recover_restores(tmp_path, capsys):
    process, bag = _start_run(tmp_path, MODES['direct'])
    time.sleep(3.0)
    process.kill()
    process.wait(timeout=30)
    assert not (bag / 'metadata.yaml').exists()
    code = main(['recover', str(bag)])
    out = capsys.readouterr().out
    assert code == 0, out
    recovered = tmp_path / 'bag_recovered'
    assert f'into {recovered}' in out
    with BagReader(recovered) as reader:
        clock_s = reader.topic('/clock').count * 0.2
        assert reader.topic('/gyro_box/imu').count >= 400 * (clock_s - 1.0)
        assert clock_s > 1.0


def test_recover_of_a_folder_without_a_bag_is_one_line(tmp_path, capsys):
    assert main(['recover', str(tmp_path)]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'holds 0 .mcap files' in err


@pytest.mark.timeout(420)
@STARTUP_RERUNS
def test_a_killed_recorder_is_named_and_the_run_exits_3(tmp_path):
    process, bag = _start_run(tmp_path, MODES['processes'])
    recorder = [pid for pid in _children(process.pid)
                if b'recorder' in Path(f'/proc/{pid}/cmdline').read_bytes()]
    assert len(recorder) == 1
    os.kill(recorder[0], signal.SIGKILL)
    out, err = process.communicate(timeout=120)
    assert process.returncode == 3, err
    assert 'Traceback' not in err
    assert 'the recorder node was killed by SIGKILL' in err and f'sofia recover {bag}' in err
    summary = json.loads((bag / 'summary.json').read_text())
    assert summary['stopped'] == 'fault' and 'recorder node was killed' in summary['reason']
    # A fault keeps the node logs and names their folder; the test removes it.
    logs = Path(re.search(r'logs in (\S+)', err).group(1))
    assert (logs / 'recorder.log').exists()
    shutil.rmtree(logs)


@pytest.mark.timeout(120)
def test_a_run_that_crashes_mid_way_closes_its_bag_and_keeps_the_reason(tmp_path, monkeypatch):
    from sofia_ros.sim.runner import LockstepRunner

    step = LockstepRunner.step

    def failing_step(runner):
        if runner.stamp_ns >= 10 * 10**9:
            raise RuntimeError('simulated bug at sim 10 s')
        return step(runner)

    monkeypatch.setattr(LockstepRunner, 'step', failing_step)
    bag = tmp_path / 'bag'
    with pytest.raises(RuntimeError, match='simulated bug at sim 10 s'):
        main(['run', 'alignment', '--direct', '--truth', TRUTH, '--bag', str(bag), '--max-sim-s', '60'])
    assert (bag / 'metadata.yaml').exists()
    summary = json.loads((bag / 'summary.json').read_text())
    assert summary['stopped'] == 'fault' and summary['reason'] == 'RuntimeError: simulated bug at sim 10 s'
    with BagReader(bag) as reader:
        assert reader.topic('/clock').count >= 50


def test_a_domain_outside_0_232_is_a_config_error(monkeypatch):
    monkeypatch.setenv('ROS_DOMAIN_ID', '233')
    with pytest.raises(ConfigError, match='ROS_DOMAIN_ID must be an integer 0-232, got 233'):
        claim_ros_domain()


def test_when_every_domain_is_held_the_run_is_told_to_wait(held_domain, monkeypatch):
    import sofia_ros.nodes.domain as domain

    monkeypatch.delenv('ROS_DOMAIN_ID')
    monkeypatch.setattr(domain, 'DOMAIN_IDS', range(held_domain, held_domain + 1))
    with pytest.raises(DomainBusyError, match=f'every ROS domain {held_domain}-{held_domain} is in use'):
        claim_ros_domain()
    assert 'ROS_DOMAIN_ID' not in os.environ


@pytest.mark.timeout(420)
@STARTUP_RERUNS
def test_a_node_that_dies_under_processes_is_a_fault_exit_3(tmp_path):
    # _start_run returns with the first second of gyro samples in the bag: the clock is at tick 5 or later, past its
    # start-up watchdog (which waits up to 120 s for the first tick), so a stall is named after stall_timeout_s.
    process, bag = _start_run(tmp_path, MODES['processes'])
    gyro_box = [pid for pid in _children(process.pid)
                if b'gyro_box' in Path(f'/proc/{pid}/cmdline').read_bytes()]
    assert len(gyro_box) == 1, _children(process.pid)
    os.kill(gyro_box[0], signal.SIGKILL)
    killed = time.monotonic()
    _, err = process.communicate(timeout=180)
    stopped_after_s = time.monotonic() - killed
    assert process.returncode == 3, err
    assert 'Traceback' not in err and 'gyro_box stopped reporting' in err
    summary = json.loads((bag / 'summary.json').read_text())
    assert summary['stopped'] == 'fault' and 'gyro_box stopped reporting' in summary['reason']
    assert (bag / 'metadata.yaml').exists()
    # A fault keeps the node logs and says where (and which node, if any, logged nothing at all).
    logs = Path(re.search(r'node logs in (\S+)', summary['reason']).group(1))
    assert (logs / 'gyro_box.log').read_text().startswith('[INFO]') and 'nothing logged' not in summary['reason']
    shutil.rmtree(logs)
    with BagReader(bag) as reader:
        reason = reader.document('/result/stop')
        counts = {topic.name: topic.count for topic in reader.topics}
    assert reason.startswith('gyro_box stopped reporting at tick') and 'the node is gone' in reason
    # The clock's watchdog names the node after the stall timeout the reason states; the run ends soon after.
    assert stopped_after_s < float(re.search(r' for ([0-9.]+) s: ', reason).group(1)) + 25.0
    assert counts['/gyro_box/imu'] > 0 and counts['/clock'] > 0
    # Everything up to the fault is there: the gyro box's samples stop where it was killed.
    assert counts['/gyro_box/imu'] <= round(400 * DEFAULT_TICK_NS / 1e9) * counts['/truth/imu']


_CLOCK_ALONE = '''
import sys
import sofia_ros.nodes.clock_node as clock_node
clock_node._STARTUP_TIMEOUT_S = 1.0  # the graph's other nodes never come: stop after stall_timeout_s
from sofia_ros.nodes.executables import main
sys.exit(main('clock', ['clock', '--ros-args', '--params-file', sys.argv[1]]))
'''


@pytest.mark.timeout(120)
@pytest.mark.parametrize('delay_s', [0.0, 0.05])
def test_a_sigint_while_the_clock_stops_the_run_keeps_its_fault_exit_code(tmp_path, delay_s):
    # The launcher stops the graph (SIGINT) as soon as the recorder has closed the bag, which the clock's stop
    # lets it do at once: the clock, still logging its reason or tearing down, exited 0 or -2 instead of 3, and
    # `sofia run --processes` reported a run that never started as a normal end (exit 0).
    from sofia_ros.campaigns.run_parameters import graph_parameters
    from sofia_ros.nodes.clock_node import STALLED_EXIT_CODE
    from sofia_ros.nodes.launch import write_params_file
    from sofia_ros.sim.calibration import AlignmentPlan

    parameters = graph_parameters(TRUTH, 1, AlignmentPlan(), tick_ns=DEFAULT_TICK_NS, max_sim_s=10.0,
                                  bag_path=tmp_path / 'bag', stall_timeout_s=2.0)
    write_params_file(tmp_path / 'params.yaml', parameters)
    clock = subprocess.Popen([sys.executable, '-c', _CLOCK_ALONE, str(tmp_path / 'params.yaml')],
                             stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    log, signalled = [], False
    for line in clock.stdout:
        log.append(line)
        if 'stopping:' in line:
            time.sleep(delay_s)
            clock.send_signal(signal.SIGINT)
            signalled = True
            break
    log.append(clock.stdout.read())
    assert signalled, ''.join(log)
    assert clock.wait(timeout=60) == STALLED_EXIT_CODE, ''.join(log)
    assert 'did not connect within 2 s' in ''.join(log)
