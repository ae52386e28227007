"""The ledger's chain kept (compare.steps): a step fitted once is read back by the chains that share it, from memory
or from the bag's cache folder, and gives the ledger and the fit a fresh chain gives; a damaged, foreign or
unwritable step file is fitted again with one line; a bag decoded anew drops its steps; without an observation cache
nothing is written.

Fits are counted through compare.run.BagSource._fitted (every fit of a bag, the chain's and BagSource.fit's) on the
session's reduced alignment bag, decoded once.
"""

import collections
import json
import re
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest

from sofia_ros.compare.cache import CACHE_DIRECTORY, ObservationCache
from sofia_ros.compare.cache_files import write_members
from sofia_ros.compare.fit import free_parameters
from sofia_ros.compare.observations import decode_observations, observation_cache, read_observations, step_store
from sofia_ros.compare.pipeline import _ledger
from sofia_ros.compare.run import BagSource
from sofia_ros.compare.steps import STEP_FILE_PREFIX, ChainStep, StepStore
from sofia_ros.config import load_effect_config
from sofia_ros.progress import Progress

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = ROOT / 'config' / 'model' / 'nominal.yaml'
#: The nominal model with only its gyro misalignment fitted: its chain is the nominal model's first two steps.
MISALIGNMENT_ONLY = """\
effects:
  earth_rotation: {}
  atmospheric_refraction: {}
  focal_plane_flexure: {}
  imager_flexure: {}
  gyro_misalignment: {fit: true}
"""


@pytest.fixture(scope='module')
def decoded(campaign_bags):
    return decode_observations(campaign_bags.reduced_alignment())


@pytest.fixture(autouse=True)
def empty_memory(monkeypatch):
    """Each test starts with no step in memory (the store's memory is the process's)."""
    monkeypatch.setattr(StepStore, '_memory', collections.OrderedDict())


@pytest.fixture
def fits(monkeypatch):
    """The number of fits BagSource runs."""
    counted = []
    real = BagSource._fitted

    def fitted(self, effects, free, start):
        counted.append([p.label for p in free])
        return real(self, effects, free, start)

    monkeypatch.setattr(BagSource, '_fitted', fitted)
    return counted


def _chain(observations, model, store):
    return _ledger(BagSource(observations, model, steps=store), Progress.silent())


def _step(key_free=('gyro_bias',)):
    free = free_parameters(key_free)
    effects = {'earth_rotation': {'rate_deg_per_h': 15.0411}, 'gyro_bias': {p.name: 0.25 for p in free},
               'vibration': {'lines': [[1.5, 2.0]], 'name': 'x'}}
    return ChainStep(effects, free, np.arange(12, dtype=float).reshape(4, 3) * 1e-6, 1234.5,
                     {'term': 'gyro_bias', 'residual_rms_arcsec': {'total': 0.5}, 'bic': 1234.5})


def test_a_step_is_fitted_once_and_a_chain_sharing_it_reads_it_back(decoded, fits, tmp_path):
    nominal = load_effect_config(str(NOMINAL))
    rows, fit = _chain(decoded, nominal, StepStore(tmp_path))
    assert len(fits) == 3  # fixed effects, + gyro_misalignment, + gyro_bias (the last): each kept
    assert len(list(tmp_path.glob(f'{STEP_FILE_PREFIX}*.npz'))) == 3
    again_rows, again = _chain(decoded, nominal, StepStore(tmp_path))
    assert len(fits) == 4  # only the last step fitted again: its whole fit is the comparison's
    assert again_rows == rows
    assert np.array_equal(again.values, fit.values) and np.array_equal(again.anchors_rad, fit.anchors_rad)
    # A chain sharing the first step: the misalignment is its last step, fitted from the kept fixed-effects step.
    shorter = tmp_path / 'misalignment-only.yaml'
    shorter.write_text(MISALIGNMENT_ONLY)
    shorter_rows, _ = _chain(decoded, load_effect_config(str(shorter)), StepStore(tmp_path))
    assert fits[4:] == [[p.label for p in free_parameters(['gyro_misalignment'])]]
    assert shorter_rows == rows[:2]
    # The loop's next round, a term added: the nominal model's steps, its last one too, are read back.
    longer = tmp_path / 'nominal-and-scale-factor.yaml'
    longer.write_text(NOMINAL.read_text() + '  gyro_scale_factor: {fit: true}\n')
    longer_rows, _ = _chain(decoded, load_effect_config(str(longer)), StepStore(tmp_path))
    assert len(fits) == 6 and 'gyro_scale_factor.el_ppm' in fits[5]
    assert longer_rows[:3] == rows


def test_steps_on_disk_give_the_ledger_and_fit_of_a_fresh_chain(decoded, fits, tmp_path, monkeypatch):
    nominal = load_effect_config(str(NOMINAL))
    rows, fit = _chain(decoded, nominal, StepStore(tmp_path))
    monkeypatch.setattr(StepStore, '_memory', collections.OrderedDict())  # another process: the disk alone
    from_disk_rows, from_disk = _chain(decoded, nominal, StepStore(tmp_path))
    assert len(fits) == 4
    assert from_disk_rows == rows
    assert np.array_equal(from_disk.values, fit.values) and np.array_equal(from_disk.sigma, fit.sigma)
    assert from_disk.bic == fit.bic


def test_a_step_round_trips_through_its_file(tmp_path, monkeypatch):
    step = _step()
    StepStore(tmp_path).put('a' * 64, step)
    monkeypatch.setattr(StepStore, '_memory', collections.OrderedDict())
    kept = StepStore(tmp_path).get('a' * 64, step.free)
    assert kept.effects == step.effects and repr(kept.effects) == repr(step.effects)
    assert kept.free == step.free and kept.bic == step.bic and kept.row == step.row
    assert np.array_equal(kept.anchors_rad, step.anchors_rad)


def test_a_step_whose_effects_json_cannot_give_back_is_kept_in_memory_only(tmp_path):
    step = _step()
    step.effects['gyro_bias']['el_deg_per_h'] = (0.1, 0.2)  # a tuple comes back from JSON as a list
    store = StepStore(tmp_path)
    store.put('b' * 64, step)
    assert not list(tmp_path.iterdir())
    assert store.get('b' * 64, step.free) is step


def _damaged_truncated(path):
    path.write_bytes(path.read_bytes()[:100])


def _damaged_compressed(path):
    with zipfile.ZipFile(path) as archive:
        members = {name: archive.read(name) for name in archive.namelist()}
    with zipfile.ZipFile(path, 'w', compression=zipfile.ZIP_DEFLATED) as archive:
        for name, data in members.items():
            archive.writestr(name, data)


def _written_again(path, **members):
    """The step file rewritten as a writer would (its members fingerprinted anew) with ``members`` in place of its
    arrays: what the reader's own checks of a step then refuse."""
    with np.load(path) as archive:
        header = json.loads(archive['header'].tobytes())
    header.pop('member_fingerprints')
    write_members(path, header, members)


def _damaged_anchors(path):
    _written_again(path, anchors_rad=np.zeros((4, 2)))


def _damaged_extra_member(path):
    with np.load(path) as archive:
        anchors = archive['anchors_rad']
    _written_again(path, anchors_rad=anchors, extra=np.zeros(3))


def _anchors_saved_again_cut(path):
    # Saved over the header it had, its zip CRCs right: the anchors of another anchor spacing gave an IndexError.
    with np.load(path) as archive:
        header, anchors = archive['header'], archive['anchors_rad']
    np.savez(path, header=header, anchors_rad=anchors[:-1])


@pytest.mark.parametrize(('damage', 'message'), [
    (_damaged_truncated, r'unreadable: BadZipFile'),
    (_damaged_compressed, r'holds compressed members'),
    (_damaged_anchors, r'anchors are not a \(K, 3\) array'),
    (_damaged_extra_member, r"members are not a step's"),
    (_anchors_saved_again_cut, r'its arrays are not those it was written with'),
], ids=['truncated', 'compressed', 'anchors-of-another-shape', 'another-member', 'anchors-saved-again-cut'])
def test_a_damaged_step_file_is_removed_and_fitted_again_with_one_line(tmp_path, monkeypatch, damage, message):
    step = _step()
    StepStore(tmp_path).put('c' * 64, step)
    path = tmp_path / f'{STEP_FILE_PREFIX}{"c" * 64}.npz'
    damage(path)
    monkeypatch.setattr(StepStore, '_memory', collections.OrderedDict())
    lines = []
    assert StepStore(tmp_path, warn=lines.append).get('c' * 64, step.free) is None
    assert len(lines) == 1
    assert lines[0].startswith('sofia compare: ignored the fit cache') and 'fitted the step again' in lines[0]
    assert re.search(message, lines[0])
    assert not path.exists()


def test_a_step_file_of_another_key_or_other_parameters_is_not_used(tmp_path, monkeypatch):
    step = _step()
    StepStore(tmp_path).put('d' * 64, step)
    (tmp_path / f'{STEP_FILE_PREFIX}{"d" * 64}.npz').rename(tmp_path / f'{STEP_FILE_PREFIX}{"e" * 64}.npz')
    StepStore(tmp_path).put('f' * 64, step)
    monkeypatch.setattr(StepStore, '_memory', collections.OrderedDict())
    lines = []
    store = StepStore(tmp_path, warn=lines.append)
    assert store.get('e' * 64, step.free) is None
    assert store.get('f' * 64, free_parameters(['gyro_misalignment'])) is None
    assert [line.split('(')[-1] for line in lines] == ["its header is for another step); fitted the step again",
                                                       "its parameters are not the step's); fitted the step again"]


def test_an_unwritable_folder_keeps_the_step_in_memory_with_one_line(tmp_path):
    blocked = tmp_path / 'file'
    blocked.write_text('not a folder')
    lines = []
    store = StepStore(blocked, warn=lines.append)
    step = _step()
    store.put('g' * 64, step)
    assert len(lines) == 1 and lines[0].startswith('sofia compare: cannot keep a fitted step in')
    assert store.get('g' * 64, step.free) is step


def test_the_store_of_a_bag_is_its_cache_folder_and_a_bag_decoded_anew_drops_its_steps(decoded, tmp_path,
                                                                                        monkeypatch):
    bag = Path(shutil.copytree(decoded.bag_path, tmp_path / 'bag', ignore=shutil.ignore_patterns(CACHE_DIRECTORY)))
    monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path / 'xdg'))
    assert step_store(bag).folder is None  # no observation cache active: memory only (--no-cache)
    with observation_cache(ObservationCache(warn=print)):
        read_observations(bag)
        store = step_store(bag)
    assert store.folder == bag / CACHE_DIRECTORY
    store.put('h' * 64, _step())
    assert len(list(store.folder.glob(f'{STEP_FILE_PREFIX}*.npz'))) == 1
    with (bag / 'metadata.yaml').open('a') as metadata:
        metadata.write('\n')  # the bag changed: its observations are decoded again
    with observation_cache(ObservationCache(warn=lambda line: None)):
        read_observations(bag)
    assert not list(store.folder.glob(f'{STEP_FILE_PREFIX}*.npz'))
