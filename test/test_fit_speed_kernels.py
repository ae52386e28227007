"""The cost of one fit iteration (issue 27): the cheaper kernels and caches against independent computations."""

import dataclasses

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from sofia_ros.compare.observations import decode_observations
from sofia_ros.compare.predict import Predictor, _bytes_digest
from sofia_ros.effects import resolve_params
from sofia_ros.frames import FFI, FPI, HIPO_2004, WFI, vector_to_pixel
from sofia_ros.sensors.imager_model import (
    _NOT_MOUNTING_FIELDS,
    camera_errors,
    camera_from_tarf_dcm,
    flexure_dcm,
    flexure_key,
    mounted_dcm,
    mounting_key,
)
from sofia_ros.units import RAD_PER_ARCSEC


@pytest.mark.parametrize('detector', [HIPO_2004, FPI, FFI, WFI], ids=lambda d: d.name)
def test_vector_to_pixel_solves_the_detector_plane_equations(detector):
    rng = np.random.default_rng(3)
    vectors = np.column_stack([rng.normal(scale=2e-3, size=(500, 2)), np.ones(500)])
    vectors /= np.linalg.norm(vectors, axis=1, keepdims=True)
    # Independently: the plane point (u/w, v/w) / S = M (X - X0, Y - Y0), solved by LAPACK (eqs. 3.2-3.7).
    plane = vectors[:, :2] / (vectors[:, 2:] * detector.scale_rad_per_px)
    expected = np.linalg.solve(detector._plane_matrix(), plane.T).T + detector.center_px
    np.testing.assert_allclose(vector_to_pixel(vectors, detector), expected, rtol=0, atol=1e-9)
    np.testing.assert_allclose(vector_to_pixel(vectors[0], detector), expected[0], rtol=0, atol=1e-9)


#: Every effect that reaches a camera's errors, at its catalogue values.
_ALL_CAMERA_EFFECTS = ('imager_boresight_offset', 'imager_rotation_of_field', 'focal_plane_flexure',
                       'fpi_internal_flexure', 'imager_flexure', 'seeing', 'timestamp_offset',
                       'atmospheric_refraction', 'hipo_fiducial_error', 'imager_scale_error')


def _errors(camera, **changed):
    effects = {name: resolve_params(name, {}) for name in _ALL_CAMERA_EFFECTS}
    for name, params in changed.items():
        effects[name] = {**effects[name], **params}
    return camera_errors(camera, effects)


def _independent_mounting(errors, elevation_deg):
    """A(rotation of field) A(boresight) A(flexure) composed by scipy alone (3.3.1, 3.3.3, 3.4.1)."""
    from sofia_ros.sensors.imager_model import flexure_rotation_arcsec

    flexure = Rotation.from_rotvec(flexure_rotation_arcsec(errors, elevation_deg) * RAD_PER_ARCSEC).inv()
    boresight = Rotation.from_rotvec(np.array([*errors.boresight_el_xel_arcsec, 0.0]) * RAD_PER_ARCSEC).inv()
    field = Rotation.from_rotvec([0.0, 0.0, np.radians(errors.rotation_of_field_deg)]).inv()
    return (field * boresight * flexure).as_matrix()


@pytest.mark.parametrize('camera', ['fpi', 'ffi', 'wfi', 'hipo'])
def test_a_mounting_kept_by_its_key_is_the_one_its_errors_give(camera):
    elevation = np.linspace(22.0, 58.0, 40)
    base = _errors(camera)
    np.testing.assert_allclose(camera_from_tarf_dcm(base, elevation), _independent_mounting(base, elevation),
                               rtol=0, atol=1e-13)
    # What acts after the frame, on the centroids or on the stars: the same key, the same frame.
    for changed in (_errors(camera, hipo_fiducial_error={'center_x_px': 3.0}),
                    _errors(camera, imager_scale_error={f'{camera}_ppm': 300.0} if camera != 'hipo' else {}),
                    _errors(camera, seeing={'rms_arcsec': 0.9}), _errors(camera, timestamp_offset={'offset_s': 0.4}),
                    _errors(camera, atmospheric_refraction={'pressure_hpa': 200.0})):
        assert mounting_key(changed) == mounting_key(base)
        np.testing.assert_array_equal(camera_from_tarf_dcm(changed, elevation), camera_from_tarf_dcm(base, elevation))
    # What turns the frame changes its key; a fixed mounting leaves the flexure's.
    flexure = flexure_dcm(base, elevation)
    if camera != 'hipo':
        for fixed in (_errors(camera, imager_boresight_offset={f'{camera}_el_arcsec': -40.0}),
                      _errors(camera, imager_rotation_of_field={f'{camera}_deg': 2.0})):
            assert mounting_key(fixed) != mounting_key(base) and flexure_key(fixed) == flexure_key(base)
            np.testing.assert_allclose(mounted_dcm(fixed, flexure), _independent_mounting(fixed, elevation),
                                       rtol=0, atol=1e-13)
    bent = _errors(camera, focal_plane_flexure={'scale': 1.5}, imager_flexure={'ffi_scale': 2.0, 'wfi_scale': 2.0})
    assert mounting_key(bent) != mounting_key(base) and flexure_key(bent) != flexure_key(base)
    assert not np.allclose(flexure_dcm(bent, elevation), flexure, rtol=0, atol=1e-12)


def test_every_camera_error_but_those_named_counts_for_the_mounting():
    base = _errors('fpi')
    for field in dataclasses.fields(base):
        if field.name in {'camera', 'detector', 'plugins', 'shift_plugins', 'weather'}:
            continue  # not a number to nudge: the camera, the geometry, the hooks, a record
        value = getattr(base, field.name)
        nudged = tuple(v + 1.0 for v in value) if isinstance(value, tuple) else value + 1.0
        changed = dataclasses.replace(base, **{field.name: nudged})
        assert (mounting_key(changed) == mounting_key(base)) == (field.name in _NOT_MOUNTING_FIELDS), field.name


@pytest.fixture(scope='module')
def predictor_effects(campaign_bags):
    observations = decode_observations(campaign_bags.reduced_alignment())
    effects = {name: resolve_params(name, {}) for name in ('earth_rotation', 'atmospheric_refraction',
                                                            'focal_plane_flexure', 'imager_flexure',
                                                            'gyro_misalignment', 'timestamp_offset',
                                                            'hipo_fiducial_error', 'imager_boresight_offset')}
    return observations, effects


def test_predictions_through_the_kept_mountings_and_row_times_are_a_fresh_predictors(predictor_effects):
    observations, effects = predictor_effects
    predictor = Predictor(observations)
    anchors = np.random.default_rng(4).normal(scale=1e-5, size=(predictor.anchor_count, 3))
    # A fiducial, a boresight offset and a clock offset stepped in turn, each predicted where the previous
    # prediction left the caches, against a predictor that has kept nothing.
    steps = [('hipo_fiducial_error', 'center_x_px', 2.0), ('imager_boresight_offset', 'wfi_el_arcsec', 30.0),
             ('timestamp_offset', 'offset_s', 0.05), ('hipo_fiducial_error', 'center_x_px', -2.0)]
    predictor.predict_px(effects, anchors)
    for effect, name, step in steps:
        effects = {**effects, effect: {**effects[effect], name: effects[effect][name] + step}}
        np.testing.assert_array_equal(predictor.predict_px(effects, anchors),
                                      Predictor(observations).predict_px(effects, anchors))


def test_row_times_are_kept_read_only_and_keyed_by_their_digest(predictor_effects):
    observations, effects = predictor_effects
    predictor = Predictor(observations)
    times = predictor.row_times_s(effects)
    assert predictor.row_times_s(effects) is times
    with pytest.raises(ValueError, match='read-only'):
        times[0] = 0.0
    assert predictor._times_digest(times) == _bytes_digest(times)
    moved = predictor.row_times_s({**effects, 'timestamp_offset': {'offset_s': 0.25}})
    hipo = observations.centroids.camera_index == observations.centroids.cameras.index('hipo')
    np.testing.assert_array_equal(moved, np.where(hipo, observations.centroids.stamp_s - 0.25,
                                                  observations.centroids.stamp_s))
    assert predictor._times_digest(moved) == _bytes_digest(moved) != _bytes_digest(times)
    # An array that is not one the predictor keeps is hashed as it is now.
    other = np.array(times)
    assert predictor._times_digest(other) == _bytes_digest(times)
    other[0] += 1.0
    assert predictor._times_digest(other) == _bytes_digest(other)


def test_without_a_fixed_mounting_a_camera_is_mounted_by_its_flexure_alone():
    elevation = np.linspace(22.0, 58.0, 40)
    errors = _errors('fpi', imager_boresight_offset={'fpi_el_arcsec': 0.0, 'fpi_xel_arcsec': 0.0},
                     imager_rotation_of_field={'fpi_deg': 0.0})
    flexure = flexure_dcm(errors, elevation)
    assert mounted_dcm(errors, flexure) is flexure
    np.testing.assert_allclose(camera_from_tarf_dcm(errors, elevation), _independent_mounting(errors, elevation),
                               rtol=0, atol=1e-13)


def test_kept_resolved_parameters_are_resolve_params_own_and_each_caller_gets_a_copy():
    from sofia_ros.effects import resolve_params
    from sofia_ros.errors import ConfigError
    from sofia_ros.sensors.imager_model import _resolved_params

    given = {'fpi_deg': 0.25, 'wfi_deg': 1}
    first = _resolved_params('imager_rotation_of_field', given)
    assert first == resolve_params('imager_rotation_of_field', given)
    first['fpi_deg'] = 99.0
    assert _resolved_params('imager_rotation_of_field', given)['fpi_deg'] == 0.25
    # What repr tells apart is resolved apart: a bool where a number belongs is refused each time, never kept.
    for _ in range(2):
        with pytest.raises(ConfigError, match='fpi_deg'):
            _resolved_params('imager_rotation_of_field', {'fpi_deg': True})
    assert camera_errors('fpi', {'imager_rotation_of_field': given}) == camera_errors(
        'fpi', {'imager_rotation_of_field': resolve_params('imager_rotation_of_field', given)})
