"""Lock-step runner: drives the node cores directly in one loop and records every message.

This is the graph without DDS, for fast campaigns, Monte Carlo studies and tests. The
cores and the order of their ticks are the same as over DDS (see protocol.py).
"""

from __future__ import annotations

from sofia_ros import messages as m
from sofia_ros.bag import wire_cdr
from sofia_ros.errors import ConfigError
from sofia_ros.sim.protocol import SET_PARAMETERS, ParameterResult
from sofia_ros.topics import PARAMETER_EVENTS

__all__ = ['LockstepRunner', 'tick_order', 'record_message']


def tick_order(cores):
    """Cores sorted so that every same-tick (lag 0) upstream core ticks first."""
    by_name = {core.name: core for core in cores}
    ordered, visiting, done = [], set(), set()

    def visit(core):
        if core.name in done:
            return
        if core.name in visiting:
            raise ConfigError(f'lag-0 dependency cycle through {core.name}')
        visiting.add(core.name)
        for upstream, lag in core.upstream:
            if lag == 0 and upstream in by_name:
                visit(by_name[upstream])
        visiting.discard(core.name)
        done.add(core.name)
        ordered.append(core)

    for core in cores:
        visit(core)
    return ordered


class LockstepRunner:
    """Ticks the cores in dependency order and routes their messages to subscribers and the bag."""

    def __init__(self, cores, *, tick_ns, bag=None):
        self.cores = tick_order(cores)
        self.tick_ns = tick_ns
        self.bag = bag
        self.by_name = {core.name: core for core in self.cores}
        self.stamp_ns = 0
        self.subscribers = {}
        self.msgtypes = {}
        for core in self.cores:
            for spec in core.inputs():
                self.subscribers.setdefault(spec.name, []).append(core)
            for spec in core.outputs():
                self.msgtypes[spec.name] = spec.msgtype
        self.msgtypes[PARAMETER_EVENTS.name] = PARAMETER_EVENTS.msgtype
        if bag is not None:
            for topic, msgtype in sorted(self.msgtypes.items()):
                # As over DDS: /clock is offered transient-local, the rest reliable and volatile.
                bag.add_topic(topic, msgtype, latched=msgtype == 'rosgraph_msgs/msg/Clock')

    def step(self):
        """Advance one tick; return its stamp in ns."""
        self.stamp_ns += self.tick_ns
        for core in self.cores:
            for topic, message in core.tick(self.stamp_ns):
                if topic == SET_PARAMETERS:
                    core.receive(topic, self._set_parameters(message))
                    continue
                self._record(topic, message)
                for subscriber in self.subscribers.get(topic, ()):
                    subscriber.receive(topic, message)
        return self.stamp_ns

    def run(self, *, until_ns=None, stop=None):
        """Step until ``until_ns`` or until ``stop()`` is true; return the final stamp."""
        while (until_ns is None or self.stamp_ns < until_ns) and not (stop is not None and stop()):
            self.step()
        return self.stamp_ns

    def _set_parameters(self, request):
        """Apply a ParameterRequest to its node, as its parameter service would; record the event."""
        target = self.by_name.get(request.node)
        reasons = {}
        for name, value in request.values.items():
            try:
                if target is None:
                    raise ConfigError(f'no node {request.node!r} in the graph')
                target.set_parameter(name, value)
                reasons[name] = ''
            except ConfigError as err:
                reasons[name] = str(err)
        for name, value in request.values.items():
            # One event per parameter, as rclpy's set_parameters service publishes them over DDS.
            if not reasons[name]:
                self._record(PARAMETER_EVENTS.name, m.parameter_event(self.stamp_ns, request.node, {name: value}))
        return ParameterResult(request.node, reasons)

    def _record(self, topic, message):
        if self.bag is not None:
            record_message(self.bag, topic, self.msgtypes[topic], message, self.stamp_ns)


def record_message(bag, topic, msgtype, message, fallback_ns):
    """Write a published message as a raw subscription receives it (an ImuBlock one record per sample, at its
    stamp), logged at its own stamp or else ``fallback_ns``; return the log stamp of its last record."""
    if isinstance(message, m.ImuBlock):
        # The samples' stamps written in UTC at once, not in campaign time and then moved (BagWriter.epoch_ns).
        bag.write_rows(topic, m.imu_block_rows(message, bag.epoch_ns), message.stamp_ns, utc_stamps=True)
        return int(message.stamp_ns[-1]) if len(message) else fallback_ns
    cdr = wire_cdr(message)
    stamp_ns = m.log_stamp_ns(msgtype, cdr, fallback_ns)
    bag.write_raw(topic, cdr, stamp_ns)
    return stamp_ns
