"""perturb_bag: a copy of a campaign bag with a shape added to one observable, outside the simulator.

The new bag directory is built in a hidden sibling, flushed to disk and renamed into place at the
end, so an error (a full disk included) leaves nothing behind. It holds the rewritten MCAP file
(rewrite.copy_mcap: only the observable's messages change, re-serialized with only that field
changed), metadata.yaml and every side file of the source (truth.yaml, model.yaml,
calibration.yaml, summary.json, ...) as they were, and perturbation.yaml recording what was added. /truth topics stay as recorded: the perturbation is
physics the truth simulator did not have.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import yaml

from sofia_ros import messages as m
from sofia_ros.bag import TYPESTORE, BagReader
from sofia_ros.bag.imu import decode_imu_rows, with_angular_velocity
from sofia_ros.bag.msgtypes import decode_cdr
from sofia_ros.config import MAX_CONFIG_BYTES, safe_load_limited
from sofia_ros.errors import BagError, PerturbationError
from sofia_ros.input_files import read_text_capped
from sofia_ros.output_files import output_error
from sofia_ros.perturb.observables import Observable, observable as observable_named
from sofia_ros.perturb.rewrite import channel_id_of, channel_payloads, copy_mcap, read_summary
from sofia_ros.perturb.shapes import evaluate_shape, parse_shape, shape_names
from sofia_ros.perturb.variables import CAMERA_SHAPE_VARIABLES, GYRO_SHAPE_VARIABLES, Rows, row_variables

if TYPE_CHECKING:
    from collections.abc import Callable, Iterator
    from os import PathLike

__all__ = ['PERTURBATION_FILE', 'Perturbation', 'perturb_bag']

#: The file in the new bag directory that records the perturbation.
PERTURBATION_FILE = 'perturbation.yaml'
_POSE_ARRAY = 'geometry_msgs/msg/PoseArray'


@dataclass(frozen=True)
class Perturbation:
    """What perturb_bag added: the shape's statistics over every row are in ``unit``."""

    observable: str
    shape: str
    unit: str
    #: rows whose recorded value changed
    rows_changed: int
    rms: float
    min: float
    max: float


@dataclass(frozen=True, eq=False)
class _Recorded:
    """The rows of the observable, its recorded values, and how to write new values back into the payloads."""

    rows: Rows
    values: np.ndarray
    #: new values (file order) -> the replace() callback of rewrite.copy_mcap
    writer: Callable[[np.ndarray], Callable[[list[memoryview]], list[bytes]]]


def perturb_bag(bag_path: str | PathLike[str], out_path: str | PathLike[str], observable: str, shape: str, *,
                unit: str | None = None) -> Perturbation:
    """Copy the bag at ``bag_path`` to the new directory ``out_path`` with ``shape`` (in ``unit``) added to
    ``observable`` at every row; PerturbationError or BagError (one line, nothing written) for bad input."""
    target = observable_named(observable)
    unit, recorded_per_unit = target.recorded_per(unit)
    tree = parse_shape(shape, CAMERA_SHAPE_VARIABLES if target.camera else GYRO_SHAPE_VARIABLES)
    source, out = Path(bag_path), Path(out_path)
    _check_new_directory(out)
    with BagReader(source) as bag:
        if target.topic not in {info.name for info in bag.topics}:
            raise BagError(f'bag {source} lacks {target.topic}, so it has no {target.name}; perturb an observable '
                           'the bag recorded (`sofia perturb --help` lists them)')
        mcap_path = _mcap_file(source)
        summary = read_summary(mcap_path)
        channel_id = channel_id_of(summary, target.topic)
        payloads = channel_payloads(mcap_path, summary, channel_id)
        recorded = _camera(payloads, target) if target.camera else _gyro(payloads, target)
        if len(recorded.values) == 0:
            raise BagError(f'{target.topic} in bag {source} holds no rows; nothing to perturb')
        variables = row_variables(bag, recorded.rows, shape_names(tree) & set(CAMERA_SHAPE_VARIABLES))
    added = np.broadcast_to(evaluate_shape(tree, variables), recorded.values.shape)
    bad = ~np.isfinite(added)
    if bad.any():
        raise PerturbationError(f'the shape {shape!r} is not finite at {np.count_nonzero(bad)} of {len(added)} rows; '
                                'keep it finite everywhere (e.g. guard log and sqrt with maximum(..., 1e-9))')
    with np.errstate(over='ignore', invalid='ignore'):
        new_values = recorded.values + added * recorded_per_unit
        rms = float(np.sqrt(np.mean(np.square(added))))
    if not (np.all(np.isfinite(new_values)) and np.isfinite(rms)):
        # 1.7e308 arcsec is finite, its pixels are not: the copy held inf at exit 0.
        raise PerturbationError(f'the shape {shape!r} takes {target.name} beyond the numbers a bag can hold '
                                f'(largest |value| {np.max(np.abs(added)):.3g} {unit}); give a shape of physical size')
    result = Perturbation(target.name, shape, unit, int(np.count_nonzero(new_values != recorded.values)),
                          rms, float(added.min()), float(added.max()))
    _write_bag(source, out, mcap_path, summary, channel_id, recorded.writer(new_values), result, target)
    return result


def _camera(payloads: Iterator[list[memoryview]], target: Observable) -> _Recorded:
    """Centroid rows (every star of every frame, file order) and the PoseArray re-serializer."""
    cdr = [payload for chunk in payloads for payload in chunk]
    messages = [decode_cdr(payload, _POSE_ARRAY) for payload in cdr]
    poses = [(m.stamp_ns_of(message.header.stamp), pose.position) for message in messages for pose in message.poses]
    stamps = np.array([stamp for stamp, _ in poses], dtype=np.int64)
    xyz = np.array([(p.x, p.y, p.z) for _, p in poses], dtype=float).reshape(-1, 3)
    rows = Rows(stamps, {'detector_x_px': xyz[:, 0], 'detector_y_px': xyz[:, 1], 'hip': np.round(xyz[:, 2])})
    field = 'xy'[target.axis]

    def writer(new_values: np.ndarray) -> Callable[[list[memoryview]], list[bytes]]:
        values = iter(new_values.tolist())
        for message in messages:
            for pose in message.poses:
                setattr(pose.position, field, next(values))
        bodies = [bytes(TYPESTORE.serialize_cdr(message, _POSE_ARRAY, little_endian=True)) for message in messages]
        for body, original in zip(bodies, cdr):
            if len(body) != len(original):
                raise BagError(f'a {len(original)}-byte message of {target.topic} re-serializes to {len(body)} bytes '
                               '(trailing bytes?); sofia perturb needs CDR as a raw subscription delivers it')
        next_body = iter(bodies)
        return lambda chunk: [next(next_body) for _ in chunk]

    return _Recorded(rows, xyz[:, target.axis], writer)


def _gyro(payloads: Iterator[list[memoryview]], target: Observable) -> _Recorded:
    """Imu sample rows (file order) with their specific force, and the angular-velocity patcher."""
    stamps, rates, forces = [np.empty(0, np.int64)], [np.empty((0, 3))], [np.empty((0, 3))]
    for chunk in payloads:
        chunk_stamps, chunk_rates, chunk_forces = np.empty(len(chunk), np.int64), np.empty((len(chunk), 3)), \
            np.empty((len(chunk), 3))
        for index, block in _equal_length_blocks(chunk):
            chunk_stamps[index], chunk_rates[index], chunk_forces[index] = decode_imu_rows(block)
        stamps.append(chunk_stamps)
        rates.append(chunk_rates)
        forces.append(chunk_forces)
    stamps, rates, forces = (np.concatenate(parts) for parts in (stamps, rates, forces))
    rows = Rows(stamps, {f'specific_force_{axis}_m_per_s2': forces[:, k] for k, axis in enumerate('xyz')})

    def writer(new_values: np.ndarray) -> Callable[[list[memoryview]], list[bytes]]:
        new_rates = rates.copy()
        new_rates[:, target.axis] = new_values
        done = 0

        def replace(chunk: list[memoryview]) -> list[bytes]:
            nonlocal done
            bodies = [b''] * len(chunk)
            for index, block in _equal_length_blocks(chunk):
                patched = with_angular_velocity(block, new_rates[done + index])
                for row, body in zip(index.tolist(), patched):
                    bodies[row] = body.tobytes()
            done += len(chunk)
            return bodies

        return replace

    return _Recorded(rows, rates[:, target.axis], writer)


def _equal_length_blocks(payloads: list[memoryview]) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """(row indices, 2-D uint8 rows) per payload length, for bulk Imu decoding and patching."""
    lengths = np.fromiter(map(len, payloads), dtype=np.int64, count=len(payloads))
    for length in np.unique(lengths):
        index = np.flatnonzero(lengths == length)
        joined = b''.join(payloads[row] for row in index.tolist())
        yield index, np.frombuffer(joined, dtype=np.uint8).reshape(len(index), int(length))


def _check_new_directory(out: Path) -> None:
    """PerturbationError unless ``out`` is a new directory in an existing folder; OutputError if it cannot be
    looked at."""
    try:
        taken, folder_exists = out.exists(), out.parent.is_dir()
    except OSError as err:  # a name too long for the file system, a folder that cannot be searched
        raise output_error(out, err) from err
    if taken:
        raise PerturbationError(f'{out} already exists; pass a new directory for the perturbed bag '
                                '(sofia perturb never overwrites)')
    if not folder_exists:
        raise PerturbationError(f'folder {out.parent} of the output bag does not exist; create it first')


def _mcap_file(source: Path) -> Path:
    """The one .mcap file of a bag directory; BagError for split bags."""
    files = sorted(source.glob('*.mcap'))
    if len(files) != 1:
        raise BagError(f'bag {source} holds {len(files)} .mcap files; sofia perturb copies one-file bags '
                       '(merge a split bag with `rosbags-convert` first)')
    return files[0]


def _write_bag(source: Path, out: Path, mcap_path: Path, summary, channel_id: int,
               replace: Callable[[list[memoryview]], list[bytes]], result: Perturbation, target: Observable) -> None:
    """Build the new bag in a hidden sibling of ``out``, flush it to disk and rename it into place.

    On any error the sibling is removed, so ``out`` is either whole or absent; an OSError (disk
    full, read-only folder) becomes one OutputError naming ``out`` (exit 3 for a full disk, else 2).
    """
    previous = _source_perturbation(source)
    record = {**asdict(result), 'topic': target.topic, 'source_bag': str(source.resolve()),
              'note': 'added by sofia perturb to the recorded bag, outside the simulator; /truth is unchanged'}
    if previous is not None:
        record['source_perturbation'] = previous
    try:
        building = Path(tempfile.mkdtemp(prefix=f'.{out.name[:200]}.', suffix='.partial', dir=out.parent))
    except OSError as err:
        raise output_error(out, err) from err
    try:
        building.chmod(0o755)
        copy_mcap(mcap_path, building / mcap_path.name, summary, channel_id, replace)
        for path in sorted(source.iterdir()):
            if path.is_file() and path not in (mcap_path, source / PERTURBATION_FILE):
                shutil.copy2(path, building / path.name)
        (building / PERTURBATION_FILE).write_text(yaml.safe_dump(record, sort_keys=False))
        _flush_to_disk(building)
        if out.exists():
            raise PerturbationError(f'{out} appeared while the perturbed bag was written; pass a new directory')
        os.rename(building, out)
    except OSError as err:
        shutil.rmtree(building, ignore_errors=True)
        raise output_error(out, err) from err
    except BaseException:
        shutil.rmtree(building, ignore_errors=True)
        raise


def _source_perturbation(source: Path) -> object:
    """The perturbation record of a bag that is itself a perturbed copy, else None; ConfigError if it is unreadable."""
    path = source / PERTURBATION_FILE
    if not path.exists():
        return None
    return safe_load_limited(read_text_capped(path, MAX_CONFIG_BYTES, 'perturbation record'), str(path))


def _flush_to_disk(directory: Path) -> None:
    """fsync every file of ``directory`` and the directory itself, so that the rename publishes whole files."""
    for path in directory.iterdir():
        with open(path, 'rb') as file:
            os.fsync(file.fileno())
    descriptor = os.open(directory, os.O_RDONLY)
    try:
        os.fsync(descriptor)
    finally:
        os.close(descriptor)
