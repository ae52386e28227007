"""Conversions between the simulation's records and common_interfaces messages.

Units follow REP-103 (rad, rad/s, m/s^2); ``frame_id`` names the reference frame.
The 400 Hz gyro stream travels as an :class:`ImuBlock` (one tick of samples) inside
the lock-step runner and, over DDS, as one message per tick holding each sample's
``sensor_msgs/Imu`` CDR (:func:`sample_block_cdr`); both become the same CDR bytes in
a bag, one record per sample (:func:`imu_block_cdr` is pinned against the typestore's
serializer by a test).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

import numpy as np
from builtin_interfaces.msg import Time
from diagnostic_msgs.msg import DiagnosticStatus, KeyValue
from geometry_msgs.msg import Point, Pose, PoseArray, QuaternionStamped, Vector3Stamped
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import Imu, JointState, Temperature
from std_msgs.msg import String

from sofia_ros.bag.imu import decode_imu_rows
from sofia_ros.bag.timebase import stamp_fields

__all__ = [
    'NS_PER_S',
    'ImuBlock',
    'ImuSample',
    'time_msg',
    'stamp_ns_of',
    'seconds_to_ns',
    'clock_msg',
    'quaternion_stamped',
    'quaternion_xyzw_of',
    'vector3_stamped',
    'vector_of',
    'joint_state',
    'joint_positions_of',
    'temperature_msg',
    'centroid_array',
    'centroids_of',
    'status_msg',
    'status_values_of',
    'string_msg',
    'imu_messages',
    'imu_block_cdr',
    'imu_block_rows',
    'parameter_event',
    'STAMPED_MSGTYPES',
    'log_stamp_ns',
    'imu_block_from_cdr',
    'sample_block_cdr',
    'samples_of_block_cdr',
    'sample_rows_of_block_cdr',
]

NS_PER_S = 1_000_000_000


def seconds_to_ns(seconds):
    """Seconds (float) to integer nanoseconds, rounded."""
    return int(round(seconds * NS_PER_S))


def time_msg(stamp_ns):
    """builtin_interfaces/Time of a stamp in ns."""
    sec, nanosec = divmod(int(stamp_ns), NS_PER_S)
    return Time(sec=sec, nanosec=nanosec)


def stamp_ns_of(stamp):
    """Nanoseconds of a builtin_interfaces/Time."""
    return stamp.sec * NS_PER_S + stamp.nanosec


def clock_msg(stamp_ns):
    """rosgraph_msgs/Clock at a stamp."""
    return Clock(clock=time_msg(stamp_ns))


def quaternion_stamped(stamp_ns, frame_id, quaternion_xyzw):
    """geometry_msgs/QuaternionStamped; scalar-last like the thesis (B.5)."""
    msg = QuaternionStamped()
    msg.header.stamp = time_msg(stamp_ns)
    msg.header.frame_id = frame_id
    q = msg.quaternion
    q.x, q.y, q.z, q.w = (float(value) for value in quaternion_xyzw)
    return msg


def quaternion_xyzw_of(msg):
    """(x, y, z, w) of a QuaternionStamped or Quaternion."""
    q = getattr(msg, 'quaternion', msg)
    return np.array([q.x, q.y, q.z, q.w])


def vector3_stamped(stamp_ns, frame_id, vector):
    """geometry_msgs/Vector3Stamped."""
    msg = Vector3Stamped()
    msg.header.stamp = time_msg(stamp_ns)
    msg.header.frame_id = frame_id
    msg.vector.x, msg.vector.y, msg.vector.z = (float(value) for value in vector)
    return msg


def vector_of(msg):
    """numpy 3-vector of a Vector3Stamped or Vector3."""
    v = getattr(msg, 'vector', msg)
    return np.array([v.x, v.y, v.z])


def joint_state(stamp_ns, positions, velocities=None):
    """sensor_msgs/JointState from name -> position (rad) and optional name -> velocity (rad/s)."""
    msg = JointState()
    msg.header.stamp = time_msg(stamp_ns)
    msg.name = list(positions)
    msg.position = [float(positions[name]) for name in msg.name]
    if velocities is not None:
        msg.velocity = [float(velocities[name]) for name in msg.name]
    return msg


def joint_positions_of(msg):
    """name -> position (float) of a JointState, an rclpy message or one decoded from CDR (numpy positions)."""
    return dict(zip(msg.name, msg.position.tolist()))


def temperature_msg(stamp_ns, frame_id, temperature_c):
    """sensor_msgs/Temperature in deg C."""
    msg = Temperature()
    msg.header.stamp = time_msg(stamp_ns)
    msg.header.frame_id = frame_id
    msg.temperature = float(temperature_c)
    return msg


def centroid_array(stamp_ns, camera, centroids):
    """geometry_msgs/PoseArray of centroids: position.x/.y = column/row in px, position.z = HIP number."""
    msg = PoseArray()
    msg.header.stamp = time_msg(stamp_ns)
    msg.header.frame_id = camera
    msg.poses = [Pose(position=Point(x=float(c.x_px), y=float(c.y_px), z=float(c.hip))) for c in centroids]
    return msg


def centroids_of(msg):
    """(hip, x_px, y_px) tuples of a centroid PoseArray."""
    return [(int(round(p.position.z)), p.position.x, p.position.y) for p in msg.poses]


def status_msg(name, message, values=None, level=DiagnosticStatus.OK, hardware_id=''):
    """diagnostic_msgs/DiagnosticStatus with key/value pairs."""
    return DiagnosticStatus(
        level=level, name=name, message=message, hardware_id=hardware_id,
        values=[KeyValue(key=str(key), value=str(value)) for key, value in (values or {}).items()],
    )


def status_values_of(msg):
    """key -> value of a DiagnosticStatus."""
    return {kv.key: kv.value for kv in msg.values}


def string_msg(text):
    """std_msgs/String."""
    return String(data=text)


@dataclass(frozen=True)
class ImuSample:
    """One gyro-box sample: stamp, rate (rad/s) and specific force (m/s^2) in GYRF."""

    stamp_ns: int
    angular_velocity_rad_per_s: tuple
    linear_acceleration_m_per_s2: tuple


@dataclass(frozen=True)
class ImuBlock:
    """One tick of 400 Hz gyro-box samples as arrays (N stamps, Nx3 rates, Nx3 specific forces)."""

    frame_id: str
    stamp_ns: np.ndarray
    angular_velocity_rad_per_s: np.ndarray
    linear_acceleration_m_per_s2: np.ndarray

    def __len__(self):
        return len(self.stamp_ns)


_NO_ORIENTATION_COVARIANCE = (-1.0,) + (0.0,) * 8  # REP-145: orientation not provided


def imu_messages(block):
    """One sensor_msgs/Imu per sample of an ImuBlock (orientation marked unknown)."""
    messages = []
    for stamp_ns, rate, force in zip(block.stamp_ns, block.angular_velocity_rad_per_s,
                                     block.linear_acceleration_m_per_s2):
        msg = Imu()
        msg.header.stamp = time_msg(stamp_ns)
        msg.header.frame_id = block.frame_id
        msg.orientation_covariance = _NO_ORIENTATION_COVARIANCE
        w, a = msg.angular_velocity, msg.linear_acceleration
        w.x, w.y, w.z = float(rate[0]), float(rate[1]), float(rate[2])
        a.x, a.y, a.z = float(force[0]), float(force[1]), float(force[2])
        messages.append(msg)
    return messages


def imu_block_rows(block, epoch_ns=0):
    """Little-endian CDR of each sample as sensor_msgs/Imu, exactly as DDS carries it: one row each, (N, bytes) uint8;
    the stamps moved by ``epoch_ns`` (a BagWriter's, for rows it writes with utc_stamps=True)."""
    frame = block.frame_id.encode() + b'\0'
    head_length = 4 + 8 + 4 + len(frame)  # encapsulation, stamp, string length, string
    head_length += -(head_length - 4) % 8  # doubles align to 8 from the end of the encapsulation
    count = len(block.stamp_ns)
    sec, nanosec = stamp_fields(np.asarray(block.stamp_ns, dtype=np.int64) + epoch_ns)
    head = np.zeros((count, head_length), dtype=np.uint8)
    head[:, :4] = np.frombuffer(b'\x00\x01\x00\x00', dtype=np.uint8)
    head[:, 4:8] = sec.view(np.uint8).reshape(count, 4)
    head[:, 8:12] = nanosec.view(np.uint8).reshape(count, 4)
    head[:, 12:16] = np.frombuffer(struct.pack('<I', len(frame)), dtype=np.uint8)
    head[:, 16:16 + len(frame)] = np.frombuffer(frame, dtype=np.uint8)
    # orientation (x y z w) and its covariance, angular velocity and its covariance, linear acceleration and its
    body = np.zeros((count, _IMU_VALUES + 9), dtype='<f8')
    body[:, 3] = 1.0
    body[:, 4:13] = _NO_ORIENTATION_COVARIANCE
    body[:, 13:16] = block.angular_velocity_rad_per_s
    body[:, 25:28] = block.linear_acceleration_m_per_s2
    return np.hstack([head, body.view(np.uint8)])


def imu_block_cdr(block):
    """Little-endian CDR of each sample as sensor_msgs/Imu, exactly as DDS carries it (imu_block_rows), as bytes."""
    rows = imu_block_rows(block)
    data, length = rows.tobytes(), rows.shape[1]
    return [data[start:start + length] for start in range(0, len(data), length)]


def parameter_event(stamp_ns, node, values):
    """rcl_interfaces/ParameterEvent reporting ``values`` (name -> value) changed on ``/node``."""
    from rcl_interfaces.msg import Parameter, ParameterEvent, ParameterType, ParameterValue

    changed = []
    for name, value in values.items():
        parameter_value = ParameterValue()
        if isinstance(value, bool):
            parameter_value.type, parameter_value.bool_value = ParameterType.PARAMETER_BOOL, value
        elif isinstance(value, (int, float)):
            parameter_value.type, parameter_value.double_value = ParameterType.PARAMETER_DOUBLE, float(value)
        else:
            parameter_value.type = ParameterType.PARAMETER_DOUBLE_ARRAY
            parameter_value.double_array_value = [float(item) for item in np.ravel(value)]
        changed.append(Parameter(name=name, value=parameter_value))
    return ParameterEvent(stamp=time_msg(stamp_ns), node=f'/{node}', changed_parameters=changed)


#: Types whose CDR starts with a builtin_interfaces/Time (a Header or a stamp): bytes 4-12 are sec, nanosec.
STAMPED_MSGTYPES = frozenset({
    'sensor_msgs/msg/Imu', 'sensor_msgs/msg/JointState', 'sensor_msgs/msg/Temperature',
    'geometry_msgs/msg/PoseArray', 'geometry_msgs/msg/QuaternionStamped', 'geometry_msgs/msg/Vector3Stamped',
    'geometry_msgs/msg/PointStamped', 'rosgraph_msgs/msg/Clock', 'rcl_interfaces/msg/ParameterEvent',
})
_STAMP = struct.Struct('<iI')


def log_stamp_ns(msgtype, cdr, fallback_ns):
    """Bag log time: the message's own stamp when its type starts with one, else ``fallback_ns``."""
    if msgtype not in STAMPED_MSGTYPES:
        return fallback_ns
    sec, nanosec = _STAMP.unpack_from(cdr, 4)
    return sec * NS_PER_S + nanosec


_IMU_VALUES = 28  # orientation 4, its covariance 9, angular velocity 3, covariance 9, linear acceleration 3


def imu_block_from_cdr(frame_id, samples):
    """ImuBlock of raw sensor_msgs/Imu CDR samples of one frame_id, hence of one length (the inverse of
    :func:`imu_block_cdr`), read as one array (bag.imu.decode_imu_rows): a tick's 80 samples cost what one did
    sample by sample."""
    if not samples:
        return ImuBlock(frame_id, np.zeros(0, dtype=np.int64), np.zeros((0, 3)), np.zeros((0, 3)))
    length = len(samples[0])
    if any(len(sample) != length for sample in samples):
        raise ValueError('IMU samples of a block must be sensor_msgs/Imu CDR of one frame_id')
    rows = np.frombuffer(b''.join(samples), dtype=np.uint8).reshape(len(samples), length)
    return ImuBlock(frame_id, *decode_imu_rows(rows))


# A block is a std_msgs/UInt8MultiArray: layout.dim = [samples (size n, stride n * L), sample CDR (size L,
# stride L)], data_offset 0, data = the n samples' CDR one after the other (each L bytes: every sample of a
# block has the same frame_id, hence the same length). ros2 topic echo shows the layout.
_BLOCK_LABELS = (b'samples\0', b'imu_cdr\0')
_UINT32 = struct.Struct('<I')


def sample_block_cdr(samples):
    """CDR of a std_msgs/UInt8MultiArray carrying equal-length CDR ``samples`` back to back (one tick's block)."""
    count = len(samples)
    length = len(samples[0]) if samples else 0
    parts = [b'\x00\x01\x00\x00', _UINT32.pack(2)]
    for label, (size, stride) in zip(_BLOCK_LABELS, ((count, count * length), (length, length))):
        # Each label is a multiple of 4 bytes long with its NUL, so no padding follows it.
        parts += [_UINT32.pack(len(label)), label, _UINT32.pack(size), _UINT32.pack(stride)]
    parts += [_UINT32.pack(0), _UINT32.pack(count * length), *samples]
    return b''.join(parts)


_BLOCK_HEADER = struct.Struct('<4sI I8sII I8sII I I')


def _block_layout(data):
    """(samples, bytes each) of a block written by :func:`sample_block_cdr`; ValueError for anything else."""
    fields = _BLOCK_HEADER.unpack_from(data) if len(data) >= _BLOCK_HEADER.size else (None,) * 12
    count, length, total = fields[4], fields[8], fields[11]
    if (fields[1] != 2 or (fields[3], fields[7]) != _BLOCK_LABELS or count * length != total
            or len(data) < _BLOCK_HEADER.size + total):
        raise ValueError('not a sample block: expected the layout of messages.sample_block_cdr')
    return count, length


def samples_of_block_cdr(data):
    """The sample CDRs of a block written by :func:`sample_block_cdr`, as memoryviews into ``data``."""
    count, length = _block_layout(data)
    view = memoryview(data)[_BLOCK_HEADER.size:]
    return [view[index * length:(index + 1) * length] for index in range(count)]


def sample_rows_of_block_cdr(data):
    """The sample CDRs of a block written by :func:`sample_block_cdr`, as the rows of a (samples, bytes) uint8
    array over ``data``."""
    count, length = _block_layout(data)
    return np.frombuffer(data, dtype=np.uint8, count=count * length, offset=_BLOCK_HEADER.size).reshape(count, length)
