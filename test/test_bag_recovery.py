"""`sofia recover`: every intact chunk is kept, also after a damaged one; errors that say what to do (issue 13)."""

from pathlib import Path

import pytest

from sofia_ros.bag import BagReader, BagWriter, recover_bag
from sofia_ros.cli import main
from sofia_ros.errors import BagError

CHUNKS = 6
PER_CHUNK = 50


@pytest.fixture
def chunked_bag(tmp_path):
    """A closed bag of CHUNKS chunks of PER_CHUNK documents each (a flush closes a chunk)."""
    path = tmp_path / 'chunked'
    with BagWriter(path) as bag:
        for chunk in range(CHUNKS):
            for index in range(PER_CHUNK):
                bag.write_document('/notes', f'chunk {chunk} note {index} ' + 'x' * 200,
                                   (chunk * PER_CHUNK + index) * 10**6)
            bag.flush()
    return path


def _chunks(data):
    """(start, end, messages held) of every chunk record."""
    from mcap.records import Message

    from sofia_ros.bag.recovery import _parse, _top_level_records

    return [(start, end, sum(isinstance(record, Message) for record in _parse(data[start:end])))
            for start, end in _top_level_records(data, 8) if data[start] == 0x06]


#: Opcode and length (9 bytes), then the chunk header before the compressed records (44 bytes).
ZSTD_FRAME = 9 + 44


def test_a_damaged_middle_chunk_loses_only_itself(chunked_bag, tmp_path, capsys):
    mcap = next(chunked_bag.glob('*.mcap'))
    data = bytearray(mcap.read_bytes())
    chunks = _chunks(bytes(data))
    assert len(chunks) >= CHUNKS
    middle, _, lost = chunks[3]
    data[middle + ZSTD_FRAME:middle + ZSTD_FRAME + 8] = bytes(8)  # the zstd frame header of one chunk
    mcap.write_bytes(bytes(data))
    (chunked_bag / 'metadata.yaml').unlink()
    assert main(['recover', str(chunked_bag), '--out', str(tmp_path / 'fixed')]) == 0
    out = capsys.readouterr().out
    assert 'skipped 1 damaged record(s)' in out
    with BagReader(tmp_path / 'fixed') as bag:
        notes = [message.data for _, _, message in bag.messages('/notes')]
    assert lost > 0 and len(notes) == CHUNKS * PER_CHUNK - lost
    assert notes[-1].startswith(f'chunk {CHUNKS - 1} note {PER_CHUNK - 1}')


def test_a_cut_file_keeps_everything_before_the_cut(chunked_bag, tmp_path):
    mcap = next(chunked_bag.glob('*.mcap'))
    data = mcap.read_bytes()
    chunks = _chunks(data)
    mcap.write_bytes(data[:chunks[4][0] + 30])
    report = recover_bag(chunked_bag, tmp_path / 'head')
    assert report.message_count == sum(held for _, _, held in chunks[:4])
    assert report.stop_reason.startswith('file cut inside the record at byte')


def test_an_empty_mcap_is_not_sent_to_recover(tmp_path):
    (tmp_path / 'empty').mkdir()
    Path(tmp_path / 'empty' / 'empty.mcap').write_bytes(b'')
    with pytest.raises(BagError, match=r'no metadata.yaml and no MCAP data to recover'):
        BagReader(tmp_path / 'empty')


def test_broken_metadata_is_one_line(chunked_bag, capsys):
    (chunked_bag / 'metadata.yaml').write_text('rosbag2_bagfile_information:\n  version: [\n')
    assert main(['compare', str(chunked_bag), '--model', 'config/model/nominal.yaml']) == 2
    err = capsys.readouterr().err
    assert err.count('\n') == 1 and f'rebuild the bag with `sofia recover {chunked_bag}`' in err
