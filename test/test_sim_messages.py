"""The 400 Hz samples' own CDR path is the same bytes as the typestore's serializer (bag equivalence)."""

import numpy as np
import pytest

from sofia_ros import messages as m
from sofia_ros.bag import wire_cdr


def _block():
    rng = np.random.default_rng(7)
    stamps = 7 * m.NS_PER_S + np.arange(1, 81, dtype=np.int64) * 2_500_000
    return m.ImuBlock('gyrf', stamps, rng.normal(size=(80, 3)), rng.normal(size=(80, 3)))


def test_imu_block_cdr_is_byte_for_byte_what_the_typestore_writes():
    block = _block()
    assert m.imu_block_cdr(block) == [bytes(wire_cdr(msg)) for msg in m.imu_messages(block)]


def test_imu_block_round_trips_through_cdr():
    block = _block()
    back = m.imu_block_from_cdr('gyrf', m.imu_block_cdr(block))
    np.testing.assert_array_equal(back.stamp_ns, block.stamp_ns)
    np.testing.assert_array_equal(back.angular_velocity_rad_per_s, block.angular_velocity_rad_per_s)
    np.testing.assert_array_equal(back.linear_acceleration_m_per_s2, block.linear_acceleration_m_per_s2)


def test_imu_samples_of_two_lengths_are_not_one_block():
    samples = m.imu_block_cdr(_block())[:2] + m.imu_block_cdr(m.ImuBlock('a_much_longer_frame', *_block_arrays()))[:1]
    with pytest.raises(ValueError, match='of one frame_id'):
        m.imu_block_from_cdr('gyrf', samples)


def _block_arrays():
    block = _block()
    return block.stamp_ns, block.angular_velocity_rad_per_s, block.linear_acceleration_m_per_s2


def test_log_stamp_is_the_header_stamp_for_stamped_types_only():
    cdr = m.imu_block_cdr(_block())[0]
    assert m.log_stamp_ns('sensor_msgs/msg/Imu', cdr, 5) == 7 * m.NS_PER_S + 2_500_000
    assert m.log_stamp_ns('std_msgs/msg/String', cdr, 5) == 5
