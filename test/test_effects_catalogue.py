"""The effect catalogue: contract names, parameter resolution and its errors."""

import pytest

from sofia_ros.effects import CATALOGUE, catalogue_as_json, get_effect, resolve_params
from sofia_ros.errors import ConfigError, UnknownEffectError

# docs/effects.md: names other tools rely on.
CONTRACT_NAMES = {
    'gyro_misalignment', 'gyro_bias', 'gyro_bias_drift', 'gyro_scale_factor', 'gyro_axis_swap', 'gyro_noise',
    'los_oscillation', 'vibration_lines', 'earth_rotation', 'heading_error', 'focal_plane_flexure',
    'imager_flexure', 'fpi_internal_flexure', 'imager_boresight_offset', 'imager_rotation_of_field',
    'imager_scale_error', 'hipo_fiducial_error', 'atmospheric_refraction', 'seeing', 'tracker_drift',
    'timestamp_offset', 'accelerometer_bias', 'accelerometer_misalignment',
}


def test_catalogue_holds_every_contract_name():
    assert CONTRACT_NAMES <= set(CATALOGUE)


def test_json_form_matches_the_contract():
    for entry in catalogue_as_json():
        assert set(entry) == {'name', 'thesis', 'description', 'params'}
        for param in entry['params'].values():
            assert set(param) == {'default', 'unit'}


def test_every_parameter_name_carries_its_unit_or_is_dimensionless():
    for spec in CATALOGUE.values():
        for param in spec.params:
            assert param.unit, f'{spec.name}.{param.name} has no unit'


def test_gyro_misalignment_defaults_are_the_eq_6_1_rotations():
    # docs/conventions.md: eq. 6.1 turns about EL ~1030", XEL ~730", LOS ~3590"
    assert resolve_params('gyro_misalignment', {}) == {
        'about_el_arcsec': 1030.0, 'about_xel_arcsec': 730.0, 'about_los_arcsec': 3590.0,
    }


def test_given_parameters_override_defaults_and_fit_flag_is_accepted():
    params = resolve_params('seeing', {'rms_arcsec': 0.5, 'fit': True})
    assert params == {'rms_arcsec': 0.5}


def test_unknown_effect_suggests_the_closest_name():
    with pytest.raises(UnknownEffectError, match="unknown effect 'gyro_misalign'; did you mean gyro_misalignment"):
        get_effect('gyro_misalign')


def test_unknown_parameter_lists_the_known_ones():
    with pytest.raises(ConfigError, match="unknown parameter 'rms' .known: rms_arcsec"):
        resolve_params('seeing', {'rms': 0.3})


def test_parameter_of_wrong_type_is_refused():
    with pytest.raises(ConfigError, match=r'rms_arcsec must be a number in \[0, 10\] arcsec'):
        resolve_params('seeing', {'rms_arcsec': 'large'})


def test_non_finite_parameter_is_refused():
    with pytest.raises(ConfigError, match='must be finite'):
        resolve_params('seeing', {'rms_arcsec': float('nan')})


def test_parameters_must_be_a_mapping():
    with pytest.raises(ConfigError, match='parameters must be a mapping'):
        resolve_params('seeing', [0.3])


def test_fit_flag_must_be_boolean():
    with pytest.raises(ConfigError, match='fit must be true or false'):
        resolve_params('seeing', {'fit': 'yes'})


def test_docs_effects_lists_the_catalogue_as_sofia_effects_prints_it():
    from pathlib import Path

    page = (Path(__file__).resolve().parents[1] / 'docs' / 'effects.md').read_text()
    for entry in catalogue_as_json():
        params = ', '.join(f"{name} ({param['unit']}, {param['default']})" for name, param in entry['params'].items())
        assert f"| `{entry['name']}` | {entry['thesis']} | {entry['description']} | {params} |" in page
