"""Gyro box core: three FOGs and three accelerometers sampled at 400 Hz (2.4.1, 2.4.2, 4.2, 5).

Each tick the plant reports the telescope's mean inertial body rate (TARF) and
specific force; the box turns them into GYRF samples through the truth's deterministic
gyro errors (sensors.gyro_errors, shared with the model side of `sofia compare`) and
the noise of 4.2.3 (sensors.gyro_noise). Samples are instantaneous at 400 Hz, so lines
above 200 Hz alias as the thesis warns (Tables 5.4, 5.5).
"""

from __future__ import annotations

import numpy as np

from sofia_ros import messages as m
from sofia_ros.frames import dcm_from_rotation_angles
from sofia_ros.sensors.gyro_errors import (
    AXES,
    AXIS_SWAP_REFERENCE_C,
    gyro_error_model,
    measured_rates_gyrf_rad_per_s,
)
from sofia_ros.sensors.gyro_noise import GyroNoiseStream, NoiseCoefficients
from sofia_ros.sim.plant import TOPICS as PLANT_TOPICS
from sofia_ros.sim.protocol import NodeCore
from sofia_ros.topics import GYRO_IMU as IMU_TOPIC
from sofia_ros.topics import GYRO_TEMPERATURE as TEMPERATURE_TOPIC
from sofia_ros.units import GYRO_SAMPLE_RATE_HZ, STANDARD_GRAVITY_M_PER_S2

__all__ = ['GyroBoxCore']


class GyroBoxCore(NodeCore):
    """Truth to gyro-box samples."""

    name = 'gyro_box'
    upstream = (('plant', 0),)

    def __init__(self, truth_effects, *, seed=0, sample_rate_hz=GYRO_SAMPLE_RATE_HZ):
        super().__init__()
        self.sample_rate_hz = sample_rate_hz
        self.errors = gyro_error_model(truth_effects)
        self.accrf_from_tarf = self.errors.tarf_from_gyrf.T @ self._accelerometer_misalignment(truth_effects)
        self.accelerometer_bias_m_per_s2 = np.array(
            [truth_effects.get('accelerometer_bias', {}).get(f'{axis}_mg', 0.0) for axis in AXES]
        ) * 1e-3 * STANDARD_GRAVITY_M_PER_S2
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
        temperature_c = self.temperature_c if self.temperature_c is not None else AXIS_SWAP_REFERENCE_C
        rates = measured_rates_gyrf_rad_per_s(self.errors, m.vector_of(truth.angular_velocity), times_s,
                                              np.full(len(times_s), temperature_c),
                                              m.vector_of(truth.linear_acceleration))
        if self.noise is not None:
            rates = self.noise.next_rad_per_s(len(stamps_ns), rates)
        force = self.accrf_from_tarf @ m.vector_of(truth.linear_acceleration) + self.accelerometer_bias_m_per_s2
        block = m.ImuBlock('gyrf', stamps_ns, rates, np.full((len(stamps_ns), 3), force))
        outputs = [(IMU_TOPIC.name, block)]
        if self.temperature_c is not None:
            outputs.append((TEMPERATURE_TOPIC.name, m.temperature_msg(stamp_ns, 'gyrf', self.temperature_c)))
        return outputs
