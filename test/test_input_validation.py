"""Values that used to pass validation and crash mid-run, YAML caps, CLI numbers, exit codes (issue 13)."""

import json
from pathlib import Path

import pytest

from sofia_ros.cli import main
from sofia_ros.config import MAX_CONFIG_BYTES, load_effect_config, parse_effect_config, safe_load_limited
from sofia_ros.effects import resolve_params
from sofia_ros.errors import ConfigError

ROOT = Path(__file__).resolve().parents[1]
TRUTH = str(ROOT / 'config' / 'truth' / 'nominal.yaml')


@pytest.mark.parametrize('text, message', [
    ('effects: {seeing: {rms_arcsec: -0.3}}', r"effect 'seeing': rms_arcsec = -0.3 is outside \[0, 10\] arcsec"),
    ('effects: {gyro_axis_swap: {swapped_axes: foo-bar}}',
     r"swapped_axes must be one of el-xel, el-los, xel-los, xel-el, los-el, los-xel, got 'foo-bar'"),
    ('effects: {vibration_lines: {frequencies_hz: [abc, 1.3]}}',
     r"frequencies_hz\[0\] must be a number in \[0, 1000\] Hz, got 'abc'"),
    ('effects: {vibration_lines: {axes: [el, up]}}', r"axes\[1\] must be one of el, xel, los, got 'up'"),
    ('effects: {gyro_bias: {el_deg_per_h: 1.0e+300}}', r'el_deg_per_h = 1e\+300 is outside \[-10, 10\] deg/h'),
    ('effects: {gyro_misalignment: {about_el_arcsec: 1.0e+300}}',
     r'about_el_arcsec = 1e\+300 is outside \[-36000, 36000\] arcsec'),
    ('effects: {gyro_misalignment: {about_el_arcsec: 1.0e300}}',  # YAML 1.1 reads this exponent as text
     r"got '1.0e300' \(YAML reads 1e3 as text: write 1000 or 1.0e\+3\)"),
    ("effects: {seeing: {rms_arcsec: '0.3'}}", r"got '0.3' \(write it without quotes\)"),
    ('effects: {seeing: {rms_arcsec: .nan}}', r'rms_arcsec must be finite, in \[0, 10\] arcsec'),
    ('effects: {seeing: {rms_arcsec: true}}', r'rms_arcsec must be a number in \[0, 10\] arcsec, got True'),
    ('effects: {vibration_lines: {frequencies_hz: [1.0, 1.3, 4.0]}}',
     r'need one entry per line, got 3, 2 and 2$'),
    ('scenario: {start_utc: 2004-13-45T99:00:00}', r'a value cannot be read \(month must be in 1..12\)'),
    ("scenario: {start_utc: '2004-09-03'}", r'start_utc needs a timezone'),
    ('scenario: {latitude_deg: .nan}', r'latitude_deg = nan is outside \[-90, 90\]'),
    ('scenario: {heading_deg: abc}', r"heading_deg must be a number in \[-360, 360\], got 'abc'"),
    ('effects: {7: {}}', r"effect names are text, got '7'"),
])
def test_a_bad_value_is_refused_at_load_naming_file_key_and_range(text, message):
    with pytest.raises(ConfigError, match=r'^truth\.yaml: .*' + message):
        parse_effect_config(text, 'truth.yaml')


def test_noise_model_and_run_agree_on_unequal_line_lists():
    with pytest.raises(ConfigError, match='one entry per line'):
        resolve_params('vibration_lines', {'amplitudes_arcsec_per_s': [0.1]})


def test_an_alias_bomb_is_refused_before_it_is_built():
    levels = ['a: &a [x, x, x, x, x, x, x, x, x]']
    for name, previous in zip('bcdefghi', 'abcdefgh'):
        levels.append(f'{name}: &{name} [' + ', '.join([f'*{previous}'] * 9) + ']')
    bomb = '\n'.join(levels) + '\n'
    assert len(bomb) < 700
    with pytest.raises(ConfigError, match=r'expands to more than 100000 values') as caught:
        parse_effect_config(bomb, 'bomb.yaml')
    assert len(str(caught.value)) < 200


def test_too_many_aliases_and_too_deep_nesting_are_refused():
    many = 'a: &a 1\nb: [' + ', '.join(['*a'] * 150) + ']\n'
    with pytest.raises(ConfigError, match='more than 100 YAML aliases'):
        parse_effect_config(many, 'm.yaml')
    with pytest.raises(ConfigError, match='nested deeper than 50 levels'):
        parse_effect_config('a: ' + '[' * 60 + ']' * 60, 'd.yaml')


def test_a_huge_or_binary_file_is_refused_by_size_and_encoding(tmp_path):
    big = tmp_path / 'big.yaml'
    big.write_text('#' * (MAX_CONFIG_BYTES + 10))
    with pytest.raises(ConfigError, match=f'larger than {MAX_CONFIG_BYTES} bytes'):
        load_effect_config(big)
    binary = tmp_path / 'bin.yaml'
    binary.write_bytes(b'effects: {}\n\xff\xfe')
    with pytest.raises(ConfigError, match='not UTF-8 text'):
        load_effect_config(binary)


def test_a_long_bad_value_is_cut_in_the_message():
    with pytest.raises(ConfigError, match=r"must be a list \(Hz\), got 'x{40,}\.\.\.$"):
        parse_effect_config('effects: {vibration_lines: {frequencies_hz: ' + 'x' * 5000 + '}}')


RUN = ['run', 'alignment', '--direct', '--truth', TRUTH]


@pytest.mark.parametrize('option, value, message', [
    ('--hold-s', 'nan', r'argument --hold-s: must be a finite number in \(0, 7200\] s, got nan'),
    ('--max-sim-s', 'nan', r'argument --max-sim-s: must be a finite number in \(0, 172800\] s, got nan'),
    ('--drift-track-s', 'nan', r'argument --drift-track-s: must be a finite number in \[1, 3600\] s'),
    ('--seed', '-1', r'argument --seed: must be a whole number in \[0, 4294967295\]'),
    ('--hours', 'inf', r'argument --hours: must be a finite number in \(0, 24\] h'),
    ('--repetitions', '1', r'argument --repetitions: must be a whole number in \[2, 100\]'),
])
def test_run_numbers_are_checked_before_anything_is_written(option, value, message, tmp_path, capsys):
    bag = tmp_path / 'bag'
    assert main([*RUN, '--bag', str(bag), option, value]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1
    assert pytest.importorskip('re').search(message, err), err
    assert not bag.exists()



@pytest.mark.parametrize('campaign, extra, message', [
    # Each was silently ignored (and --plan '' or --variant '' flew the thesis' whole plan).
    ('alignment', ['--hold-s', '5'], '--hold-s is for the star-hop campaign, not alignment; drop it'),
    ('alignment', ['--no-follow-times'], '--no-follow-times is for the star-hop campaign'),
    ('star-hop', ['--repetitions', '3'], '--repetitions is for the alignment campaign, not star-hop'),
    ('star-hop', ['--case', 'TC-1'], '--case is for the gyro-stability campaign'),
    ('alignment', ['--plan', ''], '--plan is given an empty value'),
    ('alignment', ['--variant', ''], '--variant is given an empty value'),
    ('star-hop', ['--model', ''], '--model is given an empty value'),
])
def test_run_options_that_the_campaign_does_not_take_or_that_are_empty_are_refused(
        campaign, extra, message, tmp_path, capsys):
    bag = tmp_path / 'bag'
    assert main(['run', campaign, '--direct', '--truth', TRUTH, '--bag', str(bag), *extra]) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and message in err, err
    assert not bag.exists()


def test_a_bag_path_through_a_file_is_bad_input_not_a_disk_fault(tmp_path, capsys):
    (tmp_path / 'afile').write_text('')
    assert main([*RUN, '--bag', str(tmp_path / 'afile' / 'bag')]) == 2  # was exit 3, "check the disk"
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'afile is a file, not a directory; choose another --bag' in err, err

@pytest.mark.parametrize('args, message', [
    (['replay', 'b', '--wait-s', 'nan'], r'argument --wait-s: must be a finite number in \[0, 3600\] s'),
    (['replay', 'b', '--rate', 'nan'], r'argument --rate: must be a finite number in \[0, 1e\+06\]'),
    (['compare', 'b', '--model', 'm', '--anchor-s', '0.001'], r'argument --anchor-s: must be a finite number in \[2, '),
    (['compare', 'b', '--model', 'm', '--anchor-s', 'nan'], r'argument --anchor-s'),
])
def test_replay_and_compare_numbers_are_one_line(args, message, capsys):
    assert main(args) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and pytest.importorskip('re').search(message, err), err


def test_anchor_memory_estimate_grows_with_the_inverse_square_of_the_spacing():
    from sofia_ros.compare.cli import anchor_memory_bytes

    assert anchor_memory_bytes(1843.0, 0.001) > 2 ** 40
    assert anchor_memory_bytes(1843.0, 2.0) < 2 ** 30


@pytest.fixture(scope='module')
def short_bag(tmp_path_factory):
    """A 40 s direct alignment run: not accepted (too short), which is no error."""
    bag = tmp_path_factory.mktemp('short') / 'bag'
    code = main([*RUN, '--bag', str(bag), '--repetitions', '2', '--verification-repetitions', '1',
                 '--max-sim-s', '40'])
    return bag, code


def test_an_alignment_that_is_not_accepted_exits_0_and_says_why(short_bag):
    bag, code = short_bag
    assert code == 0
    summary = json.loads((bag / 'summary.json').read_text())
    assert summary['accepted'] is False and 'stopped' not in summary


def test_a_rerun_into_an_existing_bag_is_one_line(short_bag, capsys):
    bag, _ = short_bag
    assert main([*RUN, '--bag', str(bag)]) == 2
    assert 'already exists' in capsys.readouterr().err


def test_replay_of_an_unrecorded_topic_is_one_line(short_bag, capsys):
    bag, _ = short_bag
    assert main(['replay', str(bag), '--topics', '/nope', '--wait-s', '0']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and f'/nope not in bag {bag}; it records ' in err


def test_compare_json_into_a_directory_is_one_line(short_bag, tmp_path, capsys):
    bag, _ = short_bag
    code = main(['compare', str(bag), '--model', str(ROOT / 'config' / 'model' / 'nominal.yaml'),
                 '--json', str(tmp_path)])
    err = capsys.readouterr().err
    assert code == 2 and err.count('\n') == 1 and 'is a directory; give a file name' in err


def _without(bag, topic, folder):
    from sofia_ros.bag import BagReader, BagWriter

    thinned = folder / 'thinned'
    with BagReader(bag) as source, BagWriter(thinned) as target:
        keep = [info for info in source.topics if info.name != topic]
        for info in keep:
            target.add_topic(info.name, info.msgtype)
        for name, stamp_ns, data in source.raw_messages(*(info.name for info in keep)):
            target.write_raw(name, bytes(data), stamp_ns)
    return thinned


@pytest.mark.timeout(300)
def test_compare_warns_when_the_reference_camera_is_missing(short_bag, tmp_path, capsys):
    bag, _ = short_bag
    thinned = _without(bag, '/hipo/centroids', tmp_path)
    main(['compare', str(thinned), '--model', str(ROOT / 'config' / 'model' / 'nominal.yaml')])
    err = capsys.readouterr().err
    assert f'sofia compare: warning: {thinned} has no /hipo/centroids: the reference camera is missing' in err


def test_an_anchor_spacing_beyond_this_machines_memory_is_refused(short_bag, capsys, monkeypatch):
    import sofia_ros.compare.cli as compare_cli

    bag, _ = short_bag
    monkeypatch.setattr(compare_cli, '_MEMORY_SHARE', 1e-9)
    assert main(['compare', str(bag), '--model', str(ROOT / 'config' / 'model' / 'nominal.yaml'),
                 '--anchor-s', '2']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and '--anchor-s 2 needs about' in err and 'choose a larger --anchor-s' in err


def test_an_anchor_spacing_longer_than_the_record_is_refused(short_bag, capsys):
    # A day's spacing on a short flight left one interval: the gyro axes vanished from the verdict, at exit 0.
    bag, _ = short_bag
    assert main(['compare', str(bag), '--model', str(ROOT / 'config' / 'model' / 'nominal.yaml'),
                 '--anchor-s', '86400']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and 'is longer than the' in err and 'give at most' in err


@pytest.mark.timeout(120)
def test_replay_interrupted_by_sigint_is_one_line_and_130(short_bag):
    import os
    import signal
    import subprocess
    import sys
    import time

    bag, _ = short_bag
    replay = subprocess.Popen([sys.executable, '-m', 'sofia_ros.cli', 'replay', str(bag), '--rate', '0.01',
                               '--wait-s', '0'], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                              env={**os.environ, 'PYTHONUNBUFFERED': '1'})
    # Interrupted once it replays (its line that no one subscribes), not while it still imports.
    assert replay.stdout.readline().startswith('no subscriber after 0 s on ')
    time.sleep(0.5)
    assert replay.poll() is None
    replay.send_signal(signal.SIGINT)
    _, err = replay.communicate(timeout=60)
    assert replay.returncode == 130
    assert err == 'sofia: interrupted by SIGINT\n'


def test_a_number_too_large_for_a_float_is_refused():
    with pytest.raises(ConfigError, match=r'rms_arcsec must be finite, in \[0, 10\] arcsec'):
        parse_effect_config('effects: {seeing: {rms_arcsec: 1' + '0' * 400 + '}}')


def test_a_list_with_too_many_entries_is_refused():
    from sofia_ros.effects import MAX_LIST_ENTRIES

    entries = ', '.join(['1.0'] * (MAX_LIST_ENTRIES + 1))
    with pytest.raises(ConfigError, match=f'frequencies_hz has {MAX_LIST_ENTRIES + 1} entries '
                                          rf'\(at most {MAX_LIST_ENTRIES}\)'):
        parse_effect_config(f'effects: {{vibration_lines: {{frequencies_hz: [{entries}]}}}}')


def test_ranges_hold_for_files_while_a_fit_may_search_beyond_them():
    fitted = resolve_params('gyro_axis_swap', {'scale_temperature_coefficient_ppm_per_c': -6137.16})
    assert fitted['scale_temperature_coefficient_ppm_per_c'] == -6137.16
    with pytest.raises(ConfigError, match=r'scale_temperature_coefficient_ppm_per_c = -6137.16 is outside '
                                          r'\[-1000, 1000\] ppm/C'):
        resolve_params('gyro_axis_swap', {'scale_temperature_coefficient_ppm_per_c': -6137.16}, within_ranges=True)


def test_a_control_character_in_a_config_is_one_line():
    # PyYAML's reader checks the characters while it is built, before the parse starts.
    with pytest.raises(ConfigError, match=r'm.yaml: not valid YAML \(unacceptable character #x0001'):
        safe_load_limited('a: \x01', 'm.yaml')
