"""Alignment solvers: the closed forms of 3.3.2 (eqs. 3.10-3.19) and a least-squares fit.

Frames and signs follow :mod:`sofia_ros.frames` (rows convention, ``A ~= I - [theta x]``).

Model of a maneuver (3.3.2, Table 3.4): the TASCU, believing ``A_est`` (the
alignment matrix active when the maneuver was flown), servoes the gyros until the
gyro-sensed rotation is ``angle_rad`` about ``A_est^T e_k``. The true rotation of
TARF is then about ``M e_k`` with ``M = A_true A_est^T``; the star is fixed in
inertial space, so its TARF pointing vector turns the opposite way,
``s_e = A(g, angle) s_b`` with ``A`` the passive DCM of that rotation. The closed
forms measure ``M``: its LOS column from LOS maneuvers, its rotation about LOS
(``beta``) from EL/XEL maneuvers; the corrected alignment is ``A_true = M A_est``.

Slips in the printed equations (see the tests): 3.16 and 3.17 cannot both vanish
for the two perpendicular motions of an aligned telescope. Under eqs. 3.5-3.6 an
EL rotation moves the star at 90 deg - phi from the X axis and an XEL rotation at
-phi, so ``beta_EL = arctan(dY/dX) - (90 deg - phi)`` (the expression printed as
3.17) and ``beta_XEL = arctan(-dX/dY) - (90 deg - phi)``; both then equal the
rotation of ``M`` about LOS, the ``beta`` of eq. 3.18.

:func:`fit_alignment` fits that model to every maneuver at once. Unknowns: the
small rotations about the axes in ``solve_for`` (others held at ``initial_dcm``)
and, as nuisance parameters, each star's true start centroid; residuals are the
measured minus modelled start and end centroids in px. On HIPO the fitted DCM is
``A_TARF,GYRF`` (Table 3.4 steps 2-3). On an imager, with the gyros already
aligned (``active_alignment`` = identity), the same model gives
``A_XYIRF,TARF``: its rotation about LOS is the rotation of field (3.3.3, step 4)
and its LOS column is TARF's w-axis in the imager, the boresight of step 1.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sofia_ros.errors import InvalidArgumentError
from sofia_ros.frames import HIPO_2004, pixel_to_vector, vector_to_pixel
from sofia_ros.rotation_kernels import matrices_from_rotvecs, rotvec_from_matrix
from sofia_ros.validate import finite_array, finite_scalar, orthonormal_dcm, positive_scalar, unit_vector

__all__ = [
    'AXIS_VECTORS',
    'los_misalignment_px',
    'turning_point_two_stars_px',
    'candidate_rotation_axes',
    'select_rotation_axis',
    'el_misalignment_rad',
    'xel_misalignment_rad',
    'dcm_from_w_and_beta',
    'gyro_alignment_from_axes',
    'passive_rotate',
    'Maneuver',
    'AlignmentFit',
    'fit_alignment',
]

#: TARF rotation axes: EL = u, XEL = v, LOS = w.
AXIS_VECTORS = {'el': np.eye(3)[0], 'xel': np.eye(3)[1], 'los': np.eye(3)[2]}
for _axis in AXIS_VECTORS.values():
    _axis.flags.writeable = False
#: Denominators below this (px^2 or unit vectors) are treated as zero.
_DEGENERATE = 1e-12


def _pixel(name, value):
    return finite_array(name, value, shape=(2,))


def _nonzero_angle(name, value):
    angle = finite_scalar(name, value)
    if abs(np.sin(angle / 2.0)) < _DEGENERATE:
        raise InvalidArgumentError(f'{name} must be a non-zero rotation angle (it is divided by), got {angle}')
    return angle


def los_misalignment_px(start_px, end_px, angle_rad):
    """LOS misalignment R in px from one star's start/end centroids and the LOS rotation angle (eq. 3.10)."""
    chord = np.linalg.norm(_pixel('end_px', end_px) - _pixel('start_px', start_px))
    return float(chord / (2.0 * np.sin(abs(_nonzero_angle('angle_rad', angle_rad)) / 2.0)))


def turning_point_two_stars_px(start1_px, end1_px, start2_px, end2_px):
    """LOS turning point (X_T, Y_T) in px from two stars before and after a rotation (eqs. 3.11-3.12)."""
    (x1b, y1b), (x1e, y1e) = _pixel('start1_px', start1_px), _pixel('end1_px', end1_px)
    (x2b, y2b), (x2e, y2e) = _pixel('start2_px', start2_px), _pixel('end2_px', end2_px)
    c1 = y1e**2 - y1b**2 + x1e**2 - x1b**2
    c2 = y2e**2 - y2b**2 + x2e**2 - x2b**2
    denominator = 2.0 * ((x1b - x1e) * (y2e - y2b) - (x2b - x2e) * (y1e - y1b))
    if abs(denominator) < _DEGENERATE:
        raise InvalidArgumentError('the two stars moved along parallel chords: no turning point (eq. 3.11)')
    if abs(y1e - y1b) < _DEGENERATE:
        raise InvalidArgumentError('star 1 moved parallel to X: eq. 3.12 divides by zero; swap the stars')
    x_t = ((y1e - y1b) * c2 - (y2e - y2b) * c1) / denominator
    y_t = (2.0 * (x1b - x1e) * x_t + c1) / (2.0 * (y1e - y1b))
    return np.array([x_t, y_t])


def candidate_rotation_axes(start_vector, end_vector, angle_rad):
    """The two rotation axes g1, g2 that carry s_b to s_e by a known angle (eqs. 3.13-3.15)."""
    s_b = unit_vector('start_vector', start_vector)
    s_e = unit_vector('end_vector', end_vector)
    angle = _nonzero_angle('angle_rad', angle_rad)
    total, cross = s_e + s_b, np.cross(s_e, s_b)
    if np.linalg.norm(cross) < _DEGENERATE or np.linalg.norm(total) < _DEGENERATE:
        raise InvalidArgumentError('start and end vectors are parallel: no rotation axis (eq. 3.14)')
    ratio = np.linalg.norm(s_e - s_b) / (np.linalg.norm(total) * np.tan(abs(angle) / 2.0))
    if ratio > 1.0 + 1e-9:
        raise InvalidArgumentError(
            f'angle_rad {angle} is too small to carry s_b to s_e (eq. 3.13: sin x = {ratio:.6g})')
    # Round-off can put an exact 90 deg case (axis perpendicular to s_b) just above 1.
    x = np.arcsin(min(ratio, 1.0))
    # Eq. 3.14 assumes angle > 0; for a signed angle the cross term flips so that
    # s_e = A(g, angle) s_b holds for both candidates and g1 stays along s_b + s_e.
    normal = np.sign(angle) * cross / np.linalg.norm(cross)
    bisector = total / np.linalg.norm(total)
    return np.cos(x) * bisector + np.sin(x) * normal, -np.cos(x) * bisector + np.sin(x) * normal


def select_rotation_axis(g1, g2, axis):
    """Pick the rotation axis as the text of 3.3.2 says: g1 for LOS, in-plane g for EL/XEL (eqs. 3.14-3.15)."""
    if axis == 'los':
        return unit_vector('g1', g1)
    if axis not in ('el', 'xel'):
        raise InvalidArgumentError(f"axis must be 'el', 'xel' or 'los', got {axis!r}")
    # The candidates differ in the sign of their LOS component; with orthogonal axes
    # the true EL/XEL axis lies in the CCD plane: average, drop LOS, renormalize.
    mean = unit_vector('g1', g1) + unit_vector('g2', g2)
    return unit_vector('in-plane axis', [mean[0], mean[1], 0.0])


def _displacement(start_px, end_px):
    return _pixel('end_px', end_px) - _pixel('start_px', start_px)


def el_misalignment_rad(start_px, end_px, phi_rad):
    """In-plane misalignment beta_EL from an EL maneuver on HIPO (eq. 3.16, corrected: see module notes)."""
    dx, dy = _displacement(start_px, end_px)
    if abs(dx) < _DEGENERATE:
        raise InvalidArgumentError('EL maneuver moved the star parallel to Y: beta_EL divides by dX = 0')
    return float(np.arctan(dy / dx) - (np.pi / 2.0 - finite_scalar('phi_rad', phi_rad)))


def xel_misalignment_rad(start_px, end_px, phi_rad):
    """In-plane misalignment beta_XEL from an XEL maneuver on HIPO (eq. 3.17, corrected: see module notes)."""
    dx, dy = _displacement(start_px, end_px)
    if abs(dy) < _DEGENERATE:
        raise InvalidArgumentError('XEL maneuver moved the star parallel to X: beta_XEL divides by dY = 0')
    return float(np.arctan(-dx / dy) - (np.pi / 2.0 - finite_scalar('phi_rad', phi_rad)))


def dcm_from_w_and_beta(w, beta_rad):
    """DCM with rows u, v, w from the w-axis and in-plane angle beta, v1 = tan(beta) v2 (eqs. 3.18-3.19)."""
    w_axis = unit_vector('w', w)
    beta = finite_scalar('beta_rad', beta_rad)
    w1, w2, w3 = w_axis
    if w3 <= 0.0:
        raise InvalidArgumentError('w must be less than 90 deg from the reference w-axis (w3 > 0, eq. 3.18)')
    if abs(np.cos(beta)) < _DEGENERATE:
        raise InvalidArgumentError('beta_rad must be less than 90 deg in magnitude (eq. 3.18 uses tan beta)')
    tan_beta = np.tan(beta)
    v2 = np.sqrt(1.0 / ((tan_beta**2 + 1.0) + ((w1 * tan_beta + w2) / w3) ** 2))
    v1 = tan_beta * v2
    v_axis = np.array([v1, v2, (-v1 * w1 - v2 * w2) / w3])
    return np.vstack([np.cross(v_axis, w_axis), v_axis, w_axis])


def gyro_alignment_from_axes(los_axis_tarf, beta_rad, active_alignment):
    """Corrected A_TARF,GYRF = M A_est with M's columns from the LOS axis and beta (eqs. 3.18-3.19, 3.20)."""
    active = orthonormal_dcm('active_alignment', active_alignment)
    # The measured axes are gyro axes seen in TARF, i.e. the COLUMNS of M (eq. 3.1).
    return dcm_from_w_and_beta(los_axis_tarf, beta_rad).T @ active


def passive_rotate(vectors, axes, angles_rad):
    """Vectors seen from a frame turned by angle about axis: s' = A(g, angle) s (eq. B.3, Rodrigues)."""
    s = np.asarray(vectors, dtype=float)
    g = np.asarray(axes, dtype=float)
    angle = np.asarray(angles_rad, dtype=float)[..., None]
    dot = np.sum(g * s, axis=-1, keepdims=True)
    return s * np.cos(angle) - np.cross(g, s) * np.sin(angle) + g * dot * (1.0 - np.cos(angle))



def _read_only(array):
    array = np.array(array, dtype=float)
    array.flags.writeable = False
    return array


@dataclass(frozen=True, eq=False)
class Maneuver:
    """One commanded rotation and the star's averaged start/end centroids (3.3.2, Table 3.4)."""

    axis: object  # 'el' | 'xel' | 'los' or a TARF 3-vector
    angle_rad: float
    start_px: np.ndarray
    end_px: np.ndarray
    active_alignment: np.ndarray = field(default_factory=lambda: np.eye(3))
    #: time from the start frames to the end frames, for the residual drift fit (6.1)
    duration_s: float = 0.0
    #: maneuvers of one block share one residual drift (a block follows one drift estimation)
    block: int = 0

    def __post_init__(self):
        if isinstance(self.axis, str):
            if self.axis not in AXIS_VECTORS:
                raise InvalidArgumentError(
                    f"axis must be 'el', 'xel', 'los' or a 3-vector, got {self.axis!r}")
        else:
            object.__setattr__(self, 'axis', _read_only(unit_vector('axis', self.axis)))
        object.__setattr__(self, 'angle_rad', _nonzero_angle('angle_rad', self.angle_rad))
        object.__setattr__(self, 'start_px', _read_only(_pixel('start_px', self.start_px)))
        object.__setattr__(self, 'end_px', _read_only(_pixel('end_px', self.end_px)))
        active = orthonormal_dcm('active_alignment', self.active_alignment)
        object.__setattr__(self, 'active_alignment', _read_only(active))
        duration = finite_scalar('duration_s', self.duration_s)
        if duration < 0.0:
            raise InvalidArgumentError(f'duration_s must be >= 0, got {duration}')
        object.__setattr__(self, 'duration_s', duration)
        if int(self.block) != self.block or self.block < 0:
            raise InvalidArgumentError(f'block must be a non-negative integer, got {self.block}')

    @property
    def axis_vector(self):
        """Commanded rotation axis as a TARF unit vector."""
        return AXIS_VECTORS[self.axis] if isinstance(self.axis, str) else self.axis

    @classmethod
    def from_vectors(cls, axis, angle_rad, start_vector, end_vector, detector=HIPO_2004,
                     active_alignment=None):
        """Maneuver from start/end pointing vectors in the detector frame (inverse of eqs. 3.2-3.7)."""
        pixels = vector_to_pixel(np.vstack([start_vector, end_vector]), detector)
        active = np.eye(3) if active_alignment is None else active_alignment
        return cls(axis, angle_rad, pixels[0], pixels[1], active)


@dataclass(frozen=True, eq=False)
class AlignmentFit:
    """Least-squares alignment from repeated maneuvers, with 1-sigma from the Jacobian (3.3, 3.5)."""

    dcm: np.ndarray  # A_TARF,GYRF on HIPO; A_XYIRF,TARF on an imager with aligned gyros
    angles_rad: np.ndarray  # simultaneous rotation angles of dcm about EL, XEL, LOS (B.19-B.22)
    sigma_rad: np.ndarray  # 1-sigma of small rotations about EL, XEL, LOS; 0 for held angles
    covariance_rad2: np.ndarray
    residuals_px: np.ndarray  # per maneuver: start X, Y, end X, Y (measured - model)
    n_maneuvers: int
    sigma_c_px: float  # centroid sigma that scales the covariance (given or from the residuals)
    solved_axes: tuple
    drift_px_per_s: np.ndarray  # fitted residual drift per block (X, Y), empty without fit_drift


#: Central-difference step of the Jacobian, in px and px-equivalent angle.
_STEP_PX = 1e-3


class _ManeuverModel:
    """End centroids predicted from the star's start centroids and the alignment (3.3.2 model)."""

    def __init__(self, maneuvers, detector, solve_for, reference, fit_drift=False):
        self.detector = detector
        self.scale = detector.scale_rad_per_px
        self.index = [list(AXIS_VECTORS).index(name) for name in solve_for]
        # Axis the gyros turn about, in GYRF: A_est^T e_k.
        self.gyro_axes = np.array([m.active_alignment.T @ m.axis_vector for m in maneuvers])
        self.angles = np.array([m.angle_rad for m in maneuvers])
        self.start = np.array([m.start_px for m in maneuvers])
        self.end = np.array([m.end_px for m in maneuvers])
        self.reference = reference
        blocks = sorted({m.block for m in maneuvers}) if fit_drift else []
        self.block_index = np.array([blocks.index(m.block) for m in maneuvers]) if fit_drift else None
        self.durations = np.array([m.duration_s for m in maneuvers])
        self.n_drift = 2 * len(blocks)
        self.k = len(self.index)

    @property
    def n_leading(self):
        """Unknowns before the per-maneuver start centroids: angles and block drifts (px/s)."""
        return self.k + self.n_drift

    def starts(self, x):
        return x[self.n_leading:].reshape(-1, 2)

    def drift_shift_px(self, x):
        """Residual drift (px/s per block) times each maneuver's duration (6.1)."""
        if not self.n_drift:
            return 0.0
        drifts = x[self.k:self.n_leading].reshape(-1, 2)
        return drifts[self.block_index] * self.durations[:, np.newaxis]

    def dcm(self, x):
        # Angles are carried as theta / S (px-equivalent) so that every unknown is O(px).
        theta = np.zeros(3)
        theta[self.index] = x[: len(self.index)] * self.scale
        return matrices_from_rotvecs(theta).T @ self.reference

    def end_px(self, x):
        axes = self.gyro_axes @ self.dcm(x).T
        axes /= np.linalg.norm(axes, axis=1, keepdims=True)
        turned = passive_rotate(pixel_to_vector(self.starts(x), self.detector), axes, self.angles)
        return vector_to_pixel(turned, self.detector) + self.drift_shift_px(x)

    def residuals(self, x):
        return np.hstack([self.start - self.starts(x), self.end - self.end_px(x)]).ravel()

    def jacobian(self, x):
        k, n, lead = self.k, len(self.start), self.n_leading
        jac = np.zeros((4 * n, lead + 2 * n))
        rows = np.arange(n) * 4
        for j in range(k):
            step = np.zeros_like(x)
            step[j] = _STEP_PX
            d_end = (self.end_px(x + step) - self.end_px(x - step)) / (2 * _STEP_PX)
            jac[rows + 2, j], jac[rows + 3, j] = -d_end[:, 0], -d_end[:, 1]
        if self.n_drift:
            for c in range(2):
                columns = k + 2 * self.block_index + c
                jac[rows + 2 + c, columns] = -self.durations
        # Each maneuver's start only moves its own end: perturb all of them at once.
        for c in range(2):
            step = np.zeros((n, 2))
            step[:, c] = _STEP_PX
            delta = np.r_[np.zeros(lead), step.ravel()]
            d_end = (self.end_px(x + delta) - self.end_px(x - delta)) / (2 * _STEP_PX)
            columns = lead + 2 * np.arange(n) + c
            jac[rows + c, columns] = -1.0
            jac[rows + 2, columns], jac[rows + 3, columns] = -d_end[:, 0], -d_end[:, 1]
        return jac


def fit_alignment(maneuvers, detector=HIPO_2004, *, solve_for=('el', 'xel', 'los'),
                  initial_dcm=None, sigma_c_px=None, fit_drift=False):
    """Alignment DCM from all maneuvers at once by least squares (3.3.2-3.3.3 model, 3.30 covariance).

    With ``fit_drift`` a residual linear centroid drift (px/s) per block of maneuvers is
    fitted and removed as in 6.1; it needs maneuvers of both signs in every block.
    """
    maneuvers = list(maneuvers)
    if not maneuvers or not all(isinstance(m, Maneuver) for m in maneuvers):
        raise InvalidArgumentError('maneuvers must be a non-empty sequence of Maneuver records')
    solve_for = tuple(solve_for)
    if not solve_for or len(set(solve_for)) != len(solve_for) or not set(solve_for) <= set(AXIS_VECTORS):
        raise InvalidArgumentError(
            f"solve_for must be distinct names from 'el', 'xel', 'los', got {solve_for}")
    if initial_dcm is None:
        reference = maneuvers[0].active_alignment
    else:
        reference = orthonormal_dcm('initial_dcm', initial_dcm)
    model = _ManeuverModel(maneuvers, detector, solve_for, reference, fit_drift)
    k, n = len(solve_for), len(maneuvers)
    x0 = np.r_[np.zeros(model.n_leading), model.start.ravel()]
    # Imported here: scipy.optimize (0.1-0.3 CPU-s) is needed when the fit runs, not by every node process that
    # imports this module through sim.calibration.
    from scipy.optimize import least_squares

    solution = least_squares(model.residuals, x0, jac=model.jacobian,
                             xtol=1e-12, ftol=1e-12, gtol=1e-12)
    # Re-linearize at the solution so that sigma refers to small rotations about the TARF axes.
    model.reference = model.dcm(solution.x)
    x_hat = np.r_[np.zeros(k), solution.x[k:]]
    drift_px_per_s = solution.x[k:model.n_leading].reshape(-1, 2)
    jac = model.jacobian(x_hat)
    residuals = model.residuals(x_hat)
    norms = np.linalg.norm(jac, axis=0)
    singular = np.linalg.svd(jac / np.where(norms > 0.0, norms, 1.0), compute_uv=False)
    if np.any(norms == 0.0) or singular[-1] < 1e-6 * singular[0]:
        raise InvalidArgumentError(
            f'angles about {solve_for} are not all observable from these maneuvers '
            '(LOS rotations do not see the rotation about LOS; a residual drift needs maneuvers of both '
            'signs in every block); restrict solve_for or fly both signs')
    if sigma_c_px is None:
        dof = 4 * n - (model.n_leading + 2 * n)
        if dof <= 0:
            raise InvalidArgumentError(
                f'{n} maneuver(s) leave no residual degrees of freedom; pass sigma_c_px')
        sigma_c = float(np.sqrt(residuals @ residuals / dof))
    else:
        sigma_c = positive_scalar('sigma_c_px', sigma_c_px)
    covariance_x = np.linalg.inv(jac.T @ jac)[:k, :k] * (sigma_c * model.scale) ** 2
    covariance = np.zeros((3, 3))
    covariance[np.ix_(model.index, model.index)] = covariance_x
    dcm = model.reference
    return AlignmentFit(
        dcm=_read_only(dcm),
        angles_rad=_read_only(rotvec_from_matrix(dcm.T)),
        sigma_rad=_read_only(np.sqrt(np.diag(covariance))),
        covariance_rad2=_read_only(covariance),
        residuals_px=_read_only(residuals.reshape(n, 4)),
        n_maneuvers=n,
        sigma_c_px=sigma_c,
        solved_axes=solve_for,
        drift_px_per_s=_read_only(drift_px_per_s),
    )
