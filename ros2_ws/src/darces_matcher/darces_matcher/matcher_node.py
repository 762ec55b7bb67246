"""The darces_matcher node: fits the growing LN onto the GN and publishes /global_pose.

Thin ROS wrapper around :class:`~darces_matcher.matcher.Matcher` (matching) and
:class:`~darces_matcher.localization.AlignmentTracker` (what each match does to the
published alignment). Topics and QoS follow docs/architecture.md.
"""

from __future__ import annotations

import dataclasses
import sys
import time

import numpy as np
import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from darces_matcher.localization import AlignmentTracker, compose_pose, yaw_quaternion
from darces_matcher.matcher import MatchConfig, Matcher, MatchResult
from roi_network.geojson import read_geojson
from roi_network.pointcloud import PointCloudFormatError, from_pointcloud2
from roi_network.records import xy
from roi_network.spin import spin_until_shutdown

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)


def _config_field_default(f: dataclasses.Field) -> bool | int | float:
    # None (automatic) is not a ROS parameter value: 0.0 stands for it.
    return 0.0 if f.default is None else f.default


class MatcherNode(Node):
    """Subscribes /local_network and /vo/odometry; publishes /global_alignment,
    /global_pose and /matcher/status."""

    def __init__(self) -> None:
        super().__init__("darces_matcher")
        gn_path = self.declare_parameter(
            "gn_path", "", ParameterDescriptor(description="GN GeoJSON file (map frame)")
        ).value
        self.ln_frame = self.declare_parameter(
            "ln_frame", "odom", ParameterDescriptor(description="expected LN header frame")
        ).value
        self.min_new_nodes = self.declare_parameter(
            "min_new_nodes", 1,
            ParameterDescriptor(description="re-match when the LN grew by this many nodes"),
        ).value
        self.max_rematch_period_s = self.declare_parameter(
            "max_rematch_period_s", 10.0,
            ParameterDescriptor(description="re-match an LN that changed but did not grow "
                                "after this long (node positions refined), seconds"),
        ).value
        consistency_m = self.declare_parameter(
            "consistency_m", 5.0,
            ParameterDescriptor(description="two fixes agree when they place every LN "
                                "node within this distance, metres"),
        ).value
        overrides = {}
        for f in dataclasses.fields(MatchConfig):
            value = self.declare_parameter(
                f"match.{f.name}", _config_field_default(f),
                ParameterDescriptor(description=f"MatchConfig.{f.name} (docs/matcher.md)"),
            ).value
            overrides[f.name] = None if f.default is None and value == 0.0 else value
        if not gn_path:
            raise ValueError("parameter 'gn_path' is not set (the GN GeoJSON file)")
        gn = read_geojson(gn_path)
        t0 = time.perf_counter()
        self.matcher = Matcher(gn, MatchConfig(**overrides))
        self.get_logger().info(
            f"GN {gn_path}: {len(gn)} ROIs, index built in "
            f"{1e3 * (time.perf_counter() - t0):.0f} ms"
        )
        self.tracker = AlignmentTracker(consistency_m)
        self.last_matched_size = 0
        self.last_match_time: float | None = None
        self.last_result: MatchResult | None = None
        self.last_event = "none"

        self.alignment_pub = self.create_publisher(TransformStamped, "/global_alignment",
                                                   LATCHED)
        self.pose_pub = self.create_publisher(PoseWithCovarianceStamped, "/global_pose",
                                              RELIABLE)
        self.status_pub = self.create_publisher(DiagnosticArray, "/matcher/status", 10)
        self.create_subscription(PointCloud2, "/local_network", self.on_local_network, LATCHED)
        self.create_subscription(Odometry, "/vo/odometry", self.on_odometry, RELIABLE)

    def on_local_network(self, msg: PointCloud2) -> None:
        """Re-match the LN when it has grown (or changed for long enough)."""
        if msg.header.frame_id != self.ln_frame:
            self.get_logger().error(
                f"/local_network: header frame '{msg.header.frame_id}', expected "
                f"'{self.ln_frame}': message ignored"
            )
            return
        try:
            records = from_pointcloud2(msg)
        except PointCloudFormatError as exc:
            self.get_logger().error(f"/local_network: {exc}: message ignored")
            return
        now = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
        grew = len(records) - self.last_matched_size >= self.min_new_nodes
        stale = (self.last_match_time is not None
                 and now - self.last_match_time >= self.max_rematch_period_s)
        if not (grew or stale):
            return
        result = self.matcher.match(records)
        self.last_matched_size, self.last_match_time = len(records), now
        self.last_result = result
        self.last_event = self.tracker.update(result, xy(records))
        if self.last_event in ("first_fix", "refined", "switched"):
            self.publish_alignment(msg.header.stamp)
        if self.last_event in ("first_fix", "switched", "conflict"):
            self.get_logger().info(
                f"{self.last_event}: LN {len(records)} nodes, support {result.support}, "
                f"margin {result.margin}, {result.timings_ms.get('total', 0.0):.1f} ms"
            )
        self.publish_status(msg.header.stamp, len(records))

    def publish_alignment(self, stamp) -> None:
        """Publish map -> odom on /global_alignment (latched)."""
        t = self.tracker.alignment.map_T_odom
        msg = TransformStamped()
        msg.header.stamp = stamp
        msg.header.frame_id = "map"
        msg.child_frame_id = self.ln_frame
        msg.transform.translation.x, msg.transform.translation.y = t.tx, t.ty
        q = yaw_quaternion(t.yaw)
        r = msg.transform.rotation
        r.x, r.y, r.z, r.w = (float(v) for v in q)
        self.alignment_pub.publish(msg)

    def on_odometry(self, msg: Odometry) -> None:
        """Once localized, publish each odometry pose composed with the alignment."""
        alignment = self.tracker.alignment
        if alignment is None:
            return
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        pos, quat, cov = compose_pose(
            alignment, np.array([p.x, p.y, p.z]), np.array([q.x, q.y, q.z, q.w]),
            np.array(msg.pose.covariance),
        )
        out = PoseWithCovarianceStamped()
        out.header.stamp = msg.header.stamp
        out.header.frame_id = "map"
        pp, pq = out.pose.pose.position, out.pose.pose.orientation
        pp.x, pp.y, pp.z = (float(v) for v in pos)
        pq.x, pq.y, pq.z, pq.w = (float(v) for v in quat)
        out.pose.covariance = [float(v) for v in cov.ravel()]
        self.pose_pub.publish(out)

    def publish_status(self, stamp, ln_size: int) -> None:
        """Publish the matcher state on /matcher/status."""
        r = self.last_result
        localized = self.tracker.alignment is not None
        status = DiagnosticStatus()
        status.name = "darces_matcher"
        status.hardware_id = "global_localization"
        status.level = DiagnosticStatus.OK if localized else DiagnosticStatus.WARN
        status.message = (f"{'localized' if localized else 'not localized'}: "
                          f"{self.last_event} ({r.reason})")
        values = {
            "state": "localized" if localized else "searching",
            "event": self.last_event,
            "reason": r.reason,
            "ln_size": ln_size,
            "votes": r.votes,
            "inliers": r.support,
            "runner_up": r.runner_up,
            "margin": r.margin,
            "hypotheses": r.n_hypotheses,
            "switches": self.tracker.switches,
            "time_ms": f"{r.timings_ms.get('total', 0.0):.2f}",
        }
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        msg = DiagnosticArray()
        msg.header.stamp = stamp
        msg.status = [status]
        self.status_pub.publish(msg)


def main(args: list[str] | None = None) -> int:
    """Run the node until shutdown; a bad GN file or parameter exits with status 1."""
    rclpy.init(args=args)
    node = None
    try:
        node = MatcherNode()
        spin_until_shutdown(node)
    except KeyboardInterrupt:
        pass
    except (OSError, ValueError) as exc:
        print(f"darces_matcher: error: {exc}", file=sys.stderr)
        return 1
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == "__main__":
    sys.exit(main())
