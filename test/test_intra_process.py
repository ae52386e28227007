"""The intra-process hand-over of an in-process graph (nodes.intra_process), without DDS: a stand-in publisher.

The live graph on the bus writes direct mode's bag (test_live_graph); a listener outside the process gets what the
bag holds (test_mode_bags).
"""

import pytest
from rclpy.impl.implementation_singleton import rclpy_implementation

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


def test_messages_are_handed_over_in_publish_order_never_inside_the_publishing_callback():
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
    bus.publish(publisher, '/a', 1)
    bus.publish(publisher, '/a', 2)
    log.append('the publisher returns')
    assert bus.pending and not bus.deliver(max_s=10.0)
    assert log == ['the publisher returns', ('a', 1), ('forward', 1), ('a', 2), ('forward', 2), ('b', '1+'),
                   ('b', '2+')]


def test_delivering_stops_after_its_time_slice_and_goes_on_where_it_stopped():
    bus = IntraProcessBus()
    publisher, received = _Publisher(matched=0), []
    bus.subscribe('/a', received.append, DATA_QOS)
    for value in range(3):
        bus.publish(publisher, '/a', value)
    assert bus.deliver(max_s=0.0) and received == [0]  # at least one, then the executor's turn
    assert not bus.deliver(max_s=10.0) and received == [0, 1, 2] and not bus.pending


def test_dds_carries_a_message_only_for_a_subscription_outside_the_bus():
    bus = IntraProcessBus()
    received = []
    bus.subscribe('/a', received.append, DATA_QOS)
    inside_only, outside_too = _Publisher(matched=0), _Publisher(matched=1)
    bus.publish(inside_only, '/a', 'kept in')
    bus.publish(outside_too, '/a', 'also out', wire=str.upper)
    bus.deliver(max_s=10.0)
    assert inside_only.sent == [] and outside_too.sent == ['ALSO OUT']
    assert received == ['kept in', 'also out']  # the object itself in the process, its wire form over DDS
    assert bus.subscriptions('/a') == 1 and bus.subscriptions('/b') == 0


def test_a_late_transient_local_subscriber_gets_the_last_message_a_volatile_one_does_not():
    bus = IntraProcessBus()
    publisher = _Publisher(matched=0)
    for report in ('done 1', 'done 2'):
        bus.publish(publisher, '/done', report)
    latched, volatile = [], []
    bus.subscribe('/done', latched.append, SYNC_QOS)
    bus.subscribe('/done', volatile.append, DATA_QOS)
    bus.publish(publisher, '/done', 'done 3')
    bus.deliver(max_s=10.0)
    assert latched == ['done 2', 'done 3'] and volatile == ['done 3']


def test_an_unsubscribed_callback_gets_no_more_messages():
    bus = IntraProcessBus()
    publisher, received = _Publisher(matched=0), []
    bus.subscribe('/a', received.append, DATA_QOS)
    bus.publish(publisher, '/a', 1)
    bus.deliver(max_s=10.0)
    bus.unsubscribe('/a', received.append)
    bus.publish(publisher, '/a', 2)
    bus.deliver(max_s=10.0)
    assert received == [1] and bus.subscriptions('/a') == 0


def test_a_failing_subscriber_reaches_the_caller_and_the_rest_stays_queued():
    # The exception ends the run (as one in a DDS callback would); nothing queued behind it is lost.
    bus = IntraProcessBus()
    publisher, received = _Publisher(matched=0), []

    def fail(message):
        raise ValueError(f'bad {message}')
    bus.subscribe('/bad', fail, DATA_QOS)
    bus.subscribe('/a', received.append, DATA_QOS)
    bus.publish(publisher, '/bad', 1)
    bus.publish(publisher, '/a', 2)
    with pytest.raises(ValueError, match='bad 1'):
        bus.deliver(max_s=10.0)
    assert bus.pending and not bus.deliver(max_s=10.0) and received == [2]


def test_a_listener_outside_that_cannot_keep_up_loses_the_message_not_the_graph():
    # A reliable listener outside that falls behind makes DDS refuse the write (RCLError): the message is dropped
    # for it, with one warning per topic, and the graph's own subscribers still get it.
    class _Refusing(_Publisher):
        topic_name = '/a'

        def publish(self, message):
            raise rclpy_implementation.RCLError('Failed to publish: cannot publish data')
    bus = IntraProcessBus()
    received = []
    bus.subscribe('/a', received.append, DATA_QOS)
    bus.publish(_Refusing(matched=1), '/a', 1)
    assert not bus.deliver(max_s=10.0) and received == [1]


def test_a_listener_outside_that_matches_hears_from_the_next_time_slice_on():
    # Whether a publisher has listeners outside is asked once a slice (a DDS call per message cost 2 % of a tick).
    bus = IntraProcessBus()
    publisher = _Publisher(matched=0)
    bus.publish(publisher, '/a', 1)
    publisher.matched = 1
    bus.publish(publisher, '/a', 2)
    bus.deliver(max_s=10.0)
    bus.publish(publisher, '/a', 3)
    assert publisher.sent == [3]


def test_any_other_failure_to_publish_is_not_taken_for_a_slow_listener():
    class _Broken(_Publisher):
        topic_name = '/a'

        def publish(self, message):
            raise rclpy_implementation.RCLError("Failed to publish: publisher's context is invalid")
    with pytest.raises(rclpy_implementation.RCLError, match='context is invalid'):
        IntraProcessBus().publish(_Broken(matched=1), '/a', 1)
