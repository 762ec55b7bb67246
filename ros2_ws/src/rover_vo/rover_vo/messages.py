"""Reading the sensor messages the node and the offline CLI receive (rosbags' and rclpy's
message objects have the same field names, so one reader serves both).
"""

from __future__ import annotations

from typing import Any

import numpy as np

from roi_network import images
from roi_network.images import IMAGE_TOPICS, side_of  # noqa: F401

# The contract's (compressed) image topics; the raw transport's are read as well
# (roi_network.images).
TOPIC_LEFT, TOPIC_RIGHT = images.STEREO_TOPICS[images.COMPRESSED]
TOPIC_LEFT_INFO = "/stereo/left/camera_info"
TOPIC_RIGHT_INFO = "/stereo/right/camera_info"
TOPIC_IMU = "/imu/data"
#: The mast's joint angles (read when rover.yaml has a mast: roi_network.mast).
TOPIC_JOINT_STATES = "/joint_states"
#: The sun sensor's unit sun vector (geometry_msgs/Vector3Stamped, its own frame; read when
#: rover.yaml has a sun sensor and a site: rover_vo.sun_heading).
TOPIC_SUN = "/sun_sensor"


def input_topics(transport: str = images.COMPRESSED) -> tuple[str, ...]:
    """The VO's input topics with the stereo images of ``transport``."""
    return (*images.STEREO_TOPICS[transport], TOPIC_LEFT_INFO, TOPIC_RIGHT_INFO, TOPIC_IMU)


INPUT_TOPICS = input_topics()


def stamp_s(msg: Any) -> float:
    """Header stamp in seconds (float64: microsecond resolution over decades)."""
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def seconds(t_ns: int) -> float:
    """A stamp in ns as :func:`stamp_s` gives it in seconds (the same float: stamps of two
    topics compare equal when their headers do)."""
    return t_ns // 1_000_000_000 + 1e-9 * (t_ns % 1_000_000_000)


def stamp_ns(msg: Any) -> int:
    """Header stamp in integer nanoseconds (exact: used to pair left and right)."""
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def imu_sample(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """``(gyro rad/s, specific force m/s^2)`` of a sensor_msgs/Imu, in its frame."""
    w, a = msg.angular_velocity, msg.linear_acceleration
    return np.array([w.x, w.y, w.z], float), np.array([a.x, a.y, a.z], float)


#: The sensor_msgs/Imu fields the estimator reads, in the order they are checked.
IMU_FIELDS = tuple(f"{part}.{axis}" for part in ("angular_velocity", "linear_acceleration")
                   for axis in "xyz")


def imu_problem(msg: Any) -> str | None:
    """The first field of a sensor_msgs/Imu the estimator reads that is not finite
    (``angular_velocity.y = nan``), None when all are. The orientation is not read."""
    for name in IMU_FIELDS:
        part, axis = name.split(".")
        value = float(getattr(getattr(msg, part), axis))
        if not np.isfinite(value):
            return f"{name} = {value}"
    return None


def joint_state(msg: Any) -> tuple[float, list[str], list[float]]:
    """``(stamp s, names, positions rad)`` of a sensor_msgs/JointState."""
    return stamp_s(msg), [str(n) for n in msg.name], [float(p) for p in msg.position]


def sun_vector(msg: Any) -> tuple[float, str, np.ndarray]:
    """``(stamp s, frame_id, vector)`` of a geometry_msgs/Vector3Stamped."""
    v = msg.vector
    return stamp_s(msg), str(msg.header.frame_id), np.array([v.x, v.y, v.z], float)


def decode_image(msg: Any) -> np.ndarray | None:
    """8-bit grey image of a sensor_msgs/CompressedImage or sensor_msgs/Image, None if it
    does not decode (:func:`roi_network.images.decode_image`)."""
    return images.decode_image(msg, colour=False)
