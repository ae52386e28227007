"""A cache of the observations `sofia compare` decodes from a bag: comparing the same bag again with another
model skips the decoding (docs/compare.md, "Cache and progress").

Where: ``<bag>/.sofia-cache/``, or when the bag directory cannot be written, a folder of the bag (its name
and a hash of its resolved path) under ``$XDG_CACHE_HOME/sofia_ros`` (``~/.cache/sofia_ros``).

Key: observations.READER_VERSION, CACHE_FORMAT and, for every regular file of the bag directory, its name,
size, mtime_ns and content (whole up to WHOLE_FILE_BYTES, else its last FOOTER_BYTES: an MCAP file's footer
with the CRC of its summary). A changed bag or reader has another key, and its cache is decoded again.

Format: one numpy .npz (read with allow_pickle=False; every member stored, none compressed), the arrays
by dataclass field and a JSON header (reader version, key, cameras, scalars, the scenario as the YAML
document the bag records). A file that fails any check is never used: it is decoded again and replaced,
with one line on stderr.
"""

from __future__ import annotations

import dataclasses
import hashlib
import os
from collections.abc import Callable
from pathlib import Path

import numpy as np

from sofia_ros.compare.cache_files import UnusableCacheFile, read_members, remove_cache_file, write_members
from sofia_ros.compare.observations import READER_VERSION, Centroids, GyroSamples, Observations, keyed
from sofia_ros.compare.steps import StepStore, remove_step_files
from sofia_ros.errors import ConfigError
from sofia_ros.output_files import describe_os_error
from sofia_ros.progress import Progress
from sofia_ros.scenario import scenario_document, scenario_from_document
from sofia_ros.sensors.imager_model import CAMERAS

__all__ = ['CACHE_DIRECTORY', 'CACHE_FORMAT', 'ObservationCache', 'bag_key', 'user_cache_home']

#: The cache's folder inside a bag directory (a subdirectory: the bag's readers list only its files).
CACHE_DIRECTORY = '.sofia-cache'
#: The layout of a cache file (members, header keys); bump it when that changes.
CACHE_FORMAT = 1
#: Bag files up to this size (metadata.yaml, the side files) are keyed by their whole content.
WHOLE_FILE_BYTES = 1 << 20
#: Of a larger file (an MCAP file), its last bytes: the MCAP footer (29 bytes) and the closing magic (8).
FOOTER_BYTES = 64
_FILE_PREFIX = 'observations-'
#: Observations' fields kept outside the arrays and the header's values: the path is the one asked for,
#: the scenario is stored as its document and the nested records field by field.
_NESTED = {'centroids': Centroids, 'gyro': GyroSamples}
_NOT_STORED = {'bag_path', 'scenario', *_NESTED}


def user_cache_home() -> Path | None:
    """The user's cache folder of sofia_ros.

    Returns:
        $XDG_CACHE_HOME/sofia_ros, or ~/.cache/sofia_ros (the XDG base directory default); None for a user
        without a home directory.
    """
    base = os.environ.get('XDG_CACHE_HOME') or ''
    # The XDG specification ignores a relative path.
    if os.path.isabs(base):
        return Path(base) / 'sofia_ros'
    try:
        return Path.home() / '.cache' / 'sofia_ros'
    except RuntimeError:  # no $HOME and no entry in the password database
        return None


def bag_key(bag_path: Path) -> str | None:
    """The cache key of the bag as it is now (module docstring).

    Args:
        bag_path: the bag directory.

    Returns:
        A sha256 hex digest; None when the bag's files cannot be listed or read (the decoding then names
        what is wrong with the bag).
    """
    digest = hashlib.sha256(f'sofia_ros observations: reader {READER_VERSION}, format {CACHE_FORMAT}\n'.encode())
    try:
        entries = sorted(os.scandir(bag_path), key=lambda entry: entry.name)
        for entry in entries:
            # Links are followed; subdirectories (this cache), FIFOs and devices are not part of a bag.
            if not entry.is_file():
                continue
            status = entry.stat()
            digest.update(f'{entry.name}\0{status.st_size}\0{status.st_mtime_ns}\0'.encode('utf-8', 'surrogateescape'))
            with open(entry.path, 'rb') as file:
                if status.st_size > WHOLE_FILE_BYTES:
                    file.seek(status.st_size - FOOTER_BYTES)
                digest.update(file.read(WHOLE_FILE_BYTES))
    except OSError:
        return None
    return digest.hexdigest()


def _file_name(key: str) -> str:
    return f'{_FILE_PREFIX}r{READER_VERSION}-{key}.npz'


def _split(observations: Observations) -> tuple[dict[str, np.ndarray], dict[str, object]]:
    """The arrays of ``observations`` by field ('gyro.time_s') and its other values ('centroids.cameras')."""
    arrays, values = {}, {}
    for prefix, record in (('', observations), *((f'{name}.', getattr(observations, name)) for name in _NESTED)):
        for field in dataclasses.fields(record):
            if not prefix and field.name in _NOT_STORED:
                continue
            value = getattr(record, field.name)
            if isinstance(value, np.ndarray):
                arrays[prefix + field.name] = value
            else:
                values[prefix + field.name] = list(value) if isinstance(value, tuple) else value
    return arrays, values


def _record(cls: type, prefix: str, arrays: dict[str, np.ndarray], values: dict[str, object], **given: object):
    """A ``cls`` from ``given`` fields and those stored as ``prefix + field`` (_load has checked that all are)."""
    stored = {}
    for field in dataclasses.fields(cls):
        name = prefix + field.name
        if field.name in given:
            stored[field.name] = given[field.name]
        elif name in arrays:
            stored[field.name] = arrays[name]
        else:
            stored[field.name] = tuple(values[name]) if isinstance(values[name], list) else values[name]
    return cls(**stored)


def _write(path: Path, key: str, observations: Observations) -> None:
    """The cache file of ``observations`` at ``path``, written whole or not at all; OSError, ConfigError."""
    arrays, values = _split(observations)
    header = {'format': CACHE_FORMAT, 'reader_version': READER_VERSION, 'key': key, 'values': values,
              'scenario_document': scenario_document(observations.scenario)}
    write_members(path, header, arrays)


def _load(path: Path, key: str, bag_path: Path) -> Observations:
    """The observations of the cache file at ``path``; UnusableCacheFile naming the first check it fails."""
    header, members = read_members(path, 'observation cache')
    _check_header(header, key)
    values = header['values']
    if set(members) != _array_names() or set(values) != set(_VALUE_CHECKS):
        raise UnusableCacheFile('its fields are not those of this reader')
    if any(value.dtype.kind not in 'biuf' or value.ndim == 0 for value in members.values()):
        raise UnusableCacheFile('it holds members that are not arrays of numbers')
    if not _rows_agree(members):
        raise UnusableCacheFile('its arrays do not agree in length')
    wrong = [name for name, check in _VALUE_CHECKS.items() if not check(values[name])]
    if wrong:
        raise UnusableCacheFile(f'its {", ".join(wrong)} is not what the reader writes')
    try:
        scenario = scenario_from_document(header.get('scenario_document'))
    except (ConfigError, AttributeError, TypeError, ValueError) as err:
        raise UnusableCacheFile(f'its scenario is not one ({err})') from err
    nested = {name: _record(cls, f'{name}.', members, values) for name, cls in _NESTED.items()}
    return _record(Observations, '', members, values, bag_path=bag_path, scenario=scenario, **nested)


def _check_header(header: dict, key: str) -> None:
    """A cache file's header checked against this reader and ``key``; UnusableCacheFile otherwise."""
    if (header.get('format'), header.get('reader_version')) != (CACHE_FORMAT, READER_VERSION):
        raise UnusableCacheFile(f'it was written by another reader (format {header.get("format")}, reader version '
                                f'{header.get("reader_version")}; this is {CACHE_FORMAT}, {READER_VERSION})')
    if header.get('key') != key or not isinstance(header.get('values'), dict):
        raise UnusableCacheFile('its header is for another bag')


def _is_float(value: object) -> bool:
    return isinstance(value, float)


def _is_count(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value >= 0


def _is_camera_list(value: object) -> bool:
    return isinstance(value, list) and bool(value) and all(camera in CAMERAS for camera in value)


#: Observations' fields that are not arrays, stored in the header: what each must be.
_VALUE_CHECKS: dict[str, Callable[[object], bool]] = {
    'centroids.cameras': _is_camera_list,
    'gyro.sample_period_s': _is_float,
    'gyro.within_tick_difference_count': _is_count,
    'initial_time_s': _is_float,
    'calibration_result': lambda value: value is None or isinstance(value, str),
}


def _rows_agree(arrays: dict[str, np.ndarray]) -> bool:
    """One row per centroid in every centroid array and per tick in the gyro's tick arrays, the ticks' sample counts
    adding up to the samples, three axes of rate noise."""
    def lengths(names):
        return {len(arrays[name]) for name in names}

    centroids = lengths(name for name in arrays if name.startswith('centroids.'))
    ticks = lengths(name for name in arrays if name.startswith('gyro.tick_'))
    return (len(centroids) == len(ticks) == 1 and arrays['initial_tarf_from_irf'].shape == (3, 3)
            and int(arrays['gyro.tick_sample_count'].sum()) == len(arrays['gyro.time_s'])
            and arrays['gyro.within_tick_rate_sigma_rad_per_s'].shape == (3,))


def _array_names() -> set[str]:
    """The names of the arrays a cache file holds: every stored field that is not a header value."""
    names = {field.name for field in dataclasses.fields(Observations) if field.name not in _NOT_STORED}
    names |= {f'{prefix}.{field.name}' for prefix, cls in _NESTED.items() for field in dataclasses.fields(cls)}
    return names - set(_VALUE_CHECKS)


class ObservationCache:
    """compare.observations' ObservationSource of `sofia compare`: decoded observations kept on disk.

    ``warn`` takes the one line for a cache that cannot be used or written (it never fails the compare);
    ``progress`` is told when the observations come from the cache.
    """

    def __init__(self, *, warn: Callable[[str], None], progress: Progress | None = None,
                 home: Path | None = None) -> None:
        self.warn = warn
        self.progress = progress or Progress.silent()
        self.home = home or user_cache_home()
        #: bag directory -> the folder its observations were read from or written to
        self._used: dict[Path, Path] = {}

    def folders(self, bag_path: Path) -> tuple[Path, ...]:
        """Where the cache of a bag may be, in the order tried.

        Args:
            bag_path: the bag directory.

        Returns:
            The cache folder inside the bag, then the bag's folder under the user's cache home if there is one
            (named for the bag's resolved path: never shared by two bags).
        """
        if self.home is None:
            return (bag_path / CACHE_DIRECTORY,)
        resolved = bag_path.resolve()
        path_hash = hashlib.sha256(os.fsencode(resolved)).hexdigest()[:16]
        return bag_path / CACHE_DIRECTORY, self.home / f'{resolved.name[:100]}-{path_hash}'

    def read(self, bag_path: Path, decode: Callable[[Path], Observations]) -> Observations:
        """The observations of a bag from its cache file when it has a usable one, else decoded and cached.

        Args:
            bag_path: the bag directory.
            decode: decodes the bag (compare.observations.decode_observations); its errors pass through.

        Returns:
            The bag's Observations, with ``bag_path`` as given, keyed by the bag's key (observations.keyed: the
            fitted steps of the bag are found by it).
        """
        key = bag_key(bag_path)
        if key is None:
            return decode(bag_path)
        folders = self.folders(bag_path)
        cached, unusable = self._lookup(folders, key, bag_path)
        if cached is not None:
            self.progress.phase('decoded observations from the cache')
            return keyed(cached, key)
        observations = keyed(decode(bag_path), key)
        unwritable = self._store(folders, key, observations, bag_path)
        # One line, once the bag decoded: a bag that cannot be read gets its one error line alone.
        told = []
        if unusable:
            told.append(f'{unusable}; decoded the bag again')
        if unwritable:
            told.append(f'cannot cache the decoded observations ({unwritable}); compared without a cache '
                        '(--no-cache skips it)')
        if told:
            self.warn('sofia compare: ' + '; '.join(told))
        return observations

    def _lookup(self, folders: tuple[Path, ...], key: str, bag_path: Path) -> tuple[Observations | None, str | None]:
        """The cached observations of the bag as it is, else None and why the cache is not used (None when there was
        none)."""
        for folder in folders:
            path = folder / _file_name(key)
            if not (path.exists() or path.is_symlink()):
                continue
            try:
                observations = _load(path, key, bag_path)
                self._used[bag_path] = folder
                return observations, None
            except UnusableCacheFile as err:
                remove_cache_file(path)
                return None, f'ignored the observation cache {path} ({err})'
        stale = [path for folder in folders for path in _cache_files(folder)]
        if stale:
            return None, f'the bag or the reader changed since {stale[0]} was written'
        return None, None

    def step_store(self, bag_path: Path) -> StepStore:
        """Where the ledger's steps of a bag read through this cache are kept (compare.steps).

        Args:
            bag_path: the bag directory, as read.

        Returns:
            A StepStore on the folder of the bag's observations (memory only where there is none).
        """
        return StepStore(self._used.get(bag_path), warn=self.warn)

    def _store(self, folders: tuple[Path, ...], key: str, observations: Observations, bag_path: Path) -> str | None:
        """Write the cache file into the first folder that takes it, removing that folder's older files (and its
        fitted steps, of the bag as it was); why none took it, or None."""
        reasons = []
        for folder in folders:
            path = folder / _file_name(key)
            try:
                folder.mkdir(parents=folder != folders[0], exist_ok=True)
                _write(path, key, observations)
            except (OSError, ConfigError) as err:
                reasons.append(str(err) if isinstance(err, ConfigError) else describe_os_error(err, folder)[0])
                continue
            for old in _cache_files(folder):
                if old != path:
                    remove_cache_file(old)
            remove_step_files(folder)
            self._used[bag_path] = folder
            return None
        return '; '.join(reasons)


def _cache_files(folder: Path) -> list[Path]:
    """The observation cache files in ``folder`` (none when it does not exist or cannot be listed)."""
    try:
        return sorted(folder.glob(f'{_FILE_PREFIX}*.npz'))
    except OSError:
        return []
