"""Intra-process hand-over between the graph's nodes in one process, as rclcpp's intra-process communication.

A message one node publishes reaches the other nodes of the process as the object itself, in publish order,
never inside the publishing callback: the bus queues it and hands it over when the callback that published
it returns (:meth:`IntraProcessBus.dispatch`). DDS carries a message only when a subscription outside the
bus has matched the publisher (``ros2 topic echo``, a user's own recorder, rclpy's /clock TimeSource), so what
leaves the process is what it was. Every node keeps its DDS subscriptions, so the graph looks the same from
outside (``ros2 topic info``); the copies DDS brings them of what the bus handed over are dropped.
"""

from __future__ import annotations

from collections import deque

from rclpy.qos import DurabilityPolicy

__all__ = ['IntraProcessBus']


class IntraProcessBus:
    """Topic -> the in-process callbacks of one graph; queued deliveries handed over in publish order."""

    def __init__(self):
        self._callbacks = {}  # topic -> [callback(message)]
        self._latest = {}  # topic -> the last message published on it, for transient-local late subscribers
        self._pending = deque()  # (callback, message) in publish order
        self._dispatching = False

    def subscribe(self, topic, callback, qos):
        """Hand ``callback`` every message published on ``topic`` from now on; with a transient-local ``qos`` the
        last one published before too, as DDS would."""
        self._callbacks.setdefault(topic, []).append(callback)
        if qos.durability == DurabilityPolicy.TRANSIENT_LOCAL and topic in self._latest:
            self._queue(callback, self._latest[topic])

    def unsubscribe(self, topic, callback):
        """Stop handing ``topic`` to ``callback`` (what is queued for it still arrives)."""
        self._callbacks[topic].remove(callback)

    def subscriptions(self, topic):
        """How many in-process callbacks take ``topic``."""
        return len(self._callbacks.get(topic, ()))

    def publish(self, publisher, topic, message, wire=None):
        """Queue ``message`` for every in-process subscriber of ``topic``; over DDS (``wire(message)``, or the
        message itself) only when a subscription outside the bus has matched ``publisher``."""
        callbacks = self._callbacks.get(topic, ())
        self._latest[topic] = message
        if publisher.get_subscription_count() > len(callbacks):
            publisher.publish(message if wire is None else wire(message))
        for callback in callbacks:
            self._queue(callback, message)

    def _queue(self, callback, message):
        self._pending.append((callback, message))
        if not self._dispatching:
            # Published outside any dispatched callback (a node's set-up): hand it over at once.
            self.dispatch(lambda: None)

    def dispatch(self, callback, *args):
        """Run an executor callback (a timer, a DDS subscription, a service response) of a node on the bus, then
        everything it and its consequences publish, one delivery at a time: a node's callback never runs inside
        another's, as under an executor."""
        if self._dispatching:
            callback(*args)
            return
        self._dispatching = True
        try:
            callback(*args)
            pending = self._pending
            while pending:
                deliver, message = pending.popleft()
                deliver(message)
        finally:
            self._dispatching = False
