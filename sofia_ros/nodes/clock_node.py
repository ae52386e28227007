"""Clock node: advances sim time one tick once every node has finished the last one; stops the run."""

from __future__ import annotations

import time

from std_msgs.msg import String

from sofia_ros.nodes.shell import LockstepNode
from sofia_ros.nodes.sync import STOP_TOPIC, SYNC_QOS
from sofia_ros.sim import messages as m
from sofia_ros.sim.plant import TOPICS as PLANT_TOPICS
from rosgraph_msgs.msg import Clock

__all__ = ['ClockNode']


class ClockNode(LockstepNode):
    """Publishes /clock per tick; ends the run when a node finishes or fails, or the graph stalls."""

    def __init__(self, participants, *, tick_ns, max_sim_s, stall_timeout_s=15.0, subscribers=1):
        super().__init__('clock', upstream=[(name, 1) for name in participants], tick_ns=tick_ns,
                         expected_outputs={PLANT_TOPICS['clock'].name: subscribers})
        self.publishers_by_topic[PLANT_TOPICS['clock'].name] = self.create_publisher(
            Clock, PLANT_TOPICS['clock'].name, SYNC_QOS)
        self.stop_publisher = self.create_publisher(String, STOP_TOPIC, SYNC_QOS)
        self.max_tick = int(max_sim_s * m.NS_PER_S // tick_ns)
        self.stall_timeout_s = stall_timeout_s
        self.last_progress = time.monotonic()
        self.create_timer(0.5, self._watchdog, clock=self._wall_clock())

    def run_tick(self, tick):
        for name, state in self.states.items():
            if state.finished or state.failed:
                reason = state.failed or f'{name} finished'
                self._stop(tick - 1, reason)
                return
        if tick > self.max_tick:
            self._stop(tick - 1, f'reached the sim-time limit of {self.max_tick * self.tick_ns / m.NS_PER_S:g} s')
            return
        self.last_progress = time.monotonic()
        self.publish(PLANT_TOPICS['clock'].name, m.clock_msg(tick * self.tick_ns))
        self.publish_done(tick)

    def _stop(self, last_tick, reason):
        if self.stop_reason is None:
            self.stop_publisher.publish(String(data=f'{last_tick};{reason}'))
            self.stop_reason = f'{last_tick};{reason}'

    def _watchdog(self):
        if not self.ready or self.stop_reason is not None:
            return
        if time.monotonic() - self.last_progress > self.stall_timeout_s:
            waiting = self.next_tick - 1
            silent = sorted(name for name, state in self.states.items() if state.latest_tick < waiting)
            self._stop(waiting, f'{", ".join(silent) or "the graph"} stopped reporting at tick {waiting} '
                                f'(sim {waiting * self.tick_ns / m.NS_PER_S:.1f} s) for {self.stall_timeout_s:g} s; '
                                'the node is gone or stuck')
