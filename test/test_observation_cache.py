"""The cache of decoded observations of `sofia compare` (compare.cache): a second read of the same bag comes from the
cache; a changed bag, a damaged or foreign cache file is decoded again with one line on stderr; a read-only bag keeps
its cache under $XDG_CACHE_HOME; nothing writable compares without one; --no-cache reads and writes none; the bag's
readers and tools do not trip on the cache folder.

Decoding is counted through compare.observations.decode_observations (not timed). Each test works on a copy of the
session's reduced alignment bag; most serve the decoding from one decoded copy, so that only the cache is exercised.
"""

import dataclasses
import errno
import io
import json
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import pytest

import sofia_ros.compare.observations as observations_module
from sofia_ros.bag import BagReader
from sofia_ros.bag.reader import mcap_file_to_recover
from sofia_ros.cli import main
from sofia_ros.compare.cache import CACHE_DIRECTORY, FOOTER_BYTES, ObservationCache, bag_key
from sofia_ros.compare.cache_files import write_members
from sofia_ros.compare.observations import READER_VERSION, decode_observations, observation_cache, read_observations
from sofia_ros.output_files import json_ready

from json_contract import load_json, validate_compare

ROOT = Path(__file__).resolve().parents[1]
MODEL = str(ROOT / 'config' / 'model' / 'nominal.yaml')


@pytest.fixture(scope='module')
def source_bag(campaign_bags):
    return campaign_bags.reduced_alignment()


@pytest.fixture(scope='module')
def decoded(source_bag):
    """The source bag's observations, decoded once for the module."""
    return decode_observations(source_bag)


@pytest.fixture(scope='module')
def comparison(decoded):
    """The comparison of the decoded observations with the nominal model: the reference, and the stand-in result
    of the tests that are about reading the bag, not the fit."""
    from sofia_ros.compare.run import compare_observations
    from sofia_ros.config import load_effect_config

    return compare_observations(decoded, load_effect_config(MODEL))


@pytest.fixture
def bag(source_bag, tmp_path):
    """A copy of the session bag (times kept; a cache another test's compare left in it is not copied)."""
    return Path(shutil.copytree(source_bag, tmp_path / 'bag', ignore=shutil.ignore_patterns(CACHE_DIRECTORY)))


@pytest.fixture
def home(tmp_path, monkeypatch):
    """$XDG_CACHE_HOME for the test: the cache home is <tmp>/xdg/sofia_ros."""
    monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path / 'xdg'))
    return tmp_path / 'xdg' / 'sofia_ros'


def _count_decodes(monkeypatch, served=None):
    """The paths decode_observations is asked for; it decodes, or serves a copy of ``served`` for the bag."""
    calls = []

    def counted(path):
        calls.append(Path(path))
        return decode_observations(path) if served is None else dataclasses.replace(served, bag_path=Path(path))

    monkeypatch.setattr(observations_module, 'decode_observations', counted)
    return calls


def _read_twice(bag, warnings, **cache_options):
    """Two reads of ``bag`` through one ObservationCache that collects its lines in ``warnings``."""
    with observation_cache(ObservationCache(warn=warnings.append, **cache_options)):
        return read_observations(bag), read_observations(bag)


def _assert_same(first, second):
    """Every field equal: arrays in dtype and value, scalars in type and value, the scenario, the path."""
    for field in dataclasses.fields(first):
        one, other = getattr(first, field.name), getattr(second, field.name)
        if isinstance(one, np.ndarray):
            assert one.dtype == other.dtype and np.array_equal(one, other), field.name
        elif field.name in ('centroids', 'gyro'):
            _assert_same(one, other)
        else:
            assert type(one) is type(other) and one == other, field.name


def _cache_files(folder):
    return sorted(path.name for path in folder.rglob('observations-*.npz')) if folder.exists() else []


def _refuse_writes_under(monkeypatch, *folders):
    """Folders of a read-only file system: creating a directory or a temporary file there fails with EROFS (the
    tests run as root, whom a chmod would not stop)."""
    real_mkdir, real_mkstemp = os.mkdir, tempfile.mkstemp

    def refused(path):
        return any(Path(path).resolve().is_relative_to(folder.resolve()) for folder in folders)

    def mkdir(path, *args, **kwargs):
        if refused(path):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))
        return real_mkdir(path, *args, **kwargs)

    def mkstemp(*args, dir=None, **kwargs):
        if dir is not None and refused(dir):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(dir))
        return real_mkstemp(*args, dir=dir, **kwargs)

    monkeypatch.setattr(os, 'mkdir', mkdir)
    monkeypatch.setattr(tempfile, 'mkstemp', mkstemp)


def _without_seconds(document):
    """A compare document without its timings (the only fields two runs may differ in)."""
    if isinstance(document, dict):
        return {key: _without_seconds(value) for key, value in document.items() if key != 'seconds'}
    if isinstance(document, list):
        return [_without_seconds(value) for value in document]
    return document


# --- reading through the cache ---------------------------------------------------------------------------------------

def test_a_second_read_comes_from_the_cache_beside_the_bag(bag, home, decoded, monkeypatch):
    calls, warnings = _count_decodes(monkeypatch), []
    first, second = _read_twice(bag, warnings)
    assert calls == [bag] and warnings == []
    _assert_same(first, second)
    _assert_same(second, dataclasses.replace(decoded, bag_path=bag))
    (name,) = _cache_files(bag / CACHE_DIRECTORY)
    assert name == f'observations-r{READER_VERSION}-{bag_key(bag)}.npz'
    assert not home.exists()


def test_the_comparison_from_the_cache_is_the_one_of_the_decoded_bag(bag, home, decoded, comparison, tmp_path,
                                                                    monkeypatch, capsys):
    """`sofia compare` on observations from the cache: the document and the print of the decoded observations'
    comparison (only the timings differ)."""
    from sofia_ros.compare.cli import print_comparison

    calls = _count_decodes(monkeypatch, served=decoded)
    _read_twice(bag, [])
    assert main(['compare', str(bag), '--model', MODEL, '--json', str(tmp_path / 'cached.json'), '--quiet']) == 0
    captured = capsys.readouterr()
    assert len(calls) == 1 and captured.err == ''
    reference = {**json_ready(comparison.document), 'bag': str(bag)}
    assert _without_seconds(validate_compare(load_json(tmp_path / 'cached.json'))) == _without_seconds(reference)
    printed = io.StringIO()
    print_comparison(reference, printed)
    assert captured.out == printed.getvalue()


# --- a changed bag ------------------------------------------------------------------------------------------------

def test_a_bag_rewritten_with_a_changed_message_is_decoded_again(bag, home, decoded, tmp_path, monkeypatch):
    """The bag's MCAP file replaced by a copy with HIPO's x shifted by 0.5 px (sofia perturb), its modification time
    kept: its size or its footer (the summary's CRC) tells the change; the old cache file goes."""
    from sofia_ros.perturb import perturb_bag

    _count_decodes(monkeypatch, served=decoded)
    warnings = []
    before, _ = _read_twice(bag, warnings)
    calls = _count_decodes(monkeypatch)
    (old,) = (bag / CACHE_DIRECTORY).glob('observations-*.npz')
    perturb_bag(bag, tmp_path / 'shifted', 'hipo.x', '0.5', unit='px')
    assert not (tmp_path / 'shifted' / CACHE_DIRECTORY).exists()  # perturb copies the bag's files, not the cache
    (mcap,) = bag.glob('*.mcap')
    kept = mcap.stat()
    shutil.copyfile(tmp_path / 'shifted' / mcap.name, mcap)
    os.utime(mcap, ns=(kept.st_atime_ns, kept.st_mtime_ns))
    after, again = _read_twice(bag, warnings)
    assert calls == [bag]
    assert warnings == [f'sofia compare: the bag or the reader changed since {old} was written; decoded the bag again']
    _assert_same(after, again)
    hipo = before.centroids.camera_index == before.centroids.cameras.index('hipo')
    shift = after.centroids.measured_px - before.centroids.measured_px
    np.testing.assert_allclose(shift[hipo, 0], 0.5, atol=1e-9)
    assert not np.any(shift[~hipo]) and not np.any(shift[:, 1])
    assert _cache_files(bag / CACHE_DIRECTORY) == [f'observations-r{READER_VERSION}-{bag_key(bag)}.npz']


def test_a_bag_damaged_after_it_was_cached_gets_its_one_error_line_alone(bag, home, decoded, tmp_path, monkeypatch,
                                                                         capsys):
    """The cache is stale, but a bag that cannot be decoded is told in one line: the bag's error, not the cache's."""
    _count_decodes(monkeypatch, served=decoded)
    _read_twice(bag, [])
    monkeypatch.setattr(observations_module, 'decode_observations', decode_observations)
    mcap = next(bag.glob('*.mcap'))
    mcap.write_bytes(mcap.read_bytes()[:mcap.stat().st_size // 2])
    assert main(['compare', str(bag), '--model', MODEL, '--json', str(tmp_path / 'out.json')]) == 2
    (line,) = capsys.readouterr().err.splitlines()
    assert line.startswith('sofia: error: ') and str(bag) in line and 'cache' not in line
    assert not (tmp_path / 'out.json').exists()


def _touch(bag):
    mcap = next(bag.glob('*.mcap'))
    os.utime(mcap, ns=(mcap.stat().st_atime_ns, mcap.stat().st_mtime_ns + 1))


def _append_to_side_file(bag):
    with open(bag / 'summary.json', 'a') as file:
        file.write(' ')


def _rewrite_metadata_keeping_time_and_size(bag):
    metadata = bag / 'metadata.yaml'
    kept, text = metadata.stat(), metadata.read_text()
    assert 'version: ' in text
    metadata.write_text(text.replace('version: ', 'version:\t', 1))
    os.utime(metadata, ns=(kept.st_atime_ns, kept.st_mtime_ns))
    assert metadata.stat().st_size == kept.st_size


def _add_file(bag):
    (bag / 'notes.txt').write_text('seen\n')


def _change_mcap_footer_keeping_time_and_size(bag):
    mcap = next(bag.glob('*.mcap'))
    kept = mcap.stat()
    with open(mcap, 'r+b') as file:
        file.seek(kept.st_size - FOOTER_BYTES // 2)
        byte = file.read(1)
        file.seek(-1, os.SEEK_CUR)
        file.write(bytes([byte[0] ^ 0xFF]))
    os.utime(mcap, ns=(kept.st_atime_ns, kept.st_mtime_ns))


CHANGES = {
    'mcap touched': _touch, 'a side file grown': _append_to_side_file, 'a file added': _add_file,
    'metadata.yaml edited, same time and size': _rewrite_metadata_keeping_time_and_size,
    'mcap footer changed, same time and size': _change_mcap_footer_keeping_time_and_size,
}


@pytest.mark.parametrize('change', CHANGES)
def test_a_changed_bag_has_another_key_and_its_cache_is_not_used(bag, home, decoded, monkeypatch, change):
    calls, warnings = _count_decodes(monkeypatch, served=decoded), []
    _read_twice(bag, warnings)
    CHANGES[change](bag)
    _read_twice(bag, warnings)
    assert len(calls) == 2
    assert len(warnings) == 1 and warnings[0].startswith('sofia compare: the bag or the reader changed since ')
    assert _cache_files(bag / CACHE_DIRECTORY) == [f'observations-r{READER_VERSION}-{bag_key(bag)}.npz']


def test_the_key_ignores_the_cache_folder_and_names_the_reader_version(bag, decoded, monkeypatch, home):
    key = bag_key(bag)
    _count_decodes(monkeypatch, served=decoded)
    _read_twice(bag, [])
    assert bag_key(bag) == key  # writing the cache does not change the bag's key
    monkeypatch.setattr('sofia_ros.compare.cache.READER_VERSION', READER_VERSION + 1)
    assert bag_key(bag) != key
    assert bag_key(bag.parent / 'missing') is None


# --- a damaged or foreign cache file --------------------------------------------------------------------------------

def _rewrite(path, change_members=lambda members: members, change_header=lambda header: header, save=None):
    """Rewrite the cache file at ``path`` with its members and header changed: as a writer would (write_members:
    the members' fingerprints made anew, so that the reader's other checks are what refuse it), or with ``save``
    over the header as it was (numpy's savez: the fingerprints of the members before the change)."""
    with np.load(path) as archive:
        members = {name: archive[name] for name in archive.files}
    header = change_header(json.loads(members.pop('header').tobytes()))
    members = change_members(members)
    if save is None:
        header.pop('member_fingerprints')
        write_members(path, header, members)
        return
    members['header'] = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    with open(path, 'wb') as file:
        save(file, **members)


def _flip_a_byte(path):
    data = bytearray(path.read_bytes())
    data[len(data) // 2] ^= 0xFF
    path.write_bytes(bytes(data))


def _as_fifo(path):
    path.unlink()
    os.mkfifo(path)


DAMAGE = {
    'truncated': (lambda path: path.write_bytes(path.read_bytes()[:path.stat().st_size // 2]), 'unreadable'),
    'empty': (lambda path: path.write_bytes(b''), 'unreadable'),
    'a byte flipped in an array': (_flip_a_byte, 'unreadable: BadZipFile'),
    'not a zip file': (lambda path: path.write_text('observations\n'), 'unreadable'),
    'a FIFO': (_as_fifo, 'not a regular file'),
    'another reader version': (lambda path: _rewrite(path, change_header=lambda header: {
        **header, 'reader_version': READER_VERSION + 1}), 'written by another reader'),
    "another bag's key": (lambda path: _rewrite(path, change_header=lambda header: {**header, 'key': '0' * 64}),
                          'for another bag'),
    'no header': (lambda path: np.savez(path.open('wb'), hip=np.arange(3)), 'no header'),
    'a pickled member': (lambda path: _rewrite(path, change_members=lambda members: {
        **members, 'centroids.hip': np.array([{'os': 'system'}], dtype=object)}, save=np.savez),
        'unreadable: ValueError'),
    # Members saved again over the header they had (their zip CRCs hold): a traceback or another fit, at exit 0.
    'an array saved again as float32': (lambda path: _rewrite(path, change_members=lambda members: {
        **members, 'centroids.measured_px': members['centroids.measured_px'].astype(np.float32)}, save=np.savez),
        'not those it was written with'),
    'a value changed': (lambda path: _rewrite(path, change_members=lambda members: {
        **members, 'centroids.camera_index': members['centroids.camera_index'] + 99}, save=np.savez),
        'not those it was written with'),
    'an array cut': (lambda path: _rewrite(path, change_members=lambda members: {
        **members, 'gyro.tick_mean_rates_gyrf_rad_per_s': members['gyro.tick_mean_rates_gyrf_rad_per_s'][:-1]},
        save=np.savez), 'not those it was written with'),
    'no fingerprints (an older writer)': (lambda path: _rewrite(path, change_header=lambda header: {
        name: value for name, value in header.items() if name != 'member_fingerprints'}, save=np.savez),
        'not those it was written with'),
    'compressed members': (lambda path: _rewrite(path, save=np.savez_compressed), 'compressed members'),
    'a field missing': (lambda path: _rewrite(path, change_members=lambda members: {
        name: value for name, value in members.items() if name != 'gyro.time_s'}), 'not those of this reader'),
    'a text array': (lambda path: _rewrite(path, change_members=lambda members: {
        **members, 'gyro.time_s': np.array(['0.0'])}), 'not arrays of numbers'),
    'rows that do not agree': (lambda path: _rewrite(path, change_members=lambda members: {
        **members, 'centroids.hip': members['centroids.hip'][:-1]}), 'do not agree in length'),
    'samples the ticks do not count': (lambda path: _rewrite(path, change_members=lambda members: {
        **members, 'gyro.time_s': members['gyro.time_s'][:-1]}), 'do not agree in length'),
    'rate noise of two axes': (lambda path: _rewrite(path, change_members=lambda members: {
        **members, 'gyro.within_tick_rate_sigma_rad_per_s': members['gyro.within_tick_rate_sigma_rad_per_s'][:2]}),
        'do not agree in length'),
    'a negative count': (lambda path: _rewrite(path, change_header=lambda header: {
        **header, 'values': {**header['values'], 'gyro.within_tick_difference_count': -1}}),
        'within_tick_difference_count is not what'),
    'a scalar array': (lambda path: _rewrite(path, change_members=lambda members: {
        **members, 'move_start_s': np.float64(1.0)}), 'not arrays of numbers'),
    'a value of the wrong type': (lambda path: _rewrite(path, change_header=lambda header: {
        **header, 'values': {**header['values'], 'initial_time_s': '0'}}), 'initial_time_s is not what'),
    'an unknown camera': (lambda path: _rewrite(path, change_header=lambda header: {
        **header, 'values': {**header['values'], 'centroids.cameras': ['x']}}), 'centroids.cameras is not what'),
    'a scenario that is not one': (lambda path: _rewrite(path, change_header=lambda header: {
        **header, 'scenario_document': 'latitude_deg: 1\n'}), 'its scenario is not one'),
}


@pytest.mark.parametrize('damage', DAMAGE)
def test_a_damaged_or_foreign_cache_is_one_line_decoded_again_and_replaced(bag, home, decoded, monkeypatch, damage):
    calls, warnings = _count_decodes(monkeypatch, served=decoded), []
    _read_twice(bag, warnings)
    (path,) = (bag / CACHE_DIRECTORY).glob('observations-*.npz')
    damaging, reason = DAMAGE[damage]
    damaging(path)
    first, second = _read_twice(bag, warnings)
    assert len(calls) == 2, 'decoded once more, then read from the replaced file'
    assert len(warnings) == 1 and warnings[0].startswith(f'sofia compare: ignored the observation cache {path} ('), \
        warnings
    assert reason in warnings[0] and warnings[0].endswith('); decoded the bag again'), warnings[0]
    assert '\n' not in warnings[0]
    for observations in (first, second):
        _assert_same(observations, dataclasses.replace(decoded, bag_path=bag))
    assert path.is_file() and _cache_files(bag / CACHE_DIRECTORY) == [path.name]


# --- where the cache goes ----------------------------------------------------------------------------------------

def test_a_read_only_bag_keeps_its_cache_under_xdg_cache_home(bag, home, decoded, monkeypatch):
    _refuse_writes_under(monkeypatch, bag)
    calls, warnings = _count_decodes(monkeypatch, served=decoded), []
    first, second = _read_twice(bag, warnings)
    assert len(calls) == 1 and warnings == []
    _assert_same(first, second)
    assert not (bag / CACHE_DIRECTORY).exists()
    (folder,) = home.iterdir()
    assert folder.name.startswith('bag-') and _cache_files(folder) == [
        f'observations-r{READER_VERSION}-{bag_key(bag)}.npz']


def test_two_bags_of_the_same_name_never_share_a_cache_folder(tmp_path, home):
    cache = ObservationCache(warn=print)
    (tmp_path / 'a' / 'bag').mkdir(parents=True)
    (tmp_path / 'b' / 'bag').mkdir(parents=True)
    first, second = (cache.folders(tmp_path / folder / 'bag')[1] for folder in 'ab')
    assert first != second and first.parent == second.parent == home


def test_a_user_without_a_home_keeps_the_cache_beside_the_bag_or_none(bag, decoded, monkeypatch):
    monkeypatch.delenv('XDG_CACHE_HOME', raising=False)
    monkeypatch.setattr(Path, 'home', classmethod(lambda cls: (_ for _ in ()).throw(RuntimeError('no home'))))
    _count_decodes(monkeypatch, served=decoded)
    cache = ObservationCache(warn=print)
    assert cache.folders(bag) == (bag / CACHE_DIRECTORY,)
    _read_twice(bag, [])
    assert len(_cache_files(bag / CACHE_DIRECTORY)) == 1
    _refuse_writes_under(monkeypatch, bag / CACHE_DIRECTORY)
    (bag / 'notes.txt').write_text('a change\n')
    warnings = []
    _read_twice(bag, warnings)
    # Each read: one line, for the stale cache and for the cache that cannot be written.
    assert len(warnings) == 2 and all(line.startswith('sofia compare: the bag or the reader changed since ') and
                                      '; decoded the bag again; cannot cache the decoded observations (' in line
                                      for line in warnings), warnings


def test_nothing_writable_compares_without_a_cache_and_says_so_in_one_line(bag, home, decoded, comparison, monkeypatch,
                                                                          capsys):
    _refuse_writes_under(monkeypatch, bag, home.parent)
    calls = _count_decodes(monkeypatch, served=decoded)
    _serve(monkeypatch, comparison)
    assert main(['compare', str(bag), '--model', MODEL, '--quiet']) == 0
    captured = capsys.readouterr()
    (line,) = captured.err.splitlines()
    assert line.startswith('sofia compare: cannot cache the decoded observations (')
    assert 'read-only file system' in line and line.endswith('compared without a cache (--no-cache skips it)')
    assert 'verdict: ' in captured.out and len(calls) == 1
    assert _cache_files(bag) == [] and not home.exists()


def _serve(monkeypatch, comparison):
    """compare_observations returns ``comparison``: these tests are about reading the bag, not the fit."""
    monkeypatch.setattr('sofia_ros.compare.run.compare_observations', lambda observations, model, **options: comparison)


def test_no_cache_neither_reads_nor_writes_a_cache(bag, home, decoded, comparison, monkeypatch, capsys):
    calls = _count_decodes(monkeypatch, served=decoded)
    _serve(monkeypatch, comparison)
    assert main(['compare', str(bag), '--model', MODEL, '--quiet', '--no-cache']) == 0
    assert not (bag / CACHE_DIRECTORY).exists() and not home.exists()
    _read_twice(bag, [])
    (path,) = (bag / CACHE_DIRECTORY).glob('observations-*.npz')
    written = path.stat().st_mtime_ns
    assert main(['compare', str(bag), '--model', MODEL, '--quiet', '--no-cache']) == 0
    assert len(calls) == 3, 'decoded by both --no-cache runs, not read from the cache'
    assert path.stat().st_mtime_ns == written and capsys.readouterr().err == ''


# --- the bag's readers and tools beside the cache folder -----------------------------------------------------------

def test_the_bag_readers_do_not_trip_on_the_cache_folder(bag, source_bag, home, decoded, monkeypatch, capsys):
    _count_decodes(monkeypatch, served=decoded)
    _read_twice(bag, [])
    assert (bag / CACHE_DIRECTORY).is_dir()
    with BagReader(bag, campaign_time=True) as reader, BagReader(source_bag) as source:
        assert reader.topics == source.topics
    assert mcap_file_to_recover(bag) == next(bag.glob('*.mcap'))
    assert capsys.readouterr().err == ''  # no warning of files metadata.yaml does not list
