"""What a model predicts for each row of a measurement set, through the simulator's own physics.

- star_distance: ERFA observed places of both stars at their times (sky.places), raised by Stone's
  refraction with the set's weather when the model has atmospheric_refraction (4.33-4.35, 6.2), in
  the IRF of the model's Earth rate (4.1); the telescope's TARF with its LOS on each star and its EL
  axis along the aircraft (heading of the logbook, C.3.2); the move between them as a constant body
  rate read through the model's gyro errors (sensors.gyro_errors: misalignment, scale factor, axis
  swap, and the rate offsets unless the table's drift was removed), and the distance of the
  believed move from its EL and XEL Euler angles (4.3.3, 4.38).
- earth_rate: eqs. 4.1-4.3 at the table's latitude, heading (+ heading_error) and elevation, read
  through the same gyro errors (5.2.4).
- turning_point / misalignment_angle: the residual rotation A_TARF,GYRF A_k^T left by the
  implemented matrix A_k; its LOS axis on HIPO (3.10, HIPO 2004 fiducials, 3.5-3.7) and its turn
  about LOS, beta (3.18-3.19).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import numpy.typing as npt
from scipy.spatial.transform import Rotation

from sofia_ros.earth_rate import earth_rate_tarf_deg_per_h
from sofia_ros.errors import ConfigError, InvalidArgumentError
from sofia_ros.effects.base import EffectParams
from sofia_ros.frames import HIPO_2004, vector_to_pixel
from sofia_ros.measurements.format import MeasurementSet, Table
from sofia_ros.mount import hrf_from_irf_dcm
from sofia_ros.sensors.gyro_errors import (
    gyro_effect_names,
    gyro_error_model,
    measured_rates_gyrf_rad_per_s,
    tarf_from_gyrf_dcm,
)
from sofia_ros.sensors.imager_model import refracted_directions_hrf
from sofia_ros.sky.distances import attitude_change_euler_arcsec, spherical_sum_arcsec
from sofia_ros.sky.places import observed_directions_hrf
from sofia_ros.units import ARCSEC_PER_RAD, RAD_PER_DEG

__all__ = ['StarGeometry', 'star_geometry', 'predict_table', 'tarf_from_hrf_on_star', 'MOVE_TIME_SAMPLES']

#: Points on which rate offsets are averaged over a move (exact for ramps; sinusoids to their period).
MOVE_TIME_SAMPLES = 33
_RAD_PER_S_PER_DEG_PER_H = RAD_PER_DEG / 3600.0


@dataclass(frozen=True)
class StarGeometry:
    """Effect-free geometry of a star_distance table: times since the epoch, HRF directions of both stars."""

    time_s: np.ndarray  # (N, 2)
    unrefracted_hrf: np.ndarray  # (N, 2, 3)
    refracted_hrf: np.ndarray  # (N, 2, 3)


def star_geometry(measurement_set: MeasurementSet, table: Table) -> StarGeometry:
    """ERFA apparent places of every row's two stars at their times (C.4.2), with and without refraction (6.2).

    Args:
        measurement_set: the set (site, weather, epoch).
        table: one of its star_distance tables.

    Returns:
        The times since the epoch and both directions of each row's stars.

    Raises:
        ConfigError: a star below 5 deg altitude at its time, or a row whose refraction the weather refuses.
    """
    times, unrefracted, refracted = [], [], []
    for number, row in enumerate(table.rows, start=1):
        pair = []
        for star, when in ((row.star_1, row.time_1_utc), (row.star_2, row.time_2_utc)):
            direction = observed_directions_hrf([star], measurement_set.site, when)[0]
            if direction[2] <= np.sin(5.0 * RAD_PER_DEG):
                raise ConfigError(f'{measurement_set.source}: table {table.name!r} row {number}: {star} is below '
                                  f'5 deg altitude at {when.isoformat()}; check the time and the site')
            pair.append(direction)
        unrefracted.append(pair)
        try:
            refracted.append(refracted_directions_hrf(np.array(pair), measurement_set.site, measurement_set.weather))
        except InvalidArgumentError as err:
            raise ConfigError(f'{measurement_set.source}: table {table.name!r} row {number}: {err}') from err
        times.append([(when - measurement_set.epoch_utc).total_seconds() for when in (row.time_1_utc, row.time_2_utc)])
    return StarGeometry(np.array(times), np.array(unrefracted), np.array(refracted))


def tarf_from_hrf_on_star(direction_hrf: npt.ArrayLike, heading_deg: float) -> np.ndarray:
    """A_TARF,HRF with the LOS on the star and the EL axis along the aircraft, level (C.3.2; fine drive XEL only).

    Args:
        direction_hrf: unit vector(s) to the star in HRF, (3,) or (..., 3).
        heading_deg: the aircraft's true heading [deg].

    Returns:
        The DCM(s), (3, 3) or (..., 3, 3), rows EL, XEL, LOS.
    """
    los = np.asarray(direction_hrf, dtype=float)
    heading = heading_deg * RAD_PER_DEG
    forward = np.array([np.cos(heading), -np.sin(heading), 0.0])
    el_axis = forward - (los @ forward)[..., None] * los if los.ndim > 1 else forward - (los @ forward) * los
    el_axis = el_axis / np.linalg.norm(el_axis, axis=-1, keepdims=True)
    # Rows EL, XEL, LOS with XEL = LOS x EL, as mount.icrf_from_abrf_dcm (V = W x U).
    return np.stack([el_axis, np.cross(los, el_axis), los], axis=-2)


def _gyro_model(effects, *, drift_removed):
    """The model's gyro errors as the reduction left them; with the drift removed, no rate offsets (6.3-6.4)."""
    gyro = {name: effects[name] for name in gyro_effect_names() if name in effects}
    model = gyro_error_model(gyro)
    if drift_removed:
        swap = model.axis_swap and {**model.axis_swap, 'bias_difference_deg_per_h': 0.0}
        model = dataclasses.replace(model, bias_rad_per_s=np.zeros(3), ramp_rad_per_s2=np.zeros(3),
                                    los_oscillation=None, vibration_lines=None, tracker_drift=None, plugins=(),
                                    axis_swap=swap)
    else:
        # Lines average out over a move: the mean of a sinusoid over many periods.
        model = dataclasses.replace(model, vibration_lines=None)
    return model


def _earth_rate_rad_per_s(effects):
    earth = effects.get('earth_rotation')
    return earth['rate_deg_per_h'] * _RAD_PER_S_PER_DEG_PER_H if earth else 0.0


def predict_star_distance_arcsec(measurement_set: MeasurementSet, table: Table, geometry: StarGeometry,
                                 effects: Mapping[str, EffectParams]) -> np.ndarray:
    """Distance of each move as the model's gyros would measure it, from EL and XEL (4.3.3, 4.38), arcsec.

    Args:
        measurement_set: the set (site, heading, gyro temperature).
        table: one of its star_distance tables.
        geometry: the table's star_geometry.
        effects: the model, effect name -> resolved parameters.

    Returns:
        The predicted distance of each row [arcsec].
    """
    directions_hrf = geometry.refracted_hrf if 'atmospheric_refraction' in effects else geometry.unrefracted_hrf
    latitude = measurement_set.site.latitude_deg
    rate = _earth_rate_rad_per_s(effects)
    # A_TARF,IRF(t) = A_TARF,HRF(t) A_HRF(t),IRF in the model's IRF (its Earth rate).
    attitudes = [tarf_from_hrf_on_star(directions_hrf[:, end], measurement_set.heading_deg)
                 @ hrf_from_irf_dcm(latitude, geometry.time_s[:, end], rate) for end in (0, 1)]
    first, second = attitudes
    # Body rotation theta of the move: A2 = exp(-[theta x]) A1 (B.23 at a constant body rate).
    theta = -Rotation.from_matrix(second @ np.swapaxes(first, -1, -2)).as_rotvec()
    interval_s = geometry.time_s[:, 1] - geometry.time_s[:, 0]
    model = _gyro_model(effects, drift_removed=table.drift_removed)
    fraction = np.linspace(0.0, 1.0, MOVE_TIME_SAMPLES)
    times = geometry.time_s[:, :1] + np.outer(interval_s, fraction)
    rates = np.repeat(theta / interval_s[:, None], MOVE_TIME_SAMPLES, axis=0)
    readings = measured_rates_gyrf_rad_per_s(model, rates, times.ravel(), measurement_set.gyro_temperature_c)
    # The gyros' angle over the move: the mean reading times the interval (the reduction reads GYRF as TARF).
    believed = readings.reshape(len(interval_s), MOVE_TIME_SAMPLES, 3).mean(axis=1) * interval_s[:, None]
    second_believed = Rotation.from_rotvec(-believed).as_matrix() @ first
    euler = attitude_change_euler_arcsec(first, second_believed)
    return spherical_sum_arcsec(euler[:, 0], euler[:, 1])


def predict_earth_rate_deg_per_h(measurement_set: MeasurementSet, table: Table,
                                 effects: Mapping[str, EffectParams]) -> np.ndarray:
    """Mean rates EL, XEL, LOS (deg/h) a braked telescope's gyros read under the model (4.1-4.3, 5.2.4).

    Args:
        measurement_set: the set (gyro temperature).
        table: one of its earth_rate tables (latitude, heading, elevation).
        effects: the model, effect name -> resolved parameters.

    Returns:
        EL, XEL, LOS [deg/h] repeated for each row, flat (the order of Table.measured()).
    """
    heading = table.heading_deg + effects.get('heading_error', {}).get('heading_error_deg', 0.0)
    earth = effects.get('earth_rotation')
    truth = earth_rate_tarf_deg_per_h(table.latitude_deg, heading, table.elevation_deg,
                                      earth['rate_deg_per_h'] if earth else 0.0)
    model = dataclasses.replace(_gyro_model(effects, drift_removed=False), los_oscillation=None,
                                ramp_rad_per_s2=np.zeros(3))
    reading = measured_rates_gyrf_rad_per_s(model, truth * _RAD_PER_S_PER_DEG_PER_H, np.zeros(1),
                                            measurement_set.gyro_temperature_c)[0] / _RAD_PER_S_PER_DEG_PER_H
    return np.tile(reading, len(table.rows))


def residual_alignment_dcm(effects: Mapping[str, EffectParams], implemented: npt.ArrayLike) -> np.ndarray:
    """M = A_TARF,GYRF A_k^T: what is left of the mounting under the implemented matrix A_k (3.20, 3.18-3.19).

    Args:
        effects: the model, effect name -> resolved parameters (its gyro_misalignment).
        implemented: the implemented alignment matrix A_k (3x3).

    Returns:
        The residual rotation M (3x3).
    """
    return tarf_from_gyrf_dcm(effects) @ np.asarray(implemented).T


def predict_turning_point_arcsec(measurement_set: MeasurementSet, table: Table,
                                 effects: Mapping[str, EffectParams]) -> np.ndarray:
    """LOS turning point minus the TARF origin along HIPO X, Y in arcsec (3.10, 3.5-3.7; Tables 6.1, 6.2).

    Args:
        measurement_set: the set (its matrices).
        table: one of its turning_point tables.
        effects: the model, effect name -> resolved parameters.

    Returns:
        X, Y [arcsec] of each row, flat (the order of Table.measured()).
    """
    out = []
    for row in table.rows:
        residual = residual_alignment_dcm(effects, measurement_set.matrices[row.matrix])
        # The measured LOS axis is the third column of M (solvers.gyro_alignment_from_axes).
        pixel = vector_to_pixel(residual[:, 2], HIPO_2004)
        out.append((pixel - HIPO_2004.center_px) * HIPO_2004.scale_arcsec_per_px)
    return np.ravel(out)


def predict_misalignment_angle_arcmin(measurement_set: MeasurementSet, table: Table,
                                      effects: Mapping[str, EffectParams]) -> np.ndarray:
    """beta, the turn about LOS left by the implemented matrix, in arcmin (3.18-3.19, Table 6.4).

    Args:
        measurement_set: the set (its matrices).
        table: one of its misalignment_angle tables.
        effects: the model, effect name -> resolved parameters.

    Returns:
        beta [arcmin] of each row.
    """
    out = []
    for row in table.rows:
        residual = residual_alignment_dcm(effects, measurement_set.matrices[row.matrix])
        # Row v of M^T: v1 = tan(beta) v2 (eq. 3.18).
        out.append(np.arctan2(residual[0, 1], residual[1, 1]) * ARCSEC_PER_RAD / 60.0)
    return np.array(out)


def predict_table(measurement_set: MeasurementSet, table: Table, effects: Mapping[str, EffectParams],
                  geometry: StarGeometry | None = None) -> np.ndarray:
    """Predicted values of one table (same order and units as Table.measured()).

    Args:
        measurement_set: the set the table belongs to.
        table: the table.
        effects: the model, effect name -> resolved parameters.
        geometry: the table's star_geometry (needed for star_distance only).

    Returns:
        One predicted value per measured value.
    """
    if table.kind == 'star_distance':
        return predict_star_distance_arcsec(measurement_set, table, geometry, effects)
    if table.kind == 'earth_rate':
        return predict_earth_rate_deg_per_h(measurement_set, table, effects)
    if table.kind == 'turning_point':
        return predict_turning_point_arcsec(measurement_set, table, effects)
    return predict_misalignment_angle_arcmin(measurement_set, table, effects)
