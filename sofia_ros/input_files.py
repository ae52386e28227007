"""Input files of the commands: regular files only, read up to a cap, decoded as UTF-8 in one line of error."""

from __future__ import annotations

import os
import stat
import sys
from pathlib import Path

from sofia_ros.errors import ConfigError

__all__ = ['read_bytes_capped', 'read_text_capped', 'require_regular_file', 'shipped_file', 'shipped_paths']


def require_regular_file(path, what='file'):
    """The path itself if it (after following links) is a regular file; ConfigError naming it otherwise.

    A device, a FIFO or a directory given where a file is expected would hang the reader
    (/dev/zero never ends, a FIFO waits for a writer) or be replaced by an output.
    """
    path = Path(path)
    try:
        mode = os.stat(path).st_mode
    except FileNotFoundError as err:
        raise ConfigError(f'cannot read {path}: no such file; check the path') from err
    except OSError as err:
        raise ConfigError(f'cannot read {path}: {err.strerror}; check the path') from err
    if stat.S_ISDIR(mode):
        raise ConfigError(f'{path} is a directory; give the {what} itself')
    if not stat.S_ISREG(mode):
        raise ConfigError(f'{path} is not a regular file (a device, FIFO or socket); give a {what} on disk')
    return path


def read_bytes_capped(path, max_bytes, what='file'):
    """The bytes of a regular file of at most ``max_bytes``; ConfigError in one line otherwise."""
    path = require_regular_file(path, what)
    try:
        with path.open('rb') as stream:
            data = stream.read(max_bytes + 1)
    except OSError as err:
        raise ConfigError(f'cannot read {path}: {err.strerror}; check the path') from err
    if len(data) > max_bytes:
        raise ConfigError(f'{path}: larger than {max_bytes} bytes, the most a {what} may have')
    return data


def read_text_capped(path, max_bytes, what='file'):
    """The UTF-8 text of a regular file of at most ``max_bytes``; ConfigError in one line otherwise."""
    data = read_bytes_capped(path, max_bytes, what)
    try:
        return data.decode('utf-8')
    except UnicodeDecodeError as err:
        raise ConfigError(f'{path}: not UTF-8 text (byte {err.start}); is it a {what}?') from err


def shipped_paths(relative):
    """Where the checkout, then an install (colcon: share/sofia_ros above the package; pip: under sys.prefix), would
    keep the shipped file or folder ``relative`` (e.g. 'config/plans'), in that order."""
    package = Path(__file__).resolve()
    return [package.parents[1] / relative,
            *(ancestor / 'share' / 'sofia_ros' / relative for ancestor in (*package.parents, Path(sys.prefix)))]


def shipped_file(relative):
    """The first of shipped_paths(``relative``) that is a file, or None."""
    return next((path for path in shipped_paths(relative) if path.is_file()), None)
