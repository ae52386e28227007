"""`sofia noise` as a user runs it: report, JSON contract (docs/noise.md), one-line errors, nothing half-written."""

import re
from pathlib import Path

import pytest

from json_contract import load_json, validate_noise
from sofia_ros.bag import BagWriter
from sofia_ros.campaigns.gyro_stability import CASES, run_gyro_stability
from sofia_ros.cli import main
from sofia_ros.config import parse_effect_config
from sofia_ros.noise.report import PLOTS

DOCS = Path(__file__).resolve().parents[1] / 'docs' / 'noise.md'
MODEL = ('effects:\n  gyro_noise: {}\n  gyro_misalignment: {}\n'
         '  vibration_lines: {frequencies_hz: [0.7], amplitudes_arcsec_per_s: [0.05], axes: [el]}\n')


@pytest.fixture(scope='module')
def bag(tmp_path_factory):
    """Three minutes of TC-3 (5.2.1) with the misaligned, biased gyros of 2004 (eq. 6.1, Table 5.7)."""
    path = tmp_path_factory.mktemp('cli') / 'tc3'
    truth = parse_effect_config('effects:\n  gyro_noise: {}\n  gyro_misalignment: {}\n  gyro_bias: {}\n')
    run_gyro_stability(truth, case='TC-3', hours=0.05, seed=8, bag_path=path)
    return path


@pytest.fixture
def model(tmp_path):
    path = tmp_path / 'noise.yaml'
    path.write_text(MODEL)
    return path


def test_report_writes_the_page_and_every_plot_and_the_json(bag, model, tmp_path, capsys):
    report, out = tmp_path / 'report', tmp_path / 'noise.json'
    assert main(['noise', str(bag), '--model', str(model), '--report', str(report), '--json', str(out)]) == 0
    assert sorted(path.name for path in report.iterdir()) == sorted(['index.html', *(name for name, _ in PLOTS)])
    for name, _ in PLOTS:
        assert (report / name).read_bytes()[:8] == b'\x89PNG\r\n\x1a\n', name
        assert f'src="{name}"' in (report / 'index.html').read_text()
    assert [path.name for path in tmp_path.iterdir() if path.name.startswith('.')] == []  # no leftovers
    page = (report / 'index.html').read_text()
    assert 'Table 5.7' in page and 'main oil pump' in page and 'uncaged (axial air springs evacuated)' in page
    printed = capsys.readouterr().out
    # Table 5.2 states of TC-3, the Table 5.7 rows, the loop's candidates.
    assert 'TA subsystems (Table 5.2): ris activated, fd braked' in printed
    assert 'misalignment corrected (TARF)' in printed and 'degenerate on a stationary record' in printed
    assert 'missing terms, best first' in printed and 'main oil pump' in printed
    document = validate_noise(load_json(out))
    assert document['subsystems'] == dict(CASES['TC-3'].subsystems)
    assert document['candidates'][0]['source'] == 'main oil pump'  # 30 Hz on EL, not in the model


def _keys(value, found=None):
    found = set() if found is None else found
    if isinstance(value, dict):
        for key, item in value.items():
            found.add(key)
            _keys(item, found)
    elif isinstance(value, list):
        for item in value:
            _keys(item, found)
    return found


def test_every_json_key_is_documented_and_the_json_is_stable(bag, model, tmp_path, capsys):
    first, second = tmp_path / 'a.json', tmp_path / 'b.json'
    for out in (first, second):
        assert main(['noise', str(bag), '--model', str(model), '--decimate', '2', '--json', str(out)]) == 0
    assert first.read_text() == second.read_text()
    document = validate_noise(load_json(first))
    spans = re.findall(r'`([^`]+)`', re.sub(r'```.*?```', '', DOCS.read_text(), flags=re.S))
    documented = {name for span in spans for name in re.findall(r'[a-z][a-z_0-9]*', span)}
    # Axis names and the Table 5.2 subsystem names are listed in the text, not as keys of their own.
    missing = _keys(document) - documented - {'el', 'xel', 'los', 'all'}
    assert missing == set()
    assert {'arw_sampled_arcsec_per_sqrt_s', 'misalignment_corrected', 'degenerate', 'candidates'} <= _keys(document)
    assert 'ARW corrected to 400 Hz by 4.27' in capsys.readouterr().out


def _write_imu_free_bag(path):
    with BagWriter(path) as writer:
        writer.write_document('/config/truth', 'effects: {}', 0)


@pytest.mark.parametrize('arguments, message', [
    (lambda tmp, bag: [str(tmp / 'none')], 'does not exist'),
    (lambda tmp, bag: [str(tmp / 'no_imu')], 'has no /gyro_box/imu; record a gyro-stability campaign first'),
    (lambda tmp, bag: [str(bag), '--model', str(tmp / 'wobble.yaml')], "unknown effect 'gyro_wobble'"),
    (lambda tmp, bag: [str(bag), '--model', str(tmp / 'absent.yaml')], 'cannot read'),
    (lambda tmp, bag: [str(bag), '--model', str(tmp / 'lines.yaml')], 'need one entry per line, got 2, 1 and 1'),
    (lambda tmp, bag: [str(bag), '--decimate', '0'], '--decimate must be >= 1'),
    (lambda tmp, bag: [str(bag), '--decimate', 'ten'], "--decimate must be a whole number of read-out samples"),
    (lambda tmp, bag: [str(bag), '--decimate', '100'], '720 samples at 4 Hz; the analysis needs at least 1024'),
    (lambda tmp, bag: [str(bag), '--report', str(tmp / 'full')], 'already exists and is not empty'),
    (lambda tmp, bag: [str(bag), '--json', str(tmp / 'nowhere' / 'out.json')], 'give a file in an existing directory'),
    # Said "already exists and is not empty" of a device, and "give a file in an existing directory" of a folder.
    (lambda tmp, bag: [str(bag), '--report', '/dev/null'], '--report /dev/null is not a directory (a file or a device)'),
    (lambda tmp, bag: [str(bag), '--json', str(tmp / 'full')], 'is a directory; give a file name'),
    # The JSON replaced the report's page at exit 0; the same path for both ran the analysis, then refused.
    (lambda tmp, bag: [str(bag), '--report', str(tmp / 'empty'), '--json', str(tmp / 'empty' / 'index.html')],
     'is inside --report'),
    (lambda tmp, bag: [str(bag), '--report', str(tmp / 'both'), '--json', str(tmp / 'both')], 'is --report'),
])
def test_bad_input_is_one_line_exit_2_and_writes_nothing(bag, tmp_path, capsys, arguments, message):
    _write_imu_free_bag(tmp_path / 'no_imu')
    (tmp_path / 'wobble.yaml').write_text('effects:\n  gyro_wobble: {}\n')
    (tmp_path / 'lines.yaml').write_text('effects:\n  vibration_lines: {frequencies_hz: [30.0, 11.7], '
                                         'amplitudes_arcsec_per_s: [0.1], axes: [el]}\n')
    (tmp_path / 'full').mkdir()
    (tmp_path / 'full' / 'notes.txt').write_text('keep')
    (tmp_path / 'empty').mkdir()
    before = sorted(path.name for path in tmp_path.rglob('*'))
    given = arguments(tmp_path, bag)
    # Every case also asks for both outputs, so that "writes nothing" is tested for each.
    outputs = [] if {'--json', '--report'} & set(given) else [
        '--json', str(tmp_path / 'out.json'), '--report', str(tmp_path / 'report')]
    status = main(['noise', *given, *outputs])
    error = capsys.readouterr().err
    assert status == 2
    assert error.count('\n') == 1 and message in error and 'Traceback' not in error
    assert sorted(path.name for path in tmp_path.rglob('*')) == before


def test_a_report_through_a_link_to_an_empty_folder_is_written_into_that_folder(bag, tmp_path, capsys):
    # It failed after the whole analysis, saying a part of the path was a file.
    (tmp_path / 'real').mkdir()
    (tmp_path / 'link').symlink_to(tmp_path / 'real')
    assert main(['noise', str(bag), '--report', str(tmp_path / 'link')]) == 0
    assert (tmp_path / 'link').is_symlink() and (tmp_path / 'real' / 'index.html').is_file()
