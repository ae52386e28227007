"""The ledger's chain kept: a step fitted once is read back wherever the same step comes again
(docs/compare.md, "Cache and progress").

The ledger fits the fixed effects alone, then adds the model's fitted terms one at a time, each step
starting from the one before. A step depends on the bag's problem (observations, noise floors, start
attitude, anchors' prior: all set by the fixed effects, compare.run.BagSource), the effects it starts
from, its free parameters and the anchors it starts at. The user's loop adds one term per round, and
the model search compares models that share their first terms: all but the last step of a chain have
then been fitted before.

A step is kept under a digest of all it depends on and of this code (every module of sofia_ros and the
numpy and scipy versions): in memory for the process (the search, the atlas' workers), and on disk in
the bag's observation cache folder (compare.cache) for the next `sofia compare`, as its effects,
anchors, BIC and ledger row. The chain's last step, whose whole fit the comparison goes on with, is
always fitted, and kept for the chains that go on from it (the loop's next round).

On disk: one numpy .npz per step (``steps-<digest>.npz``, compare.cache_files), the anchors and a
JSON header (the digest, the effects, the parameters, the BIC, the row). A file that fails
a check is removed and the step fitted again, with one line on stderr.
"""

from __future__ import annotations

import hashlib
import json
from collections import OrderedDict
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import scipy

from sofia_ros.compare.cache_files import UnusableCacheFile, read_members, remove_cache_file, write_members
from sofia_ros.errors import ConfigError

__all__ = ['STEP_FILE_PREFIX', 'ChainStep', 'StepStore', 'code_fingerprint', 'remove_step_files', 'step_key']

#: Prefix of the step files in a bag's cache folder.
STEP_FILE_PREFIX = 'steps-'
#: Steps kept in memory per process (an atlas worker compares many bags).
MEMORY_STEPS = 256
#: Step files kept in one cache folder; the oldest are removed beyond (a file is a few kB per 100 anchors).
DISK_STEPS = 512
_ANCHORS = 'anchors_rad'
_PACKAGE = Path(__file__).resolve().parents[1]


@dataclass(frozen=True, eq=False)
class ChainStep:
    """A step of the ledger's chain as kept: what the next step starts from and the step's row.

    ``effects`` at the fitted values, ``free`` the parameters fitted, ``anchors_rad`` (K, 3) the anchors,
    ``bic`` and ``row`` the ledger's (compare.records.LedgerRow).
    """

    effects: dict
    free: tuple
    anchors_rad: np.ndarray
    bic: float
    row: dict


@lru_cache(maxsize=1)
def code_fingerprint() -> str:
    """A digest of this code: every module of sofia_ros and the numpy and scipy versions a fit runs on.

    Returns:
        A sha256 hex digest.
    """
    digest = hashlib.sha256(f'numpy {np.__version__}, scipy {scipy.__version__}\n'.encode())
    for path in sorted(_PACKAGE.rglob('*.py')):
        digest.update(f'{path.relative_to(_PACKAGE)}\0'.encode())
        digest.update(path.read_bytes())
    return digest.hexdigest()


def step_key(problem: str, effects: Mapping, free_labels: Iterable[str], start_anchors_rad: np.ndarray | None,
             fitted_labels: Iterable[str]) -> str:
    """The digest a step is kept under.

    Args:
        problem: the digest of the bag's problem (compare.run.BagSource.problem_digest).
        effects: {effect: params} the step starts from.
        free_labels: the labels of its free parameters.
        start_anchors_rad: the anchors it starts at, or None.
        fitted_labels: the labels of the parameters the step before fitted (its time shifts are not profiled again).

    Returns:
        A sha256 hex digest.
    """
    digest = hashlib.sha256(f'{code_fingerprint()}\0{problem}\0{effects!r}\0'.encode())
    digest.update(json.dumps([list(free_labels), list(fitted_labels)]).encode())
    if start_anchors_rad is not None:
        digest.update(np.ascontiguousarray(start_anchors_rad, dtype=float).tobytes())
    return digest.hexdigest()


class StepStore:
    """Chain steps by key: in memory (shared by the process) and, given a folder, on disk.

    ``warn`` takes the one line for a step file that cannot be used or written (it never fails a compare).
    """

    _memory: OrderedDict[str, ChainStep] = OrderedDict()

    def __init__(self, folder: Path | None = None, *, warn: Callable[[str], None] = lambda line: None) -> None:
        self.folder = folder
        self.warn = warn

    def get(self, key: str, free: tuple) -> ChainStep | None:
        """The step kept under ``key``, or None.

        Args:
            key: step_key's digest.
            free: the step's free parameters (a file stores their labels only).

        Returns:
            The ChainStep, or None.
        """
        if key in self._memory:
            self._memory.move_to_end(key)
            return self._memory[key]
        if self.folder is None:
            return None
        path = self.folder / f'{STEP_FILE_PREFIX}{key}.npz'
        if not (path.exists() or path.is_symlink()):
            return None
        try:
            step = _load(path, key, free)
        except UnusableCacheFile as err:
            remove_cache_file(path)
            self.warn(f'sofia compare: ignored the fit cache {path} ({err}); fitted the step again')
            return None
        self._remember(key, step)
        return step

    def put(self, key: str, step: ChainStep) -> None:
        """Keep ``step`` under ``key``: in memory, and on disk where the store has a folder and the step's effects
        are plain numbers, strings and lists (their JSON gives them back exactly).

        Args:
            key: step_key's digest.
            step: the step.
        """
        self._remember(key, step)
        if self.folder is None or json.loads(json.dumps(step.effects)) != step.effects:
            return
        try:
            _write(self.folder / f'{STEP_FILE_PREFIX}{key}.npz', key, step)
        except (OSError, ConfigError) as err:
            self.warn(f'sofia compare: cannot keep a fitted step in {self.folder} ({err}); compared without keeping it')
            return
        _prune(self.folder)

    def _remember(self, key, step):
        self._memory[key] = step
        self._memory.move_to_end(key)
        while len(self._memory) > MEMORY_STEPS:
            self._memory.popitem(last=False)


def _write(path: Path, key: str, step: ChainStep) -> None:
    header = {'key': key, 'effects': step.effects, 'free': [p.label for p in step.free], 'bic': step.bic,
              'row': step.row}
    write_members(path, header, {_ANCHORS: np.asarray(step.anchors_rad, dtype=float)})


def _load(path: Path, key: str, free: tuple) -> ChainStep:
    """The step of the file at ``path``; UnusableCacheFile naming the first check it fails."""
    header, members = read_members(path, 'fit cache')
    if set(members) != {_ANCHORS}:
        raise UnusableCacheFile('its members are not a step\'s')
    anchors = members[_ANCHORS]
    if header.get('key') != key:
        raise UnusableCacheFile('its header is for another step')
    if header.get('free') != [p.label for p in free]:
        raise UnusableCacheFile('its parameters are not the step\'s')
    if anchors.dtype.kind != 'f' or anchors.ndim != 2 or anchors.shape[1] != 3 or not np.all(np.isfinite(anchors)):
        raise UnusableCacheFile('its anchors are not a (K, 3) array of finite numbers')
    if not isinstance(header.get('effects'), dict) or not isinstance(header.get('row'), dict):
        raise UnusableCacheFile('its effects or row are not JSON objects')
    bic = header.get('bic')
    if not isinstance(bic, float):
        raise UnusableCacheFile('its BIC is not a number')
    return ChainStep(header['effects'], free, anchors, bic, header['row'])


def _prune(folder: Path) -> None:
    """Remove the oldest step files of ``folder`` beyond DISK_STEPS."""
    try:
        files = sorted((path.stat().st_mtime_ns, path) for path in folder.glob(f'{STEP_FILE_PREFIX}*.npz'))
    except OSError:
        return
    for _, path in files[:max(len(files) - DISK_STEPS, 0)]:
        remove_cache_file(path)


def remove_step_files(folder: Path) -> None:
    """Remove every step file of a cache folder (its bag has changed: none of them can be used again).

    Args:
        folder: the bag's cache folder.
    """
    try:
        files = list(folder.glob(f'{STEP_FILE_PREFIX}*.npz'))
    except OSError:
        return
    for path in files:
        remove_cache_file(path)
