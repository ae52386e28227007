"""The lock-step contract every simulation core follows, in-process or over DDS.

Simulated time advances in ticks of ``tick_ns``. At tick k (stamp ``k * tick_ns``) a
core is handed every message its inputs produced for that tick and for earlier ones
- :meth:`NodeCore.receive` buffers them - and then :meth:`NodeCore.tick` returns
its outputs as ``(topic, message)`` pairs. ``upstream`` says which cores must have
finished a tick first: lag 0 for the same tick, lag 1 for the previous one (the
plant uses the TASCU's fine-drive command of the tick before). The direct runner
calls cores in that order; over DDS each node waits for its upstream nodes'
``/sim/done/<name>`` handshake, which also carries how many messages were sent on
each topic, so nothing is processed early or missed. Both give the same messages.
"""

from __future__ import annotations

from dataclasses import dataclass

__all__ = ['NodeCore', 'RunOutcome', 'SET_PARAMETERS', 'ParameterRequest',
           'ParameterResult']

@dataclass
class RunOutcome:
    """How a run ended: finished normally, or stopped with a reason."""

    finished: bool = False
    failed: bool = False
    reason: str = ''


class NodeCore:
    """Base of the ROS-free node cores."""

    #: node name, also the executable's name
    name = ''
    #: (node name, lag in ticks) this core waits for before its tick
    upstream = ()
    #: True for the core whose sequence is the campaign: the run ends when it finishes or fails
    ends_run = False
    #: the nodes this core sets parameters on (SET_PARAMETERS requests; parameter clients in the live graph)
    parameter_targets = ()
    #: an input topic of sensor_msgs/Imu samples that the core takes as one ImuBlock per tick (over DDS the
    #: samples arrive as one block message, topics.SAMPLE_BLOCKS, decoded in one go), or None
    imu_block_input = None

    def __init__(self):
        self.outcome = RunOutcome()

    def inputs(self):
        """TopicSpecs (sofia_ros.topics) this core consumes."""
        return ()

    def outputs(self):
        """TopicSpecs this core produces."""
        return ()

    def receive(self, topic, message):
        """Buffer one message on an input topic."""

    def tick(self, stamp_ns):
        """Work for the tick ending at ``stamp_ns``; return [(topic, message), ...]."""
        return []


#: Pseudo-topic on which a core asks another core to set parameters (a parameter service call).
SET_PARAMETERS = '/sim/set_parameters'


@dataclass(frozen=True)
class ParameterRequest:
    """Set ``values`` (name -> value) on node ``node``: rcl_interfaces SetParameters in the live graph."""

    node: str
    values: dict


@dataclass(frozen=True)
class ParameterResult:
    """Outcome of one ParameterRequest: name -> '' when set, else the reason it was refused."""

    node: str
    reasons: dict

    @property
    def successful(self):
        """True if every parameter was set."""
        return not any(self.reasons.values())
