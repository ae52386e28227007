"""Run a campaign's node graph over DDS: all nodes in one process under an executor, or one process each."""

from __future__ import annotations

import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import rclpy
from rclpy.logging import LoggingSeverity
from rclpy.experimental import EventsExecutor

from sofia_ros.bag.timebase import epoch_ns_of
from sofia_ros.errors import SofiaError
from sofia_ros.nodes.clock_node import ClockNode
from sofia_ros.nodes.graph_params import graph_parameters, write_params_file
from sofia_ros.nodes.recorder_node import RecorderNode
from sofia_ros.nodes.shell import CoreNode
from sofia_ros.nodes.sync import parse_stop
from sofia_ros.sim.graph import build_cores, graph_topics

__all__ = ['isolate_ros_environment', 'run_graph_in_process', 'run_graph_in_processes', 'start_graph_processes',
           'wait_for_graph', 'stop_graph', 'GraphProcesses', 'GraphRunError']


class GraphRunError(SofiaError):
    """The live graph did not finish (stall, crash or wall-clock timeout)."""


def isolate_ros_environment(domain_id=None):
    """Keep DDS traffic on this machine and, unless given, in a random domain of its own."""
    os.environ.setdefault('ROS_AUTOMATIC_DISCOVERY_RANGE', 'LOCALHOST')
    if domain_id is not None:
        os.environ['ROS_DOMAIN_ID'] = str(domain_id)
    os.environ.setdefault('ROS_DOMAIN_ID', str(random.randint(1, 101)))


def _participants(cores):
    return [core.name for core in cores if core.name != 'clock']


def run_graph_in_process(config, bag_path, *, documents=(), max_sim_s=7200.0, timeout_s=3600.0, progress=None):
    """All nodes in one process under one executor; return the calibration core and the stop reason."""
    isolate_ros_environment()
    rclpy.init()
    try:
        cores = build_cores(config)
        topics = graph_topics(cores)
        nodes = [CoreNode(core, graph_topics=topics, tick_ns=config.tick_ns) for core in cores if core.name != 'clock']
        clock_subscribers = len(topics['/clock'][2]) + 1
        clock = ClockNode([*_participants(cores), 'recorder'], tick_ns=config.tick_ns, max_sim_s=max_sim_s,
                          subscribers=clock_subscribers)
        recorder = RecorderNode(bag_path, topics, [core.name for core in cores], tick_ns=config.tick_ns,
                                epoch_ns=epoch_ns_of(config.scenario.start_utc), documents=documents)
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
            # The executor's own loop: no return to Python between callbacks.
            executor.spin_until_future_complete(recorder.finished, timeout_sec=timeout_s)
            if not recorder.closed:
                raise GraphRunError(f'the graph did not finish within {timeout_s:g} s of wall time')
        finally:
            recorder.abort()
        calibration = next(node.core for node in nodes if node.core.name == 'calibration')
        reason = parse_stop(clock.stop_reason)[2] if clock.stop_reason else ''
        for node in (*nodes, clock, recorder):
            node.destroy_node()
        return calibration, reason
    finally:
        rclpy.try_shutdown()


@dataclass
class GraphProcesses:
    """The node processes of one run and the folder with their params file and logs."""

    processes: dict
    workdir: Path


def start_graph_processes(truth_file, seed, plan, bag_path, *, tick_ns, max_sim_s=7200.0, stall_timeout_s=15.0,
                          model_file=''):
    """Start every node as its own process (what `ros2 run` gives), sharing one params file."""
    isolate_ros_environment()
    workdir = Path(tempfile.mkdtemp(prefix='sofia_graph_'))
    params = workdir / 'params.yaml'
    values = graph_parameters(truth_file, seed, plan, tick_ns=tick_ns, max_sim_s=max_sim_s, bag_path=bag_path,
                              stall_timeout_s=stall_timeout_s, model_file=model_file)
    write_params_file(params, values)
    executables = [('clock', 'clock', ()), ('plant', 'plant', ()), ('gyro_box', 'gyro_box', ()),
                   ('hipo', 'hipo', ()), ('tascu', 'tascu', ()), ('calibration', 'calibration', ()),
                   ('recorder', 'recorder', ()),
                   *((camera, 'imager', ('-r', f'__node:={camera}', '-p', f'camera:={camera}'))
                     for camera in ('fpi', 'ffi', 'wfi'))]
    processes = {}
    for name, executable, extra in executables:
        with open(workdir / f'{name}.log', 'w') as log:
            processes[name] = subprocess.Popen(
                [sys.executable, '-m', 'sofia_ros.nodes.executables', executable, '--ros-args', '--params-file',
                 str(params), *extra], stdout=log, stderr=subprocess.STDOUT, env=os.environ.copy())
    return GraphProcesses(processes, workdir)


def wait_for_graph(graph, *, timeout_s=3600.0, progress=None, max_sim_s=None):
    """Wait until the recorder has closed the bag; then stop every remaining node."""
    start = time.monotonic()
    try:
        while graph.processes['recorder'].poll() is None:
            time.sleep(0.2)
            if progress is not None:
                progress(None, max_sim_s)
            if time.monotonic() - start > timeout_s:
                raise GraphRunError(f'the graph did not finish within {timeout_s:g} s of wall time; '
                                    f'logs in {graph.workdir}')
    finally:
        stop_graph(graph)


def stop_graph(graph):
    """SIGINT every node still running (the recorder closes its bag), then kill stragglers."""
    for process in graph.processes.values():
        if process.poll() is None:
            process.send_signal(signal.SIGINT)
    for process in graph.processes.values():
        try:
            process.wait(timeout=10)
        except subprocess.TimeoutExpired:
            process.kill()
            process.wait()


def run_graph_in_processes(truth_file, seed, plan, bag_path, *, tick_ns, max_sim_s=7200.0, timeout_s=3600.0,
                           stall_timeout_s=15.0, model_file='', progress=None):
    """Each node as its own process; return the GraphProcesses after the recorder closed the bag.

    The node logs and params file are removed once the bag is closed; a run that fails keeps
    them, and its GraphRunError names the folder.
    """
    graph = start_graph_processes(truth_file, seed, plan, bag_path, tick_ns=tick_ns, max_sim_s=max_sim_s,
                                  stall_timeout_s=stall_timeout_s, model_file=model_file)
    wait_for_graph(graph, timeout_s=timeout_s, progress=progress, max_sim_s=max_sim_s)
    shutil.rmtree(graph.workdir, ignore_errors=True)
    return graph
