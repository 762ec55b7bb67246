"""Pipeline inputs shared by the offline CLI and the nodes: images, rover.yaml, odometry.

Bad input is counted per kind and reported once per kind (``BadInput``): the caller skips
the message and goes on, so neither a node nor a CLI run dies on one bad frame. Each report
names the topic, the message's stamp and the field (``/stereo/left/camera_info at
1403715273.712 s: K[0] (fx) = 0``): a CameraInfo the pipeline cannot use
(:func:`roi_network.camera_info.camera_info_problem`), an image that does not decode or
whose encoding is not one it reads, a stereo pair whose images differ in size from each
other or from their CameraInfo, a message older than the one before it on its topic
(:class:`StampOrder`).
"""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import yaml
from scipy.spatial.transform import Rotation, Slerp

from roi_network import images
from roi_network.camera_info import camera_info_problem

# POSE_COVARIANCE_FILE and write_tum are this package's names for the shared ones.
from roi_network.trajectory import (  # noqa: F401
    POSE_COVARIANCE_FILE,
    read_pose_covariance_rows,
    read_tum_rows,
    write_tum,
)

LEFT_INFO = "/stereo/left/camera_info"
RIGHT_INFO = "/stereo/right/camera_info"
#: Each side's CameraInfo topic.
INFO_TOPICS = {"left": LEFT_INFO, "right": RIGHT_INFO}
#: Pairs wait this long (stamps of the input read after them) for a usable CameraInfo
#: before they are counted as ``no camera_info`` and dropped, ns (the nodes give a lone
#: pair half as long).
INFO_WAIT_NS = 2_000_000_000
#: A mast's joint angles (DESIGN.md; read with :class:`~roi_detector.camera_poses.PairPoses`).
JOINT_STATES = "/joint_states"


class BadInput:
    """Counts skipped inputs per kind and reports the first of each kind once.

    Args:
        report: called with a one-line message the first time a kind occurs.
    """

    def __init__(self, report: Callable[[str], None]) -> None:
        self.counts: Counter[str] = Counter()
        self._report = report

    def __call__(self, kind: str, detail: str) -> None:
        """Count one skipped input of ``kind``; report it if it is the first."""
        self.counts[kind] += 1
        if self.counts[kind] == 1:
            self._report(f"{kind}: {detail} (skipped; further '{kind}' counted, not logged)")


class StampOrder:
    """The newest header stamp read on each topic: a message stamped before the one read
    before it on its topic is counted (``stamp out of order``), named and skipped.

    Args:
        bad: the bad-input counter.
    """

    def __init__(self, bad: BadInput) -> None:
        self.bad = bad
        self.last: dict[str, int] = {}

    def __call__(self, topic: str, stamp_ns: int) -> bool:
        """Whether the message of ``topic`` stamped ``stamp_ns`` is in order (and read)."""
        prev = self.last.get(topic)
        if prev is not None and stamp_ns < prev:
            self.bad("stamp out of order", f"{topic} at {stamp_ns * 1e-9:.3f} s: stamped "
                     f"before the message before it ({prev * 1e-9:.3f} s)")
            return False
        self.last[topic] = stamp_ns
        return True


def decode_image(msg) -> np.ndarray | None:
    """BGR uint8 image of a sensor_msgs/CompressedImage or sensor_msgs/Image; None if it
    does not decode (:func:`roi_network.images.decode_image`)."""
    return images.decode_image(msg, colour=True)


def image_topic(side: str, msg) -> str:
    """The stereo image topic of ``side`` that carries a message of ``msg``'s type."""
    transport = images.RAW if hasattr(msg, "encoding") else images.COMPRESSED
    return images.STEREO_TOPICS[transport][0 if side == "left" else 1]


def why_undecodable(msg) -> tuple[str, str]:
    """(bad-input kind, what is wrong) of an image message that does not decode: an
    encoding the pipeline does not read, or a payload that is empty, corrupt or shorter
    than its size says."""
    encoding = getattr(msg, "encoding", None)
    if encoding is not None and str(encoding) not in images.RAW_ENCODINGS:
        return ("unsupported image encoding",
                f"encoding '{encoding}' is not one this pipeline reads "
                f"({', '.join(images.RAW_ENCODINGS)})")
    return "undecodable image", images.describe(msg)


def info_size(info) -> tuple[int, int] | None:
    """(width, height) of the images a CameraInfo describes (its region of interest, if
    set, over its binning); None when it gives none (width or height 0)."""
    roi = getattr(info, "roi", None)
    w = int(roi.width) if roi is not None and int(roi.width) > 0 else int(info.width)
    h = int(roi.height) if roi is not None and int(roi.height) > 0 else int(info.height)
    w //= max(1, int(getattr(info, "binning_x", 0) or 0))
    h //= max(1, int(getattr(info, "binning_y", 0) or 0))
    return (w, h) if w > 0 and h > 0 else None


def load_rover_params(path: str | Path) -> dict:
    """The ``ros__parameters`` of a rover.yaml file (first section that has them).

    Raises:
        ValueError: naming the file when it is missing, unreadable or has no
            ``base_to_left_camera``.
    """
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"{path}: cannot read rover parameters ({exc})") from None
    for section in (doc or {}).values():
        params = (section or {}).get("ros__parameters") if isinstance(section, dict) else None
        if params and "base_to_left_camera" in params:
            return params
    raise ValueError(f"{path}: no ros__parameters with 'base_to_left_camera'")


@dataclass
class StereoFrame:
    """One stereo pair as the pipeline sees it.

    Attributes:
        stamp_ns: header stamp of the left image, nanoseconds.
        left, right: BGR uint8 images.
        left_k: left CameraInfo K (9 values); right_p: right CameraInfo P (12 values).
    """

    stamp_ns: int
    left: np.ndarray
    right: np.ndarray
    left_k: np.ndarray
    right_p: np.ndarray


def _stamp_ns(header) -> int:
    return int(header.stamp.sec) * 1_000_000_000 + int(header.stamp.nanosec)


class FrameMaker:
    """StereoFrames of decoded pairs and each side's latest CameraInfo, for the CLI and the
    node alike.

    The images are rectified to their CameraInfo's P (:class:`roi_network.images.
    Rectifier`: the identity for DESIGN.md's CameraInfo, which describes rectified images;
    a camera driver's carries its lens distortion D and rectifying rotation R), and the
    left camera's intrinsics are P's left 3x3, those of the rectified image.

    Args:
        bad: bad-input counter (a CameraInfo it cannot use, an image that does not decode
            or whose size is not its CameraInfo's or the other side's).
        rectify: False reads every image as rectified, whatever its CameraInfo says.
        log: called once per side when its images are rectified.
    """

    def __init__(self, bad: BadInput, rectify: bool = True,
                 log: Callable[[str], None] | None = None) -> None:
        self.bad = bad
        self.rectifiers = images.StereoRectifiers(log or (lambda _text: None), "rectify") \
            if rectify else None
        self.info: dict[str, object] = {"left": None, "right": None}
        #: CameraInfo messages refused per side (:meth:`set_info`).
        self.rejected: Counter[str] = Counter()

    @property
    def ready(self) -> bool:
        """Both CameraInfo have come."""
        return self.info["left"] is not None and self.info["right"] is not None

    def set_info(self, side: str, msg) -> bool:
        """Take ``side``'s CameraInfo; one the pipeline cannot use
        (:func:`camera_info_problem`) is counted (``bad camera_info``), named with its
        topic, stamp and field, and skipped: the side keeps the one it had."""
        problem = camera_info_problem(msg, side)
        if problem is not None:
            self.rejected[side] += 1
            self.bad("bad camera_info", f"{INFO_TOPICS[side]} at "
                     f"{_stamp_ns(msg.header) * 1e-9:.3f} s: {problem}")
            return False
        self.info[side] = msg
        return True

    def missing(self) -> str:
        """Why no pair can be read yet: the sides with no usable CameraInfo, and how many
        of theirs were refused."""
        parts = [f"{INFO_TOPICS[side]} ("
                 + (f"{self.rejected[side]} refused as bad camera_info" if self.rejected[side]
                    else "none came") + ")"
                 for side in ("left", "right") if self.info[side] is None]
        return "no usable CameraInfo on " + " and ".join(parts)

    def frame(self, stamp: int, left_msg, right_msg) -> StereoFrame | None:
        """The pair as the pipeline sees it; None (counted, naming the image's topic,
        the pair's stamp and what is wrong) when it cannot be: an image that does not
        decode, one whose size is not its CameraInfo's, a right image of another size
        than the left."""
        at = f"at {stamp * 1e-9:.3f} s"
        msgs = {"left": left_msg, "right": right_msg}
        pixels = {}
        for side, msg in msgs.items():
            image = decode_image(msg)
            if image is None:
                kind, why = why_undecodable(msg)
                self.bad(kind, f"{image_topic(side, msg)} {at}: {why}")
                return None
            pixels[side] = image
        size = {side: (image.shape[1], image.shape[0]) for side, image in pixels.items()}
        for side, msg in msgs.items():
            want = info_size(self.info[side])
            if want is not None and size[side] != want:
                self.bad("image size mismatch", f"{image_topic(side, msg)} {at}: "
                         f"{size[side][0]}x{size[side][1]}, its {INFO_TOPICS[side]} says "
                         f"{want[0]}x{want[1]}")
                return None
        if size["left"] != size["right"]:
            self.bad("image size mismatch", f"{image_topic('right', right_msg)} {at}: "
                     f"{size['right'][0]}x{size['right'][1]} beside the left image's "
                     f"{size['left'][0]}x{size['left'][1]}")
            return None
        if self.rectifiers is not None:
            try:
                for side in pixels:
                    pixels[side] = self.rectifiers(side, self.info[side], pixels[side])
            except ValueError as exc:
                self.bad("bad camera_info", str(exc))
                return None
        p_left = np.asarray(self.info["left"].p, float)
        left_k = p_left[[0, 1, 2, 4, 5, 6, 8, 9, 10]]
        return StereoFrame(stamp, pixels["left"], pixels["right"], left_k,
                           np.asarray(self.info["right"].p, float))


def read_stereo_frames(bag_dir: str | Path, bad: BadInput, every: int = 1,
                       rectify: bool = True,
                       log: Callable[[str], None] = print,
                       sync_tolerance_s: float = images.SYNC_TOLERANCE_S,
                       keep: Callable[[int], bool] | None = None,
                       joints=None,
                       ) -> Iterator[StereoFrame]:
    """Stereo pairs of a bag directory (``BAG/rosbag``), paired by header stamp
    (exact, or within ``sync_tolerance_s``: :class:`roi_network.images.StereoHalves`).

    Args:
        bag_dir: the bag directory (holding ``rosbag/``) or the rosbag2 directory itself.
        bad: bad-input counter (undecodable image, missing pair half).
        every: keep one pair in ``every`` (1: all).
        rectify: rectify images whose CameraInfo has distortion (:class:`FrameMaker`).
        log: told once per side when the images are rectified.
        sync_tolerance_s: most difference between a pair's two stamps, seconds.
        keep: ``keep(stamp_ns)`` decides, before a pair is decoded, whether it is read
            (:class:`PairSpacing`); None: every pair.
        joints: a mast's :class:`~roi_detector.camera_poses.PairPoses`: it is given
            every /joint_states message in the bag's order, and a pair waits (before
            ``keep``) until its pose can be decided (``PairPoses.decidable``); None: the
            bag's joint states are not read.

    The images are those of the transport the bag carries (compressed, the contract,
    when it carries both; :func:`roi_network.images.bag_transport`).

    Raises:
        FileNotFoundError: when the bag is missing.
        ValueError: naming the bag when it carries no stereo image pair.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    bag_dir = Path(bag_dir)
    rosbag = bag_dir / "rosbag" if (bag_dir / "rosbag").is_dir() else bag_dir
    if not (rosbag / "metadata.yaml").is_file():
        raise FileNotFoundError(f"{bag_dir}: no rosbag2 directory (metadata.yaml) found")
    pending = images.StereoHalves(sync_tolerance_s, "stereo sync tolerance")
    maker = FrameMaker(bad, rectify, log)
    order = StampOrder(bad)
    ready: list[tuple[int, dict]] = []
    index = 0
    mast = joints is not None and joints.has_mast

    def decided(stamp_ns: int) -> bool:
        return not mast or joints.decidable(stamp_ns * 1e-9)

    with AnyReader([rosbag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        transport = images.bag_transport(
            {c.topic: c.msgtype for c in reader.connections}, str(rosbag))
        left_image, right_image = images.STEREO_TOPICS[transport]
        topics = (left_image, right_image, LEFT_INFO, RIGHT_INFO) + \
            ((JOINT_STATES,) if mast else ())
        conns = [c for c in reader.connections if c.topic in topics]
        for conn, _t, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            if conn.topic == JOINT_STATES:
                joints.add(_stamp_ns(msg.header) * 1e-9, list(msg.name), list(msg.position))
            elif not order(conn.topic, _stamp_ns(msg.header)):
                continue
            elif conn.topic in (LEFT_INFO, RIGHT_INFO):
                maker.set_info("left" if conn.topic == LEFT_INFO else "right", msg)
            else:
                stamp = _stamp_ns(msg.header)
                key = pending.add(images.side_of(conn.topic), stamp, msg)
                if key is None:
                    bad("duplicate image", f"{conn.topic}: two images with stamp "
                        f"{stamp * 1e-9:.3f} s: the second dropped")
                    continue
                if len(pending.slots[key]) == 2:
                    slot = pending.pop(key)
                    if mast:
                        joints.pair_arrived(key * 1e-9)
                    index += 1
                    if (index - 1) % every == 0:
                        ready.append((key, slot))
                # A pair half that never comes: older pending stamps are given up.
                for line in pending.give_up(stamp - 2_000_000_000):
                    bad("missing pair half", line)
            # CameraInfo is recorded after the images of its stamp: pairs wait for it
            # (and, on a mast, for the joint states around their stamp), INFO_WAIT_NS.
            if not maker.ready:
                newest = _stamp_ns(msg.header)
                while ready and ready[0][0] < newest - INFO_WAIT_NS:
                    stamp_r, _slot = ready.pop(0)
                    bad("no camera_info", f"stereo pair at {stamp_r * 1e-9:.3f} s: "
                        f"{maker.missing()}")
                continue
            while ready and decided(ready[0][0]):
                stamp_r, slot_r = ready.pop(0)
                if keep is not None and not keep(stamp_r):
                    continue
                frame = maker.frame(stamp_r, slot_r["left"], slot_r["right"])
                if frame is not None:
                    yield frame
    for line in pending.give_up(2 ** 63 - 1):
        bad("missing pair half", line)
    if ready and not maker.ready:
        for stamp_r, _slot in ready:
            bad("no camera_info", f"stereo pair at {stamp_r * 1e-9:.3f} s: {maker.missing()}")
        return
    # The bag ended: no joint sample is still to come for the pairs that wait.
    for stamp_r, slot_r in ready:
        if keep is not None and not keep(stamp_r):
            continue
        frame = maker.frame(stamp_r, slot_r["left"], slot_r["right"])
        if frame is not None:
            yield frame


class PoseTrack:
    """Timestamped base_link poses in odom, interpolated (slerp) at any stamp in range.

    Args:
        stamps_s: (N,) increasing times, seconds.
        positions: (N, 3) base_link origins in odom, metres.
        quats_xyzw: (N, 4) base_link orientations in odom.
        covariances: optional (N, 2, 2) x-y position covariance in odom, m^2.
        max_gap_s: an interpolation across a gap longer than this returns None
            (odometry gap).
    """

    def __init__(self, stamps_s, positions, quats_xyzw, covariances=None,
                 max_gap_s: float = 1.0) -> None:
        self.t = np.asarray(stamps_s, float)
        self.p = np.asarray(positions, float)
        self.q = np.asarray(quats_xyzw, float)
        self.cov = None if covariances is None else np.asarray(covariances, float)
        self.max_gap_s = max_gap_s

    def __len__(self) -> int:
        return len(self.t)

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray | None] | None:
        """(R_odom_base (3, 3), t_odom_base (3,), xy covariance or None) at ``t``; None when
        ``t`` is outside the track or inside a gap longer than ``max_gap_s``."""
        n = len(self.t)
        if n == 0 or t < self.t[0] - 1e-6 or t > self.t[-1] + 1e-6:
            return None
        i = int(np.searchsorted(self.t, t))
        # A stamp equal to a pose's (within float rounding of nanosecond stamps) takes it.
        for k in (i - 1, i):
            if 0 <= k < n and abs(self.t[k] - t) < 1e-6:
                cov = None if self.cov is None else self.cov[k]
                return Rotation.from_quat(self.q[k]).as_matrix(), self.p[k].copy(), cov
        if i == 0 or i >= n:
            return None
        t0, t1 = self.t[i - 1], self.t[i]
        if t1 - t0 > self.max_gap_s:
            return None
        w = (t - t0) / (t1 - t0)
        rot = Slerp([t0, t1], Rotation.from_quat(self.q[i - 1:i + 1]))([t]).as_matrix()[0]
        pos = (1 - w) * self.p[i - 1] + w * self.p[i]
        cov = None if self.cov is None else (1 - w) * self.cov[i - 1] + w * self.cov[i]
        return rot, pos, cov


@dataclass
class PairSpacing:
    """Which stereo pairs the detector reads: one each ``min_travel_m`` of travel, each
    ``min_turn_deg`` of heading, and at least each ``max_interval_s`` (a stopped rover).

    The elevation map and its statistics (a cell observed once 3 pairs saw it, a detection
    round every 3 pairs, one pair's weight capped) were set at the simulator's spacing, a
    pair each 0.45 m. A field camera streams at 1-15 Hz, a pair every 1-15 cm at rover
    speed: read as they come, the pairs would outrun the detector (4-6 per second on one
    core) and DDS would drop the excess uncounted, and every cell would count 10x the
    views. The decision reads the odometry at the pair's stamp, before the pair is decoded.
    The defaults keep every pair of the simulator's bags (0.45 m apart while moving, 10 s
    while stopped, at most 4.3 deg of heading between two at its tightest turn, and on a
    mast the panorama's pairs, each turned from the last).

    Args:
        min_travel_m: a pair is read once the rover moved this far since the last read
            (0: every pair is read).
        min_turn_deg: ... or turned this much.
        max_interval_s: ... or this long passed.
    """

    min_travel_m: float = 0.4
    min_turn_deg: float = 10.0
    max_interval_s: float = 5.0
    #: the last pair read: t, R_odom_base, t_odom_base
    last: tuple[float, np.ndarray, np.ndarray] | None = field(default=None, init=False,
                                                              repr=False)
    skipped: int = field(default=0, init=False)  #: pairs not read

    def __post_init__(self) -> None:
        for name in ("min_travel_m", "min_turn_deg", "max_interval_s"):
            value = getattr(self, name)
            if not np.isfinite(value) or value < 0:
                raise ValueError(f"pair spacing: {name} {value}: expected >= 0")

    def keep(self, t: float, pose, base_r_cam: np.ndarray | None = None) -> bool:
        """Whether the pair at ``t`` (odometry pose ``(R, p, cov)`` there) is read; a read
        pair becomes the reference of the next decision. ``base_r_cam``: on a mast, the
        camera's rotation in base_link at ``t``; the turn is then the camera's in odom
        (a panorama's pairs, taken while the rover stands, are each read)."""
        rot, pos = pose[0], pose[1]
        if base_r_cam is not None:
            rot = rot @ np.asarray(base_r_cam, float)
        if self.min_travel_m > 0 and self.last is not None:
            t0, rot0, pos0 = self.last
            turn = np.degrees(Rotation.from_matrix(rot0.T @ rot).magnitude())
            if (np.linalg.norm(pos - pos0) < self.min_travel_m and turn < self.min_turn_deg
                    and t - t0 < self.max_interval_s):
                self.skipped += 1
                return False
        self.last = (t, rot, pos)
        return True


class OdometryBuffer:
    """Odometry poses as they arrive (node side), queried like a :class:`PoseTrack`."""

    def __init__(self, max_gap_s: float = 1.0, max_len: int = 20000) -> None:
        self.max_gap_s = max_gap_s
        self.max_len = max_len
        self._rows: list[tuple] = []
        self._track: PoseTrack | None = None

    @property
    def latest_t(self) -> float | None:
        """Stamp of the newest pose, seconds (None before the first)."""
        return self._rows[-1][0] if self._rows else None

    def append(self, t: float, position, quat_xyzw, cov_xy) -> bool:
        """Add a pose; False (and not added) when ``t`` is not after the newest stamp."""
        if self._rows and t <= self._rows[-1][0]:
            return False
        self._rows.append((t, np.asarray(position, float), np.asarray(quat_xyzw, float),
                           np.asarray(cov_xy, float)))
        if len(self._rows) > self.max_len:
            del self._rows[: len(self._rows) - self.max_len]
        self._track = None
        return True

    def at(self, t: float):
        """See :meth:`PoseTrack.at`."""
        if not self._rows:
            return None
        if self._track is None:
            ts, ps, qs, cs = zip(*self._rows, strict=True)
            self._track = PoseTrack(ts, ps, qs, cs, self.max_gap_s)
        return self._track.at(t)


def read_tum(path: str | Path, max_gap_s: float = 12.0) -> PoseTrack:
    """A TUM trajectory file (``t x y z qx qy qz qw``, base_link in odom) as a PoseTrack.

    Raises:
        ValueError: naming the file and line of the first malformed row.
    """
    a = read_tum_rows(path)
    a = a[np.argsort(a[:, 0], kind="stable")]
    return PoseTrack(a[:, 0], a[:, 1:4], a[:, 4:8], max_gap_s=max_gap_s)


def read_pose_covariance(path: str | Path, stamps_s) -> np.ndarray:
    """(N, 2, 2) x-y covariance in odom at each of the odometry's stamps ``stamps_s``,
    from a pose covariance file (:data:`POSE_COVARIANCE_FILE`), as the roi_detector node
    takes it from each /vo/odometry message.

    Raises:
        ValueError: naming the file (and line) of a malformed row, a covariance that is
            not finite or has a negative variance, or the first odometry stamp with no
            covariance row (within 1 microsecond).
    """
    t, cov = read_pose_covariance_rows(path)
    order = np.argsort(t, kind="stable")
    t, cov = t[order], cov[order][:, :2, :2]
    want = np.asarray(stamps_s, float)
    # The nearest covariance row to each stamp: the one at or after it, or the one before.
    after = np.clip(np.searchsorted(t, want), 0, len(t) - 1)
    before = np.clip(after - 1, 0, len(t) - 1)
    j = np.where(np.abs(t[before] - want) < np.abs(t[after] - want), before, after)
    missing = np.flatnonzero(np.abs(t[j] - want) > 1e-6)
    if len(missing):
        raise ValueError(f"{path}: no covariance at odometry stamp {want[missing[0]]:.9f} "
                         f"({len(missing)} of {len(want)} stamps have none)")
    return cov[j]
