"""The numpy files the comparison's caches keep (compare.cache, compare.steps): members stored, never compressed
or pickled, and a JSON header; a file that fails a check is UnusableCacheFile, never used."""

from __future__ import annotations

import json
import zipfile
import zlib
from pathlib import Path

import numpy as np

from sofia_ros.errors import ConfigError
from sofia_ros.input_files import require_regular_file
from sofia_ros.output_files import atomic_output

__all__ = ['HEADER', 'UnusableCacheFile', 'read_members', 'remove_cache_file', 'write_members']

#: The member that holds a file's JSON header.
HEADER = 'header'
#: The header's entry of each array member's fingerprint (_fingerprint).
_FINGERPRINTS = 'member_fingerprints'


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
    header = {**header, _FINGERPRINTS: {name: _fingerprint(array) for name, array in arrays.items()}}
    encoded = np.frombuffer(json.dumps(header).encode(), dtype=np.uint8)
    with atomic_output(path, 'wb') as stream:
        np.savez(stream, **{HEADER: encoded}, **arrays)


def _fingerprint(array: np.ndarray) -> list:
    """What an array member must still be when read: its dtype, shape and the CRC-32 of its bytes."""
    return [array.dtype.str, list(array.shape), zlib.crc32(np.ascontiguousarray(array).view(np.uint8))]


def read_members(path: Path, what: str) -> tuple[dict, dict[str, np.ndarray]]:
    """The JSON header and the other members of a cache file.

    Args:
        path: the file.
        what: what the file is, for the messages ('observation cache').

    Returns:
        (the header, {member: array}).

    Raises:
        UnusableCacheFile: not a regular file, unreadable, a member that fails its CRC, compressed or pickled
            members, no header or one that is not a JSON object, members that are not the fingerprinted ones.
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
    # The zip's CRCs hold for members saved again: a member rewritten (as float32, a value changed, an array cut)
    # then gave a traceback or another fit at exit 0 (issue 27: never a wrong result from the cache).
    fingerprints = header.pop(_FINGERPRINTS, None)
    if fingerprints != {name: _fingerprint(array) for name, array in members.items()}:
        raise UnusableCacheFile('its arrays are not those it was written with')
    return header, members
