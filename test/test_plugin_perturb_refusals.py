"""Refusals of `sofia effects new`, of empirical term names and of `sofia perturb`: one line, exit 2 (3 for a
full disk), nothing left behind.

A plug-in named like an importable module would shadow it for every sofia command once its folder
is on PYTHONPATH; an empirical name is bounded to what a record resolves (a period of 1e-300 s was
added and fitted); a shape's number beyond a float's range, and a perturbed copy onto a full or
read-only disk, are one line with no partial bag. Full and read-only disks are small tmpfs mounts
where this process may mount them, else the failing call is simulated.
"""

import errno
import os
import subprocess
from contextlib import suppress
from pathlib import Path

import pytest

from sofia_ros.cli import main
from sofia_ros.config import load_effect_config
from sofia_ros.effects import get_effect
from sofia_ros.effects.empirical import empirical_name, empirical_parts
from sofia_ros.errors import ConfigError, UnknownEffectError

MODEL = 'effects:\n  gyro_bias: {}  # a comment the edit keeps\n'
GOOD_SHAPE = '0.25'


def _one_error_line(capsys, prefix='sofia: error:'):
    """The one stderr line of a refused command (asserted: one line, the prefix, no traceback)."""
    err = capsys.readouterr().err
    assert 'Traceback' not in err
    lines = err.splitlines()
    assert len(lines) == 1 and err.endswith('\n'), err
    assert lines[0].startswith(prefix), err
    return lines[0]


@pytest.fixture(scope='module')
def bag(campaign_bags):
    return campaign_bags.reduced_alignment()


# --- file systems that refuse to be written ------------------------------------------------------


def _mount_tmpfs(folder, options):
    """Mount a small tmpfs at ``folder`` with ``options``; False where this process may not mount."""
    folder.mkdir()
    with suppress(OSError, subprocess.SubprocessError):
        done = subprocess.run(['mount', '-t', 'tmpfs', '-o', options, 'tmpfs', str(folder)], capture_output=True,
                              timeout=10)
        return done.returncode == 0
    return False


def _fill(folder):
    """Write into ``folder`` until its file system is full."""
    with suppress(OSError), open(folder / 'filler', 'wb', buffering=0) as file:
        while True:
            file.write(b'\0' * 4096)


@pytest.fixture(params=['full', 'read-only'])
def refusing_folder(request, tmp_path, monkeypatch):
    """(folder, exit code, errno) of a folder whose file system is full (exit 3) or read-only (exit 2).

    A real tmpfs where `mount` works here; else a plain folder, and the first file or directory
    created under it fails with that errno (os.open and os.mkdir, as the kernel would).
    """
    kind = request.param
    folder = tmp_path / kind
    code, number = (3, errno.ENOSPC) if kind == 'full' else (2, errno.EROFS)
    if _mount_tmpfs(folder, 'size=64k' if kind == 'full' else 'size=64k,ro'):
        request.addfinalizer(lambda: subprocess.run(['umount', str(folder)], check=True, timeout=10))
        if kind == 'full':
            _fill(folder)
        yield folder, code, number
        return
    real_open, real_mkdir = os.open, os.mkdir

    def refused(real):
        def call(path, *args, **kwargs):
            if isinstance(path, (str, os.PathLike)) and folder in Path(path).parents:
                raise OSError(number, os.strerror(number), str(path))
            return real(path, *args, **kwargs)
        return call

    monkeypatch.setattr(os, 'open', refused(real_open))
    monkeypatch.setattr(os, 'mkdir', refused(real_mkdir))
    yield folder, code, number


def _listing(folder):
    """The names in ``folder`` but a filler file."""
    return sorted(path.name for path in folder.iterdir() if path.name != 'filler')


# --- 1. sofia effects new -------------------------------------------------------------------------


@pytest.mark.parametrize('name', ['numpy', 'yaml', 'sofia_ros', 'json'])
def test_effects_new_refuses_a_name_that_would_shadow_an_importable_module(tmp_path, capsys, name):
    assert main(['effects', 'new', name, '--kind', 'gyro', '--dir', str(tmp_path)]) == 2
    line = _one_error_line(capsys)
    assert f"plug-in name '{name}' is the name of an importable module" in line and f'{name}_effect' in line
    assert _listing(tmp_path) == []


def test_effects_new_onto_a_full_or_read_only_folder_is_one_line_and_leaves_nothing(refusing_folder, capsys):
    folder, code, number = refusing_folder
    assert main(['effects', 'new', 'disk_check_effect', '--kind', 'camera', '--dir', str(folder)]) == code
    line = _one_error_line(capsys)
    assert line.startswith(f'sofia: error: cannot write {folder}/disk_check_effect.py: ')
    assert ('disk full' if number == errno.ENOSPC else 'read-only file system') in line
    assert _listing(folder) == []


def test_effects_new_writes_a_module_that_compiles_or_refuses_the_folder(tmp_path, capsys):
    quoted = tmp_path / 'a"""b'
    quoted.mkdir()
    assert main(['effects', 'new', 'quoted_folder_effect', '--kind', 'gyro', '--dir', str(quoted)]) == 2
    assert "cannot be written into the template's docstring" in _one_error_line(capsys)
    assert _listing(quoted) == []
    assert main(['effects', 'new', 'plain_folder_effect', '--kind', 'gyro', '--dir', str(tmp_path)]) == 0
    compile((tmp_path / 'plain_folder_effect.py').read_text(), 'plain_folder_effect.py', 'exec')


def test_effects_new_refuses_a_dangling_link_and_a_folder_it_cannot_create_in(tmp_path, capsys):
    # A dangling link was written through at exit 0 (a file made elsewhere); /proc was exit 3, the disk-full code.
    (tmp_path / 'dang.py').symlink_to(tmp_path / 'nothere.py')
    assert main(['effects', 'new', 'dang', '--kind', 'camera', '--dir', str(tmp_path)]) == 2
    assert 'dang.py exists; choose another name' in _one_error_line(capsys)
    assert not (tmp_path / 'nothere.py').exists()
    assert main(['effects', 'new', 'procfx', '--kind', 'camera', '--dir', '/proc']) == 2
    assert 'no such file or directory; check the path' in _one_error_line(capsys)
    assert main(['effects', 'new', 'emptydir', '--kind', 'camera', '--dir', '']) == 2
    assert '--dir is given an empty value' in _one_error_line(capsys)
    assert main(['effects', 'new', 'nulldir', '--kind', 'camera', '--dir', '/dev/null']) == 2
    assert 'directory /dev/null is not a directory' in _one_error_line(capsys)


# --- 2. empirical names ---------------------------------------------------------------------------


def test_model_add_refuses_a_period_no_record_resolves(tmp_path, capsys):
    """Was: added at exit 0, and compare then fitted a 1e-300 s sinusoid and reported its amplitude and sigma."""
    model = tmp_path / 'model.yaml'
    model.write_text(MODEL)
    assert main(['model', 'add', 'empirical:fpi.x:time:period_1e-300s', '--model', str(model)]) == 2
    line = _one_error_line(capsys)
    assert 'the period must be between 1 and 1e+06 s' in line and 'got 1e-300 s' in line
    assert model.read_text() == MODEL and _listing(tmp_path) == ['model.yaml']
    # A model file naming it (what compare reads) is refused the same way.
    model.write_text('effects:\n  empirical:fpi.x:time:period_1e-300s: {fit: true}\n')
    with pytest.raises(ConfigError, match=r'the period must be between 1 and 1e\+06 s'):
        load_effect_config(model)


@pytest.mark.parametrize(('period_s', 'range_'), [(12345.6, None), (None, (0.5, 14400.0)),
                                                  (None, (1.7e9, 1.7e9 + 3600.0)), (None, (1.00001, 1.00002))])
def test_names_that_empirical_name_writes_are_read_back(period_s, range_):
    """Was: 1.235e+04 (a period or range end from 1e4 on) failed the grammar, and ends 4 digits cannot part
    (a record's times since 1970) made LOW..HIGH equal."""
    name = empirical_name('fpi.x', 'time', period_s, range_)
    assert get_effect(name).family == 'empirical'
    assert empirical_parts(name)[2] == (None if period_s is None else pytest.approx(period_s, rel=1e-3))


# --- 3. sofia perturb -----------------------------------------------------------------------------


def test_perturb_refuses_a_number_beyond_a_float_in_one_line(bag, tmp_path, capsys):
    """Was: OverflowError (int too large to convert to float) with a traceback."""
    assert main(['perturb', str(bag), str(tmp_path / 'out'), '--observable', 'fpi.x', '--shape', '1' * 400]) == 2
    line = _one_error_line(capsys)
    assert "beyond a float's range (+-1.8e+308); write a smaller number" in line and len(line) < 300
    assert _listing(tmp_path) == []


def test_perturb_onto_a_full_or_read_only_disk_is_one_line_and_leaves_no_partial_bag(bag, refusing_folder, capsys):
    folder, code, number = refusing_folder
    out = folder / 'perturbed'
    assert main(['perturb', str(bag), str(out), '--observable', 'hipo.y', '--shape', GOOD_SHAPE]) == code
    line = _one_error_line(capsys)
    assert line.startswith(f'sofia: error: cannot write {out}: ')
    assert ('disk full' if number == errno.ENOSPC else 'read-only file system') in line
    assert _listing(folder) == []


def test_perturb_removes_its_partial_bag_when_the_disk_fills_midway(bag, tmp_path, monkeypatch, capsys):
    """The copy fails after part of the MCAP file is written: the hidden build directory goes too."""
    from sofia_ros.perturb import run

    def half_then_full(source, target, *args):
        target.write_bytes(source.read_bytes()[:4096])
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(target))

    monkeypatch.setattr(run, 'copy_mcap', half_then_full)
    assert main(['perturb', str(bag), str(tmp_path / 'out'), '--observable', 'fpi.x', '--shape', GOOD_SHAPE]) == 3
    assert 'disk full; free space or write elsewhere' in _one_error_line(capsys)
    assert _listing(tmp_path) == []


# --- generated bad input --------------------------------------------------------------------------

_SHADOWED = ('numpy', 'yaml', 'json', 'os', 'sys', 'math', 're', 'scipy', 'sofia_ros', 'pytest', 'mcap', 'ruamel')
_KEYWORDS_AND_BUILTINS = ('for', 'class', 'lambda', 'import', 'match', 'print', 'len', 'open', 'list', 'id')
_NOT_IDENTIFIERS = ('1abc', 'a-b', 'a b', 'Abc', 'aB', '_x', 'a.b', 'ñame', 'ﬁeld_shift', 'x/y', '../up', 'a' * 65,
                    'a' * 300, ' ', 'gyro_bias')
#: Folders a module's docstring cannot hold: quotes end it, \\N is a bad escape, a byte that is not UTF-8.
_ODD_FOLDERS = ('a"""b', 'x\\N', 'not_utf8_\udcff')
_BAD_KINDS = ('cam', 'GYRO', '', 'camera rotation', 'gyro;rm')
_BAD_PERIODS = ('1e-300', '0', '0.5', '0.999', '1.0e6000', '1e7', '1000001', '1e999', '-5', '0e0', '1e-1')
_BAD_RANGES = ('60..20', '1..1', '1e11..1e12', '-1e999..0', '0..1e999', '1..1.0000000000001', '-0..0',
               '5e9..2e10')
_BAD_GRAMMAR = ('empirical:', 'empirical:fpi.x', 'empirical:fpi.x:time', 'empirical:fpi.x:time:period_s',
                'empirical:fpi.x:time:period_nans', 'empirical:fpi.x:time:period_infs', 'empirical:fpi.x:time:poly',
                'empirical:fpi.x:time:poly4', 'empirical:fpi.x:time:poly0', 'empirical:fpi.x:time:poly33',
                'empirical:fpi.x:time:poly' + '9' * 120, 'empirical:fpi.z:time:poly3',
                'empirical:gyro.el:elevation:poly3',
                'empirical:fpi.x:elevation:period_60s', 'empirical:fpi.x:time:period_1e+999s',
                'empirical:fpi.x:' + 'a' * 400 + ':poly3', 'empirical:ffi.y:elevation:poly3@' + '1' * 200 + '..2')
_BAD_SHAPES = ('1' * 400, '-' + '9' * 310, '1e999', '2*' + '9' * 320 + '.0', '1e400*time_s', '10**400', '1/0',
               '0*time_s/0', 'log(-1 + 0*time_s)', '', '   ', '1+', 'sin', 'time_s.real', '__import__("os")', '1j',
               "'a'", '[1]', 'lambda: 1', 'x', 'where(time_s)', 'time_s' + '+1' * 300, '~1', 'not 1',
               'time_s if 1 else 0')


def _cases():
    """(id, argv builder, expected exit code, stderr prefix): every builder takes (tmp_path, bag, model)."""
    cases = []
    for name in (*_SHADOWED, *_KEYWORDS_AND_BUILTINS, *_NOT_IDENTIFIERS):
        cases.append((f'plugin-name-{name[:20]}', lambda d, b, m, n=name: ['effects', 'new', n, '--kind', 'gyro',
                                                                           '--dir', str(d)], 2, 'sofia: error:'))
    for kind in _BAD_KINDS:  # argparse's choices: its own prefix, one line all the same
        cases.append((f'plugin-kind-{kind}', lambda d, b, m, k=kind: ['effects', 'new', 'fine_effect', '--kind', k,
                                                                      '--dir', str(d)], 2, 'sofia effects: error:'))
    for folder in ('missing', 'a_file', *_ODD_FOLDERS):
        cases.append((f'plugin-dir-{folder}', lambda d, b, m, f=folder: ['effects', 'new', 'fine_effect', '--kind',
                                                                         'camera', '--dir', str(d / f)],
                      2, 'sofia: error:'))
    names = [*(f'empirical:fpi.x:time:period_{period}s' for period in _BAD_PERIODS),
             *(f'empirical:ffi.y:elevation:poly3@{span}' for span in _BAD_RANGES), *_BAD_GRAMMAR]
    for name in names:
        cases.append((f'empirical-{name[10:40]}', lambda d, b, m, n=name: ['model', 'add', n, '--model', str(m)],
                      2, 'sofia: error:'))
    for shape in _BAD_SHAPES:
        cases.append((f'shape-{shape[:20]}', lambda d, b, m, s=shape: ['perturb', str(b), str(d / 'out'),
                                                                       '--observable', 'fpi.x', '--shape', s],
                      2, 'sofia: error:'))
    return [(f'{index:03d}-{label}', *rest) for index, (label, *rest) in enumerate(cases)]


CASES = _cases()


def test_the_generator_makes_enough_cases():
    assert len(CASES) >= 50 and len({case[0] for case in CASES}) == len(CASES)


@pytest.mark.parametrize(('build', 'code', 'prefix'), [case[1:] for case in CASES], ids=[case[0] for case in CASES])
def test_generated_bad_input_is_one_line_and_leaves_nothing(bag, tmp_path, capsys, build, code, prefix):
    work = tmp_path
    (work / 'a_file').write_text('not a folder\n')
    for folder in _ODD_FOLDERS:
        (work / folder).mkdir()
    model = work / 'model.yaml'
    model.write_text(MODEL)
    before = sorted(str(path.relative_to(work)) for path in work.rglob('*'))
    assert main(build(work, bag, model)) == code
    _one_error_line(capsys, prefix)
    assert sorted(str(path.relative_to(work)) for path in work.rglob('*')) == before
    assert model.read_text() == MODEL


def test_an_empirical_name_that_is_refused_says_so_in_get_effect():
    with pytest.raises(UnknownEffectError, match=r'the polynomial order must be 3'):
        get_effect('empirical:fpi.x:time:poly4')
