"""A plug-in effect in one module: the FFI's rotation of field follows the gravity load along the LOS.

The thesis measured the FFI boresight against HIPO over 23-60 deg of elevation (6.2, Fig. 6.4)
but not its rotation of field, which the calibration sets once at one elevation (3.3.3,
Table 3.4 step 4). If the head-ring mount twists with the LOS load, the field rotation set at
one elevation is wrong at another. Use it with

    SOFIA_EFFECT_MODULES=ffi_field_flexure PYTHONPATH=examples/effects sofia effects
"""

import numpy as np

from sofia_ros.effects import EffectSpec, Parameter
from sofia_ros.flexure import gravity_load_tarf
from sofia_ros.units import STANDARD_GRAVITY_M_PER_S2


def ffi_field_rotation_arcsec(params, context):
    """Rotation (EL, XEL, LOS) ["] of the FFI frame: a LOS twist proportional to the LOS load (cf. 6.2)."""
    load = gravity_load_tarf(context.elevation_deg)
    rotation = np.zeros(load.shape)
    if context.camera == 'ffi':
        rotation[:, 2] = params['los_arcsec_per_g'] * -load[:, 2] / STANDARD_GRAVITY_M_PER_S2
    return rotation


EFFECTS = (
    EffectSpec(
        'ffi_field_flexure', 'flexure', '6.2 (plug-in example)',
        'FFI rotation of field that changes with the gravity load along the LOS (sin of elevation): '
        'a head-ring mount twist the FEM of Table 3.3 does not carry.',
        (Parameter('los_arcsec_per_g', 600.0, 'arcsec/g', 'FFI twist about the LOS per 1 g load along -LOS'),),
        camera_rotation=ffi_field_rotation_arcsec,
    ),
)
