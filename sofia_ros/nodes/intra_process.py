"""Intra-process hand-over between the graph's nodes in one process, as rclcpp's intra-process communication.

A message one node publishes on a graph topic reaches the other nodes of the process as the object itself, in
publish order,
never inside the publishing callback: the bus queues it, and the run's loop hands the queue over
(:meth:`IntraProcessBus.deliver`) between turns of the executor, which keeps serving timers, services and
DDS. Every publisher is on DDS, and DDS carries a message only when a subscription outside the process has
matched it (``ros2 topic echo``, a user's own recorder), so what leaves the process is what it was. The
subscriptions the bus serves are not on DDS: the executor would take and drop a copy of every message such a
listener makes DDS carry (``ros2 topic info`` counts only the subscribers outside). ``/sim/stop``, the
parameter services and ``/parameter_events`` stay on DDS inside the process too: rare, and rclpy's own.
"""

from __future__ import annotations

import time
from collections import deque

from rclpy.impl.implementation_singleton import rclpy_implementation
from rclpy.logging import get_logger
from rclpy.qos import DurabilityPolicy

__all__ = ['REFUSED_WRITE', 'IntraProcessBus', 'publish_outside']


#: How rmw_fastrtps words a write that DDS refused (a reliable reader outside that does not keep up).
REFUSED_WRITE = 'cannot publish data'


def publish_outside(publisher, message):
    """Publish to subscriptions outside the graph only (a publisher with nodes.sync.OUTSIDE_QOS): a listener
    that cannot keep up loses the message, with one warning per topic, and the graph goes on."""
    try:
        publisher.publish(message)
    except rclpy_implementation.RCLError as err:
        if REFUSED_WRITE not in str(err):
            raise
        _warn_of_a_slow_listener(publisher.topic_name, str(err))


_WARNED_TOPICS = set()


def _warn_of_a_slow_listener(topic, error):
    if topic in _WARNED_TOPICS:
        return
    _WARNED_TOPICS.add(topic)
    get_logger('sofia_ros').warning(f'a listener outside the graph does not keep up with {topic} ({error}): what '
                                    f'it cannot take is dropped for it (the graph and its bag go on)')


class IntraProcessBus:
    """Topic -> the in-process callbacks of one graph; the messages published, queued in publish order."""

    def __init__(self):
        self._callbacks = {}  # topic -> [callback(message)]
        self._latest = {}  # topic -> the last message published on it, for transient-local late subscribers
        self._pending = deque()  # (callback, message) in publish order
        self._listened = {}  # publisher -> whether a subscription outside has matched it, learnt once a time slice

    def subscribe(self, topic, callback, qos):
        """Hand ``callback`` every message published on ``topic`` from now on; with a transient-local ``qos`` the
        last one published before too, as DDS would."""
        self._callbacks.setdefault(topic, []).append(callback)
        if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL and topic in self._latest:
            self._pending.append((callback, self._latest[topic]))

    def unsubscribe(self, topic, callback):
        """Stop handing ``topic`` to ``callback`` (what is queued for it still arrives)."""
        self._callbacks[topic].remove(callback)

    def subscriptions(self, topic):
        """How many in-process callbacks take ``topic``."""
        return len(self._callbacks.get(topic, ()))

    def publish(self, publisher, topic, message, wire=None):
        """Queue ``message`` for every in-process subscriber of ``topic``; over DDS (``wire(message)``, or the
        message itself) only when a subscription outside the process has matched ``publisher`` (the ones the bus
        serves are not on DDS)."""
        self._latest[topic] = message
        listened = self._listened.get(publisher)
        if listened is None:
            listened = self._listened[publisher] = publisher.get_subscription_count() > 0
        if listened:
            publish_outside(publisher, message if wire is None else wire(message))
        pending = self._pending
        for callback in self._callbacks.get(topic, ()):
            pending.append((callback, message))

    @property
    def pending(self):
        """Whether messages wait to be handed over."""
        return bool(self._pending)

    def deliver(self, max_s):
        """Hand the queued messages over one at a time, with what they cause, for at most about ``max_s`` (then
        the executor's turn); return whether messages still wait. A listener outside that matched a publisher
        meanwhile hears from it from this slice on."""
        self._listened.clear()
        pending = self._pending
        deadline = time.perf_counter() + max_s
        while pending:
            callback, message = pending.popleft()
            callback(message)
            if time.perf_counter() > deadline:
                break
        return bool(pending)
