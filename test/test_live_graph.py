"""The node graph over DDS: one process under an executor (messages handed over in it, or all over DDS), one
process per node, the recorder stopped, replays.

A node killed mid-run is test_run_signals.py's (`sofia run --processes`, the same stall watchdog).
"""

import shutil
import signal
import subprocess
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import rclpy
import yaml
from rclpy.experimental import EventsExecutor
from rclpy.task import Future
from rosgraph_msgs.msg import Clock

from graph_startup import STARTUP_RERUNS
from sofia_ros.bag import BagReader
from sofia_ros.bag.digest import topic_digests
from sofia_ros.campaigns.alignment import run_alignment
from sofia_ros.campaigns.run_parameters import graph_parameters
from sofia_ros.config import load_effect_config
from sofia_ros.errors import GraphRunError
from sofia_ros.nodes import launch
from sofia_ros.nodes.clock_node import STALLED_EXIT_CODE
from sofia_ros.nodes.intra_process import IntraProcessBus
from sofia_ros.nodes.launch import share_time_source, start_graph_processes, stop_graph
from sofia_ros.nodes.shell import LockstepNode
from sofia_ros.nodes.sync import SYNC_QOS
from sofia_ros.sim.calibration import AlignmentPlan
from sofia_ros.sim.graph import DEFAULT_MAX_SIM_S
from sofia_ros.topics import DEFAULT_TICK_NS, GYRO_IMU, STOP_DOCUMENT

ROOT = Path(__file__).resolve().parents[1]
#: The nominal truth with a thermal control, so that a plan's temperature element commands it (docs/plans.md).
TRUTH = load_effect_config(ROOT / 'config/truth/nominal-thermal.yaml')
# The whole sequence in 301 s of sim time: one frame per position, 2 deg LOS moves, a boresight series of one
# elevation and a 5 s temperature hold, which still publishes on every topic of the graph (the coarse drive's
# commands and MTBS_INERTIAL only in the series, /thermal_control/command only for a temperature element).
SHORT = AlignmentPlan(repetitions=2, verification_repetitions=1, drift_track_s=5.0, frames_per_position=1,
                      los_angle_deg=2.0, flexure_elevations_deg=(23.0,),
                      elements_yaml='- temperature: {target_c: 23.0, duration_s: 5.0}\n')


@pytest.fixture(scope='module')
def direct_run(tmp_path_factory):
    return run_alignment(TRUTH, seed=21, bag_path=tmp_path_factory.mktemp('direct') / 'bag', plan=SHORT,
                         mode='direct')


def _topic_counts(path):
    with BagReader(path) as bag:
        return {topic.name: topic.count for topic in bag.topics if not topic.name.startswith(('/config', '/result'))
                and topic.name != '/parameter_events'}


#: A node outside the graph in the same ROS domain that sets its own parameter ten times a second: parameter
#: events stamped in wall time (about 1.8e9 s, past int32 once the campaign's epoch is added), as a user's tool
#: or the executables' parameter readers publish them. The recorder keeps them out of the bag.
_VISITOR = '''
import rclpy, rclpy.parameter
rclpy.init()
node = rclpy.create_node('visitor')
node.declare_parameter('count', 0)
count = 0
def bump():
    global count
    count += 1
    node.set_parameters([rclpy.parameter.Parameter('count', value=count)])
node.create_timer(0.1, bump)
rclpy.spin(node)
'''


@contextmanager
def _parameter_visitor(tmp_path):
    """Run _VISITOR for the body of the with-statement."""
    with open(tmp_path / 'visitor.log', 'w') as log:
        visitor = subprocess.Popen([sys.executable, '-c', _VISITOR], stdout=log, stderr=subprocess.STDOUT)
    try:
        yield
    finally:
        visitor.send_signal(signal.SIGINT)
        try:
            visitor.wait(timeout=10)
        except subprocess.TimeoutExpired:
            visitor.kill()
            visitor.wait()


@pytest.mark.timeout(600)
@STARTUP_RERUNS
@pytest.mark.parametrize('mode', ['executor', 'executor-dds', 'processes'])
def test_live_graph_writes_the_lock_step_runs_bag(direct_run, tmp_path, mode):
    # The same cores with the same seeds behind DDS (in one process the messages handed over in it, or every
    # one over DDS): the same accepted matrix and the same bag, every
    # topic with the same type, QoS, count, log times and bytes (sofia_ros.bag.digest). /result/stop
    # (why a live run stopped) exists over DDS only (docs/bag.md).
    with _parameter_visitor(tmp_path):
        live = run_alignment(TRUTH, seed=21, bag_path=tmp_path / mode, plan=SHORT, mode=mode, timeout_s=500)
    assert live.summary['accepted'] == direct_run.summary['accepted'] is True
    np.testing.assert_array_equal(yaml.safe_load(live.result_yaml)['tarf_from_gyrf'],
                                  yaml.safe_load(direct_run.result_yaml)['tarf_from_gyrf'])
    digests, direct = topic_digests(live.bag_path), topic_digests(direct_run.bag_path)
    assert set(digests) - {STOP_DOCUMENT.name} == set(direct)
    for topic, digest in direct.items():
        assert digests[topic] == digest, f'{topic}: {mode} differs from direct'
    counts = _topic_counts(live.bag_path)
    assert all(counts.values()), counts  # every topic of the graph carried messages (SHORT above)
    assert direct[GYRO_IMU.name][2] == round(400 * live.summary['sim_seconds'])  # every 400 Hz sample


def _wait_until_running(graph, sim_s=5.0, timeout_s=180.0):
    """Until the graph's /clock has passed ``sim_s`` (startup of eleven processes takes a while)."""
    import rclpy
    from rosgraph_msgs.msg import Clock

    from sofia_ros.nodes.sync import SYNC_QOS

    rclpy.init()
    try:
        node = rclpy.create_node('clock_watcher')
        latest = [0.0]
        node.create_subscription(Clock, '/clock', lambda msg: latest.__setitem__(0, msg.clock.sec), SYNC_QOS)
        deadline = time.monotonic() + timeout_s
        while latest[0] < sim_s:
            assert time.monotonic() < deadline, f'the graph did not start; logs in {graph.workdir}'
            assert graph.processes['clock'].poll() is None, \
                f'the clock exited ({(graph.workdir / "clock.log").read_text()}); logs in {graph.workdir}'
            rclpy.spin_once(node, timeout_sec=0.1)
    finally:
        rclpy.try_shutdown()


def _truth_file(tmp_path):
    path = tmp_path / 'truth.yaml'
    path.write_text(TRUTH.text)
    return path


def _parameters(tmp_path, seed, bag):
    """The graph parameters of a SHORT alignment run recorded to ``bag``."""
    return graph_parameters(_truth_file(tmp_path), seed, SHORT, tick_ns=DEFAULT_TICK_NS, max_sim_s=DEFAULT_MAX_SIM_S,
                            bag_path=bag)


@pytest.mark.timeout(300)
@STARTUP_RERUNS
def test_recorder_stopped_by_sigint_closes_a_complete_bag(tmp_path):
    bag = tmp_path / 'sigint'
    graph = start_graph_processes(_parameters(tmp_path, 4, bag), bag)
    try:
        _wait_until_running(graph)
        graph.processes['recorder'].send_signal(signal.SIGINT)
        assert graph.processes['recorder'].wait(timeout=30) == 0
    finally:
        stop_graph(graph)
    shutil.rmtree(graph.workdir)  # the node logs, kept when the graph did not start (the error names them)
    assert (bag / 'metadata.yaml').exists()
    with BagReader(bag) as reader:
        counts = {topic.name: topic.count for topic in reader.topics}
        stamps = [stamp for _, stamp, _ in reader.raw_messages('/clock')]
    assert counts['/clock'] > 10 and counts['/gyro_box/imu'] > 400
    assert stamps == sorted(stamps)


@pytest.mark.timeout(120)
def test_replay_publishes_a_bag_into_a_live_graph(direct_run):

    import rclpy
    from geometry_msgs.msg import QuaternionStamped

    from sofia_ros.nodes.sync import DATA_QOS

    rclpy.init()
    try:
        node = rclpy.create_node('replay_listener')
        received = []
        node.create_subscription(QuaternionStamped, '/tascu/attitude', received.append, DATA_QOS)
        replay = subprocess.Popen([sys.executable, '-m', 'sofia_ros.cli', 'replay', str(direct_run.bag_path),
                                   '--rate', '0', '--topics', '/tascu/attitude', '/clock', '--wait-s', '60'],
                                  stdout=subprocess.PIPE, text=True)
        while replay.poll() is None:
            rclpy.spin_once(node, timeout_sec=0.05)
        for _ in range(40):
            rclpy.spin_once(node, timeout_sec=0.05)
        assert replay.returncode == 0
        expected = _topic_counts(direct_run.bag_path)['/tascu/attitude']
        assert f'replayed {2 * expected} messages' in replay.stdout.read()
        assert len(received) == expected
    finally:
        rclpy.try_shutdown()


def test_a_campaign_bag_runs_on_the_campaigns_utc_time(direct_run):
    # Polaris from Waco, 2004-09-02 23:32:51 CDT (Table D.3 observation 2): the bag is on that time axis.
    start_ns = 1_094_185_971 * 10**9
    with BagReader(direct_run.bag_path) as bag:
        assert bag.campaign_epoch_ns() == start_ns
        clock = [(stamp_ns, message.clock.sec * 10**9 + message.clock.nanosec)
                 for _, stamp_ns, message in bag.messages('/clock')]
        attitude = [(stamp_ns, message.header.stamp.sec) for _, stamp_ns, message in bag.messages('/tascu/attitude')]
        imu = bag.imu_arrays('/gyro_box/imu')
    assert clock[0] == (start_ns + DEFAULT_TICK_NS, start_ns + DEFAULT_TICK_NS)
    assert all(log_ns == stamp_ns for log_ns, stamp_ns in clock)
    assert attitude[0][1] == (start_ns + DEFAULT_TICK_NS) // 10**9
    assert imu.header_stamp_ns[0] == start_ns + 2_500_000
    sim_ns = round(direct_run.summary['sim_seconds'] * 1e9)
    assert clock[-1][0] == start_ns + sim_ns
    info = yaml.safe_load((direct_run.bag_path / 'metadata.yaml').read_text())['rosbag2_bagfile_information']
    assert info['starting_time']['nanoseconds_since_epoch'] == start_ns  # the documents, at the start
    assert info['duration']['nanoseconds'] == sim_ns
    # Read for analysis, the same bag counts from the campaign's start.
    with BagReader(direct_run.bag_path, campaign_time=True) as bag:
        assert [stamp_ns for _, stamp_ns, _ in bag.messages('/clock')][:2] == [DEFAULT_TICK_NS, 2 * DEFAULT_TICK_NS]


@pytest.mark.timeout(120)
def test_a_replay_re_latches_the_documents_for_a_late_subscriber(direct_run):

    import rclpy
    from rosgraph_msgs.msg import Clock
    from std_msgs.msg import String

    from sofia_ros.nodes.sync import DATA_QOS, SYNC_QOS

    with BagReader(direct_run.bag_path) as bag:
        truth_text = bag.document('/config/truth')
    rclpy.init()
    replay = None
    try:
        node = rclpy.create_node('late_listener')
        ticks = []
        node.create_subscription(Clock, '/clock', ticks.append, DATA_QOS)
        replay = subprocess.Popen([sys.executable, '-m', 'sofia_ros.cli', 'replay', str(direct_run.bag_path),
                                   '--topics', '/config/truth', '/clock'], stdout=subprocess.PIPE,
                                  stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 60.0
        # The documents are logged at the start: once ten ticks of /clock have arrived they were published.
        while len(ticks) < 10:
            assert time.monotonic() < deadline and replay.poll() is None, 'the replay did not start'
            rclpy.spin_once(node, timeout_sec=0.05)
        documents = []
        node.create_subscription(String, '/config/truth', documents.append, SYNC_QOS)
        while not documents:
            assert time.monotonic() < deadline and replay.poll() is None, 'the late subscriber got no document'
            rclpy.spin_once(node, timeout_sec=0.05)
        assert [message.data for message in documents] == [truth_text]
        assert 1_094_185_971 <= ticks[0].clock.sec < 1_094_185_971 + 60  # replayed on the campaign's UTC time
        # Stopped mid-replay, it says so in one line, without a traceback, and exits 143 (SIGTERM).
        replay.terminate()
        _, errors = replay.communicate(timeout=20)
        assert replay.returncode == 143, errors
        assert errors.strip() == 'sofia: interrupted by SIGTERM' and 'Traceback' not in errors
    finally:
        if replay is not None and replay.poll() is None:
            replay.kill()
            replay.communicate(timeout=10)
        rclpy.try_shutdown()


@pytest.mark.timeout(60)
def test_a_recorder_that_never_heard_the_stop_is_stopped_once_the_clock_has_exited(tmp_path, monkeypatch):
    # A recorder that never connected does not hear /sim/stop; before, `sofia run --processes` then waited on it
    # for the whole wall-time limit. Stand-ins: a clock that logged its reason and exited 3, a recorder that waits.
    monkeypatch.setattr(launch, 'RECORDER_GRACE_S', 1.0)
    # The stand-in ignores SIGINT (as a pytest-xdist worker, which it inherits that from): it is killed after this.
    monkeypatch.setattr(launch, 'STOP_GRACE_S', 1.0)
    (tmp_path / 'clock.log').write_text('[INFO] [clock]: stopping: recorder did not connect within 120 s\n')
    processes = {'clock': subprocess.Popen([sys.executable, '-c', 'raise SystemExit(3)']),
                 'recorder': subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(600)'])}
    graph = launch.GraphProcesses(processes, tmp_path, bag_path=tmp_path / 'bag')
    started = time.monotonic()
    with pytest.raises(GraphRunError, match=r'the recorder did not close the bag within 1 s of the clock stopping the '
                                            r'run \(clock exited with code 3: .*did not connect within 120 s\)'):
        launch.wait_for_graph(graph, timeout_s=50)
    assert time.monotonic() - started < 20
    assert processes['recorder'].poll() is not None


@pytest.mark.timeout(60)
def test_a_graph_that_runs_out_of_time_leaves_where_each_node_hung_in_its_log(tmp_path):
    # Node processes register SIGUSR1 to dump their Python stacks (nodes.executables); at the wall-time limit the
    # launcher signals every running node before stopping it. Stand-ins: two nodes stuck in a sleep.
    hang = ('import faulthandler, signal, time\n'
            'faulthandler.register(signal.SIGUSR1, all_threads=True)\n'
            'signal.signal(signal.SIGINT, signal.default_int_handler)\n'  # a pytest-xdist worker ignores SIGINT
            'def waiting_for_ever():\n'
            '    time.sleep(600)\n'
            'waiting_for_ever()')
    processes = {}
    for node in ('clock', 'recorder'):
        with open(tmp_path / f'{node}.log', 'w') as log:
            processes[node] = subprocess.Popen([sys.executable, '-c', hang], stderr=log)
    time.sleep(1.0)  # the stand-ins have registered their handler
    with pytest.raises(GraphRunError, match='did not finish within 2 s of wall time; logs, with where each running '
                                            'node was, in'):
        launch.wait_for_graph(launch.GraphProcesses(processes, tmp_path, bag_path=tmp_path / 'bag'), timeout_s=2)
    for node in ('clock', 'recorder'):
        assert 'in waiting_for_ever' in (tmp_path / f'{node}.log').read_text()
        assert processes[node].returncode == -signal.SIGINT  # stopped by the launcher's SIGINT, not killed


@pytest.mark.timeout(60)
def test_a_recorder_that_closed_its_bag_but_does_not_exit_is_stopped(tmp_path, monkeypatch):
    # Stuck destroying its DDS entities after the bag is complete: the run ends, without an error.
    monkeypatch.setattr(launch, 'RECORDER_GRACE_S', 1.0)
    monkeypatch.setattr(launch, 'STOP_GRACE_S', 1.0)  # the stand-in ignores SIGINT, as above
    (tmp_path / 'bag').mkdir()
    (tmp_path / 'bag' / 'metadata.yaml').write_text('rosbag2_bagfile_information: {}\n')
    processes = {'clock': subprocess.Popen([sys.executable, '-c', 'pass']),
                 'recorder': subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(600)'])}
    started = time.monotonic()
    launch.wait_for_graph(launch.GraphProcesses(processes, tmp_path, bag_path=tmp_path / 'bag'), timeout_s=50)
    assert time.monotonic() - started < 20
    assert processes['recorder'].poll() is not None


@pytest.mark.timeout(60)
def test_a_clock_still_exiting_when_the_recorder_is_done_keeps_its_exit_code(tmp_path):
    # The clock stops the run, the recorder closes the bag and exits at once; the clock, still tearing down its
    # DDS entities, then got the launcher's SIGINT and lost its exit code 3: a fault reported as a normal end.
    (tmp_path / 'bag').mkdir()
    (tmp_path / 'bag' / 'metadata.yaml').write_text('rosbag2_bagfile_information: {}\n')
    clock = ('import signal, time\n'
             'signal.signal(signal.SIGINT, lambda *_: (_ for _ in ()).throw(SystemExit(-2)))\n'
             'time.sleep(1.5)\n'
             'raise SystemExit(3)')
    processes = {'clock': subprocess.Popen([sys.executable, '-c', clock]),
                 'recorder': subprocess.Popen([sys.executable, '-c', 'pass'])}
    launch.wait_for_graph(launch.GraphProcesses(processes, tmp_path, bag_path=tmp_path / 'bag'), timeout_s=50)
    assert processes['clock'].returncode == STALLED_EXIT_CODE


@pytest.mark.timeout(60)
def test_on_an_intra_process_bus_clock_reaches_every_nodes_sim_time_without_dds():
    """With the nodes on a bus (nodes.intra_process) /clock comes from it: every node's clock reads the sim time,
    no node subscribes to /clock over DDS, and DDS carries /clock only for a subscription outside the bus."""
    rclpy.init()
    try:
        bus = IntraProcessBus()
        nodes = [LockstepNode(name, upstream=[], tick_ns=DEFAULT_TICK_NS, bus=bus) for name in ('keeper', 'first')]
        share_time_source(nodes[0], nodes[1:], bus)
        publisher = nodes[0].create_publisher(Clock, '/clock', SYNC_QOS)
        stamp_ns = 1234 * DEFAULT_TICK_NS
        bus.publish(publisher, '/clock', Clock(clock=rclpy.time.Time(nanoseconds=stamp_ns).to_msg()))
        assert not bus.deliver(max_s=1.0)
        assert [node.get_clock().now().nanoseconds for node in nodes] == [stamp_ns] * 2
        assert not any(topic == '/clock' for node in nodes
                       for topic, _ in node.get_subscriber_names_and_types_by_node(node.get_name(), '/'))
        assert publisher.get_subscription_count() == 0 and bus.subscriptions('/clock') == 1
        for node in nodes:
            node.destroy_node()
    finally:
        rclpy.try_shutdown()


@pytest.mark.timeout(60)
def test_the_executor_gets_its_turn_while_the_bus_hands_messages_over():
    """A graph whose messages never stop (ticks that follow each other at once) still serves its timers: the
    clock's watchdog, which notices SIGINT, the progress line, parameter responses (launch.BUS_SLICE_S)."""
    rclpy.init()
    try:
        bus = IntraProcessBus()
        node = rclpy.create_node('ticker')
        publisher = node.create_publisher(Clock, '/endless', SYNC_QOS)
        handed_over = []

        def tick_again(message):
            handed_over.append(message)
            bus.publish(publisher, '/endless', message)
        bus.subscribe('/endless', tick_again, SYNC_QOS)
        bus.publish(publisher, '/endless', Clock())
        stopped = Future()
        node.create_timer(0.2, lambda: stopped.done() or stopped.set_result(len(handed_over)))
        executor = EventsExecutor()
        executor.add_node(node)
        started = time.monotonic()
        launch._spin_until_recorded(executor, bus, stopped, timeout_s=20.0)
        assert stopped.done() and time.monotonic() - started < 5.0
        assert stopped.result() > 100 and bus.pending  # the timer ran in the middle of the hand-over
        executor.shutdown()
        node.destroy_node()
    finally:
        rclpy.try_shutdown()


@pytest.mark.timeout(60)
def test_one_clock_subscription_drives_every_nodes_sim_time():
    """Under one executor the nodes share the first node's /clock subscription (launch.share_time_source):
    every node's clock still reads the sim time /clock gives, and use_sim_time stays true."""
    rclpy.init()
    try:
        nodes = [LockstepNode(name, upstream=[], tick_ns=DEFAULT_TICK_NS) for name in ('keeper', 'first', 'second')]
        share_time_source(nodes[0], nodes[1:])
        clock = rclpy.create_node('clock_source')
        publisher = clock.create_publisher(Clock, '/clock', 10)
        executor = EventsExecutor()
        for node in (*nodes, clock):
            executor.add_node(node)
        stamp_ns = 1234 * DEFAULT_TICK_NS
        deadline = time.monotonic() + 30.0
        while (any(node.get_clock().now().nanoseconds != stamp_ns for node in nodes)
               and time.monotonic() < deadline):
            publisher.publish(Clock(clock=rclpy.time.Time(nanoseconds=stamp_ns).to_msg()))
            executor.spin_once(timeout_sec=0.1)
        assert [node.get_clock().now().nanoseconds for node in nodes] == [stamp_ns] * 3
        subscribed = [node.get_name() for node in nodes
                      if any(topic == '/clock' for topic, _ in
                             node.get_subscriber_names_and_types_by_node(node.get_name(), '/'))]
        assert subscribed == ['keeper']
        assert all(node.get_parameter('use_sim_time').value for node in nodes)
        executor.shutdown()
        for node in (*nodes, clock):
            node.destroy_node()
    finally:
        rclpy.try_shutdown()
