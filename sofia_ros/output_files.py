"""Output files of the commands: written whole or not at all, JSON strict."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from sofia_ros.errors import ConfigError

__all__ = ['current_umask', 'json_ready', 'write_text_atomically']


def current_umask():
    """The process' umask (read by setting it and setting it back)."""
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def write_text_atomically(path, text):
    """Write a file whole or not at all (temporary file in the same directory, then rename).

    A symlink is written through (its target is replaced, the link stays); the file keeps its
    mode, a new one gets 0666 less the umask like any other output. ConfigError in one line when
    the directory or file cannot be written.
    """
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f'{path} is a directory; give a file name')
    target = path.resolve() if path.is_symlink() else path
    if target.parent and not target.parent.exists():
        raise ConfigError(f'directory {target.parent} does not exist; create it or choose another path')
    try:
        mode = target.stat().st_mode & 0o7777
    except FileNotFoundError:
        mode = 0o666 & ~current_umask()
    try:
        handle, temporary = tempfile.mkstemp(prefix=f'.{target.name}.', dir=target.parent)
    except OSError as err:
        raise ConfigError(f'cannot write {path}: {err.strerror} (directory {target.parent})') from err
    try:
        with os.fdopen(handle, 'w') as stream:
            os.fchmod(stream.fileno(), mode)
            stream.write(text)
            stream.flush()
            os.fsync(stream.fileno())
        os.replace(temporary, target)
    except OSError as err:
        Path(temporary).unlink(missing_ok=True)
        raise ConfigError(f'cannot write {path}: {err.strerror}') from err
    except BaseException:
        Path(temporary).unlink(missing_ok=True)
        raise


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
