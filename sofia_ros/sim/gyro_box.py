"""Gyro box core: three FOGs and three accelerometers sampled at 400 Hz (2.4.1, 2.4.2, 4.2, 5).

Each tick the plant reports the telescope's mean inertial body rate (TARF) and
specific force; the box turns them into GYRF samples with the truth's sensor errors:
misalignment (the true A_TARF,GYRF is the rotation by ``gyro_misalignment``, read like
eq. 6.1), scale factor, bias, bias drift (rate ramp), noise (4.2.3), the LOS
oscillation and vibration lines of 5.2, the calibration axis swap of 6.3, and the
residual tracker drift of 6.3 (a rate error the gyros do not see, so the telescope
really drifts). Samples are instantaneous at 400 Hz, so lines above 200 Hz alias as
the thesis warns (Tables 5.4, 5.5).
"""

from __future__ import annotations

import numpy as np

from sofia_ros.frames import dcm_from_rotation_angles
from sofia_ros.sensors.gyro_noise import GyroNoiseStream, NoiseCoefficients
from sofia_ros.sim import messages as m
from sofia_ros.sim.plant import TOPICS as PLANT_TOPICS
from sofia_ros.sim.protocol import NodeCore, TopicSpec
from sofia_ros.units import (
    GYRO_SAMPLE_RATE_HZ,
    RAD_PER_ARCSEC,
    RAD_PER_DEG,
    STANDARD_GRAVITY_M_PER_S2,
)

__all__ = ['GyroBoxCore', 'IMU_TOPIC', 'true_tarf_from_gyrf']

IMU_TOPIC = TopicSpec('/gyro_box/imu', 'sensor_msgs/msg/Imu',
                      'one 400 Hz sample: FOG rates (rad/s) and accelerations (m/s^2) in GYRF')
TEMPERATURE_TOPIC = TopicSpec('/gyro_box/temperature', 'sensor_msgs/msg/Temperature',
                              'gyro box temperature (deg C), once per tick')
AXES = ('el', 'xel', 'los')
_AXIS_INDEX = {axis: index for index, axis in enumerate(AXES)}
_FPI_ARCSEC_PER_PX = 0.55


def true_tarf_from_gyrf(truth_effects):
    """True A_TARF,GYRF: the rotation by the gyro_misalignment angles (eq. 6.1 reading), else identity."""
    params = truth_effects.get('gyro_misalignment')
    if params is None:
        return np.eye(3)
    angles_arcsec = [params[f'about_{axis}_arcsec'] for axis in AXES]
    return dcm_from_rotation_angles(np.asarray(angles_arcsec) * RAD_PER_ARCSEC)


def _per_axis(params, suffix, scale=1.0):
    return np.array([params[f'{axis}_{suffix}'] for axis in AXES]) * scale if params else np.zeros(3)


class GyroBoxCore(NodeCore):
    """Truth to gyro-box samples."""

    name = 'gyro_box'
    upstream = (('plant', 0),)

    def __init__(self, truth_effects, *, seed=0, sample_rate_hz=GYRO_SAMPLE_RATE_HZ):
        super().__init__()
        self.sample_rate_hz = sample_rate_hz
        self.gyrf_from_tarf = true_tarf_from_gyrf(truth_effects).T
        self.accrf_from_tarf = self.gyrf_from_tarf @ self._accelerometer_misalignment(truth_effects)
        self.scale_error = _per_axis(truth_effects.get('gyro_scale_factor'), 'ppm', 1e-6)
        self.bias_rad_per_s = _per_axis(truth_effects.get('gyro_bias'), 'deg_per_h', RAD_PER_DEG / 3600.0)
        self.ramp_rad_per_s2 = _per_axis(truth_effects.get('gyro_bias_drift'), 'deg_per_h2', RAD_PER_DEG / 3600.0**2)
        self.accelerometer_bias_m_per_s2 = _per_axis(
            truth_effects.get('accelerometer_bias'), 'mg', 1e-3 * STANDARD_GRAVITY_M_PER_S2)
        self.los_oscillation = truth_effects.get('los_oscillation')
        self.vibration_lines = truth_effects.get('vibration_lines')
        self.axis_swap = truth_effects.get('gyro_axis_swap')
        self.tracker_drift = truth_effects.get('tracker_drift')
        noise = truth_effects.get('gyro_noise')
        self.noise = None
        if noise is not None:
            coefficients = NoiseCoefficients(
                quantization_arcsec=noise['quantization_arcsec'], arw_deg_per_sqrt_h=noise['arw_deg_per_sqrt_h'],
                bias_instability_deg_per_h=noise['bias_instability_deg_per_h'],
                bias_cutoff_hz=noise['bias_instability_cutoff_hz'], rrw_deg_per_h_sqrt_h=noise['rrw_deg_per_h_sqrt_h'])
            self.noise = GyroNoiseStream(coefficients, sample_rate_hz=sample_rate_hz, rng=seed)
        self.last_stamp_ns = 0
        self.temperature_c = None
        self.pending = None

    @staticmethod
    def _accelerometer_misalignment(truth_effects):
        params = truth_effects.get('accelerometer_misalignment')
        if params is None:
            return np.eye(3)
        return dcm_from_rotation_angles(np.array([params[f'about_{axis}_urad'] for axis in AXES]) * 1e-6).T

    def inputs(self):
        return (PLANT_TOPICS['truth_imu'], PLANT_TOPICS['truth_temperature'])

    def outputs(self):
        return (IMU_TOPIC, TEMPERATURE_TOPIC)

    def receive(self, topic, message):
        if topic == PLANT_TOPICS['truth_imu'].name:
            self.pending = message
        elif topic == PLANT_TOPICS['truth_temperature'].name:
            self.temperature_c = message.temperature

    def tick(self, stamp_ns):
        truth = self.pending
        if truth is None:
            return []
        self.pending = None
        period_ns = int(round(m.NS_PER_S / self.sample_rate_hz))
        first_ns = (self.last_stamp_ns // period_ns + 1) * period_ns
        stamps_ns = np.arange(first_ns, stamp_ns + 1, period_ns, dtype=np.int64)
        self.last_stamp_ns = stamp_ns
        times_s = stamps_ns / m.NS_PER_S
        true_rate_gyrf = self.gyrf_from_tarf @ m.vector_of(truth.angular_velocity)
        rates = np.tile(true_rate_gyrf * (1.0 + self.scale_error), (len(stamps_ns), 1))
        rates += self.bias_rad_per_s + np.outer(times_s, self.ramp_rad_per_s2)
        rates += self._disturbances_rad_per_s(times_s)
        rates += self._axis_swap_error_rad_per_s(true_rate_gyrf)
        if self.noise is not None:
            rates = self.noise.next_rad_per_s(len(stamps_ns), rates)
        force = self.accrf_from_tarf @ m.vector_of(truth.linear_acceleration) + self.accelerometer_bias_m_per_s2
        block = m.ImuBlock('gyrf', stamps_ns, rates, np.tile(force, (len(stamps_ns), 1)))
        outputs = [(IMU_TOPIC.name, block)]
        if self.temperature_c is not None:
            outputs.append((TEMPERATURE_TOPIC.name, m.temperature_msg(stamp_ns, 'gyrf', self.temperature_c)))
        return outputs

    def _disturbances_rad_per_s(self, times_s):
        """LOS oscillation (5.2.4), vibration lines (5.2.5) and the residual tracker drift (6.3)."""
        extra = np.zeros((len(times_s), 3))
        if self.los_oscillation:
            omega = 2.0 * np.pi / self.los_oscillation['period_s']
            amplitude_rad = self.los_oscillation['amplitude_arcsec'] * RAD_PER_ARCSEC
            extra[:, 2] += amplitude_rad * omega * np.cos(omega * times_s)
        if self.vibration_lines:
            lines = zip(self.vibration_lines['frequencies_hz'], self.vibration_lines['amplitudes_arcsec_per_s'],
                        self.vibration_lines['axes'])
            for frequency_hz, amplitude_arcsec_per_s, axis in lines:
                extra[:, _AXIS_INDEX[axis]] += (amplitude_arcsec_per_s * RAD_PER_ARCSEC
                                               * np.sin(2.0 * np.pi * frequency_hz * times_s))
        if self.tracker_drift:
            # The telescope drifts by the negative of an unseen rate error about EL: FPI rows
            # move linearly plus a sinusoid (1.4 px/min, 2.2 px, 5.2 min in 6.3).
            params = self.tracker_drift
            omega = 2.0 * np.pi / (params['sine_period_min'] * 60.0)
            drift_px_per_s = (params['linear_px_per_min'] / 60.0
                              + params['sine_amplitude_px'] * omega * np.cos(omega * times_s))
            extra[:, 0] += drift_px_per_s * _FPI_ARCSEC_PER_PX * RAD_PER_ARCSEC
        return extra

    def _axis_swap_error_rad_per_s(self, true_rate_gyrf):
        """Scale and bias error of calibrations applied to the wrong axes, temperature dependent (6.3)."""
        if not self.axis_swap or self.temperature_c is None:
            return np.zeros(3)
        params = self.axis_swap
        first, second = (_AXIS_INDEX[axis] for axis in params['swapped_axes'].split('-'))
        delta_t_c = self.temperature_c - 22.8
        scale = (params['scale_difference_ppm'] + params['scale_temperature_coefficient_ppm_per_c'] * delta_t_c) * 1e-6
        bias_rad_per_s = params['bias_difference_deg_per_h'] * RAD_PER_DEG / 3600.0
        error = np.zeros(3)
        error[first] = scale * true_rate_gyrf[first] + bias_rad_per_s
        error[second] = -scale * true_rate_gyrf[second] - bias_rad_per_s
        return error
