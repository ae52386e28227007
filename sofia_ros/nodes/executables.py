"""Entry points of the node executables (``ros2 run sofia_ros <name>``), one per entry of
graph_nodes.EXECUTABLES: clock, plant, gyro_box, imager (fpi/ffi/wfi by the ``camera`` parameter,
``ros2 run sofia_ros imager --ros-args -p camera:=fpi -r __node:=fpi``), hipo, tascu, calibration, recorder."""

from __future__ import annotations

import ctypes
import faulthandler
import os
import signal
import sys
from pathlib import Path

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.experimental import EventsExecutor
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rclpy.parameter import Parameter
from rclpy.qos import qos_profile_rosout_default

import sofia_ros
from sofia_ros.campaigns.graph_params import GRAPH_PARAMETERS, graph_config_from_parameters
from sofia_ros.errors import SofiaError
from sofia_ros.graph_nodes import EXECUTABLES, IMAGERS
from sofia_ros.nodes.clock_node import STALLED_EXIT_CODE
from sofia_ros.nodes.sync import parse_stop
from sofia_ros.topics import CLOCK

__all__ = ['main', *EXECUTABLES]


def _read_parameters(executable):
    """Graph parameters as given by --ros-args (params file or -p), with their defaults, and every plan.* given."""
    context = rclpy.get_default_context()
    # The overrides rcl resolves for this node's name (after any __node remap), read from a bare rcl node: an rclpy
    # Node would create and destroy DDS writers here, and Fast DDS 3.2 can deadlock destroying a writer while the
    # graph's other processes are still being discovered (seen: ~TimedEvent waiting forever, the node never up).
    with context.handle:
        reader = _rclpy.Node(f'{executable}_parameters', '', context.handle, None, True, False,
                             qos_profile_rosout_default.get_c_qos_profile())
        try:
            overrides = {name: parameter.value for name, parameter in reader.get_parameters(Parameter).items()}
        finally:
            reader.destroy_when_not_in_use()
    values = {name: default for name, (default, _) in GRAPH_PARAMETERS.items()}
    values['camera'] = ''
    values.update((name, overrides[name]) for name in list(values) if name in overrides)
    values.update((name, value) for name, value in overrides.items() if name.startswith('plan.'))
    return values


def _build(executable, values):
    from sofia_ros.bag.timebase import epoch_ns_of
    from sofia_ros.campaigns.recording import graph_documents
    from sofia_ros.config import load_effect_config
    from sofia_ros.nodes.clock_node import ClockNode
    from sofia_ros.nodes.shell import CoreNode
    from sofia_ros.sim.graph import build_core, build_cores, graph_topics

    config = graph_config_from_parameters(values)
    cores = build_cores(config)
    topics = graph_topics(cores)
    participants = [core.name for core in cores if core.name != 'clock']
    if executable == 'clock':
        return ClockNode([*participants, 'recorder'], tick_ns=config.tick_ns, max_sim_s=values['max_sim_s'],
                         stall_timeout_s=values['stall_timeout_s'], subscribers=len(topics[CLOCK.name][2]) + 1,
                         ending=[core.name for core in cores if core.ends_run])
    if executable == 'recorder':
        from sofia_ros.nodes.recorder_node import RecorderNode  # the bag writer: the recorder's process alone

        if not values['bag_path']:
            raise SofiaError('parameter bag_path is empty; pass -p bag_path:=bags/run1')
        model_text = load_effect_config(values['model_file']).text if values['model_file'] else None
        return RecorderNode(values['bag_path'], topics, [core.name for core in cores], tick_ns=config.tick_ns,
                            epoch_ns=epoch_ns_of(config.scenario.start_utc), documents=graph_documents(config, model_text))
    name = values['camera'] if executable == 'imager' else executable
    if executable == 'imager' and name not in IMAGERS:
        raise SofiaError(f"imager needs -p camera:={'|'.join(IMAGERS)}, got {name!r}")
    return CoreNode(build_core(name, config), graph_topics=topics, tick_ns=config.tick_ns)


def main(executable=None, argv=None):
    """Run one node until /sim/stop (or Ctrl-C); errors in its configuration exit with code 2. A process's entry
    point: once the node's run has stopped, SIGINT is ignored until the process exits."""
    argv = list(sys.argv if argv is None else argv)
    if executable is None:
        executable = argv.pop(1)
    # SIGUSR1 writes every thread's Python stack to stderr (the node's log): where a hung node hangs.
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    rclpy.init(args=argv)
    node = None
    try:
        try:
            node = _build(executable, _read_parameters(executable))
            # Which install runs is worth a line: a workspace can hold more than one sofia_ros. The launcher reads it
            # as the sign that the process is up (launch.STARTED_LOG).
            package_dir = Path(sofia_ros.__file__).parent
            node.get_logger().info(f'started from {package_dir}; waiting for the other nodes of the graph')
            # EventsExecutor: 3-10x the callback rate of the SingleThreadedExecutor.
            executor = EventsExecutor()
            executor.add_node(node)
            interrupted = []
            if executable == 'recorder':
                # A KeyboardInterrupt raised inside a write and the bag closed after it left that message counted
                # in the statistics but not indexed (a loaded machine: "the message indexes list 35 messages on
                # /clock, the statistics 40"): the recorder takes SIGINT between callbacks instead.
                signal.signal(signal.SIGINT, lambda signum, frame: interrupted.append(signum))
            while (node.stop_reason is None or (hasattr(node, 'closed') and not node.closed)) and not interrupted:
                executor.spin_once(timeout_sec=0.1)
        except SofiaError as err:
            print(f'{executable}: error: {err}', file=sys.stderr)
            return 2
        except (KeyboardInterrupt, ExternalShutdownException):
            pass
        except RuntimeError:
            # rclpy's SIGINT handler shut the context down while a callback of this spin was publishing (rcl:
            # "publisher's context is invalid"): that is the interruption, not a fault of the node.
            if rclpy.ok():
                raise
        finally:
            if node is not None and node.stop_reason is not None:
                # How the run ended is decided: the launcher's SIGINT, stopping the graph while this node tears
                # down its DDS entities, must not turn the clock's fault (exit 3) into an interruption.
                signal.signal(signal.SIGINT, signal.SIG_IGN)
            if node is not None and hasattr(node, 'abort'):
                node.abort()
            rclpy.try_shutdown()
    except KeyboardInterrupt:
        # A second SIGINT cut the teardown short (the recorder may not have closed its bag): not a clean end,
        # unless the run had stopped and how it ended is decided.
        if node is None or node.stop_reason is None:
            return 128 + signal.SIGINT
    return _exit_code(executable, node)


def _exit_code(executable, node):
    """0, or for the clock STALLED_EXIT_CODE when it stopped the run for a fault (a stall) rather than its end."""
    stopped = node is not None and node.stop_reason is not None
    return STALLED_EXIT_CODE if executable == 'clock' and stopped and not parse_stop(node.stop_reason)[1] else 0


def __getattr__(name):
    """The console-script entry point of each executable of graph_nodes.EXECUTABLES (``ros2 run sofia_ros <name>``)."""
    if name not in EXECUTABLES:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')

    def entry_point():
        _exit_at_once(main(name))

    entry_point.__name__ = entry_point.__qualname__ = name
    entry_point.__doc__ = f'ros2 run sofia_ros {name}'
    return entry_point


def _exit_at_once(code):
    """End the node's process with ``code`` once main() has returned, without the interpreter's teardown.

    The run is over and rclpy is shut down; unloading numpy, scipy and rclpy is all that is left, and in a
    --processes graph its eleven processes did it at once: they exited 2.5-4.5 s after the run's stop at load 7-10,
    0.2-0.6 s without it. Python's and C's output buffers (the node's log) are flushed first.
    """
    sys.stdout.flush()
    sys.stderr.flush()
    ctypes.CDLL(None).fflush(None)
    os._exit(code)


if __name__ == '__main__':
    _exit_at_once(main())
