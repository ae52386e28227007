"""Bags that are not what their metadata.yaml says, and damaged files: read right or refused in one line (round 3).

A stray .mcap beside the listed one, a metadata.yaml of another recording, metadata that is not
text, a directory or a device where the .mcap should be; `sofia recover` past a damaged magic or
header, beside a stray file, onto a full or read-only disk. The fuzz cases at the end damage a
small bag every way and position, and each must read back exactly or stop with one BagError line,
and a recover either succeeds or leaves nothing behind.
"""

import errno
import os
import shutil
from pathlib import Path

import numpy as np
import pytest
import yaml
from mcap.reader import make_reader
from sensor_msgs.msg import Imu

from sofia_ros.bag import BagReader, BagWriter, recover_bag
from sofia_ros.bag.digest import topic_digests
from sofia_ros.cli import main
from sofia_ros.errors import BagError
from sofia_ros.topics import SCENARIO_DOCUMENT

EPOCH_NS = 1_094_185_971_000_000_000  # 2004-09-03T04:32:51Z, the default alignment campaign's start
SCENARIO = 'start_utc: 2004-09-03T04:32:51Z\n'
IMU_TOPIC = '/gyro_box/imu'
PERIOD_NS = 2_500_000
SAMPLES = 400  # 1 s at 400 Hz: about 5 chunks of 0.2 s


def _imu(stamp_ns):
    message = Imu()
    message.header.frame_id = 'gyrf'
    message.header.stamp.sec, message.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    message.angular_velocity.x = stamp_ns * 1e-12
    message.linear_acceleration.z = 9.81
    return message


def _write_bag(path, *, samples=SAMPLES, epoch_ns=EPOCH_NS):
    """A campaign-like bag in UTC: its scenario document and ``samples`` Imu messages in several chunks."""
    with BagWriter(path, epoch_ns=epoch_ns, flush_period_ns=80 * PERIOD_NS) as bag:
        bag.write_document(SCENARIO_DOCUMENT.name, SCENARIO, 0)
        bag.add_topic(IMU_TOPIC, 'sensor_msgs/msg/Imu')
        for index in range(samples):
            bag.write_message(IMU_TOPIC, _imu(index * PERIOD_NS), index * PERIOD_NS)
    return Path(path)


@pytest.fixture(scope='module')
def small_bag(tmp_path_factory):
    """The undamaged bag every test copies (a directory named `run`, as every copy is)."""
    return _write_bag(tmp_path_factory.mktemp('small') / 'run')


@pytest.fixture(scope='module')
def other_run(tmp_path_factory):
    """Another recording, also in a directory named `run`: fewer samples, a later epoch."""
    return _write_bag(tmp_path_factory.mktemp('other') / 'run', samples=SAMPLES // 2, epoch_ns=EPOCH_NS + 10**9)


@pytest.fixture
def bag(small_bag, tmp_path):
    """A copy of the small bag to damage."""
    return Path(shutil.copytree(small_bag, tmp_path / 'run'))


def _campaign_imu_stamps(path):
    with BagReader(path, campaign_time=True) as reader:
        imu = reader.imu_arrays(IMU_TOPIC)
    return imu.stamp_ns, imu.header_stamp_ns


def _chunks(mcap):
    with mcap.open('rb') as stream:
        return make_reader(stream).get_summary().chunk_indexes


def _one_error_line(capsys):
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith('sofia: error: ') and 'Traceback' not in err, err
    return err


# --- 1. a stray .mcap beside the listed one ----------------------------------------------------------------------

def test_a_stray_mcap_is_not_read_and_is_named_on_stderr(bag, capsys):
    shutil.copy(bag / 'run.mcap', bag / 'run copy.mcap')
    stamps, header_stamps = _campaign_imu_stamps(bag)
    expected = np.arange(SAMPLES) * PERIOD_NS
    # Before: the stray file sent the reading down a path that took the epoch off twice.
    assert np.array_equal(stamps, expected) and np.array_equal(header_stamps, expected)
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and err.startswith('sofia: warning: bag ')
    assert 'run copy.mcap, which its metadata.yaml does not list: read only run.mcap' in err


def test_a_stray_mcap_does_not_skip_the_crc_check(bag):
    shutil.copy(bag / 'run.mcap', bag / 'stray.mcap')
    chunk = _chunks(bag / 'run.mcap')[2]
    data = bytearray((bag / 'run.mcap').read_bytes())
    data[chunk.chunk_start_offset + chunk.chunk_length - 50] ^= 0x10
    (bag / 'run.mcap').write_bytes(bytes(data))
    with BagReader(bag) as reader, pytest.raises(BagError, match=r'chunk 3 of \d+ .* fails'):
        reader.imu_arrays(IMU_TOPIC)


def test_a_listed_file_that_is_missing_is_one_line(bag):
    (bag / 'run.mcap').rename(bag / 'renamed.mcap')
    with pytest.raises(BagError, match=r'its metadata.yaml lists run.mcap, which is not in the bag '
                                       r'\(.mcap files there: renamed.mcap\); restore the file') as caught:
        BagReader(bag)
    assert '\n' not in str(caught.value)


def _imu_message_index(mcap, chunk_number):
    """Byte offset of the Imu topic's MessageIndex record after chunk ``chunk_number``."""
    with mcap.open('rb') as stream:
        summary = make_reader(stream).get_summary()
    channel = next(channel.id for channel in summary.channels.values() if channel.topic == IMU_TOPIC)
    return summary.chunk_indexes[chunk_number].message_index_offsets[channel]


@pytest.mark.parametrize(('field', 'message'), [
    # opcode (1), record length (8), channel id (2), length of the pairs (4), then (log time, offset) pairs
    (15 + 2, 'a message index disagrees with the messages of its chunk'),
    (15 + 8 + 1, 'a message index points outside the message records of its chunk'),
    (11, r'the message indexes list \d+ messages on /gyro_box/imu, the statistics 400'),
])
def test_a_damaged_message_index_is_refused_not_read(bag, field, message):
    # Message indexes carry no CRC: a moved log time, offset or pair count would move or drop samples.
    index = _imu_message_index(bag / 'run.mcap', 1)
    data = bytearray((bag / 'run.mcap').read_bytes())
    if field == 11:  # one pair fewer: the record keeps its length, the index lists a message less
        pairs = int.from_bytes(data[index + field:index + field + 4], 'little')
        data[index + field:index + field + 4] = (pairs - 16).to_bytes(4, 'little')
    else:
        data[index + field] ^= 0x40
    (bag / 'run.mcap').write_bytes(bytes(data))
    with BagReader(bag) as reader, pytest.raises(BagError, match=message) as caught:
        reader.imu_arrays(IMU_TOPIC)
    assert '\n' not in str(caught.value)


# --- 2. a metadata.yaml of another recording ------------------------------------------------------------------------

def test_metadata_of_another_recording_is_refused_naming_the_mismatch(bag, other_run, capsys):
    shutil.copy(other_run / 'metadata.yaml', bag / 'metadata.yaml')
    with pytest.raises(BagError, match=rf'metadata.yaml does not match run.mcap: it lists {SAMPLES // 2} messages '
                                       rf'on {IMU_TOPIC}, the MCAP file\(s\) hold {SAMPLES} .*`sofia recover '):
        BagReader(bag).open()
    assert main(['compare', str(bag), '--model', 'config/model/nominal.yaml']) == 2
    assert 'does not match run.mcap' in _one_error_line(capsys)


def test_metadata_with_the_right_counts_but_another_start_is_refused(bag):
    metadata = yaml.safe_load((bag / 'metadata.yaml').read_text())
    metadata['rosbag2_bagfile_information']['starting_time']['nanoseconds_since_epoch'] = 0
    (bag / 'metadata.yaml').write_text(yaml.safe_dump(metadata))
    # Before: "recorded with times from 0 ... re-record it", a wrong diagnosis.
    with pytest.raises(BagError, match=r'its starting time is 0 ns, the first message is logged at '
                                       rf'{EPOCH_NS} ns'):
        _campaign_imu_stamps(bag)


def test_recover_rebuilds_a_bag_whose_metadata_is_foreign(bag, other_run, tmp_path):
    shutil.copy(other_run / 'metadata.yaml', bag / 'metadata.yaml')
    report = recover_bag(bag, tmp_path / 'rebuilt')
    assert report.message_count == SAMPLES + 1
    stamps, _ = _campaign_imu_stamps(tmp_path / 'rebuilt')
    assert np.array_equal(stamps, np.arange(SAMPLES) * PERIOD_NS)


# --- 3. metadata.yaml read capped, with the limited YAML loader ------------------------------------------------------

@pytest.mark.parametrize(('text', 'message'), [
    ('rosbag2_bagfile_information: {}\nrosbag2_bagfile_information: {}\n', 'given twice'),
    ('a: &a [' + '1, ' * 10 + ']\n' + ''.join(f'k{i}: [*a, *a, *a, *a]\n' for i in range(300)), 'aliases'),
    ('# ' + 'x' * (1 << 20) + '\n', 'larger than'),
])
def test_metadata_is_read_with_the_capped_and_limited_loader(bag, text, message):
    (bag / 'metadata.yaml').write_text(text)
    with pytest.raises(BagError, match=rf'metadata.yaml is not rosbag2 metadata \(ConfigError: .*{message}') as caught:
        BagReader(bag)
    assert '\n' not in str(caught.value)


# --- 4. sofia recover ----------------------------------------------------------------------------------------------

@pytest.mark.parametrize('damaged_bytes', [1, 8, 20])
def test_recover_reads_past_a_damaged_magic_and_header(bag, tmp_path, capsys, damaged_bytes):
    data = bytearray((bag / 'run.mcap').read_bytes())
    data[:damaged_bytes] = bytes(damaged_bytes)
    (bag / 'run.mcap').write_bytes(bytes(data))
    assert main(['recover', str(bag), '--out', str(tmp_path / 'fixed')]) == 0
    assert f'recovered {SAMPLES + 1} messages on 2 topics' in capsys.readouterr().out
    stamps, _ = _campaign_imu_stamps(tmp_path / 'fixed')
    assert np.array_equal(stamps, np.arange(SAMPLES) * PERIOD_NS)


def test_recover_keeps_the_side_files_as_they_were(bag, tmp_path):
    # A run writes its truth, model, plan and summary beside the bag: a recovered bag without them could no longer
    # say what it recorded (they were dropped, healthy bag or not). The source's .mcap and metadata are rebuilt.
    side = {'truth.yaml': 'effects: {gyro_bias: {}}\n', 'summary.json': '{"stopped": "SIGKILL"}\n',
            'plan.yaml': 'plan: 1\n'}
    for name, text in side.items():
        (bag / name).write_text(text)
    (bag / '.sofia-cache').mkdir()
    recover_bag(bag, tmp_path / 'fixed')
    for name, text in side.items():
        assert (tmp_path / 'fixed' / name).read_text() == text
    assert sorted(path.name for path in (tmp_path / 'fixed').iterdir()) == sorted(
        ['fixed.mcap', 'metadata.yaml', *side])


def test_recover_beside_a_stray_file_takes_the_listed_one(bag, other_run, tmp_path):
    shutil.copy(other_run / 'run.mcap', bag / 'aaa.mcap')
    chunks = _chunks(bag / 'run.mcap')
    data = bytearray((bag / 'run.mcap').read_bytes())
    data[chunks[2].chunk_start_offset + chunks[2].chunk_length - 50] ^= 0x10
    (bag / 'run.mcap').write_bytes(bytes(data))
    report = recover_bag(bag, tmp_path / 'fixed')
    assert report.skipped_offsets == (chunks[2].chunk_start_offset,)
    assert SAMPLES // 2 < report.message_count < SAMPLES  # the listed file's, less one chunk


def test_recover_of_a_file_without_any_chunk_is_one_line_and_leaves_nothing(bag, tmp_path, capsys):
    (bag / 'run.mcap').write_bytes(os.urandom(4096))
    assert main(['recover', str(bag), '--out', str(tmp_path / 'fixed')]) == 2
    err = _one_error_line(capsys)
    assert 'run.mcap holds no intact MCAP chunk (' in err and err.endswith('); nothing to recover\n')
    assert not (tmp_path / 'fixed').exists()


@pytest.mark.parametrize('writes_before', [0, 1, 3])
@pytest.mark.parametrize(('code', 'exit_code', 'reason'), [
    (errno.ENOSPC, 3, 'disk full; free space or write elsewhere'),
    (errno.EROFS, 2, 'read-only file system; write to a writable directory'),
])
def test_recover_onto_a_full_or_read_only_disk_is_one_line_and_leaves_nothing(
        bag, tmp_path, capsys, monkeypatch, code, exit_code, reason, writes_before):
    from sofia_ros.bag.mcap_storage import CheckedMcapStorage

    emit, writes = CheckedMcapStorage._emit, []

    def fill_up(self, data):  # the header, then chunks, then the summary: the disk fills after writes_before
        if len(writes) == writes_before:
            raise OSError(code, os.strerror(code))
        writes.append(len(data))
        emit(self, data)

    monkeypatch.setattr(CheckedMcapStorage, '_emit', fill_up)
    assert main(['recover', str(bag), '--out', str(tmp_path / 'new' / 'folders' / 'fixed')]) == exit_code
    assert reason in _one_error_line(capsys)
    assert not (tmp_path / 'new').exists()  # nor the folders made for it


def test_recover_onto_a_directory_that_cannot_be_made_is_one_line(bag, tmp_path, capsys, monkeypatch):
    def refuse(self, *args, **kwargs):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(self))

    monkeypatch.setattr(Path, 'mkdir', refuse)
    assert main(['recover', str(bag), '--out', str(tmp_path / 'fixed')]) == 2
    assert 'read-only file system' in _one_error_line(capsys)
    assert not (tmp_path / 'fixed').exists()


@pytest.mark.parametrize(('qos', 'latched'), [
    ('- {durability: transient_local}\n', True),
    ('- {durability: volatile}\n', False),
    ('', False),
    ('durability: transient_local\n', False),  # not a list of profiles
    ('- transient_local\n', False),
])
def test_recover_reads_a_channels_qos_with_the_limited_loader(qos, latched):
    from mcap.records import Channel

    from sofia_ros.bag.recovery import _is_latched

    assert _is_latched(Channel(id=1, schema_id=1, topic='/x', message_encoding='cdr',
                               metadata={'offered_qos_profiles': qos})) is latched


@pytest.mark.parametrize('qos', ['- {durability: [\n', '- &a {d: 1}\n' + '- *a\n' * 200, '- {a: 1, a: 2}\n'])
def test_recover_refuses_a_channel_whose_qos_is_not_yaml_in_one_line(qos):
    from mcap.records import Channel

    from sofia_ros.bag.recovery import _is_latched

    with pytest.raises(BagError, match=r'the QoS of channel /x: .*; the channel metadata of this .mcap is damaged'):
        _is_latched(Channel(id=1, schema_id=1, topic='/x', message_encoding='cdr',
                            metadata={'offered_qos_profiles': qos}))


# --- 5. metadata that is not text, the .mcap a directory or a device -------------------------------------------------

@pytest.mark.parametrize(('damage', 'message'), [
    ('non_utf8', r'not UTF-8 text \(byte 0\)'),
    ('garbage', r'is not rosbag2 metadata'),
    ('metadata_dev_zero', r'not a regular file'),
    ('mcap_directory', r'run.mcap is a directory; give the MCAP file itself'),
    ('mcap_dev_zero', r'run.mcap is not a regular file \(a device, FIFO or socket\)'),
])
def test_files_that_are_not_what_they_should_be_are_one_line(bag, capsys, damage, message):
    if damage == 'non_utf8':
        (bag / 'metadata.yaml').write_bytes(b'\xff\xfe\x00r\x00o')
    elif damage == 'garbage':
        (bag / 'metadata.yaml').write_bytes(bytes(range(1, 32)) * 8)
    elif damage == 'metadata_dev_zero':
        (bag / 'metadata.yaml').unlink()
        (bag / 'metadata.yaml').symlink_to('/dev/zero')
    else:
        (bag / 'run.mcap').unlink()
        if damage == 'mcap_directory':
            (bag / 'run.mcap').mkdir()
        else:
            (bag / 'run.mcap').symlink_to('/dev/zero')
    with pytest.raises(BagError, match=message) as caught:
        BagReader(bag).open()
    assert '\n' not in str(caught.value)
    if damage.startswith('mcap'):  # nothing to recover from
        assert main(['recover', str(bag), '--out', str(bag.parent / 'fixed')]) == 2
        assert message.replace('\\', '') in _one_error_line(capsys)
        assert not (bag.parent / 'fixed').exists()
    else:  # the metadata is rebuilt from the intact .mcap
        assert main(['recover', str(bag), '--out', str(bag.parent / 'fixed')]) == 0
        assert f'recovered {SAMPLES + 1} messages' in capsys.readouterr().out


# --- fuzz: damage kinds x positions ---------------------------------------------------------------------------------

def _fuzz_cases():
    """(id, damage(bag, other_run)) for every damage kind at every position the generator names."""
    cases = []

    def flip_at(where):
        def damage(bag, other_run):
            data = bytearray((bag / 'run.mcap').read_bytes())
            position = where(data, _chunks(bag / 'run.mcap'))
            data[position] ^= 0x5A
            (bag / 'run.mcap').write_bytes(bytes(data))
        return damage

    def cut_at(where):
        def damage(bag, other_run):
            data = (bag / 'run.mcap').read_bytes()
            (bag / 'run.mcap').write_bytes(data[:where(data, _chunks(bag / 'run.mcap'))])
        return damage

    header_positions = {f'header+{offset}': (lambda offset: lambda data, chunks: offset)(offset)
                        for offset in (0, 3, 7, 8, 9, 12, 20, 30)}
    chunk_positions = {}
    for number in range(4):
        for part, fraction in (('head', 0.0), ('crc', None), ('middle', 0.5), ('end', 0.98)):
            def where(data, chunks, number=number, fraction=fraction):
                chunk = chunks[number]
                if fraction is None:  # the uncompressed_crc field after opcode, length, two times and size
                    return chunk.chunk_start_offset + 1 + 8 + 8 + 8 + 8
                return chunk.chunk_start_offset + int(fraction * (chunk.chunk_length - 1))
            chunk_positions[f'chunk{number}-{part}'] = where
    for number in range(3):
        def index_at(data, chunks, number=number):  # inside a message index after the chunk: a log time
            chunk = chunks[number]
            return chunk.chunk_start_offset + chunk.chunk_length + 9 + 6 + 3
        chunk_positions[f'message-index{number}'] = index_at
    tail_positions = {f'tail-{back}': (lambda back: lambda data, chunks: len(data) - back)(back)
                      for back in (1, 5, 9, 14, 20, 30, 60, 120, 300)}
    for name, where in {**header_positions, **chunk_positions, **tail_positions}.items():
        cases.append((f'flip-{name}', flip_at(where)))
    for fraction in (0.0, 0.001, 0.01, 0.2, 0.45, 0.7, 0.9, 0.97, 0.999):
        cases.append((f'cut-{fraction}', cut_at(lambda data, chunks, fraction=fraction: int(fraction * len(data)))))

    def stray_copy(bag, other_run):
        shutil.copy(bag / 'run.mcap', bag / 'stray.mcap')

    def stray_other(bag, other_run):
        shutil.copy(other_run / 'run.mcap', bag / 'run_0.mcap')

    def stray_garbage(bag, other_run):
        (bag / 'zz.mcap').write_bytes(os.urandom(1000))

    def foreign_metadata(bag, other_run):
        shutil.copy(other_run / 'metadata.yaml', bag / 'metadata.yaml')

    def missing_file(bag, other_run):
        (bag / 'run.mcap').unlink()

    def renamed_file(bag, other_run):
        (bag / 'run.mcap').rename(bag / 'other.mcap')

    def no_metadata(bag, other_run):
        (bag / 'metadata.yaml').unlink()

    cases += [('stray-copy', stray_copy), ('stray-other-run', stray_other), ('stray-garbage', stray_garbage),
              ('foreign-metadata', foreign_metadata), ('missing-mcap', missing_file),
              ('renamed-mcap', renamed_file), ('no-metadata', no_metadata)]

    def both(first, second):
        def damage(bag, other_run):
            first(bag, other_run)
            second(bag, other_run)
        return damage

    # An intact copy beside a damaged listed file, and damage where metadata.yaml is missing too.
    cases += [(f'stray-copy+flip-chunk{number}', both(stray_copy, flip_at(chunk_positions[f'chunk{number}-middle'])))
              for number in (0, 2)]
    cases += [('stray-other-run+cut-0.5', both(stray_other, cut_at(lambda data, chunks: len(data) // 2))),
              ('no-metadata+flip-chunk1', both(no_metadata, flip_at(chunk_positions['chunk1-crc']))),
              ('no-metadata+stray-copy', both(no_metadata, stray_copy))]

    def edit_metadata(edit):
        def damage(bag, other_run):
            document = yaml.safe_load((bag / 'metadata.yaml').read_text())
            edit(document['rosbag2_bagfile_information'])
            (bag / 'metadata.yaml').write_text(yaml.safe_dump(document))
        return damage

    edits = {
        'count': lambda info: info['topics_with_message_count'][0].update(message_count=7),
        'negative-count': lambda info: info.update(message_count=-1),
        'text-count': lambda info: info.update(message_count='many'),
        'duration': lambda info: info['duration'].update(nanoseconds=1),
        'start': lambda info: info['starting_time'].update(nanoseconds_since_epoch=EPOCH_NS - 10**9),
        'paths-not-a-list': lambda info: info.update(relative_file_paths='run.mcap'),
        'no-paths': lambda info: info.update(relative_file_paths=[]),
        'path-escapes': lambda info: info.update(relative_file_paths=['../../etc/passwd']),
        'extra-path': lambda info: info.update(relative_file_paths=['run.mcap', 'more.mcap']),
        'files-section': lambda info: info['files'][0].update(path='else.mcap'),
        'no-topics-key': lambda info: info.pop('topics_with_message_count'),
        'topics-not-a-list': lambda info: info.update(topics_with_message_count=5),
        'storage-sqlite': lambda info: info.update(storage_identifier='sqlite3'),
    }
    cases += [(f'metadata-{name}', edit_metadata(edit)) for name, edit in edits.items()]
    texts = {'empty': b'', 'a-list': b'- 1\n- 2\n', 'not-utf8': b'\xc3\x28', 'binary': bytes(range(256)),
             'unclosed': b'rosbag2_bagfile_information: {version: [\n'}

    def write_metadata(text):
        return lambda bag, other_run: (bag / 'metadata.yaml').write_bytes(text)

    cases += [(f'metadata-text-{name}', write_metadata(text)) for name, text in texts.items()]
    return cases


FUZZ_CASES = _fuzz_cases()


def _read_all(path):
    """What a reader sees: per-topic digests and the Imu samples in campaign time."""
    stamps, header_stamps = _campaign_imu_stamps(path)
    return topic_digests(path), stamps.tolist(), header_stamps.tolist()


@pytest.fixture(scope='module')
def written(small_bag):
    """What the undamaged small bag reads back as."""
    return _read_all(small_bag)


@pytest.mark.parametrize(('name', 'damage'), FUZZ_CASES, ids=[name for name, _ in FUZZ_CASES])
def test_fuzz_a_damaged_bag_reads_right_or_is_refused_in_one_line(small_bag, other_run, written, tmp_path, capsys,
                                                                   name, damage):
    bag = Path(shutil.copytree(small_bag, tmp_path / 'run'))
    damage(bag, other_run)
    try:
        seen = _read_all(bag)
    except BagError as err:
        assert '\n' not in str(err) and str(err)
    else:
        assert seen == written, f'{name}: read at exit 0 but not what was written'
    capsys.readouterr()
    out = tmp_path / 'recovered'
    code = main(['recover', str(bag), '--out', str(out)])
    if code == 0:
        with BagReader(out) as recovered:
            counts = {info.name: info.count for info in recovered.topics}
        assert counts.get(IMU_TOPIC, 0) <= SAMPLES
    else:
        assert code == 2
        _one_error_line(capsys)
        assert not out.exists()
