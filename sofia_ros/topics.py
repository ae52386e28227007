"""Every topic of the node graph and every document of a bag, in one place (docs/topics.md, docs/bag.md).

ROS-free: the cores, the rclpy shells, the recorder, replay, ``sofia compare``, ``sofia noise``,
``sofia perturb`` and the topic table of docs/topics.md all take topic names, types and meanings from here,
so a topic is renamed or added in one line. Who subscribes is not listed: each core's ``inputs()``
says what it reads, and ``sim.graph.graph_topics`` joins the two.
"""

from __future__ import annotations

from dataclasses import dataclass
from types import MappingProxyType
from typing import Mapping

from sofia_ros.graph_nodes import CAMERAS

__all__ = [
    'DEFAULT_TICK_NS', 'TopicSpec', 'CD_JOINT', 'FD_JOINTS',
    'CLOCK', 'TRUTH_IMU', 'TRUTH_JOINTS', 'TRUTH_TEMPERATURE', 'JOINT_STATES',
    'GYRO_IMU', 'GYRO_TEMPERATURE',
    'TASCU_ATTITUDE', 'MOTION_STATUS', 'DRIFT_ESTIMATE', 'COMMAND_STATUS', 'FD_COMMAND', 'CD_COMMAND',
    'MOVE_RELATIVE', 'MTBS_CENTROID', 'MTBS_INERTIAL', 'TRACK',
    'CALIBRATION_PROGRESS', 'CALIBRATION_RESULT', 'CALIBRATION_MANEUVERS', 'THERMAL_COMMAND',
    'CENTROIDS', 'centroid_topic',
    'TRUTH_DOCUMENT', 'MODEL_DOCUMENT', 'SCENARIO_DOCUMENT', 'PLAN_DOCUMENT', 'CASE_DOCUMENT',
    'STOP_DOCUMENT', 'SUBSYSTEM_STATUS', 'PARAMETER_EVENTS',
    'GRAPH_TOPICS', 'BAG_DOCUMENTS', 'GYRO_IMU_BLOCK', 'SAMPLE_BLOCKS',
]

#: 0.2 s: the servo and the sensors exchange once per tick (a 5 Hz position loop with a 2/s gain
#: settles a move in 2-3 s); the gyro box still samples at 400 Hz and cameras keep their own timing.
#: ``/clock`` advances one tick per message, so a bag's duration is its ``/clock`` count times this.
DEFAULT_TICK_NS = 200_000_000

#: Joint names in the plant's JointState messages: the coarse-drive elevation, the fine-drive angles.
CD_JOINT = 'cd_elevation'
FD_JOINTS = ('fd_el', 'fd_xel', 'fd_los')


@dataclass(frozen=True)
class TopicSpec:
    """A topic: its name, ROS type string, one-line meaning (for the table of docs/topics.md) and publishing node."""

    name: str
    msgtype: str
    meaning: str
    #: the node that publishes it; '' for documents the recorder or a campaign runner writes
    publisher: str = ''


CLOCK = TopicSpec('/clock', 'rosgraph_msgs/msg/Clock', 'simulated time, one message per tick', 'clock')

TRUTH_IMU = TopicSpec('/truth/imu', 'sensor_msgs/msg/Imu',
                      'true TARF attitude in IRF, mean inertial rate over the tick (TARF), specific force', 'plant')
TRUTH_JOINTS = TopicSpec('/truth/joints', 'sensor_msgs/msg/JointState',
                         'true coarse-drive elevation and fine-drive angles (rad)', 'plant')
TRUTH_TEMPERATURE = TopicSpec('/truth/temperature', 'sensor_msgs/msg/Temperature',
                              'telescope structure temperature (deg C)', 'plant')
JOINT_STATES = TopicSpec('/ta/joint_states', 'sensor_msgs/msg/JointState',
                         'housekeeping: CD encoder and FD spherical-sensor angles (rad)', 'plant')

GYRO_IMU = TopicSpec('/gyro_box/imu', 'sensor_msgs/msg/Imu',
                     'one 400 Hz sample: FOG rates (rad/s) and accelerations (m/s^2) in GYRF', 'gyro_box')
#: Over DDS, inside the graph, a tick's /gyro_box/imu samples travel as one message: a DDS message and
#: its Python callbacks per 400 Hz sample cost the live graph more than the simulation itself. The
#: recorder writes the samples, each as its own /gyro_box/imu record; the gyro box publishes them one by
#: one on /gyro_box/imu as well while a subscriber outside the graph listens there (ros2 topic echo,
#: ros2 bag record). Under /sim/ with the handshake: the graph's own transport, never in a bag.
GYRO_IMU_BLOCK = TopicSpec('/sim/blocks/gyro_box/imu', 'std_msgs/msg/UInt8MultiArray',
                           "one tick of /gyro_box/imu: each sample's sensor_msgs/Imu CDR, back to back", 'gyro_box')
GYRO_TEMPERATURE = TopicSpec('/gyro_box/temperature', 'sensor_msgs/msg/Temperature',
                             'gyro box temperature (deg C), once per tick', 'gyro_box')

TASCU_ATTITUDE = TopicSpec('/tascu/attitude', 'geometry_msgs/msg/QuaternionStamped',
                           'TASCU estimate of TARF in IRF (quaternion, scalar last), once per tick', 'tascu')
MOTION_STATUS = TopicSpec('/tascu/motion_status', 'diagnostic_msgs/msg/DiagnosticStatus',
                          'transient / settled / locked (1" RSS for 0.1 s) with the control deviation', 'tascu')
DRIFT_ESTIMATE = TopicSpec('/tascu/drift_estimate', 'geometry_msgs/msg/Vector3Stamped',
                           'tracker drift estimate subtracted from the gyro rates, TARF, rad/s', 'tascu')
COMMAND_STATUS = TopicSpec('/tascu/command_status', 'diagnostic_msgs/msg/DiagnosticStatus',
                           'accepted / done / refused (with the reason) per command, keyed by its stamp', 'tascu')
FD_COMMAND = TopicSpec('/tascu/fd_command', 'geometry_msgs/msg/Vector3Stamped',
                       'inertial body rate the fine drive is to hold over the next tick, TARF, rad/s', 'tascu')
CD_COMMAND = TopicSpec('/tascu/cd_command', 'sensor_msgs/msg/JointState',
                       'coarse-drive target elevation (cd_elevation, rad)', 'tascu')

MOVE_RELATIVE = TopicSpec('/tascu/move_relative', 'geometry_msgs/msg/Vector3Stamped',
                          'command: turn by (EL, XEL, LOS) rad about the TARF axes', 'calibration')
MTBS_CENTROID = TopicSpec('/tascu/mtbs_centroid', 'geometry_msgs/msg/PointStamped',
                          'command: move the star at (x, y) px of camera frame_id to its boresight', 'calibration')
MTBS_INERTIAL = TopicSpec('/tascu/mtbs_inertial', 'geometry_msgs/msg/QuaternionStamped',
                          'command: move TARF to this attitude in IRF (coarse drive for large EL)', 'calibration')
TRACK = TopicSpec('/tascu/track', 'geometry_msgs/msg/PointStamped',
                  'command: estimate drift on the star at (x, y) px of camera frame_id for z seconds', 'calibration')

CALIBRATION_PROGRESS = TopicSpec('/calibration/progress', 'diagnostic_msgs/msg/DiagnosticStatus',
                                 'calibration step, iteration and the latest fitted angles', 'calibration')
CALIBRATION_RESULT = TopicSpec('/calibration/result', 'std_msgs/msg/String',
                               'accepted alignment matrices and their accuracy, YAML', 'calibration')
CALIBRATION_MANEUVERS = TopicSpec(
    '/calibration/maneuvers', 'std_msgs/msg/String',
    'each fit: the maneuvers it used (axis, angle, centroids, active matrix, block), YAML', 'calibration')
#: A plan's temperature element (docs/plans.md): the setpoint of the truth's thermal control, which the plant and
#: the cameras follow from the command's stamp on (scenario.ThermalHistory).
THERMAL_COMMAND = TopicSpec(
    '/thermal_control/command', 'geometry_msgs/msg/Vector3Stamped',
    'command: slew the thermal setpoint to x deg C at y deg C/s from the stamp on, then hold it', 'calibration')


def centroid_topic(camera: str) -> TopicSpec:
    """TopicSpec of a camera's centroid stream."""
    return TopicSpec(f'/{camera}/centroids', 'geometry_msgs/msg/PoseArray',
                     f'{camera.upper()} centroids of every star on the chip: x, y px; z = HIP number', camera)


#: camera -> its centroid topic
CENTROIDS: Mapping[str, TopicSpec] = MappingProxyType({camera: centroid_topic(camera) for camera in CAMERAS})

# Documents: one message each, recorded transient-local (docs/bag.md).
TRUTH_DOCUMENT = TopicSpec('/config/truth', 'std_msgs/msg/String', 'the truth file the run simulated, YAML')
MODEL_DOCUMENT = TopicSpec('/config/model', 'std_msgs/msg/String', 'the model file given to the run, YAML')
#: where and when (start_utc) the campaign happened, as a logbook would record it (sofia_ros.scenario);
#: BagReader(campaign_time=True) counts time from its start
SCENARIO_DOCUMENT = TopicSpec('/config/scenario', 'std_msgs/msg/String',
                              'site, epoch, heading: the logbook `sofia compare` reads, YAML')
PLAN_DOCUMENT = TopicSpec('/config/plan', 'std_msgs/msg/String', "the campaign's plan, YAML")
CASE_DOCUMENT = TopicSpec('/config/case', 'std_msgs/msg/String',
                          'gyro-stability test case and its geometry, YAML')
STOP_DOCUMENT = TopicSpec('/result/stop', 'std_msgs/msg/String', 'why a live run stopped')
SUBSYSTEM_STATUS = TopicSpec('/ta/subsystem_status', 'diagnostic_msgs/msg/DiagnosticStatus',
                             'the Table 5.2 subsystem configuration of a gyro-stability case')
PARAMETER_EVENTS = TopicSpec('/parameter_events', 'rcl_interfaces/msg/ParameterEvent',
                             'every parameter the calibration node set on the TASCU and the imagers')

#: every topic a node of the graph publishes (the recorder records them all)
GRAPH_TOPICS: tuple[TopicSpec, ...] = (
    CLOCK, TRUTH_IMU, TRUTH_JOINTS, TRUTH_TEMPERATURE, JOINT_STATES, GYRO_IMU, GYRO_TEMPERATURE,
    *CENTROIDS.values(),
    TASCU_ATTITUDE, MOTION_STATUS, DRIFT_ESTIMATE, COMMAND_STATUS, FD_COMMAND, CD_COMMAND,
    MOVE_RELATIVE, MTBS_CENTROID, MTBS_INERTIAL, TRACK,
    CALIBRATION_PROGRESS, CALIBRATION_RESULT, CALIBRATION_MANEUVERS, THERMAL_COMMAND,
)
#: sample topic -> the topic its samples travel on inside the live graph, one message per tick
SAMPLE_BLOCKS: Mapping[str, TopicSpec] = MappingProxyType({GYRO_IMU.name: GYRO_IMU_BLOCK})
#: the one-shot documents a bag may hold beside the graph's topics
BAG_DOCUMENTS: tuple[TopicSpec, ...] = (TRUTH_DOCUMENT, MODEL_DOCUMENT, SCENARIO_DOCUMENT, PLAN_DOCUMENT,
                                        CASE_DOCUMENT, STOP_DOCUMENT, SUBSYSTEM_STATUS)
