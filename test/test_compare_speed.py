"""The compare's faster paths against independent computations of the same numbers (issue 27)."""

import numpy as np
import pytest

from sofia_ros.compare.predict import inverse_right_jacobians, right_jacobians


@pytest.mark.parametrize('scale', [0.0, 1e-9, 1e-5, 1e-4, 1e-3, 0.01, 0.5, 3.0])
def test_inverse_right_jacobians_are_the_inverses_of_the_right_jacobians(scale):
    directions = np.random.default_rng(7).normal(size=(200, 3))
    rotvecs = scale * directions / np.linalg.norm(directions, axis=1, keepdims=True)
    # The series branch below |phi| = 1e-4, the closed form above it, both against LAPACK's inverse.
    np.testing.assert_allclose(inverse_right_jacobians(rotvecs), np.linalg.inv(right_jacobians(rotvecs)),
                               rtol=0, atol=1e-12)
