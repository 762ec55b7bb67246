"""Test stand-in for pipeline nodes, started by ``globloc run`` from a test graph file.

Parameters (from the run's params file, under this node's name):
    mode: 'echo' (default) publishes, per IMU message received, an Odometry on /vo/odometry
        stamped like the IMU message, and every 10th IMU message a pose on /global_pose;
        at start-up it latches an empty /global_network (transient local).
        'crash': prints 30 numbered lines to stderr at the first IMU message, then exits 3.
        'crash_once': exits 3 at the first IMU message if the file ``marker`` does not
            exist (creating it), else 'echo': a node that is restarted once.
        'silent': publishes no output, only /vo/status every 10th IMU message (as a
            rover_vo that reads no pair: ``pairs 0``, ``bad_input.camera_info`` counting).
        'no_fix': publishes only /matcher/status, every 10th IMU message (as a matcher
            that never localizes: ``reason too_few_nodes``).
    marker: the file of 'crash_once'.
    bag_dir: a string parameter; echoed in the log to check $BAG_DIR substitution.
    camera_height: a float parameter; echoed in the log to check that rover.yaml is passed.
"""

from __future__ import annotations

import sys
from pathlib import Path

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseWithCovarianceStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, PointCloud2

from roi_network.spin import spin_until_shutdown

CRASH_STATUS = 3


class FakePipeline(Node):
    """Echoes IMU input as pipeline outputs (or crashes on purpose)."""

    def __init__(self) -> None:
        super().__init__('fake_pipeline')
        self.mode = self.declare_parameter('mode', 'echo').value
        marker = self.declare_parameter('marker', '').value
        if self.mode == 'crash_once':
            self.mode = 'echo' if Path(marker).exists() else 'crash'
            Path(marker).touch()
        bag_dir = self.declare_parameter('bag_dir', '').value
        height = self.declare_parameter('camera_height', 0.0).value
        self.get_logger().info(f'mode={self.mode} bag_dir={bag_dir} camera_height={height}')
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.odom_pub = self.create_publisher(Odometry, '/vo/odometry', reliable)
        self.pose_pub = self.create_publisher(PoseWithCovarianceStamped, '/global_pose', reliable)
        self.status_pubs = {t: self.create_publisher(DiagnosticArray, t, reliable)
                            for t in ('/vo/status', '/matcher/status')}
        gn_pub = self.create_publisher(PointCloud2, '/global_network', latched)
        cloud = PointCloud2()
        cloud.header.frame_id = 'map'
        gn_pub.publish(cloud)
        self._gn_pub = gn_pub  # keep it alive: transient local needs the writer
        self.count = 0
        self.create_subscription(
            Imu, '/imu/data', self.on_imu,
            QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT),
        )

    def on_imu(self, msg: Imu) -> None:
        """Publish outputs derived from one IMU message."""
        if self.mode == 'crash':
            for i in range(30):
                print(f'fake failure detail line {i}', file=sys.stderr)
            sys.stderr.flush()
            raise SystemExit(CRASH_STATUS)
        self.count += 1
        if self.mode == 'silent':
            if self.count % 10 == 1:
                self.status('/vo/status', msg, 'imu_propagation: 0 inliers',
                            pairs=0, imu_samples=self.count,
                            **{'bad_input.camera_info': self.count // 10 + 1,
                               'bad_input.imu': 0})
            return
        if self.mode == 'no_fix':
            if self.count % 10 == 1:
                self.status('/matcher/status', msg, 'not localized: none (too_few_nodes)',
                            state='searching', event='none', reason='too_few_nodes',
                            ln_size=3, votes=0)
            return
        odom = Odometry()
        odom.header.stamp = msg.header.stamp
        odom.header.frame_id = 'odom'
        odom.child_frame_id = 'base_link'
        odom.pose.pose.position.x = msg.linear_acceleration.x
        self.odom_pub.publish(odom)
        if self.count % 10 == 1:
            pose = PoseWithCovarianceStamped()
            pose.header = odom.header
            pose.header.frame_id = 'map'
            pose.pose.pose.position.x = msg.linear_acceleration.x
            self.pose_pub.publish(pose)

    def status(self, topic: str, msg: Imu, text: str, **values) -> None:
        """Publish one DiagnosticArray on ``topic``, stamped like ``msg``."""
        status = DiagnosticStatus(name=self.get_name(), message=text)
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        out = DiagnosticArray(status=[status])
        out.header.stamp = msg.header.stamp
        self.status_pubs[topic].publish(out)


def main() -> int:
    """Spin until SIGTERM."""
    rclpy.init()
    try:
        spin_until_shutdown(FakePipeline())
    except KeyboardInterrupt:
        pass
    finally:
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
