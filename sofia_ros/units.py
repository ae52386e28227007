"""Unit conversions and physical constants used throughout sofia_ros.

Names carry their units; messages use SI (rad, rad/s, m/s^2), configuration
and reports use arcsec and degrees.
"""

from __future__ import annotations

import math

__all__ = [
    'RAD_PER_ARCSEC',
    'ARCSEC_PER_RAD',
    'RAD_PER_DEG',
    'DEG_PER_RAD',
    'ARCSEC_PER_DEG',
    'EARTH_RATE_DEG_PER_H',
    'EARTH_RATE_RAD_PER_S',
    'STANDARD_GRAVITY_M_PER_S2',
    'GYRO_SAMPLE_RATE_HZ',
    'arcsec_to_rad',
    'rad_to_arcsec',
    'deg_per_h_to_rad_per_s',
    'rad_per_s_to_deg_per_h',
]

RAD_PER_DEG = math.pi / 180.0
DEG_PER_RAD = 180.0 / math.pi
ARCSEC_PER_DEG = 3600.0
RAD_PER_ARCSEC = RAD_PER_DEG / ARCSEC_PER_DEG
ARCSEC_PER_RAD = 1.0 / RAD_PER_ARCSEC

#: Earth's rotation rate as the thesis uses it (section 4.1).
EARTH_RATE_DEG_PER_H = 15.0411
EARTH_RATE_RAD_PER_S = EARTH_RATE_DEG_PER_H * RAD_PER_DEG / 3600.0

STANDARD_GRAVITY_M_PER_S2 = 9.80665

#: FOG180 read-out rate (section 2.4.1).
GYRO_SAMPLE_RATE_HZ = 400.0


def arcsec_to_rad(value_arcsec):
    """Convert arcseconds to radians."""
    return value_arcsec * RAD_PER_ARCSEC


def rad_to_arcsec(value_rad):
    """Convert radians to arcseconds."""
    return value_rad * ARCSEC_PER_RAD


def deg_per_h_to_rad_per_s(value_deg_per_h):
    """Convert deg/h to rad/s."""
    return value_deg_per_h * RAD_PER_DEG / 3600.0


def rad_per_s_to_deg_per_h(value_rad_per_s):
    """Convert rad/s to deg/h."""
    return value_rad_per_s * DEG_PER_RAD * 3600.0
