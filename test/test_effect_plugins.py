"""Effect plug-ins: one module adds an effect that the simulator, `sofia effects` and `sofia compare` all use.

The example plug-in is examples/effects/ffi_field_flexure.py (a FFI twist about the LOS
proportional to the LOS gravity load, 600"/g by default). Hidden in a reduced alignment
campaign (direct mode, 2 repetitions) and absent from config/model/nominal.yaml, it must come
out as the top candidate within 3 sigma of its truth value, as the built-in effects do in
test_compare.py.
"""

import importlib
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest
import yaml

from sofia_ros.campaigns.alignment import run_alignment
from sofia_ros.compare.run import compare_bag
from sofia_ros.config import load_effect_config
from sofia_ros.effects import CATALOGUE, PLUGIN_ENVIRONMENT_VARIABLE, load_catalogue
from sofia_ros.errors import ConfigError
from sofia_ros.sensors.gyro_errors import gyro_error_model, measured_rates_gyrf_rad_per_s, true_rates_tarf_rad_per_s
from sofia_ros.sensors.imager_model import camera_errors, flexure_rotation_arcsec
from sofia_ros.sim.calibration import AlignmentPlan

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / 'examples' / 'effects'


@pytest.fixture
def example_plugin(monkeypatch):
    """The example plug-in in the catalogue of this process, as SOFIA_EFFECT_MODULES would put it."""
    monkeypatch.syspath_prepend(str(EXAMPLES))
    module = importlib.import_module('ffi_field_flexure')
    for spec in module.EFFECTS:
        monkeypatch.setitem(CATALOGUE, spec.name, spec)
    return module


def _write_module(folder, name, text):
    (folder / f'{name}.py').write_text(textwrap.dedent(text))
    return name


def test_sofia_effects_lists_a_plugin_named_in_the_environment():
    environment = {**os.environ, PLUGIN_ENVIRONMENT_VARIABLE: 'ffi_field_flexure',
                   'PYTHONPATH': os.pathsep.join([str(EXAMPLES), os.environ.get('PYTHONPATH', '')])}
    result = subprocess.run([sys.executable, '-m', 'sofia_ros.cli', 'effects'], capture_output=True, text=True,
                            env=environment, timeout=60)
    assert result.returncode == 0, result.stderr
    assert 'ffi_field_flexure  [flexure; thesis 6.2 (plug-in example)]' in result.stdout
    assert 'los_arcsec_per_g = 600.0 arcsec/g' in result.stdout


def test_camera_hook_adds_to_the_flexure_of_its_camera_only(example_plugin):
    effects = {'ffi_field_flexure': {'los_arcsec_per_g': 600.0}}
    elevation_deg = np.array([23.0, 60.0])
    ffi = flexure_rotation_arcsec(camera_errors('ffi', effects), elevation_deg)
    # 600"/g times the LOS load sin(el) in g, about the LOS only.
    np.testing.assert_allclose(ffi[:, 2], 600.0 * np.sin(np.radians(elevation_deg)), atol=1e-9)
    np.testing.assert_allclose(ffi[:, :2], 0.0, atol=1e-12)
    np.testing.assert_allclose(flexure_rotation_arcsec(camera_errors('fpi', effects), elevation_deg), 0.0,
                               atol=1e-12)


def test_gyro_hook_is_read_by_the_box_and_removed_by_the_model(tmp_path, monkeypatch):
    name = _write_module(tmp_path, 'thermal_bias_plugin', '''
        import numpy as np
        from sofia_ros.effects import EffectSpec, Parameter

        def thermal_bias_rad_per_s(params, times_s, temperature_c):
            """EL rate bias proportional to the temperature above 20 C."""
            offsets = np.zeros((len(times_s), 3))
            offsets[:, 0] = params['el_rad_per_s_per_c'] * (temperature_c - 20.0)
            return offsets

        EFFECTS = (EffectSpec('gyro_thermal_bias', 'gyro', 'test', 'thermal bias',
                              (Parameter('el_rad_per_s_per_c', 1e-7, 'rad/s/C', 'EL bias slope'),),
                              gyro_rate_offset=thermal_bias_rad_per_s),)
    ''')
    monkeypatch.syspath_prepend(str(tmp_path))
    catalogue = load_catalogue({PLUGIN_ENVIRONMENT_VARIABLE: name})
    monkeypatch.setitem(CATALOGUE, 'gyro_thermal_bias', catalogue['gyro_thermal_bias'])
    model = gyro_error_model({'gyro_thermal_bias': {'el_rad_per_s_per_c': 1e-7}})
    true_rates = np.tile([1e-3, -2e-3, 5e-4], (3, 1))
    times_s, temperature_c = np.array([0.0, 1.0, 2.0]), np.array([20.0, 25.0, 30.0])
    measured = measured_rates_gyrf_rad_per_s(model, true_rates, times_s, temperature_c)
    np.testing.assert_allclose(measured[:, 0] - true_rates[:, 0], [0.0, 5e-7, 1e-6], atol=1e-15)
    np.testing.assert_allclose(true_rates_tarf_rad_per_s(model, measured, times_s, temperature_c), true_rates,
                               atol=1e-15)


@pytest.mark.parametrize('text, message', [
    ('EFFECTS = []\n', 'must define EFFECTS as a tuple of EffectSpec'),
    ('from sofia_ros.effects import EffectSpec\nEFFECTS = (EffectSpec("gyro_bias", "gyro", "", ""),)\n',
     "'gyro_bias' is already in the catalogue; rename it"),
    ('from sofia_ros.effects import EffectSpec\nEFFECTS = (EffectSpec("no_physics", "gyro", "", ""),)\n',
     "'no_physics' needs exactly one callable hook"),
])
def test_malformed_plugins_are_refused_with_the_fix(tmp_path, monkeypatch, text, message):
    name = f'plugin_{abs(hash(text))}'
    (tmp_path / f'{name}.py').write_text(text)
    monkeypatch.syspath_prepend(str(tmp_path))
    with pytest.raises(ConfigError, match=message):
        load_catalogue({PLUGIN_ENVIRONMENT_VARIABLE: name})


def test_a_plugin_that_cannot_be_imported_is_one_line_and_exit_2():
    environment = {**os.environ, PLUGIN_ENVIRONMENT_VARIABLE: 'no_such_plugin_module'}
    result = subprocess.run([sys.executable, '-m', 'sofia_ros.cli', 'effects'], capture_output=True, text=True,
                            env=environment, timeout=60)
    assert result.returncode == 2
    assert result.stderr.strip() == ("sofia: error: SOFIA_EFFECT_MODULES: cannot import 'no_such_plugin_module' "
                                     "(No module named 'no_such_plugin_module'); put its folder on PYTHONPATH")


def test_a_hidden_plugin_effect_is_the_top_candidate_within_three_sigma(tmp_path, example_plugin):
    nominal = yaml.safe_load((ROOT / 'config' / 'truth' / 'nominal.yaml').read_text())['effects']
    truth = load_effect_config(EXAMPLES / 'truth-ffi-field-flexure.yaml')
    # The example truth is the nominal one plus the plug-in.
    assert set(truth.effects) == {*nominal, 'ffi_field_flexure'}
    bag = tmp_path / 'bag'
    run_alignment(truth, seed=3, bag_path=bag, plan=AlignmentPlan(repetitions=2, verification_repetitions=1),
                  mode='direct')
    result = compare_bag(bag, load_effect_config(ROOT / 'config' / 'model' / 'nominal.yaml')).document
    top = result['candidates'][0]
    assert top['effect'] == 'ffi_field_flexure', [(c['effect'], round(c['delta_bic'])) for c in result['candidates'][:3]]
    assert top['delta_bic'] >= 6.0 and top['refined']
    value, sigma = top['params']['los_arcsec_per_g'], top['sigma']['los_arcsec_per_g']
    assert abs(value - 600.0) <= 3.0 * sigma, (value, sigma)
    assert top['rms_after_arcsec'] <= 1.2 * result['noise_floor_arcsec']
