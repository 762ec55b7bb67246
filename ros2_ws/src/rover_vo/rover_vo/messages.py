"""Reading the sensor messages the node and the offline CLI receive (rosbags' and rclpy's
message objects have the same field names, so one reader serves both).
"""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

TOPIC_LEFT = "/stereo/left/image_raw/compressed"
TOPIC_RIGHT = "/stereo/right/image_raw/compressed"
TOPIC_LEFT_INFO = "/stereo/left/camera_info"
TOPIC_RIGHT_INFO = "/stereo/right/camera_info"
TOPIC_IMU = "/imu/data"
INPUT_TOPICS = (TOPIC_LEFT, TOPIC_RIGHT, TOPIC_LEFT_INFO, TOPIC_RIGHT_INFO, TOPIC_IMU)


def stamp_s(msg: Any) -> float:
    """Header stamp in seconds (float64: microsecond resolution over decades)."""
    return msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec


def stamp_ns(msg: Any) -> int:
    """Header stamp in integer nanoseconds (exact: used to pair left and right)."""
    return int(msg.header.stamp.sec) * 1_000_000_000 + int(msg.header.stamp.nanosec)


def imu_sample(msg: Any) -> tuple[np.ndarray, np.ndarray]:
    """``(gyro rad/s, specific force m/s^2)`` of a sensor_msgs/Imu, in its frame."""
    w, a = msg.angular_velocity, msg.linear_acceleration
    return np.array([w.x, w.y, w.z], float), np.array([a.x, a.y, a.z], float)


def decode_image(msg: Any) -> np.ndarray | None:
    """8-bit grey image of a sensor_msgs/CompressedImage (JPEG or PNG), None if corrupt."""
    data = np.frombuffer(bytes(msg.data), np.uint8)
    if data.size == 0:
        return None
    # OpenCV prints libjpeg warnings for truncated data and may still return an image;
    # a truncated JPEG decodes to grey padding, caught by the exposure check downstream.
    img = cv2.imdecode(data, cv2.IMREAD_GRAYSCALE)
    return img
