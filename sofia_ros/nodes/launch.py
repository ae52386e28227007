"""Run a campaign's node graph: all nodes in one process under an executor (messages handed over on an
intra-process bus, or every one over DDS), or one process each, over DDS."""

from __future__ import annotations

import ctypes
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Mapping

import rclpy
import yaml
from rclpy.logging import LoggingSeverity
from rclpy.experimental import EventsExecutor
from rclpy.signals import SignalHandlerOptions

from sofia_ros import interrupts
from sofia_ros.bag.timebase import epoch_ns_of
from sofia_ros.errors import GraphRunError
from sofia_ros.graph_nodes import EXECUTABLES
from sofia_ros.nodes.clock_node import STALLED_EXIT_CODE, ClockNode
from sofia_ros.nodes.domain import claim_ros_domain, claimed_ros_domain, release_ros_domain
from sofia_ros.nodes.intra_process import IntraProcessBus
from sofia_ros.nodes.recorder_node import RecorderNode
from sofia_ros.nodes.shell import CoreNode
from sofia_ros.nodes.sync import SYNC_QOS, parse_stop
from sofia_ros.sim.graph import DEFAULT_MAX_SIM_S, build_cores, graph_topics
from sofia_ros.topics import CLOCK

__all__ = ['run_graph_in_process', 'share_time_source', 'run_graph_in_processes', 'start_graph_processes',
           'write_params_file', 'wait_for_graph', 'stop_graph', 'silent_nodes', 'GraphProcesses', 'RecorderError']


def _participants(cores):
    return [core.name for core in cores if core.name != 'clock']


def run_graph_in_process(config, bag_path, *, documents=(), max_sim_s=DEFAULT_MAX_SIM_S, timeout_s=3600.0,
                         progress=None, intra_process=True):
    """All nodes in one process under one executor; return the calibration core, the stop reason and
    whether the run ended by itself (False: a stall or a signal stopped it; the bag is closed either way).
    ``intra_process``: the nodes hand their messages over in the process (nodes.intra_process), DDS carrying
    only what a subscription outside the process takes; False: every message over DDS, as between processes.

    The ROS domain is claimed for the run (nodes.domain). SIGINT/SIGTERM are left to sofia_ros.interrupts:
    the clock stops the graph at the next watchdog check and the recorder closes the bag.
    """
    with claimed_ros_domain():
        return _run_graph_in_process(config, bag_path, documents, max_sim_s, timeout_s, progress, intra_process)


def _run_graph_in_process(config, bag_path, documents, max_sim_s, timeout_s, progress, intra_process):
    rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
    created, executor = [], None
    try:
        cores = build_cores(config)
        topics = graph_topics(cores)
        bus = IntraProcessBus() if intra_process else None
        nodes = [CoreNode(core, graph_topics=topics, tick_ns=config.tick_ns, bus=bus)
                 for core in cores if core.name != 'clock']
        created.extend(nodes)
        clock_subscribers = len(topics[CLOCK.name][2]) + 1
        clock = ClockNode([*_participants(cores), 'recorder'], tick_ns=config.tick_ns, max_sim_s=max_sim_s,
                          subscribers=clock_subscribers, ending=[core.name for core in cores if core.ends_run], bus=bus)
        created.append(clock)
        recorder = RecorderNode(bag_path, topics, [core.name for core in cores], tick_ns=config.tick_ns,
                                epoch_ns=epoch_ns_of(config.scenario.start_utc), documents=documents, bus=bus,
                                raise_bag_failures=False)
        created.append(recorder)
        share_time_source(nodes[0], (*nodes[1:], clock, recorder), bus)
        # EventsExecutor: 3-10x the callback rate of the SingleThreadedExecutor with this many entities.
        executor = EventsExecutor()
        for node in (*nodes, clock, recorder):
            # In one process the nodes' start/stop lines would only clutter the caller's output.
            node.get_logger().set_level(LoggingSeverity.WARN)
            executor.add_node(node)
        if progress is not None:
            clock.create_timer(0.5, lambda: progress(clock.next_tick * config.tick_ns / 1e9, max_sim_s),
                               clock=clock._wall_clock())
        try:
            _spin_until_recorded(executor, bus, recorder.finished, timeout_s)
            if recorder.failure is not None:
                raise recorder.failure  # the bag's disk filled up: BagWriter's line says what it keeps
            if not recorder.closed:
                raise GraphRunError(f'the graph did not finish within {timeout_s:g} s of wall time')
        finally:
            recorder.abort()
        calibration = next(node.core for node in nodes if node.core.ends_run)
        _, complete, reason = parse_stop(clock.stop_reason) if clock.stop_reason else (0, False, '')
        return calibration, reason, complete
    finally:
        # Whatever ended the run (a full disk, the time limit), the executor lets go of the nodes and they are
        # destroyed: else their DDS entities stay in the domain (an exception's traceback keeps the executor), and a
        # graph this process ran there next got the old clock's /sim/stop and stopped at once.
        if executor is not None:
            executor.shutdown()
        for node in created:
            node.destroy_node()
        rclpy.try_shutdown()


#: How long the intra-process bus hands messages over before the executor's turn, one event (a timer: the clock's
#: watchdog, which notices SIGINT; a parameter service's response; a DDS message): about ten ticks of the alignment
#: graph. The executor has every turn while the queue is empty, as when a node waits for a service.
BUS_SLICE_S = 0.02


def _spin_until_recorded(executor, bus, recorded, timeout_s):
    """Run the graph until the future ``recorded`` is done or ``timeout_s`` has passed."""
    if bus is None:
        # The executor's own loop: no return to Python between callbacks.
        executor.spin_until_future_complete(recorded, timeout_sec=timeout_s)
        return
    deadline = time.monotonic() + timeout_s
    while not recorded.done() and time.monotonic() < deadline:
        if bus.deliver(BUS_SLICE_S):
            executor.spin_once(timeout_sec=0)  # one event that became due meanwhile, then back to the queue
        elif not recorded.done():
            executor.spin_once(timeout_sec=0.05)  # waiting: for a node to connect, a service's response


def share_time_source(keeper, nodes, bus=None):
    """Drive the sim-time clocks of ``nodes`` from ``keeper``'s /clock subscription: under one executor every
    node's own one (rclpy's TimeSource, one per node with use_sim_time) would take and convert each /clock
    message again, about 10 % of the graph's cost per tick. use_sim_time stays true on every node. With an
    intra-process ``bus`` /clock reaches the clocks from it, and no node subscribes to /clock over DDS."""
    # Node._time_source is rclpy's own (pinned by the locks); test_live_graph checks that one /clock
    # subscription serves the process and that every node's clock still reads sim time. Setting use_sim_time
    # false on the keeper would stop every node's clock: nothing does.
    time_source = keeper._time_source
    for node in nodes:
        node._time_source.detach_node()
        time_source.attach_clock(node.get_clock())
    if bus is not None:
        time_source.detach_node()  # its /clock subscription; the clocks stay attached and on sim time
        bus.subscribe(CLOCK.name, time_source.clock_callback, SYNC_QOS)


#: The exit code of a node process that stopped on an error it reported itself, its log's last such line being
#: ``<node>: error: <reason>`` (nodes.executables.main): the recorder's bag on a full disk, for one.
NODE_ERROR_EXIT_CODE = 2


class RecorderError(GraphRunError):
    """The recorder node stopped on an error it reported (its bag's disk filled up): the reason is whole, and the
    node logs, which say nothing more, are not kept."""


#: How long the recorder may take to close its bag once the clock has stopped the run and exited.
RECORDER_GRACE_S = 30.0
#: How long the clock may take to exit by itself once the recorder has closed the bag: the clock stopped the run
#: first, and its exit code (3: a fault) is how the run ended; a SIGINT during its teardown would lose it.
CLOCK_EXIT_GRACE_S = 10.0
#: How long every node may take to connect (find the graph's other nodes and report done(0)) once the first node
#: process has logged its start. Starting is the slow part on a loaded machine (each process imports numpy, scipy and
#: rclpy: 15-50 s at load 5-20), but the processes do it side by side: the last started 2.5 s after the first at most,
#: and connected 1-3 s after that. A node not connected after this never connected in the runs seen (one never got
#: as far as its first line, one never heard the others), and the clock's own start-up limit (120 s from its start)
#: only told the user minutes later.
CONNECT_GRACE_S = 30.0
#: How long the nodes of a stopped graph may take to exit after its SIGINT, all together, before they are killed.
STOP_GRACE_S = 10.0
#: What a node process logs once it is up (nodes.executables.main) and once it has connected
#: (nodes.shell.LockstepNode._check_ready).
STARTED_LOG = ': started from '
CONNECTED_LOG = ': connected; waiting for ticks'


@dataclass
class GraphProcesses:
    """The node processes of one run and the folder with their params file and logs."""

    processes: dict
    workdir: Path
    #: the ROS domain the graph holds (nodes.domain), released by stop_graph
    domain: object = None
    bag_path: Path | None = None


def write_params_file(path: Path, values: Mapping[str, Any],
                      per_node: Mapping[str, Mapping[str, Any]] | None = None) -> None:
    """A --params-file with the graph parameters for every node (``/**``) plus per-node sections."""
    document = {'/**': {'ros__parameters': values}}
    for node, node_values in (per_node or {}).items():
        document[node] = {'ros__parameters': node_values}
    path.write_text(yaml.safe_dump(document, sort_keys=False))


def start_graph_processes(parameters: Mapping[str, Any], bag_path: str | os.PathLike[str]) -> GraphProcesses:
    """Start every node as its own process (what `ros2 run` gives), sharing one params file of the graph
    ``parameters`` (campaigns.graph_params.graph_parameters; bag_path among them for the recorder).

    The nodes share one process group of their own (stop_graph signals the group) and get SIGINT
    from the kernel if this process dies, so no node outlives the run. The ROS domain is claimed
    until stop_graph.
    """
    domain = claim_ros_domain()
    try:
        return _start_graph_processes(parameters, bag_path, domain)
    except BaseException:
        release_ros_domain(domain)
        raise


def _die_with_parent():
    """In the child before exec: SIGINT when the parent dies (Linux prctl PR_SET_PDEATHSIG)."""
    libc = ctypes.CDLL(None, use_errno=True)
    libc.prctl(1, signal.SIGINT, 0, 0, 0)


def _start_graph_processes(parameters, bag_path, domain):
    workdir = Path(tempfile.mkdtemp(prefix='sofia_graph_'))
    params = workdir / 'params.yaml'
    write_params_file(params, parameters)
    # (node, executable, extra arguments): an executable that runs several nodes is told which by its remap
    executables = [(node, executable, ('-r', f'__node:={node}', '-p', f'camera:={node}') if len(nodes) > 1 else ())
                   for executable, nodes in EXECUTABLES.items() for node in nodes]
    processes = {}
    graph = GraphProcesses(processes, workdir, domain, Path(bag_path))
    try:
        for name, executable, extra in executables:
            with open(workdir / f'{name}.log', 'w') as log:
                group = next(iter(processes.values())).pid if processes else 0
                processes[name] = subprocess.Popen(
                    # faulthandler: a node that dies in native code (rmw, Fast DDS) leaves its Python stack in its log
                    [sys.executable, '-X', 'faulthandler', '-m', 'sofia_ros.nodes.executables', executable,
                     '--ros-args', '--params-file', str(params), *extra],
                    stdout=log, stderr=subprocess.STDOUT, env=os.environ.copy(), process_group=group,
                    preexec_fn=_die_with_parent)
    except BaseException:
        stop_graph(graph)
        shutil.rmtree(workdir, ignore_errors=True)
        raise
    return graph


def wait_for_graph(graph, *, timeout_s=3600.0, progress=None, max_sim_s=None):
    """Wait until the recorder has closed the bag, or a signal asks to stop (sofia_ros.interrupts);
    then stop every remaining node. GraphRunError when the recorder died or the time ran out."""
    start = time.monotonic()
    clock, clock_stopped, bag_closed = graph.processes['clock'], None, None
    # when the first node process logged its start; checked until every node has connected
    connecting, first_started = True, None
    try:
        with interrupts.graceful():
            while graph.processes['recorder'].poll() is None and interrupts.requested() is None:
                time.sleep(0.2)
                if progress is not None:
                    progress(None, max_sim_s)
                now = time.monotonic()
                if now - start > timeout_s:
                    _dump_stacks(graph)
                    raise GraphRunError(f'the graph did not finish within {timeout_s:g} s of wall time; '
                                        f'logs, with where each running node was, in {graph.workdir}')
                if connecting:
                    unconnected = _unconnected_nodes(graph)
                    connecting = unconnected != []
                    # A node process that died starting (seen: a SIGSEGV reading its parameters) never connects.
                    dead = [name for name in unconnected or () if graph.processes[name].poll() is not None]
                    if dead:
                        raise GraphRunError(f'{dead[0]} did not connect within {now - start:.0f} s: its process '
                                            f'{_exit_text(graph.processes[dead[0]].returncode)} while the graph was '
                                            f'starting; logs in {graph.workdir}')
                    if unconnected:
                        first_started = first_started or now
                        if now - first_started > CONNECT_GRACE_S:
                            _dump_stacks(graph)
                            raise GraphRunError(f'{", ".join(unconnected)} did not connect within '
                                                f'{CONNECT_GRACE_S:g} s of the first node starting; is every node '
                                                f'running? logs, with where each node was, in {graph.workdir}')
                if clock_stopped is None and clock.poll() is not None:
                    clock_stopped = now
                if bag_closed is None and _bag_is_closed(graph):
                    bag_closed = now
                # A recorder that closed its bag but does not exit (stuck destroying its DDS entities) is stopped.
                if bag_closed is not None and now - bag_closed > RECORDER_GRACE_S:
                    break
                # A recorder that never connected does not hear /sim/stop: the clock's exit ends the run too.
                if bag_closed is None and clock_stopped is not None and now - clock_stopped > RECORDER_GRACE_S:
                    raise GraphRunError(f'the recorder did not close the bag within {RECORDER_GRACE_S:g} s of the '
                                        f'clock stopping the run (clock {_exit_text(clock.returncode)}: '
                                        f'{_last_log_line(graph, "clock")}); logs in {graph.workdir}')
            # The bag is closed because the clock stopped the run: let it exit with its own code first.
            deadline = min(time.monotonic() + CLOCK_EXIT_GRACE_S, start + timeout_s)
            while (_bag_is_closed(graph) and clock.poll() is None and interrupts.requested() is None
                   and time.monotonic() < deadline):
                time.sleep(0.1)
            if clock.returncode == STALLED_EXIT_CODE:
                # A node fell silent: the one that is stuck rather than gone leaves where it hangs in its log.
                _dump_stacks(graph)
    finally:
        stop_graph(graph)
    recorder = graph.processes['recorder']
    # Stopped by a signal, a recorder that had not started yet exits non-zero too; that is no fault.
    if recorder.returncode not in (0, None) and interrupts.requested() is None and not _bag_is_closed(graph):
        reported = _reported_error(graph, 'recorder') if recorder.returncode == NODE_ERROR_EXIT_CODE else None
        if reported:
            raise RecorderError(reported)
        raise GraphRunError(f'the recorder node {_exit_text(recorder.returncode)}; its bag is not closed: '
                            f'rebuild it with `sofia recover {graph.bag_path}`; logs in {graph.workdir}')


def _unconnected_nodes(graph):
    """The nodes that have not logged their connection yet (read from their logs), or None while no node has logged
    its start."""
    started, unconnected = False, []
    for name in graph.processes:
        try:
            text = (graph.workdir / f'{name}.log').read_text(errors='replace')
        except OSError:
            text = ''
        started = started or STARTED_LOG in text
        if CONNECTED_LOG not in text:
            unconnected.append(name)
    return unconnected if started else None


def _dump_stacks(graph):
    """Have every running node write its Python stacks to its log (nodes.executables registers SIGUSR1)."""
    for process in graph.processes.values():
        if process.poll() is None:
            process.send_signal(signal.SIGUSR1)
    time.sleep(1.0)


def _bag_is_closed(graph):
    """Whether the recorder has closed the bag (BagWriter.close writes metadata.yaml last)."""
    return graph.bag_path is not None and (graph.bag_path / 'metadata.yaml').exists()


def _exit_text(returncode):
    """How a process ended, for an error line: 'exited with code 3', 'was killed by SIGSEGV'."""
    if returncode < 0:
        return f'was killed by {signal.Signals(-returncode).name}'
    return f'exited with code {returncode}'


def _last_log_line(graph, node):
    """The last line a node process logged (its stop reason, for the clock), or a note that it logged nothing."""
    try:
        lines = (graph.workdir / f'{node}.log').read_text(errors='replace').strip().splitlines()
    except OSError:
        lines = []
    return lines[-1] if lines else 'nothing logged'


def _reported_error(graph, node):
    """The reason of the last ``<node>: error: <reason>`` line in a node's log, or None."""
    prefix = f'{node}: error: '
    try:
        lines = (graph.workdir / f'{node}.log').read_text(errors='replace').splitlines()
    except OSError:
        return None
    return next((line[len(prefix):] for line in reversed(lines) if line.startswith(prefix)), None)


def stop_graph(graph):
    """SIGINT the graph's process group (the recorder closes its bag), kill stragglers, release the domain."""
    running = [process for process in graph.processes.values() if process.poll() is None]
    if running:
        first = next(iter(graph.processes.values()))
        try:
            os.killpg(first.pid, signal.SIGINT)
        except ProcessLookupError:
            for process in running:
                process.send_signal(signal.SIGINT)
    # One deadline for all: a wait of its own for each would let eleven stuck nodes hold the run for minutes.
    deadline = time.monotonic() + STOP_GRACE_S
    for process in graph.processes.values():
        try:
            process.wait(timeout=max(deadline - time.monotonic(), 0.0))
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()
    release_ros_domain(graph.domain)


def run_graph_in_processes(parameters: Mapping[str, Any], bag_path: str | os.PathLike[str], *,
                           timeout_s: float = 3600.0,
                           progress: Callable[[float | None, float], None] | None = None) -> GraphProcesses:
    """Each node as its own process (start_graph_processes); return the GraphProcesses after the recorder
    closed the bag.

    The node logs and params file are removed once the bag is closed; a run that fails (a GraphRunError, which
    names the folder, or a fault the clock stopped the run for) keeps them, unless the recorder reported the
    error itself (RecorderError: its reason is whole).
    """
    graph = start_graph_processes(parameters, bag_path)
    try:
        wait_for_graph(graph, timeout_s=timeout_s, progress=progress, max_sim_s=parameters['max_sim_s'])
    except GraphRunError as err:
        if isinstance(err, RecorderError):
            shutil.rmtree(graph.workdir, ignore_errors=True)
        raise
    except BaseException:
        # A second signal or a bug in this process: the nodes are down, their logs say nothing new.
        shutil.rmtree(graph.workdir, ignore_errors=True)
        raise
    if graph.processes['clock'].returncode != STALLED_EXIT_CODE:
        shutil.rmtree(graph.workdir, ignore_errors=True)
    return graph


def silent_nodes(graph):
    """The nodes whose process logged nothing (never got as far as its first line): names for a fault's error line."""
    logs = {name: graph.workdir / f'{name}.log' for name in graph.processes}
    return sorted(name for name, log in logs.items() if not log.exists() or not log.stat().st_size)
