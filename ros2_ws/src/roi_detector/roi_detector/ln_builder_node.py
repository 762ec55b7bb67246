"""The ln_builder node: the incremental Local Network from the confirmed ROI tracks.

Thin ROS wrapper around :class:`~roi_detector.local_network.LocalNetwork`. Subscribes
``/rois/tracks`` (odom); publishes ``/local_network`` (odom, reliable, transient local)
whenever the LN changes, and writes it to ``ln_path`` (atomically) at the same time, so a
killed ln_builder restarted with the same ``ln_path`` resumes with the LN it had. A saved
LN that cannot be read is moved aside (``<ln_path>.corrupt-<unix time>``), the error
logged, and a fresh LN started.
"""

from __future__ import annotations

import sys

from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import PointCloud2

from roi_detector.local_network import LnConfig, load_or_fresh
from roi_network.pointcloud import PointCloudFormatError, from_pointcloud2, to_pointcloud2
from roi_network.spin import run_node

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)


class LnBuilderNode(Node):
    """/rois/tracks in, /local_network out (and on disk)."""

    def __init__(self) -> None:
        super().__init__("ln_builder")
        d = ParameterDescriptor
        self.ln_path = self.declare_parameter(
            "ln_path", "", d(description="file the LN is kept in and reloaded from "
                             "(GeoJSON, odom); '' keeps it in memory only")).value
        min_obs = self.declare_parameter(
            "min_obs", LnConfig().min_obs,
            d(description="observations of a track before it enters the LN")).value
        self.cfg = LnConfig(min_obs=int(min_obs))
        if self.ln_path:
            self.ln = load_or_fresh(self.ln_path, self.cfg,
                                    lambda m: self.get_logger().error(m))
        else:
            from roi_detector.local_network import LocalNetwork

            self.ln = LocalNetwork(self.cfg)
            self.get_logger().warning("parameter 'ln_path' is empty: the LN is not kept "
                                      "on disk and a restart loses it")
        self.pub = self.create_publisher(PointCloud2, "/local_network", LATCHED)
        self.create_subscription(PointCloud2, "/rois/tracks", self.on_tracks, RELIABLE)
        self.last_stamp = None
        self.bad_messages = 0
        if len(self.ln):
            self.get_logger().info(f"resumed the LN of {self.ln_path}: {len(self.ln)} nodes")
            self.publish(self.get_clock().now().to_msg())

    def on_tracks(self, msg: PointCloud2) -> None:
        """Fold the tracks into the LN; publish and save it when it changed."""
        if msg.header.frame_id != "odom":
            self._bad(f"/rois/tracks: header frame '{msg.header.frame_id}', expected 'odom'")
            return
        try:
            tracks = from_pointcloud2(msg)
        except PointCloudFormatError as exc:
            self._bad(f"/rois/tracks: {exc}")
            return
        if self.ln.update(tracks):
            self.publish(msg.header.stamp)

    def _bad(self, text: str) -> None:
        self.bad_messages += 1
        if self.bad_messages == 1:
            self.get_logger().error(f"{text}: message skipped (further ones counted)")

    def publish(self, stamp) -> None:
        """Write the LN to ln_path, then publish it (latched): what was published is on
        disk."""
        if self.ln_path:
            try:
                self.ln.save(self.ln_path)
            except OSError as exc:
                self._bad(f"cannot write {self.ln_path}: {exc.strerror}")
        self.pub.publish(to_pointcloud2(self.ln.records, "odom", stamp=stamp))


def main(args: list[str] | None = None) -> int:
    """Run the node until shutdown; a bad parameter exits with status 1."""
    return run_node(LnBuilderNode, "ln_builder", args)


if __name__ == "__main__":
    sys.exit(main())
