"""Recorder node: every topic of the graph, raw, into a rosbag2 MCAP bag; closes when the run stops."""

from __future__ import annotations

from rcl_interfaces.msg import ParameterEvent
from rclpy.task import Future

from sofia_ros import messages as m
from sofia_ros.bag import BagWriter
from sofia_ros.bag.msgtypes import TYPESTORE
from sofia_ros.bag.timebase import leading_stamps_ns
from sofia_ros.errors import InvalidArgumentError, OutputError
from sofia_ros.nodes.shell import LockstepNode, decode_received, message_class
from sofia_ros.nodes.sync import DATA_QOS, SYNC_QOS, parse_stop
from sofia_ros.sim.runner import record_message
from sofia_ros.topics import PARAMETER_EVENTS, SAMPLE_BLOCKS, STOP_DOCUMENT

__all__ = ['RecorderNode']


def _canonical_cdr(cdr, msgtype):
    """The bytes direct mode writes for a message rclpy serialized (bag.wire_cdr): its padding zeroed (rmw_fastrtps
    leaves it uninitialised) and its length exact (between processes the payload arrives padded to 4 bytes)."""
    return TYPESTORE.serialize_cdr(decode_received(cdr, msgtype), msgtype, little_endian=True)


class RecorderNode(LockstepNode):
    """Records; reports done(k) once everything counted for tick k is in the bag."""

    def __init__(self, bag_path, graph_topics, participants, *, tick_ns, epoch_ns, documents=(), bus=None,
                 raise_bag_failures=True):
        """Record into a new bag at ``bag_path``; ``epoch_ns``: the campaign's start in UTC ns (BagWriter);
        ``bus``: as for LockstepNode.

        An OutputError of the bag (its disk full: BagWriter has aborted it) ends the recording: it is kept as
        ``failure`` and ``finished`` is set. ``raise_bag_failures``: True (a node process of its own) raises it
        out of the callback too, which ends the process with its one line (nodes.executables); False (under
        the caller's executor) leaves it to the caller, since rclpy reports an exception out of an executor's
        callback in a dozen lines on stderr first."""
        topics = {name: msgtype for name, (msgtype, publisher, _) in graph_topics.items() if publisher}
        # A sample topic arrives as its per-tick blocks (topics.SAMPLE_BLOCKS); the bag holds the samples.
        wires = {name: (SAMPLE_BLOCKS[name].name, SAMPLE_BLOCKS[name].msgtype) if name in SAMPLE_BLOCKS
                 else (name, msgtype) for name, msgtype in topics.items()}
        super().__init__('recorder', upstream=[(name, 0) for name in participants], tick_ns=tick_ns,
                         expected_inputs=[wire for wire, _ in wires.values()], bus=bus)
        self.bag = BagWriter(bag_path, epoch_ns=epoch_ns)
        self.bag.open()
        self.msgtypes = dict(topics)
        self.msgtypes[PARAMETER_EVENTS.name] = PARAMETER_EVENTS.msgtype
        for topic, msgtype in sorted(self.msgtypes.items()):
            # /clock is offered transient-local (nodes.sync.SYNC_QOS), the rest as DATA_QOS.
            self.bag.add_topic(topic, msgtype, latched=msgtype == 'rosgraph_msgs/msg/Clock')
        for topic, text in documents:
            self.bag.write_document(topic, text, 0)
        self.clock_ns = 0
        self.closed = False
        self.finished = Future()
        self.failure = None
        self._raise_bag_failures = raise_bag_failures
        for topic, (wire, msgtype) in wires.items():
            qos = SYNC_QOS if msgtype == 'rosgraph_msgs/msg/Clock' else DATA_QOS
            on_cdr = self._block_callback(topic, wire) if wire != topic else self._record_callback(topic)
            # Over DDS a publisher outside the graph can send a stamp the bag cannot hold; handed over in the process,
            # only the graph's own messages arrive (LockstepNode._warn_dropped, CoreNode._input_callbacks).
            self.subscribe_graph_topic(message_class(msgtype), wire, self._guarded(on_cdr, topic),
                                       self._guarded(self._message_callback(topic, wire)), qos)
        # rclpy publishes parameter events itself, over DDS in every mode.
        self.create_subscription(ParameterEvent, PARAMETER_EVENTS.name,
                                 self._guarded(self._parameter_event_callback({f'/{name}' for name in participants}),
                                               PARAMETER_EVENTS.name),
                                 DATA_QOS, raw=True)

    def _guarded(self, callback, topic=None):
        """``callback``, ending the recording on an OutputError of the bag (see __init__); a no-op after that. With a
        ``topic`` (a subscription over DDS), a message stamped on another clock than the graph's is dropped
        (LockstepNode._warn_dropped)."""
        def guarded(*args):
            if self.failure is not None:
                return
            try:
                callback(*args)
            except InvalidArgumentError as err:
                if topic is None:
                    raise
                # A wall-clock stamp (a publisher outside the graph, a replay) does not fit the bag's campaign time:
                # it stopped the recorder, and the run, with a traceback.
                self._warn_dropped(topic, err)
            except OutputError as err:
                if self.failure is None:  # a guarded callback can run inside another (a count that ends a tick)
                    self.failure = err
                    self.closed = True
                    self.finished.set_result(True)
                if self._raise_bag_failures:
                    raise
        return guarded

    def _message_callback(self, topic, wire):
        msgtype = self.msgtypes[topic]

        def callback(message):
            # Handed over in the process: recorded as direct mode records it.
            stamp_ns = record_message(self.bag, topic, msgtype, message, self.clock_ns)
            if msgtype == 'rosgraph_msgs/msg/Clock':
                self.clock_ns = stamp_ns
            self._count(wire)
        return callback

    def _record_callback(self, topic, counted=True):
        msgtype = self.msgtypes[topic]

        def callback(cdr):
            stamp_ns = m.log_stamp_ns(msgtype, cdr, self.clock_ns)
            if msgtype == 'rosgraph_msgs/msg/Clock':
                self.clock_ns = stamp_ns
            self.bag.write_raw(topic, _canonical_cdr(cdr, msgtype), stamp_ns)
            if counted:
                self._count(topic)
            else:
                self._close_if_complete()
        return callback

    def _parameter_event_callback(self, graph_nodes):
        record = self._record_callback(PARAMETER_EVENTS.name, False)

        def callback(cdr):
            # Only parameters set on a graph node, as direct mode records them. Every node's own declarations
            # (new_parameters, seen or not depending on start-up order) and any other node in the domain (the
            # executables' parameter readers, a user's tool; their stamps are wall time) stay out of the bag.
            event = decode_received(cdr, PARAMETER_EVENTS.msgtype)  # decoded once: recording re-serializes it
            if event.node in graph_nodes and event.changed_parameters and not (event.new_parameters
                                                                               or event.deleted_parameters):
                record(cdr)
        return callback

    def _block_callback(self, topic, block_topic):
        def callback(block):
            # Each sample its own record, at its own header stamp: the bag direct mode writes.
            rows = m.sample_rows_of_block_cdr(block)
            self.bag.write_rows(topic, rows, leading_stamps_ns(rows))
            self._count(block_topic)
        return callback

    def _count(self, topic):
        self.received[topic] += 1
        if self._requirements is not None and topic in self._requirements:
            self.try_ticks()
        self._close_if_complete()

    def extra_ready(self):
        # The clock starts the first tick on the recorder's done(0): it must mean that every node has connected.
        return all(state.latest_tick >= 0 for state in self.states.values())

    def run_tick(self, tick):
        self._guarded(self._finish_tick)(tick)

    def _finish_tick(self, tick):
        self.publish_done(tick)
        self._close_if_complete()

    def on_stop(self):
        self._guarded(self._record_stop)()

    def _record_stop(self):
        # Why the run ended goes into the bag too (a finished calibration, a stall, the time limit).
        self.bag.write_document(STOP_DOCUMENT.name, parse_stop(self.stop_reason)[2], self.clock_ns)
        self._close_if_complete()

    def tick_requirements(self, tick):
        # The recorder keeps recording after /sim/stop until the last tick is complete.
        stop, self.stop_reason = self.stop_reason, None
        try:
            return super().tick_requirements(tick)
        finally:
            self.stop_reason = stop

    def _close_if_complete(self):
        if self.closed or self.stop_reason is None:
            return
        last_tick, complete, _ = parse_stop(self.stop_reason)
        # A finished run is recorded to its last tick; an aborted one keeps what arrived up to the fault.
        if self.next_tick > last_tick or not complete:
            self.bag.close()
            self.closed = True
            self.finished.set_result(True)

    def abort(self):
        """Close what was recorded so far (SIGINT): a complete, readable bag."""
        if not self.closed:
            self.bag.close()
            self.closed = True
            self.finished.set_result(True)
