"""The intra-process hand-over of an in-process graph (nodes.intra_process), without DDS: a stand-in publisher.

The live graph on the bus writes direct mode's bag (test_live_graph); a listener outside the process gets what the
bag holds (test_mode_bags).
"""

import pytest

from sofia_ros.nodes.intra_process import IntraProcessBus
from sofia_ros.nodes.sync import DATA_QOS, SYNC_QOS


class _Publisher:
    """What the bus asks of an rclpy publisher: its matched subscriptions, and publish."""

    def __init__(self, matched):
        self.matched = matched
        self.sent = []

    def get_subscription_count(self):
        return self.matched

    def publish(self, message):
        self.sent.append(message)


def test_what_a_callback_publishes_is_handed_over_after_it_returns_in_publish_order():
    bus = IntraProcessBus()
    log = []
    publisher = _Publisher(matched=2)
    bus.subscribe('/a', lambda message: log.append(('a', message)), DATA_QOS)
    bus.subscribe('/b', lambda message: log.append(('b', message)), DATA_QOS)

    def forward(message):
        # A subscriber that publishes in turn: its message goes behind those already queued.
        log.append(('forward', message))
        bus.publish(publisher, '/b', f'{message}+')
    bus.subscribe('/a', forward, DATA_QOS)

    def timer():
        bus.publish(publisher, '/a', 1)
        bus.publish(publisher, '/a', 2)
        log.append('timer returns')
    bus.dispatch(timer)
    assert log == ['timer returns', ('a', 1), ('forward', 1), ('a', 2), ('forward', 2), ('b', '1+'), ('b', '2+')]


def test_dds_carries_a_message_only_for_a_subscription_outside_the_bus():
    bus = IntraProcessBus()
    received = []
    bus.subscribe('/a', received.append, DATA_QOS)
    inside_only, outside_too = _Publisher(matched=1), _Publisher(matched=2)
    bus.dispatch(lambda: bus.publish(inside_only, '/a', 'kept in'))
    bus.dispatch(lambda: bus.publish(outside_too, '/a', 'also out', wire=str.upper))
    assert inside_only.sent == [] and outside_too.sent == ['ALSO OUT']
    assert received == ['kept in', 'also out']  # the object itself in the process, its wire form over DDS
    assert bus.subscriptions('/a') == 1 and bus.subscriptions('/b') == 0


def test_a_late_transient_local_subscriber_gets_the_last_message_a_volatile_one_does_not():
    bus = IntraProcessBus()
    publisher = _Publisher(matched=0)
    bus.dispatch(lambda: [bus.publish(publisher, '/done', report) for report in ('done 1', 'done 2')])
    latched, volatile = [], []
    bus.subscribe('/done', latched.append, SYNC_QOS)
    bus.subscribe('/done', volatile.append, DATA_QOS)
    bus.dispatch(lambda: bus.publish(publisher, '/done', 'done 3'))
    assert latched == ['done 2', 'done 3'] and volatile == ['done 3']


def test_an_unsubscribed_callback_gets_no_more_messages():
    bus = IntraProcessBus()
    publisher, received = _Publisher(matched=0), []
    bus.subscribe('/a', received.append, DATA_QOS)
    bus.dispatch(lambda: bus.publish(publisher, '/a', 1))
    bus.unsubscribe('/a', received.append)
    bus.dispatch(lambda: bus.publish(publisher, '/a', 2))
    assert received == [1] and bus.subscriptions('/a') == 0


def test_a_failing_subscriber_leaves_the_bus_usable():
    # The exception reaches the executor (the run fails, as with a DDS callback); the bus does not stay locked.
    bus = IntraProcessBus()
    publisher, received = _Publisher(matched=0), []

    def fail(message):
        raise ValueError(f'bad {message}')
    bus.subscribe('/bad', fail, DATA_QOS)
    bus.subscribe('/a', received.append, DATA_QOS)
    with pytest.raises(ValueError, match='bad 1'):
        bus.dispatch(lambda: bus.publish(publisher, '/bad', 1))
    bus.dispatch(lambda: bus.publish(publisher, '/a', 2))
    assert received == [2]
