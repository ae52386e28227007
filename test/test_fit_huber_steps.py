"""compare.fit's step to the least Huber cost of a linearized problem, against scipy's minimizers (issue 27).

huber_line_minimum is the exact minimum along one step; linearized_huber_step the minimum of the whole linearized
problem (sparse anchor columns under a prior, dense parameter columns) where a third of the rows lie beyond k, as
on a model that lacks an effect. The references minimize the same cost with scipy, knowing nothing of its pieces.
"""

from types import SimpleNamespace

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize
import scipy.sparse

from sofia_ros.analysis.ranking import KEPT_EIGENVALUE_FRACTION, NormalInverse, normal_solution
from sofia_ros.compare.fit import HUBER_K, huber_line_minimum, linearized_huber_step


def _huber_cost(residual):
    magnitude = np.abs(residual)
    return np.sum(np.where(magnitude <= HUBER_K, 0.5 * magnitude**2, HUBER_K * magnitude - 0.5 * HUBER_K**2))


def _huber_gradient(residual):
    """d cost / d residual: psi(r)."""
    return np.clip(residual, -HUBER_K, HUBER_K)


def _problem(seed, rows=240, knots=4, parameters=3, outlier_share=0.3):
    """A linearized problem: two knots per row (hat weights), a random-walk prior between knots, residuals of which
    ``outlier_share`` lie far beyond k."""
    rng = np.random.default_rng(seed)
    knot_of_row = rng.integers(0, knots - 1, rows)
    fraction = rng.uniform(0.0, 1.0, rows)
    derivative = rng.normal(size=(rows, 3))
    data, columns = [], []
    for weight, knot in ((1.0 - fraction, knot_of_row), (fraction, knot_of_row + 1)):
        data.append(weight[:, None] * derivative)
        columns.append(3 * knot[:, None] + np.arange(3))
    anchor_columns = scipy.sparse.csr_matrix((np.hstack(data).ravel(), np.hstack(columns).ravel(),
                                              np.arange(0, 6 * rows + 1, 6)), shape=(rows, 3 * knots))
    parameter_columns = rng.normal(size=(rows, parameters))
    truth = rng.normal(size=3 * knots + parameters)
    residual = anchor_columns @ truth[:3 * knots] + parameter_columns @ truth[3 * knots:] + rng.normal(size=rows)
    outliers = rng.random(rows) < outlier_share
    residual[outliers] += rng.choice([-1.0, 1.0], outliers.sum()) * rng.uniform(10.0, 60.0, outliers.sum())
    increments = scipy.sparse.eye(3 * (knots - 1), 3 * knots, k=3) - scipy.sparse.eye(3 * (knots - 1), 3 * knots)
    prior_matrix = scipy.sparse.csr_matrix(2.0 * increments)
    prior = SimpleNamespace(matrix=prior_matrix, gram=(prior_matrix.T @ prior_matrix).toarray())
    prior_residual = rng.normal(size=prior_matrix.shape[0])
    return anchor_columns, parameter_columns, prior, residual, prior_residual


def _cost_after(step, anchor_columns, parameter_columns, prior, residual, prior_residual):
    anchors = anchor_columns.shape[1]
    data = residual - anchor_columns @ step[:anchors] - parameter_columns @ step[anchors:]
    after_prior = prior_residual - prior.matrix @ step[:anchors]
    return _huber_cost(data) + 0.5 * after_prior @ after_prior


@pytest.mark.parametrize('seed', range(4))
def test_the_line_minimum_is_the_least_cost_along_the_step(seed):
    anchor_columns, parameter_columns, prior, residual, prior_residual = _problem(seed)
    rng = np.random.default_rng(100 + seed)
    step = rng.normal(size=anchor_columns.shape[1] + parameter_columns.shape[1]) * 0.3
    anchors = anchor_columns.shape[1]
    change = anchor_columns @ step[:anchors] + parameter_columns @ step[anchors:]
    prior_change = prior.matrix @ step[:anchors]
    # The sign that lowers the cost first: the function looks along t >= 0 only.
    if _cost_after(1e-6 * step, anchor_columns, parameter_columns, prior, residual, prior_residual) > _cost_after(
            0 * step, anchor_columns, parameter_columns, prior, residual, prior_residual):
        change, prior_change = -change, -prior_change

    def along(t):
        after_prior = prior_residual - t * prior_change
        return _huber_cost(residual - t * change) + 0.5 * after_prior @ after_prior

    found = huber_line_minimum(residual, change, prior_residual, prior_change)
    reference = scipy.optimize.minimize_scalar(along, bounds=(0.0, 100.0), method='bounded',
                                               options={'xatol': 1e-12}).x
    assert found == pytest.approx(reference, rel=1e-5, abs=1e-9)
    assert along(found) <= along(reference) + 1e-9 * abs(along(reference))


def test_a_step_that_raises_the_cost_has_no_length():
    residual = np.array([1.0, -2.0, 50.0])
    change = np.array([-1.0, 2.0, -1.0])
    assert huber_line_minimum(residual, change, np.zeros(0), np.zeros(0)) == 0.0


@pytest.mark.parametrize('seed', range(3))
def test_the_linearized_step_reaches_the_least_huber_cost(seed):
    anchor_columns, parameter_columns, prior, residual, prior_residual = _problem(seed)
    size = anchor_columns.shape[1] + parameter_columns.shape[1]
    names = [''] * size
    rows = residual.size + prior_residual.size
    step, sigma, _, drop = linearized_huber_step(anchor_columns, parameter_columns, prior, residual, prior_residual,
                                              names, rows)
    anchors = anchor_columns.shape[1]
    jacobian = scipy.sparse.hstack([anchor_columns, scipy.sparse.csr_matrix(parameter_columns)]).tocsr()

    def cost_and_gradient(x):
        data = residual - jacobian @ x
        after_prior = prior_residual - prior.matrix @ x[:anchors]
        gradient = -(jacobian.T @ _huber_gradient(data))
        gradient[:anchors] -= prior.matrix.T @ after_prior
        return _huber_cost(data) + 0.5 * after_prior @ after_prior, gradient

    reference = scipy.optimize.minimize(cost_and_gradient, np.zeros(size), jac=True, method='BFGS',
                                        options={'gtol': 1e-10, 'maxiter': 5000})
    # BFGS stops on its line search's precision near the minimum: its gradient there says it is one.
    assert np.linalg.norm(reference.jac) < 1e-6 * np.linalg.norm(cost_and_gradient(np.zeros(size))[1])
    assert np.all(np.isfinite(sigma)) and sigma.shape == (size,)
    # The same minimum: each value within 1e-3 of its sigma (the inner tolerance), the cost to rounding.
    assert np.max(np.abs(step - reference.x) / sigma) < 1e-3
    assert cost_and_gradient(step)[0] == pytest.approx(reference.fun, rel=1e-10)
    # The drop it reports is the cost it removed, at the scale of the cost itself.
    assert drop == pytest.approx(cost_and_gradient(np.zeros(size))[0] - cost_and_gradient(step)[0], rel=1e-9)


@pytest.mark.parametrize('case', ['full rank', 'two equal columns', 'a column 1e-7 from another'])
def test_the_normal_solution_is_the_pseudo_inverse_step(case):
    rng = np.random.default_rng(7)
    jacobian = rng.normal(size=(60, 5)) * np.array([1.0, 1e3, 1e-3, 1.0, 5.0])
    if case == 'two equal columns':
        jacobian[:, 4] = jacobian[:, 3]
    elif case == 'a column 1e-7 from another':
        jacobian[:, 4] = jacobian[:, 3] + 1e-7 * rng.normal(size=60)
    residual = rng.normal(size=60)
    gram, gradient = jacobian.T @ jacobian, jacobian.T @ residual
    solution = normal_solution(gram, gradient)
    assert np.allclose(solution, NormalInverse.of(gram).matrix @ gradient, rtol=1e-9, atol=1e-12)
    # The minimum-norm least-squares step of the column-scaled problem, singular values below the square root of
    # KEPT_EIGENVALUE_FRACTION of the largest cut (that fraction of the Gram matrix's eigenvalues): the combination
    # the data do not determine gets no step.
    norms = np.linalg.norm(jacobian, axis=0)
    reference = np.linalg.lstsq(jacobian / norms, residual, rcond=np.sqrt(KEPT_EIGENVALUE_FRACTION))[0] / norms
    assert np.allclose(solution, reference, rtol=1e-6, atol=1e-9)


def test_the_null_directions_of_one_weighting_serve_another():
    # Two equal columns: every weighting of the rows leaves their difference undetermined.
    rng = np.random.default_rng(11)
    jacobian = rng.normal(size=(80, 6)) * np.array([1.0, 1e3, 1e-3, 1.0, 1.0, 5.0])
    jacobian[:, 4] = jacobian[:, 3]
    residual = rng.normal(size=80)
    first = NormalInverse.of(jacobian.T @ jacobian)
    assert first.null_directions.shape == (6, 1)
    weights = rng.uniform(0.05, 1.0, 80)
    gram, gradient = jacobian.T @ (weights[:, None] * jacobian), jacobian.T @ (weights * residual)
    solution = normal_solution(gram, gradient, first.null_directions)
    assert np.allclose(solution, NormalInverse.of(gram).matrix @ gradient, rtol=1e-8, atol=1e-12)
    # numpy's minimum-norm weighted least squares of the column-scaled problem: the same step.
    root = np.sqrt(weights)[:, None]
    norms = np.sqrt(np.diag(gram))
    reference = np.linalg.lstsq(root * jacobian / norms, root[:, 0] * residual,
                                rcond=np.sqrt(KEPT_EIGENVALUE_FRACTION))[0] / norms
    assert np.allclose(solution, reference, rtol=1e-6, atol=1e-9)


def _gram_with_a_known_null_and_a_weak_combination(size, weak):
    """(the null direction, G, g): G of ``size`` columns on random orthonormal directions, one eigenvalue 0 (the
    known null direction), one ``weak``, the rest 1e-3 to 1; g random."""
    rng = np.random.default_rng(size)
    vectors = np.linalg.qr(rng.normal(size=(size, size)))[0]
    eigenvalues = np.concatenate([[0.0, weak], np.geomspace(1e-3, 1.0, size - 2)])
    return vectors[:, :1], (vectors * eigenvalues) @ vectors.T, rng.normal(size=size)


@pytest.mark.parametrize('size', [20, 100, 600])
@pytest.mark.parametrize('weak', [1e-15, 5e-14, 3e-13, 1.7e-11, 1e-10])
def test_a_combination_the_known_null_directions_miss_is_cut_or_kept_as_the_pseudo_inverse_does(size, weak):
    # A known null direction (a degeneracy of the columns) and another combination at ``weak`` of the largest
    # eigenvalue that the known ones miss: on either side of KEPT_EIGENVALUE_FRACTION, normal_solution's Cholesky path
    # must keep exactly what the eigendecomposition keeps. (With the acceptance divided by the size, a combination at
    # 5e-14 was kept at 20 columns and one at 1e-14 at 100: steps 1e9-1e10 times too long.)
    known_null, gram, gradient = _gram_with_a_known_null_and_a_weak_combination(size, weak)
    reference = NormalInverse.of(gram).matrix @ gradient
    solution = normal_solution(gram, gradient, known_null)
    # A kept combination at 1.7e-11 is solved to about eps / 1.7e-11 of its own part by either path, no better.
    tolerance = 1e-9 if weak < KEPT_EIGENVALUE_FRACTION else 10 * np.finfo(float).eps / weak
    assert np.abs(solution - reference).max() <= tolerance * np.abs(reference).max()


def test_a_kept_combination_the_condition_estimate_understates_is_solved_without_the_eigendecomposition(monkeypatch):
    # At 1e-11 of the largest eigenvalue with 600 columns, LAPACK's 1-norm estimate of the reciprocal condition falls
    # below KEPT_EIGENVALUE_FRACTION (7.6e-13): Lanczos measures the smallest eigenvalue itself, and the step is the
    # pseudo-inverse's without an eigendecomposition (30-50 ms a step at this size).
    size, weak = 600, 1e-11
    known_null, gram, gradient = _gram_with_a_known_null_and_a_weak_combination(size, weak)
    reference = NormalInverse.of(gram).matrix @ gradient
    norms = np.sqrt(np.diag(gram))
    scaled = gram / np.outer(norms, norms)
    null = np.linalg.qr(known_null * norms[:, None])[0]
    factor = scipy.linalg.lapack.dpotrf(scaled + null @ null.T, lower=True)[0]
    estimate = scipy.linalg.lapack.dpocon(factor, np.abs(scaled + null @ null.T).sum(axis=0).max(), uplo='L')[0]
    assert estimate < KEPT_EIGENVALUE_FRACTION

    def no_eigendecomposition(*args, **kwargs):
        raise AssertionError('Lanczos should decide this one')

    monkeypatch.setattr(np.linalg, 'eigh', no_eigendecomposition)
    solution = normal_solution(gram, gradient, known_null)
    assert np.abs(solution - reference).max() <= 10 * np.finfo(float).eps / weak * np.abs(reference).max()
