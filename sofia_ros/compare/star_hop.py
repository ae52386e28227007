"""Star-hop analysis of a bag: measured against catalogue distances (Table 6.7, Fig. 6.11) and imager flexure (Fig. 6.4).

For each hold window (the calibration node's /calibration/result): HIPO's locked centroids of
the held star, mapped through the model's HIPO (detector 3.5-3.7, flexure) and gyro attitude
(compare.predict, no anchors) into IRF directions; their linear drift during the hold is the
gyro drift (6.3). For each move between consecutive holds the drift is solved as one rotation
rate from both holds' drifts and removed over the move where it stands out of its noise (6.3-6.6;
the model's gyro biases are left out: fitted to the whole run they would take up part of a missing
scale error); the angle between the two
directions is the measured distance, compared with the catalogue distance of the two stars'
observed places in IRF with and without refraction (4.36-4.38, 6.2, Table D.3). The deviation
against distance is fitted with a line (Fig. 6.11).

Short moves (6.3, Fig. 6.10, Tables D.5, D.6): the FPI centroid of the star just before the move
(the last locked frames before the move starts) and of the next star just after it (the first
locked frames of its hold), each the mean of three frames; the attitude change between the two
times from the same gyro attitude, with the holds' drift removed over the short interval (the
TA's drift estimation on the tracked star, which this campaign does not run), as EL, XEL with
LOS last of the FPI's own frame (the model's FPI mounting and flexure at each elevation: the
pixels are the FPI's, as eq. 6.5 turns the rotation into the FPI frame); EL, XEL corrected by
the pixels (6.7-6.8) give the distance (4.38), against the catalogue distance at the same two
times. Their deviations get their own line, weighted by the predicted sigma of each move.

The FPI and FFI see the HIPO-centred star during every hold: their offsets from the first hold,
as rotations (6.2), against elevation, give the differential flexure beside the FEM prediction
(Table 3.3, Fig. 6.4). The FPI centroid of each hold is fitted for its residual drift, column
linear and row linear plus a sinusoid where the BIC selects it (6.3, analysis.centroid_drift).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt
import yaml
from scipy.spatial.transform import Rotation

from sofia_ros.analysis.centroid_drift import fit_centroid_drift
from sofia_ros.calibration.boresights import boresight_shift_arcsec, flexure_fit
from sofia_ros.compare.observations import MOTION_STATES, Centroids
from sofia_ros.effects.base import EffectParams
from sofia_ros.errors import BagError
from sofia_ros.flexure import differential_imager_rotation_arcsec, gravity_load_tarf
from sofia_ros.sensors.imager_model import camera_errors, camera_from_tarf_dcm, nominal_detector
from sofia_ros.sky.distances import attitude_change_euler_arcsec, short_move_euler_arcsec, spherical_sum_arcsec
from sofia_ros.units import ARCSEC_PER_RAD

if TYPE_CHECKING:
    from sofia_ros.compare.predict import Predictor

__all__ = ['star_hop_analysis', 'hold_windows', 'hold_rows', 'hold_centroid_drift', 'drift_removed_attitude']

_LOCKED = MOTION_STATES.index('locked')
_MIN_FRAMES = 5
#: Hold drift rates below this many sigma are noise, not drift.
_DRIFT_SIGNIFICANCE = 3.0
#: Frames averaged on each side of a short move: "the first three images" (6.3).
_SHORT_MOVE_FRAMES = 3
#: The keys of a move's short-move entries, None where the FPI did not see both stars.
_SHORT_MOVE_KEYS = ('short_move_arcsec', 'short_move_catalogue_arcsec', 'short_move_deviation_arcsec',
                    'short_move_sigma_arcsec', 'short_move_interval_s', 'short_move_euler_arcsec',
                    'short_move_pixels_px')


def hold_windows(result_text: str) -> list[dict[str, Any]] | None:
    """The observations of a star-hop result document, or None for another campaign's result.

    Args:
        result_text: the bag's /calibration/result document (YAML).

    Returns:
        The hold windows (star, hip, hold_start_s, hold_end_s, ...), or None when the result is not star-hop's.

    Raises:
        BagError: the document is not YAML.
    """
    try:
        result = yaml.safe_load(result_text)
    except yaml.YAMLError as err:
        raise BagError('/calibration/result is not YAML; the bag is damaged') from err
    if not isinstance(result, dict) or result.get('campaign') != 'star-hop':
        return None
    return result.get('observations', [])


def hold_rows(centroids: Centroids, camera: str, hip: int, window: Mapping[str, Any]) -> np.ndarray:
    """Rows of one camera's locked centroids of the held star inside a hold window, in time order.

    Args:
        centroids: the bag's star centroids.
        camera: the camera's name ('hipo', 'fpi', ...).
        hip: the held star's Hipparcos number.
        window: the hold window (its hold_start_s and hold_end_s).

    Returns:
        The row indices (int), empty when the camera is not in the bag.
    """
    if camera not in centroids.cameras:
        return np.empty(0, dtype=int)
    rows = np.flatnonzero((centroids.camera_index == centroids.cameras.index(camera)) & (centroids.hip == hip)
                          & (centroids.motion_code == _LOCKED) & (centroids.stamp_s >= window['hold_start_s'])
                          & (centroids.stamp_s <= window['hold_end_s']))
    return rows


def _hold_direction(predictor, effects, rows):
    """Mean IRF direction of the held star at the hold's mid time, its drift d(direction)/dt (1/s) and that drift's sigma."""
    times = predictor.row_times_s(effects)[rows]
    # Through the model's HIPO: its detector, fiducials and gravity flexure (3.5-3.7, Table 3.2).
    in_tarf = predictor.measured_directions_tarf(effects, rows)
    directions = np.einsum('nji,nj->ni', predictor.attitudes(effects, times), in_tarf)
    mid_s = float(times.mean())
    design = np.column_stack([np.ones_like(times), times - mid_s])
    coefficients, *_ = np.linalg.lstsq(design, directions, rcond=None)
    scatter = directions - design @ coefficients
    slope_sigma = np.sqrt(np.sum(scatter**2, axis=0) / max(len(times) - 2, 1)
                          / np.sum((times - mid_s) ** 2))
    direction = coefficients[0] / np.linalg.norm(coefficients[0])
    return mid_s, direction, coefficients[1], slope_sigma


def _drift_rate(first, second):
    """One rotation rate w (rad/s, IRF) with s = w x d for both holds' drifts, and its covariance (weighted LSQ, 6.3)."""
    rows, rhs, weights = [], [], []
    for direction, slope, sigma in (first, second):
        # w x d = -[d x] w
        rows.append(-np.array([[0.0, -direction[2], direction[1]], [direction[2], 0.0, -direction[0]],
                               [-direction[1], direction[0], 0.0]]))
        rhs.append(slope)
        weights.append(1.0 / np.maximum(sigma, 1e-15))
    design = np.vstack(rows) * np.concatenate(weights)[:, None]
    target = np.concatenate(rhs) * np.concatenate(weights)
    rate, *_ = np.linalg.lstsq(design, target, rcond=None)
    return rate, np.linalg.pinv(design.T @ design)


def drift_removed_attitude(attitude_dcm: npt.ArrayLike, drift_rate_irf_rad_per_s: npt.ArrayLike,
                           elapsed_s: float) -> np.ndarray:
    """A R(w dt): an attitude with the drift w (IRF, s = w x d) of the holds removed over elapsed_s (6.3).

    Args:
        attitude_dcm: (3, 3) the attitude A.
        drift_rate_irf_rad_per_s: (3,) the holds' drift rate w in IRF (rad/s).
        elapsed_s: the time dt the drift acted over (s).

    Returns:
        (3, 3) A R(w dt).
    """
    # The drifting attitude maps a fixed star to R(w dt) d; A R(w dt) maps it back onto d.
    turn = Rotation.from_rotvec(np.asarray(drift_rate_irf_rad_per_s) * elapsed_s).as_matrix()
    return np.asarray(attitude_dcm) @ turn


def _angle_arcsec(first, second):
    return float(np.arctan2(np.linalg.norm(np.cross(first, second)), first @ second) * ARCSEC_PER_RAD)


def _imager_flexure(observations, windows):
    """FPI and FFI boresight against HIPO per hold, relative to the first hold, with the FEM beside (6.2)."""
    centroids = observations.centroids
    rows_out = []
    for window in windows:
        row = {'star': window['star'], 'elevation_deg': float(window['elevation_deg'])}
        hipo_rows = hold_rows(centroids, 'hipo', window['hip'], window)
        if len(hipo_rows) < _MIN_FRAMES:
            continue
        hipo_px = centroids.measured_px[hipo_rows].mean(axis=0)
        hipo_shift = boresight_shift_arcsec('hipo', hipo_px, nominal_detector('hipo').center_px)
        complete = True
        for camera in ('fpi', 'ffi'):
            rows = hold_rows(centroids, camera, window['hip'], window)
            if len(rows) < 2:
                complete = False
                break
            pixel = centroids.measured_px[rows].mean(axis=0)
            row[camera] = (boresight_shift_arcsec(camera, pixel, nominal_detector(camera).center_px)
                           - hipo_shift).tolist()
        if complete:
            rows_out.append(row)
    if len(rows_out) < 3:
        return None
    reference = rows_out[0]
    for row in rows_out[::-1]:
        for camera in ('fpi', 'ffi'):
            row[camera] = (np.asarray(row[camera]) - np.asarray(reference[camera])).tolist()
        change = differential_imager_rotation_arcsec('ffi', gravity_load_tarf(row['elevation_deg']),
                                                     gravity_load_tarf(reference['elevation_deg']))
        row['ffi_fem'] = change.tolist()
    fits = {camera: flexure_fit(rows_out, camera, reference['elevation_deg']) for camera in ('fpi', 'ffi')}
    fem = differential_imager_rotation_arcsec('ffi', gravity_load_tarf(60.0), gravity_load_tarf(23.0))
    return {'reference_elevation_deg': reference['elevation_deg'], 'points': rows_out, 'fit': fits,
            'fem_change_23_to_60_deg_arcsec': {'fpi': [0.0, 0.0], 'ffi': fem.tolist()}}


def star_hop_analysis(predictor: Predictor, effects: Mapping[str, EffectParams],
                      windows: Sequence[Mapping[str, Any]], *, fpi_noise_arcsec: float,
                      arw_rad_per_sqrt_s: float) -> dict[str, Any]:
    """Moves (drift-corrected and short) against catalogue distances, their lines, imager flexure, hold drift.

    Args:
        predictor: the bag's predictor (its observations and gyro attitude).
        effects: the fitted model's effects and parameters (the gyro biases are left out, as 6.3 does).
        windows: the hold windows (hold_windows).
        fpi_noise_arcsec: the FPI's centroid noise ["], for the short moves' sigmas.
        arw_rad_per_sqrt_s: the gyros' angle random walk (rad/sqrt(s)), for the short moves' sigmas.

    Returns:
        The JSON's ``star_hop`` entry: moves, deviation_fit, short_move_fit, imager_flexure, centroid_drift.
    """
    observations = predictor.observations
    # As 6.3 does: the gyro drift comes from the holds, not from biases fitted to the whole run
    # (a fit of biases would take up part of a missing scale error).
    effects = {name: params for name, params in effects.items() if name not in ('gyro_bias', 'gyro_bias_drift')}
    holds = []
    for window in windows:
        rows = hold_rows(observations.centroids, 'hipo', window['hip'], window)
        if len(rows) >= _MIN_FRAMES:
            holds.append((window, *_hold_direction(predictor, effects, rows)))
    refracted = {name: value for name, value in effects.items() if name != 'atmospheric_refraction'}
    moves = []
    for (first, t1, d1, s1, e1), (second, t2, d2, s2, e2) in zip(holds, holds[1:]):
        if first['hip'] == second['hip']:
            continue
        rate, rate_covariance = _drift_rate((d1, s1, e1), (d2, s2, e2))
        rate_sigma = np.sqrt(np.diag(rate_covariance))
        # Only a rotation about the axis normal to both stars changes their distance (first order).
        normal = np.cross(d1, d2) / np.linalg.norm(np.cross(d1, d2))
        distance_sigma_rad = float(np.sqrt(normal @ rate_covariance @ normal)) * (t2 - t1)
        # The holds' drift is removed where it stands out of its own noise (6.3): removing noise adds error.
        corrected_by_drift = bool(np.any(np.abs(rate) > _DRIFT_SIGNIFICANCE * rate_sigma))
        corrected = d2 - np.cross(rate, d2) * (t2 - t1) if corrected_by_drift else d2
        measured = _angle_arcsec(d1, corrected / np.linalg.norm(corrected))
        rows = _short_move_rows(observations, first, second)
        short = dict.fromkeys(_SHORT_MOVE_KEYS) if rows is None else _short_move(
            predictor, effects, rows, rate if corrected_by_drift else np.zeros(3),
            float(np.sqrt(normal @ rate_covariance @ normal)), fpi_noise_arcsec, arw_rad_per_sqrt_s)
        catalogue = {}
        for label, model in (('refracted', effects), ('unrefracted', refracted)):
            stars = _catalogue_directions(predictor, model, (first['hip'], second['hip']), (t1, t2))
            catalogue[label] = _angle_arcsec(*stars)
        moves.append({'from': first['star'], 'to': second['star'], 'time_s': t2,
                      'measured_arcsec': measured, 'uncorrected_arcsec': _angle_arcsec(d1, d2),
                      'drift_corrected': corrected_by_drift,
                      'catalogue_arcsec': catalogue['refracted'], 'catalogue_unrefracted_arcsec': catalogue['unrefracted'],
                      'refraction_change_arcsec': catalogue['refracted'] - catalogue['unrefracted'],
                      'deviation_arcsec': measured - catalogue['refracted'],
                      # What the holds leave unknown of the drift over the move, corrected or not.
                      'deviation_sigma_arcsec': distance_sigma_rad * ARCSEC_PER_RAD,
                      'drift_rate_arcsec_per_s': (rate * ARCSEC_PER_RAD).tolist(),
                      'drift_rate_sigma_arcsec_per_s': (rate_sigma * ARCSEC_PER_RAD).tolist(), **short})
    short_moves = [move for move in moves if move['short_move_arcsec'] is not None]
    return {'moves': moves, 'deviation_fit': _deviation_fit(moves),
            'short_move_fit': _deviation_fit(short_moves, 'short_move_deviation_arcsec', 'short_move_sigma_arcsec'),
            'imager_flexure': _imager_flexure(observations, windows),
            'centroid_drift': hold_centroid_drift(observations.centroids, windows)}


def _short_move_rows(observations, first, second):
    """FPI rows of the star just before the move (last locked stretch) and of the next star just after it."""
    centroids = observations.centroids
    if 'fpi' not in centroids.cameras:
        return None
    stamps = centroids.stamp_s
    before = np.flatnonzero((centroids.camera_index == centroids.cameras.index('fpi'))
                            & (centroids.hip == first['hip']) & (centroids.motion_code == _LOCKED)
                            & (stamps >= first['hold_start_s']) & (stamps < second['hold_start_s']))
    if len(before):
        # Every move starts "transient": the last stretch between two move starts is just before the move.
        stretch = np.searchsorted(observations.move_start_s, centroids.stamp_s[before])
        before = before[stretch == stretch[-1]][-_SHORT_MOVE_FRAMES:]
    # The hold starts locked after the last centring: its first frames are the first of a still telescope.
    after = hold_rows(centroids, 'fpi', second['hip'], second)[:_SHORT_MOVE_FRAMES]
    if len(before) < _SHORT_MOVE_FRAMES or len(after) < _SHORT_MOVE_FRAMES:
        return None
    return before, after


def _short_move(predictor, effects, rows, drift_rate_rad_per_s, normal_rate_sigma_rad_per_s, fpi_noise_arcsec,
                arw_rad_per_sqrt_s):
    """One short move (6.3, Fig. 6.10, Tables D.5-D.6): distance, catalogue distance at its times, sigma."""
    centroids = predictor.observations.centroids
    times = predictor.row_times_s(effects)
    start_s, end_s = (float(times[side].mean()) for side in rows)
    errors = camera_errors('fpi', effects)
    # The FPI's attitude A_FPI,IRF = A_FPI,TARF(elevation) A_TARF,IRF: the model's mounting and flexure.
    first, second = (camera_from_tarf_dcm(errors, float(centroids.elevation_deg[side].mean())) @ attitude
                     for side, attitude in zip(rows, predictor.attitudes(effects, np.array([start_s, end_s]))))
    second = drift_removed_attitude(second, drift_rate_rad_per_s, end_s - start_s)
    el, xel, los = attitude_change_euler_arcsec(first, second)
    before_px, after_px = (centroids.measured_px[side].mean(axis=0) for side in rows)
    el_short, xel_short = short_move_euler_arcsec(el, xel, before_px, after_px, errors.detector.scale_arcsec_per_px)
    distance = float(spherical_sum_arcsec(el_short, xel_short))
    hips = tuple(int(centroids.hip[side[0]]) for side in rows)
    catalogue = _angle_arcsec(*_catalogue_directions(predictor, effects, hips, (start_s, end_s)))
    interval_s = end_s - start_s
    # Each end's mean centroid scatters along the great circle by its frames' noise; the gyros walk
    # over the interval (ARW, 4.2.3); the holds leave the drift rate about the stars' normal uncertain.
    variance = (fpi_noise_arcsec**2 * sum(1.0 / len(side) for side in rows)
                + (arw_rad_per_sqrt_s * ARCSEC_PER_RAD) ** 2 * interval_s
                + (normal_rate_sigma_rad_per_s * ARCSEC_PER_RAD * interval_s) ** 2)
    return {'short_move_arcsec': distance, 'short_move_catalogue_arcsec': catalogue,
            'short_move_deviation_arcsec': distance - catalogue, 'short_move_sigma_arcsec': float(np.sqrt(variance)),
            'short_move_interval_s': interval_s,
            'short_move_euler_arcsec': [float(el_short), float(xel_short), float(los)],
            'short_move_pixels_px': [before_px.tolist(), after_px.tolist()]}


def hold_centroid_drift(centroids: Centroids, windows: Sequence[Mapping[str, Any]]) -> list[dict[str, Any]]:
    """The FPI centroid drift of each hold: column linear, row linear + sinusoid where BIC selects it (6.3).

    Args:
        centroids: the bag's star centroids.
        windows: the hold windows (hold_windows).

    Returns:
        One entry per hold with enough FPI frames: the star, its window and the drift fit
        (analysis.centroid_drift.CentroidDrift's keys).
    """
    drifts = []
    for window in windows:
        rows = hold_rows(centroids, 'fpi', window['hip'], window)
        if len(rows) < _MIN_FRAMES:
            continue
        fit = fit_centroid_drift(centroids.stamp_s[rows], *centroids.measured_px[rows].T)
        drifts.append({'star': window['star'], 'hip': int(window['hip']),
                       'hold_start_s': float(window['hold_start_s']), 'hold_end_s': float(window['hold_end_s']), **fit})
    return drifts


def _catalogue_directions(predictor, effects, hips, times_s):
    """Observed IRF directions of two stars, each at its own time, through the model's sky (refraction, Earth)."""
    directions = []
    for hip, time_s in zip(hips, times_s):
        row = int(np.flatnonzero(predictor.observations.centroids.hip == hip)[0])
        directions.append(predictor.star_direction_irf(effects, row, time_s))
    return directions


def _deviation_fit(moves, deviation_key='deviation_arcsec', sigma_key=None):
    """Deviation = a + b distance (Fig. 6.11), b in arcsec per deg of distance, with 1-sigma errors.

    With ``sigma_key`` the points are weighted by their predicted sigmas, which then set the errors.
    """
    if len(moves) < 3:
        return None
    distance_deg = np.array([move['catalogue_arcsec'] for move in moves]) / 3600.0
    deviation = np.array([move[deviation_key] for move in moves])
    if sigma_key is None:
        coefficients, covariance = np.polyfit(distance_deg, deviation, 1, cov='unscaled' if len(moves) < 4 else True)
    else:
        weights = 1.0 / np.array([move[sigma_key] for move in moves])
        coefficients, covariance = np.polyfit(distance_deg, deviation, 1, w=weights, cov='unscaled')
    sigma = np.sqrt(np.diag(covariance))
    residual = deviation - np.polyval(coefficients, distance_deg)
    return {'slope_arcsec_per_deg': float(coefficients[0]), 'slope_sigma': float(sigma[0]),
            'intercept_arcsec': float(coefficients[1]), 'intercept_sigma': float(sigma[1]),
            'rms_about_fit_arcsec': float(np.sqrt(np.mean(residual**2))),
            'scale_error_ppm': float(coefficients[0] / 3600.0 * 1e6)}
