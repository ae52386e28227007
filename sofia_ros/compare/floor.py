"""The noise floor of a bag, from the data alone: centroid scatter per camera while locked (6.1).

For one star in consecutive frames of one camera while the TASCU reports "locked", the
second difference x[i+1] - 2 x[i] + x[i-1] removes the star's slow motion (drift, the sky)
and leaves white centroid noise with variance 6 sigma^2. The median absolute deviation makes
the estimate robust against a frame caught in a servo transient. The gyro random walk over
the anchor spacing is small against it (0.0132"/sqrt(s) x sqrt(120 s / 6) = 0.06", Table 5.1).
"""

from __future__ import annotations

import numpy as np

from sofia_ros.compare.observations import MOTION_STATES
from sofia_ros.errors import BagError

__all__ = ['centroid_noise_arcsec', 'MIN_NOISE_ARCSEC']

#: Below this the centroid noise is quantization-free simulation; weights must stay finite.
MIN_NOISE_ARCSEC = 1e-3
_LOCKED = MOTION_STATES.index('locked')
_MAD_TO_SIGMA = 1.482602218505602


def centroid_noise_arcsec(centroids):
    """Per-camera centroid noise per axis ["], from second differences of locked frames (robust)."""
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
