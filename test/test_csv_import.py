"""`sofia import`: CSV logs -> bag; a simulated bag exported to CSV and imported compares the same."""

import shutil

import pytest

from sofia_ros.bag.csv_logs import export_csv_logs
from sofia_ros.cli import main
from sofia_ros.compare.run import compare_bag
from sofia_ros.config import load_effect_config

CANDIDATES = ['gyro_scale_factor', 'timestamp_offset', 'imager_rotation_of_field']


@pytest.fixture(scope='module')
def campaign(campaign_bags):
    """The session's reduced nominal alignment bag, seed 3 (2 repetitions, 1 verification, direct mode)."""
    return campaign_bags.reduced_alignment()


@pytest.fixture(scope='module')
def exported(campaign, tmp_path_factory):
    """The campaign's CSV logs, exported once for the module (about 7 CPU-s); a test that edits them edits a copy."""
    return export_csv_logs(campaign, tmp_path_factory.mktemp('export') / 'logs')


@pytest.mark.timeout(600)
def test_export_import_round_trip_compares_the_same(campaign, exported, tmp_path, capsys):
    assert main(['import', str(exported), '--bag', str(tmp_path / 'imported')]) == 0
    assert 'bag: ' in capsys.readouterr().out
    model = load_effect_config('config/model/nominal.yaml')
    original = compare_bag(campaign, model, candidate_names=CANDIDATES).document
    imported = compare_bag(tmp_path / 'imported', model, candidate_names=CANDIDATES).document
    for key in ('observations', 'residual_rms_arcsec', 'noise_floor_arcsec', 'terms', 'ledger', 'degenerate'):
        assert imported[key] == original[key], key
    assert [(c['effect'], c['delta_bic'], c['params']) for c in imported['candidates']] == [
        (c['effect'], c['delta_bic'], c['params']) for c in original['candidates']]


def test_bad_logs_are_one_line_and_exit_2(exported, tmp_path, capsys):
    logs = shutil.copytree(exported, tmp_path / 'logs')
    text = (logs / 'joints.csv').read_text().replace('fd_los_rad', 'fd_los_deg')
    (logs / 'joints.csv').write_text(text)
    assert main(['import', str(logs), '--bag', str(tmp_path / 'bag')]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and "missing column 'fd_los_rad'" in error[0]
    (logs / 'joints.csv').write_text(text.replace('fd_los_deg', 'fd_los_rad'))
    gyro = (logs / 'gyro.csv').read_text().splitlines()
    late = [line.replace(line.split(',')[0], str(int(line.split(',')[0]) + 3 * 10**18), 1) for line in gyro[1:]]
    (logs / 'gyro.csv').write_text('\n'.join([gyro[0], *late]) + '\n')
    assert main(['import', str(logs), '--bag', str(tmp_path / 'late')]) == 2
    error = capsys.readouterr().err.strip().splitlines()
    assert len(error) == 1 and 'gyro.csv line 2: time_ns = ' in error[0]
    assert 'to before 2038-01-19 (what the int32 seconds of a ROS stamp hold)' in error[0]
    assert not (tmp_path / 'late').exists()  # refused before a bag is begun
    (logs / 'scenario.yaml').unlink()
    assert main(['import', str(logs), '--bag', str(tmp_path / 'bag2')]) == 2
    assert 'scenario.yaml' in capsys.readouterr().err
