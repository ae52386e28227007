"""rosbag2 bags in MCAP storage: writing (recorder, lock-step runner), reading (replay, analysis).

A bag is a directory ``DIR/`` holding ``DIR.mcap`` (zstd-compressed chunks, the
ROS 2 Kilted message definitions as ``ros2msg`` schemas) and ``metadata.yaml``
(rosbag2 version 9, ``storage_identifier: mcap``), as ``ros2 bag``, rosbags,
the mcap tools and Foxglove expect. Every chunk, the data section and the
summary carry their CRC-32 (mcap_storage), checked on reading; each chunk's
records are in log-time order; every topic records its offered QoS. A
campaign's bag is on the campaign's UTC time axis (timebase). docs/bag.md is
the contract.

Writing::

    with BagWriter('bags/run1', epoch_ns=start_ns) as bag:   # callers write campaign time
        bag.add_topic('/gyro_box/imu', 'sensor_msgs/msg/Imu')
        bag.write_raw('/gyro_box/imu', cdr_bytes, stamp_ns)    # from a raw subscription
        bag.write_message('/gyro_box/imu', imu_msg, stamp_ns)  # rclpy message object
        bag.write_document('/config/truth', truth_yaml_text, stamp_ns)

``write_raw`` stores the bytes as DDS delivered them. ``write_message`` stores
``wire_cdr(msg)``: rclpy's serialize_message leaves junk in padding and may add
trailing bytes, so the message goes through the typestore to get the exact CDR
a raw subscription receives (zero padding, no trailing bytes). A seeded run
that writes the same messages in the same order therefore writes the same bag,
byte for byte.

Documents: a text file that belongs to the run is stored as a latched
``std_msgs/msg/String`` on its own topic: ``/config/truth`` and ``/config/model``
for truth.yaml and model.yaml as used, ``/result/<name>`` for results (e.g.
``/result/summary``). ``BagReader.document(topic)`` returns the last one.

Crash safety: like ``ros2 bag record``, the writer writes ``metadata.yaml``
(atomically, tmp + rename) only in ``close()``; a bag without it was not
finished, and BagReader refuses it, naming the fix. An exception inside the
``with`` block aborts the same way: a failed run never looks complete. Complete
MCAP chunks (at most about 1 MiB each) reach the OS at every ``flush()`` and
whenever a message's log time is ``flush_period_ns`` (default 1 s) past the
previous flush (then with every message logged before that one), so a process
that is killed loses only the messages after the last flush.
``recover_bag(DIR)`` copies every complete chunk into a new, closed bag
``DIR_recovered`` and leaves ``DIR`` untouched.

Reading::

    with BagReader('bags/run1', campaign_time=True) as bag:  # times from the start again
        bag.topics                                  # (TopicInfo(name, msgtype, count), ...)
        for topic, stamp_ns, msg in bag.messages('/tascu/attitude', '/clock'):
            ...
        imu = bag.imu_arrays('/gyro_box/imu')       # numpy, decoded in bulk
        joints = bag.messages_by_topic('/ta/joint_states', columns=('/ta/joint_states',))['/ta/joint_states']
        joints.values['position[]'], joints.counts['position[]']   # any type as columns (bag.columns)
"""

from importlib import import_module

# Each name's module, imported on first use: a node process needs only the light modules (timebase, imu), and
# importing any of them runs this file first; the reader, writer and type store (rosbags, mcap) cost 0.2-0.4 CPU-s.
_MODULE_OF = {
    'BagReader': 'reader',
    'BagWriter': 'writer',
    'DOCUMENT_MSGTYPE': 'msgtypes',
    'IMU_MSGTYPE': 'msgtypes',
    'ImuArrays': 'imu',
    'ROS_DISTRO': 'msgtypes',
    'RecoveryReport': 'recovery',
    'TYPESTORE': 'msgtypes',
    'TopicInfo': 'msgtypes',
    'recover_bag': 'recovery',
    'wire_cdr': 'msgtypes',
}

__all__ = [
    'BagReader',
    'BagWriter',
    'DOCUMENT_MSGTYPE',
    'IMU_MSGTYPE',
    'ImuArrays',
    'ROS_DISTRO',
    'RecoveryReport',
    'TYPESTORE',
    'TopicInfo',
    'recover_bag',
    'wire_cdr',
]


def __getattr__(name: str) -> object:
    """The public name ``name`` from its module (PEP 562), imported now."""
    if name not in _MODULE_OF:
        raise AttributeError(f'module {__name__!r} has no attribute {name!r}')
    return getattr(import_module(f'{__name__}.{_MODULE_OF[name]}'), name)
