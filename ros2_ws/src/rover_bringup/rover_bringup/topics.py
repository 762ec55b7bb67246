"""The topic contract of docs/architecture (DESIGN.md "Topics"): types and QoS per topic.

The player falls back to these QoS when a bag recorded none; the recorder subscribes to the
output topics with them.
"""

from __future__ import annotations

from dataclasses import dataclass

from roi_network import images
from rover_bringup.qos import DEFAULT_QOS, LATCHED_QOS, SENSOR_DATA_QOS, TopicQos


@dataclass(frozen=True)
class TopicContract:
    """One row of the design's topic table.

    Attributes:
        msgtype: ROS 2 message type, ``pkg/msg/Type``.
        qos: QoS the publisher offers.
    """

    msgtype: str
    qos: TopicQos


CLOCK_TOPIC = '/clock'

#: Topics a bag carries (inputs of the pipeline) plus /clock. The stereo images come in
#: either transport: the contract's CompressedImage, or the raw Image a field bag may carry
#: instead (roi_network.images).
INPUT_TOPICS: dict[str, TopicContract] = {
    CLOCK_TOPIC: TopicContract('rosgraph_msgs/msg/Clock', DEFAULT_QOS),
    **{topic: TopicContract(images.MSGTYPES[transport], SENSOR_DATA_QOS)
       for transport, pair in images.STEREO_TOPICS.items() for topic in pair},
    '/stereo/left/camera_info': TopicContract('sensor_msgs/msg/CameraInfo', SENSOR_DATA_QOS),
    '/stereo/right/camera_info': TopicContract('sensor_msgs/msg/CameraInfo', SENSOR_DATA_QOS),
    '/imu/data': TopicContract('sensor_msgs/msg/Imu', SENSOR_DATA_QOS),
    '/joint_states': TopicContract('sensor_msgs/msg/JointState', SENSOR_DATA_QOS),
    '/sun_sensor': TopicContract('geometry_msgs/msg/Vector3Stamped', SENSOR_DATA_QOS),
    '/ground_truth/pose': TopicContract('geometry_msgs/msg/PoseStamped', DEFAULT_QOS),
}

#: Topics the pipeline publishes: everything ``globloc run`` records (the nodes' status
#: topics too: the run's verdict reads their counts).
OUTPUT_TOPICS: dict[str, TopicContract] = {
    '/vo/odometry': TopicContract('nav_msgs/msg/Odometry', DEFAULT_QOS),
    '/vo/status': TopicContract('diagnostic_msgs/msg/DiagnosticArray', DEFAULT_QOS),
    '/rois/status': TopicContract('diagnostic_msgs/msg/DiagnosticArray', DEFAULT_QOS),
    '/rois/detections': TopicContract('sensor_msgs/msg/PointCloud2', DEFAULT_QOS),
    '/rois/tracks': TopicContract('sensor_msgs/msg/PointCloud2', DEFAULT_QOS),
    '/local_network': TopicContract('sensor_msgs/msg/PointCloud2', LATCHED_QOS),
    '/global_network': TopicContract('sensor_msgs/msg/PointCloud2', LATCHED_QOS),
    '/global_alignment': TopicContract('geometry_msgs/msg/TransformStamped', LATCHED_QOS),
    '/global_pose': TopicContract('geometry_msgs/msg/PoseWithCovarianceStamped', DEFAULT_QOS),
    '/matcher/status': TopicContract('diagnostic_msgs/msg/DiagnosticArray', DEFAULT_QOS),
}


#: The static transforms of a field bag, whose sensor frames ``globloc rover-yaml`` reads.
TF_STATIC = '/tf_static'

#: The sensor topics the pipeline needs besides the stereo images.
SENSOR_TOPICS = ('/stereo/left/camera_info', '/stereo/right/camera_info', '/imu/data')


def sensor_problems(topics: dict[str, str], source: str) -> list[str]:
    """What keeps the pipeline from reading a bag's sensors, one line per problem.

    Args:
        topics: the bag's topics, name -> message type.
        source: the bag, named in each line.

    Returns:
        Empty when the bag carries a stereo pair (either transport), both CameraInfo topics
        and the IMU, with the contract's types.
    """
    problems = []
    try:
        images.bag_transport(topics, source)
    except ValueError as exc:
        problems.append(str(exc))
    for topic in SENSOR_TOPICS:
        wanted = INPUT_TOPICS[topic].msgtype
        if topic not in topics:
            problems.append(f'{source}: no {topic} ({wanted}): the pipeline needs it')
        elif topics[topic] != wanted:
            problems.append(f'{source}: {topic} is {topics[topic]}, the pipeline reads '
                            f'{wanted}')
    return problems


def design_qos(topic: str) -> TopicQos:
    """QoS the design gives ``topic``; the ROS default profile for topics it does not list."""
    contract = INPUT_TOPICS.get(topic) or OUTPUT_TOPICS.get(topic)
    return contract.qos if contract else DEFAULT_QOS
