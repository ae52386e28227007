"""`sofia replay BAG`: re-publish a bag's messages on their topics, with /clock, into a live graph."""

from __future__ import annotations

import time

import rclpy
import rclpy.duration
from rclpy.signals import SignalHandlerOptions
from rclpy.impl.implementation_singleton import rclpy_implementation as _rclpy
from rosgraph_msgs.msg import Clock

from sofia_ros import messages as m
from sofia_ros.bag import BagReader
from sofia_ros.errors import BagError
from sofia_ros.nodes.intra_process import REFUSED_WRITE as _REFUSED_WRITE
from sofia_ros.nodes.shell import message_class
from sofia_ros.nodes.sync import DATA_QOS, SYNC_QOS
from sofia_ros.topics import CLOCK

__all__ = ['replay_bag']


def replay_bag(bag_path, *, rate=1.0, topics=None, out=None, wait_s=5.0):
    """Publish every recorded message at its log time, scaled by ``rate`` (0: as fast as possible).

    Each topic is offered with the QoS it was recorded with: transient-local topics (the /config/*
    documents, /result/*, /clock) are re-latched, so a subscriber that joins later still gets their
    last message while the replay runs. Publishing starts once every replayed volatile topic has a
    subscriber, or after ``wait_s`` of wall time: a volatile topic drops what is published before
    discovery has matched its subscribers. A bag with a damaged chunk is refused before anything is published.
    """
    from rclpy.node import Node

    with BagReader(bag_path) as bag:
        recorded = {info.name for info in bag.topics}
        missing = sorted(set(topics or ()) - recorded)
        if missing:
            raise BagError(f'{", ".join(missing)} not in bag {bag_path}; it records {", ".join(sorted(recorded))}')
        infos = [info for info in bag.topics if topics is None or info.name in topics]
        # Every chunk checked first: a chunk damaged mid-file stopped the replay after those before it were published.
        bag.check_chunks()
        # SIGINT/SIGTERM stay with sofia_ros.interrupts: one line and exit 130/143, not an RCLError.
        rclpy.init(signal_handler_options=SignalHandlerOptions.NO)
        try:
            node = Node('replay')
            publishers = {}
            latched = bag.latched_topics()
            for info in infos:
                qos = SYNC_QOS if info.name in latched else DATA_QOS
                publishers[info.name] = node.create_publisher(message_class(info.msgtype), info.name, qos)
            clock = publishers.get(CLOCK.name) or node.create_publisher(Clock, CLOCK.name, SYNC_QOS)
            # A topic without a message (a stability run's /parameter_events) waits for no subscriber.
            empty = {info.name for info in infos if info.count == 0}
            waiting = _wait_for_subscribers(
                node, [p for name, p in publishers.items() if name not in latched and name not in empty], wait_s)
            if waiting and out is not None:
                out.write(f'no subscriber after {wait_s:g} s on {", ".join(waiting)}; replaying anyway\n')
            start_wall, first_ns, count, refused = time.monotonic(), None, 0, {}
            for topic, stamp_ns, data in bag.raw_messages(*publishers):
                first_ns = stamp_ns if first_ns is None else first_ns
                if rate > 0:
                    delay = (stamp_ns - first_ns) / 1e9 / rate - (time.monotonic() - start_wall)
                    if delay > 0:
                        time.sleep(delay)
                if topic != CLOCK.name and CLOCK.name not in publishers:
                    _published(clock, m.clock_msg(stamp_ns), refused)
                if _published(publishers[topic], bytes(data), refused):
                    count += 1
            for publisher in publishers.values():
                # Reliable delivery: do not exit before subscribers have every message.
                publisher.wait_for_all_acked(rclpy.duration.Duration(seconds=10.0))
            if out is not None:
                out.write(f'replayed {count} messages on {len(publishers)} topics from {bag_path}\n')
                for topic, dropped in refused.items():
                    out.write(f'  {dropped} message(s) on {topic} refused by DDS (a subscriber that left mid-replay '
                              'or could not keep up)\n')
            node.destroy_node()
        finally:
            rclpy.try_shutdown()
    return count


def _published(publisher, data, refused):
    """Publish ``data``; a write DDS refuses (rmw_fastrtps: 'cannot publish data', when a reliable subscriber leaves
    mid-replay or cannot keep up) is counted in ``refused`` by topic and the replay goes on: it stopped with an
    RCLError traceback, exit 1."""
    try:
        publisher.publish(data)
    except _rclpy.RCLError as err:
        if _REFUSED_WRITE not in str(err):
            raise
        refused[publisher.topic_name] = refused.get(publisher.topic_name, 0) + 1
        return False
    return True


def _wait_for_subscribers(node, publishers, wait_s):
    """Spin until every publisher has a matched subscription or ``wait_s`` passed; return the topics still without."""
    deadline = time.monotonic() + wait_s
    while True:
        waiting = [publisher.topic_name for publisher in publishers if publisher.get_subscription_count() == 0]
        if not waiting or time.monotonic() >= deadline:
            return waiting
        rclpy.spin_once(node, timeout_sec=0.05)
