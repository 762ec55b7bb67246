"""rosbag2 writer (MCAP storage, Jazzy message types) for the simulated sensors.

Topics, types, frames and QoS follow DESIGN.md. Each connection records its offered QoS
(sensor data: best effort / volatile / keep last 5; ground truth: reliable / keep last 10;
``/tf_static`` and ``/robot_description``: reliable / transient local / keep last 1, as
robot_state_publisher latches them), so a player can re-offer the same profiles. Header
stamps equal bag time, POSIX UTC (the bag starts at the epoch of :mod:`atacama_sim.sky`);
the site and epoch go into the metadata's ``custom_data`` (:meth:`BagWriter.set_site`).
"""

from __future__ import annotations

from pathlib import Path

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
from rosbags.typesys import Stores, get_typestore

from atacama_sim.camera import StereoRig
from atacama_sim.robot import FRAME_IMU, FRAME_LEFT, FRAME_RIGHT, FRAME_SUN_SENSOR

FRAME_MAP = "map"

T_LEFT_IMG = "/stereo/left/image_raw/compressed"
T_RIGHT_IMG = "/stereo/right/image_raw/compressed"
T_LEFT_INFO = "/stereo/left/camera_info"
T_RIGHT_INFO = "/stereo/right/camera_info"
T_IMU = "/imu/data"
T_GT = "/ground_truth/pose"
T_JOINTS = "/joint_states"
T_TF_STATIC = "/tf_static"
T_ROBOT = "/robot_description"
T_SUN = "/sun_sensor"
#: Prefix of the site's keys in the rosbag2 metadata's ``custom_data``.
CUSTOM_DATA_PREFIX = "site."

_ZERO = QosTime(0, 0)
_INF = QosTime(2147483647, 4294967295)  # rmw "infinite" duration as rosbag2 stores it


def _qos(reliable: bool, depth: int, latched: bool = False) -> Qos:
    return Qos(QosHistory.KEEP_LAST, depth,
               QosReliability.RELIABLE if reliable else QosReliability.BEST_EFFORT,
               QosDurability.TRANSIENT_LOCAL if latched else QosDurability.VOLATILE,
               _INF, _INF, QosLiveliness.AUTOMATIC, _INF, False)


SENSOR_QOS = _qos(reliable=False, depth=5)
RELIABLE_QOS = _qos(reliable=True, depth=10)
LATCHED_QOS = _qos(reliable=True, depth=1, latched=True)


class BagWriter:
    """Streams messages into ``path`` (a rosbag2 directory); use as a context manager."""

    def __init__(self, path: Path, start_ns: int) -> None:
        self.ts = get_typestore(Stores.ROS2_JAZZY)
        self.start_ns = start_ns
        self.writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        self.conn: dict[str, object] = {}
        self.counts: dict[str, int] = {}

    def __enter__(self) -> BagWriter:
        self.writer.open()
        ts = self.ts
        for topic, msgtype, qos in (
                (T_LEFT_IMG, "sensor_msgs/msg/CompressedImage", SENSOR_QOS),
                (T_RIGHT_IMG, "sensor_msgs/msg/CompressedImage", SENSOR_QOS),
                (T_LEFT_INFO, "sensor_msgs/msg/CameraInfo", SENSOR_QOS),
                (T_RIGHT_INFO, "sensor_msgs/msg/CameraInfo", SENSOR_QOS),
                (T_IMU, "sensor_msgs/msg/Imu", SENSOR_QOS),
                (T_GT, "geometry_msgs/msg/PoseStamped", RELIABLE_QOS),
                (T_JOINTS, "sensor_msgs/msg/JointState", SENSOR_QOS),
                (T_SUN, "geometry_msgs/msg/Vector3Stamped", SENSOR_QOS),
                (T_TF_STATIC, "tf2_msgs/msg/TFMessage", LATCHED_QOS),
                (T_ROBOT, "std_msgs/msg/String", LATCHED_QOS)):
            self.conn[topic] = self.writer.add_connection(
                topic, msgtype, typestore=ts, offered_qos_profiles=[qos])
            self.counts[topic] = 0
        return self

    def __exit__(self, *exc: object) -> None:
        self.writer.close()

    def set_site(self, site: dict[str, object]) -> None:
        """Record the site and epoch (:meth:`atacama_sim.sky.Sky.metadata`) in the
        metadata's ``custom_data``, each as ``site.<key>``: its text."""
        for key, value in site.items():
            self.writer.set_custom_data(f"{CUSTOM_DATA_PREFIX}{key}", str(value))

    # -- message builders ---------------------------------------------------------------
    def _header(self, t_ns: int, frame: str):
        ts = self.ts
        stamp = ts.types["builtin_interfaces/msg/Time"](sec=t_ns // 1_000_000_000,
                                                        nanosec=t_ns % 1_000_000_000)
        return ts.types["std_msgs/msg/Header"](stamp=stamp, frame_id=frame)

    def _write(self, topic: str, msgtype: str, msg: object, t_ns: int) -> None:
        self.writer.write(self.conn[topic], t_ns, self.ts.serialize_cdr(msg, msgtype))
        self.counts[topic] += 1

    def stamp(self, t: float) -> int:
        return self.start_ns + round(t * 1e9)

    def camera_info(self, rig: StereoRig, right: bool, t_ns: int):
        """Rectified CameraInfo; right P[3] = -fx * baseline (DESIGN.md)."""
        ts = self.ts
        k = np.array([rig.fx, 0, rig.cx, 0, rig.fy, rig.cy, 0, 0, 1], np.float64)
        tx = -rig.fx * rig.baseline if right else 0.0
        p = np.array([rig.fx, 0, rig.cx, tx, 0, rig.fy, rig.cy, 0, 0, 0, 1, 0], np.float64)
        roi = ts.types["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0,
                                                           width=0, do_rectify=False)
        return ts.types["sensor_msgs/msg/CameraInfo"](
            header=self._header(t_ns, FRAME_RIGHT if right else FRAME_LEFT),
            height=rig.height, width=rig.width, distortion_model="plumb_bob",
            d=np.zeros(5), k=k, r=np.eye(3).ravel(), p=p, binning_x=0, binning_y=0, roi=roi)

    def write_stereo(self, t: float, rig: StereoRig, jpeg_left: bytes,
                     jpeg_right: bytes) -> None:
        t_ns = self.stamp(t)
        ts = self.ts
        for topic, info_topic, data, right in ((T_LEFT_IMG, T_LEFT_INFO, jpeg_left, False),
                                               (T_RIGHT_IMG, T_RIGHT_INFO, jpeg_right, True)):
            msg = ts.types["sensor_msgs/msg/CompressedImage"](
                header=self._header(t_ns, FRAME_RIGHT if right else FRAME_LEFT),
                format="rgb8; jpeg compressed bgr8",
                data=np.frombuffer(data, np.uint8))
            self._write(topic, "sensor_msgs/msg/CompressedImage", msg, t_ns)
            self._write(info_topic, "sensor_msgs/msg/CameraInfo",
                        self.camera_info(rig, right, t_ns), t_ns)

    def write_imu(self, t: float, gyro: np.ndarray, accel: np.ndarray, gyro_sigma: float,
                  accel_sigma: float) -> None:
        t_ns = self.stamp(t)
        ts = self.ts
        v3 = ts.types["geometry_msgs/msg/Vector3"]
        msg = ts.types["sensor_msgs/msg/Imu"](
            header=self._header(t_ns, FRAME_IMU),
            orientation=ts.types["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            orientation_covariance=np.array([-1.0, 0, 0, 0, 0, 0, 0, 0, 0]),  # not provided
            angular_velocity=v3(x=float(gyro[0]), y=float(gyro[1]), z=float(gyro[2])),
            angular_velocity_covariance=np.diag([gyro_sigma ** 2] * 3).ravel(),
            linear_acceleration=v3(x=float(accel[0]), y=float(accel[1]), z=float(accel[2])),
            linear_acceleration_covariance=np.diag([accel_sigma ** 2] * 3).ravel())
        self._write(T_IMU, "sensor_msgs/msg/Imu", msg, t_ns)

    def write_sun_sensor(self, t: float, v: np.ndarray) -> None:
        """One ``/sun_sensor`` sample: the unit sun vector in the sensor frame."""
        t_ns = self.stamp(t)
        ts = self.ts
        msg = ts.types["geometry_msgs/msg/Vector3Stamped"](
            header=self._header(t_ns, FRAME_SUN_SENSOR),
            vector=ts.types["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]),
                                                         z=float(v[2])))
        self._write(T_SUN, "geometry_msgs/msg/Vector3Stamped", msg, t_ns)

    def write_pose(self, t: float, p: np.ndarray, q: np.ndarray) -> None:
        t_ns = self.stamp(t)
        ts = self.ts
        pose = ts.types["geometry_msgs/msg/Pose"](
            position=ts.types["geometry_msgs/msg/Point"](x=float(p[0]), y=float(p[1]),
                                                         z=float(p[2])),
            orientation=ts.types["geometry_msgs/msg/Quaternion"](
                x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])))
        msg = ts.types["geometry_msgs/msg/PoseStamped"](header=self._header(t_ns, FRAME_MAP),
                                                        pose=pose)
        self._write(T_GT, "geometry_msgs/msg/PoseStamped", msg, t_ns)

    def write_joint_state(self, t: float, names: tuple[str, ...], position: np.ndarray,
                          velocity: np.ndarray) -> None:
        """One ``/joint_states`` sample (rad, rad/s; frame '', no effort)."""
        t_ns = self.stamp(t)
        msg = self.ts.types["sensor_msgs/msg/JointState"](
            header=self._header(t_ns, ""), name=list(names),
            position=np.asarray(position, np.float64), velocity=np.asarray(velocity, np.float64),
            effort=np.zeros(0, np.float64))
        self._write(T_JOINTS, "sensor_msgs/msg/JointState", msg, t_ns)

    def write_tf_static(self, t: float, transforms: list[tuple[str, str, np.ndarray]]) -> None:
        """Every fixed joint in one ``/tf_static`` message: ``(parent, child, 4x4)``."""
        from scipy.spatial.transform import Rotation

        t_ns = self.stamp(t)
        ts = self.ts
        out = []
        for parent, child, m in transforms:
            q = Rotation.from_matrix(np.asarray(m)[:3, :3]).as_quat()
            tr = ts.types["geometry_msgs/msg/Transform"](
                translation=ts.types["geometry_msgs/msg/Vector3"](
                    x=float(m[0, 3]), y=float(m[1, 3]), z=float(m[2, 3])),
                rotation=ts.types["geometry_msgs/msg/Quaternion"](
                    x=float(q[0]), y=float(q[1]), z=float(q[2]), w=float(q[3])))
            out.append(ts.types["geometry_msgs/msg/TransformStamped"](
                header=self._header(t_ns, parent), child_frame_id=child, transform=tr))
        self._write(T_TF_STATIC, "tf2_msgs/msg/TFMessage",
                    ts.types["tf2_msgs/msg/TFMessage"](transforms=out), t_ns)

    def write_robot_description(self, t: float, text: str) -> None:
        """The URDF, once (``/robot_description``, std_msgs/String)."""
        self._write(T_ROBOT, "std_msgs/msg/String",
                    self.ts.types["std_msgs/msg/String"](data=text), self.stamp(t))
