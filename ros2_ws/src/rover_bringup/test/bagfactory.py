"""Small synthetic bags for the tests, written with rosbags (Jazzy types, rosbag2 version 9).

Every message encodes its sequence number, so a receiver can check content and order:
IMU ``linear_acceleration.x``, pose ``position.x`` and the image pixels (the PNG is a
gradient shifted by the index; receivers compare its SHA-256).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

T0_NS = 1_700_000_000 * 1_000_000_000
IMU_TOPIC = '/imu/data'
IMAGE_TOPIC = '/stereo/left/image_raw/compressed'
POSE_TOPIC = '/ground_truth/pose'

_INF = QosTime(sec=9223372036, nsec=854775807)  # how Jazzy's rosbag2 records "infinite"
_ZERO = QosTime(sec=0, nsec=0)

#: What Jazzy's `ros2 bag record` stores for a sensor-data publisher: DDS does not propagate
#: history, so history is UNKNOWN and depth 0.
SENSOR_QOS_AS_RECORDED = Qos(
    history=QosHistory.UNKNOWN,
    depth=0,
    reliability=QosReliability.BEST_EFFORT,
    durability=QosDurability.VOLATILE,
    deadline=_INF,
    lifespan=_INF,
    liveliness=QosLiveliness.AUTOMATIC,
    liveliness_lease_duration=_INF,
    avoid_ros_namespace_conventions=False,
)
SENSOR_QOS = Qos(
    QosHistory.KEEP_LAST, 5, QosReliability.BEST_EFFORT, QosDurability.VOLATILE,
    _ZERO, _ZERO, QosLiveliness.AUTOMATIC, _ZERO, False,
)
RELIABLE_QOS = Qos(
    QosHistory.KEEP_LAST, 10, QosReliability.RELIABLE, QosDurability.VOLATILE,
    _ZERO, _ZERO, QosLiveliness.AUTOMATIC, _ZERO, False,
)


def image_bytes(index: int) -> bytes:
    """PNG (64x48 mono) number ``index``: a gradient shifted by the index."""
    xs = np.arange(64, dtype=np.uint16)[None, :] + np.arange(48, dtype=np.uint16)[:, None]
    img = ((xs * 3 + index * 7) % 256).astype(np.uint8)
    ok, png = cv2.imencode('.png', img)
    assert ok
    return png.tobytes()


def sha256(data: bytes) -> str:
    """Hex SHA-256 of ``data``."""
    return hashlib.sha256(data).hexdigest()


@dataclass
class BagSpec:
    """Content of a test bag.

    Attributes:
        imu_hz: IMU rate. images_hz: image rate. pose_hz: ground-truth rate.
        duration_s: Bag length.
        storage: 'mcap' or 'sqlite3'.
        record_qos: Store offered QoS profiles (False: none, like old bags).
    """

    imu_hz: float = 100.0
    images_hz: float = 10.0
    pose_hz: float = 10.0
    duration_s: float = 10.0
    storage: str = 'mcap'
    record_qos: bool = True
    expected: dict[str, list[dict]] = field(default_factory=dict)


def _stamps(hz: float, duration_s: float) -> list[int]:
    n = round(hz * duration_s)
    return [T0_NS + round(i * 1e9 / hz) for i in range(n)]


def write_bag(path: Path, spec: BagSpec | None = None) -> BagSpec:
    """Write a bag of IMU, images and ground-truth poses at ``path`` (a new directory).

    Returns:
        The spec, with ``expected`` filled: per topic, what a receiver must see, in order.
    """
    spec = spec or BagSpec()
    ts = get_typestore(Stores.ROS2_JAZZY)
    imu_t = ts.types['sensor_msgs/msg/Imu']
    img_t = ts.types['sensor_msgs/msg/CompressedImage']
    pose_t = ts.types['geometry_msgs/msg/PoseStamped']
    header = ts.types['std_msgs/msg/Header']
    time_t = ts.types['builtin_interfaces/msg/Time']
    vec = ts.types['geometry_msgs/msg/Vector3']
    quat = ts.types['geometry_msgs/msg/Quaternion']
    point = ts.types['geometry_msgs/msg/Point']
    pose = ts.types['geometry_msgs/msg/Pose']

    def hdr(stamp: int, frame: str) -> object:
        return header(time_t(sec=stamp // 10**9, nanosec=stamp % 10**9), frame)

    events: list[tuple[int, str, bytes]] = []
    expected: dict[str, list[dict]] = {IMU_TOPIC: [], IMAGE_TOPIC: [], POSE_TOPIC: []}
    for i, stamp in enumerate(_stamps(spec.imu_hz, spec.duration_s)):
        msg = imu_t(
            hdr(stamp, 'imu_link'), quat(0.0, 0.0, 0.0, 1.0), np.zeros(9),
            vec(0.0, 0.0, 0.01), np.zeros(9), vec(float(i), 0.0, 9.81), np.zeros(9),
        )
        events.append((stamp, IMU_TOPIC, ts.serialize_cdr(msg, imu_t.__msgtype__)))
        expected[IMU_TOPIC].append({'stamp': stamp, 'seq': i})
    for i, stamp in enumerate(_stamps(spec.images_hz, spec.duration_s)):
        data = image_bytes(i)
        msg = img_t(hdr(stamp, 'camera_left_optical'), 'png', np.frombuffer(data, np.uint8))
        events.append((stamp, IMAGE_TOPIC, ts.serialize_cdr(msg, img_t.__msgtype__)))
        expected[IMAGE_TOPIC].append({'stamp': stamp, 'format': 'png', 'sha256': sha256(data)})
    for i, stamp in enumerate(_stamps(spec.pose_hz, spec.duration_s)):
        msg = pose_t(hdr(stamp, 'map'), pose(point(float(i), 2.0, 0.0), quat(0.0, 0.0, 0.0, 1.0)))
        events.append((stamp, POSE_TOPIC, ts.serialize_cdr(msg, pose_t.__msgtype__)))
        expected[POSE_TOPIC].append({'stamp': stamp, 'seq': i})
    # Same stamp: keep a fixed topic order, as a recorder would have it.
    events.sort(key=lambda e: (e[0], e[1]))

    plugin = StoragePlugin.MCAP if spec.storage == 'mcap' else StoragePlugin.SQLITE3
    qos = {
        IMU_TOPIC: [SENSOR_QOS],
        IMAGE_TOPIC: [SENSOR_QOS_AS_RECORDED],
        POSE_TOPIC: [RELIABLE_QOS],
    }
    types = {IMU_TOPIC: imu_t.__msgtype__, IMAGE_TOPIC: img_t.__msgtype__,
             POSE_TOPIC: pose_t.__msgtype__}
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conns = {
            topic: writer.add_connection(
                topic, types[topic], typestore=ts,
                offered_qos_profiles=qos[topic] if spec.record_qos else (),
            )
            for topic in (IMU_TOPIC, IMAGE_TOPIC, POSE_TOPIC)
        }
        for stamp, topic, data in events:
            writer.write(conns[topic], stamp, data)
    spec.expected = expected
    return spec


BAR_MSG = 'int32 value\nstring name\n'


def write_custom_type_bag(path: Path, topics: Sequence[str] = ('/foo',),
                          imu_messages: int = 0) -> None:
    """A bag whose topics have type ``foo_msgs/msg/Bar``, unknown to this ROS install, and
    ``imu_messages`` IMU messages on /imu/data beside them (a field bag's mix)."""
    ts = get_typestore(Stores.ROS2_JAZZY)
    ts.register(get_types_from_msg(BAR_MSG, 'foo_msgs/msg/Bar'))
    bar = ts.types['foo_msgs/msg/Bar']
    imu_t = ts.types['sensor_msgs/msg/Imu']
    vec, quat = ts.types['geometry_msgs/msg/Vector3'], ts.types['geometry_msgs/msg/Quaternion']
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        for topic in topics:
            conn = writer.add_connection(topic, 'foo_msgs/msg/Bar', typestore=ts)
            writer.write(conn, T0_NS, ts.serialize_cdr(bar(1, 'x'), 'foo_msgs/msg/Bar'))
        if imu_messages:
            conn = writer.add_connection(IMU_TOPIC, imu_t.__msgtype__, typestore=ts)
            for i in range(imu_messages):
                stamp = T0_NS + i * 10_000_000
                msg = imu_t(ts.types['std_msgs/msg/Header'](
                    ts.types['builtin_interfaces/msg/Time'](sec=stamp // 10**9,
                                                             nanosec=stamp % 10**9),
                    'imu_link'), quat(0.0, 0.0, 0.0, 1.0), np.zeros(9), vec(0.0, 0.0, 0.0),
                    np.zeros(9), vec(0.0, 0.0, 9.81), np.zeros(9))
                writer.write(conn, stamp, ts.serialize_cdr(msg, imu_t.__msgtype__))
