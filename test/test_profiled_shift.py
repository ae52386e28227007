"""The clock offset's grid (compare.fit._profiled_values) predicts only the rows the offset moves.

A HIPO clock offset moves HIPO's row times and nothing else, so the grid predicts HIPO's rows alone
(Predictor.predict_camera_px): on the Waco star hop 1800 of 123k rows; so does its column in each iteration
(WhitenedProblem.moved_rows_change). Checked here: one camera's rows predicted
alone equal predict_px's rows of that camera, and the grid's choice is that of the whole prediction's cost.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from sofia_ros.compare import fit
from sofia_ros.compare.observations import read_observations
from sofia_ros.compare.run import BagSource
from sofia_ros.config import parse_effect_config

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope='module')
def source(campaign_bags):
    text = (ROOT / 'config' / 'model' / 'nominal.yaml').read_text() + '  timestamp_offset: {offset_s: 0.2, fit: true}\n'
    model = parse_effect_config(text, 'nominal + timestamp_offset')
    return BagSource(read_observations(campaign_bags.reduced_alignment()), model)


def _anchors(source) -> np.ndarray:
    """Anchors of a few arcseconds, so that their interpolation at the row times counts."""
    rng = np.random.default_rng(7)
    return rng.normal(scale=2e-5, size=(source.predictor.anchor_count, 3))


def test_one_cameras_rows_predicted_alone_are_predict_pxs_rows(source):
    predictor, effects = source.predictor, {name: dict(params) for name, params in source.effects.items()}
    anchors = _anchors(source)
    everything = predictor.predict_px(effects, anchors)
    for camera, name in enumerate(predictor.observations.centroids.cameras):
        alone = predictor.predict_camera_px(effects, camera, anchors)
        # 1e-9 px: the same arithmetic on fewer rows, only summation order may differ.
        np.testing.assert_allclose(alone, everything[predictor.camera_rows(camera)], rtol=0, atol=1e-9, err_msg=name)


def test_the_shift_grid_chooses_what_the_whole_predictions_cost_chooses(source):
    predictor = source.predictor
    effects = {name: dict(params) for name, params in source.effects.items()}
    free = fit.free_parameters(['timestamp_offset'])
    problem = fit.WhitenedProblem(predictor, source.noise_arcsec, source.prior)
    anchors = _anchors(source)
    values = np.array([effects[p.effect][p.name] for p in free], dtype=float)
    grid = np.linspace(-0.5, 0.5, 21)
    cameras = fit._cameras_moved(problem, effects, free, values, 0, grid)
    assert [predictor.observations.centroids.cameras[c] for c in cameras] == ['hipo']
    alone = np.array([fit._shift_cost(problem, effects, free, np.array([value]), anchors, cameras) for value in grid])
    whole = np.array([fit._robust_cost(problem.whiten(predictor.predict_px(fit.with_values(effects, free, [value]),
                                                                           anchors))) for value in grid])
    # The other cameras' cost does not depend on the offset: the two differ by a constant.
    difference = whole - alone
    assert np.ptp(difference) <= 1e-9 * np.max(whole)
    assert np.argmin(alone) == np.argmin(whole)
    assert np.ptp(alone) > 1.0, 'the grid must span costs that differ, or the test chooses nothing'


@pytest.mark.parametrize('stepped', ['timestamp_offset.offset_s', 'atmospheric_refraction.pressure_hpa'])
def test_a_time_shifts_column_predicts_only_the_moved_cameras_and_equals_the_whole_predictions(source, stepped):
    """A step of the clock offset moves HIPO's rows alone (moved_rows_change); a refraction step moves every star."""
    predictor = source.predictor
    effects = {name: dict(params) for name, params in source.effects.items()}
    effect, name = stepped.split('.')
    parameter = fit.FreeParameter(effect, name, '', 1e-3 * max(abs(effects[effect][name]), 1.0))
    moved = {**effects, effect: {**effects[effect], name: effects[effect][name] + parameter.step}}
    problem = fit.WhitenedProblem(predictor, source.noise_arcsec, source.prior)
    anchors = _anchors(source)
    predicted = predictor.predict_px(effects, anchors)
    change = problem.moved_rows_change(effects, parameter, moved, anchors, predicted)
    whole = predictor.predict_px(moved, anchors) - predicted
    np.testing.assert_allclose(change, whole, rtol=0, atol=1e-9)
    changed_cameras = np.unique(predictor.observations.centroids.camera_index[np.any(change != 0, axis=1)])
    expected = ['hipo'] if effect == 'timestamp_offset' else list(predictor.observations.centroids.cameras)
    assert [predictor.observations.centroids.cameras[c] for c in changed_cameras] == expected
