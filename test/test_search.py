"""The model search (issue 25): linearized models against a direct least-squares solve, and the stepwise moves."""

import numpy as np
import pytest
import scipy.sparse

from sofia_ros.analysis.ranking import CandidateTerm
from sofia_ros.compare.fit import free_parameters
from sofia_ros.compare.search import (EMPIRICAL_PENALTY, LinearizedModels, equivalent_models, model_terms,
                                      structural_changes)

ROWS = 3000
ANCHORS = 6


def _best_change(models, current):
    """The best change structural_changes proposes, or None."""
    return next(iter(structural_changes(models, current)), None)


def _problem(truth, model_terms=('gyro_bias',), seed=7):
    """A residual of the fitted 'model' built from column shapes; ``truth`` maps a shape name to its amplitude.

    Shapes: gyro_bias (in the model, fitted at 1.0 of the truth's 1.0), tracker_drift, hipo_fiducial_error,
    imager_boresight_offset (nearly the fiducial error's shape) and an empirical shape equal to the drift's.
    """
    rng = np.random.default_rng(seed)
    shapes = {name: rng.standard_normal(ROWS) for name in ('gyro_bias', 'tracker_drift', 'hipo_fiducial_error')}
    shapes['imager_boresight_offset'] = shapes['hipo_fiducial_error'] + 0.02 * rng.standard_normal(ROWS)
    shapes['empirical:fpi.x:time:period_312s'] = shapes['tracker_drift'].copy()
    nuisance = scipy.sparse.csr_matrix(rng.standard_normal((ROWS, ANCHORS)))
    signal = sum(amplitude * shapes[name] for name, amplitude in truth.items() if name not in model_terms)
    residual = signal + rng.standard_normal(ROWS)
    # One parameter of each term (its first scaling one): the shapes stand for its column.
    free = tuple(free_parameters([name])[0] for name in model_terms)
    values = np.ones(len(free))
    jacobian = scipy.sparse.hstack([nuisance, scipy.sparse.csr_matrix(
        np.column_stack([shapes[name] for name in model_terms]))], format='csr')
    candidates = [CandidateTerm(name, ('el_deg_per_h',), np.zeros(1), shapes[name][:, None])
                  for name in shapes if name not in model_terms]
    return residual, jacobian, free, values, candidates, shapes, nuisance


def test_a_linearized_model_has_the_rss_of_a_direct_solve():
    residual, jacobian, free, values, candidates, shapes, nuisance = _problem(
        {'gyro_bias': 1.0, 'tracker_drift': 0.3})
    models = LinearizedModels.at_fit(residual, jacobian, free, values, ANCHORS, candidates)
    # gyro_bias switched off (its part back in the residual), tracker_drift on: a direct lstsq of the same problem.
    target = residual + shapes['gyro_bias'] * 1.0
    design = np.column_stack([nuisance.toarray(), shapes['tracker_drift']])
    solution, *_ = np.linalg.lstsq(design, target, rcond=None)
    direct = float(np.sum((target - design @ solution) ** 2))
    assert models.rss({'tracker_drift'}) == pytest.approx(direct, rel=1e-9)
    design = np.column_stack([nuisance.toarray(), shapes['gyro_bias'], shapes['tracker_drift']])
    solution, *_ = np.linalg.lstsq(design, target, rcond=None)
    assert models.rss({'gyro_bias', 'tracker_drift'}) == pytest.approx(float(np.sum((target - design @ solution) ** 2)),
                                                                       rel=1e-9)


def _mimicking_model(truth):
    """The model holds the boresight offset, fitted (at 0.5) to what the fiducial error of the truth leaves."""
    residual, jacobian, free, values, candidates, shapes, nuisance = _problem(
        truth, model_terms=('gyro_bias', 'imager_boresight_offset'))
    return (residual - 0.5 * shapes['imager_boresight_offset'], jacobian, free, np.array([1.0, 0.5]), candidates,
            shapes)


def test_a_term_that_mimics_the_truth_is_replaced():
    residual, jacobian, free, values, candidates, _ = _mimicking_model({'gyro_bias': 1.0, 'hipo_fiducial_error': 0.5})
    models = LinearizedModels.at_fit(residual, jacobian, free, values, ANCHORS, candidates)
    change = _best_change(models, {'gyro_bias', 'imager_boresight_offset'})
    assert (change['action'], change['term'], change['effect']) == ('replace', 'imager_boresight_offset',
                                                                   'hipo_fiducial_error')
    # The linearized gain is the BIC difference itself.
    assert change['expected_delta_bic'] == pytest.approx(
        models.bic({'gyro_bias', 'imager_boresight_offset'}) - models.bic({'gyro_bias', 'hipo_fiducial_error'}))
    [bias, boresight] = model_terms(models, {'gyro_bias', 'imager_boresight_offset'})
    assert bias['pays'] and bias['rivals'] == []
    assert boresight['pays'] and boresight['rivals'][0]['effect'] == 'hipo_fiducial_error'
    assert boresight['rivals'][0]['shared_fraction'] > 0.99


def test_a_term_the_data_do_not_need_is_removed():
    residual, jacobian, free, values, candidates, shapes = _mimicking_model({'gyro_bias': 1.0})
    # The boresight term was fitted to nothing: value 0, residual pure noise.
    residual = residual + 0.5 * shapes['imager_boresight_offset']
    models = LinearizedModels.at_fit(residual, jacobian, free, np.array([1.0, 0.0]), ANCHORS, candidates)
    change = _best_change(models, {'gyro_bias', 'imager_boresight_offset'})
    assert (change['action'], change['term'], change['effect']) == ('remove', 'imager_boresight_offset', None)
    assert not model_terms(models, {'gyro_bias', 'imager_boresight_offset'})[1]['pays']


def test_physics_wins_a_tie_with_the_empirical_shape_that_mimics_it():
    residual, jacobian, free, values, candidates, _, _ = _problem({'gyro_bias': 1.0, 'tracker_drift': 0.3},
                                                                  model_terms=('gyro_bias', 'tracker_drift'))
    values = np.array([1.0, 0.3])
    models = LinearizedModels.at_fit(residual, jacobian, free, values, ANCHORS, candidates)
    # The shape is the drift's own: swapping them changes nothing but the preference.
    assert _best_change(models, {'gyro_bias', 'tracker_drift'}) is None
    gap = models.bic({'gyro_bias', 'empirical:fpi.x:time:period_312s'}) - models.bic({'gyro_bias', 'tracker_drift'})
    assert gap == pytest.approx(EMPIRICAL_PENALTY, abs=1e-6)
    equivalent = {entry['model'] for entry in equivalent_models(models, {'gyro_bias', 'tracker_drift'})}
    assert 'empirical:fpi.x:time:period_312s instead of tracker_drift' in equivalent


def test_a_model_that_holds_the_truth_is_left_as_it_is():
    residual, jacobian, free, values, candidates, _, _ = _problem({'gyro_bias': 1.0})
    models = LinearizedModels.at_fit(residual, jacobian, free, values, ANCHORS, candidates)
    assert _best_change(models, {'gyro_bias'}) is None
    assert equivalent_models(models, {'gyro_bias'}) == []


def test_the_models_of_a_part_of_the_candidates_are_the_part_of_the_models_of_all():
    residual, jacobian, free, values, candidates, _, _ = _problem({'gyro_bias': 1.0, 'tracker_drift': 0.3})
    every = LinearizedModels.at_fit(residual, jacobian, free, values, ANCHORS, candidates)
    part = ['hipo_fiducial_error', 'empirical:fpi.x:time:period_312s']
    direct = LinearizedModels.at_fit(residual, jacobian, free, values, ANCHORS,
                                     [term for term in candidates if term.name in part])
    restricted = every.restricted_to(part)
    assert restricted.names == direct.names == ('gyro_bias', *part)
    assert (restricted.in_model, restricted.widths, restricted.parameters) == (
        direct.in_model, direct.widths, direct.parameters)
    np.testing.assert_allclose(restricted.gram, direct.gram, rtol=1e-12, atol=1e-9)
    for chosen in ({'gyro_bias'}, {'hipo_fiducial_error'}, {'gyro_bias', 'empirical:fpi.x:time:period_312s'}):
        assert restricted.bic(chosen) == pytest.approx(direct.bic(chosen), rel=1e-12)
