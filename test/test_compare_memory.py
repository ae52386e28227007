"""What a comparison holds, hashes and computes again (issue 27): no refit outlives its use but the preferred one;
the bag's problem digest stands for the observations (by the observation cache's key where they came through the
cache, else by their bytes): it changes when an observation changes and not otherwise; a HIPO clock offset's new
value computes HIPO's star directions alone again, the same numbers.

The refits are counted on test_pipeline's linear fake source; the digests on the session's reduced alignment bag.
"""

import copy
import dataclasses
import gc
import shutil
import weakref
from pathlib import Path

import numpy as np
import pytest
from test_pipeline import FakeSource

from sofia_ros.compare.cache import CACHE_DIRECTORY, ObservationCache, bag_key
from sofia_ros.compare.fit import free_parameters
from sofia_ros.compare.observations import content_key, decode_observations, keyed
from sofia_ros.compare.pipeline import run_comparison
from sofia_ros.compare.predict import Predictor
from sofia_ros.compare.run import BagSource
from sofia_ros.config import load_effect_config, parse_effect_config
from sofia_ros.effects import resolve_params

ROOT = Path(__file__).resolve().parents[1]
NOMINAL = ROOT / 'config' / 'model' / 'nominal.yaml'


class CountedFits(FakeSource):
    """The fake source, each fit it returns watched through a weak reference."""

    def __init__(self, model):
        super().__init__(model)
        self.fits = []

    def fit(self, effects, free, start):
        fit = super().fit(effects, free, start)
        self.fits.append(weakref.ref(fit))
        return fit


def test_only_the_final_fit_and_the_preferred_refit_outlive_the_comparison():
    # The truth's gyro_bias and gyro_scale_factor both missing: both refitted, unrelated (not competing), so the
    # scale factor's refit is no contender and nothing needs it once its entry is written.
    model = parse_effect_config('effects: {accelerometer_bias: {fit: true}}', 'fake-model.yaml')
    source = CountedFits(model)
    outcome = run_comparison(source, model.effects,
                             candidate_names=('gyro_bias', 'gyro_scale_factor'))
    refined = [c['effect'] for c in outcome.document['candidates'] if c['refined']]
    assert sorted(refined) == ['gyro_bias', 'gyro_scale_factor'] and outcome.best_name == 'gyro_bias'
    gc.collect()
    alive = [fit for fit in (reference() for reference in source.fits) if fit is not None]
    assert sorted(map(id, alive)) == sorted({id(outcome.final_fit), id(outcome.best_fit)})
    assert not hasattr(outcome, 'refits') and not hasattr(outcome, 'linearized')


class WatchedTerms(FakeSource):
    """The fake source, the candidates' linearized terms it returns watched; at each fit, how many are alive."""

    def __init__(self, model):
        super().__init__(model)
        self.terms = []
        self.alive_at_fits = []

    def linearize(self, fit, names):
        linearized, unseen = super().linearize(fit, names)
        self.terms += [weakref.ref(candidate.term) for candidate in linearized]
        return linearized, unseen

    def fit(self, effects, free, start):
        gc.collect()
        self.alive_at_fits.append(sum(reference() is not None for reference in self.terms))
        return super().fit(effects, free, start)


def test_the_candidates_columns_are_let_go_before_the_refits():
    # Their columns (about 190 MB on a star hop) serve the ranking and the linearized models; a refit holds its own.
    model = parse_effect_config('effects: {accelerometer_bias: {fit: true}}', 'fake-model.yaml')
    source = WatchedTerms(model)
    outcome = run_comparison(source, model.effects, candidate_names=('gyro_bias', 'gyro_scale_factor'))
    assert any(c['refined'] for c in outcome.document['candidates']) and source.terms
    assert source.alive_at_fits and max(source.alive_at_fits) == 0


@pytest.fixture(scope='module')
def decoded(campaign_bags):
    return decode_observations(campaign_bags.reduced_alignment())


@pytest.fixture(scope='module')
def nominal():
    return load_effect_config(str(NOMINAL))


def test_a_released_fit_holds_no_columns_and_takes_the_same_again(decoded, nominal, monkeypatch):
    # A gyro term (the attitude part of the columns) and a camera term (the reprojection part).
    source = BagSource(decoded, nominal)
    terms = ('gyro_bias', 'hipo_fiducial_error')
    effects = {**source.ledger_start(None, None), **{name: resolve_params(name, {}) for name in terms}}
    fit = source._fitted(effects, free_parameters(terms), None)
    released = fit.released()
    assert released.bic == fit.bic and released.parameter_count == fit.parameter_count
    assert '_columns' not in vars(released)  # nor did the BIC need them
    anchors, columns = released.anchor_columns, released.parameter_columns
    for name in ('data', 'indices', 'indptr'):
        np.testing.assert_array_equal(getattr(anchors, name), getattr(fit.anchor_columns, name), strict=True)
    np.testing.assert_array_equal(columns, fit.parameter_columns, strict=True)
    # BagSource.fit (the refits' and the checked changes') hands the comparison released fits.
    monkeypatch.setattr(BagSource, '_fitted', lambda self, effects, free, start: fit)
    assert '_columns' not in vars(source.fit(effects, free_parameters(terms), None))


def _digest(observations, model):
    return BagSource(observations, model).problem_digest


def _with_measured(observations, measured_px):
    return dataclasses.replace(observations, centroids=dataclasses.replace(observations.centroids,
                                                                           measured_px=measured_px))


def test_the_digest_of_observations_without_a_key_changes_with_any_observation_and_not_otherwise(decoded, nominal):
    digest = _digest(decoded, nominal)
    assert _digest(dataclasses.replace(decoded, bag_path=Path('elsewhere')), nominal) == digest
    nudged = decoded.centroids.measured_px.copy()
    nudged[-1, 1] += 1e-9
    assert _digest(_with_measured(decoded, nudged), nominal) != digest


def test_keyed_observations_digest_by_their_key_are_read_only_and_a_changed_copy_has_none(decoded, nominal):
    first = keyed(copy.deepcopy(decoded), 'a' * 64)  # a copy: keyed makes the arrays read-only
    same_bag = keyed(dataclasses.replace(first, bag_path=Path('again')), 'a' * 64)
    assert content_key(first) == 'a' * 64 and _digest(first, nominal) == _digest(same_bag, nominal)
    assert _digest(first, nominal) != _digest(decoded, nominal)  # by the key, not by the bytes
    with pytest.raises(ValueError, match='read-only'):
        first.centroids.measured_px[0, 0] = 0.0
    nudged = first.centroids.measured_px.copy()
    nudged[-1, 1] += 1e-9
    changed = _with_measured(first, nudged)
    assert content_key(changed) is None and _digest(changed, nominal) != _digest(first, nominal)


def test_observations_through_the_cache_carry_the_bag_key_and_a_changed_bag_another(decoded, tmp_path, monkeypatch):
    bag = Path(shutil.copytree(decoded.bag_path, tmp_path / 'bag', ignore=shutil.ignore_patterns(CACHE_DIRECTORY)))
    monkeypatch.setenv('XDG_CACHE_HOME', str(tmp_path / 'xdg'))
    cache = ObservationCache(warn=lambda line: None)
    from_decoding = cache.read(bag, lambda path: copy.deepcopy(decoded))
    from_file = cache.read(bag, lambda path: pytest.fail('the cache file was not used'))
    assert content_key(from_decoding) == content_key(from_file) == bag_key(bag)
    np.testing.assert_array_equal(from_file.centroids.measured_px, decoded.centroids.measured_px)
    with (bag / 'metadata.yaml').open('a') as metadata:
        metadata.write('\n')  # read again, the bag's observations would be decoded and keyed anew
    assert bag_key(bag) != content_key(from_file)


def test_a_clock_offset_computes_hipos_star_directions_alone_again_the_same(decoded, monkeypatch):
    predictor = Predictor(decoded)
    effects = {name: resolve_params(name, {}) for name in ('earth_rotation', 'atmospheric_refraction',
                                                            'timestamp_offset')}
    hipo = decoded.centroids.cameras.index('hipo')
    computed = []
    real = Predictor._directions_of

    def directions_of(self, effects, hip_rows, times_s):
        computed.append(len(hip_rows))
        return real(self, effects, hip_rows, times_s)

    monkeypatch.setattr(Predictor, '_directions_of', directions_of)
    for offset_s in (0.0, 0.25):
        effects['timestamp_offset']['offset_s'] = offset_s
        times = predictor.row_times_s(effects)
        np.testing.assert_array_equal(predictor._directions(effects, times),
                                      predictor._star_directions(effects, times), strict=True)
    hipo_rows = int(np.sum(decoded.centroids.camera_index == hipo))
    # the first offset: every camera, then the whole for the check; the second: HIPO alone, then the whole
    assert computed[len(decoded.centroids.cameras) + 1:] == [hipo_rows, len(decoded.centroids)]
