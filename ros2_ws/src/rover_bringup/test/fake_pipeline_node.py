"""Test stand-in for pipeline nodes, started by ``globloc run`` from a test graph file.

Parameters (from the run's params file, under this node's name):
    mode: 'echo' (default) publishes, per IMU message received, an Odometry on /vo/odometry
        stamped like the IMU message, and every 10th IMU message a pose on /global_pose;
        at start-up it latches an empty /global_network (transient local).
        'crash': prints 30 numbered lines to stderr at the first IMU message, then exits 3.
    bag_dir: a string parameter; echoed in the log to check $BAG_DIR substitution.
    camera_height: a float parameter; echoed in the log to check that rover.yaml is passed.
"""

from __future__ import annotations

import sys

import rclpy
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
        bag_dir = self.declare_parameter('bag_dir', '').value
        height = self.declare_parameter('camera_height', 0.0).value
        self.get_logger().info(f'mode={self.mode} bag_dir={bag_dir} camera_height={height}')
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.odom_pub = self.create_publisher(Odometry, '/vo/odometry', reliable)
        self.pose_pub = self.create_publisher(PoseWithCovarianceStamped, '/global_pose', reliable)
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
        odom = Odometry()
        odom.header.stamp = msg.header.stamp
        odom.header.frame_id = 'odom'
        odom.child_frame_id = 'base_link'
        odom.pose.pose.position.x = msg.linear_acceleration.x
        self.odom_pub.publish(odom)
        if self.count % 10 == 0:
            pose = PoseWithCovarianceStamped()
            pose.header = odom.header
            pose.header.frame_id = 'map'
            pose.pose.pose.position.x = msg.linear_acceleration.x
            self.pose_pub.publish(pose)
        self.count += 1


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
