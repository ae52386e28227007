"""Clock node: advances sim time one tick once every node has finished the last one; stops the run."""

from __future__ import annotations

import signal
import time

from std_msgs.msg import String

from sofia_ros import interrupts
from sofia_ros import messages as m
from sofia_ros.nodes.shell import LockstepNode
from sofia_ros.nodes.sync import STOP_TOPIC, SYNC_QOS, UpstreamState, done_topic, stop_text
from sofia_ros.topics import CLOCK
from rosgraph_msgs.msg import Clock

__all__ = ['ClockNode', 'FIRST_TICK_STALL', 'STALLED_EXIT_CODE']

#: Exit code of the clock node's process when it stopped the run because a node fell silent (a fault).
STALLED_EXIT_CODE = 3
#: The end of the stop reason of a graph whose node connected and then fell silent on the first tick: its process's
#: DDS events stopped arriving (it waits in the executor, /sim/stop unheard too), about 1 start in 30 with three
#: graphs at once on two cores (test/graph_startup.py). A new start does not meet it again; `sofia run` starts once
#: more (campaigns.recording).
FIRST_TICK_STALL = '; a graph stalled on its first tick starts cleanly again'

_STARTUP_TIMEOUT_S = 120.0


class ClockNode(LockstepNode):
    """Publishes /clock per tick; ends the run when a node finishes or fails, or the graph stalls."""

    def __init__(self, participants, *, tick_ns, max_sim_s, stall_timeout_s=15.0, subscribers=1, ending=(), bus=None):
        """``participants`` in tick order, the recorder among them: the first silent one is the likely culprit of a
        stall. ``ending``: the nodes whose reports can end the run (finished or failed).

        The next tick waits on the recorder's done report alone, and on those of ``ending``: the recorder's
        done(k) follows every node's done(k) and every message of tick k. Every participant's reports are
        read only while the graph starts and when it seems to stall, to name who is missing: each is one more
        delivery per tick.
        """
        super().__init__('clock', upstream=[(name, 1) for name in (*ending, 'recorder')], tick_ns=tick_ns,
                         expected_outputs={CLOCK.name: subscribers}, bus=bus)
        self.participants = list(participants)
        self.states.update((name, UpstreamState()) for name in self.participants if name not in self.states)
        self._watching = []
        self._watch_every_participant()
        self.publishers_by_topic[CLOCK.name] = self.create_publisher(
            Clock, CLOCK.name, SYNC_QOS)
        self.stop_publisher = self.create_publisher(String, STOP_TOPIC, SYNC_QOS)
        self.max_tick = int(max_sim_s * m.NS_PER_S // tick_ns)
        self.stall_timeout_s = stall_timeout_s
        self.last_progress = time.monotonic()
        self.create_timer(0.5, self._watchdog, clock=self._wall_clock())

    def _watch_every_participant(self):
        """Read every participant's done reports; the latest arrives at once (transient-local)."""
        self._watching = [self.subscribe_graph_topic(String, done_topic(name), *self._done_callbacks(name), SYNC_QOS)
                          for name in self.participants if name not in self.upstream]

    def _stop_watching(self):
        for handle in self._watching:
            self.unsubscribe_graph_topic(handle)
        self._watching = []

    def run_tick(self, tick):
        if self._watching:
            # Every node has connected, or the graph moves on: the recorder's reports stand for all of them.
            self._stop_watching()
        for name, state in self.states.items():
            if state.finished or state.failed:
                reason = state.failed or f'{name} finished'
                self._stop(tick - 1, reason)
                return
        if tick > self.max_tick:
            self._stop(tick - 1, f'reached the sim-time limit of {self.max_tick * self.tick_ns / m.NS_PER_S:g} s')
            return
        self.last_progress = time.monotonic()
        self.publish(CLOCK.name, m.clock_msg(tick * self.tick_ns))
        self.publish_done(tick)

    def _stop(self, last_tick, reason, complete=True):
        if self.stop_reason is None:
            self.stop_reason = stop_text(last_tick, complete, reason)
            self.stop_publisher.publish(String(data=self.stop_reason))
            self.get_logger().info(f'stopping: {reason}')

    def _watchdog(self):
        if self.stop_reason is not None:
            return
        signum = interrupts.requested()
        if signum is not None:
            # SIGINT/SIGTERM of `sofia run` (executor mode): the recorder keeps every completed tick.
            self._stop(self.next_tick - 1, f'interrupted by {signal.Signals(signum).name}', complete=False)
            return
        waited_s = time.monotonic() - self.last_progress
        if self.next_tick > 1 and waited_s > self.stall_timeout_s / 2.0 and not self._watching:
            # Possibly stalling: learn where every node is before the timeout names the culprit.
            self._watch_every_participant()
        if self.next_tick <= 1:
            # Starting up: every process imports, discovers and connects; allow for a slow machine.
            if waited_s > max(self.stall_timeout_s, _STARTUP_TIMEOUT_S):
                absent = sorted(name for name, state in self.states.items() if state.latest_tick < 0)
                self._stop(0, f'{", ".join(absent) or "the clock"} did not connect within '
                              f'{max(self.stall_timeout_s, _STARTUP_TIMEOUT_S):g} s; is every node running?',
                           complete=False)
            return
        if waited_s > self.stall_timeout_s:
            waiting = self.next_tick - 1
            silent = [name for name in self.participants if self.states[name].latest_tick < waiting]
            # A node whose handshake topic has lost its publisher is gone; otherwise the first silent
            # node in tick order is the one the others wait for.
            gone = [name for name in silent if self.count_publishers(done_topic(name)) == 0]
            culprit = (gone or silent or ['the graph'])[0]
            state = 'the node is gone' if gone else 'the node is gone or stuck'
            others = ', '.join(name for name in silent if name != culprit)
            waiting_note = f'; waiting on it: {others}' if others else ''
            first_tick_note = FIRST_TICK_STALL if waiting == 1 else ''
            self._stop(waiting, f'{culprit} stopped reporting at tick {waiting} '
                                f'(sim {waiting * self.tick_ns / m.NS_PER_S:.1f} s) for {self.stall_timeout_s:g} s: '
                                f'{state}{waiting_note}{first_tick_note}', complete=False)
