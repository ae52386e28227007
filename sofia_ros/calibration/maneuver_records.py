"""A maneuver as the plain record the calibration node publishes on /calibration/maneuvers, and back.

The record holds every input of a fit (3.3.2), so ``analysis.alignment_bag`` repeats the node's
fits from a bag and gets its matrices bit for bit.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from sofia_ros.calibration.solvers import Maneuver

__all__ = ['maneuver_record', 'maneuver_from_record']


def maneuver_record(maneuver: Maneuver) -> dict:
    """A Maneuver as plain YAML-able values (the /calibration/maneuvers record)."""
    return {'axis': maneuver.axis, 'angle_rad': float(maneuver.angle_rad),
            'start_px': [float(v) for v in maneuver.start_px], 'end_px': [float(v) for v in maneuver.end_px],
            'active_alignment': np.asarray(maneuver.active_alignment).tolist(),
            'duration_s': float(maneuver.duration_s), 'block': int(maneuver.block)}


def maneuver_from_record(record: Mapping[str, Any]) -> Maneuver:
    """Inverse of maneuver_record."""
    return Maneuver(record['axis'], record['angle_rad'], record['start_px'], record['end_px'],
                    np.asarray(record['active_alignment']), record['duration_s'], record['block'])
