"""Test isolation: DDS stays on this machine, in a random domain of its own per session.

The domain is one no sofia run holds at the start (nodes.domain's lock files), so a session
does not collide with another engineer's tests or runs on the same machine.
"""

import os
import random

from sofia_ros.nodes.domain import claim_ros_domain, release_ros_domain

os.environ['ROS_AUTOMATIC_DISCOVERY_RANGE'] = 'LOCALHOST'
_probe = claim_ros_domain({}, rng=random.SystemRandom())
release_ros_domain(_probe, {})
os.environ['ROS_DOMAIN_ID'] = str(_probe.domain_id)
