"""How long the launcher of a --processes graph waits (nodes.launch): a node that never connects is named soon after
the last node has started, and a stopped graph's stuck nodes share one grace period. Stand-in processes, no DDS."""

import signal
import subprocess
import sys
import time

import pytest

from sofia_ros.errors import GraphRunError
from sofia_ros.nodes import launch

#: A node process as the launcher sees it: its log lines (nodes.executables, nodes.shell), then waiting; SIGUSR1
#: writes its stack to its log, as the real nodes' faulthandler does.
_NODE = '''
import faulthandler, signal, sys, time
faulthandler.register(signal.SIGUSR1, all_threads=True)
signal.signal(signal.SIGINT, signal.default_int_handler)  # a pytest-xdist worker ignores SIGINT
name, connects = sys.argv[1], sys.argv[2] == 'yes'
print(f'[INFO] [1795798817.4] [{name}]: started from /sofia_ros; waiting for the other nodes of the graph', flush=True)
if connects:
    print(f'[INFO] [1795798817.5] [{name}]: connected; waiting for ticks', flush=True)
def waiting_for_the_graph():
    time.sleep(600)
waiting_for_the_graph()
'''


def _stand_ins(tmp_path, unconnected):
    """A clock, a plant and a recorder, each logging into tmp_path like a real node; ``unconnected`` never connect."""
    processes = {}
    for name in ('clock', 'plant', 'recorder'):
        with open(tmp_path / f'{name}.log', 'w') as log:
            processes[name] = subprocess.Popen(
                [sys.executable, '-c', _NODE, name, 'no' if name in unconnected else 'yes'],
                stdout=log, stderr=subprocess.STDOUT)
    return launch.GraphProcesses(processes, tmp_path, bag_path=tmp_path / 'bag')


@pytest.mark.timeout(60)
def test_a_node_that_never_connects_is_named_soon_after_the_last_node_started(tmp_path, monkeypatch):
    # Before, only the clock's start-up limit (120 s from its own start) or the wall-time limit ended such a run.
    monkeypatch.setattr(launch, 'CONNECT_GRACE_S', 1.0)
    graph = _stand_ins(tmp_path, unconnected={'recorder'})
    started = time.monotonic()
    with pytest.raises(GraphRunError, match=r'^recorder did not connect within 1 s of the last node starting; is '
                                            r'every node running\? logs, with where each node was, in '):
        launch.wait_for_graph(graph, timeout_s=50)
    assert time.monotonic() - started < 20  # start-up of the stand-ins, 1 s, the stack dump's 1 s
    assert 'in waiting_for_the_graph' in (tmp_path / 'recorder.log').read_text()
    assert all(process.returncode == -signal.SIGINT for process in graph.processes.values())


@pytest.mark.timeout(60)
def test_a_graph_whose_nodes_all_connected_is_left_to_run(tmp_path, monkeypatch):
    monkeypatch.setattr(launch, 'CONNECT_GRACE_S', 1.0)
    graph = _stand_ins(tmp_path, unconnected=set())
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
