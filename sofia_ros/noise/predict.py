"""A noise model's Allan variance and Welch PSD per gyro axis (docs/noise.md, 4.2: 4.6-4.22).

A noise model is an effects file with the schema of a truth (docs/effects.md): ``gyro_noise``
(quantization, ARW, bias instability, RRW), ``gyro_bias_drift`` (the rate ramp), ``vibration_lines``
and ``los_oscillation``; other effects are constant rates the mean removes.
"""

from __future__ import annotations

from collections.abc import Mapping

import numpy as np

from sofia_ros.analysis.spectra import welch_sinusoid_psd
from sofia_ros.effects.base import EffectParams
from sofia_ros.errors import ConfigError
from sofia_ros.frames import AXES
from sofia_ros.noise.fit import (
    BIAS_INSTABILITY_PLATEAU,
    bias_instability_psd,
    decimated_quantization_variance,
    quantization_psd,
    rate_ramp_psd,
    rrw_psd,
    sinusoid_adev,
)
from sofia_ros.noise.measure import NoiseGrid
from sofia_ros.sensors.gyro_noise import NoiseCoefficients, rate_ramp_deg_per_h2_to_arcsec_per_s2

__all__ = ['model_lines', 'check_noise_model', 'predicted_noise']

_AXIS_INDEX = {axis: index for index, axis in enumerate(AXES)}


def _white(variance_per_sample, grid, freq_hz):
    """AV var t_s / tau and one-sided PSD 2 var / fs of white rate noise (4.16, 4.14)."""
    return (variance_per_sample / grid.sample_rate_hz / grid.tau_s,
            np.full(freq_hz.shape, 2.0 * variance_per_sample / grid.sample_rate_hz))


def _sinusoid(amplitude_arcsec_per_s, frequency_hz, grid, freq_hz):
    """AV (4.6-4.7) and expected Welch PSD of a sampled line."""
    return (sinusoid_adev(grid.tau_s, amplitude_arcsec_per_s, frequency_hz, grid.sample_rate_hz) ** 2,
            welch_sinusoid_psd(freq_hz, amplitude_arcsec_per_s, frequency_hz, grid.sample_rate_hz,
                               grid.segment_samples))


def _gyro_noise_terms(params, grid, freq_hz, include_arw):
    """(AV, PSD) of each gyro_noise process, the same on every axis (4.11-4.20, decimation per module)."""
    coefficients = NoiseCoefficients(
        quantization_arcsec=params['quantization_arcsec'], arw_deg_per_sqrt_h=params['arw_deg_per_sqrt_h'],
        bias_instability_deg_per_h=params['bias_instability_deg_per_h'],
        bias_cutoff_hz=params['bias_instability_cutoff_hz'], rrw_deg_per_h_sqrt_h=params['rrw_deg_per_h_sqrt_h'],
    ).as_arcsec()
    tau, terms = grid.tau_s, []
    quantization = coefficients['quantization_arcsec']
    if grid.decimation > 1.0:
        terms.append(_white(decimated_quantization_variance(quantization, grid.readout_rate_hz), grid, freq_hz))
    else:
        terms.append(((quantization / (2.0 * tau)) ** 2, quantization_psd(freq_hz, quantization, grid.sample_rate_hz)))
    if include_arw:
        arw = coefficients['arw_arcsec_per_sqrt_s']
        terms.append(_white(arw**2 * grid.readout_rate_hz, grid, freq_hz))
    bias = coefficients['bias_instability_arcsec_per_s']
    terms.append((np.full(tau.shape, (BIAS_INSTABILITY_PLATEAU * bias) ** 2),
                  bias_instability_psd(freq_hz, bias, params['bias_instability_cutoff_hz'])))
    rrw = coefficients['rrw_arcsec_per_s_sqrt_s']
    terms.append((rrw**2 * tau / 3.0, rrw_psd(freq_hz, rrw)))
    return terms


def model_lines(effects: Mapping[str, EffectParams]) -> list[tuple[float, float, int]]:
    """(frequency Hz, amplitude arcsec/s, axis index) of the model's vibration_lines, checked.

    Args:
        effects: the noise model, effect name -> parameters.

    Returns:
        One (frequency [Hz], amplitude [arcsec/s], axis index) per line; empty without vibration_lines.

    Raises:
        ConfigError: lists of different lengths, an unknown axis, or an entry that is no number.
    """
    params = effects.get('vibration_lines')
    if not params:
        return []
    frequencies, amplitudes, axes = params['frequencies_hz'], params['amplitudes_arcsec_per_s'], params['axes']
    if not len(frequencies) == len(amplitudes) == len(axes):
        raise ConfigError('vibration_lines: frequencies_hz, amplitudes_arcsec_per_s and axes need one entry per '
                          f'line, got {len(frequencies)}, {len(amplitudes)} and {len(axes)}')
    unknown = sorted(set(map(str, axes)) - set(AXES))
    if unknown:
        raise ConfigError(f'vibration_lines: unknown axis {", ".join(unknown)}; use el, xel or los')
    try:
        return [(float(f), float(a), _AXIS_INDEX[axis]) for f, a, axis in zip(frequencies, amplitudes, axes)]
    except (TypeError, ValueError) as err:
        raise ConfigError(f'vibration_lines: frequencies and amplitudes must be numbers ({err})') from err


def check_noise_model(effects: Mapping[str, EffectParams]) -> None:
    """ConfigError naming the effect when a model cannot predict noise (lines, LOS period, noise coefficients).

    Args:
        effects: the noise model, effect name -> parameters.

    Raises:
        ConfigError: bad vibration_lines (model_lines), a LOS period <= 0, or a negative gyro_noise coefficient.
    """
    model_lines(effects)
    if effects.get('los_oscillation') and effects['los_oscillation']['period_s'] <= 0.0:
        raise ConfigError(f'los_oscillation: period_s must be > 0 s, got {effects["los_oscillation"]["period_s"]:g}')
    negative = sorted(key for key, value in (effects.get('gyro_noise') or {}).items()
                      if isinstance(value, float) and value < 0.0)
    if negative:
        raise ConfigError(f'gyro_noise: {", ".join(negative)} must be >= 0 (noise coefficients, Table 5.1)')


def predicted_noise(effects: Mapping[str, EffectParams], grid: NoiseGrid, freq_hz: np.ndarray | None = None, *,
                    include_arw: bool = True) -> tuple[np.ndarray, np.ndarray]:
    """Model AV (3 x taus, (arcsec/s)^2) and one-sided PSD (3 x freqs) per axis (module docstring).

    Args:
        effects: the noise model, effect name -> parameters.
        grid: the taus, sample and read-out rates and segment length compared on.
        freq_hz: the PSD's frequencies [Hz]; None for the grid's.
        include_arw: add gyro_noise's ARW (False when the caller fits the white level itself).

    Returns:
        The AV, (3, n_tau) [(arcsec/s)^2], and the PSD, (3, n_freq) [(arcsec/s)^2/Hz], rows el, xel, los.

    Raises:
        ConfigError: bad vibration_lines (model_lines).
    """
    freq_hz = grid.freq_hz if freq_hz is None else freq_hz
    av, psd = np.zeros((3, grid.tau_s.size)), np.zeros((3, freq_hz.size))
    if effects.get('gyro_noise'):
        for term_av, term_psd in _gyro_noise_terms(effects['gyro_noise'], grid, freq_hz, include_arw):
            av += term_av
            psd += term_psd
    if effects.get('gyro_bias_drift'):
        for index, axis in enumerate(AXES):
            ramp = rate_ramp_deg_per_h2_to_arcsec_per_s2(effects['gyro_bias_drift'][f'{axis}_deg_per_h2'])
            av[index] += (ramp * grid.tau_s) ** 2 / 2.0
            psd[index] += rate_ramp_psd(freq_hz, ramp)
    for frequency_hz, amplitude, index in model_lines(effects):
        line_av, line_psd = _sinusoid(amplitude, frequency_hz, grid, freq_hz)
        av[index] += line_av
        psd[index] += line_psd
    if effects.get('los_oscillation'):
        params = effects['los_oscillation']
        line_av, line_psd = _sinusoid(2.0 * np.pi * params['amplitude_arcsec'] / params['period_s'],
                                      1.0 / params['period_s'], grid, freq_hz)
        av[2] += line_av
        psd[2] += line_psd
    return av, psd
