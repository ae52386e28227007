"""Clock core: one /clock message per tick (rosgraph_msgs/Clock), the graph's sim time."""

from sofia_ros.sim import messages as m
from sofia_ros.sim.plant import TOPICS as PLANT_TOPICS
from sofia_ros.sim.protocol import NodeCore

__all__ = ['ClockCore']


class ClockCore(NodeCore):
    """Publishes the tick's stamp on /clock."""

    name = 'clock'

    def outputs(self):
        return (PLANT_TOPICS['clock'],)

    def tick(self, stamp_ns):
        return [(PLANT_TOPICS['clock'].name, m.clock_msg(stamp_ns))]
