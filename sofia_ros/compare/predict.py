"""The model side of every effect: predicted centroids of a bag's frames from a model's effects.

The prediction reuses the truth simulator's own physics with the model's parameters:

1. Attitude: the recorded 400 Hz GYRF rates, turned into the TARF rates the model believes
   (sensors.gyro_errors inverted: misalignment, scale, bias, ramp, axis swap, LOS oscillation,
   tracker drift), summed per tick (the plant holds its rate over a tick) and composed from
   the TASCU's first attitude (3.20, B.23), interpolated at each frame's time.
2. Attitude anchors: a piecewise-linear small rotation of IRF with knots every
   ``anchor_spacing_s`` absorbs what no model term describes on long time scales (the gyro
   random walk, 4.2.3; a start attitude known only to arcminutes), as 6.1 fits a drift per block.
3. Stars: ERFA places of the Hipparcos stars (sky.places), refracted with the model's weather
   (Stone, 4.33-4.35) when it has ``atmospheric_refraction``, in the IRF of the model's Earth rate.
4. Cameras: sensors.imager_model.camera_errors with the model's effects - mounting, flexure
   (Tables 3.2, 3.3, 6.2), detector fiducials and scale (3.2-3.7), HIPO clock offset (6.2).
"""

from __future__ import annotations

import dataclasses
import hashlib
from collections import OrderedDict
from collections.abc import Iterable, Iterator, Mapping
from typing import Any, Protocol

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from sofia_ros.frames import pixel_to_vector, vector_to_pixel
from sofia_ros.mount import hrf_from_irf_dcm
from sofia_ros.sensors.gyro_errors import (
    gyro_effect_names,
    gyro_error_model,
    rate_offsets_rad_per_s,
    true_rates_tarf_rad_per_s,
)
from sofia_ros.effects.base import EffectParams
from sofia_ros.effects.context import CameraContext
from sofia_ros.sensors.gyro_errors import tarf_from_gyrf_dcm
from sofia_ros.sensors.imager_model import (
    Scene,
    camera_errors,
    flexure_dcm,
    flexure_key,
    mounted_dcm,
    mounting_key,
    refracted_directions_hrf,
    shifted_centroids_px,
    star_directions_irf,
)
from sofia_ros.sky.catalogue import star_by_hip
from sofia_ros.units import RAD_PER_DEG

__all__ = ['CLOCK_OFFSET_CAMERA', 'NamedParameter', 'Predictor', 'attitudes_at', 'inverse_right_jacobians',
           'propagate_tick_attitudes', 'right_jacobians', 'tick_means']


class NamedParameter(Protocol):
    """A parameter by its effect and name (compare.fit.FreeParameter; not imported: fit builds on this module)."""

    effect: str
    name: str


#: Star places are evaluated on this grid and interpolated; unrefracted places move < 0.003" per minute in IRF.
_PLACE_EPOCH_S = 300.0
#: Entries of each cache, least recently used dropped first. 'main': gyro tracks, star places and hook contexts
#: (a star hop's gyro track is 2.5 MB; a fit steps through a few new ones per iteration). 'rows': attitudes at
#: the rows and their linearization maps (a star hop's are 9 MB each): a Gauss-Newton step evaluates the same rows
#: under the same gyro errors for its prediction, its derivatives and its columns. 'cameras': each camera's errors
#: under an effect set (a column asks for them per camera). 'anchors': the anchors' knot weights and rotations at a
#: set of times (2-3 MB each on a star hop): an iteration asks for one set of each at its anchors for its trial
#: prediction, its IRF derivative and its gyro columns. 'row times': the rows' times under a HIPO clock offset (1 MB
#: on a star hop), with their digest (_times_digest). 'flexure': each camera's flexure DCMs at its rows (9 MB for
#: all a star hop's cameras), which its mountings share. 'mountings': each camera's A_CAM,TARF at its rows (its
#: flexure's array itself without a fixed mounting), apart from 'main', whose gyro tracks pushed them out. These
#: three hold 4 entries, a set of cameras (8 each held 50 MB more at the peak of a star hop's compare).
_CACHE_ENTRIES = {'main': 32, 'rows': 4, 'cameras': 128, 'reach': 1024, 'anchors': 4, 'row times': 4, 'flexure': 4,
                  'mountings': 4}


def _dcms_from_rotvecs(rotvecs):
    """Attitude DCMs of rotation vectors, A = R^T (the passive convention of B.3), (N, 3, 3)."""
    # A writeable copy: scipy's Cython takes no read-only buffer, and cached rotations are read-only.
    return np.swapaxes(Rotation.from_rotvec(np.array(rotvecs, dtype=float).reshape(-1, 3)).as_matrix(), -1, -2)


def propagate_tick_attitudes(increments_rad: npt.ArrayLike, initial_dcm: npt.ArrayLike) -> np.ndarray:
    """A_TARF,IRF at every tick end from per-tick body rotation vectors, A_k = R(phi_k)^T A_k-1 (3.20, B.23).

    The running product in blocks of about sqrt(N) ticks: the products within every block advance
    together (one batched 3x3 product per tick of a block), then each block is carried by the
    product of the blocks before it - about 3N products in 3 sqrt(N) numpy calls, where a scan
    takes N log2(N) and a loop N calls; the same products, grouped differently (rounding ~1e-15).

    Args:
        increments_rad: (N, 3) each tick's body rotation vector phi_k (rad).
        initial_dcm: (3, 3) the attitude A_0 before the first tick.

    Returns:
        (N + 1, 3, 3) A_0 and the attitude at every tick end.
    """
    initial_dcm = np.asarray(initial_dcm, dtype=float)
    steps = _dcms_from_rotvecs(increments_rad)
    count = len(steps)
    size = max(int(np.sqrt(count)), 1)
    blocks = max(-(-count // size), 1)
    prefix = np.concatenate([steps, np.broadcast_to(np.eye(3), (blocks * size - count, 3, 3))])
    prefix = prefix.reshape(blocks, size, 3, 3)
    for tick in range(1, size):
        prefix[:, tick] = prefix[:, tick] @ prefix[:, tick - 1]
    carry = np.empty((blocks, 3, 3))
    carry[0] = initial_dcm
    for block in range(1, blocks):
        carry[block] = prefix[block - 1, -1] @ carry[block - 1]
    attitudes = (prefix @ carry[:, None]).reshape(-1, 3, 3)[:count]
    return np.concatenate([initial_dcm[None], attitudes])


def _tick_fractions(times_s, tick_end_s):
    """The tick each time falls in (index of its end) and the elapsed fraction of that tick."""
    index = np.clip(np.searchsorted(tick_end_s, times_s, side='left'), 1, len(tick_end_s) - 1)
    start_s, end_s = tick_end_s[index - 1], tick_end_s[index]
    return index, (times_s - start_s) / (end_s - start_s)


def attitudes_at(times_s: np.ndarray, tick_end_s: np.ndarray, tick_attitudes: np.ndarray,
                 increments_rad: np.ndarray) -> np.ndarray:
    """Attitudes at times inside the ticks: the tick's constant rate applied for the elapsed fraction.

    Args:
        times_s: (M,) the times (s).
        tick_end_s: (N + 1,) the tick ends (s), ascending.
        tick_attitudes: (N + 1, 3, 3) the attitudes at the tick ends (propagate_tick_attitudes).
        increments_rad: (N, 3) each tick's body rotation vector (rad).

    Returns:
        (M, 3, 3) the attitudes at the times.
    """
    index, fraction = _tick_fractions(times_s, tick_end_s)
    # np.take: a row gather 3x faster than fancy indexing, the same values.
    partial = _dcms_from_rotvecs(np.take(increments_rad, index - 1, axis=0) * fraction[:, None])
    return partial @ np.take(tick_attitudes, index - 1, axis=0)


def _identity_cross_square(rotvecs, cross_coefficient, square_coefficient):
    """I + c1 [phi]x + c2 [phi]x^2 (N, 3, 3) for rows phi and per-row coefficients, element by element with
    [phi]x^2 = phi phi^T - |phi|^2 I: batched 3x3 products cost about twice as much."""
    squares = np.einsum('ni,ni->n', rotvecs, rotvecs)
    matrices = (square_coefficient[:, None] * rotvecs)[:, :, None] * rotvecs[:, None, :]
    for axis in range(3):
        matrices[:, axis, axis] += 1.0 - square_coefficient * squares
    scaled = cross_coefficient[:, None] * rotvecs
    # [phi]x = [[0, -z, y], [z, 0, -x], [-y, x, 0]]
    for row, column, component, sign in ((0, 1, 2, -1.0), (0, 2, 1, 1.0), (1, 2, 0, -1.0)):
        matrices[:, row, column] += sign * scaled[:, component]
        matrices[:, column, row] -= sign * scaled[:, component]
    return matrices


def _angles(rotvecs):
    """|phi|^2 of rows, whether each is below 1e-4 rad (where the closed forms cancel: series instead), and |phi|
    with 1 in place of the small ones."""
    squares = np.einsum('ni,ni->n', rotvecs, rotvecs)
    small = squares < 1e-8
    return squares, small, np.sqrt(np.where(small, 1.0, squares))


def right_jacobians(rotvecs: np.ndarray) -> np.ndarray:
    """J_r(phi) (N, 3, 3) of rows of rotation vectors: R(phi + v) = R(phi) R(J_r(phi) v) to first order (SO(3)),
    J_r = I - (1 - cos|phi|)/|phi|^2 [phi]x + (|phi| - sin|phi|)/|phi|^3 [phi]x^2 (Sola, Deray and Atchuthan 2018,
    "A micro Lie theory", appendix B).

    Args:
        rotvecs: (N, 3) the rotation vectors phi (rad).

    Returns:
        (N, 3, 3) the right Jacobians.
    """
    squares, small, angle = _angles(rotvecs)
    first = np.where(small, 0.5 - squares / 24.0, (1.0 - np.cos(angle)) / angle**2)
    second = np.where(small, 1.0 / 6.0 - squares / 120.0, (angle - np.sin(angle)) / angle**3)
    return _identity_cross_square(rotvecs, -first, second)


def inverse_right_jacobians(rotvecs: np.ndarray) -> np.ndarray:
    """J_r(phi)^-1 (N, 3, 3) in closed form, I + [phi]x / 2 + (1/|phi|^2 - (1 + cos|phi|) / (2 |phi| sin|phi|)) [phi]x^2
    (the SO(3) right Jacobian's inverse: Sola, Deray and Atchuthan 2018, "A micro Lie theory", appendix B).

    A batched np.linalg.inv of right_jacobians costs about five times more (a star hop's 123k rows: 0.46 s).

    Args:
        rotvecs: (N, 3) the rotation vectors phi (rad), |phi| < pi.

    Returns:
        (N, 3, 3) the inverses of right_jacobians(rotvecs).
    """
    squares, small, angle = _angles(rotvecs)
    # The coefficient of [phi]x^2 by its series 1/12 + |phi|^2/720 where |phi| < 1e-4.
    second = np.where(small, 1.0 / 12.0 + squares / 720.0,
                      1.0 / angle**2 - (1.0 + np.cos(angle)) / (2.0 * angle * np.sin(angle)))
    return _identity_cross_square(rotvecs, np.full(len(rotvecs), 0.5), second)


def _contiguous(indices):
    """A slice for sorted, gap-free row indices (views instead of copies), else the indices."""
    if len(indices) and indices[-1] - indices[0] + 1 == len(indices):
        return slice(int(indices[0]), int(indices[-1]) + 1)
    return indices


#: The camera whose row times the model's HIPO clock offset moves (row_times_s, eq. 6.2): one name for the times
#: and for the star directions kept per camera.
CLOCK_OFFSET_CAMERA = 'hipo'


class Predictor:
    """Predicted centroids (px) of one bag's frames for any effect set, with caches per effect family."""

    def __init__(self, observations, *, anchor_spacing_s=30.0):
        self.observations = observations
        centroids = observations.centroids
        self.scene = Scene(observations.scenario.site, observations.scenario.start_utc)
        self.anchor_knots_s = _knots(observations.initial_time_s, float(centroids.stamp_s.max()), anchor_spacing_s)
        self._hips = np.unique(centroids.hip)
        self._hip_row = np.searchsorted(self._hips, centroids.hip)
        gyro = observations.gyro
        self._first_tick = int(np.searchsorted(gyro.tick_end_s, observations.initial_time_s, side='left'))
        self._tick_end_s = gyro.tick_end_s[self._first_tick:]
        self._directions_irf = self._catalogue_directions()
        self._camera_rows = [_contiguous(np.flatnonzero(centroids.camera_index == index))
                             for index in range(len(centroids.cameras))]
        self._caches = {kind: OrderedDict() for kind in _CACHE_ENTRIES}
        self.initial_dcm = observations.initial_tarf_from_irf

    @property
    def anchor_count(self) -> int:
        """Number of anchor knots (three rotation parameters each)."""
        return len(self.anchor_knots_s)

    def anchor_weights(self, times_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Knot index k and fraction f of each time: the anchor there is (1 - f) a_k + f a_k+1.

        Args:
            times_s: (N,) the times (s).

        Returns:
            (N,) the knot indices k and (N,) the fractions f in [0, 1], read-only (cached).
        """
        knots = self.anchor_knots_s

        def compute():
            index = np.clip(np.searchsorted(knots, times_s, side='right') - 1, 0, len(knots) - 2)
            fraction = np.clip((times_s - knots[index]) / (knots[index + 1] - knots[index]), 0.0, 1.0)
            return _read_only(index), _read_only(fraction)

        return self._cached(('anchor weights', self._times_digest(times_s)), compute, kind='anchors')

    def anchor_rotations_rad(self, anchors_rad: npt.ArrayLike, times_s: np.ndarray) -> np.ndarray:
        """The piecewise-linear anchor rotation (N, 3) at times.

        Args:
            anchors_rad: (knots, 3) the anchors' small IRF rotations (rad), or the same flat.
            times_s: (N,) the times (s).

        Returns:
            (N, 3) the interpolated rotation vectors (rad), read-only (cached: a fit's iteration asks for the rows'
            rotations at its anchors for its trial prediction, its IRF derivative and its gyro columns).
        """
        anchors = np.asarray(anchors_rad, dtype=float).reshape(-1, 3)

        def compute():
            index, fraction = self.anchor_weights(times_s)
            return _read_only((1.0 - fraction)[:, None] * np.take(anchors, index, axis=0)
                              + fraction[:, None] * np.take(anchors, index + 1, axis=0))

        return self._cached(('anchor rotations', _bytes_digest(anchors), self._times_digest(times_s)), compute,
                            kind='anchors')

    def _catalogue_directions(self):
        """IRF unit vectors of every observed star on the place epochs, (epochs, stars, 3) (4.1, C.4.2)."""
        stamps = self.observations.centroids.stamp_s
        epochs = np.arange(np.floor(stamps.min() / _PLACE_EPOCH_S), np.floor(stamps.max() / _PLACE_EPOCH_S) + 2)
        stars = [star_by_hip(int(hip)) for hip in self._hips]
        self._epoch_origin = epochs[0]
        return np.stack([star_directions_irf(stars, self.scene, epoch * _PLACE_EPOCH_S) for epoch in epochs])

    def _cached(self, key, compute, *, kind='main'):
        """compute() kept under key in the cache of its kind (_CACHE_ENTRIES)."""
        cache = self._caches[kind]
        if key in cache:
            cache.move_to_end(key)
        else:
            cache[key] = compute()
            if len(cache) > _CACHE_ENTRIES[kind]:
                cache.popitem(last=False)
        return cache[key]

    def _clear_caches(self):
        for cache in self._caches.values():
            cache.clear()

    def _tick_track(self, gyro_effects):
        """Tick-end attitudes and per-tick increments of the gyro data under the model's gyro errors."""
        increments = self._tick_increments(gyro_effects)
        return propagate_tick_attitudes(increments, self.initial_dcm), increments

    def _tick_increments(self, gyro_effects):
        """Per-tick TARF rotation vectors of the gyro data under the model's gyro errors (K, 3).

        The plant holds its rate over a tick and the error model is linear in the rate, so the
        tick means of the samples give the exact tick increments; only vibration lines, fast
        against a tick, are averaged over the samples themselves.
        """
        gyro = self.observations.gyro
        errors = gyro_error_model(gyro_effects)
        lines = errors.vibration_lines
        errors = dataclasses.replace(errors, vibration_lines=None)
        means = gyro.tick_mean_rates_gyrf_rad_per_s
        if lines:
            per_sample = rate_offsets_rad_per_s(gyro_error_model({'vibration_lines': lines}), gyro.time_s, 0.0)
            means = means - tick_means(per_sample, gyro.tick_start_index)
        force_tarf = gyro.tick_mean_specific_force_m_per_s2 @ errors.tarf_from_gyrf.T
        rates = true_rates_tarf_rad_per_s(errors, means, gyro.tick_mean_time_s, gyro.tick_temperature_c, force_tarf)
        return (rates * (gyro.tick_sample_count * gyro.sample_period_s)[:, None])[self._first_tick + 1:]

    @staticmethod
    def _gyro_effects(effects):
        return {name: effects[name] for name in gyro_effect_names(effects) if name in effects}

    def _gyro_track(self, effects):
        gyro_effects = self._gyro_effects(effects)
        return self._cached(('gyro', repr(gyro_effects)), lambda: self._tick_track(gyro_effects))

    def attitudes(self, effects: Mapping[str, EffectParams], times_s: np.ndarray) -> np.ndarray:
        """A_TARF,IRF the model believes at times (gyro propagation only, no anchors).

        Args:
            effects: the model's effects and parameters (its gyro errors count).
            times_s: (N,) the times (s).

        Returns:
            (N, 3, 3) the attitudes, read-only (cached).
        """
        tick_attitudes, increments = self._gyro_track(effects)
        return self._cached(self._times_key('attitudes', effects, times_s),
                            lambda: _read_only(attitudes_at(times_s, self._tick_end_s, tick_attitudes, increments)),
                            kind='rows')

    def _times_key(self, what, effects, times_s):
        # The times by a digest of their bytes: the same rows under other model terms come as new arrays.
        return what, repr(self._gyro_effects(effects)), self._times_digest(times_s)

    def _change_maps(self, effects, times_s):
        """What attitude_changes_irf maps tick increment changes with: per tick A_k+1^T J_r(phi_k), per time
        A(t)^T J_r(f phi) f for the elapsed fraction f of its tick, and the index of each time's tick's increment."""
        tick_attitudes, increments = self._gyro_track(effects)

        def compute():
            index, fraction = _tick_fractions(times_s, self._tick_end_s)
            attitude = self.attitudes(effects, times_s)
            per_tick_map = np.swapaxes(tick_attitudes[1:], 1, 2) @ right_jacobians(increments)
            per_row_map = (np.swapaxes(attitude, 1, 2)
                           @ right_jacobians(np.take(increments, index - 1, axis=0) * fraction[:, None])
                           * fraction[:, None, None])
            return _read_only(per_tick_map), _read_only(per_row_map), _read_only(index - 1)

        return self._cached(self._times_key('change maps', effects, times_s), compute, kind='rows')

    def attitude_changes_irf(self, effects: Mapping[str, EffectParams], changed: Iterable[Mapping[str, EffectParams]],
                             times_s: np.ndarray) -> Iterator[np.ndarray]:
        """The small IRF rotations c (N, 3), A_changed(t) = A(t) R(c)^T, that each effect set of ``changed`` makes of
        the attitudes at times through its gyro errors, one set at a time (a refit's nine gyro parameters at once
        held 27 MB of a star hop's rows).

        The propagation (3.20, B.23) to first order in the change of the tick increments d phi_k:
        c(t) = sum over ticks of A_k^T J_r(phi_k) d phi_k (J_r the right Jacobian of SO(3)), the tick
        of t counted for its elapsed fraction: a column per gyro parameter without propagating the
        gyro track again.

        Args:
            effects: the model's effects and parameters, the attitudes' reference.
            changed: the P changed effect sets.
            times_s: (N,) the times (s).

        Yields:
            (N, 3) the small IRF rotations (rad) of each changed set, in turn.
        """
        _, increments = self._gyro_track(effects)
        # A body rotation b after tick k is the IRF rotation A_k+1^T b from then on (_change_maps).
        per_tick_map, per_row_map, tick_before = self._change_maps(effects, times_s)
        for other in changed:
            delta = self._tick_increments(self._gyro_effects(other)) - increments
            per_tick = np.einsum('kij,kj->ki', per_tick_map, delta)
            cumulative = np.concatenate([np.zeros((1, 3)), np.cumsum(per_tick, axis=0)])
            yield (np.take(cumulative, tick_before, axis=0)
                   + np.einsum('nij,nj->ni', per_row_map, np.take(delta, tick_before, axis=0)))

    def projection_key(self, effects: Mapping[str, EffectParams]) -> tuple[Any, ...]:
        """What a prediction depends on besides the gyro attitude: row times, star places, camera models.

        Args:
            effects: the model's effects and parameters.

        Returns:
            The key: the HIPO clock offset, the star places' key and each camera's model key.
        """
        return (repr(effects.get('timestamp_offset')), self._star_key(effects),
                tuple(self._camera_key(effects, index)[0] for index in range(len(self.observations.centroids.cameras))))

    def parameter_reach(self, effects: Mapping[str, EffectParams], parameter: NamedParameter,
                        stepped_effects: Mapping[str, EffectParams]) -> tuple[bool, bool, tuple[int, ...]]:
        """What a step of one parameter moves: whether the row times or star places (projection_key's first two
        parts), whether only the gyro attitude, and the indices of the cameras whose model it changes.

        Found by comparing the keys of ``effects`` and ``stepped_effects`` (the parameter stepped) once per effect set
        and parameter: which parts a parameter moves is a property of the effects present, not of their values, and
        the keys cost a camera model per camera.

        Args:
            effects: the model's effects and parameters.
            parameter: the parameter stepped.
            stepped_effects: ``effects`` with the parameter stepped.

        Returns:
            Whether the step moves the row times or star places, whether only the gyro attitude, and the
            indices of the cameras whose model it changes.
        """
        def compute():
            projection, stepped = self.projection_key(effects), self.projection_key(stepped_effects)
            moves_rows = stepped[:2] != projection[:2]
            moves_gyro = not moves_rows and self.gyro_key(stepped_effects) != self.gyro_key(effects)
            cameras = tuple(camera for camera, (moved, now) in enumerate(zip(stepped[2], projection[2])) if moved != now)
            return moves_rows, moves_gyro, cameras

        return self._cached((tuple(effects), parameter.effect, parameter.name), compute, kind='reach')

    def gyro_key(self, effects: Mapping[str, EffectParams]) -> str:
        """What the gyro attitude depends on: the model's gyro error terms.

        Args:
            effects: the model's effects and parameters.

        Returns:
            The key: the gyro error terms' repr.
        """
        return repr(self._gyro_effects(effects))

    def _star_directions(self, effects, times_s):
        """Model IRF directions of each row's star at times: refraction and Earth rate as the model has them."""
        return self._directions_of(effects, self._hip_row, times_s)

    def star_direction_irf(self, effects: Mapping[str, EffectParams], row: int, time_s: float) -> np.ndarray:
        """The model's IRF direction of the star of one row at one time.

        Args:
            effects: the model's effects and parameters (refraction, Earth rate).
            row: the centroid row whose star is meant.
            time_s: the time (s).

        Returns:
            (3,) the unit vector in IRF.
        """
        return self._directions_of(effects, self._hip_row[[row]], np.array([float(time_s)]))[0]

    def _directions_of(self, effects, hip_rows, times_s):
        # Linear interpolation between the place epochs (aberration and parallax change smoothly).
        position = np.clip(times_s / _PLACE_EPOCH_S - self._epoch_origin, 0.0, len(self._directions_irf) - 1.0)
        epoch = np.minimum(position.astype(int), len(self._directions_irf) - 2)
        fraction = (position - epoch)[:, None]
        directions = ((1.0 - fraction) * self._directions_irf[epoch, hip_rows]
                      + fraction * self._directions_irf[epoch + 1, hip_rows])
        directions /= np.linalg.norm(directions, axis=1, keepdims=True)
        earth = effects.get('earth_rotation')
        model_rate = earth['rate_deg_per_h'] * RAD_PER_DEG / 3600.0 if earth else 0.0
        refraction = effects.get('atmospheric_refraction')
        hrf_from_irf = hrf_from_irf_dcm(self.scene.earth_latitude_deg, times_s)
        directions_hrf = np.einsum('nij,nj->ni', hrf_from_irf, directions)
        if refraction is not None:
            weather = camera_errors('hipo', {'atmospheric_refraction': refraction}).weather
            directions_hrf = refracted_directions_hrf(directions_hrf, self.scene.site, weather)
        model_hrf_from_irf = hrf_from_irf_dcm(self.scene.earth_latitude_deg, times_s, model_rate)
        return np.einsum('nji,nj->ni', model_hrf_from_irf, directions_hrf)

    def measured_directions_tarf(self, effects: Mapping[str, EffectParams], rows: npt.ArrayLike | None = None) -> np.ndarray:
        """Measured star directions in TARF of the rows (all by default) through the model's detectors and mountings.

        Args:
            effects: the model's effects and parameters (detectors, mountings, flexure).
            rows: the centroid rows (indices or a mask), or None for all.

        Returns:
            (rows, 3) the unit vectors in TARF.
        """
        centroids = self.observations.centroids
        selected = np.zeros(len(centroids), dtype=bool)
        selected[np.arange(len(centroids)) if rows is None else rows] = True
        measured = np.empty((len(centroids), 3))
        times = self.row_times_s(effects)
        for index in range(len(centroids.cameras)):
            camera_rows = centroids.camera_index == index
            chosen = selected & camera_rows
            if not np.any(chosen):
                continue
            errors, mounting, _ = self._camera_model(effects, index, times)
            in_camera = pixel_to_vector(centroids.measured_px[chosen], errors.detector)
            measured[chosen] = np.einsum('nji,nj->ni', mounting[chosen[camera_rows]], in_camera)
        return measured[selected] if rows is not None else measured

    def align_initial_attitude(self, effects: Mapping[str, EffectParams]) -> None:
        """Set the start attitude that best maps the model's stars onto all measured ones (Wahba's problem).

        Args:
            effects: the model's effects and parameters.
        """
        self.initial_dcm = np.eye(3)
        self._clear_caches()
        times = self.row_times_s(effects)
        # With A = A_rel(t) A_0: A_rel(t)^T v_TARF = A_0 d_IRF for every row.
        at_start = np.einsum('nji,nj->ni', self.attitudes(effects, times), self.measured_directions_tarf(effects))
        rotation, _ = Rotation.align_vectors(at_start, self._star_directions(effects, times))
        self.initial_dcm = rotation.as_matrix()
        self._clear_caches()

    def row_times_s(self, effects: Mapping[str, EffectParams]) -> np.ndarray:
        """Each row's exposure-midpoint time on the TA clock: the stamp less the model's HIPO clock offset (6.2).

        Args:
            effects: the model's effects and parameters (its timestamp_offset).

        Returns:
            (N,) the times (s), read-only (cached: the caches of the rows key by them, _times_digest).
        """
        centroids = self.observations.centroids
        offset_s = None
        if 'timestamp_offset' in effects and CLOCK_OFFSET_CAMERA in centroids.cameras:
            offset_s = effects['timestamp_offset']['offset_s']

        def compute():
            times = centroids.stamp_s.copy()
            if offset_s is not None:
                times[centroids.camera_index == centroids.cameras.index(CLOCK_OFFSET_CAMERA)] -= offset_s
            return _KeyedTimes(_read_only(times))

        return self._cached(('row times', repr(offset_s)), compute, kind='row times').times

    def _times_digest(self, times_s):
        """_bytes_digest of times, kept with the arrays row_times_s hands out: an iteration keys its caches by the
        same rows a dozen times, and hashing a star hop's (1 MB) each time cost 2.5 % of a compare. Other arrays
        are hashed each time (they may change between calls)."""
        for keyed in self._caches['row times'].values():
            if keyed.times is times_s:
                if keyed.digest is None:
                    keyed.digest = _bytes_digest(times_s)
                return keyed.digest
        return _bytes_digest(times_s)

    def camera_context(self, effects: Mapping[str, EffectParams], camera_index: int, times_s: np.ndarray) -> CameraContext:
        """The CameraContext of one camera's rows: what plug-in hooks see on the model side (effects.context).

        Args:
            effects: the model's effects and parameters (the gyro misalignment turns the forces into TARF).
            camera_index: the camera's index in the centroids' cameras.
            times_s: (N,) every row's time (s) (row_times_s).

        Returns:
            The camera's rows' context.
        """
        centroids = self.observations.centroids
        rows = centroids.camera_index == camera_index
        gyro = self.observations.gyro
        force_gyrf = np.column_stack([np.interp(times_s[rows], gyro.tick_mean_time_s,
                                                gyro.tick_mean_specific_force_m_per_s2[:, axis]) for axis in range(3)])
        force_tarf = force_gyrf @ tarf_from_gyrf_dcm(effects).T
        return CameraContext(centroids.cameras[camera_index], times_s[rows], centroids.elevation_deg[rows],
                             centroids.temperature_c[rows], force_tarf, centroids.fd_los_deg[rows])

    def _camera_key(self, effects, index):
        """What one camera's projection depends on under effects (its errors, its hooks' context), and its errors."""
        camera = self.observations.centroids.cameras[index]

        def compute():
            errors = camera_errors(camera, effects)
            hooked = bool(errors.plugins or errors.shift_plugins)
            # A hook's context depends on the row times (HIPO clock offset) and the misalignment (forces in TARF).
            context = repr((effects.get('timestamp_offset'), effects.get('gyro_misalignment'))) if hooked else None
            return (camera, repr(errors), context), errors

        return self._cached((camera, repr(effects)), compute, kind='cameras')

    def _camera_model(self, effects, index, times_s):
        """A_CAM,TARF of one camera's rows, its errors and its hooks' context (each cached by what it depends on)."""
        centroids = self.observations.centroids
        (camera, _, context_key), errors = self._camera_key(effects, index)
        context = None
        if context_key is not None:
            context = self._cached(('context', camera, context_key),
                                   lambda: self.camera_context(effects, index, times_s))
        # Only rotation hooks see the context. The mounting is kept by what turns the frame alone (a HIPO clock
        # offset or a detector's fiducials leave it), and its flexure apart from the fixed mounting: a step of a
        # boresight offset or a rotation of field multiplies the kept flexure again (from_rotvec of the rows saved).
        hooks_context = context_key if errors.plugins else None

        def mounting():
            flexure = self._cached(('flexure', camera, flexure_key(errors), hooks_context), lambda: _read_only(
                flexure_dcm(errors, centroids.elevation_deg[centroids.camera_index == index], context)),
                                   kind='flexure')
            return _read_only(mounted_dcm(errors, flexure))

        return errors, self._cached(('mount', camera, mounting_key(errors), hooks_context), mounting,
                                    kind='mountings'), context

    @staticmethod
    def _star_key(effects):
        # The directions depend on the sky effects and the row times (the HIPO clock offset) only.
        return ('stars', repr(effects.get('atmospheric_refraction')), repr(effects.get('earth_rotation')),
                repr(effects.get('timestamp_offset')))

    def _directions(self, effects, times):
        """_star_directions of every row (N, 3), kept camera by camera: a HIPO clock offset (a fit steps it every
        iteration) moves HIPO's rows alone, and the other cameras' directions (122k of the Waco star hop's 123k
        rows) are read back. A row's direction depends on its own star and time only: the same numbers."""
        directions = np.empty((len(times), 3))
        for index, rows in enumerate(self._camera_rows):
            directions[rows] = self._cached(
                self._camera_star_key(effects, index),
                lambda rows=rows: _read_only(self._directions_of(effects, self._hip_row[rows], times[rows])))
        return directions

    def _camera_star_key(self, effects, camera_index):
        # A camera's row times move with the HIPO clock offset only if it is HIPO (row_times_s).
        moves_in_time = self.observations.centroids.cameras[camera_index] == CLOCK_OFFSET_CAMERA
        return ('stars', camera_index, repr(effects.get('atmospheric_refraction')), repr(effects.get('earth_rotation')),
                repr(effects.get('timestamp_offset')) if moves_in_time else None)

    def _anchor_correction(self, anchors_rad, times):
        if anchors_rad is None:
            return np.zeros((len(times), 3))
        return self.anchor_rotations_rad(anchors_rad, times)

    def _project_camera_px(self, effects, index, rows_in_tarf, times):
        """Pixels (rows, 2) of one camera's rows from their TARF star directions through its model."""
        rows = self._camera_rows[index]
        errors, mounting, context = self._camera_model(effects, index, times)
        pixels = vector_to_pixel(np.einsum('nij,nj->ni', mounting, rows_in_tarf), errors.detector)
        if errors.shift_plugins:
            pixels = shifted_centroids_px(errors, pixels, context, self.observations.centroids.hip[rows])
        return pixels

    def _project_px(self, effects, in_tarf, times):
        """Pixels (N, 2) of TARF star directions through each camera's model."""
        predicted = np.empty((len(times), 2))
        for index, rows in enumerate(self._camera_rows):
            predicted[rows] = self._project_camera_px(effects, index, in_tarf[rows], times)
        return predicted

    def tarf_directions(self, effects: Mapping[str, EffectParams], anchors_rad: npt.ArrayLike | None = None) -> np.ndarray:
        """The rows' model star directions in TARF (N, 3), what the cameras see: star places, anchors, gyro attitude.

        Args:
            effects: the model's effects and parameters.
            anchors_rad: (knots, 3) the attitude anchors (rad), or None for none.

        Returns:
            (N, 3) the unit vectors in TARF.
        """
        times = self.row_times_s(effects)
        correction = self._anchor_correction(anchors_rad, times)
        directions = self._directions(effects, times)
        if np.any(correction):
            directions = np.einsum('nij,nj->ni', _dcms_from_rotvecs(correction), directions)
        return np.einsum('nij,nj->ni', self.attitudes(effects, times), directions)

    def predict_px(self, effects: Mapping[str, EffectParams], anchors_rad: npt.ArrayLike | None = None) -> np.ndarray:
        """Predicted centroids (N, 2) px; anchors (knots, 3) rad.

        Args:
            effects: the model's effects and parameters.
            anchors_rad: (knots, 3) the attitude anchors (rad), or None for none.

        Returns:
            (N, 2) the predicted centroids (px).
        """
        return self._project_px(effects, self.tarf_directions(effects, anchors_rad), self.row_times_s(effects))

    def camera_rows(self, camera_index: int) -> slice | np.ndarray:
        """The rows of one camera (a slice where they are contiguous), as predict_px orders them.

        Args:
            camera_index: the camera's index in the centroids' cameras.

        Returns:
            The rows.
        """
        return self._camera_rows[camera_index]

    def predict_camera_px(self, effects: Mapping[str, EffectParams], camera_index: int,
                          anchors_rad: npt.ArrayLike | None = None) -> np.ndarray:
        """predict_px's rows of one camera (camera_rows), computed alone and not cached: a row's prediction depends
        on its own time only, so a trial that moves one camera's times (a HIPO clock offset) costs that camera's rows.

        Args:
            effects: the model's effects and parameters.
            camera_index: the camera's index in the centroids' cameras.
            anchors_rad: (knots, 3) the attitude anchors (rad), or None for none.

        Returns:
            (n, 2) the camera's predicted centroids (px).
        """
        rows = self._camera_rows[camera_index]
        all_times = self.row_times_s(effects)
        times = all_times[rows]
        directions = self._directions_of(effects, self._hip_row[rows], times)
        correction = self._anchor_correction(anchors_rad, times)
        if np.any(correction):
            directions = np.einsum('nij,nj->ni', _dcms_from_rotvecs(correction), directions)
        tick_attitudes, increments = self._gyro_track(effects)
        attitudes = attitudes_at(times, self._tick_end_s, tick_attitudes, increments)
        return self._project_camera_px(effects, camera_index, np.einsum('nij,nj->ni', attitudes, directions),
                                       all_times)

    def reprojected_px(self, effects: Mapping[str, EffectParams], cameras: Iterable[int], in_tarf: np.ndarray,
                       predicted_px: npt.ArrayLike) -> np.ndarray:
        """predict_px under ``effects``, which change only the models of the cameras (indices) against the effect set
        of ``in_tarf`` (its tarf_directions) and ``predicted_px``: the other cameras' rows are kept as they were.

        Args:
            effects: the changed effects and parameters.
            cameras: the indices of the cameras whose model they change.
            in_tarf: (N, 3) the rows' TARF directions under the earlier effect set.
            predicted_px: (N, 2) the centroids predicted under the earlier effect set (px).

        Returns:
            (N, 2) the centroids (px), a new array.
        """
        times = self.row_times_s(effects)
        pixels = np.array(predicted_px, dtype=float)
        for index in cameras:
            rows = self._camera_rows[index]
            pixels[rows] = self._project_camera_px(effects, index, in_tarf[rows], times)
        return pixels

    def irf_derivative_px(self, effects: Mapping[str, EffectParams], anchors_rad: npt.ArrayLike | None, predicted_px: np.ndarray,
                          step_rad: float) -> np.ndarray:
        """Forward differences d predicted px / d IRF rotation (N, 2, 3), as predict_px with a further IRF rotation
        of step_rad about each axis would give, sharing the attitudes, star places and camera models.

        Args:
            effects: the model's effects and parameters.
            anchors_rad: (knots, 3) the attitude anchors (rad), or None for none.
            predicted_px: (N, 2) predict_px under the same effects and anchors (px).
            step_rad: the rotation step about each IRF axis (rad).

        Returns:
            (N, 2, 3) the derivatives (px/rad).
        """
        times = self.row_times_s(effects)
        correction = self._anchor_correction(anchors_rad, times)
        attitude = self.attitudes(effects, times)
        directions = self._directions(effects, times)
        derivative = np.empty((len(times), 2, 3))
        for axis in range(3):
            moved = correction.copy()
            moved[:, axis] += step_rad
            in_tarf = np.einsum('nij,nj->ni', attitude,
                                np.einsum('nij,nj->ni', _dcms_from_rotvecs(moved), directions))
            derivative[:, :, axis] = (self._project_px(effects, in_tarf, times) - predicted_px) / step_rad
        return derivative


def tick_means(per_sample: np.ndarray, tick_start_index: np.ndarray) -> np.ndarray:
    """Mean of per-sample rows over each tick (zero for a tick without samples).

    Args:
        per_sample: (S, C) one row per sample.
        tick_start_index: (K,) the index of each tick's first sample, ascending.

    Returns:
        (K, C) each tick's mean row.
    """
    counts = np.diff(np.append(tick_start_index, len(per_sample)))
    sums = np.add.reduceat(per_sample, np.minimum(tick_start_index, len(per_sample) - 1), axis=0)
    sums[counts == 0] = 0.0
    return sums / np.maximum(counts, 1)[:, None]


def _bytes_digest(array):
    """A digest of a float array's values, to key a cache by (the same values come as new arrays)."""
    return hashlib.blake2b(np.ascontiguousarray(array, dtype=float).tobytes(), digest_size=16).digest()


@dataclasses.dataclass
class _KeyedTimes:
    """Row times as row_times_s keeps them, and their digest once a cache has asked for it."""

    times: np.ndarray
    digest: bytes | None = None


def _read_only(array):
    """The array, locked: cached arrays are shared by every caller."""
    array.flags.writeable = False
    return array


def _knots(start_s, end_s, spacing_s):
    count = max(int(np.ceil((end_s - start_s) / spacing_s)), 1)
    return np.linspace(start_s, end_s, count + 1)
