"""The compare's faster paths against independent computations of the same numbers (issue 27)."""

import numpy as np
import pytest
import scipy.sparse

from sofia_ros.compare.predict import inverse_right_jacobians, right_jacobians


@pytest.mark.parametrize('scale', [0.0, 1e-9, 1e-5, 1e-4, 1e-3, 0.01, 0.5, 3.0])
def test_inverse_right_jacobians_are_the_inverses_of_the_right_jacobians(scale):
    directions = np.random.default_rng(7).normal(size=(200, 3))
    rotvecs = scale * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    # The series branch below |phi| = 1e-4, the closed form above it, both against LAPACK's inverse.
    np.testing.assert_allclose(inverse_right_jacobians(rotvecs), np.linalg.inv(right_jacobians(rotvecs)),
                               rtol=0, atol=1e-12)


def _synthetic_fit(rows=400, knots=6, parameters=3, seed=5):
    """A ModelFit of random whitened columns shaped as a bag's (two anchor knots per row, dense parameters)."""
    from sofia_ros.compare.fit import ModelFit
    from sofia_ros.compare.prior import anchor_prior

    rng = np.random.default_rng(seed)
    knots_s = np.linspace(0.0, 150.0, knots)
    prior = anchor_prior(knots_s, np.broadcast_to(np.eye(3), (knots - 1, 3, 3)), 1e-5, 1e-7)
    interval = np.repeat(rng.integers(0, knots - 1, rows), 2)
    indices = (3 * interval[:, None] + np.arange(6)).ravel()
    anchor_columns = scipy.sparse.csr_matrix((rng.normal(size=12 * rows), indices, np.arange(0, 12 * rows + 1, 6)),
                                             shape=(2 * rows, 3 * knots))
    whitened = rng.normal(size=2 * rows) * 2.0
    weights = np.where(np.abs(whitened) <= 3.0, 1.0, 3.0 / np.abs(whitened))
    fit = ModelFit({}, (), np.zeros(parameters), np.ones(parameters), np.eye(parameters), np.zeros((knots, 3)),
                   np.zeros((rows, 2)), whitened, rng.normal(size=3 * (knots - 1)), prior, weights,
                   np.zeros(rows, dtype=bool), 1, None)
    fit.__dict__['_columns'] = (anchor_columns, rng.normal(size=(2 * rows, parameters)))
    return fit, rng


@pytest.mark.parametrize('share', [0.1, 0.5, 0.9])
def test_split_normal_equations_are_those_of_each_half(share):
    from sofia_ros.compare.fit import normal_equations

    fit, rng = _synthetic_fit()
    rows = rng.random(fit.whitened.size) < share
    step = rng.normal(size=fit.weighted_normal_equations[0].shape[0])
    for half, mask in zip(fit.split_normal_equations(rows), (rows, ~rows)):
        # The half computed alone, each row weighted as the fit weights it (Huber) or not at all.
        gram, gradient, rss_after = normal_equations(fit.anchor_columns, fit.parameter_columns, fit.anchor_prior,
                                                     fit.whitened, fit.weights * mask, fit.prior_residual)
        scale = np.abs(fit.weighted_normal_equations[0]).max()
        np.testing.assert_allclose(half[0], gram, rtol=0, atol=1e-12 * scale)
        np.testing.assert_allclose(half[1], gradient, rtol=0, atol=1e-12 * np.abs(gradient).max())
        assert half[2](step) == pytest.approx(rss_after(step), rel=1e-12)


def test_a_parameter_the_larger_half_lacks_has_an_exact_zero_there():
    # A camera's term: its column is zero outside that camera's rows, the split's smaller half. Rows enough that
    # BLAS sums the whole and the half in another order (their difference is then rounding, not zero).
    fit, rng = _synthetic_fit(rows=20000, parameters=13)
    rows = np.repeat(rng.random(20000) < 0.1, 2)
    fit.parameter_columns[~rows, 0] = 0.0
    _, others = fit.split_normal_equations(rows)
    column = fit.anchor_columns.shape[1]
    assert np.all(others[0][column, :] == 0.0) and np.all(others[0][:, column] == 0.0) and others[1][column] == 0.0
    assert np.all(np.diag(others[0])[column + 1:] > 0.0)


def test_normal_equations_in_bands_are_the_dense_weighted_products(monkeypatch):
    from sofia_ros.analysis import ranking
    from sofia_ros.compare import fit as fit_module

    fit, _ = _synthetic_fit(rows=50, parameters=4)
    # Bands of 7 rows: the last one short (100 data rows), so that the bands' sum is exercised.
    monkeypatch.setattr(ranking, 'GRAM_BAND_ROWS', 7)
    gram, gradient, _ = fit_module.normal_equations(fit.anchor_columns, fit.parameter_columns, fit.anchor_prior,
                                                    fit.whitened, fit.weights, fit.prior_residual)
    data = np.hstack([fit.anchor_columns.toarray(), fit.parameter_columns])
    prior_matrix = fit.anchor_prior.matrix
    prior_matrix = prior_matrix.toarray() if scipy.sparse.issparse(prior_matrix) else np.asarray(prior_matrix)
    prior = np.hstack([prior_matrix, np.zeros((prior_matrix.shape[0], 4))])
    expected = data.T @ (fit.weights[:, None] * data) + prior.T @ prior
    np.testing.assert_allclose(gram, expected, rtol=0, atol=1e-12 * np.abs(expected).max())
    np.testing.assert_allclose(gradient, data.T @ (fit.weights * fit.whitened) + prior.T @ fit.prior_residual,
                               rtol=0, atol=1e-12 * np.abs(gradient).max())


def test_the_gram_matrix_of_some_rows_is_that_of_their_copy_bit_for_bit(monkeypatch):
    from sofia_ros.analysis import ranking
    from sofia_ros.compare import fit as fit_module

    fit, rng = _synthetic_fit(rows=60, parameters=4)
    monkeypatch.setattr(ranking, 'GRAM_BAND_ROWS', 7)  # the subset's bands, the last one short
    rows = np.flatnonzero(rng.random(fit.whitened.size) < 0.4)
    copied = fit_module._data_gram(fit.anchor_columns[rows], fit.parameter_columns[rows], fit.weights[rows])
    np.testing.assert_array_equal(
        fit_module._data_gram(fit.anchor_columns, fit.parameter_columns, fit.weights, rows), copied)


def test_a_split_copies_no_half_of_the_parameter_columns():
    import tracemalloc

    # A star hop's split held a copy of the smaller half's columns (56 MB of a judgement's 208 MB peak).
    fit, rng = _synthetic_fit(rows=50_000, parameters=60)
    rows = rng.random(fit.whitened.size) < 0.5
    fit.weighted_normal_equations  # the whole fit's, which a judgement has before it splits
    tracemalloc.start()
    try:
        fit.split_normal_equations(rows)
        _, peak_bytes = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    # The anchors' half is copied (a sixth as large here), and a band of rows at a time.
    assert peak_bytes < fit.parameter_columns[rows].nbytes


def test_weighted_normal_equations_are_the_fits_own_at_its_weights():
    fit, _ = _synthetic_fit()
    gram, gradient, _ = fit.normal_equations(fit.weights)
    np.testing.assert_array_equal(fit.weighted_normal_equations[0], gram)
    np.testing.assert_array_equal(fit.weighted_normal_equations[1], gradient)
    np.testing.assert_allclose(fit.weighted_inverse.matrix @ gram, np.eye(len(gram)), atol=1e-8)


def test_projected_gram_in_bands_is_the_projection_of_the_stacked_pieces(monkeypatch):
    from sofia_ros.analysis import ranking
    from sofia_ros.compare import search

    rng = np.random.default_rng(11)
    pieces = [rng.normal(size=(50, width)) for width in (1, 1, 3, 2)]
    nuisance = scipy.sparse.csr_matrix(rng.normal(size=(50, 4)) * (rng.random((50, 4)) < 0.5))
    # Bands of 7 rows: the last one short, so that the bands' sum is exercised.
    monkeypatch.setattr(ranking, 'GRAM_BAND_ROWS', 7)
    stacked = np.hstack(pieces)
    dense = nuisance.toarray()
    projected = stacked - dense @ np.linalg.lstsq(dense, stacked, rcond=None)[0]
    np.testing.assert_allclose(search._projected_gram(pieces, nuisance), projected.T @ projected, rtol=0, atol=1e-9)


def test_sparse_gram_in_bands_is_the_dense_product(monkeypatch):
    from sofia_ros.analysis import ranking

    rng = np.random.default_rng(12)
    # A bag's shape: data rows with a few non-zeros, then nearly dense prior rows, one of them inside the data rows
    # too, so that bands mix both kinds; bands of 7 rows, the last one short.
    dense = np.zeros((53, 16))
    dense[np.arange(53)[:, None], rng.integers(0, 16, size=(53, 2))] = rng.normal(size=(53, 2))
    dense[[20, 48, 49, 50, 51, 52]] = rng.normal(size=(6, 16))
    monkeypatch.setattr(ranking, 'GRAM_BAND_ROWS', 7)
    matrix = scipy.sparse.csr_matrix(dense)
    assert np.sum(np.diff(matrix.indptr) > ranking._DENSE_FRACTION * 16) == 6
    np.testing.assert_allclose(ranking._gram(matrix), dense.T @ dense, rtol=0, atol=1e-12)
    np.testing.assert_allclose(ranking._gram(matrix.tocsc()), dense.T @ dense, rtol=0, atol=1e-12)
