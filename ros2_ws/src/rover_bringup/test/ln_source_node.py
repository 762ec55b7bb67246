"""Test stand-in for rover_vo + ln_builder, feeding the real darces_matcher node.

It knows the true alignment (test only): the rover drives east across the GN from its
westmost ROI (map), at ``speed_mps``; ``odom`` is ``map`` seen through the inverse of
``map_T_odom = Rigid2D(yaw, x0, y0)``. At start-up it latches an LN (/local_network,
``odom``) of the ``ln_size`` GN ROIs nearest the route; for every IMU message it publishes
/vo/odometry at the pose the rover has at that stamp.

Parameters: gn_path (GN GeoJSON), t0_ns (stamp of the route's start), speed_mps,
route_m, ln_size, yaw (rad).
"""

from __future__ import annotations

import sys

import numpy as np
import rclpy
from nav_msgs.msg import Odometry
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import Imu, PointCloud2

from roi_network.geojson import read_geojson
from roi_network.pointcloud import to_pointcloud2
from roi_network.records import xy
from roi_network.spin import spin_until_shutdown
from roi_network.transform import Rigid2D


def route_start(gn_xy: np.ndarray) -> np.ndarray:
    """Start of the route (map): the westmost GN ROI, shifted 5 m south of it."""
    return gn_xy[np.argmin(gn_xy[:, 0])] + [0.0, -5.0]


class LnSource(Node):
    """Latches an LN and turns IMU stamps into odometry along a straight route."""

    def __init__(self) -> None:
        super().__init__('ln_source')
        gn = read_geojson(self.declare_parameter('gn_path', '').value)
        self.t0_ns = self.declare_parameter('t0_ns', 0).value
        self.speed = self.declare_parameter('speed_mps', 20.0).value
        route_m = self.declare_parameter('route_m', 600.0).value
        n = self.declare_parameter('ln_size', 24).value
        yaw = self.declare_parameter('yaw', 0.8).value
        pts = xy(gn.records)
        start = route_start(pts)
        self.map_T_odom = Rigid2D(yaw, *start)
        route = start + np.linspace(0, route_m, 200)[:, None] * [1.0, 0.0]
        dist = np.min(np.linalg.norm(pts[:, None] - route[None], axis=2), axis=1)
        ln = gn.records[np.argsort(dist)[:n]].copy()
        odom = self.map_T_odom.inverse().apply(xy(ln))
        ln['x'], ln['y'] = odom[:, 0], odom[:, 1]
        ln['cov_xx'] = ln['cov_yy'] = 0.3**2
        latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                             durability=DurabilityPolicy.TRANSIENT_LOCAL)
        self.ln_pub = self.create_publisher(PointCloud2, '/local_network', latched)
        self.ln_pub.publish(to_pointcloud2(ln, 'odom', stamp=self.t0_ns))
        reliable = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
        self.odom_pub = self.create_publisher(Odometry, '/vo/odometry', reliable)
        self.create_subscription(Imu, '/imu/data', self.on_imu,
                                 QoSProfile(depth=1000, reliability=ReliabilityPolicy.BEST_EFFORT))

    def on_imu(self, msg: Imu) -> None:
        """Odometry at this stamp: map route position seen in odom."""
        t_ns = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
        s = self.speed * (t_ns - self.t0_ns) * 1e-9
        start = self.map_T_odom.translation
        p = self.map_T_odom.inverse().apply(start + np.array([s, 0.0]))
        yaw = -self.map_T_odom.yaw  # heading east in map
        odom = Odometry()
        odom.header.stamp = msg.header.stamp
        odom.header.frame_id, odom.child_frame_id = 'odom', 'base_link'
        odom.pose.pose.position.x, odom.pose.pose.position.y = float(p[0]), float(p[1])
        odom.pose.pose.orientation.z = float(np.sin(yaw / 2))
        odom.pose.pose.orientation.w = float(np.cos(yaw / 2))
        odom.pose.covariance = list(np.diag([0.01, 0.01, 0.01, 1e-4, 1e-4, 1e-4]).ravel())
        self.odom_pub.publish(odom)


def main() -> int:
    """Spin until SIGTERM."""
    rclpy.init()
    try:
        spin_until_shutdown(LnSource())
    except KeyboardInterrupt:
        pass
    finally:
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
