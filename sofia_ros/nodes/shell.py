"""The generic rclpy shell around a lock-step core (protocol in sofia_ros.sim.protocol, nodes.sync)."""

from __future__ import annotations

import importlib
import struct
from collections import Counter
from functools import lru_cache

from rcl_interfaces.msg import ParameterDescriptor, SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.parameter_client import AsyncParameterClient
from std_msgs.msg import String

from sofia_ros import messages as m
from sofia_ros.bag.msgtypes import decode_cdr
from sofia_ros.errors import ConfigError, SofiaError
from sofia_ros.nodes.intra_process import publish_outside
from sofia_ros.nodes.sync import (DATA_QOS, OUTSIDE_QOS, STOP_TOPIC, SYNC_QOS, DoneReport, UpstreamState, done_text,
                                  done_topic, parse_done_text, parse_stop)
from sofia_ros.sim.protocol import SET_PARAMETERS, ParameterResult
from sofia_ros.topics import SAMPLE_BLOCKS

__all__ = ['message_class', 'decode_received', 'LockstepNode', 'CoreNode']


def message_class(msgtype):
    """The rclpy message class of a type string like 'sensor_msgs/msg/Imu'."""
    package, _, name = msgtype.split('/')
    return getattr(importlib.import_module(f'{package}.msg'), name)


@lru_cache(maxsize=256)
def decode_received(cdr, msgtype):
    """A received message's CDR decoded once per process: under one executor every DDS subscriber of a topic,
    the recorder among them, gets the same bytes. The message is shared, as direct mode shares it: read it,
    never change it."""
    return decode_cdr(cdr, msgtype)


class LockstepNode(Node):
    """A node that takes part in the tick handshake: waits for its upstream, reports done(k)."""

    def __init__(self, name, *, upstream, tick_ns, expected_inputs=(), expected_outputs=None, bus=None):
        """``bus``: the graph's nodes.intra_process.IntraProcessBus when they share this process, else every message
        travels over DDS."""
        super().__init__(name, parameter_overrides=[Parameter('use_sim_time', value=True)])
        self.bus = bus
        self.tick_ns = tick_ns
        self.upstream = dict(upstream)
        self.states = {node: UpstreamState() for node in self.upstream}
        self._upstream_states = [(self.states[node], lag) for node, lag in self.upstream.items()]
        self.received = Counter()
        self.published = Counter()
        self.next_tick = 1
        self.ready = False
        self.stop_reason = None
        self.expected_inputs = tuple(expected_inputs)
        # On a bus messages arrive in publish order, so whatever a report counts has arrived before it: none is counted.
        self._counted_inputs = frozenset() if bus is not None else frozenset(self.expected_inputs)
        self._requirements = None  # what the next tick still waits for, once every report is in
        self.expected_outputs = dict(expected_outputs or {})  # topic -> number of subscribers
        self.publishers_by_topic = {}
        self._dropped_topics = set()  # topics a message was dropped from (_warn_dropped)
        self.done_topic = done_topic(name)
        self.done_publisher = self.create_publisher(String, self.done_topic, SYNC_QOS)
        self.create_subscription(String, STOP_TOPIC, self._on_stop, SYNC_QOS)
        for node in self.upstream:
            self.subscribe_graph_topic(String, done_topic(node), *self._done_callbacks(node), SYNC_QOS)
        self._ready_timer = self.create_timer(0.05, self._check_ready, clock=self._wall_clock())

    def _wall_clock(self):
        from rclpy.clock import Clock, ClockType

        return Clock(clock_type=ClockType.STEADY_TIME)

    # --- topics of the graph: over DDS, or handed over in the process --------------------------
    def subscribe_graph_topic(self, message_type, topic, on_cdr, on_message, qos):
        """Subscribe to a topic of the graph: ``on_cdr`` takes its CDR from DDS, or, on a bus, ``on_message`` the
        published object (no DDS subscription: the executor would have to take and drop a copy of each message
        a listener outside makes DDS carry). Returns the handle :meth:`unsubscribe_graph_topic` takes."""
        if self.bus is None:
            return self.create_subscription(message_type, topic, on_cdr, qos, raw=True), topic, None
        self.bus.subscribe(topic, on_message, qos)
        return None, topic, on_message

    def unsubscribe_graph_topic(self, handle):
        """Undo :meth:`subscribe_graph_topic`."""
        subscription, topic, on_message = handle
        if subscription is None:
            self.bus.unsubscribe(topic, on_message)
        else:
            self.destroy_subscription(subscription)

    def _send(self, publisher, topic, message, wire=None):
        """Publish ``message`` (over DDS as ``wire(message)`` when given), or hand it to the bus."""
        if self.bus is None:
            publisher.publish(message if wire is None else wire(message))
        else:
            self.bus.publish(publisher, topic, message, wire)

    # --- handshake -----------------------------------------------------------------------------
    def _done_callbacks(self, node):
        """(from CDR, from the message) callbacks of ``node``'s done reports."""
        state, lag = self.states[node], self.upstream.get(node)

        def on_report(report):
            state.announce(*report)
            # Only the report the next tick waits for can let it run; requirements already worked out stand.
            if lag is not None and report[0] == self.next_tick - lag:
                self.try_ticks()
        def on_cdr(cdr):
            try:
                report = _parse_done(cdr)
            except (ValueError, UnicodeDecodeError) as err:  # not a report a node sent: it killed the node
                self._warn_dropped(done_topic(node), err)
                return
            on_report(report)
        return on_cdr, on_report

    def _warn_dropped(self, topic, err):
        """One warning a topic for a message dropped because it could not be taken (a publisher outside the graph)."""
        if topic not in self._dropped_topics:
            self._dropped_topics.add(topic)
            self.get_logger().warning(f'dropped a message on {topic}: {type(err).__name__}: {err} (the next such '
                                      'messages are dropped without a word)')

    def _on_stop(self, message):
        try:
            last_tick, _, reason = parse_stop(message.data)
        except ValueError as err:  # not a stop the clock sent: it killed every node
            self._warn_dropped(STOP_TOPIC, err)
            return
        self.stop_reason = message.data
        self._requirements = None
        self.get_logger().info(f'stop after tick {last_tick}: {reason}')
        self.on_stop()

    def on_stop(self):
        """Called when /sim/stop arrives."""

    def _check_ready(self):
        if self.ready:
            return
        inputs_ok = all(self.count_publishers(topic) > 0 for topic in self.expected_inputs)
        # On a bus the subscribers in the process have no DDS subscriptions to match: the bus reaches them.
        outputs_ok = self.bus is not None or all(self._matched_subscriptions(topic) >= count
                                                 for topic, count in self.expected_outputs.items())
        if inputs_ok and outputs_ok and self.extra_ready():
            self.ready = True
            self._ready_timer.cancel()
            self.get_logger().info('connected; waiting for ticks')
            self.publish_done(0)
            self.try_ticks()

    def _matched_subscriptions(self, topic):
        """Subscriptions this node's publisher of ``topic`` is matched with: the graph's count (count_subscribers)
        can see a subscription before the DDS writer has matched its reader, and a volatile message written in
        between never reaches it (a node then waits on tick 1 for good)."""
        publisher = self.publishers_by_topic.get(topic)
        return publisher.get_subscription_count() if publisher is not None else self.count_subscribers(topic)

    def extra_ready(self):
        """Subclasses add conditions (e.g. services available) before the first done(0)."""
        return True

    def tick_requirements(self, tick):
        """{topic: count} to receive before tick ``tick``, or None while an upstream report is missing."""
        if not self.ready or self.stop_reason is not None:
            return None
        reports = []
        # Every report first: until the last one is in (each arriving report calls this) no counts are merged.
        for state, lag in self._upstream_states:
            # done(0) means connected: nothing starts before every upstream node is.
            report = state.reports.get(tick - lag) if tick >= lag else {}
            if report is None:
                return None
            reports.append(report)
        inputs = self.counted_inputs()
        needed_counts = {}
        for report in reports:
            for topic in inputs & report.keys():
                needed_counts[topic] = report[topic]
        return needed_counts

    def counted_inputs(self):
        """Topics this node subscribes to and counts."""
        return self._counted_inputs

    def try_ticks(self):
        """Run every tick that has become possible."""
        while not self.busy():
            if self._requirements is None:
                self._requirements = self.tick_requirements(self.next_tick)
                if self._requirements is None:
                    return
            if any(self.received[topic] < count for topic, count in self._requirements.items()):
                return
            self._requirements = None
            tick = self.next_tick
            self.next_tick += 1
            self.run_tick(tick)

    def busy(self):
        """True while an asynchronous part of the last tick (a service call) is still open."""
        return False

    def run_tick(self, tick):
        """Work of one tick; must end with publish_done(tick) (possibly later)."""
        self.publish_done(tick)

    def publish_done(self, tick, finished=False, failed=''):
        """Report done(tick) with cumulative counts of everything published."""
        # On a bus the report itself is handed over; its text only goes out over DDS (';' separates its fields).
        report = DoneReport(tick, dict(self.published), bool(finished), failed.replace(';', ','))
        self._send(self.done_publisher, self.done_topic, report, wire=_done_message)

    def publish(self, topic, message, wire=None):
        """Publish on an output topic (over DDS as ``wire(message)`` when given), counting messages."""
        self._send(self.publishers_by_topic[topic], topic, message, wire)
        self.published[topic] += 1


_CDR_STRING_LENGTH = struct.Struct('<I')


@lru_cache(maxsize=64)
def _parse_done(cdr):
    """The DoneReport of a done report's std_msgs/String CDR; in one process several nodes
    read each report, so it is parsed once (the counts mapping is shared: read it, never change it)."""
    length, = _CDR_STRING_LENGTH.unpack_from(cdr, 4)
    return parse_done_text(cdr[8:7 + length].decode())


def _done_message(report):
    """The std_msgs/String a done report travels as over DDS."""
    return String(data=done_text(report))


class CoreNode(LockstepNode):
    """A ROS-free core (sofia_ros.sim) behind topics, parameters and the handshake."""

    def __init__(self, core, *, graph_topics, tick_ns, upstream=None, bus=None):
        names = {node for _, (_, publisher, subscribers) in graph_topics.items() for node in (publisher, *subscribers)}
        upstream = upstream if upstream is not None else [(n, lag) for n, lag in core.upstream if n in names]
        # A sample topic (topics.SAMPLE_BLOCKS) is waited for, counted and sent as its per-tick blocks.
        inputs = [_wire(spec).name for spec in core.inputs()
                  if graph_topics.get(spec.name, (None, None))[1] is not None]
        outputs = {_wire(spec).name: len(graph_topics[spec.name][2]) + 1 for spec in core.outputs()}  # + recorder
        super().__init__(core.name, upstream=upstream, tick_ns=tick_ns, expected_inputs=inputs,
                         expected_outputs=outputs, bus=bus)
        self.core = core
        self.pending_calls = 0
        self.tick_in_progress = None
        for spec in core.inputs():
            wire = _wire(spec)
            if wire.name in inputs:
                # /clock is transient-local: a reader that matches late still gets the current tick.
                qos = SYNC_QOS if spec.msgtype == 'rosgraph_msgs/msg/Clock' else DATA_QOS
                self.subscribe_graph_topic(message_class(wire.msgtype), wire.name,
                                           *self._input_callbacks(spec, wire.name), qos)
        self.sample_publishers = {}
        output_qos = DATA_QOS if bus is None else OUTSIDE_QOS
        for spec in core.outputs():
            wire = _wire(spec)
            self.publishers_by_topic[wire.name] = self.create_publisher(message_class(wire.msgtype), wire.name,
                                                                        output_qos)
            if wire is not spec:
                self.sample_publishers[spec.name] = self.create_publisher(message_class(spec.msgtype), spec.name,
                                                                          OUTSIDE_QOS)
        self.parameter_clients = {}
        if hasattr(core, 'parameters'):
            self._declare_core_parameters()
        for target in core.parameter_targets:
            self.parameter_clients[target] = AsyncParameterClient(self, target)

    def extra_ready(self):
        return all(client.services_are_ready() for client in self.parameter_clients.values())

    def _declare_core_parameters(self):
        for name, (value, description) in self.core.parameters().items():
            self.declare_parameter(name, value, ParameterDescriptor(description=description))
        for name in self.core.parameters():
            self.core.set_parameter(name, self.get_parameter(name).value)
        self.add_on_set_parameters_callback(self._on_set_parameters)

    def _on_set_parameters(self, parameters):
        for parameter in parameters:
            if parameter.name == 'use_sim_time':
                if parameter.value is not True:
                    # Off the graph's /clock, the node stamped wall time, which stopped the recorder.
                    return SetParametersResult(successful=False, reason='the graph runs on /clock: use_sim_time stays '
                                                                        'true')
                continue
            try:
                self.core.set_parameter(parameter.name, parameter.value)
            except ConfigError as err:
                return SetParametersResult(successful=False, reason=str(err))
        return SetParametersResult(successful=True)

    def _input_callbacks(self, spec, wire_topic):
        """(from CDR, from the message) callbacks of an input."""
        topic, msgtype, block = spec.name, spec.msgtype, spec.name == self.core.imu_block_input

        def on_message(message):
            self.received[wire_topic] += 1
            self.core.receive(topic, message)
            if self._requirements is not None and wire_topic in self._requirements:
                self.try_ticks()

        def on_cdr(cdr):
            # Over DDS every input arrives raw: a tick's samples in one block that reaches the core as one
            # ImuBlock, the rest decoded by the typestore (2-4x faster than rclpy's own conversion).
            message = (m.imu_block_from_cdr('gyrf', m.samples_of_block_cdr(cdr)) if block
                       else decode_received(cdr, msgtype))
            try:
                on_message(message)
            except (SofiaError, ValueError, KeyError, TypeError, IndexError) as err:
                # Over DDS a publisher outside the graph can send what no node of it would (NaN, a coarse drive
                # beyond its range, a frame no camera has): dropped with one warning a topic; it killed the node,
                # and the run. Handed over in the process, only the graph's own messages arrive: an error there
                # is a fault and stops the run.
                self._warn_dropped(topic, err)
        return on_cdr, on_message

    def busy(self):
        return self.pending_calls > 0

    def run_tick(self, tick):
        self.tick_in_progress = tick
        for topic, message in self.core.tick(tick * self.tick_ns):
            if topic == SET_PARAMETERS:
                self._call_set_parameters(message)
            elif isinstance(message, m.ImuBlock):
                sample_publisher = self.sample_publishers[topic]
                wire = _sample_block_cdr
                # One message per sample only for a listener outside the graph (ros2 topic echo, bag record).
                if sample_publisher.get_subscription_count():
                    samples = m.imu_block_cdr(message)
                    for sample in samples:
                        publish_outside(sample_publisher, sample)
                    wire = lambda _: m.sample_block_cdr(samples)  # noqa: E731 (serialized once)
                self.publish(SAMPLE_BLOCKS[topic].name, message, wire=wire)
            else:
                self.publish(topic, message)
        if not self.pending_calls:
            self._finish_tick()

    def _finish_tick(self):
        outcome = self.core.outcome
        self.publish_done(self.tick_in_progress, outcome.finished, outcome.reason if outcome.failed else '')

    def _call_set_parameters(self, request):
        client = self.parameter_clients[request.node]
        parameters = [Parameter(name, value=_parameter_value(value)) for name, value in request.values.items()]
        self.pending_calls += 1

        def on_response(future):
            results = future.result().results
            reasons = {name: '' if result.successful else result.reason
                       for name, result in zip(request.values, results)}
            self.core.receive(SET_PARAMETERS, ParameterResult(request.node, reasons))
            self.pending_calls -= 1
            if not self.pending_calls:
                self._finish_tick()
                self.try_ticks()

        client.set_parameters(parameters, callback=on_response)


def _sample_block_cdr(block):
    """An ImuBlock as its block topic carries it over DDS, serialized by struct: the bytes DDS would make, at a
    tenth of the cost."""
    return m.sample_block_cdr(m.imu_block_cdr(block))


def _wire(spec):
    """The TopicSpec a topic travels on between the graph's nodes: its block topic for a sample topic."""
    return SAMPLE_BLOCKS.get(spec.name, spec)


def _parameter_value(value):
    """rclpy needs homogeneous, typed parameter values."""
    if isinstance(value, (list, tuple)):
        return [float(item) for item in value]
    return value
