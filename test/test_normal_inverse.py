"""NormalInverse.of: the pseudo-inverse of a Gram matrix by Cholesky where that is the eigendecomposition's answer.

The reference is numpy's pseudo-inverse of the column-scaled Gram matrix, its eigenvalues below
KEPT_EIGENVALUE_FRACTION of the largest cut (np.linalg.pinv's ``rcond``, hermitian), scaled back.
"""

import numpy as np
import pytest

from sofia_ros.analysis.ranking import KEPT_EIGENVALUE_FRACTION, NormalInverse


def _reference_inverse(gram):
    norms = np.sqrt(np.diag(gram))
    scaled = gram / np.outer(norms, norms)
    return np.linalg.pinv(scaled, rcond=KEPT_EIGENVALUE_FRACTION, hermitian=True) / np.outer(norms, norms)


def _close(matrix, reference, tolerance):
    """Whether two matrices agree to ``tolerance`` of the reference's Frobenius norm (an inverse of condition c is
    computed to about c times the float epsilon of its norm)."""
    return np.linalg.norm(matrix - reference) <= tolerance * np.linalg.norm(reference)


def _same_space(first, second):
    """Whether two sets of directions span the same space (each the other's projection of itself)."""
    projector = first @ np.linalg.pinv(first)
    return np.allclose(projector @ second, second, atol=1e-8)


def _jacobian(rng, rows=120):
    jacobian = rng.normal(size=(rows, 6)) * np.array([1.0, 1e3, 1e-3, 1.0, 1.0, 5.0])
    jacobian[:, 4] = jacobian[:, 3]  # their difference is undetermined by any rows
    return jacobian


def test_the_null_directions_of_all_rows_serve_a_part_of_them(monkeypatch):
    rng = np.random.default_rng(3)
    jacobian = _jacobian(rng)
    whole = NormalInverse.of(jacobian.T @ jacobian)
    assert whole.null_directions.shape == (6, 1)
    part = jacobian[:50].T @ jacobian[:50]
    reference = _reference_inverse(part)

    eigendecomposition = np.linalg.eigh

    def only_of_the_known_directions(matrix, *args, **kwargs):
        if len(matrix) == len(part):
            raise AssertionError('the known null directions should spare the whole eigendecomposition')
        return eigendecomposition(matrix, *args, **kwargs)

    monkeypatch.setattr(np.linalg, 'eigh', only_of_the_known_directions)
    inverse = NormalInverse.of(part, whole.null_directions)
    assert np.allclose(inverse.matrix, reference, rtol=1e-8, atol=1e-14)
    assert np.array_equal(inverse.unconstrained, [False, False, False, True, True, False])
    assert _same_space(inverse.null_directions, whole.null_directions)


def test_directions_that_are_not_null_are_not_taken_for_null():
    rng = np.random.default_rng(5)
    whole = NormalInverse.of(_jacobian(rng).T @ _jacobian(rng))
    jacobian = rng.normal(size=(120, 6))  # full rank: the other Gram matrix's null direction is not null here
    gram = jacobian.T @ jacobian
    inverse = NormalInverse.of(gram, whole.null_directions)
    assert np.allclose(inverse.matrix, np.linalg.inv(gram), rtol=1e-10)
    assert not np.any(inverse.unconstrained)


def test_a_part_with_a_null_direction_of_its_own_is_decided_by_the_eigendecomposition():
    rng = np.random.default_rng(9)
    jacobian = _jacobian(rng)
    jacobian[:60, 2] = 0.0  # the first half of the rows does not see the third column
    whole = NormalInverse.of(jacobian.T @ jacobian)
    part = jacobian[:60].T @ jacobian[:60]
    part[2, 2] = 1.0  # as the split test decouples a parameter its half lacks
    inverse = NormalInverse.of(part, whole.null_directions)
    assert np.allclose(inverse.matrix, _reference_inverse(part), rtol=1e-8, atol=1e-14)
    assert inverse.null_directions.shape == (6, 1)

    part[2, 2] = 0.0  # undecoupled, the column is a second null direction
    with np.errstate(divide='ignore', invalid='ignore'):
        inverse = NormalInverse.of(part, whole.null_directions)
    assert inverse.null_directions.shape == (6, 2)
    assert np.array_equal(inverse.unconstrained, [False, False, True, True, True, False])


def _gram_of_condition(condition, size=200, seed=1, smallest=None):
    rng = np.random.default_rng(seed)
    vectors = np.linalg.qr(rng.normal(size=(size, size)))[0]
    eigenvalues = np.geomspace(1.0, 1.0 / condition, size)
    if smallest is not None:
        eigenvalues[-1] = smallest
    gram = (vectors * eigenvalues) @ vectors.T
    norms = np.sqrt(np.diag(gram))
    return gram / np.outer(norms, norms)


def test_a_condition_the_one_norm_bound_overstates_keeps_every_combination_by_cholesky():
    condition = 0.2 / KEPT_EIGENVALUE_FRACTION
    gram = _gram_of_condition(condition)
    eigenvalues = np.linalg.eigvalsh(gram)
    assert eigenvalues[0] > KEPT_EIGENVALUE_FRACTION * eigenvalues[-1]
    # The bound the cheap path checks first says otherwise: the condition's true size decides.
    one_norm_bound = np.abs(gram).sum(axis=0).max() * np.abs(np.linalg.inv(gram)).sum(axis=0).max()
    assert one_norm_bound * KEPT_EIGENVALUE_FRACTION > 1.0
    inverse = NormalInverse.of(gram)
    assert inverse.null_directions is None
    assert not np.any(inverse.unconstrained)
    assert _close(inverse.matrix, _reference_inverse(gram), 10 * condition * np.finfo(float).eps)


def test_a_combination_below_the_kept_fraction_is_cut():
    gram = _gram_of_condition(1e8, smallest=1e-14)
    eigenvalues = np.linalg.eigvalsh(gram)
    assert np.sum(eigenvalues < KEPT_EIGENVALUE_FRACTION * eigenvalues[-1]) == 1
    inverse = NormalInverse.of(gram)
    assert inverse.null_directions.shape == (200, 1)
    assert _close(inverse.matrix, _reference_inverse(gram), 1e-7)


@pytest.mark.parametrize('condition', [1e4, 0.2 / KEPT_EIGENVALUE_FRACTION])
def test_the_inverse_is_scaled_back_to_the_gram_matrix_columns(condition):
    scales = np.geomspace(1e-3, 1e3, 200)
    gram = _gram_of_condition(condition) * np.outer(scales, scales)
    inverse = NormalInverse.of(gram)
    tolerance = max(1e-6, 10 * condition * np.finfo(float).eps)
    assert _close(inverse.matrix * np.outer(scales, scales), _reference_inverse(gram) * np.outer(scales, scales),
                  tolerance)


def test_a_direction_merely_weak_in_all_rows_is_not_taken_for_null_in_a_part():
    rng = np.random.default_rng(0)
    jacobian = rng.normal(size=(200, 6)) * np.array([1.0, 1e3, 1e-3, 1.0, 1.0, 5.0])
    jacobian[:, 4] = jacobian[:, 3]  # null in any rows
    # 1.5e-6 from the second column: an eigenvalue near 2e-14 of the largest, cut in all rows and in a part (below
    # KEPT_EIGENVALUE_FRACTION), but along another combination in each, and ten times the rounding (n eps); and a kept
    # one near 2e-9 that a wrong null direction leaks into.
    jacobian[:, 5] = jacobian[:, 1] * 5e-3 + 1.5e-6 * rng.normal(size=200)
    jacobian[:, 2] = jacobian[:, 0] * 1e-3 + 1e-7 * rng.normal(size=200)
    whole = NormalInverse.of(jacobian.T @ jacobian)
    assert whole.null_directions.shape == (6, 2)
    part = jacobian[:40].T @ jacobian[:40]
    inverse = NormalInverse.of(part, whole.null_directions)
    # Both known directions taken for null, the part's inverse was 2e-4 off.
    assert _close(inverse.matrix, _reference_inverse(part), 1e-10)
    assert inverse.null_directions.shape == (6, 2)


def test_a_weakly_determined_combination_gets_its_step_and_a_null_one_none():
    # The eigenvalues of the Waco 2004 star hop's model with the imagers' boresight offsets: two combinations at
    # 1.7e-11 and 2.1e-11 of the largest (the gyro box's misalignment with the offsets and the anchors), one at
    # 1.2e-16 (rounding: the EL gyro bias with the anchors), on random orthonormal directions.
    rng = np.random.default_rng(13)
    vectors, _ = np.linalg.qr(rng.normal(size=(8, 8)))
    eigenvalues = np.array([1.2e-16, 1.7e-11, 2.1e-11, 1e-4, 1e-2, 0.3, 1.0, 4.0])
    gram = (vectors * eigenvalues) @ vectors.T
    gradient = vectors @ np.ones(8)
    inverse = NormalInverse.of(gram)
    step = inverse.matrix @ gradient
    assert np.allclose(step, _reference_inverse(gram) @ gradient, rtol=1e-6)
    along = vectors.T @ step
    assert np.all(np.abs(along[1:3]) > 1e9), 'the weakly determined combinations get their step (1/eigenvalue)'
    # The null one gets none, in the column-scaled coordinates the minimum-norm step is taken in: to the rounding of
    # the constructed matrix's null vector, eps |G| / 1.7e-11 = 5e-5 (taken, its step would be 1e5 times the others).
    norms = np.sqrt(np.diag(gram))
    null = norms * vectors[:, 0]
    assert abs(null @ (norms * step)) <= 1e-4 * np.linalg.norm(null) * np.linalg.norm(norms * step)
    assert inverse.null_directions.shape == (8, 1)
    assert _same_space(inverse.null_directions, vectors[:, :1])
