"""The numpy files the comparison's caches keep (compare.cache, compare.steps): members stored, never compressed
or pickled, and a JSON header; a file that fails a check is UnusableCacheFile, never used."""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import numpy as np

from sofia_ros.errors import ConfigError
from sofia_ros.input_files import require_regular_file
from sofia_ros.output_files import atomic_output

__all__ = ['HEADER', 'UnusableCacheFile', 'read_members', 'remove_cache_file', 'write_members']

#: The member that holds a file's JSON header.
HEADER = 'header'


class UnusableCacheFile(Exception):
    """A cache file that must not be used; the message says why, for the line on stderr."""


def remove_cache_file(path: Path) -> None:
    """Remove a cache file that is not to be used again; one that cannot be removed is left (it is checked anew).

    Args:
        path: the file.
    """
    try:
        path.unlink(missing_ok=True)
    except OSError:
        pass


def write_members(path: Path, header: dict, arrays: dict[str, np.ndarray]) -> None:
    """A cache file of ``arrays`` and the JSON ``header``, written whole or not at all.

    Args:
        path: the file.
        header: the header, JSON.
        arrays: the arrays by member name.

    Raises:
        OSError, ConfigError: the file cannot be written (output_files.atomic_output).
    """
    encoded = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    with atomic_output(path, 'wb') as stream:
        np.savez(stream, **{HEADER: encoded}, **arrays)


def read_members(path: Path, what: str) -> tuple[dict, dict[str, np.ndarray]]:
    """The JSON header and the other members of a cache file.

    Args:
        path: the file.
        what: what the file is, for the messages ('observation cache').

    Returns:
        (the header, {member: array}).

    Raises:
        UnusableCacheFile: not a regular file, unreadable, a member that fails its CRC, compressed or pickled
            members, no header or one that is not a JSON object.
    """
    try:
        require_regular_file(path, what)
        with np.load(path, allow_pickle=False) as archive:
            # np.savez stores every member: a compressed one is not ours (and could expand without bound).
            if any(info.compress_type != zipfile.ZIP_STORED for info in archive.zip.infolist()):
                raise UnusableCacheFile('it holds compressed members')
            members = {name: archive[name] for name in archive.files}
    except ConfigError as err:
        raise UnusableCacheFile(str(err)) from err
    except (OSError, ValueError, EOFError, zipfile.BadZipFile) as err:
        # zipfile checks every member's CRC-32 as it reads it; numpy refuses object arrays (pickles).
        detail = str(err).splitlines()[0] if str(err) else ''
        raise UnusableCacheFile(f'unreadable: {type(err).__name__} {detail}'.rstrip()) from err
    member = members.pop(HEADER, None)
    if member is None or member.dtype != np.uint8 or member.ndim != 1:
        raise UnusableCacheFile('it has no header')
    try:
        header = json.loads(member.tobytes().decode())
    except (UnicodeDecodeError, json.JSONDecodeError) as err:
        raise UnusableCacheFile('its header is not JSON') from err
    if not isinstance(header, dict):
        raise UnusableCacheFile('its header is not a JSON object')
    return header, members
