"""Earth's rotation rate as sensed by the EL/XEL/LOS gyros on the ground (section 4.1).

Assumes, as the thesis does, the telescope centred in bulkhead and inner cradle,
the EL axis parallel to the aircraft centre line and the centre line level.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import minimize_scalar

from sofia_ros.units import EARTH_RATE_DEG_PER_H, RAD_PER_DEG
from sofia_ros.validate import finite_array

__all__ = [
    'earth_rate_tarf_deg_per_h',
    'earth_rate_tarf_rad_per_s',
    'best_fit_heading_deg',
]


def earth_rate_tarf_deg_per_h(latitude_deg, heading_deg, elevation_deg, earth_rate_deg_per_h=EARTH_RATE_DEG_PER_H):
    """Earth rate components (EL, XEL, LOS) in deg/h sensed on the ground (eqs. 4.1-4.3)."""
    lat = finite_array('latitude_deg', latitude_deg) * RAD_PER_DEG
    heading = finite_array('heading_deg', heading_deg) * RAD_PER_DEG
    elevation = finite_array('elevation_deg', elevation_deg) * RAD_PER_DEG
    omega = earth_rate_deg_per_h
    rate_el = omega * np.cos(lat) * np.cos(heading)
    rate_xel = omega * np.cos(lat) * np.sin(heading) * np.sin(elevation) - omega * np.sin(lat) * np.cos(elevation)
    rate_los = omega * np.cos(lat) * np.sin(heading) * np.cos(elevation) + omega * np.sin(lat) * np.sin(elevation)
    return np.stack(np.broadcast_arrays(rate_el, rate_xel, rate_los), axis=-1)


def earth_rate_tarf_rad_per_s(latitude_deg, heading_deg, elevation_deg):
    """Earth rate components (EL, XEL, LOS) in rad/s sensed on the ground (eqs. 4.1-4.3)."""
    return earth_rate_tarf_deg_per_h(latitude_deg, heading_deg, elevation_deg) * RAD_PER_DEG / 3600.0


def best_fit_heading_deg(measured_rate_deg_per_h, latitude_deg, elevation_deg, search_range_deg=(0.0, 360.0)):
    """Heading minimizing the sum of squared residual biases against 4.1-4.3 (section 5.2.4)."""
    measured = finite_array('measured_rate_deg_per_h', measured_rate_deg_per_h, shape=(3,))

    def residual_sum_of_squares(heading_deg):
        predicted = earth_rate_tarf_deg_per_h(latitude_deg, heading_deg, elevation_deg)
        return float(np.sum((measured - predicted) ** 2))

    low_deg, high_deg = search_range_deg
    grid_deg = np.linspace(low_deg, high_deg, 721)
    start_deg = grid_deg[np.argmin([residual_sum_of_squares(h) for h in grid_deg])]
    step_deg = (high_deg - low_deg) / 720.0
    result = minimize_scalar(
        residual_sum_of_squares,
        bounds=(start_deg - step_deg, start_deg + step_deg),
        method='bounded',
        options={'xatol': 1e-6},
    )
    return float(result.x)
