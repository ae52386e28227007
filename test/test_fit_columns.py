"""The fit's parameter columns are the derivatives of the prediction (compare.fit.WhitenedProblem.parameter_columns).

Each column of a gyro parameter comes from the attitude change its step makes, through the derivative against the
anchors' rotation. That change composes with each row's anchor rotation a, so it enters through the inverse right
Jacobian at a; taken as a change of a itself it was off by about |a|. The Waco 2004 star hop's anchors reach 0.5
deg, its gyro columns were 0.8 % off, and the fits converged where those wrong columns said the gradient vanished
(round 1 of its loop: 0.9 sigma from the minimum) or could not descend at all (a field rotation's refit stuck at
delta-BIC -12539 where it reaches +325001). Checked here against central differences of the whole prediction on the
session's reduced alignment bag, at anchors of 0.5 deg and at none.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse

from sofia_ros.compare import fit
from sofia_ros.compare.observations import read_observations
from sofia_ros.compare.run import BagSource
from sofia_ros.config import load_effect_config

ROOT = Path(__file__).resolve().parents[1]
#: A column may differ from the central difference by this fraction of its norm: the forward-difference steps of
#: the IRF derivative (1e-6 rad) and of the parameters (1e-3 of their scale) leave about 1e-5.
COLUMN_TOLERANCE = 1e-4


@pytest.fixture(scope='module')
def source(campaign_bags):
    model = load_effect_config(str(ROOT / 'config' / 'model' / 'nominal.yaml'))
    return BagSource(read_observations(campaign_bags.reduced_alignment()), model)


@pytest.mark.parametrize('anchor_deg', [0.0, 0.5], ids=['no-anchors', 'anchors-of-half-a-degree'])
def test_each_gyro_column_is_the_central_difference_of_the_prediction(source, anchor_deg):
    predictor = source.predictor
    problem = fit.WhitenedProblem(predictor, source.noise_arcsec, source.prior)
    effects = {name: dict(params) for name, params in source.effects.items()}
    free = fit.free_parameters(['gyro_misalignment', 'gyro_bias'])
    values = np.array([effects[p.effect][p.name] for p in free], dtype=float)
    # Anchors that turn slowly through +-anchor_deg about every axis, as a large absorbed attitude error does.
    phase = np.linspace(0.0, np.pi, predictor.anchor_count)[:, None] + np.array([0.0, 2.0, 4.0])
    anchors = np.radians(anchor_deg) * np.sin(phase)
    predicted = predictor.predict_px(effects, anchors)
    derivative = problem.irf_derivative(effects, anchors, predicted)
    columns = problem.parameter_columns(effects, free, values, anchors, predicted, derivative)
    for index, parameter in enumerate(free):
        up, down = values.copy(), values.copy()
        up[index] += parameter.step
        down[index] -= parameter.step
        central = problem.scaled(predictor.predict_px(fit.with_values(effects, free, up), anchors)
                                 - predictor.predict_px(fit.with_values(effects, free, down), anchors)) / (
            2.0 * parameter.step)
        error = np.linalg.norm(columns[:, index] - central) / np.linalg.norm(central)
        assert error < COLUMN_TOLERANCE, f'{parameter.label}: column off by {error:.1e} of its norm'


def _general_gram(columns, weights):
    """A^T diag(w) A by scipy's general sparse product: the independent computation."""
    return (columns.T @ scipy.sparse.diags(weights) @ columns).toarray()


def test_the_anchor_gram_knot_by_knot_is_scipys_sparse_product(source):
    predictor = source.predictor
    problem = fit.WhitenedProblem(predictor, source.noise_arcsec, source.prior)
    effects = {name: dict(params) for name, params in source.effects.items()}
    anchors = np.zeros((predictor.anchor_count, 3))
    predicted = predictor.predict_px(effects, anchors)
    columns = problem.anchor_columns(effects, problem.irf_derivative(effects, anchors, predicted))
    rng = np.random.default_rng(5)
    # Huber weights in (0, 1] and their corrections w - 1 on the rows beyond k (negative), as gram_of takes them.
    weights = rng.uniform(0.0, 1.0, columns.shape[0])
    beyond = np.flatnonzero(weights < 0.1)
    for rows, row_weights in ((slice(None), weights), (beyond, weights[beyond] - 1.0)):
        expected = _general_gram(columns[rows], row_weights)
        gram = fit.anchor_gram(columns[rows], row_weights)
        assert np.max(np.abs(gram - expected)) <= 1e-12 * np.max(np.abs(expected))


def test_columns_of_another_sparsity_take_the_general_product():
    rng = np.random.default_rng(6)
    columns = scipy.sparse.random(400, 12, density=0.3, format='csr', random_state=rng)
    weights = rng.uniform(0.5, 1.5, 400)
    np.testing.assert_allclose(fit.anchor_gram(columns, weights), _general_gram(columns, weights), rtol=1e-12,
                               atol=0.0)
