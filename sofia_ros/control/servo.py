"""Fine-drive servo of the TASCU: commanded attitude profile, rate law and motion status (2.3, 6.3).

The servo closes the loop on the gyro-propagated attitude: it commands the inertial
body rate that moves the estimate onto the command. Motion status follows [Schmolke
2001b] as quoted in 6.3: *transient* while a commanded move is in progress, *settled*
while only the control deviation remains, *locked* once the deviation has stayed
inside 1" RSS for 0.1 s.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sofia_ros.rotation_kernels import matrices_from_rotvecs
from sofia_ros.units import RAD_PER_ARCSEC, RAD_PER_DEG
from sofia_ros.validate import finite_array

__all__ = [
    'TRANSIENT',
    'SETTLED',
    'LOCKED',
    'ServoSettings',
    'MoveProfile',
    'servo_rate_rad_per_s',
    'MotionStatus',
]

TRANSIENT, SETTLED, LOCKED = 'transient', 'settled', 'locked'
#: Left-over angle of a slew that is only floating-point rounding.
_ANGLE_ROUNDING_RAD = 1e-12


@dataclass(frozen=True)
class ServoSettings:
    """Servo gains and limits; lock limit and time as set during the 2004 tests (6.3)."""

    position_gain_per_s: float = 2.0
    max_rate_rad_per_s: float = 1.0 * RAD_PER_DEG
    slew_rate_rad_per_s: float = 0.5 * RAD_PER_DEG
    lock_limit_rad: float = 1.0 * RAD_PER_ARCSEC
    lock_time_s: float = 0.1


class MoveProfile:
    """Constant-rate slew of the commanded attitude about a fixed TARF axis."""

    def __init__(self, rotation_rad, slew_rate_rad_per_s):
        rotation = finite_array('rotation_rad', rotation_rad, shape=(3,))
        angle_rad = float(np.linalg.norm(rotation))
        self.axis = rotation / angle_rad if angle_rad > 0.0 else np.zeros(3)
        self.remaining_rad = angle_rad
        self.rate_rad_per_s = slew_rate_rad_per_s

    @property
    def done(self):
        """True once the whole rotation has been commanded."""
        return self.remaining_rad <= 0.0

    def advance(self, commanded_from_inertial, interval_s):
        """Turn the command by one interval of the slew; return (new command, feed-forward rate)."""
        step_rad = min(self.remaining_rad, self.rate_rad_per_s * interval_s)
        self.remaining_rad -= step_rad
        if self.remaining_rad < _ANGLE_ROUNDING_RAD:
            step_rad += self.remaining_rad
            self.remaining_rad = 0.0
        turn = matrices_from_rotvecs(self.axis * step_rad)
        return turn.T @ commanded_from_inertial, self.axis * step_rad / interval_s


def servo_rate_rad_per_s(error_rad, feedforward_rad_per_s, settings):
    """Commanded inertial body rate: feed-forward plus proportional correction, rate-limited."""
    rate = feedforward_rad_per_s + settings.position_gain_per_s * error_rad
    magnitude = float(np.linalg.norm(rate))
    if magnitude > settings.max_rate_rad_per_s:
        rate = rate * (settings.max_rate_rad_per_s / magnitude)
    return rate


class MotionStatus:
    """transient / settled / locked from the move state and the control deviation (6.3)."""

    def __init__(self, settings):
        self.settings = settings
        self.state = LOCKED
        self._inside_since_s = None

    def update(self, moving, error_rad, now_s):
        """Advance the status at time ``now_s``; return it."""
        inside = float(np.linalg.norm(error_rad)) <= self.settings.lock_limit_rad
        if moving:
            self.state, self._inside_since_s = TRANSIENT, None
        elif not inside:
            self.state, self._inside_since_s = SETTLED, None
        else:
            if self._inside_since_s is None:
                self._inside_since_s = now_s
            locked = now_s - self._inside_since_s >= self.settings.lock_time_s - 1e-9
            self.state = LOCKED if locked else SETTLED
        return self.state
