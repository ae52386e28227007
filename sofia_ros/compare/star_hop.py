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
against distance is fitted with a line (Fig. 6.11). The FPI and FFI see the HIPO-centred star
during every hold: their offsets from the first hold, as rotations (6.2), against elevation,
give the differential flexure beside the FEM prediction (Table 3.3, Fig. 6.4).
"""

from __future__ import annotations

import numpy as np
import yaml

from sofia_ros.compare.observations import MOTION_STATES
from sofia_ros.errors import BagError
from sofia_ros.flexure import differential_imager_rotation_arcsec, gravity_load_tarf
from sofia_ros.sensors.imager_model import nominal_detector
from sofia_ros.sim.calibration import boresight_shift_arcsec, flexure_fit
from sofia_ros.units import ARCSEC_PER_RAD

__all__ = ['star_hop_analysis', 'hold_windows']

_LOCKED = MOTION_STATES.index('locked')
_MIN_FRAMES = 5
#: Hold drift rates below this many sigma are noise, not drift.
_DRIFT_SIGNIFICANCE = 3.0


def hold_windows(result_text):
    """The observations of a star-hop result document, or None for another campaign's result."""
    try:
        result = yaml.safe_load(result_text)
    except yaml.YAMLError as err:
        raise BagError('/calibration/result is not YAML; the bag is damaged') from err
    if not isinstance(result, dict) or result.get('campaign') != 'star-hop':
        return None
    return result.get('observations', [])


def _hold_rows(centroids, camera, hip, window):
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


def _angle_arcsec(first, second):
    return float(np.arctan2(np.linalg.norm(np.cross(first, second)), first @ second) * ARCSEC_PER_RAD)


def _imager_flexure(observations, windows):
    """FPI and FFI boresight against HIPO per hold, relative to the first hold, with the FEM beside (6.2)."""
    centroids = observations.centroids
    rows_out = []
    for window in windows:
        row = {'star': window['star'], 'elevation_deg': float(window['elevation_deg'])}
        hipo_rows = _hold_rows(centroids, 'hipo', window['hip'], window)
        if len(hipo_rows) < _MIN_FRAMES:
            continue
        hipo_px = centroids.measured_px[hipo_rows].mean(axis=0)
        hipo_shift = boresight_shift_arcsec('hipo', hipo_px, nominal_detector('hipo').center_px)
        complete = True
        for camera in ('fpi', 'ffi'):
            rows = _hold_rows(centroids, camera, window['hip'], window)
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


def star_hop_analysis(predictor, effects, windows):
    """Moves with measured and catalogue distances, their deviation fit, and the imager flexure series."""
    observations = predictor.observations
    # As 6.3 does: the gyro drift comes from the holds, not from biases fitted to the whole run
    # (a fit of biases would take up part of a missing scale error).
    effects = {name: params for name, params in effects.items() if name not in ('gyro_bias', 'gyro_bias_drift')}
    holds = []
    for window in windows:
        rows = _hold_rows(observations.centroids, 'hipo', window['hip'], window)
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
                      'drift_rate_sigma_arcsec_per_s': (rate_sigma * ARCSEC_PER_RAD).tolist()})
    return {'moves': moves, 'deviation_fit': _deviation_fit(moves),
            'imager_flexure': _imager_flexure(observations, windows)}


def _catalogue_directions(predictor, effects, hips, times_s):
    """Observed IRF directions of two stars, each at its own time, through the model's sky (refraction, Earth)."""
    directions = []
    for hip, time_s in zip(hips, times_s):
        row = int(np.flatnonzero(predictor.observations.centroids.hip == hip)[0])
        directions.append(predictor.star_direction_irf(effects, row, time_s))
    return directions


def _deviation_fit(moves):
    """Deviation = a + b distance (Fig. 6.11), b in arcsec per deg of distance, with 1-sigma errors."""
    if len(moves) < 3:
        return None
    distance_deg = np.array([move['catalogue_arcsec'] for move in moves]) / 3600.0
    deviation = np.array([move['deviation_arcsec'] for move in moves])
    coefficients, covariance = np.polyfit(distance_deg, deviation, 1, cov='unscaled' if len(moves) < 4 else True)
    sigma = np.sqrt(np.diag(covariance))
    residual = deviation - np.polyval(coefficients, distance_deg)
    return {'slope_arcsec_per_deg': float(coefficients[0]), 'slope_sigma': float(sigma[0]),
            'intercept_arcsec': float(coefficients[1]), 'intercept_sigma': float(sigma[1]),
            'rms_about_fit_arcsec': float(np.sqrt(np.mean(residual**2))),
            'scale_error_ppm': float(coefficients[0] / 3600.0 * 1e6)}
