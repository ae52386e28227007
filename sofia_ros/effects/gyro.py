"""Gyro effects: alignment, bias, scale factor, calibration assignment and noise (2.4.1, 4.2, 5, 6.1, 6.3)."""

from __future__ import annotations

from sofia_ros.effects.base import EffectParams, EffectSpec, Parameter
from sofia_ros.frames import AXES


def _equal_line_lists(params: EffectParams) -> str | None:
    """vibration_lines: one frequency, amplitude and axis per line."""
    lengths = [len(params[key]) for key in ('frequencies_hz', 'amplitudes_arcsec_per_s', 'axes')]
    if len(set(lengths)) > 1:
        return ('frequencies_hz, amplitudes_arcsec_per_s and axes need one entry per line, got '
                f'{lengths[0]}, {lengths[1]} and {lengths[2]}')
    return None

EFFECTS: tuple[EffectSpec, ...] = (
    EffectSpec(
        'gyro_misalignment', 'gyro', '3.3.2, 6.1, eq. 6.1',
        'GYRF rotated against TARF by small angles about the EL, XEL and LOS axes; defaults are the '
        'rotations in the matrix of eq. 6.1 (the as-mounted gyro box of 2004).',
        (
            Parameter('about_el_arcsec', 1030.0, 'arcsec', 'rotation of GYRF about the TARF EL axis',
                      minimum=-36000.0, maximum=36000.0),
            Parameter('about_xel_arcsec', 730.0, 'arcsec', 'rotation of GYRF about the TARF XEL axis',
                      minimum=-36000.0, maximum=36000.0),
            Parameter('about_los_arcsec', 3590.0, 'arcsec', 'rotation of GYRF about the TARF LOS axis',
                      minimum=-36000.0, maximum=36000.0),
        ),
    ),
    EffectSpec(
        'gyro_bias', 'gyro', '2.4.1, 5.2.4, Table 5.7',
        'Constant rate bias per gyro axis left after the temperature bias model; defaults are the '
        'residual biases of Table 5.7 at the least-squares heading.',
        (
            Parameter('el_deg_per_h', -0.0643, 'deg/h', 'rate bias of the EL gyro', minimum=-10.0, maximum=10.0),
            Parameter('xel_deg_per_h', 0.1624, 'deg/h', 'rate bias of the XEL gyro', minimum=-10.0, maximum=10.0),
            Parameter('los_deg_per_h', -0.0909, 'deg/h', 'rate bias of the LOS gyro', minimum=-10.0, maximum=10.0),
        ),
    ),
    EffectSpec(
        'gyro_bias_drift', 'gyro', '4.2.3, Table 5.1',
        'Rate ramp: the bias changes linearly with time; defaults are the 2008 rate-ramp '
        'coefficients of gyros 001, 002 and 003 (Table 5.1).',
        (
            Parameter('el_deg_per_h2', 0.0008, 'deg/h^2', 'rate ramp of the EL gyro', minimum=-1.0, maximum=1.0),
            Parameter('xel_deg_per_h2', 0.00288, 'deg/h^2', 'rate ramp of the XEL gyro', minimum=-1.0, maximum=1.0),
            Parameter('los_deg_per_h2', 0.01224, 'deg/h^2', 'rate ramp of the LOS gyro', minimum=-1.0, maximum=1.0),
        ),
    ),
    EffectSpec(
        'gyro_scale_factor', 'gyro', '2.4.1, 6.3',
        'Scale factor error per gyro axis; 400 ppm gives the ~50" deviation at 34 deg separation '
        'of Fig. 6.11.',
        (
            Parameter('el_ppm', 400.0, 'ppm', 'scale factor error of the EL gyro', minimum=-10000.0, maximum=10000.0),
            Parameter('xel_ppm', 400.0, 'ppm', 'scale factor error of the XEL gyro', minimum=-10000.0, maximum=10000.0),
            Parameter('los_ppm', 400.0, 'ppm', 'scale factor error of the LOS gyro', minimum=-10000.0, maximum=10000.0),
        ),
    ),
    EffectSpec(
        'gyro_axis_swap', 'gyro', '6.3',
        'Temperature calibration polynomials (scale factor and bias) applied to the wrong gyro axes, '
        'found after the 2004 tests: each swapped axis gets the other gyro\'s scale factor and bias '
        'model, an error that changes with temperature.',
        (
            Parameter('swapped_axes', 'el-xel', 'axis pair', 'the two gyro axes whose calibrations are exchanged',
                      choices=('el-xel', 'el-los', 'xel-los', 'xel-el', 'los-el', 'los-xel')),
            Parameter('scale_difference_ppm', 400.0, 'ppm', 'scale factor difference of the two calibrations',
                      minimum=-10000.0, maximum=10000.0),
            Parameter('scale_temperature_coefficient_ppm_per_c', 20.0, 'ppm/C',
                      'temperature slope of that difference (illustrative; the polynomials are not printed)',
                                                             minimum=-1000.0, maximum=1000.0),
            Parameter('bias_difference_deg_per_h', 0.05, 'deg/h', 'bias difference of the two calibrations',
                      minimum=-10.0, maximum=10.0),
        ),
    ),
    EffectSpec(
        'gyro_noise', 'gyro', '4.2, Table 5.1',
        'Random noise of the FOGs: quantization, angle random walk, bias instability, rate random walk; '
        'defaults are gyro 002 (2008) of Table 5.1 with K read as printed / 60 (the printed K cannot '
        'reproduce the table\'s own in-run bias stability) and no bias instability (5.1: no plateau).',
        (
            Parameter('quantization_arcsec', 0.000767, 'arcsec', 'angular increment (scale factor) per count',
                      minimum=0.0, maximum=1.0),
            Parameter('arw_deg_per_sqrt_h', 0.00022, 'deg/sqrt(h)', 'angle random walk coefficient N',
                      minimum=0.0, maximum=1.0),
            Parameter('bias_instability_deg_per_h', 0.0, 'deg/h', 'bias instability coefficient B',
                      minimum=0.0, maximum=10.0),
            Parameter('bias_instability_cutoff_hz', 10.0, 'Hz', '3-dB cut-off f0 of the 1/f noise', shape=True,
                      minimum=0.001, maximum=200.0),
            Parameter('rrw_deg_per_h_sqrt_h', 0.00216, 'deg/h^1.5', 'rate random walk coefficient K',
                      minimum=0.0, maximum=1.0),
        ),
    ),
    EffectSpec(
        'los_oscillation', 'gyro', '5.2.4, Figs. 5.8-5.9',
        'Slow sinusoid on the LOS gyro, period about 20 min, documented since [Moik 2000].',
        (
            Parameter('period_s', 1200.0, 's', 'period of the oscillation', shape=True, minimum=1.0, maximum=86400.0),
            Parameter('amplitude_arcsec', 5.0, 'arcsec', 'amplitude of the integrated angle',
                      minimum=0.0, maximum=3600.0),
            Parameter('phase_deg', 0.0, 'deg', 'phase of the integrated angle at the start of the record', shape=True,
                      minimum=-360.0, maximum=360.0),
        ),
    ),
    EffectSpec(
        'vibration_lines', 'gyro', 'Tables 5.4, 5.5, 5.2.5',
        'Sinusoidal rate lines from ground equipment and TA subsystems (0.7/1.3 Hz always, VIS 2.3 Hz '
        'uncaged, main oil pump 30 Hz, cooling carts, fans), aliased by the 400 Hz sampling.',
        (
            Parameter('frequencies_hz', [0.7, 1.3], 'Hz', 'line frequencies (before aliasing)',
                      minimum=0.0, maximum=1000.0),
            Parameter('amplitudes_arcsec_per_s', [0.05, 0.05], 'arcsec/s', 'rate amplitude of each line',
                      minimum=0.0, maximum=100.0),
            Parameter('axes', ['el', 'el'], 'axis', 'gyro axis each line appears on', choices=AXES),
        ),
        check=_equal_line_lists,
    ),
)
