"""The darces_matcher node: fits the growing LN onto the GN and publishes /global_pose.

Thin ROS wrapper around :class:`~darces_matcher.matcher.Matcher` (matching) and
:class:`~darces_matcher.localization.MapOdomFilter` (the map -> odom estimate fused from
successive matches and the odometry's drift). Once localized, /global_pose follows every
/vo/odometry message. Topics and QoS follow docs/architecture.md.
"""

from __future__ import annotations

import dataclasses
import sys
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from darces_matcher.ln_drift import NodeOdometry
from darces_matcher.localization import (
    ALIGNMENT_EVENTS,
    FilterConfig,
    MapOdomFilter,
    global_pose,
    yaw_quaternion,
)
from darces_matcher.matcher import MatchConfig, Matcher, MatchResult
from roi_network.dtm import read_dtm, z_is_estimated
from roi_network.geojson import domain_reasons, domain_status, read_geojson
from roi_network.pointcloud import PointCloudFormatError, from_pointcloud2
from roi_network.records import xy
from roi_network.spin import run_node

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
#: Deep enough for ~100 s of 10 Hz odometry arriving while the GN index is built.
ODOMETRY = QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
#: The /vo/status key that says the odometry's heading is bounded (rover_vo's sun heading).
VO_HEADING_BOUNDED_KEY = "sun.heading_bounded"


class MatcherNode(Node):
    """Subscribes /local_network and /vo/odometry; publishes /global_alignment,
    /global_pose and /matcher/status."""

    def __init__(self) -> None:
        super().__init__("darces_matcher")
        gn_path = self.declare_parameter(
            "gn_path", "", ParameterDescriptor(description="GN GeoJSON file (map frame)")
        ).value
        dtm_path = self.declare_parameter(
            "dtm_path", "",
            ParameterDescriptor(description="orbital elevation model, a GeoTIFF in the GN's "
                                "CRS (map z): /global_pose z from it; empty: z not "
                                "estimated (variance 1e6 m^2)"),
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
        self.track = self.declare_parameter(
            "track", True,
            ParameterDescriptor(description="once localized, fit an LN the global search "
                                "leaves without a fix near the current alignment "
                                "(Matcher.track)"),
        ).value
        filter_overrides = {
            f.name: self.declare_parameter(
                f"localization.{f.name}", f.default,
                ParameterDescriptor(description=f"FilterConfig.{f.name} (docs/matcher.md)"),
            ).value
            for f in dataclasses.fields(FilterConfig)
        }
        overrides = {
            f.name: self.declare_parameter(
                f"match.{f.name}", f.default,
                ParameterDescriptor(description=f"MatchConfig.{f.name} (docs/matcher.md)"),
            ).value
            for f in dataclasses.fields(MatchConfig)
        }
        if not gn_path:
            raise ValueError("parameter 'gn_path' is not set (the GN GeoJSON file)")
        gn = read_geojson(gn_path)
        # orbital_gn prepare's verdict on the orthoimage against its training: a doubtful
        # GN is said at start and in every /matcher/status.
        self.gn_domain = domain_status(gn)
        if self.gn_domain not in ("ok", "unknown"):
            reasons = "; ".join(domain_reasons(gn)[:3])
            self.get_logger().warning(
                f"GN {gn_path}: domain check {self.gn_domain} (metadata.domain_check): the "
                f"GN may not be this terrain's{': ' + reasons if reasons else ''}")
        # A DTM that cannot be used (unreadable, another CRS than the GN's) ends the node
        # with a line naming the file, as a bad GN does.
        self.dtm = read_dtm(dtm_path, gn.map_frame) if dtm_path else None
        if self.dtm is None:
            self.get_logger().info(
                "no DTM (parameter dtm_path): /global_pose z is not estimated, its "
                "variance 1e6 m^2")
        else:
            self.get_logger().info(f"{self.dtm.describe()}: /global_pose z from it")
            if not self.dtm.sigma_stated:
                self.get_logger().warning(
                    f"DTM {dtm_path} states no VERTICAL_SIGMA_M: its vertical 1-sigma is "
                    f"taken as {self.dtm.vertical_sigma_m:g} m (HiRISE's); set the tag "
                    f"(rio edit-info --tag VERTICAL_SIGMA_M=<m> {dtm_path}) if it differs")
        self.z_off_dtm = 0
        self.filter = MapOdomFilter(FilterConfig(**filter_overrides))
        self.gn_xy = xy(gn.records)
        self.last_matched_size = 0
        self.last_match_time: float | None = None
        self.last_result: MatchResult | None = None
        # The odometry covariance each LN node was observed with (its heading error).
        self.node_odometry = NodeOdometry()
        self.last_event = "none"
        # rover_vo's /vo/status says whether its heading is bounded (sun heading updates).
        self.vo_heading_bounded = False

        self.alignment_pub = self.create_publisher(TransformStamped, "/global_alignment",
                                                   LATCHED)
        self.pose_pub = self.create_publisher(PoseWithCovarianceStamped, "/global_pose",
                                              RELIABLE)
        self.status_pub = self.create_publisher(DiagnosticArray, "/matcher/status", 10)
        # Subscribed before the index is built (which takes seconds on a large GN): the
        # player starts once every node subscribed to /clock, and what arrives meanwhile
        # waits in these queues (callbacks run only once spinning) instead of being missed.
        self.create_subscription(PointCloud2, "/local_network", self.on_local_network, LATCHED)
        self.create_subscription(Odometry, "/vo/odometry", self.on_odometry, ODOMETRY)
        self.create_subscription(DiagnosticArray, "/vo/status", self.on_vo_status, RELIABLE)
        t0 = time.perf_counter()
        self.matcher = Matcher(gn, MatchConfig(**overrides))
        self.get_logger().info(
            f"GN {gn_path}: {len(gn)} ROIs, index built in "
            f"{1e3 * (time.perf_counter() - t0):.0f} ms"
        )

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
        self.node_odometry.add_ln(now, records["id"], xy(records))
        grew = len(records) - self.last_matched_size >= self.min_new_nodes
        stale = (self.last_match_time is not None
                 and now - self.last_match_time >= self.max_rematch_period_s)
        if not (grew or stale):
            return
        odom_cov = self.node_odometry.covariances(records["id"])
        alignment = self.filter.alignment if self.track else None
        if alignment is None:
            result = self.matcher.match_or_track(records, odom_cov=odom_cov)
        else:
            result = self.matcher.match_or_track(records, alignment.map_T_odom,
                                                 alignment.covariance, odom_cov=odom_cov)
        self.last_matched_size, self.last_match_time = len(records), now
        self.last_result = result
        try:
            self.last_event = self.filter.update(result, xy(records), self.gn_xy)
        except (ValueError, IndexError) as exc:
            # A fix the filter cannot use (no covariance, inliers out of range): logged,
            # the estimate kept; never a dead node.
            self.get_logger().error(f"/local_network: match not usable: {exc}")
            self.last_event = "kept" if self.filter.localized else "none"
        if self.last_event in ALIGNMENT_EVENTS:
            self.publish_alignment(msg.header.stamp)
        if self.last_event in ("first_fix", "switched", "held"):
            self.get_logger().info(
                f"{self.last_event}: LN {len(records)} nodes, support {result.support}, "
                f"margin {result.margin}, {result.timings_ms.get('total', 0.0):.1f} ms"
            )
        self.publish_status(msg.header.stamp, len(records))

    def publish_alignment(self, stamp) -> None:
        """Publish map -> odom on /global_alignment (latched)."""
        t = self.filter.alignment.map_T_odom
        msg = TransformStamped()
        msg.header.stamp = stamp
        msg.header.frame_id = "map"
        msg.child_frame_id = self.ln_frame
        msg.transform.translation.x, msg.transform.translation.y = t.tx, t.ty
        q = yaw_quaternion(t.yaw)
        r = msg.transform.rotation
        r.x, r.y, r.z, r.w = (float(v) for v in q)
        self.alignment_pub.publish(msg)

    def on_vo_status(self, msg: DiagnosticArray) -> None:
        """Whether rover_vo's heading is bounded by absolute (sun) updates now."""
        for status in msg.status:
            for kv in status.values:
                if kv.key == VO_HEADING_BOUNDED_KEY:
                    self.vo_heading_bounded = kv.value == "True"

    def on_odometry(self, msg: Odometry) -> None:
        """Feed the drive to the filter; once localized, publish the pose in ``map``."""
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        position = np.array([p.x, p.y, p.z])
        quaternion = np.array([q.x, q.y, q.z, q.w])
        if not (np.all(np.isfinite(position)) and np.all(np.isfinite(quaternion))
                and np.linalg.norm(quaternion) > 1e-6):
            self.get_logger().error(
                "/vo/odometry: non-finite position or invalid orientation: message ignored")
            return
        yaw_var = float(msg.pose.covariance[35])
        self.filter.predict(position[:2], 2.0 * yaw_var if self.vo_heading_bounded else None)
        self.node_odometry.add_odometry(
            msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec, msg.pose.covariance)
        alignment = self.filter.alignment
        if alignment is None:
            return
        pos, quat, cov = global_pose(
            alignment, position, quaternion, np.array(msg.pose.covariance), self.dtm,
        )
        if self.dtm is not None and not z_is_estimated(cov[2, 2]):
            if self.z_off_dtm == 0:
                self.get_logger().warning(
                    f"/global_pose at map ({pos[0]:.1f}, {pos[1]:.1f}) m, stamp "
                    f"{msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec:.3f} s: off "
                    f"the DTM {self.dtm.source} (or on a nodata post): z not estimated "
                    "there (variance 1e6 m^2); counted in /matcher/status z_off_dtm")
            self.z_off_dtm += 1
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
        localized = self.filter.localized
        status = DiagnosticStatus()
        status.name = "darces_matcher"
        status.hardware_id = "global_localization"
        status.level = DiagnosticStatus.OK if localized else DiagnosticStatus.WARN
        status.message = (f"{'localized' if localized else 'not localized'}: "
                          f"{self.last_event} ({r.reason})")
        if self.gn_domain not in ("ok", "unknown"):
            status.message += f"; GN domain check {self.gn_domain}"
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
            "switches": self.filter.switches,
            "held": len(self.filter.held),
            "distance_m": f"{self.filter.distance_m:.1f}",
            "sigma_xy_m": (f"{np.sqrt(np.linalg.eigvalsh(self.filter.p[:2, :2]).max()):.2f}"
                           if localized else "inf"),
            "time_ms": f"{r.timings_ms.get('total', 0.0):.2f}",
            "z_source": "dtm" if self.dtm is not None else "none",
            "z_off_dtm": self.z_off_dtm,
            "gn_domain_check": self.gn_domain,
        }
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        msg = DiagnosticArray()
        msg.header.stamp = stamp
        msg.status = [status]
        self.status_pub.publish(msg)


def main(args: list[str] | None = None) -> int:
    """Run the node until shutdown; a bad GN file or parameter exits with status 1."""
    return run_node(MatcherNode, "darces_matcher", args)

if __name__ == "__main__":
    sys.exit(main())
