"""The gn_server node: loads the GN file and publishes /global_network once.

/global_network is a sensor_msgs/PointCloud2 of ROI records (roi_network's codec) in the
``map`` frame, reliable and transient local, so that a late subscriber (the matcher, a
Foxglove session) gets it. The GN's domain check (``metadata.domain_check``, written by
``orbital_gn prepare``) is passed on: logged (a warning per reason when it is not ``ok``)
and published once on /gn_server/status (diagnostic_msgs/DiagnosticArray, transient local).
A missing or malformed GN file makes the node exit with status 2 and a one-line error
naming the file and the reason.
"""

from __future__ import annotations

import sys

from roi_network.geojson import GeoJsonFormatError, domain_reasons, domain_status, read_geojson

#: Exit status of a bad GN file.
EXIT_BAD_GN = 2


def load_gn(path: str):
    """Read the GN file; raise ValueError('<path>: <reason>') on any problem."""
    if not path:
        raise ValueError("parameter 'gn_path' is not set (the GN GeoJSON file)")
    try:
        gn = read_geojson(path)
    except FileNotFoundError as exc:
        raise ValueError(f"{path}: GN file not found") from exc
    except GeoJsonFormatError as exc:
        raise ValueError(str(exc)) from exc
    except OSError as exc:
        raise ValueError(f"{path}: cannot read the GN file ({exc})") from exc
    if gn.frame_id != "map":
        raise ValueError(f"{path}: field 'metadata.frame_id' is '{gn.frame_id}', expected 'map'")
    return gn


def domain_summary(gn, path: str) -> tuple[str, list[str]]:
    """(status, one line per reason) of a GN's domain check, for the log and the status."""
    status = domain_status(gn)
    if status == "unknown":
        return status, [f"{path}: the GN carries no domain check (not written by orbital_gn "
                        "prepare, or by an older one)"]
    return status, [f"{path}: domain check {status}: {m}" for m in domain_reasons(gn)]


def main(args=None) -> int:
    from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
    from rcl_interfaces.msg import ParameterDescriptor
    from rclpy.node import Node
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import PointCloud2

    from roi_network.pointcloud import to_pointcloud2
    from roi_network.spin import run_node

    latched = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                         durability=DurabilityPolicy.TRANSIENT_LOCAL)

    class GnServer(Node):
        """Publishes the GN on /global_network (latched) once at start-up."""

        def __init__(self) -> None:
            super().__init__("gn_server")
            path = self.declare_parameter(
                "gn_path", "", ParameterDescriptor(
                    description="GN GeoJSON file (orbital_gn prepare), map frame")).value
            self.gn = load_gn(path)
            self.pub = self.create_publisher(PointCloud2, "/global_network", latched)
            msg = to_pointcloud2(self.gn.records, "map", self.get_clock().now().to_msg())
            self.pub.publish(msg)
            origin = self.gn.map_frame.origin if self.gn.map_frame else (0.0, 0.0)
            status, reasons = domain_summary(self.gn, path)
            self.get_logger().info(
                f"/global_network: {len(self.gn)} ROIs from {path} "
                f"(CRS {self.gn.map_frame.crs if self.gn.map_frame else '?'}, "
                f"map origin {origin[0]:.1f}, {origin[1]:.1f}; domain check {status})")
            if status != "ok":
                for line in reasons:
                    self.get_logger().warning(line)
            diag = DiagnosticStatus(
                name="gn_server", hardware_id="global_network",
                level=DiagnosticStatus.OK if status == "ok" else DiagnosticStatus.WARN,
                message=f"GN {path}: domain check {status}")
            diag.values = [KeyValue(key="domain_check", value=status),
                           KeyValue(key="gn_path", value=path),
                           KeyValue(key="rois", value=str(len(self.gn)))]
            diag.values += [KeyValue(key=f"reason_{i}", value=r)
                            for i, r in enumerate(domain_reasons(self.gn))]
            self.status_pub = self.create_publisher(DiagnosticArray, "/gn_server/status",
                                                    latched)
            arr = DiagnosticArray(status=[diag])
            arr.header.stamp = msg.header.stamp
            self.status_pub.publish(arr)

    return run_node(GnServer, "gn_server", args, error_status=EXIT_BAD_GN)


if __name__ == "__main__":
    sys.exit(main())
