"""How long the launcher of a --processes graph waits (nodes.launch): a node that never connects is named soon after
the last node has started, and a stopped graph's stuck nodes share one grace period. Stand-in processes, no DDS."""

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from sofia_ros.errors import GraphRunError
from sofia_ros.nodes import launch

NOMINAL_TRUTH = Path(__file__).resolve().parents[1] / 'config' / 'truth' / 'nominal.yaml'

#: A node process as the launcher sees it: its log lines (nodes.executables, nodes.shell), then waiting; SIGUSR1
#: writes its stack to its log, as the real nodes' faulthandler does.
_NODE = '''
import faulthandler, signal, sys, time
faulthandler.register(signal.SIGUSR1, all_threads=True)
signal.signal(signal.SIGINT, signal.default_int_handler)  # a pytest-xdist worker ignores SIGINT
name, gets_as_far_as = sys.argv[1], sys.argv[2]
if gets_as_far_as in ('start', 'connection'):
    print(f'[INFO] [1795798817.4] [{name}]: started from /sofia_ros; waiting for the other nodes of the graph',
          flush=True)
if gets_as_far_as == 'connection':
    print(f'[INFO] [1795798817.5] [{name}]: connected; waiting for ticks', flush=True)
if gets_as_far_as == 'death':
    signal.signal(signal.SIGSEGV, signal.SIG_DFL)
    signal.raise_signal(signal.SIGSEGV)
def waiting_for_the_graph():
    time.sleep(600)
waiting_for_the_graph()
'''


def _stand_ins(tmp_path, stuck=None):
    """A clock, a plant, a wfi, a tascu and a recorder, each logging into tmp_path like a real node; ``stuck``: (node,
    as far as it gets: 'start', 'nothing' or 'death'), the others get as far as their connection."""
    processes = {}
    for name in ('clock', 'plant', 'wfi', 'tascu', 'recorder'):
        gets_as_far_as = stuck[1] if stuck and name == stuck[0] else 'connection'
        with open(tmp_path / f'{name}.log', 'w') as log:
            processes[name] = subprocess.Popen([sys.executable, '-c', _NODE, name, gets_as_far_as],
                                               stdout=log, stderr=subprocess.STDOUT)
    # Those that connect have, before the launcher looks: on a loaded machine a stand-in may take a second to start.
    deadline = time.monotonic() + 30.0
    while not all(launch.CONNECTED_LOG in (tmp_path / f'{name}.log').read_text()
                  for name in processes if not stuck or name != stuck[0]) or (
            stuck and stuck[1] == 'death' and processes[stuck[0]].poll() is None):
        assert time.monotonic() < deadline, 'the stand-ins did not start'
        time.sleep(0.05)
    return launch.GraphProcesses(processes, tmp_path, bag_path=tmp_path / 'bag')


#: Both seen in --processes graphs on a loaded machine: a recorder that started and never heard the others, a tascu
#: whose process never logged its first line.
STUCK = [('recorder', 'start'), ('tascu', 'nothing')]


@pytest.mark.timeout(60)
@pytest.mark.parametrize('stuck', STUCK, ids=[f'{node}-{gets_as_far_as}' for node, gets_as_far_as in STUCK])
def test_a_node_that_never_connects_is_named_soon_after_the_first_node_started(tmp_path, monkeypatch, stuck):
    # Before, only the clock's start-up limit (120 s from its own start) or the wall-time limit ended such a run.
    monkeypatch.setattr(launch, 'CONNECT_GRACE_S', 1.0)
    graph = _stand_ins(tmp_path, stuck)
    started = time.monotonic()
    with pytest.raises(GraphRunError, match=rf'^{stuck[0]} did not connect within 1 s of the first node starting; '
                                            r'is every node running\? logs, with where each node was, in '):
        launch.wait_for_graph(graph, timeout_s=50)
    assert time.monotonic() - started < 20  # start-up of the stand-ins, 1 s, the stack dump's 1 s
    assert 'in waiting_for_the_graph' in (tmp_path / f'{stuck[0]}.log').read_text()
    assert all(process.returncode == -signal.SIGINT for process in graph.processes.values())


@pytest.mark.timeout(60)
def test_a_node_process_that_dies_starting_is_named_at_once(tmp_path):
    # Seen: wfi's process killed by SIGSEGV in _read_parameters; the others waited for the clock's 120 s.
    graph = _stand_ins(tmp_path, ('wfi', 'death'))
    started = time.monotonic()
    with pytest.raises(GraphRunError, match=r'^wfi did not connect within \d+ s: its process was killed by SIGSEGV '
                                            r'while the graph was starting; logs in '):
        launch.wait_for_graph(graph, timeout_s=50)
    assert time.monotonic() - started < launch.CONNECT_GRACE_S / 2


@pytest.mark.timeout(60)
def test_a_graph_whose_nodes_all_connected_is_left_to_run(tmp_path, monkeypatch):
    monkeypatch.setattr(launch, 'CONNECT_GRACE_S', 1.0)
    graph = _stand_ins(tmp_path)
    with pytest.raises(GraphRunError, match='did not finish within 4 s of wall time'):
        launch.wait_for_graph(graph, timeout_s=4)


_STUCK = 'import signal, time; signal.signal(signal.SIGINT, signal.SIG_IGN); print("up", flush=True); time.sleep(600)'


@pytest.mark.timeout(60)
def test_nodes_stuck_in_their_teardown_share_one_grace_period(tmp_path, monkeypatch):
    # Each had STOP_GRACE_S of its own: eleven nodes stuck destroying their DDS entities held a run for 110 s.
    monkeypatch.setattr(launch, 'STOP_GRACE_S', 1.0)
    processes = {f'node{index}': subprocess.Popen([sys.executable, '-c', _STUCK], stdout=subprocess.PIPE, text=True)
                 for index in range(4)}
    for process in processes.values():
        assert process.stdout.readline() == 'up\n'  # SIGINT is ignored from here on
    started = time.monotonic()
    launch.stop_graph(launch.GraphProcesses(processes, tmp_path))
    assert time.monotonic() - started < 3.0  # one grace of 1 s, then killed; 4 s or more with one each
    assert all(process.returncode == -signal.SIGKILL for process in processes.values())


_NODE_END = '''
import ctypes, sys
from sofia_ros.nodes.executables import _exit_at_once
print('[INFO] [recorder]: stop after tick 7: done', flush=False)  # Python's buffer
ctypes.CDLL(None).printf(b'[INFO] [recorder]: from C\\n')  # C's buffer, as rcutils' would be into a file
_exit_at_once(3)
'''


@pytest.mark.timeout(60)
def test_a_node_process_ends_without_the_interpreters_teardown_and_keeps_its_log_and_exit_code(tmp_path):
    # A graph's eleven node processes unloading numpy, scipy and rclpy at once took 2.5-4.5 s after every run's stop.
    environment = {name: value for name, value in os.environ.items() if name != 'PYTHONUNBUFFERED'}  # C's buffered
    with open(tmp_path / 'recorder.log', 'w') as log:
        code = subprocess.run([sys.executable, '-c', _NODE_END], stdout=log, stderr=subprocess.STDOUT, timeout=50,
                              env=environment)
    assert code.returncode == 3
    assert sorted((tmp_path / 'recorder.log').read_text().splitlines()) == [
        '[INFO] [recorder]: from C', '[INFO] [recorder]: stop after tick 7: done']


def _fake_graph_runs(tmp_path, reasons):
    """A run_graph_in_processes that writes a bag stopped for each reason in turn (a stall: the clock's exit 3), and
    the starts it was asked for."""
    from types import SimpleNamespace

    from sofia_ros.bag import BagWriter
    from sofia_ros.nodes.clock_node import STALLED_EXIT_CODE
    from sofia_ros.topics import STOP_DOCUMENT

    starts = []

    def run(parameters, bag_path, *, timeout_s, progress):
        reason = reasons[len(starts)]
        starts.append(parameters['bag_path'])
        workdir = tmp_path / f'logs{len(starts)}'
        workdir.mkdir()
        (workdir / 'clock.log').write_text('[INFO] [1795798817.4] [clock]: started\n')
        bag = BagWriter(bag_path, epoch_ns=0)
        bag.open()
        bag.write_document(STOP_DOCUMENT.name, reason or 'calibration finished', 0)
        bag.close()
        clock = SimpleNamespace(returncode=STALLED_EXIT_CODE if reason else 0)
        return SimpleNamespace(processes={'clock': clock}, workdir=workdir)
    return run, starts


@pytest.mark.parametrize('second', [None, 'again'], ids=['then-runs', 'stalls-again'])
def test_a_graph_stalled_on_its_first_tick_is_started_once_more_on_a_new_bag(second, tmp_path, monkeypatch, capsys):
    from sofia_ros.campaigns.alignment import graph_config
    from sofia_ros.campaigns.recording import _run_processes
    from sofia_ros.config import load_effect_config
    from sofia_ros.nodes.clock_node import FIRST_TICK_STALL

    stall = f'gyro_box stopped reporting at tick 1 (sim 0.2 s) for 15 s: the node is gone or stuck{FIRST_TICK_STALL}'
    run, starts = _fake_graph_runs(tmp_path, [stall, stall if second else None])
    monkeypatch.setattr(launch, 'run_graph_in_processes', run)
    config = graph_config(load_effect_config(str(NOMINAL_TRUTH)), seed=0)
    reason = _run_processes(config, tmp_path / 'bag', 'effects: {}\n', 10.0, 60.0, None)
    assert len(starts) == 2 and starts[0] == starts[1]
    assert not (tmp_path / 'logs1').exists(), 'the first start\'s logs go with its bag'
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'the graph stalled on its first tick' in err and 'starting it again' in err
    if second:
        assert reason.startswith('gyro_box stopped reporting at tick 1') and str(tmp_path / 'logs2') in reason
        # Not "starts cleanly again": it just did not.
        assert FIRST_TICK_STALL not in reason
        assert 'on a second start as well: run it again, or without --processes' in reason
    else:
        assert reason is None


def test_a_stall_after_the_first_tick_is_not_started_again(tmp_path, monkeypatch, capsys):
    from sofia_ros.campaigns.alignment import graph_config
    from sofia_ros.campaigns.recording import _run_processes
    from sofia_ros.config import load_effect_config

    run, starts = _fake_graph_runs(tmp_path, ['gyro_box stopped reporting at tick 9 (sim 1.8 s) for 15 s: the node is '
                                              'gone'])
    monkeypatch.setattr(launch, 'run_graph_in_processes', run)
    config = graph_config(load_effect_config(str(NOMINAL_TRUTH)), seed=0)
    reason = _run_processes(config, tmp_path / 'bag', 'effects: {}\n', 10.0, 60.0, None)
    assert len(starts) == 1 and reason.startswith('gyro_box stopped reporting at tick 9')
    assert capsys.readouterr().err == ''
