"""The lock-step handshake over DDS: ``/sim/done/<node>`` carries the tick and cumulative message counts.

A node may run tick k once every upstream node has reported tick k - lag and every
message those reports count has arrived; DDS keeps order within a topic but not
across topics, hence the counts (an intra-process bus keeps publish order across
topics, so there nothing is counted: nodes.intra_process). ``/sim/stop`` ends the run
with a reason.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Mapping, NamedTuple

from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

__all__ = ['DONE_PREFIX', 'STOP_TOPIC', 'SYNC_QOS', 'DATA_QOS', 'OUTSIDE_QOS', 'done_topic', 'DoneReport', 'done_text',
           'parse_done_text', 'UpstreamState', 'stop_text', 'parse_stop']

DONE_PREFIX = '/sim/done/'
STOP_TOPIC = '/sim/stop'
#: Late joiners get the latest handshake.
SYNC_QOS = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL,
                      history=HistoryPolicy.KEEP_LAST)
#: Nothing is dropped: the lock-step bounds what is in flight to one tick.
DATA_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE,
                      history=HistoryPolicy.KEEP_ALL)
#: A data publisher whose DDS readers are all outside the graph (a CoreNode output on an intra-process bus; the
#: per-sample gyro topic in every mode): a listener that falls 1000 messages behind loses the oldest instead of
#: holding up the graph (with DATA_QOS the publisher would block, then fail).
OUTSIDE_QOS = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE,
                         history=HistoryPolicy.KEEP_LAST)


def done_topic(node):
    """Handshake topic of a node."""
    return DONE_PREFIX + node


class DoneReport(NamedTuple):
    """A node's done(tick): the cumulative count of what it published on each topic, whether it has finished
    the run, and why it failed ('' unless it did; no ';')."""

    tick: int
    counts: Mapping[str, int]
    finished: bool
    failed: str


def done_text(report):
    """The text a done report travels as over DDS: ``tick;finished;failed;topic=count,...``."""
    counts = ','.join(f'{topic}={count}' for topic, count in sorted(report.counts.items()))
    return f'{report.tick};{int(report.finished)};{report.failed};{counts}'


def parse_done_text(text):
    """The DoneReport of :func:`done_text`."""
    tick, finished, failed, counts = text.split(';', 3)
    pairs = (item.rsplit('=', 1) for item in counts.split(',') if item)
    return DoneReport(int(tick), {topic: int(count) for topic, count in pairs}, finished == '1', failed)


@dataclass
class UpstreamState:
    """What one upstream node has announced, tick by tick (cumulative counts per topic)."""

    reports: dict = field(default_factory=dict)  # tick -> {topic: cumulative count}
    latest_tick: int = -1
    finished: bool = False
    failed: str = ''

    def announce(self, tick, counts, finished=False, failed=''):
        """Record a done(tick) report."""
        self.reports[tick] = counts
        self.latest_tick = max(self.latest_tick, tick)
        self.finished = self.finished or finished
        self.failed = self.failed or failed
        # Reports arrive in tick order, so the oldest comes first: drop those before the last three.
        while next(iter(self.reports)) < tick - 2:
            del self.reports[next(iter(self.reports))]


def stop_text(last_tick, complete, reason):
    """Body of a /sim/stop message: the last tick, whether it was completed, and why the run ends."""
    return f'{last_tick};{"complete" if complete else "abort"};{reason}'


def parse_stop(text):
    """(last_tick, complete, reason) of a /sim/stop message."""
    last_tick, kind, reason = text.split(';', 2)
    return int(last_tick), kind == 'complete', reason
