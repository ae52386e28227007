"""Each imager's boresight against HIPO over elevation (Table 3.5, 6.2, Fig. 6.4) and its fit about el0.

Shared by the calibration node, which measures the series live, and by ``sofia compare``'s
star-hop analysis, which measures it again from a bag.
"""

from __future__ import annotations

from typing import Any, Mapping, Sequence

import numpy as np

from sofia_ros.control.tracker import pixel_jacobian_px_per_rad
from sofia_ros.units import ARCSEC_PER_RAD

__all__ = ['boresight_shift_arcsec', 'flexure_fit']


def boresight_shift_arcsec(camera: str, pixel: Sequence[float], boresight_px: Sequence[float]) -> np.ndarray:
    """Imager rotation (dEL, dXEL) ["] against HIPO since el0, from the HIPO-centred star's pixel (3.2-3.4, 6.2).

    A camera turned by theta against the focal plane sees the star as if the telescope had turned
    by theta, so the offset from the el0 boresight, mapped back through the pixel geometry, is the
    differential flexure of Fig. 3.17 (right) and Fig. 6.4.
    """
    jacobian = pixel_jacobian_px_per_rad(camera, boresight_px, np.eye(3))[:, :2]
    return np.linalg.solve(jacobian, np.asarray(pixel) - np.asarray(boresight_px)) * ARCSEC_PER_RAD


def flexure_fit(rows: Sequence[Mapping[str, Any]], camera: str, reference_elevation_deg: float) -> dict:
    """Least-squares p cos(el) + q sin(el) about el0 per axis (the form of 3.28/3.29 with 3.4.2)."""
    elevations = np.radians([row['elevation_deg'] for row in rows])
    el0 = np.radians(reference_elevation_deg)
    design = np.column_stack([np.cos(elevations) - np.cos(el0), np.sin(elevations) - np.sin(el0)])
    shifts = np.array([row[camera] for row in rows])
    coefficients, *_ = np.linalg.lstsq(design, shifts, rcond=None)
    span = np.radians([23.0, 60.0])
    change = (np.column_stack([np.cos(span), np.sin(span)]) @ coefficients)
    return {'el_arcsec_cos_sin': coefficients[:, 0].tolist(), 'xel_arcsec_cos_sin': coefficients[:, 1].tolist(),
            'change_23_to_60_deg_arcsec': (change[1] - change[0]).tolist(),
            'rms_residual_arcsec': float(np.sqrt(np.mean((design @ coefficients - shifts) ** 2)))}
