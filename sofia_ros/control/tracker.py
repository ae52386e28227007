"""Tracker geometry of the TASCU: moves that centre a star, and drift from centroid trends (2.3, 6.1, 6.3)."""

from __future__ import annotations

import numpy as np

from sofia_ros.frames import dcm_from_rotation_angles, pixel_to_vector
from sofia_ros.sensors.imager_model import nominal_detector, predicted_centroid_px
from sofia_ros.validate import finite_array

__all__ = [
    'star_direction_tarf',
    'centring_rotation_rad',
    'pixel_jacobian_px_per_rad',
    'drift_rate_from_centroids_rad_per_s',
]

_JACOBIAN_STEP_RAD = 1e-6


def star_direction_tarf(camera, pixel_xy, camera_from_tarf):
    """Unit vector in TARF of a centroid, through the camera's alignment matrix (3.2-3.7, C.1.3)."""
    return camera_from_tarf.T @ pixel_to_vector(finite_array('pixel_xy', pixel_xy, shape=(2,)),
                                                nominal_detector(camera))


def centring_rotation_rad(camera, pixel_xy, boresight_xy, camera_from_tarf):
    """Rotation vector (TARF) of the move that brings the star at ``pixel_xy`` onto the boresight (MTBS, 6.3)."""
    star = star_direction_tarf(camera, pixel_xy, camera_from_tarf)
    target = star_direction_tarf(camera, boresight_xy, camera_from_tarf)
    axis = np.cross(target, star)
    sine = np.linalg.norm(axis)
    if sine == 0.0:
        return np.zeros(3)
    return axis / sine * np.arctan2(sine, float(np.dot(target, star)))


def pixel_jacobian_px_per_rad(camera, pixel_xy, camera_from_tarf):
    """2x3 change of a star's centroid per small telescope rotation about EL, XEL, LOS (3.2-3.7)."""
    star_tarf = star_direction_tarf(camera, pixel_xy, camera_from_tarf)
    columns = []
    for axis in np.eye(3):
        turned = dcm_from_rotation_angles(axis * _JACOBIAN_STEP_RAD)
        plus = predicted_centroid_px(camera, star_tarf, turned, camera_from_tarf)
        minus = predicted_centroid_px(camera, star_tarf, turned.T, camera_from_tarf)
        columns.append((plus - minus) / (2.0 * _JACOBIAN_STEP_RAD))
    return np.column_stack(columns)


def drift_rate_from_centroids_rad_per_s(camera, times_s, pixels_xy, camera_from_tarf):
    """Telescope drift rate about EL and XEL from a linear fit to a tracked star's centroids (6.1, 6.3)."""
    times = finite_array('times_s', times_s, shape=(None,))
    pixels = finite_array('pixels_xy', pixels_xy, shape=(len(times), 2))
    slope_px_per_s = np.polyfit(times - times.mean(), pixels, 1)[0]
    jacobian = pixel_jacobian_px_per_rad(camera, pixels.mean(axis=0), camera_from_tarf)
    # One star cannot show a turn about its own line of sight: solve for EL and XEL only.
    el_xel = np.linalg.solve(jacobian[:, :2], slope_px_per_s)
    return np.array([el_xel[0], el_xel[1], 0.0])
