"""`sofia model add` as a careful editor: comments, order, symlinks, mode, concurrent edits (issue 13)."""

import errno
import os
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from sofia_ros.cli import main
from sofia_ros.output_files import write_text_atomically
from sofia_ros.config import load_effect_config, parse_effect_config
from sofia_ros.errors import ConfigError

MODEL = """\
# my model: what the TASCU assumes
description: "hand-written"   # keep me
effects:
  earth_rotation: {}          # 4.1
  # the FEM
  focal_plane_flexure: {scale: 1.0}
  gyro_bias:
    fit: true
    el_deg_per_h: -0.06   # from the last run
"""


def test_comments_order_and_style_survive_and_the_effect_is_fitted(tmp_path, capsys):
    model = tmp_path / 'm.yaml'
    model.write_text(MODEL)
    assert main(['model', 'add', 'gyro_misalignment', '--model', str(model)]) == 0
    text = model.read_text()
    assert text.startswith(MODEL)
    assert text[len(MODEL):] == '  gyro_misalignment:\n    fit: true\n'
    assert load_effect_config(model).fitted == {'gyro_bias', 'gyro_misalignment'}


def test_an_effect_already_listed_gets_fit_beside_its_values(tmp_path, capsys):
    model = tmp_path / 'm.yaml'
    model.write_text(MODEL)
    assert main(['model', 'add', 'focal_plane_flexure', '--model', str(model)]) == 0
    assert '  focal_plane_flexure: {scale: 1.0, fit: true}\n' in model.read_text()
    assert '# the FEM' in model.read_text()
    # It said "starting at its thesis defaults" while the fit starts from the file's values.
    assert 'focal_plane_flexure added as a fitted term (starting at its values in the file)' in capsys.readouterr().out


def test_a_symlink_is_written_through_and_the_mode_kept(tmp_path):
    real = tmp_path / 'models' / 'real.yaml'
    real.parent.mkdir()
    real.write_text(MODEL)
    real.chmod(0o640)
    link = tmp_path / 'm.yaml'
    link.symlink_to(real)
    assert main(['model', 'add', 'seeing', '--model', str(link)]) == 0
    assert link.is_symlink() and link.resolve() == real
    assert stat.S_IMODE(real.stat().st_mode) == 0o640
    assert 'seeing' in load_effect_config(real).fitted
    assert sorted(p.name for p in real.parent.iterdir() if not p.name.startswith('.real.yaml.lock')) == ['real.yaml']


def test_concurrent_adds_keep_every_effect(tmp_path):
    model = tmp_path / 'm.yaml'
    model.write_text(MODEL)
    effects = ['seeing', 'timestamp_offset', 'gyro_scale_factor', 'imager_rotation_of_field', 'tracker_drift',
               'fpi_internal_flexure']
    runs = [subprocess.Popen([sys.executable, '-m', 'sofia_ros.cli', 'model', 'add', effect, '--model', str(model)],
                             stdout=subprocess.PIPE, stderr=subprocess.PIPE) for effect in effects]
    for run in runs:
        assert run.wait(timeout=120) == 0, run.stderr.read()
    assert load_effect_config(model).fitted == {'gyro_bias', *effects}
    assert model.read_text().startswith(MODEL)


def test_an_unwritable_file_is_one_line(tmp_path, capsys, monkeypatch):
    model = tmp_path / 'm.yaml'
    model.write_text(MODEL)

    def refuse(*args):
        raise PermissionError(13, 'Permission denied')

    monkeypatch.setattr(os, 'replace', refuse)
    assert main(['model', 'add', 'seeing', '--model', str(model)]) == 2
    err = capsys.readouterr().err
    assert err == f'sofia: error: cannot write {model}: permission denied; write to a directory you may write to\n'
    assert model.read_text() == MODEL
    assert [p.name for p in tmp_path.iterdir() if p.name.startswith('.m.yaml.') and 'lock' not in p.name] == []


def test_a_full_disk_is_one_line_and_exit_3(tmp_path, capsys, monkeypatch):
    model = tmp_path / 'm.yaml'
    model.write_text(MODEL)

    def full(*args):
        raise OSError(errno.ENOSPC, 'No space left on device')

    monkeypatch.setattr(os, 'replace', full)
    assert main(['model', 'add', 'seeing', '--model', str(model)]) == 3
    assert capsys.readouterr().err == f'sofia: error: cannot write {model}: disk full; free space or write elsewhere\n'
    assert model.read_text() == MODEL


def test_a_link_to_a_device_is_refused_and_the_device_kept(tmp_path, capsys):
    link = tmp_path / 'L.yaml'
    link.symlink_to('/dev/null')
    assert main(['model', 'add', 'seeing', '--model', str(link)]) == 2
    err = capsys.readouterr().err
    assert err == (f'sofia: error: {link} is not a regular file (/dev/null is a device, FIFO or socket); '
                   'give a file name on disk\n')
    assert stat.S_ISCHR(os.stat('/dev/null').st_mode)
    assert not Path('/dev/.null.lock').exists()


def test_an_output_onto_a_device_is_refused(tmp_path):
    link = tmp_path / 'out.json'
    link.symlink_to('/dev/null')
    with pytest.raises(ConfigError, match='is not a regular file'):
        write_text_atomically(link, '{}\n')
    assert stat.S_ISCHR(os.stat('/dev/null').st_mode)


def test_an_unlockable_file_is_one_line(capsys):
    # /proc allows no new files: the sidecar lock cannot be created.
    assert main(['model', 'add', 'seeing', '--model', '/proc/version']) == 2
    err = capsys.readouterr().err
    assert err.startswith('sofia: error: cannot lock /proc/version for editing') and err.count('\n') == 1


def test_new_outputs_follow_the_umask(tmp_path):
    previous = os.umask(0o022)
    try:
        write_text_atomically(tmp_path / 'out.json', '{}\n')
    finally:
        os.umask(previous)
    assert stat.S_IMODE((tmp_path / 'out.json').stat().st_mode) == 0o644


def test_writing_onto_a_directory_is_refused(tmp_path):
    with pytest.raises(ConfigError, match='is a directory; give a file name'):
        write_text_atomically(tmp_path, '{}\n')


def test_a_missing_directory_is_refused(tmp_path):
    with pytest.raises(ConfigError, match='does not exist; create it'):
        write_text_atomically(Path(tmp_path, 'no', 'out.json'), '{}\n')


def test_a_duplicate_key_is_refused_without_touching_the_file(tmp_path, capsys):
    model = tmp_path / 'm.yaml'
    text = MODEL + 'effects: {}\n'
    model.write_text(text)
    assert main(['model', 'add', 'seeing', '--model', str(model)]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and f"{model}: key 'effects' given twice (line 10); keep one" in err
    assert model.read_text() == text


def test_remove_and_replace_edit_the_file_and_keep_its_comments(tmp_path, capsys):
    model = tmp_path / 'm.yaml'
    model.write_text(MODEL)
    assert main(['model', 'add', 'imager_boresight_offset', '--model', str(model)]) == 0
    assert main(['model', 'replace', 'imager_boresight_offset', 'hipo_fiducial_error', '--model', str(model)]) == 0
    effects = load_effect_config(model)
    assert 'imager_boresight_offset' not in effects.effects and 'hipo_fiducial_error' in effects.fitted
    assert main(['model', 'remove', 'hipo_fiducial_error', '--model', str(model)]) == 0
    assert model.read_text() == MODEL
    assert 'hipo_fiducial_error removed' in capsys.readouterr().out


@pytest.mark.parametrize('argv, message', [
    (['model', 'remove', 'tracker_drift'], "has no tracker_drift; nothing to remove"),
    (['model', 'replace', 'seeing'], 'usage: sofia model replace OLD NEW'),
    (['model', 'add', 'seeing', 'tracker_drift'], 'takes one effect; did you mean `sofia model replace seeing'),
    (['model', 'replace', 'seeing', 'no_such_effect'], "unknown effect 'no_such_effect'"),
    # OLD[,OLD2] NEW: three terms out were accepted, a term twice said the file had none, a term for itself rewrote it.
    (['model', 'replace', 'gyro_bias,earth_rotation,focal_plane_flexure', 'seeing'],
     'takes one or two different terms to take out and another to put in'),
    (['model', 'replace', 'gyro_bias,gyro_bias', 'seeing'], 'takes one or two different terms'),
    (['model', 'replace', 'gyro_bias', 'gyro_bias'], 'takes one or two different terms'),
])
def test_bad_model_edits_are_one_line_and_leave_the_file(tmp_path, capsys, argv, message):
    model = tmp_path / 'm.yaml'
    model.write_text(MODEL)
    assert main([*argv, '--model', str(model)]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and message in err
    assert model.read_text() == MODEL


def test_an_effect_sharing_a_yaml_anchor_is_fitted_alone(tmp_path):
    # `tracker_drift: *b` aliased seeing's mapping: adding seeing fitted tracker_drift too, at exit 0.
    model = tmp_path / 'm.yaml'
    model.write_text('effects:\n  seeing: &b {}\n  tracker_drift: *b\n')
    assert main(['model', 'add', 'seeing', '--model', str(model)]) == 0
    assert load_effect_config(model).fitted == {'seeing'}


def test_an_empirical_term_spelled_otherwise_is_the_same_term(tmp_path, capsys):
    # period_95s, period_095s and period_95.0s were three terms of one sinusoid, fitted side by side.
    model = tmp_path / 'm.yaml'
    model.write_text('effects:\n  empirical:hipo.x:time:period_95s: {fit: true}\n')
    for spelling in ('period_095s', 'period_95.0s'):
        assert main(['model', 'add', f'empirical:hipo.x:time:{spelling}', '--model', str(model)]) == 2
        assert 'already fits empirical:hipo.x:time:period_95s' in capsys.readouterr().err
    assert main(['model', 'remove', 'empirical:hipo.x:time:period_095s', '--model', str(model)]) == 0
    assert load_effect_config(model).effects == {}
    with pytest.raises(ConfigError, match='is empirical:hipo.y:detector_y:poly3@20..60 spelled otherwise'):
        parse_effect_config('effects:\n  empirical:hipo.y:detector_y:poly3@20..60: {}\n'
                            '  empirical:hipo.y:detector_y:poly3@20.0..60: {}\n', 'm.yaml')


def test_a_model_recorded_with_a_bag_is_not_edited(tmp_path, capsys):
    # `sofia model add seeing --model BAG/truth.yaml` rewrote what the run recorded, at exit 0.
    bag = tmp_path / 'bag'
    bag.mkdir()
    (bag / 'bag.mcap').write_bytes(b'')
    (bag / 'truth.yaml').write_text(MODEL)
    assert main(['model', 'add', 'seeing', '--model', str(bag / 'truth.yaml')]) == 2
    assert 'is a file of the bag' in capsys.readouterr().err
    assert (bag / 'truth.yaml').read_text() == MODEL
