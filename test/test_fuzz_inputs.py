"""Generated bad inputs: configs, CLI numbers, damaged bags, missing topics (issue 13).

Each one exits 2 with one line on stderr: never a traceback, never a half-written output.
Run in-process through ``sofia_ros.cli.main``; the one bag is recorded once per session (conftest.CampaignBags).
"""

import shutil
from pathlib import Path

import pytest

from sofia_ros.bag import BagReader, BagWriter
from sofia_ros.cli import main
from sofia_ros.compare.observations import REQUIRED_TOPICS
from sofia_ros.effects import CATALOGUE
from sofia_ros.scenario import SCENARIO_RANGES

ROOT = Path(__file__).resolve().parents[1]
TRUTH = str(ROOT / 'config' / 'truth' / 'nominal.yaml')
MODEL = str(ROOT / 'config' / 'model' / 'nominal.yaml')

BAD_NUMBERS = ('.nan', '.inf', '-.inf', 'abc', 'true', '1.0e+300', '-1.0e+300', '[1.0]', '{a: 1}')
BAD_LIST_ENTRIES = ('[abc]', '[.nan]', '[1.0e+300]', '5', '[[1]]', '[true]')
BAD_TEXTS = ('123', 'nope', '[el]', '{a: 1}')


def _bad_configs():
    cases = []
    for spec in CATALOGUE.values():
        for param in spec.params:
            if isinstance(param.default, float):
                values = BAD_NUMBERS
            elif isinstance(param.default, list) and param.choices:
                values = [f'[{value}]' for value in BAD_TEXTS[1:]]
            elif isinstance(param.default, list):
                values = BAD_LIST_ENTRIES
            else:
                values = BAD_TEXTS
            cases += [(f'{spec.name}.{param.name}={value}', f'effects:\n  {spec.name}: {{{param.name}: {value}}}\n')
                      for value in values]
    for key in SCENARIO_RANGES:
        cases += [(f'scenario.{key}={value}', f'scenario:\n  {key}: {value}\n')
                  for value in ('.nan', 'abc', '1.0e+300', 'true')]
    cases += [(f'scenario.start_utc={value}', f'scenario:\n  start_utc: {value}\n')
              for value in ('2004-13-45T99:00:00', 'yesterday', "'2004-09-03'", '1200-01-01T00:00:00Z', '[1]')]
    bomb = ['a: &a [x, x, x, x, x, x, x, x, x]'] + [
        f'{name}: &{name} [' + ', '.join([f'*{previous}'] * 9) + ']' for name, previous in zip('bcdefg', 'abcdef')]
    cases += [
        ('alias bomb', '\n'.join(bomb) + '\n'),
        ('deep nesting', 'effects: ' + '[' * 200 + ']' * 200 + '\n'),
        ('a list at the top', '- effects\n'),
        ('unknown top-level key', 'effect: {}\n'),
        ('effects as a list', 'effects: [seeing]\n'),
        ('unknown effect', 'effects: {gyro_wobble: {}}\n'),
        ('unknown parameter', 'effects: {seeing: {rms_arcseconds: 0.3}}\n'),
        ('fit not a bool', 'effects: {seeing: {fit: maybe}}\n'),
        ('unclosed bracket', 'effects: {seeing: {\n'),
        ('tab indentation', 'effects:\n\tseeing: {}\n'),
        ('unequal line lists', 'effects: {vibration_lines: {frequencies_hz: [1.0, 2.0, 3.0]}}\n'),
        ('binary', b'\x89PNG\r\n\x1a\n\xff\xfe\x00'),
        ('too large', '#' * (1 << 20) + '\n'),
    ]
    return cases


CONFIGS = _bad_configs()


def _one_line(capsys):
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith('sofia') and ' error: ' in err, err
    assert 'Traceback' not in err
    return err


@pytest.mark.parametrize('label, text', CONFIGS, ids=[label for label, _ in CONFIGS])
def test_a_bad_config_is_refused_before_anything_is_written(label, text, tmp_path, capsys):
    truth = tmp_path / 'truth.yaml'
    (truth.write_bytes if isinstance(text, bytes) else truth.write_text)(text)
    bag = tmp_path / 'bag'
    assert main(['run', 'alignment', '--direct', '--truth', str(truth), '--bag', str(bag)]) == 2
    _one_line(capsys)
    assert not bag.exists()


def test_the_bad_config_count():
    assert len(CONFIGS) >= 200


NUMBERS = ('nan', 'inf', '-inf', 'abc', '1e400', '', '-1e12', '1e12')
CLI_CASES = [
    *((['run', 'alignment', '--direct', '--truth', TRUTH, option], value)
      for option in ('--hold-s', '--max-sim-s', '--drift-track-s', '--repetitions', '--verification-repetitions',
                     '--seed') for value in NUMBERS),
    *((['run', 'gyro-stability', '--case', 'TC-1', '--truth', TRUTH, '--hours'], value) for value in NUMBERS),
    *((['replay', 'BAG', option], value) for option in ('--rate', '--wait-s') for value in NUMBERS),
    *((['compare', 'BAG', '--model', MODEL, '--anchor-s'], value) for value in (*NUMBERS, '0', '0.001', '1.99')),
]


@pytest.mark.parametrize('args, value', CLI_CASES, ids=[f'{" ".join(a[:2])} {a[-1]} {v!r}' for a, v in CLI_CASES])
def test_a_bad_cli_number_is_one_line(args, value, tmp_path, capsys):
    bag = tmp_path / 'bag'
    argv = [str(bag) if arg == 'BAG' else arg for arg in args] + [value]
    if argv[0] == 'run':
        argv += ['--bag', str(bag)]
    assert main(argv) == 2
    err = _one_line(capsys)
    assert f'argument {args[-1]}' in err
    assert not bag.exists()


def _record_40_s(path):
    assert main(['run', 'alignment', '--direct', '--truth', TRUTH, '--bag', str(path), '--repetitions', '2',
                 '--verification-repetitions', '1', '--max-sim-s', '40']) == 0


@pytest.fixture(scope='module')
def bag(campaign_bags):
    """A 40 s direct alignment run, recorded once per session (the tests below read copies of it)."""
    return campaign_bags.get('fuzz-alignment-40s', _record_40_s)


def _copy(bag, folder):
    copy = shutil.copytree(bag, folder / 'damaged')
    return copy, next(copy.glob('*.mcap'))


def _chunk_starts(data):
    from sofia_ros.bag.recovery import _top_level_records

    return [start for start, _ in _top_level_records(data, 8) if data[start] == 0x06]


def _compare_refuses(bag, folder, capsys):
    out = folder / 'out.json'
    assert main(['compare', str(bag), '--model', MODEL, '--json', str(out)]) == 2
    err = _one_line(capsys)
    assert not out.exists()
    return err


@pytest.mark.parametrize('fraction', [0.0, 0.001, 0.05, 0.2, 0.35, 0.5, 0.65, 0.8, 0.95, 0.999])
def test_a_cut_bag_is_one_line(bag, fraction, tmp_path, capsys):
    copy, mcap = _copy(bag, tmp_path)
    data = mcap.read_bytes()
    mcap.write_bytes(data[:int(len(data) * fraction)])
    _compare_refuses(copy, tmp_path, capsys)


@pytest.mark.parametrize('chunk', range(1, 9))
def test_a_bag_with_a_flipped_chunk_is_one_line(bag, chunk, tmp_path, capsys):
    # The first chunk holds only /config/truth, which compare never reads (it must not see the
    # truth): damage there is rightly not noticed. Every later chunk holds data compare reads.
    copy, mcap = _copy(bag, tmp_path)
    data = bytearray(mcap.read_bytes())
    starts = _chunk_starts(bytes(data))
    start = starts[chunk * (len(starts) - 1) // 9 + 1]
    data[start + 53:start + 61] = bytes(byte ^ 0xFF for byte in data[start + 53:start + 61])  # its zstd frame header
    mcap.write_bytes(bytes(data))
    _compare_refuses(copy, tmp_path, capsys)


@pytest.mark.parametrize('where', ['magic', 'trailing magic', 'metadata.yaml', 'no metadata.yaml', 'no mcap'])
def test_a_bag_with_a_broken_frame_is_one_line(bag, where, tmp_path, capsys):
    copy, mcap = _copy(bag, tmp_path)
    data = bytearray(mcap.read_bytes())
    if where == 'magic':
        data[1:4] = b'XYZ'
        mcap.write_bytes(bytes(data))
    elif where == 'trailing magic':
        data[-8:] = bytes(8)
        mcap.write_bytes(bytes(data))
    elif where == 'metadata.yaml':
        (copy / 'metadata.yaml').write_text('rosbag2_bagfile_information: [\n')
    elif where == 'no metadata.yaml':
        (copy / 'metadata.yaml').unlink()
    else:
        mcap.unlink()
    _compare_refuses(copy, tmp_path, capsys)


@pytest.mark.parametrize('dropped', [*REQUIRED_TOPICS, 'every camera'])
def test_a_bag_without_a_needed_topic_is_one_line(bag, dropped, tmp_path, capsys):
    thinned = tmp_path / 'thinned'
    with BagReader(bag) as source, BagWriter(thinned) as target:
        keep = [info for info in source.topics
                if info.name != dropped and not (dropped == 'every camera' and info.name.endswith('/centroids'))]
        for info in keep:
            target.add_topic(info.name, info.msgtype)
        for topic, stamp_ns, data in source.raw_messages(*(info.name for info in keep)):
            target.write_raw(topic, bytes(data), stamp_ns)
    err = _compare_refuses(thinned, tmp_path, capsys)
    assert dropped in err or dropped == 'every camera'


def test_replay_of_unknown_topics_is_one_line(bag, capsys):
    assert main(['replay', str(bag), '--topics', '/nope', '/clock', '--wait-s', '0']) == 2
    assert '/nope not in bag' in _one_line(capsys)


def test_replay_of_a_bag_damaged_mid_file_publishes_nothing(bag, tmp_path, capsys, monkeypatch):
    # It published the chunks before the damage, then failed: a graph listening had taken half a recording.
    copy, mcap = _copy(bag, tmp_path)
    data = bytearray(mcap.read_bytes())
    starts = _chunk_starts(bytes(data))
    start = starts[len(starts) // 2]
    data[start + 53:start + 61] = bytes(byte ^ 0xFF for byte in data[start + 53:start + 61])
    mcap.write_bytes(bytes(data))

    def no_graph(*args, **kwargs):
        raise AssertionError('the replay started a ROS context for a damaged bag')

    monkeypatch.setattr('sofia_ros.nodes.replay.rclpy.init', no_graph)
    assert main(['replay', str(copy), '--rate', '0', '--wait-s', '0']) == 2
    err = _one_line(capsys)
    assert 'is truncated or corrupt' in err and f'sofia recover {copy}' in err


@pytest.mark.parametrize('topics, message', [
    ([], 'expected at least one argument'),  # replayed every topic, exit 0
    ([''], '--topics is given an empty topic name'),
])
def test_replay_of_no_topic_is_one_line(bag, capsys, topics, message):
    assert main(['replay', str(bag), '--topics', *topics, '--wait-s', '0']) == 2
    assert message in _one_line(capsys)


def test_a_write_dds_refuses_during_a_replay_is_counted_and_the_replay_goes_on():
    # A reliable subscriber that left mid-replay made rmw_fastrtps refuse a write: an RCLError traceback, exit 1.
    from rclpy.impl.implementation_singleton import rclpy_implementation

    from sofia_ros.nodes.replay import _published

    class Publisher:
        topic_name = '/gyro_box/imu'

        def __init__(self, error):
            self.error = error

        def publish(self, data):
            raise rclpy_implementation.RCLError(self.error)

    refused = {}
    refusing = Publisher('Failed to publish: cannot publish data, at ./src/rmw_publish.cpp:120')
    assert not _published(refusing, b'', refused) and not _published(refusing, b'', refused)
    assert refused == {'/gyro_box/imu': 2}
    with pytest.raises(rclpy_implementation.RCLError, match='publisher is invalid'):
        _published(Publisher('publisher is invalid'), b'', refused)
