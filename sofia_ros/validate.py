"""Argument checks shared by the science core.

Each check raises one project exception whose message names the argument and
says what was expected, so callers never need an ``assert``.
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from sofia_ros.errors import InvalidArgumentError, NotOrthonormalError
from sofia_ros.rotation_kernels import determinant_3x3

__all__ = [
    'finite_array',
    'finite_scalar',
    'positive_scalar',
    'unit_vector',
    'orthonormal_dcm',
    'number_text_hint',
    'DCM_REJECT_TOLERANCE',
    'DCM_EXACT_TOLERANCE',
]

#: Largest |A A^T - I| accepted at all; published matrices reach 9e-6 (Table D.2).
DCM_REJECT_TOLERANCE = 1e-3
#: Below this a DCM is taken as it is; between the two it is re-orthonormalized with a warning.
DCM_EXACT_TOLERANCE = 1e-9
_IDENTITY = np.eye(3)


def finite_array(name, value, shape=None):
    """Return ``value`` as a float array; raise if it has NaN/inf or the wrong shape.

    ``shape`` may contain ``None`` for a free dimension, e.g. ``(None, 3)``.
    """
    try:
        array = np.asarray(value, dtype=float)
    except (TypeError, ValueError) as err:
        raise InvalidArgumentError(f'{name} must be numeric, got {type(value).__name__}') from err
    if shape is not None and array.shape != shape:
        # Equal shapes pass at once; otherwise each dimension is compared, None taking any length.
        ok = array.ndim == len(shape) and all(
            want is None or want == have for want, have in zip(shape, array.shape)
        )
        if not ok:
            want = 'x'.join('N' if s is None else str(s) for s in shape) or 'scalar'
            raise InvalidArgumentError(f'{name} must have shape {want}, got {array.shape}')
    # The method, not np.all: the per-tick callers pass 3-vectors and 3x3 matrices, where np.all's dispatch costs
    # more than the test.
    if not np.isfinite(array).all():
        raise InvalidArgumentError(f'{name} contains NaN or infinite values')
    return array


def finite_scalar(name, value):
    """Return ``value`` as a finite float; raise otherwise."""
    if type(value) is float:
        # What the per-tick callers pass: checked without making an array (the same float comes back).
        if not math.isfinite(value):
            raise InvalidArgumentError(f'{name} contains NaN or infinite values')
        return value
    return float(finite_array(name, value, shape=()))


def positive_scalar(name, value):
    """Return ``value`` as a finite float > 0; raise otherwise."""
    number = finite_scalar(name, value)
    if number <= 0.0:
        raise InvalidArgumentError(f'{name} must be > 0, got {number}')
    return number


def unit_vector(name, value):
    """``value`` as a unit 3-vector; raise on NaN, wrong shape or zero length."""
    vector = finite_array(name, value, shape=(3,))
    norm = float(np.linalg.norm(vector))
    if norm == 0.0:
        raise InvalidArgumentError(f'{name} must be a non-zero 3-vector')
    return vector / norm


def orthonormal_dcm(name, value):
    """Return a 3x3 DCM; re-orthonormalize small departures with a warning, reject large ones.

    Published matrices (Table D.2, eq. 6.1) are orthonormal to about 1e-5 only.
    """
    matrix = finite_array(name, value, shape=(3, 3))
    departure = float(np.abs(matrix @ matrix.T - _IDENTITY).max())
    if departure > DCM_REJECT_TOLERANCE:
        raise NotOrthonormalError(
            f'{name} is not orthonormal: max |A A^T - I| = {departure:.3g} '
            f'(limit {DCM_REJECT_TOLERANCE:g}); pass a rotation matrix'
        )
    # By cofactors: near a rotation or reflection (|A A^T - I| <= 1e-3, |det| within 5e-3 of 1) its sign is
    # np.linalg.det's, without LAPACK's call overhead.
    if determinant_3x3(matrix) < 0.0:
        raise NotOrthonormalError(f'{name} is a reflection (det < 0), not a rotation')
    if departure > DCM_EXACT_TOLERANCE:
        warnings.warn(
            f'{name} re-orthonormalized (max |A A^T - I| = {departure:.2g})',
            stacklevel=2,
        )
        u, _, vt = np.linalg.svd(matrix)
        matrix = u @ vt
    return matrix


def number_text_hint(text):
    """Where YAML read a number as text: how to write it ('1e3' needs a dot and a sign, 1.0e+3), else ''."""
    try:
        float(text)
    except ValueError:
        return ''
    return ' (YAML reads 1e3 as text: write 1000 or 1.0e+3)' if 'e' in text.lower() else ' (write it without quotes)'
