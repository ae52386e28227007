"""The atlas' results: a Parquet table (a pyarrow dataset directory), one row per task, keyed.

``OUT/`` holds ``_grid.json`` (the grid and its fingerprint) and ``part-*.parquet`` files, each
written whole (temporary name, then rename) as tasks finish, so an interrupted atlas loses at most
the rows of its last few seconds and a resumed one skips every key the table holds. Read it with
``pyarrow.parquet.read_table(OUT)`` (files starting with ``_`` or ``.`` are not data).

Every part carries the grid's fingerprint in its schema metadata and page checksums. A part of
another grid (copied in from another run) or one that cannot be read whole is refused in one line
naming it, before anything runs: merged, it would count another grid's rows (a 2-task grid
reported 3 rows); skipped, it would still be read by ``pyarrow.parquet.read_table(OUT)``.
"""

from __future__ import annotations

import json
import time
import uuid
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq

from sofia_ros.atlas.task import ROW_FIELDS
from sofia_ros.errors import ConfigError
from sofia_ros.input_files import read_text_capped, require_regular_file
from sofia_ros.output_files import atomic_output, write_text_atomically

__all__ = ['GRID_FILE', 'ResultStore', 'ROW_SCHEMA']

GRID_FILE = '_grid.json'
_ARROW_TYPES = {'str': pa.string(), 'float': pa.float64(), 'int': pa.int64(), 'bool': pa.bool_()}
ROW_SCHEMA = pa.schema([pa.field(name, _ARROW_TYPES[kind]) for name, kind in ROW_FIELDS.items()])
#: The schema metadata key of a part's grid fingerprint.
_FINGERPRINT_KEY = b'sofia_atlas_grid'
#: _grid.json lists every seed: a million seeds are some 8 MB.
_MAX_GRID_FILE_BYTES = 64 << 20


class ResultStore:
    """The results table of one grid: open (refusing another grid's), append rows, flush, read."""

    def __init__(self, path, grid_description: dict, *, flush_s: float = 5.0):
        self.path = Path(path)
        self.flush_s = flush_s
        self._pending: list[dict] = []
        self._last_flush = time.monotonic()
        self._fingerprint = grid_description['fingerprint']
        grid_file = self.path / GRID_FILE
        if self.path.exists() and not self.path.is_dir():
            raise ConfigError(f'{self.path} is a file; the atlas writes its results directory there, give another --out')
        existing = next(parent for parent in self.path.parents if parent.exists())
        if not self.path.exists() and not existing.is_dir():
            raise ConfigError(f'{existing} is a file; the atlas writes its results directory below it, give another --out')
        if grid_file.exists():
            try:
                stored = json.loads(read_text_capped(grid_file, _MAX_GRID_FILE_BYTES, 'atlas grid file'))['fingerprint']
            except (ValueError, KeyError, TypeError) as err:
                raise ConfigError(f'{grid_file} is damaged ({err}); move {self.path} away and start afresh') from err
            if stored != self._fingerprint:
                raise ConfigError(f'{self.path} holds the results of a different grid (fingerprint {stored[:12]}, '
                                  f'this grid {self._fingerprint[:12]}); give a new --out or the grid it was made with')
        elif self.path.is_dir() and any(self.path.iterdir()):
            raise ConfigError(f'{self.path} is not empty and holds no atlas ({GRID_FILE} missing); give a new --out')
        self._grid_description = grid_description
        self._keys = set(self.read().column('key').to_pylist())

    def finished_keys(self) -> set[str]:
        """Keys of every row in the table or waiting to be written."""
        return set(self._keys)

    def append(self, row: dict) -> bool:
        """Queue one row (flushed every ``flush_s``); False, and nothing written, for a key already held."""
        if row['key'] in self._keys:
            return False
        self._keys.add(row['key'])
        self._pending.append(row)
        if time.monotonic() - self._last_flush >= self.flush_s:
            self.flush()
        return True

    def flush(self) -> None:
        """Write the queued rows as one part file (whole or not at all)."""
        self._last_flush = time.monotonic()
        if not self._pending:
            return
        self._create()
        table = pa.Table.from_pylist(self._pending, schema=self._schema())
        _write_part(self.path / f'part-{time.strftime("%Y%m%dT%H%M%S")}-{uuid.uuid4().hex[:8]}.parquet', table)
        self._pending = []

    def _create(self) -> None:
        """The directory and its grid file, at the first rows (so bad input found earlier writes nothing)."""
        grid_file = self.path / GRID_FILE
        if grid_file.exists():
            return
        try:
            self.path.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise ConfigError(f'cannot create {self.path}: {err.strerror}; give another --out') from err
        write_text_atomically(grid_file, json.dumps(self._grid_description, indent=1))

    def read(self) -> pa.Table:
        """Every row written so far (one per key), in no particular order; ConfigError naming a part of another
        grid or a damaged one."""
        parts = sorted(self.path.glob('part-*.parquet'))
        if not parts:
            return self._schema().empty_table()
        table = pa.concat_tables([self._read_part(part) for part in parts])
        keys, keep = set(), []
        for index, key in enumerate(table.column('key').to_pylist()):  # a crash inside compact() may double a row
            if key not in keys:
                keys.add(key)
                keep.append(index)
        return table.take(keep) if len(keep) < table.num_rows else table

    def compact(self) -> None:
        """Merge the part files into one (written before the old ones go, so a crash loses nothing)."""
        self.flush()
        parts = sorted(self.path.glob('part-*.parquet'))
        if len(parts) <= 1:
            return
        table = self.read()
        _write_part(self.path / f'part-{time.strftime("%Y%m%dT%H%M%S")}-{uuid.uuid4().hex[:8]}-all.parquet', table)
        for part in parts:
            part.unlink()

    def _read_part(self, part: Path) -> pa.Table:
        """One part's rows, if it is whole and of this grid; ConfigError naming it and the fix otherwise."""
        require_regular_file(part, 'atlas part file')
        try:
            with pq.ParquetFile(part, page_checksum_verification=True) as parquet:
                stored = (parquet.schema_arrow.metadata or {}).get(_FINGERPRINT_KEY)
                table = parquet.read() if stored == self._fingerprint.encode() else None
        except (pa.ArrowException, OSError, ValueError) as err:
            raise _damaged(part, str(err)) from err
        if table is None:
            origin = f'grid {stored.decode(errors="replace")[:12]}' if stored else 'no atlas grid'
            raise ConfigError(f'{part} holds rows of {origin}, not of this table\'s grid {self._fingerprint[:12]}; '
                              f'move it out of {self.path} (the atlas never merges the rows of different grids)')
        if not table.schema.remove_metadata().equals(ROW_SCHEMA):
            raise _damaged(part, 'its columns are not the atlas row')
        return table.replace_schema_metadata(self._schema().metadata)

    def _schema(self) -> pa.Schema:
        return ROW_SCHEMA.with_metadata({_FINGERPRINT_KEY: self._fingerprint})


def _damaged(part: Path, reason: str) -> ConfigError:
    reason = (reason.splitlines() or ['unreadable'])[0][:200]
    return ConfigError(f'{part} is damaged ({reason}); delete it and run the same command again: '
                       'the atlas runs the tasks whose rows it held again')


def _write_part(path: Path, table: pa.Table) -> None:
    """One part file, whole or not at all, with page checksums (a flipped bit is found when it is read)."""
    with atomic_output(path, 'wb') as stream:
        pq.write_table(table, stream, write_page_checksum=True)
