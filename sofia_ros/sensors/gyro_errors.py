"""Deterministic gyro errors: true TARF rates to GYRF measurements and back (2.4.1, 5.2, 6.1, 6.3).

One error model serves both sides of an effect (docs/effects.md): the gyro box of the truth
simulator turns true rates into measurements with it, and `sofia compare` inverts it with
the model's parameters to turn recorded measurements into the rates the model believes.

    measured_gyrf = D(T) A_GYRF,TARF omega_tarf + offset(t, T)

with A_TARF,GYRF the rotation by ``gyro_misalignment`` (read like eq. 6.1), D = diag(1 + scale
factor error + the axis-swap scale error at temperature T), and the offset the bias, rate
ramp (4.2.3), LOS oscillation (5.2.4), vibration lines (5.2.5), axis-swap bias (6.3) and the
residual tracker drift (6.3: a rate error the gyros do not see, so the telescope really drifts),
plus the rate offsets of plug-in effects (EffectSpec.gyro_rate_offset).
Random noise is not here: it is sensors.gyro_noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from sofia_ros.effects import CATALOGUE, get_effect, is_empirical, plugin_terms
from sofia_ros.effects.context import GyroContext
from sofia_ros.frames import AXES, dcm_from_rotation_angles
from sofia_ros.units import RAD_PER_ARCSEC, RAD_PER_DEG

__all__ = ['AXES', 'GyroErrorModel', 'gyro_error_model', 'gyro_effect_names', 'measured_rates_gyrf_rad_per_s',
           'true_rates_tarf_rad_per_s', 'tarf_from_gyrf_dcm', 'AXIS_SWAP_REFERENCE_C']

_AXIS_INDEX = {axis: index for index, axis in enumerate(AXES)}
#: Temperature at which the swapped calibrations differ by scale_difference_ppm (the Waco night, 6.2).
AXIS_SWAP_REFERENCE_C = 22.8
_FPI_ARCSEC_PER_PX = 0.55
_RAD_PER_S_PER_DEG_PER_H = RAD_PER_DEG / 3600.0
_BUILT_IN_EFFECTS = ('gyro_misalignment', 'gyro_scale_factor', 'gyro_bias', 'gyro_bias_drift', 'gyro_axis_swap',
                     'los_oscillation', 'vibration_lines', 'tracker_drift')


def gyro_effect_names(effects=()):
    """Names of the effects that change what the gyros read: built-in, gyro plug-ins, and gyro empirical terms of ``effects``."""
    empirical = tuple(name for name in effects if is_empirical(name) and get_effect(name).gyro_rate_offset is not None)
    return (_BUILT_IN_EFFECTS + tuple(name for name, spec in CATALOGUE.items() if spec.gyro_rate_offset is not None)
            + empirical)


def tarf_from_gyrf_dcm(effects):
    """A_TARF,GYRF: the rotation by the gyro_misalignment angles (eq. 6.1 reading), else identity."""
    params = effects.get('gyro_misalignment')
    if params is None:
        return np.eye(3)
    angles_arcsec = [params[f'about_{axis}_arcsec'] for axis in AXES]
    return dcm_from_rotation_angles(np.asarray(angles_arcsec) * RAD_PER_ARCSEC)


def _per_axis(params, suffix, scale=1.0):
    return np.array([params[f'{axis}_{suffix}'] for axis in AXES]) * scale if params else np.zeros(3)


@dataclass(frozen=True)
class GyroErrorModel:
    """The deterministic gyro errors of one effect set, resolved to SI per axis."""

    tarf_from_gyrf: np.ndarray
    scale_error: np.ndarray
    bias_rad_per_s: np.ndarray
    ramp_rad_per_s2: np.ndarray
    los_oscillation: dict | None = None
    vibration_lines: dict | None = None
    axis_swap: dict | None = None
    tracker_drift: dict | None = None
    #: HookTerms of plug-in and empirical effects (EffectSpec.gyro_rate_offset).
    plugins: tuple = ()


def gyro_error_model(effects):
    """The GyroErrorModel of an effect set (resolved parameters, docs/effects.md)."""
    return GyroErrorModel(
        tarf_from_gyrf=tarf_from_gyrf_dcm(effects),
        scale_error=_per_axis(effects.get('gyro_scale_factor'), 'ppm', 1e-6),
        bias_rad_per_s=_per_axis(effects.get('gyro_bias'), 'deg_per_h', _RAD_PER_S_PER_DEG_PER_H),
        ramp_rad_per_s2=_per_axis(effects.get('gyro_bias_drift'), 'deg_per_h2', _RAD_PER_S_PER_DEG_PER_H / 3600.0),
        los_oscillation=effects.get('los_oscillation'),
        vibration_lines=effects.get('vibration_lines'),
        axis_swap=effects.get('gyro_axis_swap'),
        tracker_drift=effects.get('tracker_drift'),
        plugins=plugin_terms(effects, 'gyro_rate_offset'),
    )


def _swap_axes(axis_swap):
    return tuple(_AXIS_INDEX[axis] for axis in axis_swap['swapped_axes'].split('-'))


def scale_factors(model, temperature_c):
    """Diagonal of D(T): 1 + scale error + the swapped calibrations' scale error at T (2.4.1, 6.3), (N, 3)."""
    temperature = np.atleast_1d(np.asarray(temperature_c, dtype=float))
    factors = np.full((len(temperature), 3), 1.0 + model.scale_error)
    if model.axis_swap:
        params = model.axis_swap
        first, second = _swap_axes(params)
        swap = (params['scale_difference_ppm'] + params['scale_temperature_coefficient_ppm_per_c']
                * (temperature - AXIS_SWAP_REFERENCE_C)) * 1e-6
        factors[:, first] += swap
        factors[:, second] -= swap
    return factors


def rate_offsets_rad_per_s(model, times_s, temperature_c, *, specific_force_tarf_m_per_s2=None, rates_gyrf_rad_per_s=None):
    """offset(t, T): bias, ramp (4.2.3), LOS oscillation (5.2.4), lines (5.2.5), swap bias, tracker drift (6.3), plug-ins, (N, 3).

    Plug-in hooks get a GyroContext: the specific force (TARF; zeros when not given) and the
    GYRF rates (zeros when not given).
    """
    times = np.atleast_1d(np.asarray(times_s, dtype=float))
    offsets = model.bias_rad_per_s + np.outer(times, model.ramp_rad_per_s2)
    if model.los_oscillation:
        params = model.los_oscillation
        omega = 2.0 * np.pi / params['period_s']
        phase = params['phase_deg'] * RAD_PER_DEG
        # The integrated LOS angle is amplitude * sin(omega t + phase).
        offsets[:, 2] += params['amplitude_arcsec'] * RAD_PER_ARCSEC * omega * np.cos(omega * times + phase)
    if model.vibration_lines:
        params = model.vibration_lines
        for frequency_hz, amplitude, axis in zip(params['frequencies_hz'], params['amplitudes_arcsec_per_s'],
                                                 params['axes']):
            offsets[:, _AXIS_INDEX[axis]] += amplitude * RAD_PER_ARCSEC * np.sin(2.0 * np.pi * frequency_hz * times)
    if model.axis_swap:
        first, second = _swap_axes(model.axis_swap)
        bias = model.axis_swap['bias_difference_deg_per_h'] * _RAD_PER_S_PER_DEG_PER_H
        offsets[:, first] += bias
        offsets[:, second] -= bias
    if model.tracker_drift:
        # FPI rows move linearly plus a sinusoid (1.4 px/min, 2.2 px, 5.2 min in 6.3): an unseen
        # rate error about EL, so the servo turns the telescope by its negative.
        params = model.tracker_drift
        omega = 2.0 * np.pi / (params['sine_period_min'] * 60.0)
        phase = params['sine_phase_deg'] * RAD_PER_DEG
        drift_px_per_s = params['linear_px_per_min'] / 60.0 + params['sine_amplitude_px'] * omega * np.cos(
            omega * times + phase)
        offsets[:, 0] += drift_px_per_s * _FPI_ARCSEC_PER_PX * RAD_PER_ARCSEC
    if model.plugins:
        temperature = np.broadcast_to(np.asarray(temperature_c, dtype=float), times.shape)
        force = np.zeros((len(times), 3)) if specific_force_tarf_m_per_s2 is None else np.broadcast_to(
            np.asarray(specific_force_tarf_m_per_s2, dtype=float), (len(times), 3))
        rates = np.zeros((len(times), 3)) if rates_gyrf_rad_per_s is None else np.broadcast_to(
            np.asarray(rates_gyrf_rad_per_s, dtype=float), (len(times), 3))
        context = GyroContext(times, temperature, force, rates)
        for term in model.plugins:
            offsets += term(context)
    return offsets


def measured_rates_gyrf_rad_per_s(model, true_rates_tarf, times_s, temperature_c, specific_force_tarf_m_per_s2=None):
    """Noise-free GYRF measurements D(T) A_GYRF,TARF omega + offset(t, T, f, omega) of true TARF rates (N, 3)."""
    rates_gyrf = np.atleast_2d(true_rates_tarf) @ model.tarf_from_gyrf
    offsets = rate_offsets_rad_per_s(model, times_s, temperature_c, rates_gyrf_rad_per_s=rates_gyrf,
                                     specific_force_tarf_m_per_s2=specific_force_tarf_m_per_s2)
    return scale_factors(model, temperature_c) * rates_gyrf + offsets


def true_rates_tarf_rad_per_s(model, measured_gyrf, times_s, temperature_c, specific_force_tarf_m_per_s2=None):
    """The inverse: TARF rates A_TARF,GYRF D(T)^-1 (measured - offset(t, T, f, measured)) a model believes (N, 3)."""
    measured = np.atleast_2d(measured_gyrf)
    offsets = rate_offsets_rad_per_s(model, times_s, temperature_c, rates_gyrf_rad_per_s=measured,
                                     specific_force_tarf_m_per_s2=specific_force_tarf_m_per_s2)
    return ((measured - offsets) / scale_factors(model, temperature_c)) @ model.tarf_from_gyrf.T
