"""`sofia import` refuses logs it cannot turn into an analysable bag: one line, exit 2, and no bag begun.

The logs are a few hand-written rows (no campaign is recorded): each case spoils one value or one
file of a directory that imports cleanly, and runs `sofia import` in this process.
"""

import errno
import os

import pytest

from sofia_ros.bag import BagReader
from sofia_ros.bag.csv_logs import import_csv_logs
from sofia_ros.bag.writer import BagWriter, _CountingMcapStorage
from sofia_ros.cli import main

#: 2004-09-03T04:32:51Z, the logbook's start_utc, in ns since the Unix epoch
START_NS = 1_094_185_971_000_000_000
SCENARIO = """latitude_deg: 31.638
longitude_deg: -97.074
height_m: 144.0
start_utc: '2004-09-03T04:32:51+00:00'
heading_deg: 90.8
start_elevation_deg: 31.7
"""


def _rows(header, *rows):
    return [header, *(','.join(map(str, row)) for row in rows)]


def _ns(ms):
    return START_NS + round(ms * 1_000_000)


#: file -> its lines: a clean set of logs, every table two or more rows
CLEAN_LOGS = {
    'gyro.csv': _rows('time_ns,el_rad_per_s,xel_rad_per_s,los_rad_per_s,el_m_per_s2,xel_m_per_s2,los_m_per_s2',
                      *((_ns(2.5 * k), 1.5e-6, -2e-7, 0.0, 0.16, -8.37, 5.11) for k in range(1, 5))),
    'gyro_temperature.csv': _rows('time_ns,temperature_c', (_ns(5), 22.8), (_ns(10), 22.79)),
    'joints.csv': _rows('time_ns,cd_elevation_rad,fd_el_rad,fd_xel_rad,fd_los_rad',
                        (_ns(5), 0.5535, 1.8e-7, -1.9e-8, -1.5e-5), (_ns(10), 0.5535, 3.7e-7, -3.8e-8, -2.9e-5)),
    'attitude.csv': _rows('time_ns,qx,qy,qz,qw', (_ns(5), 0.0, 0.0, 0.0, 1.0), (_ns(10), 0.6, 0.0, 0.0, 0.8)),
    'centroids.csv': _rows('camera,time_ns,hip,x_px,y_px', ('hipo', _ns(6), 11767, 624.1, 403.0),
                           ('hipo', _ns(7), 11767, 625.5, 403.3), ('fpi', _ns(6), '', '', '')),
    'motion_status.csv': _rows('time_ns,state', (_ns(5), 'settled'), (_ns(10), 'locked')),
}
NUMBER_COLUMNS = {
    'gyro.csv': ('el_rad_per_s', 'xel_rad_per_s', 'los_rad_per_s', 'el_m_per_s2', 'xel_m_per_s2', 'los_m_per_s2'),
    'gyro_temperature.csv': ('temperature_c',),
    'joints.csv': ('cd_elevation_rad', 'fd_el_rad', 'fd_xel_rad', 'fd_los_rad'),
    'attitude.csv': ('qx', 'qy', 'qz', 'qw'),
    'centroids.csv': ('x_px', 'y_px'),
}
BAD_NUMBERS = ('nan', 'inf', '-inf', '1e308', '', 'x1')
BAD_TIMES = ('-1', str(2**31 * 10**9), '1' * 40, '1e18', 'nan', '', str(START_NS - 1))
BAD_HIPS = ('-3', '0', '2e19', '2' + '0' * 19, '120417', '11767.0', 'Polaris')


def write_logs(directory, replace=None, files=None):
    """The clean logs in ``directory``: ``replace`` = (file, row, column, text) spoils one value (row 1 = the
    first after the header); ``files`` maps a name to its bytes instead (None: leave the file out)."""
    directory.mkdir()
    (directory / 'scenario.yaml').write_text(SCENARIO)
    for name, lines in CLEAN_LOGS.items():
        lines = list(lines)
        if replace and replace[0] == name:
            _, row, column, text = replace
            values = lines[row].split(',')
            values[lines[0].split(',').index(column)] = text
            lines[row] = ','.join(values)
        (directory / name).write_text('\n'.join(lines) + '\n')
    for name, data in (files or {}).items():
        (directory / name).unlink(missing_ok=True)
        if data is not None:
            (directory / name).write_bytes(data)
    return directory


def refusal(tmp_path, capsys, logs, exit_code=2):
    """Run `sofia import` into tmp_path/bag: the one stderr line, after asserting exit code and no bag."""
    capsys.readouterr()
    assert main(['import', str(logs), '--bag', str(tmp_path / 'bag')]) == exit_code
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith('sofia: error:'), captured.err
    assert 'Traceback' not in captured.err and captured.out == ''
    assert not (tmp_path / 'bag').exists()
    return lines[0]


def test_the_clean_logs_import(tmp_path, capsys):
    assert main(['import', str(write_logs(tmp_path / 'logs')), '--bag', str(tmp_path / 'bag')]) == 0
    with BagReader(tmp_path / 'bag') as bag:
        counts = {topic.name: topic.count for topic in bag.topics}
    assert counts['/gyro_box/imu'] == 4 and counts['/hipo/centroids'] == 2 and counts['/fpi/centroids'] == 1


@pytest.mark.parametrize('replace, message', [
    (('gyro.csv', 2, 'el_rad_per_s', 'nan'), "el_rad_per_s = 'nan' is not a number in [-10, 10] rad/s"),
    (('gyro.csv', 1, 'los_rad_per_s', 'inf'), "los_rad_per_s = 'inf' is not a number in"),
    (('joints.csv', 2, 'fd_los_rad', '1e308'), "fd_los_rad = '1e308' is not a number in [-6.28319, 6.28319]"),
    (('gyro_temperature.csv', 1, 'temperature_c', '-inf'), "temperature_c = '-inf' is not a number in [-100, 100]"),
    (('centroids.csv', 1, 'x_px', 'nan'), "x_px = 'nan' is not on the hipo detector ([-1, 1153] px)"),
    (('centroids.csv', 2, 'y_px', '1e308'), "y_px = '1e308' is not on the hipo detector"),
    (('attitude.csv', 1, 'qw', '0'), "|q| = 0 is not a unit quaternion"),
    (('attitude.csv', 2, 'qw', '0.9'), "|q| = 1.08166538 is not a unit quaternion"),
    (('attitude.csv', 1, 'qx', 'nan'), "qx = 'nan' is not a number in"),
    (('centroids.csv', 1, 'hip', '-3'), "hip = '-3' is not a star of the Hipparcos 2 catalogue (HIP 1 to 120416"),
    (('centroids.csv', 2, 'hip', '2e19'), "hip = '2e19' is not a star of the Hipparcos 2 catalogue"),
    (('joints.csv', 2, 'time_ns', str(2**31 * 10**9)), "time_ns = '2147483648000000000' must be ns since 1970"),
    (('motion_status.csv', 1, 'state', 'moving'), "state = 'moving' is not a motion state (known: transient, "),
    # Out of order or written twice: only gyro.csv was checked; the others were sorted silently, the twice-written
    # temperature kept as two messages at one stamp, a star twice in one frame.
    (('gyro_temperature.csv', 2, 'time_ns', str(_ns(5))), "time_ns = '%d' is not after the row before it" % _ns(5)),
    (('joints.csv', 2, 'time_ns', str(_ns(4))), "time_ns = '%d' is not after the row before it" % _ns(4)),
    (('attitude.csv', 2, 'time_ns', str(_ns(5))), "time_ns = '%d' is not after the row before it" % _ns(5)),
    (('motion_status.csv', 2, 'time_ns', str(_ns(1))), "time_ns = '%d' is not after the row before it" % _ns(1)),
    (('centroids.csv', 2, 'time_ns', str(_ns(5))),
     "time_ns = '%d' is before the hipo row before it; time_ns must not decrease" % _ns(5)),
    (('centroids.csv', 2, 'time_ns', str(_ns(6))), 'hip = \'11767\' is in this hipo frame twice'),
])
def test_values_that_cannot_be_analysed_are_refused(tmp_path, capsys, replace, message):
    line = refusal(tmp_path, capsys, write_logs(tmp_path / 'logs', replace))
    assert f'{replace[0]} line {replace[1] + 1}: {message}' in line and line.endswith('; correct or remove the row')


@pytest.mark.parametrize('text, message', [
    ('', 'the logbook must be a mapping (latitude_deg, start_utc, heading_deg, ...), got NoneType'),
    ('- 1\n- 2\n', 'the logbook must be a mapping'),
    ('{{{', 'not valid YAML'),
    ('latitude_deg: 31.6\nheading_deg: 90\n', 'the logbook lacks start_utc'),
    (SCENARIO.replace('31.638', '.nan'), 'scenario: latitude_deg = nan is outside [-90, 90]'),
])
def test_a_logbook_that_is_not_a_scenario_is_refused(tmp_path, capsys, text, message):
    logs = write_logs(tmp_path / 'logs', files={'scenario.yaml': text.encode()})
    assert f'scenario.yaml: {message}' in refusal(tmp_path, capsys, logs)


@pytest.mark.parametrize('name, data, message', [
    ('gyro.csv', b'time_ns,el_rad_per_s,xel_rad_per_s,los_rad_per_s\n\xff\xfe,1,2,3\n',
     'not UTF-8 text (byte 49); is it a CSV log?'),
    ('scenario.yaml', SCENARIO.encode() + b'# \xe9t\xe9\n', 'not UTF-8 text'),
    ('joints.csv', b'time_ns,cd_elevation_rad,fd_el_rad,fd_xel_rad,fd_los_rad\n1094185971005000000,0.5\n',
     'line 2: 2 values where the header has 5 columns'),
    ('gyro_temperature.csv', b'time_ns,temperature_c\n1094185971005000000\n', 'line 2: 1 values where the header'),
    ('centroids.csv', b'camera,time_ns,hip,x_px,y_px\nhipo,1094185971006000000,11767,624\n',
     'line 2: 4 values where the header has 5'),
    ('centroids.csv', b'camera,time_ns,hip,x_px,y_px\nhipo,1094185971006000000,HIP 11767,624,403\n',
     "line 2: hip = 'HIP 11767' is not a star"),
    ('gyro.csv', b'time_ns,el_rad_per_s,xel_rad_per_s,los_rad_per_s\n' + b'9' * 40 + b',0,0,0\n',
     "line 2: time_ns = '9999999999999999999999999999999999999999' must be ns since 1970-01-01 UTC"),
    ('attitude.csv', b'time_ns,qx,qy,qz,qw\n1094185971005000000,' + b'0' * 140_000 + b',0,0,1\n',
     'line 2: not a CSV row (field larger than field limit (131072))'),
], ids=['gyro-not-utf8', 'scenario-not-utf8', 'joints-short-row', 'temperature-short-row', 'centroids-short-row',
        'hip-not-integer', 'time-40-digits', 'field-over-limit'])
def test_what_raised_a_traceback_is_one_line(tmp_path, capsys, name, data, message):
    logs = write_logs(tmp_path / 'logs', files={name: data})
    assert f'{name}{":" if "line" not in message else ""} {message}' in refusal(tmp_path, capsys, logs)


@pytest.mark.parametrize('replace', [('attitude.csv', 2, 'qz', 'nan'), ('joints.csv', 2, 'fd_el_rad', 'inf'),
                                     ('gyro_temperature.csv', 2, 'temperature_c', 'nan'),
                                     ('centroids.csv', 2, 'x_px', 'inf'), ('motion_status.csv', 2, 'state', 'x')])
def test_a_refused_import_begins_no_bag_and_the_same_bag_can_be_retried(tmp_path, capsys, replace):
    logs = write_logs(tmp_path / 'logs', replace)
    refusal(tmp_path, capsys, logs)  # the bad value is in a table written after the gyro's (it left a 9 MB bag)
    (logs / replace[0]).write_text('\n'.join(CLEAN_LOGS[replace[0]]) + '\n')
    assert main(['import', str(logs), '--bag', str(tmp_path / 'bag')]) == 0
    assert (tmp_path / 'bag' / 'metadata.yaml').is_file()


def test_a_bag_the_disk_cannot_hold_is_removed_and_can_be_retried(tmp_path, capsys, monkeypatch):
    def full_disk(*_):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    logs = write_logs(tmp_path / 'logs')
    with monkeypatch.context() as patch:
        patch.setattr(_CountingMcapStorage, '_write_chunk', full_disk)
        line = refusal(tmp_path, capsys, logs, exit_code=3)
    assert '/bag: disk full; free space or write elsewhere;' in line and 'the unfinished bag was removed' in line
    assert main(['import', str(logs), '--bag', str(tmp_path / 'bag')]) == 0


def test_an_import_interrupted_while_writing_leaves_no_bag(tmp_path, monkeypatch):
    def interrupted(*_):
        raise KeyboardInterrupt

    monkeypatch.setattr(BagWriter, 'write_message', interrupted)
    with pytest.raises(KeyboardInterrupt):
        import_csv_logs(write_logs(tmp_path / 'logs'), tmp_path / 'bag')
    assert not (tmp_path / 'bag').exists()


@pytest.mark.timeout(60)
@pytest.mark.parametrize('name', ['gyro.csv', 'motion_status.csv', 'calibration_result.yaml', 'scenario.yaml'])
def test_a_log_linked_to_a_device_is_refused_not_read(tmp_path, capsys, name):
    logs = write_logs(tmp_path / 'logs', files={name: None})
    (logs / name).symlink_to('/dev/zero')
    assert f'{name} is not a regular file (a device, FIFO or socket)' in refusal(tmp_path, capsys, logs)


def bad_cases():
    """(id, replace, files): every table x every kind of bad value, and every file x every kind of bad file."""
    for name, columns in NUMBER_COLUMNS.items():
        for column in columns:
            for index, text in enumerate(BAD_NUMBERS):
                yield f'{name}-{column}-number{index}', (name, 2, column, text), None
    for name in CLEAN_LOGS:
        for index, text in enumerate(BAD_TIMES):
            yield f'{name}-time{index}', (name, 2, 'time_ns', text), None
    yield 'gyro.csv-time-not-increasing', ('gyro.csv', 2, 'time_ns', str(_ns(2.5))), None
    for index, text in enumerate(BAD_HIPS):
        yield f'centroids.csv-hip{index}', ('centroids.csv', 2, 'hip', text), None
    for index, text in enumerate(('', 'HIPO', 'hipo ')):
        yield f'centroids.csv-camera{index}', ('centroids.csv', 2, 'camera', text), None
    for index, text in enumerate(('', 'Locked', 'moving')):
        yield f'motion_status.csv-state{index}', ('motion_status.csv', 2, 'state', text), None
    for name, lines in CLEAN_LOGS.items():
        header, row = lines[0].encode(), lines[1].encode()
        spoiled = {'short-row': row.rsplit(b',', 1)[0], 'long-row': row + b',1', 'not-utf8': row + b'\xff',
                   'huge-field': row + b'9' * 131_073, 'stray-quote': row + b'"', 'header-only': b'',
                   'unknown-column': None, 'missing-column': None}
        for kind, data in spoiled.items():
            if kind == 'unknown-column':
                data = header + b',extra\n' + row + b',1\n'
            elif kind == 'missing-column':
                data = header.rsplit(b',', 1)[0] + b'\n' + row.rsplit(b',', 1)[0] + b'\n'
            else:
                data = header + b'\n' + data + (b'\n' if data else b'')
            yield f'{name}-{kind}', None, {name: data}
        if name != 'motion_status.csv':
            yield f'{name}-missing', None, {name: None}
    for kind, text in {'empty': b'', 'list': b'- 1\n', 'garbage': b'\x00\x01', 'number': b'42\n',
                       'no-timezone': SCENARIO.replace('+00:00', '').encode(), 'missing': None}.items():
        yield f'scenario.yaml-{kind}', None, {'scenario.yaml': text}
    for kind, text in {'list': b'- 1\n', 'not-utf8': b'\xff', 'not-yaml': b'{{'}.items():
        yield f'calibration_result.yaml-{kind}', None, {'calibration_result.yaml': text}


BAD_CASES = list(bad_cases())


def test_the_generator_covers_every_table_and_kind():
    assert len(BAD_CASES) >= 80
    assert {name for _, replace, files in BAD_CASES for name in ([replace[0]] if replace else files)} == {
        *CLEAN_LOGS, 'scenario.yaml', 'calibration_result.yaml'}


@pytest.mark.parametrize('replace, files', [case[1:] for case in BAD_CASES], ids=[case[0] for case in BAD_CASES])
def test_generated_bad_logs_are_one_line_exit_2_and_no_bag(tmp_path, capsys, replace, files):
    line = refusal(tmp_path, capsys, write_logs(tmp_path / 'logs', replace, files))
    assert (replace[0] if replace else next(iter(files))) in line
