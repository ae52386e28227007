"""Quasi-static flexure against Tables 3.2/3.3 and the closed forms 3.24/3.25, 3.28/3.29."""

import numpy as np
import pytest

from sofia_ros import flexure
from sofia_ros.errors import InvalidArgumentError

ELEVATIONS_DEG = np.linspace(20.0, 60.0, 9)


def test_gravity_load_matches_the_load_cases_of_3_24():
    # 0 g along u, 1 g cos(el) along v, 1 g sin(el) along -w (text under eq. 3.25)
    load = flexure.gravity_load_tarf(30.0) / 9.80665
    np.testing.assert_allclose(load, [0.0, np.cos(np.radians(30)), -np.sin(np.radians(30))], atol=1e-15)


def test_equations_3_22_3_23_reduce_to_the_printed_closed_forms_3_24_3_25():
    # expected coefficients: eq. 3.24 phi_V = -2.107 cos - 0.612 sin; eq. 3.25 phi_W = -0.061 cos + 69.902 sin
    general = flexure.focal_plane_image_motion(flexure.gravity_load_tarf(ELEVATIONS_DEG))[:, 1:]
    closed = flexure.focal_plane_image_motion_at_elevation(ELEVATIONS_DEG)
    np.testing.assert_allclose(general, closed, atol=1e-12)
    el = np.radians(ELEVATIONS_DEG)
    np.testing.assert_allclose(closed[:, 1], 69.902 * np.sin(el) - 0.061 * np.cos(el), atol=1e-12)
    np.testing.assert_allclose(closed[:, 0], -2.107 * np.cos(el) - 0.612 * np.sin(el), atol=1e-12)


def test_unit_load_cases_return_the_columns_of_table_3_2():
    g = 9.80665
    for column, load in enumerate(np.eye(3) * g):
        np.testing.assert_allclose(flexure.focal_plane_image_motion(load), flexure.FOCAL_PLANE_LOAD_MATRIX[:, column])
    # Table 3.2, 1 g along w: focus +10.952 mm, phi_W -69.902"
    motion = flexure.focal_plane_image_motion([0.0, 0.0, g])
    assert motion[0] == pytest.approx(10.952)
    assert motion[2] == pytest.approx(-69.902)


@pytest.mark.parametrize('imager', ['ffi', 'wfi'])
def test_equations_3_26_3_27_reduce_to_3_28_3_29(imager):
    general = flexure.imager_rotation_arcsec(imager, flexure.gravity_load_tarf(ELEVATIONS_DEG))[:, :2]
    closed = flexure.imager_rotation_at_elevation_arcsec(imager, ELEVATIONS_DEG)
    np.testing.assert_allclose(general, closed, atol=1e-12)


def test_table_3_3_values_are_kept_in_the_corrected_wfi_ffi_order():
    # Table 3.3, load case 1 g along w: WFI rot(v) = 54.04", FFI rot(w) = -26.61"
    g = 9.80665
    assert flexure.imager_rotation_arcsec('wfi', [0, 0, g])[1] == pytest.approx(54.04)
    assert flexure.imager_rotation_arcsec('ffi', [0, 0, g])[2] == pytest.approx(-26.61)
    assert flexure.imager_rotation_arcsec('ffi', [0, g, 0])[0] == pytest.approx(6.91)


def test_fem_predicts_about_nine_arcsec_ffi_xel_differential_flexure_from_23_to_60_deg():
    # Section 6.2: FFI boresight moves ~9" in XEL relative to HIPO over 23-60 deg and the
    # FEM predictions "agree reasonably well"; this pins the image-motion sign conventions.
    reference = flexure.gravity_load_tarf(23.0)
    change = flexure.differential_imager_rotation_arcsec('ffi', flexure.gravity_load_tarf(60.0), reference)
    assert change[1] == pytest.approx(8.95, abs=0.05)
    assert abs(change[0]) < 4.0


def test_differential_flexure_vanishes_at_the_reference_elevation():
    reference = flexure.gravity_load_tarf(30.0)
    np.testing.assert_allclose(flexure.differential_imager_rotation_arcsec('ffi', reference, reference), 0.0)
    np.testing.assert_allclose(flexure.referenced_focal_plane_rotation_arcsec(reference, reference), 0.0)


def test_referencing_by_load_equals_difference_of_closed_forms_not_elevation_subtraction():
    el0 = 30.0
    referenced = flexure.referenced_focal_plane_rotation_arcsec(
        flexure.gravity_load_tarf(ELEVATIONS_DEG), flexure.gravity_load_tarf(el0)
    )
    difference = -(flexure.focal_plane_image_motion_at_elevation(ELEVATIONS_DEG)
                   - flexure.focal_plane_image_motion_at_elevation(el0))
    np.testing.assert_allclose(referenced, difference, atol=1e-12)
    # Subtracting el0 from el inside 3.24/3.25 (the text's shortcut) differs by arcseconds.
    shortcut = -flexure.focal_plane_image_motion_at_elevation(ELEVATIONS_DEG - el0)
    assert np.max(np.abs(shortcut - referenced)) > 1.0


def test_specific_force_is_the_negative_gravity_load():
    load = flexure.gravity_load_tarf(40.0)
    np.testing.assert_allclose(flexure.gravity_load_from_specific_force(-load), load)


def test_unknown_imager_is_refused():
    with pytest.raises(InvalidArgumentError, match="imager must be one of"):
        flexure.imager_rotation_arcsec('hipo', [0, 0, 9.8])


def test_load_vector_must_have_three_components():
    with pytest.raises(InvalidArgumentError, match='3-vector'):
        flexure.focal_plane_image_motion([0.0, 9.8])


def test_nan_elevation_is_refused():
    with pytest.raises(InvalidArgumentError, match='elevation_deg contains NaN'):
        flexure.focal_plane_image_motion_at_elevation(float('nan'))
