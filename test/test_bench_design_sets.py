"""bench/bench_design.py's competing sets with effects fitted under both members (issue 28's HIPO set judged with
the imagers' boresight offsets free): the truth holds them and the model fits them; the other sets keep the
nominal model and their truth unchanged."""

import importlib.util
import sys
from pathlib import Path

import yaml

from sofia_ros.config import load_effect_config

ROOT = Path(__file__).resolve().parents[1]


def _bench_design():
    spec = importlib.util.spec_from_file_location('bench_design', ROOT / 'bench' / 'bench_design.py')
    module = importlib.util.module_from_spec(spec)
    # dataclasses look their module up in sys.modules (the bench is a script, not an installed module).
    sys.modules[spec.name] = module
    spec.loader.exec_module(module)
    return module


bench_design = _bench_design()


def _effects(path: Path) -> dict:
    return yaml.safe_load(path.read_text())['effects']


def test_a_set_with_effects_fitted_in_both_puts_them_in_the_truth_at_the_catalogue_values(tmp_path):
    nominal = _effects(ROOT / 'config' / 'truth' / 'nominal.yaml')
    truth = _effects(bench_design._truth(tmp_path, 'hipo-rot', bench_design.SETS['hipo-rot']))
    assert truth == {**nominal, 'imager_boresight_offset': {}, 'hipo_fiducial_error': {}}


def test_a_set_without_them_keeps_its_truth(tmp_path):
    nominal = _effects(ROOT / 'config' / 'truth' / 'nominal.yaml')
    truth = _effects(bench_design._truth(tmp_path, 'hipo', bench_design.SETS['hipo']))
    assert truth == {**nominal, 'hipo_fiducial_error': {}}


def test_a_set_with_effects_fitted_in_both_fits_them_in_a_model_of_its_own(tmp_path):
    nominal_text = bench_design.MODEL.read_text()
    path = bench_design._model(tmp_path, 'hipo-rot-hop', bench_design.SETS['hipo-rot-hop'])
    assert path.parent == tmp_path
    assert _effects(path) == {**yaml.safe_load(nominal_text)['effects'], 'imager_boresight_offset': {'fit': True}}
    assert 'imager_boresight_offset' in load_effect_config(path).fitted
    assert bench_design.MODEL.read_text() == nominal_text


def test_a_set_without_them_is_fitted_with_the_nominal_model(tmp_path):
    assert bench_design._model(tmp_path, 'hipo-min', bench_design.SETS['hipo-min']) == bench_design.MODEL
    assert not list(tmp_path.iterdir())
