"""The roi_detector node: per stereo pair, find ROIs and follow them in odom.

Thin ROS wrapper around :class:`~roi_detector.rover_pipeline.RoverDetector` (the pair's
stereo points, or its classified detections with the paper's per-pair method) and
:class:`~roi_detector.rover_pipeline.DriveMapper` (the drive's elevation map, or the
tracker), the code ``roi_detector ln`` runs offline.

Subscribes the stereo pair (CompressedImage or raw Image + CameraInfo, sensor-data QoS),
``/vo/odometry`` and, when the rover.yaml parameters have a mast (``mast.*``),
``/joint_states``; publishes, after each pair whose odometry pose and camera pose are
known, ``/rois/detections`` (base_link: the ROIs in the pair's view; per_pair: what the
pair detected) and ``/rois/tracks`` (odom, every ROI followed).
Bad input (a CameraInfo it cannot use, an image that does not decode or is of an encoding
it does not read, a pair whose sizes differ, a message stamped before the one before it,
a missing pair half, a pair with no usable CameraInfo, odometry gap, a detection with no
valid depth, a pair the joint states cannot place, a joint-state message the mast cannot
read) is counted, logged once per kind naming its topic, stamp and field, and skipped;
counts are on ``/rois/status``.
"""

from __future__ import annotations

import sys
import time

import numpy as np
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from nav_msgs.msg import Odometry
from rcl_interfaces.msg import ParameterDescriptor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from sensor_msgs.msg import CameraInfo, CompressedImage, Image, JointState, PointCloud2

from roi_detector.camera_poses import PairPoses, rotation_of
from roi_detector.inputs import (
    INFO_TOPICS,
    INFO_WAIT_NS,
    JOINT_STATES,
    BadInput,
    FrameMaker,
    OdometryBuffer,
    PairSpacing,
    StampOrder,
)
from roi_detector.rover_pipeline import (
    METHODS,
    DriveMapper,
    RoverConfig,
    RoverDetector,
    load_classifier,
    records_in_view,
    session_id_base,
)
from roi_detector.tracking import TrackerConfig
from roi_network import images
from roi_network.images import TRANSPORT_PARAMETER_HELP, TransportLock
from roi_network.mast import MAST_PARAMS, MastError
from roi_network.pointcloud import to_pointcloud2
from roi_network.spin import run_node

RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
#: Sensor-data QoS (best effort) with room for the pairs that arrive while one is processed.
SENSOR = QoSProfile(depth=20, reliability=qos_profile_sensor_data.reliability,
                    durability=qos_profile_sensor_data.durability)
#: Sensor-data QoS for /joint_states: a 10 Hz stream, 50 Hz at 5x, with room for the
#: seconds a detection round takes (at depth 20 the samples around a pair were lost).
JOINTS = QoSProfile(depth=200, reliability=qos_profile_sensor_data.reliability,
                    durability=qos_profile_sensor_data.durability)


def _stamp_s(stamp) -> float:
    return stamp.sec + 1e-9 * stamp.nanosec


class RoiDetectorNode(Node):
    """Stereo pairs + odometry in, /rois/detections and /rois/tracks out."""

    def __init__(self) -> None:
        super().__init__("roi_detector")
        d = ParameterDescriptor
        extrinsic = self.declare_parameter(
            "base_to_left_camera", [0.0] * 7,
            d(description="left optical frame in base_link [x y z qx qy qz qw] (rover.yaml)"),
        ).value
        model = self.declare_parameter(
            "model_path", "",
            d(description="rover classifier model (.npz); '' = the installed model, "
              "'none' = no classifier"),
        ).value
        self.max_gap_s = self.declare_parameter(
            "odometry_max_gap_s", 12.0,
            d(description="longest odometry gap interpolated across, seconds (odometry may "
              "come once per stereo pair: every 0.45 m, every 10 s when stopped)"),
        ).value
        self.odometry_wait_s = self.declare_parameter(
            "odometry_wait_s", 3.0,
            d(description="how long a pair waits for odometry past its stamp, seconds"),
        ).value
        min_obs = self.declare_parameter(
            "min_obs", TrackerConfig().min_obs,
            d(description="observations that confirm a track"),
        ).value
        method = self.declare_parameter(
            "method", RoverConfig().method,
            d(description=f"one of {METHODS}: ROIs found in the drive's elevation map "
              "(default), or detected per pair and tracked (the paper's)"),
        ).value
        working_fx = self.declare_parameter(
            "working_fx_px", RoverConfig().working_fx_px,
            d(description="the angular resolution the detector works at, as a focal length "
              "in pixels: finer stereo pairs are resampled to it (the pixel parameters and "
              "the committed Rock Rovers are set at it); 0: pairs as they come"),
        ).value
        transport = self.declare_parameter(
            "image_transport", "auto", d(description=TRANSPORT_PARAMETER_HELP)).value
        rectify = self.declare_parameter(
            "rectify", True,
            d(description="rectify images whose CameraInfo has distortion (D) or a "
              "rectifying rotation (R) to its P, as image_proc does; false: read every "
              "image as rectified (DESIGN.md's are)")).value
        spacing = PairSpacing()
        travel = self.declare_parameter(
            "min_pair_travel_m", spacing.min_travel_m,
            d(description="read a stereo pair once the odometry moved this far since the last "
              "read (a field camera's stream thinned to the spacing the detector is set at; "
              "0: every pair)")).value
        turn = self.declare_parameter(
            "min_pair_turn_deg", spacing.min_turn_deg,
            d(description="... or turned this much")).value
        interval = self.declare_parameter(
            "max_pair_interval_s", spacing.max_interval_s,
            d(description="... or this long passed (a stopped rover)")).value
        sync_tolerance = self.declare_parameter(
            "stereo_sync_tolerance_s", images.SYNC_TOLERANCE_S,
            d(description=images.SYNC_PARAMETER_HELP)).value
        mast = {}
        for name in MAST_PARAMS:
            value = self.declare_parameter(name, None, d(
                dynamic_typing=True, description="the stereo head's pan-tilt mast "
                "(rover.yaml; roi_network.mast.MastKinematics); unset: a fixed camera")).value
            if value is not None:
                mast[name] = value if isinstance(value, str) else list(value)
        if not mast.get("mast.pan_joint") and (len(extrinsic) != 7 or not any(extrinsic)):
            raise ValueError("parameter 'base_to_left_camera' is not set (pass the bag's "
                             "rover.yaml as a params file)")
        self.transports = TransportLock(str(transport), self.get_logger().warning)
        if method not in METHODS:
            raise ValueError(f"parameter 'method': unknown '{method}' (one of {METHODS})")
        cfg = RoverConfig(method=method, tracker=TrackerConfig(min_obs=int(min_obs)),
                          working_fx_px=float(working_fx))
        classifier = load_classifier(model or None, cfg)
        self.bad = BadInput(lambda m: self.get_logger().warning(m))
        try:
            # A joint-state message the mast cannot read is logged once and dropped.
            self.poses = PairPoses({"base_to_left_camera": list(extrinsic), **mast},
                                   self.bad, strict=False)
        except MastError as exc:
            raise ValueError(str(exc)) from None
        self.detector = RoverDetector(extrinsic, classifier, cfg, self.bad)
        self.mapper = DriveMapper(cfg, classifier=classifier)
        self.odometry = OdometryBuffer(self.max_gap_s)
        try:
            self.spacing = PairSpacing(float(travel), float(turn), float(interval))
        except ValueError as e:
            raise ValueError(f"parameters min_pair_travel_m, min_pair_turn_deg, "
                             f"max_pair_interval_s: {e}") from None
        try:
            self.halves = images.StereoHalves(float(sync_tolerance),
                                              "parameter stereo_sync_tolerance_s")
        except (TypeError, ValueError) as e:
            raise ValueError(str(e)) from None
        # Pairs awaiting their odometry pose: (stamp s, header stamp, stamp ns, left, right).
        self.waiting: list = []
        self.frames = FrameMaker(self.bad, bool(rectify), self.get_logger().info)
        self.order = StampOrder(self.bad)
        self._status_ns = -(2 ** 62)  # stamp of the latest /rois/status, ns
        self.n_pairs = 0
        self.id_base = session_id_base(time.time())
        prov = {} if classifier is None else classifier.meta.get("provenance", {})
        self.get_logger().info(f"classifier: {prov.get('command', 'none')}")

        self.det_pub = self.create_publisher(PointCloud2, "/rois/detections", RELIABLE)
        self.track_pub = self.create_publisher(PointCloud2, "/rois/tracks", RELIABLE)
        self.status_pub = self.create_publisher(DiagnosticArray, "/rois/status", 10)
        self.transports.subscribe(self, self.on_image, SENSOR)
        for side in ("left", "right"):
            self.create_subscription(CameraInfo, f"/stereo/{side}/camera_info",
                                     lambda m, s=side: self.on_info(s, m), SENSOR)
        self.create_subscription(Odometry, "/vo/odometry", self.on_odometry, RELIABLE)
        if self.poses.has_mast:
            self.create_subscription(JointState, JOINT_STATES, self.on_joint_state, JOINTS)
            kin = self.poses.poser.kinematics
            self.get_logger().info(f"mast joints '{kin.pan_joint}', '{kin.tilt_joint}': each "
                                   f"pair placed at its camera pose from {JOINT_STATES}")

    def on_joint_state(self, msg: JointState) -> None:
        """Keep the mast's angles (PairPoses); resolve the pairs waiting for them."""
        t = _stamp_s(msg.header.stamp)
        self.poses.add(t, list(msg.name), list(msg.position))
        self._track_waiting()

    def on_info(self, side: str, msg: CameraInfo) -> None:
        """Take a side's CameraInfo (one the pipeline cannot use, or stamped before the
        last, is counted and skipped: the side keeps the one it had)."""
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if not self.order(INFO_TOPICS[side], stamp) or not self.frames.set_info(side, msg):
            self.publish_status(msg.header.stamp, throttle=True)
            return
        self._process_ready()

    def on_image(self, topic: str, msg: CompressedImage | Image) -> None:
        """Pair the halves by header stamp (:class:`roi_network.images.StereoHalves`); a
        half left alone for 2 s is dropped."""
        side = images.side_of(topic)
        stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
        if not self.order(topic, stamp):
            self.publish_status(msg.header.stamp, throttle=True)
            return
        key = self.halves.add(side, stamp, msg)
        if key is None:
            self.bad("duplicate image", f"{topic}: two images with stamp "
                     f"{stamp * 1e-9:.3f} s: the second dropped")
            return
        if len(self.halves.slots[key]) == 2:
            self.poses.pair_arrived(key * 1e-9)  # a mast's joint states come between pairs
        if not self.frames.ready:
            # Complete pairs that waited INFO_WAIT_NS for a usable CameraInfo.
            dropped = [s for s in self.halves.complete() if s < stamp - INFO_WAIT_NS]
            for s in dropped:
                self.halves.pop(s)
                self.bad("no camera_info", f"stereo pair at {s * 1e-9:.3f} s: "
                         f"{self.frames.missing()}")
            if dropped:
                self.publish_status(msg.header.stamp, throttle=True)
        for line in self.halves.give_up(stamp - 2_000_000_000):
            self.bad("missing pair half", line)
        self._process_ready()

    def _process_ready(self) -> None:
        if not self.frames.ready:
            return
        for stamp in self.halves.complete():
            pair = self.halves.pop(stamp)
            left = pair["left"]
            self.waiting.append((_stamp_s(left.header.stamp), left.header.stamp, stamp, left,
                                 pair["right"]))
        self._track_waiting()

    def observe(self, stamp: int, left_msg, right_msg, base_t_left=None):
        """The pair's observation (detections or stereo points) at its camera pose (None:
        the fixed one); None (counted) when it cannot be decoded or measured."""
        frame = self.frames.frame(stamp, left_msg, right_msg)
        if frame is None:  # undecodable, or a CameraInfo it cannot rectify with
            return None
        try:
            obs = self.detector.observe(frame, base_t_left)
        except ValueError as exc:  # inconsistent CameraInfo: named field
            self.bad("bad camera_info", str(exc))
            return None
        self.n_pairs += 1
        return obs

    def on_odometry(self, msg: Odometry) -> None:
        """Buffer the odometry pose and x-y covariance; resolve waiting detections."""
        p, q = msg.pose.pose.position, msg.pose.pose.orientation
        cov = np.asarray(msg.pose.covariance, float).reshape(6, 6)[:2, :2]
        if not (np.all(np.isfinite([p.x, p.y, p.z, q.x, q.y, q.z, q.w]))
                and np.all(np.isfinite(cov))):
            self.bad("bad odometry", "non-finite pose or covariance on /vo/odometry")
            return
        if not self.odometry.append(_stamp_s(msg.header.stamp), [p.x, p.y, p.z],
                                    [q.x, q.y, q.z, q.w], cov):
            self.bad("odometry out of order", "a /vo/odometry stamp went backwards")
            return
        self._track_waiting()

    def _track_waiting(self) -> None:
        """Pairs whose odometry pose has come and whose camera pose can be decided (a
        mast's joint states around their stamp, PairPoses): read those the spacing keeps
        (detect, map, publish); a pair whose odometry does not come within
        odometry_wait_s, or that the joint states cannot place, is counted."""
        latest = self.odometry.latest_t
        keep = []
        changed = tracks = None
        status = None
        for item in self.waiting:
            t, header_stamp, stamp, left_msg, right_msg = item
            pose = self.odometry.at(t)
            if pose is not None and not self.poses.decidable(t):
                keep.append(item)  # its joint states may still come
                continue
            if pose is not None:
                status = header_stamp
                cam = self.poses.pose(t)
                if cam is None:  # not placed: counted by PairPoses
                    continue
                if not (self.spacing.keep(t, pose, rotation_of(cam)) if self.poses.has_mast
                        else self.spacing.keep(t, pose)):
                    continue
                obs = self.observe(stamp, left_msg, right_msg,
                                   cam if self.poses.has_mast else None)
                if obs is None:
                    continue
                tracks = self.mapper.add_pair(obs, t, pose, self.detector.camera)
                seen = obs.records if obs.records is not None else records_in_view(
                    tracks, pose, self.detector.camera, self.mapper.cfg.elevation_map.max_range_m)
                self.det_pub.publish(to_pointcloud2(self._session_ids(seen), "base_link",
                                                    stamp=header_stamp))
                changed = t
            elif latest is not None and latest > t + self.odometry_wait_s:
                self.bad("odometry gap", f"no odometry pose at {t:.3f} s")
                status = header_stamp
            elif latest is None and self.waiting[-1][0] > t + self.odometry_wait_s:
                self.bad("odometry gap", f"no odometry at all by {self.waiting[-1][0]:.3f} s")
                status = header_stamp
            else:
                keep.append(item)
        self.waiting = keep
        if changed is not None:
            stamp = round(changed * 1e9)
            self.track_pub.publish(to_pointcloud2(self._session_ids(tracks), "odom", stamp=stamp))
        if status is not None:
            self.publish_status(status)

    def _session_ids(self, records: np.ndarray) -> np.ndarray:
        """The records with this start's id offset added (``session_id_base``)."""
        out = records.copy()
        out["id"] += np.uint32(self.id_base)
        return out

    def publish_status(self, stamp, throttle: bool = False) -> None:
        """Pair, track and bad-input counts on /rois/status; with ``throttle`` (input
        skipped outside a pair's processing) at most once per second of stamps."""
        stamp_ns = stamp.sec * 1_000_000_000 + stamp.nanosec
        if throttle and abs(stamp_ns - self._status_ns) < 1_000_000_000:
            return
        self._status_ns = stamp_ns
        status = DiagnosticStatus(name="roi_detector", hardware_id="rover_stereo")
        status.level = DiagnosticStatus.OK if not self.bad.counts else DiagnosticStatus.WARN
        status.message = f"{self.n_pairs} pairs, {self.mapper.n_tracks} tracks"
        if not self.n_pairs and self.bad.counts:
            kinds = ", ".join(f"{k} {v}" for k, v in self.bad.counts.most_common(3))
            status.message += f"; no pair read ({kinds})"
        values = {"pairs": self.n_pairs, "tracks": self.mapper.n_tracks,
                  "confirmed": int((self.mapper.current_tracks()["n_obs"]
                                    >= self.mapper.cfg.ln.min_obs).sum()),
                  "waiting_for_odometry": len(self.waiting),
                  "pairs_spaced_out": self.spacing.skipped,
                  "stereo_sync_max_offset_ms": round(self.halves.max_offset_ns * 1e-6, 3),
                  **({"joint_states": self.poses.joint_samples} if self.poses.has_mast
                     else {}), **{f"skipped: {k}": v for k, v in self.bad.counts.items()},
                  **{f"not a rock: {k}": v for k, v in self.mapper.map.rejected.items()}}
        status.values = [KeyValue(key=k, value=str(v)) for k, v in values.items()]
        msg = DiagnosticArray()
        msg.header.stamp = stamp
        msg.status = [status]
        self.status_pub.publish(msg)


def main(args: list[str] | None = None) -> int:
    """Run the node until shutdown; a bad parameter exits with status 1."""
    return run_node(RoiDetectorNode, "roi_detector", args)


if __name__ == "__main__":
    sys.exit(main())
