"""Output files of the commands: written whole or not at all, JSON strict."""

from __future__ import annotations

import errno
import os
import stat
import tempfile
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from sofia_ros.errors import ConfigError, OutputError

__all__ = ['atomic_output', 'checked_output_directory', 'checked_output_file', 'current_umask', 'describe_os_error',
           'json_ready', 'output_error', 'output_target', 'refuse_empty_paths', 'refuse_over_inputs',
           'write_text_atomically']


def current_umask():
    """The process' umask (read by setting it and setting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def output_target(path):
    """The file an output at ``path`` replaces: a link's target; ConfigError unless it is new or a regular file.

    A link to /dev/null (or any device, FIFO or directory) is refused: renaming a temporary file
    over it would replace the device with a regular file.
    """
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f'{path} is a directory; give a file name')
    target = path.resolve() if path.is_symlink() else path
    try:
        mode = target.stat().st_mode
    except FileNotFoundError:
        mode = None
    except OSError as err:
        raise ConfigError(f'cannot write {path}: {err.strerror}') from err
    if mode is not None and not stat.S_ISREG(mode):
        raise ConfigError(f'{path} is not a regular file ({target} is a device, FIFO or socket); '
                          'give a file name on disk')
    if target.parent and not target.parent.exists():
        raise ConfigError(f'directory {target.parent} does not exist; create it or choose another path')
    return target


def checked_output_file(option, path, inputs):
    """The target of the output file ``option`` (e.g. '--json') at ``path``, checked before a command works: a new or
    regular file (output_target) in a directory it may write, replacing none of ``inputs`` ({what: path}, a file or
    a folder such as a bag's, whose files are inputs too); ConfigError in one line otherwise."""
    target = output_target(path)
    _require_writable(path, target.parent)
    refuse_over_inputs(option, path, inputs)
    return target


def checked_output_directory(option, path, inputs):
    """The output folder ``option`` (e.g. '--report') at ``path``, checked before a command works: a folder, or a new
    one in an existing folder, that it may write and that is none of ``inputs`` nor inside one ({what: path});
    ConfigError in one line otherwise."""
    directory = Path(path)
    if directory.exists() and not directory.is_dir():
        raise ConfigError(f'{option} {path} is a file; give a directory')
    existing = directory if directory.exists() else directory.parent
    if not existing.is_dir():
        raise ConfigError(f'the directory of {path} does not exist; create it first')
    _require_writable(path, existing)
    refuse_over_inputs(option, path, inputs)
    return directory


def _require_writable(path, directory):
    """ConfigError, in the words of a failed write (describe_os_error), unless ``directory`` takes new files: checked
    before the command works, where a read-only disk found at the end wasted the whole run."""
    if os.access(directory, os.W_OK | os.X_OK):
        return
    read_only = bool(os.statvfs(directory).f_flag & os.ST_RDONLY)
    line, _ = describe_os_error(OSError(errno.EROFS if read_only else errno.EACCES, ''), filename=path)
    raise ConfigError(f'cannot write {line}')


def refuse_empty_paths(*given):
    """ConfigError for the first (name, value) given as an empty string, which a Path reads as the current folder."""
    for name, value in given:
        if value == '':
            raise ConfigError(f'{name} is given an empty value; give a path')


def refuse_over_inputs(option, path, inputs):
    """ConfigError when ``path`` is one of ``inputs`` (the same file, through any link) or lies inside an input
    folder: `--json BAG/BAG.mcap` replaced a recording with the comparison, at exit 0."""
    target = Path(path).resolve()
    for what, given in inputs.items():
        if not given:
            continue
        source = Path(given).resolve()
        if target == source or _same_file(target, source):
            role = 'another output' if what.startswith('--') else 'which the command reads'
            raise ConfigError(f'{option} {path} is {what} ({given}), {role}; write it elsewhere')
        if source in target.parents:  # a folder, or one the command is yet to make (an atlas' table)
            does = 'writes' if what.startswith('--') else 'reads'
            raise ConfigError(f'{option} {path} is inside {what} {given}, whose files the command {does}; '
                              'write it elsewhere')


def _same_file(first, second):
    try:
        return os.path.samefile(first, second)
    except OSError:  # one of them does not exist (yet)
        return False


@contextmanager
def atomic_output(path, mode='w'):
    """A stream whose file appears at ``path`` whole when the block ends, and never if it fails.

    Temporary file in the same directory, fsync, rename; a symlink is written through (its
    regular-file target replaced, the link kept), the file keeps its mode, a new one gets 0666
    less the umask. ConfigError in one line when the target or its directory cannot be written.
    """
    target = output_target(path)
    try:
        file_mode = target.stat().st_mode & 0o7777
    except FileNotFoundError:
        file_mode = 0o666 & ~current_umask()
    try:
        handle, temporary = tempfile.mkstemp(prefix=f'.{target.name[:200]}.', dir=target.parent)
    except OSError as err:
        raise output_error(path, err) from err
    try:
        with os.fdopen(handle, mode) as stream:
            os.fchmod(stream.fileno(), file_mode)
            yield stream
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, target)
    except OSError as err:
        Path(temporary).unlink(missing_ok=True)
        raise output_error(path, err) from err
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


def write_text_atomically(path, text):
    """Write a text file whole or not at all (atomic_output)."""
    with atomic_output(path) as stream:
        stream.write(text)


#: How an operating-system error on a command's files is told, and its exit code: 3 where the
#: machine ran out of something (the command was right), 2 where the user's path is at fault.
_OS_ERROR_EXITS = {
    errno.ENOSPC: (3, 'disk full', 'free space or write elsewhere'),
    errno.EDQUOT: (3, 'disk quota exceeded', 'free space or write elsewhere'),
    errno.EROFS: (2, 'read-only file system', 'write to a writable directory'),
    errno.EACCES: (2, 'permission denied', 'write to a directory you may write to'),
    errno.EPERM: (2, 'operation not permitted', 'write to a directory you may write to'),
    errno.ENAMETOOLONG: (2, 'file name too long', 'choose a shorter name'),
    errno.ENOTDIR: (2, 'a part of the path is a file, not a directory', 'check the path'),
    errno.ENOENT: (2, 'no such file or directory', 'check the path'),
}


def output_error(path, err):
    """The OutputError for an OSError met writing ``path``: one line, exit 3 for a full disk, else 2."""
    line, exit_code = describe_os_error(err, filename=path)
    return OutputError(f'cannot write {line}', exit_code)


def describe_os_error(err, filename=None):
    """One line and an exit code for an OSError a command met on its files (3: out of space, 2: the path)."""
    exit_code, reason, fix = _OS_ERROR_EXITS.get(err.errno, (3, err.strerror or 'input/output error',
                                                             'check the disk and the path'))
    filename = filename or err.filename
    where = f'{filename}: ' if filename else ''
    return f'{where}{reason}; {fix}', exit_code


def json_ready(value):
    """A document with numpy scalars as Python ones and non-finite floats as null (strict JSON)."""
    if isinstance(value, dict):
        return {key: json_ready(item) for key, item in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(item) for item in value]
    if isinstance(value, (np.floating, float)):
        return float(value) if np.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    if isinstance(value, np.bool_):
        return bool(value)
    return value
