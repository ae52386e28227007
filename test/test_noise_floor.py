"""The angle random walk compare takes from a bag's gyro samples (compare.floor, 4.2.3), against allantools."""

import allantools
import numpy as np
import pytest

from sofia_ros.compare.floor import MIN_WITHIN_TICK_DIFFERENCES, angle_random_walk_rad_per_sqrt_s
from sofia_ros.compare.observations import GyroSamples
from sofia_ros.errors import BagError
from sofia_ros.sensors.gyro_noise import within_tick_rate_sigma_rad_per_s

SAMPLE_RATE_HZ = 400.0
SAMPLES_PER_TICK = 20
#: Table 5.1's angle random walk, 0.0132"/sqrt(s) -> rad/sqrt(s).
ARW_RAD_PER_SQRT_S = np.radians(0.0132 / 3600.0)


def _ticked_rates(tick_count, rng):
    """A plant rate held over each tick (a different one per tick, up to 1 deg/s) plus white rate noise of N."""
    time_s = np.arange(tick_count * SAMPLES_PER_TICK) / SAMPLE_RATE_HZ
    tick_end_s = time_s[SAMPLES_PER_TICK - 1::SAMPLES_PER_TICK]
    held_rad_per_s = np.repeat(rng.uniform(-0.0175, 0.0175, (tick_count, 3)), SAMPLES_PER_TICK, axis=0)
    noise_rad_per_s = ARW_RAD_PER_SQRT_S * np.sqrt(SAMPLE_RATE_HZ) * rng.standard_normal(held_rad_per_s.shape)
    return time_s, held_rad_per_s + noise_rad_per_s, tick_end_s, noise_rad_per_s


def _gyro(time_s, rates, tick_end_s):
    sigma, count = within_tick_rate_sigma_rad_per_s(time_s, rates, tick_end_s)
    empty = np.zeros(0)
    return GyroSamples(time_s, sigma, count, tick_end_s, empty, empty, 1.0 / SAMPLE_RATE_HZ, empty, empty, empty,
                       empty)


def test_the_angle_random_walk_is_allantools_one_of_the_noise_without_the_held_rates():
    time_s, rates, tick_end_s, noise = _ticked_rates(2000, np.random.default_rng(5))
    # The held rates step by up to 2 deg/s between ticks: differences across a tick's end would swamp the noise.
    arw = angle_random_walk_rad_per_sqrt_s(_gyro(time_s, rates, tick_end_s))
    # Allan deviation of the noise alone at tau = one sample: N / sqrt(tau) for white rate noise (4.16).
    _, adev, _, _ = allantools.oadev(noise[:, 0], rate=SAMPLE_RATE_HZ, data_type='freq', taus=[1.0 / SAMPLE_RATE_HZ])
    allantools_arw = adev[0] * np.sqrt(1.0 / SAMPLE_RATE_HZ)
    # 38 000 differences per axis, the worst of three: a few 1/sqrt(2 x 38 000) = 0.4 % apart.
    assert arw == pytest.approx(allantools_arw, rel=0.02)
    assert arw == pytest.approx(ARW_RAD_PER_SQRT_S, rel=0.02)


def test_too_few_samples_within_ticks_is_an_error_naming_them():
    # One sample per tick: no two samples share a tick.
    time_s = np.arange(500) / SAMPLE_RATE_HZ
    rates = np.zeros((500, 3))
    gyro = _gyro(time_s, rates, time_s)
    assert gyro.within_tick_difference_count == 0
    with pytest.raises(BagError, match=f'fewer than {MIN_WITHIN_TICK_DIFFERENCES} gyro samples within ticks'):
        angle_random_walk_rad_per_sqrt_s(gyro)
