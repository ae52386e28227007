"""Plain-numpy rotation algebra for the per-tick hot paths (Appendix B), scipy's algorithms without its checks.

scipy's ``Rotation`` validates, promotes and dispatches on every call (20-60 us for one 3x3
matrix); the lock-step loop converts attitudes several times per tick. These kernels run the
same formulas scipy uses (rotation vector, Hamilton product, Shepperd's matrix-to-quaternion,
canonical quaternion) on plain arrays; ``test/test_frames.py`` pins them to scipy within 1e-12.
Quaternions are scalar-last (x, y, z, w), rotations active, as in ``scipy.spatial.transform``.
Matrices that are not orthonormal to 1e-12 are orthonormalized as scipy does them; a left-handed
or null frame goes to scipy for its error, so the result never depends on which path ran. scipy.spatial
is imported only where it is used (scipy_rotation): its import, about 0.4 CPU-s, was a third of every
node process's start-up, and no tick of the graph needs it.
"""

from __future__ import annotations

import numpy as np

__all__ = ['determinant_3x3', 'is_proper_orthonormal', 'quaternions_from_rotvecs', 'compose_quaternions',
           'matrices_from_quaternions', 'matrices_from_rotvecs', 'quaternion_from_matrix', 'rotvec_from_quaternion',
           'rotvec_from_matrix', 'canonical_quaternion', 'slerp_quaternion', 'scipy_rotation']

#: scipy's test for a matrix to use as it is: M M^T within 1e-12 of I off the diagonal, 1e-12 + 1e-5 on it
#: (numpy.isclose's default rtol); others are orthonormalized first (SVD, U V^T), as scipy does.
_ORTHONORMAL_TOLERANCE = 1e-12
_DIAGONAL_TOLERANCE = 1e-12 + 1e-5
_SMALL_ANGLE_RAD = 1e-3
#: Up to this many quaternion pairs compose_quaternions is cheaper on Python floats than with numpy's 40 operations.
_FEW_PAIRS = 10
_IDENTITY = np.eye(3)


def quaternions_from_rotvecs(rotvecs):
    """Unit quaternions (N x 4) of active rotation vectors (N x 3, rad), as Rotation.from_rotvec."""
    rotvecs = np.asarray(rotvecs, dtype=float)
    angle = np.sqrt(np.einsum('...i,...i->...', rotvecs, rotvecs))[..., np.newaxis]
    half_angle = angle / 2
    return np.concatenate([rotvecs * _sine_ratio(angle, half_angle), np.cos(half_angle)], axis=-1)


def _sine_ratio(angle, half_angle):
    """sin(angle / 2) / angle of angles (..., 1), by its Taylor series at small angles as scipy."""
    if angle.size == 1:
        # One rotation (most calls): only the branch np.where would take, computed on the same array.
        if angle <= _SMALL_ANGLE_RAD:
            return _small_sine_ratio(angle)
        with np.errstate(invalid='ignore'):
            return np.sin(half_angle) / angle
    with np.errstate(invalid='ignore', divide='ignore'):
        return np.where(angle <= _SMALL_ANGLE_RAD, _small_sine_ratio(angle), np.sin(half_angle) / angle)


def _small_sine_ratio(angle):
    """sin(angle / 2) / angle by its Taylor series to the fourth power."""
    angle2 = angle * angle
    return 0.5 - angle2 / 48 + angle2 * angle2 / 3840


def compose_quaternions(p, q):
    """Quaternion of rotation q followed by rotation p (Rotation p * q; eq. B.25 in active form)."""
    p, q = np.asarray(p, dtype=float), np.asarray(q, dtype=float)
    if p.ndim == 1 and q.ndim == 1:
        # One pair: the expressions on Python floats, whose IEEE double arithmetic gives numpy's bits at a fifth
        # of the cost of operations on numpy scalars.
        return np.array(_hamilton_product(*p.tolist(), *q.tolist()))
    if p.ndim == 2 and p.shape == q.shape and len(p) <= _FEW_PAIRS:
        # A few pairs (the last levels of attitude.propagate_dcm's tree): each on Python floats likewise.
        pairs = zip(p.tolist(), q.tolist())
        return np.array([_hamilton_product(*left, *right) for left, right in pairs]).reshape(p.shape)
    return _last_axis_stacked(_hamilton_product(p[..., 0], p[..., 1], p[..., 2], p[..., 3],
                                                q[..., 0], q[..., 1], q[..., 2], q[..., 3]))


def _hamilton_product(px, py, pz, pw, qx, qy, qz, qw):
    """The x, y, z, w of p * q (eq. B.25) from the components, numbers or arrays."""
    return (
        pw * qx + qw * px + (py * qz - pz * qy),
        pw * qy + qw * py + (pz * qx - px * qz),
        pw * qz + qw * pz + (px * qy - py * qx),
        pw * qw - px * qx - py * qy - pz * qz,
    )


def matrices_from_quaternions(quaternions):
    """Active rotation matrices (... x 3 x 3) of unit quaternions (... x 4), as Rotation.as_matrix."""
    quaternions = np.asarray(quaternions, dtype=float)
    if quaternions.ndim == 1:
        # One quaternion: on Python floats, as in compose_quaternions.
        return np.array(_matrix_elements(*quaternions.tolist())).reshape(3, 3)
    x, y, z, w = quaternions[..., 0], quaternions[..., 1], quaternions[..., 2], quaternions[..., 3]
    return _last_axis_stacked(_matrix_elements(x, y, z, w)).reshape(*x.shape, 3, 3)


def _matrix_elements(x, y, z, w):
    """The nine elements, row by row, of the active rotation matrix of quaternion (x, y, z, w), numbers or arrays."""
    x2, y2, z2, w2 = x * x, y * y, z * z, w * w
    xy, zw, xz, yw, yz, xw = x * y, z * w, x * z, y * w, y * z, x * w
    return (x2 - y2 - z2 + w2, 2 * (xy - zw), 2 * (xz + yw),
            2 * (xy + zw), -x2 + y2 - z2 + w2, 2 * (yz - xw),
            2 * (xz - yw), 2 * (yz + xw), -x2 - y2 + z2 + w2)


def matrices_from_rotvecs(rotvecs):
    """Active rotation matrices (... x 3 x 3) of rotation vectors (... x 3, rad), as Rotation.from_rotvec().as_matrix()."""
    return matrices_from_quaternions(quaternions_from_rotvecs(rotvecs))


def _last_axis_stacked(components):
    """np.stack(components, axis=-1) of equal-shape arrays or scalars, without its checks and concatenation (the
    same values, each copied into its column; these kernels run several times per lock-step tick)."""
    stacked = np.empty((*np.shape(components[0]), len(components)))
    for column, component in enumerate(components):
        stacked[..., column] = component
    return stacked


def determinant_3x3(matrix):
    """det of a 3x3 matrix by cofactors, on Python floats."""
    (a, b, c), (d, e, f), (g, h, i) = matrix.tolist()
    return a * (e * i - f * h) - b * (d * i - f * g) + c * (d * h - e * g)


def _is_orthonormal(matrix):
    """Whether scipy's from_matrix takes a 3x3 matrix as orthonormal (see _ORTHONORMAL_TOLERANCE)."""
    (d00, d01, d02), (d10, d11, d12), (d20, d21, d22) = np.abs(matrix @ matrix.T - _IDENTITY).tolist()
    # Python's comparisons of the nine numbers, not numpy's masked maxima; a NaN fails either way.
    return (all(departure <= _ORTHONORMAL_TOLERANCE for departure in (d01, d02, d10, d12, d20, d21))
            and all(departure <= _DIAGONAL_TOLERANCE for departure in (d00, d11, d22)))


def is_proper_orthonormal(matrix):
    """Whether a 3x3 matrix is orthonormal to 1e-12 with determinant +1."""
    departure = np.abs(matrix @ matrix.T - _IDENTITY)
    return bool(departure.max() <= _ORTHONORMAL_TOLERANCE) and determinant_3x3(matrix) > 0.0


def quaternion_from_matrix(matrix):
    """Unit quaternion of an active 3x3 rotation matrix (Shepperd's method, as Rotation.from_matrix)."""
    matrix = np.asarray(matrix, dtype=float)
    if not determinant_3x3(matrix) > 0.0:
        return scipy_rotation().from_matrix(matrix).as_quat()  # scipy's error for a left-handed or null frame
    if not _is_orthonormal(matrix):
        left, _, right = np.linalg.svd(matrix)
        matrix = left @ right
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = matrix.tolist()
    trace = m00 + m11 + m22
    # np.argmax's choice (the first largest; the matrix is finite here) without making an array of four floats.
    candidates = (m00, m11, m22, trace)
    choice = candidates.index(max(candidates))
    if choice == 0:
        quaternion = (1 - trace + 2 * m00, m10 + m01, m20 + m02, m21 - m12)
    elif choice == 1:
        quaternion = (m10 + m01, 1 - trace + 2 * m11, m21 + m12, m02 - m20)
    elif choice == 2:
        quaternion = (m20 + m02, m21 + m12, 1 - trace + 2 * m22, m10 - m01)
    else:
        quaternion = (m21 - m12, m02 - m20, m10 - m01, 1 + trace)
    quaternion = np.array(quaternion)
    return quaternion / np.sqrt(quaternion @ quaternion)


def canonical_quaternion(quaternion):
    """The one of q and -q with w > 0 (or the first non-zero of w, x, y, z positive), as as_quat(canonical=True)."""
    quaternion = np.asarray(quaternion, dtype=float)
    x, y, z, w = quaternion.tolist()
    for value in (w, x, y, z):
        if value != 0.0:
            return -quaternion if value < 0.0 else quaternion
    return quaternion


def rotvec_from_quaternion(quaternion):
    """Rotation vector (rad) of a unit quaternion, as Rotation.as_rotvec."""
    quaternion = canonical_quaternion(quaternion)
    vector = quaternion[:3]
    angle = 2 * np.arctan2(np.sqrt(vector @ vector), quaternion[3])
    if angle <= _SMALL_ANGLE_RAD:
        angle2 = angle * angle
        return (2 + angle2 / 12 + 7 * angle2 * angle2 / 2880) * vector
    return angle / np.sin(angle / 2.0) * vector


def rotvec_from_matrix(matrix):
    """Rotation vector (rad) of an active 3x3 rotation matrix, as Rotation.from_matrix().as_rotvec()."""
    return rotvec_from_quaternion(quaternion_from_matrix(matrix))


def slerp_quaternion(start, end, fraction):
    """Quaternion a ``fraction`` of the way from rotation ``start`` to ``end`` (scipy's Slerp of two keys)."""
    start = np.asarray(start, dtype=float)
    end = np.asarray(end, dtype=float)
    start = start / np.sqrt(start @ start)
    end = end / np.sqrt(end @ end)
    inverse_start = start * np.array([-1.0, -1.0, -1.0, 1.0])
    rotvec = rotvec_from_quaternion(compose_quaternions(inverse_start, end))
    return compose_quaternions(start, quaternions_from_rotvecs(rotvec * fraction))


def scipy_rotation():
    """scipy's ``Rotation`` class, imported on the first call (see the module's note on its import cost)."""
    from scipy.spatial.transform import Rotation

    return Rotation
