"""Outputs that would replace an input, or that cannot be written, are refused in one line before any work.

`sofia compare BAG --json BAG/BAG.mcap` replaced the recording with the comparison at exit 0, and a report folder's
ledger.json linked to /dev/full was read until the machine ran out of memory. Every case here is refused before
the comparison (or analysis, or design) starts: the stand-in for it fails the test if it is reached.
"""

import os
import shutil

import pytest

from sofia_ros.cli import main

MODEL = 'config/model/nominal.yaml'


@pytest.fixture
def bag(tmp_path):
    """A folder standing in for a bag (the checks come before the bag is read): its recording and metadata."""
    folder = tmp_path / 'bag'
    folder.mkdir()
    (folder / 'bag.mcap').write_bytes(b'recording')
    (folder / 'metadata.yaml').write_text('rosbag2_bagfile_information: {}\n')
    return folder


@pytest.fixture
def model(tmp_path):
    path = tmp_path / 'model.yaml'
    shutil.copy(MODEL, path)
    return path


@pytest.fixture(autouse=True)
def no_work(monkeypatch):
    """The commands' work, which none of these cases may reach."""
    def reached(*args, **kwargs):
        raise AssertionError('the command started its work before refusing its output')

    monkeypatch.setattr('sofia_ros.compare.run.compare_bag', reached)
    monkeypatch.setattr('sofia_ros.noise.run.load_noise_record', reached)


def _refused(capsys, args, fragment):
    """Exit 2 and one stderr line holding ``fragment``."""
    assert main(args) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and fragment in lines[0], lines


def test_compare_json_onto_a_file_of_the_bag_is_refused_and_the_recording_kept(bag, model, capsys):
    _refused(capsys, ['compare', str(bag), '--model', str(model), '--json', str(bag / 'bag.mcap')],
             f'--json {bag / "bag.mcap"} is inside the bag {bag}')
    assert (bag / 'bag.mcap').read_bytes() == b'recording'


def test_compare_json_new_in_the_bag_folder_is_refused(bag, model, capsys):
    _refused(capsys, ['compare', str(bag), '--model', str(model), '--json', str(bag / 'compare.json')],
             'is inside the bag')
    assert sorted(path.name for path in bag.iterdir()) == ['bag.mcap', 'metadata.yaml']


@pytest.mark.parametrize('link', ['same', 'symlink', 'hardlink'])
def test_compare_json_onto_the_model_is_refused_through_any_link(bag, model, tmp_path, capsys, link):
    target = {'same': model, 'symlink': tmp_path / 'link.json', 'hardlink': tmp_path / 'hard.json'}[link]
    if link == 'symlink':
        target.symlink_to(model)
    elif link == 'hardlink':
        os.link(model, target)
    text = model.read_text()
    _refused(capsys, ['compare', str(bag), '--model', str(model), '--json', str(target)], 'is the model')
    assert model.read_text() == text


def test_compare_json_and_write_model_on_one_file_are_refused(bag, model, tmp_path, capsys):
    out = tmp_path / 'found.yaml'
    _refused(capsys, ['compare', str(bag), '--model', str(model), '--search', '--write-model', str(out),
                      '--json', str(out)], 'is --write-model')


@pytest.mark.parametrize('option', ['--write-model', '--report'])
def test_compare_writes_nothing_into_the_bag_folder(bag, model, capsys, option):
    target = bag / ('found.yaml' if option == '--write-model' else 'report')
    _refused(capsys, ['compare', str(bag), '--model', str(model), '--search', option, str(target)],
             f'{option} {target} is inside the bag')


def test_compare_report_onto_the_bag_folder_itself_is_refused(bag, model, capsys):
    _refused(capsys, ['compare', str(bag), '--model', str(model), '--report', str(bag)], f'--report {bag} is the bag')


def test_compare_json_linked_to_a_device_is_refused_before_the_comparison(bag, model, tmp_path, capsys):
    link = tmp_path / 'out.json'
    link.symlink_to('/dev/full')
    _refused(capsys, ['compare', str(bag), '--model', str(model), '--json', str(link)], 'is not a regular file')


@pytest.mark.parametrize('ledger,fragment', [
    ('device', 'not a regular file'),
    ('fifo', 'not a regular file'),
    ('folder', 'is a directory'),
    ('{"a": 1}', 'not a list of runs'),
    ('[1, 2]', 'not a list of runs'),
    ('[{"last_term": "x", "residual_rms_arcsec": {"total": "1"}, "noise_floor_arcsec": 1}]', 'not a list of runs'),
    ('not json', 'is not a ledger written by sofia compare'),
    (b'\xff\xfe', 'not UTF-8'),
])
def test_a_report_folder_whose_ledger_is_not_a_ledger_is_refused_before_the_comparison(
        bag, model, tmp_path, capsys, ledger, fragment):
    report = tmp_path / 'report'
    report.mkdir()
    path = report / 'ledger.json'
    if ledger == 'device':
        path.symlink_to('/dev/full')  # read whole, it never ends: the memory ran out
    elif ledger == 'fifo':
        os.mkfifo(path)  # read, it waits for a writer for ever
    elif ledger == 'folder':
        path.mkdir()
    elif isinstance(ledger, bytes):
        path.write_bytes(ledger)
    else:
        path.write_text(ledger)
    _refused(capsys, ['compare', str(bag), '--model', str(model), '--report', str(report)], fragment)


def test_a_ledger_of_earlier_runs_passes_the_check(tmp_path):
    from sofia_ros.compare.report import read_ledger

    (tmp_path / 'ledger.json').write_text('[{"model": "m.yaml", "last_term": "gyro_bias", "residual_rms_arcsec": '
                                          '{"total": 1.5}, "noise_floor_arcsec": 0.3, "top_candidate": "none"}]')
    assert read_ledger(tmp_path)[0]['last_term'] == 'gyro_bias'
    assert read_ledger(tmp_path / 'new') == []


@pytest.mark.parametrize('option', ['--json', '--report'])
def test_an_empty_output_path_is_refused_not_ignored(bag, model, capsys, option):
    _refused(capsys, ['compare', str(bag), '--model', str(model), option, ''], f'{option} is given an empty path')


def test_search_rounds_without_search_is_refused_not_ignored(bag, model, capsys):
    _refused(capsys, ['compare', str(bag), '--model', str(model), '--search-rounds', '3'], 'add --search')


def test_noise_json_onto_its_model_or_into_its_bag_is_refused(bag, model, capsys):
    _refused(capsys, ['noise', str(bag), '--model', str(model), '--json', str(model)], 'is the model')
    _refused(capsys, ['noise', str(bag), '--json', str(bag / 'bag.mcap')], 'is inside the bag')
    _refused(capsys, ['noise', str(bag), '--report', str(bag / 'report')], 'is inside the bag')
    assert (bag / 'bag.mcap').read_bytes() == b'recording'


def test_design_plan_out_onto_the_bags_plan_or_the_json_is_refused(bag, model, tmp_path, capsys):
    (bag / 'plan.yaml').write_text('campaign: alignment\n')
    design = ['design', str(bag), '--model', str(model), '--between', 'gyro_scale_factor,gyro_axis_swap']
    _refused(capsys, [*design, '--plan-out', str(bag / 'plan.yaml')], 'is inside the bag')
    _refused(capsys, [*design, '--plan-out', str(tmp_path / 'p.yaml'), '--json', str(tmp_path / 'p.yaml')],
             'is --json')
    _refused(capsys, [*design, '--json', str(model)], 'is the model')
    assert (bag / 'plan.yaml').read_text() == 'campaign: alignment\n'


def test_compare_json_and_report_on_one_path_are_refused(bag, model, tmp_path, capsys):
    # A set's comparison wrote the JSON, then failed on the report at exit 3 ("File exists").
    out = tmp_path / 'x.json'
    _refused(capsys, ['compare', str(bag), '--model', str(model), '--json', str(out), '--report', str(out)],
             f'--json {out} is --report ({out}), another output')
    assert not out.exists()


@pytest.mark.parametrize('where', ['in the table', 'the model'])
def test_an_atlas_report_in_its_table_or_over_its_model_is_refused_before_any_task(model, tmp_path, capsys, where):
    # Written after every task: into OUT/table it made the table unreadable (pyarrow reads every file there),
    # over the model it replaced it, at exit 0.
    out = tmp_path / 'atlas'
    report = {'in the table': out / 'table' / 'report', 'the model': model}[where]
    fragment = {'in the table': 'is inside the results table', 'the model': 'is a file; give a directory'}[where]
    _refused(capsys, ['atlas', '--out', str(out), '--model', str(model), '--effects', 'timestamp_offset', '--sizes',
                      '1', '--campaigns', 'alignment:minimal', '--seeds', '1', '--serial', '--report', str(report)],
             fragment)
    assert not out.exists()
