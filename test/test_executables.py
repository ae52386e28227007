"""nodes.executables.main around a node's spin: a publish cut short by SIGINT's shutdown is the interruption.

rclpy's SIGINT handler shuts the context down at once; a callback already running in that spin then fails to
publish ("publisher's context is invalid"). Seen in the processes-mode SIGINT test: the recorder closed its bag
but exited 1 with a traceback. The node and its executor are stand-ins; rclpy's context is real.
"""

import logging

import pytest
import rclpy
from rclpy.impl.implementation_singleton import rclpy_implementation

from sofia_ros.nodes import executables

_INVALID_CONTEXT = "Failed to publish: publisher's context is invalid, at /project/src/rcl/publisher.c:427"


class _Recorder:
    """A recorder-like node: stop_reason, closed and abort() as main() uses them."""

    stop_reason = None
    closed = False

    def __init__(self):
        self.aborted = False

    def get_logger(self):
        return logging.getLogger('test_executables')

    def abort(self):
        self.aborted = self.closed = True


def _run_main(monkeypatch, *, shut_down_first):
    """main('recorder') over a stand-in node whose first spin fails to publish; (exit code, the node)."""
    node = _Recorder()

    class Executor:
        def add_node(self, _node):
            pass

        def spin_once(self, timeout_sec):
            if shut_down_first:
                rclpy.shutdown()  # as rclpy's SIGINT handler does
            raise rclpy_implementation.RCLError(_INVALID_CONTEXT)

    monkeypatch.setattr(executables, '_read_parameters', lambda executable: {})
    monkeypatch.setattr(executables, '_build', lambda executable, values: node)
    monkeypatch.setattr(executables, 'EventsExecutor', Executor)
    try:
        return executables.main('recorder', ['recorder']), node
    finally:
        rclpy.try_shutdown()


def test_a_publish_cut_short_by_the_shutdown_ends_the_node_cleanly(monkeypatch):
    code, node = _run_main(monkeypatch, shut_down_first=True)
    assert code == 0 and node.aborted


def test_the_same_failure_with_the_context_up_is_raised(monkeypatch):
    with pytest.raises(rclpy_implementation.RCLError, match="publisher's context is invalid"):
        _run_main(monkeypatch, shut_down_first=False)
