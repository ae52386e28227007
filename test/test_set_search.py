"""`sofia compare SET.yaml --search`: the model search over a measurement set, through the one pipeline."""

from pathlib import Path

import yaml

from json_contract import load_json, validate_compare
from sofia_ros.cli import main

ROOT = Path(__file__).resolve().parents[1]
SHORT_MOVES = ROOT / 'data' / 'thesis-2004' / 'star-hop-2004-09-03-short-moves.yaml'
NOMINAL_MODEL = ROOT / 'config' / 'model' / 'nominal.yaml'


def test_a_set_search_finds_the_swapped_gyro_calibration_and_names_its_equivalent(tmp_path, capsys):
    # The 2004 star hop's short moves: the gyro calibrations on the wrong axes (6.3), which a set of nearly
    # pure-EL moves cannot tell from a scale-factor error: one of the two is found, the other stated equivalent.
    found_model, output = tmp_path / 'found.yaml', tmp_path / 'compare.json'
    assert main(['compare', str(SHORT_MOVES), '--model', str(NOMINAL_MODEL), '--search', '--search-rounds', '3',
                 '--json', str(output), '--write-model', str(found_model), '--quiet']) == 0
    document = load_json(output)
    validate_compare(document)
    search = document['search']
    pair = {'gyro_scale_factor', 'gyro_axis_swap'}
    assert search['status'] == 'explained' and len(set(search['added']) & pair) == 1
    assert any(other in entry['model'] for entry in search['equivalent'] for other in pair - set(search['added']))
    written = yaml.safe_load(found_model.read_text())['effects']
    assert set(search['added']) <= {name for name, params in written.items() if params and params.get('fit')}
    assert 'search:' in capsys.readouterr().out
