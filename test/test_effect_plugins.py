"""Effect plug-ins: one module adds an effect that the simulator, `sofia effects` and `sofia compare` all use.

The example plug-in is examples/effects/ffi_field_flexure.py (a FFI twist about the LOS
proportional to the LOS gravity load, 600"/g by default). Hidden in a reduced alignment
campaign (direct mode, 2 repetitions) and absent from config/model/nominal.yaml, it must come
out as the top candidate within 3 sigma of its truth value, as the built-in effects do in
test_compare.py.
"""

import dataclasses
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

        def thermal_bias_rad_per_s(params, context):
            """EL rate bias proportional to the temperature above 20 C."""
            offsets = np.zeros((len(context), 3))
            offsets[:, 0] = params['el_rad_per_s_per_c'] * (context.temperature_c - 20.0)
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
     "'no_physics' needs a callable hook"),
    ('from sofia_ros.effects import EffectSpec\nEFFECTS = (EffectSpec("empirical:x", "gyro", "", "", (), abs),)\n',
     'uses the reserved prefix "empirical:"'),
    ('EFFECTS = (\n', r"importing 'plugin_\d+' failed \(SyntaxError: "),
    ('raise RuntimeError("no calibration table")\n',
     r"importing 'plugin_\d+' failed \(RuntimeError: no calibration table\); fix the module"),
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


def _gyro_plugin(tmp_path, monkeypatch, name, body):
    """A gyro plug-in whose hook body is given, registered in this process's catalogue."""
    module = _write_module(tmp_path, f'{name}_{abs(hash(body))}', f'''
        import numpy as np
        from sofia_ros.effects import EffectSpec, Parameter

        def hook(params, context):
            {body}

        EFFECTS = (EffectSpec({name!r}, 'gyro', 'test', 'test hook',
                              (Parameter('k', 1.0, '1', 'gain'),), gyro_rate_offset=hook),)
    ''')
    monkeypatch.syspath_prepend(str(tmp_path))
    spec = load_catalogue({PLUGIN_ENVIRONMENT_VARIABLE: module})[name]
    monkeypatch.setitem(CATALOGUE, name, spec)
    return gyro_error_model({name: {'k': 1.0}})


@pytest.mark.parametrize('body, message', [
    ('raise RuntimeError("table missing")', "effect 'bad_hook': its gyro_rate_offset hook raised RuntimeError: "
                                            "table missing; fix the plug-in"),
    ('return np.zeros((len(context), 2))', r"returned shape \(3, 2\) for 3 rows; it must return \(3, 3\)"),
    ('return np.full((len(context), 3), np.nan)', 'returned NaN or inf'),
])
def test_a_failing_hook_is_one_line_naming_the_plugin(tmp_path, monkeypatch, body, message):
    model = _gyro_plugin(tmp_path, monkeypatch, 'bad_hook', body)
    with pytest.raises(ConfigError, match=message):
        measured_rates_gyrf_rad_per_s(model, np.zeros((3, 3)), np.arange(3.0), np.full(3, 20.0))


def test_a_gyro_hook_sees_the_specific_force_and_may_scale_the_rate(tmp_path, monkeypatch):
    # g-sensitivity on LOS plus a 100 ppm scale error on EL, both in one hook.
    model = _gyro_plugin(tmp_path, monkeypatch, 'g_sensitive',
                         'return np.column_stack([1e-4 * context.rates_rad_per_s[:, 0], 0 * context.time_s, '
                         'params["k"] * 1e-7 * context.specific_force_m_per_s2[:, 2]])')
    true_rates = np.tile([1e-3, 0.0, 0.0], (2, 1))
    force_tarf = np.array([[0.0, -5.0, 8.0], [0.0, -8.0, 5.0]])
    measured = measured_rates_gyrf_rad_per_s(model, true_rates, np.arange(2.0), np.full(2, 20.0), force_tarf)
    np.testing.assert_allclose(measured[:, 0], 1e-3 * (1 + 1e-4), rtol=1e-12)
    np.testing.assert_allclose(measured[:, 2], [8e-7, 5e-7], rtol=1e-12)
    # The model side evaluates the scale on the measured rate: exact to the square of the scale error.
    recovered = true_rates_tarf_rad_per_s(model, measured, np.arange(2.0), np.full(2, 20.0), force_tarf)
    np.testing.assert_allclose(recovered, true_rates, atol=1e-3 * 1e-8)


def test_a_camera_shift_hook_moves_the_centroids_on_the_detector(tmp_path, monkeypatch):
    from sofia_ros.effects.context import CameraContext
    from sofia_ros.sensors.imager_model import shifted_centroids_px

    module = _write_module(tmp_path, 'distortion_module', '''
        import numpy as np
        from sofia_ros.effects import EffectSpec, Parameter

        def radial_px(params, context):
            """A radial distortion of the WFI: k r^2 along the radius from the chip centre."""
            shift = np.zeros((len(context), 2))
            if context.camera == 'wfi':
                dx, dy = context.detector_x_px - 511.5, context.detector_y_px - 511.5
                shift[:, 0], shift[:, 1] = params['k_per_px2'] * (dx**2 + dy**2) * np.array([dx, dy]) / 1.0
            return shift

        EFFECTS = (EffectSpec('wfi_distortion', 'camera', 'test', 'radial distortion',
                              (Parameter('k_per_px2', 1e-9, '1/px^2', 'cubic radial term'),),
                              camera_shift_px=radial_px),)
    ''')
    monkeypatch.syspath_prepend(str(tmp_path))
    monkeypatch.setitem(CATALOGUE, 'wfi_distortion', load_catalogue({PLUGIN_ENVIRONMENT_VARIABLE: module})['wfi_distortion'])
    effects = {'wfi_distortion': {'k_per_px2': 1e-9}}
    pixels = np.array([[511.5, 511.5], [1011.5, 511.5]])
    context = CameraContext.at_rest('wfi', [40.0, 40.0])
    shifted = shifted_centroids_px(camera_errors('wfi', effects), pixels, context, np.array([1, 2]))
    np.testing.assert_allclose(shifted - pixels, [[0.0, 0.0], [1e-9 * 500.0**3, 0.0]], atol=1e-12)
    fpi = shifted_centroids_px(camera_errors('fpi', effects), pixels, CameraContext.at_rest('fpi', [40.0, 40.0]),
                               np.array([1, 2]))
    np.testing.assert_array_equal(fpi, pixels)


@pytest.mark.parametrize('kind, hook', [('camera', 'camera_shift_px'), ('camera-rotation', 'camera_rotation'),
                                        ('gyro', 'gyro_rate_offset')])
def test_effects_new_writes_a_template_that_loads_and_changes_nothing_at_its_default(tmp_path, monkeypatch, capsys,
                                                                                     kind, hook):
    from sofia_ros.cli import main
    from sofia_ros.effects.context import CameraContext, GyroContext

    name = f'my_{kind.replace("-", "_")}_effect'
    assert main(['effects', 'new', name, '--kind', kind, '--dir', str(tmp_path)]) == 0
    assert f'SOFIA_EFFECT_MODULES={name}' in capsys.readouterr().out
    monkeypatch.syspath_prepend(str(tmp_path))
    spec = load_catalogue({PLUGIN_ENVIRONMENT_VARIABLE: name})[name]
    assert spec.hooks == (hook,)
    context = (GyroContext.at_rest(np.arange(3.0), 20.0) if kind == 'gyro'
               else CameraContext.at_rest('ffi', [30.0, 40.0, 50.0], temperature_c=25.0).with_detector(
                   np.zeros((3, 2)), np.arange(3)))
    defaults = spec.defaults()
    np.testing.assert_array_equal(getattr(spec, hook)(defaults, context), 0.0)
    # A non-zero parameter moves something: the template is live physics, not a stub.
    assert np.any(getattr(spec, hook)({key: 1.0 for key in defaults}, context) != 0.0)


@pytest.mark.parametrize('argv, message', [
    (['effects', 'new', 'gyro_bias', '--kind', 'gyro'], "'gyro_bias' is already an effect; choose another name"),
    (['effects', 'new', 'Bad-Name', '--kind', 'gyro'], "'Bad-Name' must be a lower-case Python identifier"),
    (['effects', 'new', 'fine_name'], 'usage: sofia effects new NAME --kind'),
    (['effects', 'new', 'fine_name', '--kind', 'gyro', '--dir', '/no/such/dir'], 'directory /no/such/dir does not exist'),
])
def test_effects_new_refuses_bad_input_with_one_line(capsys, argv, message):
    from sofia_ros.cli import main

    assert main(argv) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and message in error


def test_effects_new_never_overwrites(tmp_path, capsys):
    from sofia_ros.cli import main

    (tmp_path / 'taken.py').write_text('# mine\n')
    assert main(['effects', 'new', 'taken', '--kind', 'camera', '--dir', str(tmp_path)]) == 2
    assert 'exists; choose another name or remove it' in capsys.readouterr().err
    assert (tmp_path / 'taken.py').read_text() == '# mine\n'


def test_empirical_names_resolve_to_hooked_effects_and_bad_ones_say_the_grammar():
    from sofia_ros.effects import get_effect
    from sofia_ros.effects.context import CameraContext
    from sofia_ros.errors import UnknownEffectError

    spec = get_effect('empirical:ffi.y:elevation:poly3@20..60')
    assert [p.name for p in spec.params] == ['p0_arcsec', 'p1_arcsec', 'p2_arcsec', 'p3_arcsec']
    context = CameraContext.at_rest('ffi', [20.0, 40.0, 60.0])
    shift = spec.camera_shift_px({'p0_arcsec': 0.0, 'p1_arcsec': 4.07, 'p2_arcsec': 0.0, 'p3_arcsec': 0.0}, context)
    # P1 of elevation mapped from 20..60 onto -1..1, 4.07" = 1 FFI pixel, along rows only.
    np.testing.assert_allclose(shift, [[0.0, -1.0], [0.0, 0.0], [0.0, 1.0]], atol=1e-12)
    assert get_effect('empirical:gyro.los:temperature:poly3').params[0].name == 'p1_deg_per_h'
    assert [p.name for p in get_effect('empirical:hipo.x:time:period_95.5s').params] == ['sin_arcsec', 'cos_arcsec']
    field = get_effect('empirical:wfi.x:detector_field:poly3')
    assert [p.name for p in field.params] == ['p00_arcsec', 'p10_arcsec', 'p01_arcsec', 'p20_arcsec', 'p11_arcsec',
                                              'p02_arcsec', 'p30_arcsec', 'p21_arcsec', 'p12_arcsec', 'p03_arcsec']
    corners = CameraContext.at_rest('wfi', [40.0] * 3)
    corners = dataclasses.replace(corners, detector_x_px=np.array([-0.5, 511.5, 1023.5]),
                                  detector_y_px=np.array([1023.5, 511.5, 1023.5]))
    values = {param.name: 0.0 for param in field.params} | {'p11_arcsec': 20.36}
    # P1(x) P1(y) over the chip (WFI 1024 px, 20.36"/px): -1, 0, +1 px along columns at two corners and the centre.
    np.testing.assert_allclose(field.camera_shift_px(values, corners), [[-1.0, 0.0], [0.0, 0.0], [1.0, 0.0]],
                               atol=1e-9)
    for name, message in (('empirical:ffi.y:slew:poly3', "variable 'slew' is not available"),
                          ('empirical:gyro.el:detector_field:poly3', "variable 'detector_field' is not available"),
                          ('empirical:wfi.x:detector_field:poly3@0..1023', 'a detector field spans the chip'),
                          ('empirical:gyro.el:detector_x:poly3', "variable 'detector_x' is not available"),
                          ('empirical:ffi.y:elevation:poly3@60..20', 'HIGH > LOW'),
                          ('empirical:ffi.y:elevation', 'empirical terms are named')):
        with pytest.raises(UnknownEffectError, match=message):
            get_effect(name)
