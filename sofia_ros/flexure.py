"""Quasi-static gravity flexure of the telescope (section 3.4, Tables 3.2 and 3.3).

Conventions, derived from the load cases of 3.4.1:

* ``gravity_tarf`` is the gravity load acceleration in TARF (u = EL, v = XEL,
  w = LOS) in m/s^2. At elevation ``el`` with a level EL axis it is
  ``(0, g cos el, -g sin el)`` - the load cases under eqs. 3.24 and 3.28.
  Accelerometers measure specific force, the negative of this at rest
  (eq. 2.13), see :func:`gravity_load_from_specific_force`.
* Table 3.2 gives focal-plane *image* motion: phi_V = -dEL, phi_W = -dXEL
  (the table's labels; the sentence after it says -dXEL twice, a slip).
  The equivalent telescope rotation is therefore (dEL, dXEL) = (-phi_V, -phi_W).
* Table 3.3 gives head-ring imager *displacements* as rotations about the TARF
  axes; the imager boresight moves with them and the image the other way.

With these signs the FEM predicts the FFI boresight moving by about 9" in XEL
relative to the focal plane between 23 and 60 deg - what section 6.2 measured.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sofia_ros.errors import InvalidArgumentError
from sofia_ros.units import RAD_PER_DEG, STANDARD_GRAVITY_M_PER_S2
from sofia_ros.validate import finite_array

__all__ = [
    'FOCAL_PLANE_LOAD_MATRIX',
    'ImagerFlexureTable',
    'FFI_FLEXURE',
    'WFI_FLEXURE',
    'IMAGER_FLEXURE',
    'gravity_load_tarf',
    'gravity_load_from_specific_force',
    'focal_plane_image_motion',
    'focal_plane_image_motion_at_elevation',
    'focal_plane_telescope_rotation_arcsec',
    'imager_rotation_arcsec',
    'imager_rotation_at_elevation_arcsec',
    'differential_imager_rotation_arcsec',
    'referenced_focal_plane_rotation_arcsec',
]

#: Table 3.2: rows (focus dU [mm], phi_V ["], phi_W ["]); columns 1 g along u, v, w.
FOCAL_PLANE_LOAD_MATRIX = np.array(
    [
        [-6.200, -0.100, 10.952],
        [0.455, -2.107, 0.612],
        [8.594, -0.061, -69.902],
    ]
)


@dataclass(frozen=True)
class ImagerFlexureTable:
    """Table 3.3 for one head-ring imager: rotations ["] about (u, v, w) per 1 g load along u, v, w."""

    name: str
    #: rows: load case along u, v, w; columns: rot about u, v, w [arcsec]
    rotation_per_g_arcsec: tuple

    def matrix(self):
        """Columns-by-load matrix M so that rot = M @ (acc / g) (eqs. 3.26-3.27)."""
        return np.asarray(self.rotation_per_g_arcsec, dtype=float).T


#: Table 3.3 (WFI and FFI in the corrected order the thesis uses).
WFI_FLEXURE = ImagerFlexureTable('wfi', ((-2.39, -9.96, 8.91), (6.66, -2.83, 70.13), (1.22, 54.04, 24.96)))
FFI_FLEXURE = ImagerFlexureTable('ffi', ((2.68, -13.20, -11.12), (6.91, -3.09, 70.75), (1.96, 53.84, -26.61)))
IMAGER_FLEXURE = {'wfi': WFI_FLEXURE, 'ffi': FFI_FLEXURE}


def gravity_load_tarf(elevation_deg, g_m_per_s2=STANDARD_GRAVITY_M_PER_S2):
    """Gravity load in TARF (0, g cos el, -g sin el) for a level EL axis (load cases of 3.24/3.28)."""
    elevation_rad = finite_array('elevation_deg', elevation_deg) * RAD_PER_DEG
    zero = np.zeros_like(elevation_rad)
    return np.stack([zero, g_m_per_s2 * np.cos(elevation_rad), -g_m_per_s2 * np.sin(elevation_rad)], axis=-1)


def gravity_load_from_specific_force(specific_force_m_per_s2):
    """Gravity load from accelerometer specific force at rest, f = a - g with a = 0 (eq. 2.13)."""
    return -finite_array('specific_force_m_per_s2', specific_force_m_per_s2)


def _load_in_g(gravity_tarf_m_per_s2):
    load = finite_array('gravity_tarf_m_per_s2', gravity_tarf_m_per_s2)
    if load.shape[-1:] != (3,):
        raise InvalidArgumentError(f'gravity_tarf_m_per_s2 must end in a 3-vector, got shape {load.shape}')
    return load / STANDARD_GRAVITY_M_PER_S2


def focal_plane_image_motion(gravity_tarf_m_per_s2):
    """Focus change [mm] and image motion phi_V, phi_W ["] from the load vector (eqs. 3.21-3.23)."""
    return _load_in_g(gravity_tarf_m_per_s2) @ FOCAL_PLANE_LOAD_MATRIX.T


def focal_plane_image_motion_at_elevation(elevation_deg):
    """Image motion phi_V, phi_W ["] at elevation for a level EL axis (eqs. 3.24-3.25)."""
    elevation_rad = finite_array('elevation_deg', elevation_deg) * RAD_PER_DEG
    phi_v = -2.107 * np.cos(elevation_rad) - 0.612 * np.sin(elevation_rad)
    phi_w = -0.061 * np.cos(elevation_rad) + 69.902 * np.sin(elevation_rad)
    return np.stack([phi_v, phi_w], axis=-1)


def focal_plane_telescope_rotation_arcsec(gravity_tarf_m_per_s2):
    """Equivalent telescope rotation (dEL, dXEL) ["] = (-phi_V, -phi_W) at the focal plane (Table 3.2)."""
    return -focal_plane_image_motion(gravity_tarf_m_per_s2)[..., 1:]


def imager_rotation_arcsec(imager, gravity_tarf_m_per_s2):
    """Head-ring imager rotation about (u, v, w) ["] from the load vector (eqs. 3.26-3.27)."""
    table = IMAGER_FLEXURE.get(imager)
    if table is None:
        raise InvalidArgumentError(f'imager must be one of {sorted(IMAGER_FLEXURE)}, got {imager!r}')
    return _load_in_g(gravity_tarf_m_per_s2) @ table.matrix().T


def imager_rotation_at_elevation_arcsec(imager, elevation_deg):
    """Head-ring imager rotation about u and v ["] at elevation for a level EL axis (eqs. 3.28-3.29)."""
    table = IMAGER_FLEXURE.get(imager)
    if table is None:
        raise InvalidArgumentError(f'imager must be one of {sorted(IMAGER_FLEXURE)}, got {imager!r}')
    elevation_rad = finite_array('elevation_deg', elevation_deg) * RAD_PER_DEG
    rows = np.asarray(table.rotation_per_g_arcsec)
    rot_u = np.cos(elevation_rad) * rows[1, 0] + np.sin(elevation_rad) * (-rows[2, 0])
    rot_v = np.cos(elevation_rad) * rows[1, 1] + np.sin(elevation_rad) * (-rows[2, 1])
    return np.stack([rot_u, rot_v], axis=-1)


def differential_imager_rotation_arcsec(imager, gravity_tarf_m_per_s2, reference_gravity_tarf_m_per_s2):
    """Imager boresight motion (dEL, dXEL) ["] relative to the focal plane, aligned at el0 (3.4.2, Fig. 3.17)."""
    change = finite_array('gravity_tarf_m_per_s2', gravity_tarf_m_per_s2) - finite_array(
        'reference_gravity_tarf_m_per_s2', reference_gravity_tarf_m_per_s2
    )
    imager_uv = imager_rotation_arcsec(imager, change)[..., :2]
    return imager_uv - focal_plane_telescope_rotation_arcsec(change)


def referenced_focal_plane_rotation_arcsec(gravity_tarf_m_per_s2, reference_gravity_tarf_m_per_s2):
    """Focal-plane telescope rotation (dEL, dXEL) ["] with the load at el0 subtracted (3.4.2).

    Subtracting the load vector is exact because 3.21-3.23 are linear. Subtracting
    el0 from the elevation inside 3.24/3.25, as the text also suggests, is not the
    same: at el = el0 it leaves phi = (-2.107", -0.061") instead of zero.
    """
    change = finite_array('gravity_tarf_m_per_s2', gravity_tarf_m_per_s2) - finite_array(
        'reference_gravity_tarf_m_per_s2', reference_gravity_tarf_m_per_s2
    )
    return focal_plane_telescope_rotation_arcsec(change)
