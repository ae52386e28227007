"""The noise floor of a bag, from the data alone: centroid scatter per camera while locked (6.1).

For one star in consecutive frames of one camera while the TASCU reports "locked", the
second difference x[i+1] - 2 x[i] + x[i-1] removes the star's slow motion (drift, the sky)
and leaves white centroid noise with variance 6 sigma^2. The median absolute deviation makes
the estimate robust against a frame caught in a servo transient. The gyro random walk over
the anchor spacing is small against it (0.0132"/sqrt(s) x sqrt(120 s / 6) = 0.06", Table 5.1).
"""

from __future__ import annotations

import numpy as np

from sofia_ros.compare.observations import MOTION_STATES, Centroids, GyroSamples
from sofia_ros.errors import BagError

__all__ = ['centroid_noise_arcsec', 'angle_random_walk_rad_per_sqrt_s', 'anchor_walk_sigma_rad', 'MIN_NOISE_ARCSEC',
           'MIN_WITHIN_TICK_DIFFERENCES']

#: Below this the centroid noise is quantization-free simulation; weights must stay finite.
MIN_NOISE_ARCSEC = 1e-3
#: The fewest within-tick rate differences the angle random walk is taken from.
MIN_WITHIN_TICK_DIFFERENCES = 100
_LOCKED = MOTION_STATES.index('locked')
_MAD_TO_SIGMA = 1.482602218505602


def centroid_noise_arcsec(centroids: Centroids) -> np.ndarray:
    """Per-camera centroid noise per axis ["], from second differences of locked frames (robust).

    Args:
        centroids: the bag's star centroids.

    Returns:
        One noise per camera (in ``centroids.cameras`` order) ["], at least ``MIN_NOISE_ARCSEC``.

    Raises:
        BagError: a camera has fewer than 10 locked consecutive frames of one star.
    """
    locked = centroids.motion_code == _LOCKED
    scale = centroids.arcsec_per_px()
    noise = []
    for index, camera in enumerate(centroids.cameras):
        differences = []
        for hip in np.unique(centroids.hip[centroids.camera_index == index]):
            rows = np.flatnonzero((centroids.camera_index == index) & (centroids.hip == hip) & locked)
            if len(rows) < 3:
                continue
            rows = rows[np.argsort(centroids.stamp_s[rows])]
            gaps = np.diff(centroids.frame_index[rows])
            consecutive = (gaps[:-1] == 1) & (gaps[1:] == 1)
            positions = centroids.measured_px[rows] * scale[rows, None]
            second = positions[2:] - 2.0 * positions[1:-1] + positions[:-2]
            differences.append(second[consecutive].ravel())
        values = np.concatenate(differences) if differences else np.empty(0)
        if len(values) < 10:
            raise BagError(f'camera {camera}: fewer than 10 locked consecutive frames of one star; '
                           'cannot estimate its centroid noise')
        mad = np.median(np.abs(values - np.median(values)))
        noise.append(max(_MAD_TO_SIGMA * mad / np.sqrt(6.0), MIN_NOISE_ARCSEC))
    return np.array(noise)


def angle_random_walk_rad_per_sqrt_s(gyro: GyroSamples) -> float:
    """Angle random walk N = sigma_rate sqrt(dt) of the worst gyro axis (4.2.3), from the within-tick rate noise the
    decoding measured (sensors.gyro_noise.within_tick_rate_sigma_rad_per_s).

    Args:
        gyro: the bag's gyro samples.

    Returns:
        N of the noisiest axis (rad/sqrt(s)).

    Raises:
        BagError: fewer than MIN_WITHIN_TICK_DIFFERENCES gyro sample pairs fall within ticks.
    """
    if gyro.within_tick_difference_count < MIN_WITHIN_TICK_DIFFERENCES:
        raise BagError(f'fewer than {MIN_WITHIN_TICK_DIFFERENCES} gyro samples within ticks; cannot estimate the '
                       'angle random walk')
    return float(np.max(gyro.within_tick_rate_sigma_rad_per_s) * np.sqrt(gyro.sample_period_s))


def anchor_walk_sigma_rad(arw_rad_per_sqrt_s: float, rrw_rad_per_s_sqrt_s: float, spacing_s: float) -> float:
    """Attitude random walk between anchor knots: sqrt(N^2 dt + K^2 dt^3 / 3) (4.2.3, Table 4.1).

    Args:
        arw_rad_per_sqrt_s: angle random walk N (rad/sqrt(s)).
        rrw_rad_per_s_sqrt_s: rate random walk K (rad/s/sqrt(s)).
        spacing_s: the knot spacing dt (s).

    Returns:
        The attitude's standard deviation over one spacing (rad).
    """
    return float(np.sqrt(arw_rad_per_sqrt_s**2 * spacing_s + rrw_rad_per_s_sqrt_s**2 * spacing_s**3 / 3.0))
