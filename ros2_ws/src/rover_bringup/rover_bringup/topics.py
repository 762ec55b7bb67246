"""The topic contract of docs/architecture (DESIGN.md "Topics"): types and QoS per topic.

The player falls back to these QoS when a bag recorded none; the recorder subscribes to the
output topics with them.
"""

from __future__ import annotations

from dataclasses import dataclass

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

#: Topics a bag carries (inputs of the pipeline) plus /clock.
INPUT_TOPICS: dict[str, TopicContract] = {
    CLOCK_TOPIC: TopicContract('rosgraph_msgs/msg/Clock', DEFAULT_QOS),
    '/stereo/left/image_raw/compressed': TopicContract(
        'sensor_msgs/msg/CompressedImage', SENSOR_DATA_QOS
    ),
    '/stereo/right/image_raw/compressed': TopicContract(
        'sensor_msgs/msg/CompressedImage', SENSOR_DATA_QOS
    ),
    '/stereo/left/camera_info': TopicContract('sensor_msgs/msg/CameraInfo', SENSOR_DATA_QOS),
    '/stereo/right/camera_info': TopicContract('sensor_msgs/msg/CameraInfo', SENSOR_DATA_QOS),
    '/imu/data': TopicContract('sensor_msgs/msg/Imu', SENSOR_DATA_QOS),
    '/ground_truth/pose': TopicContract('geometry_msgs/msg/PoseStamped', DEFAULT_QOS),
}

#: Topics the pipeline publishes: everything ``globloc run`` records.
OUTPUT_TOPICS: dict[str, TopicContract] = {
    '/vo/odometry': TopicContract('nav_msgs/msg/Odometry', DEFAULT_QOS),
    '/rois/detections': TopicContract('sensor_msgs/msg/PointCloud2', DEFAULT_QOS),
    '/rois/tracks': TopicContract('sensor_msgs/msg/PointCloud2', DEFAULT_QOS),
    '/local_network': TopicContract('sensor_msgs/msg/PointCloud2', LATCHED_QOS),
    '/global_network': TopicContract('sensor_msgs/msg/PointCloud2', LATCHED_QOS),
    '/global_alignment': TopicContract('geometry_msgs/msg/TransformStamped', LATCHED_QOS),
    '/global_pose': TopicContract('geometry_msgs/msg/PoseWithCovarianceStamped', DEFAULT_QOS),
    '/matcher/status': TopicContract('diagnostic_msgs/msg/DiagnosticArray', DEFAULT_QOS),
}


def design_qos(topic: str) -> TopicQos:
    """QoS the design gives ``topic``; the ROS default profile for topics it does not list."""
    contract = INPUT_TOPICS.get(topic) or OUTPUT_TOPICS.get(topic)
    return contract.qos if contract else DEFAULT_QOS
