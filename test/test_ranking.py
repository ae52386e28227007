"""The shared candidate-ranking machinery (analysis.ranking) against scipy and synthetic truths."""

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize

from sofia_ros.analysis.ranking import (
    SIGNIFICANT_DELTA_BIC,
    CandidateTerm,
    bic,
    linear_fit,
    rank_candidates,
    whitened_bic,
)
from sofia_ros.errors import InvalidArgumentError

N_SAMPLES = 2000


@pytest.fixture
def design():
    rng = np.random.default_rng(4)
    t = np.linspace(0.0, 1.0, N_SAMPLES)
    base = np.column_stack([np.ones_like(t), t])
    terms = {
        'sine': np.sin(2 * np.pi * 3 * t)[:, None],
        'quadratic': (t**2)[:, None],
        'step': (t > 0.5).astype(float)[:, None],
    }
    return rng, t, base, terms


def test_linear_fit_matches_scipy_least_squares_and_covariance(design):
    rng, t, base, terms = design
    jacobian = np.column_stack([base, terms['sine']])
    truth = np.array([0.3, -1.2, 0.05])
    residual = jacobian @ truth + rng.normal(0.0, 0.01, N_SAMPLES)
    fit = linear_fit(residual, jacobian, ('offset', 'slope', 'sine'))
    reference = scipy.optimize.lsq_linear(jacobian, residual, tol=1e-12)
    np.testing.assert_allclose(fit.step, reference.x, rtol=0, atol=1e-9)
    # Independent covariance: s^2 pinv(J^T J) from scipy.linalg.
    variance = fit.rss / (N_SAMPLES - 3)
    expected = np.sqrt(np.diag(scipy.linalg.pinv(jacobian.T @ jacobian) * variance))
    np.testing.assert_allclose(fit.sigma, expected, rtol=1e-8)
    assert np.all(np.abs(fit.step - truth) < 4 * fit.sigma)
    assert fit.correlation.shape == (3, 3)
    np.testing.assert_allclose(np.diag(fit.correlation), 1.0)


def test_linear_fit_flags_unconstrained_directions_with_infinite_sigma(design):
    _, t, base, _ = design
    jacobian = np.column_stack([base, 2.0 * base[:, 1]])  # slope twice: not separable
    fit = linear_fit(t, jacobian, ('offset', 'slope', 'slope_again'))
    assert np.isinf(fit.sigma[1]) and np.isinf(fit.sigma[2])
    assert np.isfinite(fit.sigma[0])


def test_hidden_term_ranks_first_within_three_sigma(design):
    rng, _, base, terms = design
    residual = 0.02 * terms['step'][:, 0] + rng.normal(0.0, 0.01, N_SAMPLES)
    candidates = [CandidateTerm(name, ('a',), np.zeros(1), columns) for name, columns in terms.items()]
    ranked = rank_candidates(residual, base, candidates)
    best = ranked[0]
    assert best.name == 'step' and best.significant
    assert abs(best.params['a'] - 0.02) < 3 * best.sigma['a']
    assert best.rss_after < ranked[1].rss_after


def test_null_residual_has_no_significant_candidate(design):
    rng, _, base, terms = design
    residual = rng.normal(0.0, 0.01, N_SAMPLES)
    ranked = rank_candidates(residual, base, [CandidateTerm(n, ('a',), np.zeros(1), c) for n, c in terms.items()])
    assert all(candidate.delta_bic < SIGNIFICANT_DELTA_BIC for candidate in ranked)


def test_collinear_candidates_are_named_degenerate_not_picked(design):
    rng, _, base, terms = design
    residual = 0.03 * terms['sine'][:, 0] + rng.normal(0.0, 0.01, N_SAMPLES)
    twin = terms['sine'] * 1.7 + 1e-4 * terms['quadratic']
    candidates = [CandidateTerm('sine', ('a',), np.zeros(1), terms['sine']),
                  CandidateTerm('twin', ('b',), np.zeros(1), twin),
                  CandidateTerm('quadratic', ('c',), np.zeros(1), terms['quadratic'])]
    ranked = {candidate.name: candidate for candidate in rank_candidates(residual, base, candidates)}
    assert ranked['sine'].degenerate_with == ('twin',)
    assert ranked['twin'].degenerate_with == ('sine',)
    assert ranked['quadratic'].degenerate_with == ()


def test_candidate_inside_the_base_span_is_unobservable(design):
    rng, t, base, _ = design
    residual = rng.normal(0.0, 0.01, N_SAMPLES)
    ranked = rank_candidates(residual, base, [CandidateTerm('drift', ('rate',), np.zeros(1), 3.0 * t)])
    assert not ranked[0].observable and ranked[0].delta_bic == 0.0 and np.isinf(ranked[0].sigma['rate'])


def test_shifted_candidate_fits_about_its_start(design):
    rng, _, base, terms = design
    # The term is linearized at a = 0.05 (its "default"): the shift is its prediction there.
    residual = 0.03 * terms['sine'][:, 0] + rng.normal(0.0, 0.01, N_SAMPLES)
    term = CandidateTerm('sine', ('a',), np.array([0.05]), terms['sine'], shift=0.05 * terms['sine'][:, 0])
    best = rank_candidates(residual, base, [term])[0]
    assert abs(best.params['a'] - 0.03) < 3 * best.sigma['a']


def test_bic_matches_its_formula_and_rejects_empty_samples():
    assert bic(2.0, 100, 3) == pytest.approx(100 * np.log(0.02) + 3 * np.log(100))
    with pytest.raises(InvalidArgumentError, match='n > 0'):
        bic(1.0, 0, 1)


def test_whitened_bic_is_bic_above_the_floor_and_the_chi_square_below_it():
    # Above the floor (RSS/n >= 1) the variance is fitted: the Schwarz form. Below it the floor's own variance
    # holds: the difference of two fits is their chi-square difference, and no fit gains more than n by going to 0.
    n, k = 100, 3
    assert whitened_bic(250.0, n, k) == bic(250.0, n, k)
    assert whitened_bic(60.0, n, k) - whitened_bic(40.0, n, k) == pytest.approx(20.0)
    assert whitened_bic(0.0, n, k) == pytest.approx(-n + k * np.log(n))
    # The two branches meet at RSS = n with the same slope (1 per unit of RSS).
    step = 1e-6
    for rss in (n - step, n + step):
        assert whitened_bic(rss, n, k) == pytest.approx(k * np.log(n) + (rss - n), abs=1e-9)
    with pytest.raises(InvalidArgumentError, match='n > 0'):
        whitened_bic(0.0, 0, 1)


def test_bad_shapes_and_values_raise_one_clear_error():
    with pytest.raises(InvalidArgumentError, match='rows for'):
        linear_fit(np.zeros(3), np.zeros((4, 1)), ('a',))
    with pytest.raises(InvalidArgumentError, match='names for'):
        linear_fit(np.zeros(3), np.zeros((3, 2)), ('a',))
    with pytest.raises(InvalidArgumentError, match='finite'):
        linear_fit(np.array([0.0, np.nan, 1.0]), np.ones((3, 1)), ('a',))


@pytest.mark.parametrize('shifted', [False, True])
def test_the_base_change_beside_a_candidate_is_the_joint_least_squares_step(design, shifted):
    rng, t, base, terms = design
    # A candidate nearly shared with the base's slope (a quadratic against a line): alone, its step would move the
    # prediction far from where the base left it; with the base moved as the joint fit moves it, the two land on the
    # joint least-squares solution (scipy), from residuals the base had already fitted.
    quadratic = terms['quadratic']
    truth = 0.4
    data = truth * quadratic[:, 0] + rng.normal(0.0, 0.01, N_SAMPLES)
    base_values = scipy.linalg.lstsq(base, data)[0]
    residual = data - base @ base_values
    start = 0.05 if shifted else 0.0
    term = CandidateTerm('quadratic', ('a',), np.array([start]), quadratic,
                         shift=start * quadratic[:, 0] if shifted else None)
    best = rank_candidates(residual, base, [term])[0]
    joint = scipy.linalg.lstsq(np.column_stack([base, quadratic]), data)[0]
    np.testing.assert_allclose(best.params['a'], joint[2], rtol=0, atol=1e-9)
    np.testing.assert_allclose(base_values + best.base_change, joint[:2], rtol=0, atol=1e-9)
    # The change is far beyond the base's own sigmas: starting the base where it was would start far off.
    assert np.max(np.abs(best.base_change)) > 100 * 0.01 / np.sqrt(N_SAMPLES)
