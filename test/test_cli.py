"""The `sofia` command as a user runs it: output, exit codes, one-line errors.

Most cases call `sofia_ros.cli.main` in this process (each subprocess costs a second or more of
imports); a few run the installed entry point as a subprocess, to show it behaves the same.
"""

import json
import subprocess
import sys
from pathlib import Path

import pytest

from sofia_ros.cli import main

SOFIA = [sys.executable, '-m', 'sofia_ros.cli']


def run_sofia(*args, timeout=120):
    """The entry point in a subprocess, as a user runs it."""
    return subprocess.run([*SOFIA, *args], capture_output=True, text=True, timeout=timeout)


@pytest.fixture
def sofia(capfd):
    """``sofia(*args)``: cli.main in this process, its exit code and output (file descriptors 1 and 2, so
    that nothing written past sys.stderr escapes) in the shape of ``run_sofia``'s."""
    def run(*args):
        capfd.readouterr()
        code = main(list(args))
        captured = capfd.readouterr()
        return subprocess.CompletedProcess(args, code, captured.out, captured.err)
    return run


def test_effects_lists_every_effect_with_units():
    result = run_sofia('effects')
    assert result.returncode == 0
    assert 'gyro_misalignment' in result.stdout
    assert 'about_los_arcsec = 3590.0 arcsec' in result.stdout


def test_effects_json_is_the_documented_contract(sofia):
    result = sofia('effects', '--json')
    assert result.returncode == 0
    entries = json.loads(result.stdout)
    names = [entry['name'] for entry in entries]
    assert 'fpi_internal_flexure' in names and 'timestamp_offset' in names


def test_unknown_verb_exits_2_without_traceback():
    result = run_sofia('fly')
    assert result.returncode == 2
    assert 'Traceback' not in result.stderr
    assert "invalid choice: 'fly'" in result.stderr


@pytest.mark.timeout(300)
def test_demo_reproduces_the_thesis_tables():
    result = run_sofia('demo', timeout=280)
    assert result.returncode == 0, result.stderr
    assert 'Traceback' not in result.stderr
    assert 'Table 5.7' in result.stdout and 'Table 6.5' in result.stdout and 'Table D.3' in result.stdout
    assert 'FAIL' not in result.stdout


BAD_TRUTHS = {
    'broken.yaml': ('effects:\n  earth_rotation: {\n', 'not valid YAML'),
    'unknown.yaml': ('effects:\n  gyro_wobble: {}\n', "unknown effect 'gyro_wobble'; did you mean"),
    'badparam.yaml': ('effects:\n  seeing: {rms_arcsec: fast}\n', 'rms_arcsec must be a number in [0, 10] arcsec'),
    'lowstar.yaml': ('effects:\n  earth_rotation: {}\nscenario:\n  latitude_deg: 12.0\n', 'below the limit of 20 deg'),
    'highcd.yaml': ('effects:\n  earth_rotation: {}\nscenario:\n  start_elevation_deg: 70.0\n',
                    'coarse drive elevation 70.000 deg is outside 16.5-68.5 deg'),
    'toplevel.yaml': ('effect:\n  seeing: {}\n', "unknown top-level key(s) effect"),
}


@pytest.mark.parametrize('name', sorted(BAD_TRUTHS))
def test_bad_truth_is_one_line_exit_2_and_no_bag(tmp_path, sofia, name):
    _assert_bad_truth_refused(tmp_path, name, sofia)


def test_the_entry_point_refuses_a_bad_truth_as_main_does(tmp_path):
    _assert_bad_truth_refused(tmp_path, 'broken.yaml', run_sofia)


def _assert_bad_truth_refused(tmp_path, name, run):
    text, message = BAD_TRUTHS[name]
    truth = tmp_path / name
    truth.write_text(text)
    bag = tmp_path / 'bag'
    result = run('run', 'alignment', '--truth', str(truth), '--bag', str(bag), '--direct')
    assert result.returncode == 2
    assert result.stderr.count('\n') == 1 and message in result.stderr and 'Traceback' not in result.stderr
    assert not bag.exists()


def test_fine_drive_maneuver_beyond_its_travel_is_refused_before_running(tmp_path):
    # A 6 deg LOS rotation cannot fit in the +-3 deg fine drive.
    from sofia_ros.errors import InvalidArgumentError
    from sofia_ros.sim.calibration import AlignmentPlan

    with pytest.raises(InvalidArgumentError, match=r'los_angle_deg must be in \(0, 5.3\]'):
        AlignmentPlan(los_angle_deg=6.0)


def test_existing_bag_directory_is_refused(tmp_path, sofia):
    bag = tmp_path / 'bag'
    bag.mkdir()
    result = sofia('run', 'alignment', '--truth', 'config/truth/nominal.yaml', '--bag', str(bag), '--direct')
    assert result.returncode == 2 and 'already exists; choose another --bag' in result.stderr


def test_missing_truth_file_is_refused(tmp_path, sofia):
    result = sofia('run', 'alignment', '--truth', str(tmp_path / 'nope.yaml'), '--bag', str(tmp_path / 'b'))
    assert result.returncode == 2 and 'cannot read' in result.stderr and 'check the path' in result.stderr


def test_replay_of_a_missing_bag_is_refused(tmp_path, sofia):
    result = sofia('replay', str(tmp_path / 'none'))
    assert result.returncode == 2 and 'does not exist' in result.stderr


@pytest.mark.parametrize('option, value, message', [
    ('--rate', '-1', 'argument --rate: must be a finite number in [0, 1e+06] x real time, got -1'),
    ('--wait-s', '-2', 'argument --wait-s: must be a finite number in [0, 3600] s, got -2')])
def test_replay_refuses_negative_rate_and_wait(tmp_path, sofia, option, value, message):
    result = sofia('replay', str(tmp_path / 'none'), option, value)
    assert result.returncode == 2 and message in result.stderr


@pytest.mark.parametrize('mode', ['--processes', '--direct', '--all-dds'])
def test_gyro_stability_refuses_a_graph_mode(tmp_path, sofia, mode):
    result = sofia('run', 'gyro-stability', '--case', 'TC-1', '--truth', 'config/truth/nominal.yaml',
                       '--bag', str(tmp_path / 'b'), mode)
    assert result.returncode == 2 and 'without a node graph; drop --processes / --direct / --all-dds' in result.stderr
    assert not (tmp_path / 'b').exists()


def test_a_flipped_byte_in_a_bag_is_one_line_naming_the_chunk(tmp_path, sofia):
    from mcap.reader import make_reader
    from sensor_msgs.msg import Imu

    from sofia_ros.bag import BagWriter

    bag = tmp_path / 'flipped'
    with BagWriter(bag, compress=False, flush_period_ns=250_000_000) as writer:
        writer.write_document('/config/case', 'case: TC-1\nheading_deg: 324.0\n', 0)
        writer.add_topic('/gyro_box/imu', 'sensor_msgs/msg/Imu')
        for i in range(4000):
            writer.write_message('/gyro_box/imu', Imu(), 2_500_000 * i)
    mcap_file = bag / 'flipped.mcap'
    with mcap_file.open('rb') as stream:
        chunks = make_reader(stream).get_summary().chunk_indexes
    data = bytearray(mcap_file.read_bytes())
    data[chunks[5].chunk_start_offset + chunks[5].chunk_length - 50] ^= 0x40
    mcap_file.write_bytes(bytes(data))
    result = sofia('noise', str(bag))
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and 'Traceback' not in result.stderr
    assert f'chunk 6 of {len(chunks)} (byte {chunks[5].chunk_start_offset},' in lines[0]
    assert lines[0].endswith(f"fails its CRC check); salvage its complete chunks with `sofia recover {bag}`")


@pytest.mark.parametrize('flags, mode', [([], 'executor'), (['--all-dds'], 'executor-dds'),
                                         (['--processes'], 'processes'), (['--direct'], 'direct')])
def test_the_run_flags_choose_the_mode(flags, mode):
    from sofia_ros.cli import _mode, build_parser

    args = build_parser().parse_args(['run', 'alignment', '--truth', 'truth.yaml', '--bag', 'bag', *flags])
    assert _mode(args) == mode


def test_two_run_modes_at_once_are_refused(tmp_path, sofia):
    result = sofia('run', 'alignment', '--truth', 'config/truth/nominal.yaml', '--bag', str(tmp_path / 'b'),
                       '--all-dds', '--direct')
    assert result.returncode == 2 and 'not allowed with argument' in result.stderr
    assert not (tmp_path / 'b').exists()


def test_a_python_warning_is_one_sofia_line(tmp_path):
    # Every star hop warns that eq. 6.1's matrix was re-orthonormalized: Python's format took two lines, the second
    # the source code of the warning's call.
    done = subprocess.run([sys.executable, '-m', 'sofia_ros.cli', 'run', 'star-hop', '--direct', '--truth',
                           'config/truth/nominal.yaml', '--observations', '1-2', '--hold-s', '1', '--no-follow-times',
                           '--bag', str(tmp_path / 'bag')], capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr
    warned = [line for line in done.stderr.splitlines() if 'warning' in line.lower()]
    assert warned == ['sofia: warning: alignment.tarf_from_gyrf re-orthonormalized (max |A A^T - I| = 9e-06)'], \
        done.stderr


def test_the_model_a_run_suggests_is_found_from_any_folder(tmp_path, monkeypatch):
    # `analyze it: sofia compare BAG --model config/model/nominal.yaml` failed from any folder but the checkout's.
    from sofia_ros.cli import _nominal_model

    monkeypatch.chdir(tmp_path)
    assert Path(_nominal_model()).is_file()


@pytest.mark.parametrize('argv, message', [
    # Each was ignored at exit 0.
    (['effects', 'new', 'wobble', '--kind', 'gyro', '--json'], '--json prints the catalogue'),
    (['effects', '--dir', 'plugins'], '--dir goes with `sofia effects new NAME --kind KIND`'),
    (['effects', '--kind', 'gyro'], '--kind goes with'),
])
def test_effects_options_that_do_not_apply_are_one_line(argv, message, tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and message in err
    assert list(tmp_path.iterdir()) == []


def test_a_run_stopped_by_its_sim_time_limit_says_so(tmp_path, capsys):
    # It said only "the calibration node published no result".
    truth = Path(__file__).resolve().parents[1] / 'config' / 'truth' / 'nominal.yaml'
    assert main(['run', 'alignment', '--variant', 'minimal', '--truth', str(truth), '--seed', '1',
                 '--bag', str(tmp_path / 'bag'), '--direct', '--max-sim-s', '60']) == 0
    assert ('alignment NOT accepted: the run reached its sim-time limit (--max-sim-s 60) before the calibration '
            'finished' in capsys.readouterr().out)
