"""The rover_vo node: stereo + IMU visual odometry on the live topics.

Thin ROS wrapper around :class:`~rover_vo.estimator.VoEstimator` (the offline CLI runs the
same estimator on the same messages). Subscribes the stereo images, camera infos, IMU,
``/sun_sensor`` and, when rover.yaml has a mast, ``/joint_states`` (sensor-data QoS);
publishes ``/vo/odometry`` (nav_msgs/Odometry, odom -> base_link, pose covariance growing
with the distance driven, its yaw bounded by the sun sensor when there is one, body twist)
at each stereo pair and ``/vo/status`` (diagnostics). Extrinsics, the mast's kinematics,
the sun sensor and the site come from the bag's rover.yaml parameters.
"""

from __future__ import annotations

import logging
import sys
from typing import Any

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import Vector3Stamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import HistoryPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import CameraInfo, Imu, JointState

from roi_network.images import TRANSPORT_PARAMETER_HELP, TransportLock
from roi_network.mast import MAST_PARAMS
from roi_network.spin import run_node
from rover_vo import messages as m
from rover_vo.config import (
    NODE_NAME,
    ROVER_PARAMETERS,
    VoConfig,
    config_from_flat,
    flat_parameters,
    unknown_options,
)
from rover_vo.estimator import VoEstimator, VoOutput
from rover_vo.restart import resume_from_file, save_state
from rover_vo.sun_heading import SENSOR_PARAMS, SITE_PARAMS

RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)


def sensor_qos(depth: int) -> QoSProfile:
    """Sensor-data QoS (best effort, volatile) with a deeper queue than the default 5."""
    qos = QoSProfile(**{k: getattr(qos_profile_sensor_data, k)
                        for k in ("reliability", "durability")}, depth=depth)
    qos.history = HistoryPolicy.KEEP_LAST
    return qos


def odometry_message(out: VoOutput, odom_frame: str, base_frame: str) -> Odometry:
    """nav_msgs/Odometry of one output: pose and covariance in odom, twist in base_link."""
    msg = Odometry()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(out.stamp_ns, 1_000_000_000)
    msg.header.frame_id, msg.child_frame_id = odom_frame, base_frame
    p, o = msg.pose.pose.position, msg.pose.pose.orientation
    p.x, p.y, p.z = (float(v) for v in out.state.p)
    o.x, o.y, o.z, o.w = (float(v) for v in Rotation.from_matrix(out.state.R).as_quat())
    msg.pose.covariance = [float(v) for v in out.state.ros_covariance().ravel()]
    tw = msg.twist.twist
    tw.linear.x, tw.linear.y, tw.linear.z = (float(v) for v in out.linear)
    tw.angular.x, tw.angular.y, tw.angular.z = (float(v) for v in out.angular)
    # Twist covariance: a coarse diagonal (the twist is a by-product, not fused downstream).
    msg.twist.covariance = [float(v) for v in np.diag([0.01] * 3 + [1e-4] * 3).ravel()]
    return msg


class VoNode(Node):
    """Subscribes the stereo pair, camera infos and IMU; publishes /vo/odometry, /vo/status."""

    def __init__(self, **node_kwargs: Any) -> None:
        """``node_kwargs`` go to ``rclpy.node.Node`` (e.g. ``context``)."""
        super().__init__(NODE_NAME, **node_kwargs)
        # An option a params file sets that the node does not have (a typo, an option that
        # does not exist) is an error, not ignored; rclpy keeps the params files' values
        # for this node in _parameter_overrides.
        overrides = getattr(self, "_parameter_overrides", {})
        if unknown := unknown_options(overrides):
            raise ValueError(f"unknown parameter '{unknown[0]}'")
        defaults = flat_parameters(VoConfig())
        values = {}
        for name, default in defaults.items():
            values[name] = self.declare_parameter(
                name, default, ParameterDescriptor(description=f"{name} (docs/rover_vo.md)")
            ).value
        rover = {}
        # rover.yaml keys the estimator reads (declared so the params file reaches it).
        for name, default in ROVER_PARAMETERS.items():
            rover[name] = self.declare_parameter(
                name, default, ParameterDescriptor(description=f"rover.yaml: {name}")).value
        # The mast's kinematics, the sun sensor and the site, as rover.yaml gives them
        # (none: a fixed camera, no sun sensor; a missing field of a mast or a sun sensor
        # is an error naming it, not a default).
        for name in (*MAST_PARAMS, *SENSOR_PARAMS, *SITE_PARAMS):
            if name in overrides:
                rover[name] = self.declare_parameter(
                    name, overrides[name].value,
                    ParameterDescriptor(description=f"rover.yaml: {name}")).value
        self.odom_frame = self.declare_parameter(
            "odom_frame", "odom", ParameterDescriptor(description="odometry frame")).value
        self.base_frame = self.declare_parameter(
            "base_frame", "base_link", ParameterDescriptor(description="body frame")).value
        transport = self.declare_parameter(
            "image_transport", "auto",
            ParameterDescriptor(description=TRANSPORT_PARAMETER_HELP)).value
        self.transports = TransportLock(str(transport), self.get_logger().warning)
        if not any(rover["base_to_left_camera"][3:]):
            raise ValueError("parameter 'base_to_left_camera' is not set (pass the bag's "
                             "rover.yaml with --params-file)")
        config = config_from_flat(values)
        logger = self.get_logger()

        def log(level: int, text: str) -> None:
            # One call site per severity: rclpy refuses a call site whose severity changes
            # ("Logger severity cannot be changed between calls"), and the node died.
            if level >= logging.ERROR:
                logger.error(text)
            elif level >= logging.WARNING:
                logger.warning(text)
            else:
                logger.info(text)

        self.estimator = VoEstimator(config, rover, log)
        self.state_path = self.declare_parameter(
            "state_path", "", ParameterDescriptor(
                description="file the estimator's state is saved to after every pose and "
                            "resumed from on restart (JSON); '' keeps it in memory only")).value
        if self.state_path and resume_from_file(self.estimator, self.state_path, logger.error):
            logger.warning(f"resuming the odom frame saved in {self.state_path}")
        self._save_failed = False
        self._pairs_said = 0  # the estimator's pair count at the last /vo/status
        self.odom_pub = self.create_publisher(Odometry, "/vo/odometry", RELIABLE)
        self.status_pub = self.create_publisher(DiagnosticArray, "/vo/status", RELIABLE)
        # The IMU first: a stereo pair's callback takes every IMU message already queued
        # before it feeds the pair (drain_imu).
        self.imu_sub = self.create_subscription(Imu, m.TOPIC_IMU, self.on_imu, sensor_qos(2000))
        self.transports.subscribe(self, self.on_image, sensor_qos(10))
        for topic in (m.TOPIC_LEFT_INFO, m.TOPIC_RIGHT_INFO):
            self.create_subscription(CameraInfo, topic,
                                     lambda msg, t=topic: self.on_message(t, msg), sensor_qos(10))
        # The sun sensor: always subscribed, so that samples of a sensor rover.yaml lacks
        # are named (bad_input.sun_no_mount).
        self.sun_sub = self.create_subscription(Vector3Stamped, m.TOPIC_SUN, self.on_sun,
                                                sensor_qos(100))
        waiting = m.TOPIC_IMU
        self.joint_sub = None
        if self.estimator.has_mast:
            self.joint_sub = self.create_subscription(
                JointState, m.TOPIC_JOINT_STATES, self.on_joint_state, sensor_qos(200))
            waiting += f" and {m.TOPIC_JOINT_STATES} (mast {', '.join(self.estimator.mast.joints)})"
        logger.info(f"mode {config.mode}; waiting for stereo images "
                    f"({' or '.join(self.transports.subscribed())}) and {waiting}")

    def on_sun(self, msg: Any) -> None:
        """One sun sample, then every other one already queued."""
        self.on_message(m.TOPIC_SUN, msg)
        self.drain(self.sun_sub, m.TOPIC_SUN)

    def on_imu(self, msg: Any) -> None:
        """One IMU message, after the joint states and sun samples queued, then every
        other IMU message already queued (:meth:`drain_imu`)."""
        self.drain(self.joint_sub, m.TOPIC_JOINT_STATES)
        self.drain(self.sun_sub, m.TOPIC_SUN)
        self.on_message(m.TOPIC_IMU, msg)
        self.drain_imu()

    def on_joint_state(self, msg: Any) -> None:
        """One joint state, then every other one already queued."""
        self.on_message(m.TOPIC_JOINT_STATES, msg)
        self.drain(self.joint_sub, m.TOPIC_JOINT_STATES)

    def on_image(self, topic: str, msg: Any) -> None:
        """A stereo image, after the joint states, sun samples and IMU messages queued
        before it (:meth:`drain_imu`): the pair takes the sun sample of its stamp."""
        self.drain(self.joint_sub, m.TOPIC_JOINT_STATES)
        self.drain(self.sun_sub, m.TOPIC_SUN)
        self.drain_imu()
        self.on_message(topic, msg)

    def drain_imu(self, limit: int = 4000) -> int:
        """Feed every IMU message waiting in the subscription's queue; returns how many.

        rclpy's executor takes one message per subscription per wait, and a wait costs
        about a millisecond of Python: at 250 IMU messages/s (a 50 Hz IMU replayed at 5x)
        on a loaded machine a node taking one at a time falls behind its IMU, the queue
        overflows, and stereo pairs are processed with seconds of gyro missing
        (``imu_gap``), which loses sharp turns. Taking the queue in one callback keeps up,
        and a pair fed after its IMU is not released before the gyro arrives.
        """
        return self.drain(self.imu_sub, m.TOPIC_IMU, limit)

    def drain(self, sub: Any, topic: str, limit: int = 4000) -> int:
        """Feed every message waiting in ``sub``'s queue as ``topic``; returns how many.
        Joint states are taken before the IMU: the IMU's stamps running ahead of joint
        states still queued would end a pair's wait for them (:mod:`rover_vo.arrivals`)."""
        n = 0
        while sub is not None and n < limit:
            with sub.handle:
                taken = sub.handle.take_message(sub.msg_type, sub.raw)
            if taken is None:
                break
            self.on_message(topic, taken[0])
            n += 1
        return n

    def on_message(self, topic: str, msg: Any) -> None:
        """Feed the estimator; publish what it completes. A failure never kills the node."""
        try:
            outputs = self.estimator.feed(topic, msg)
        except Exception as exc:  # a bug on one message must not stop the odometry
            self.estimator.bad("internal_error", f"{topic}: {type(exc).__name__}: {exc}")
            return
        for out in outputs:
            self.odom_pub.publish(odometry_message(out, self.odom_frame, self.base_frame))
            self.publish_status(out)
        if outputs and self.state_path:
            self.save_state()
        pairs = self.estimator.counts.pairs
        if pairs != self._pairs_said and not outputs and self.estimator.state is None:
            # A pair was read and gave no pose (no usable CameraInfo, images...): say why.
            self.publish_status(None)
        self._pairs_said = pairs

    def save_state(self) -> None:
        """Write the estimator's snapshot to ``state_path`` (what a restart resumes)."""
        try:
            save_state(self.state_path, self.estimator.snapshot())
        except OSError as exc:
            if not self._save_failed:
                self.get_logger().error(f"cannot write {self.state_path}: {exc.strerror}: a "
                                        "restart will start a new odom frame")
            self._save_failed = True

    def publish_status(self, out: VoOutput | None) -> None:
        """/vo/status: features, stereo matches, inliers, state and bad-input counts; with
        no ``out`` (a pair gave no pose, and none has come yet), level ERROR and why."""
        values = self.estimator.status()
        status = DiagnosticStatus()
        status.name = "rover_vo"
        status.hardware_id = "stereo_imu"
        msg = DiagnosticArray()
        if out is None:
            status.level = DiagnosticStatus.ERROR
            status.message = f"no pose yet: {self.estimator.last_bad or 'no usable pair'}"
            stamp_ns = self.estimator.last_pair_ns or 0
        else:
            status.level = (DiagnosticStatus.OK if out.source in ("vision", "zero_velocity",
                                                                  "initial", "resumed")
                            else DiagnosticStatus.WARN)
            status.message = f"{out.source}: {values['inliers']} inliers"
            stamp_ns = out.stamp_ns
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 1_000_000_000)
        msg.status = [status]
        self.status_pub.publish(msg)


def main(args: list[str] | None = None) -> int:
    """Run the node until shutdown; a missing or bad parameter exits with status 1."""
    import faulthandler

    import cv2

    # One OpenCV thread: the graph shares few cores between its nodes, and OpenCV's worker
    # pool is one more set of threads to tear down at exit.
    cv2.setNumThreads(1)
    faulthandler.enable()  # a crash in native code leaves a Python stack in the log
    return run_node(VoNode, "rover_vo", args)

if __name__ == "__main__":
    sys.exit(main())
