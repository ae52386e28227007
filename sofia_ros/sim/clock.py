"""Clock core: one /clock message per tick (rosgraph_msgs/Clock), the graph's sim time."""

from sofia_ros import messages as m
from sofia_ros.sim.protocol import NodeCore
from sofia_ros.topics import CLOCK

__all__ = ['ClockCore']


class ClockCore(NodeCore):
    """Publishes the tick's stamp on /clock."""

    name = 'clock'

    def outputs(self):
        return (CLOCK,)

    def tick(self, stamp_ns):
        return [(CLOCK.name, m.clock_msg(stamp_ns))]
