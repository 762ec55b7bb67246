"""The stereo images the pipeline reads, in either of the two ROS image transports.

DESIGN.md's contract is ``sensor_msgs/CompressedImage`` on ``/stereo/{left,right}/
image_raw/compressed``, as the simulator records. A field bag often carries the raw
transport instead: ``sensor_msgs/Image`` on ``/stereo/{left,right}/image_raw`` (what a
camera driver publishes and ``ros2 bag record`` keeps unless told otherwise). Both are
read here, the one way every node and offline CLI decodes a stereo image:

- :func:`decode_image`: 8-bit grey or BGR pixels of either message (JPEG/PNG payloads;
  raw ``mono8``, ``mono16``, ``rgb8``, ``bgr8``, ``rgba8``, ``bgra8``, ``8UC1``,
  ``8UC3``, ``16UC1`` and the four 8-bit Bayer patterns), None when it does not decode;
- :func:`bag_transport`: which transport a bag's topics carry (an error naming the
  topics when neither pair is complete);
- :class:`TransportLock`: a node subscribes to both and keeps the first transport that
  delivers, so a bag that carries both is not read twice;
- :class:`StereoHalves`: left and right images paired by header stamp, exact or within a
  tolerance (cameras triggered together, stamped by their own drivers);
- :class:`Rectifier`: a camera driver's images come as the sensor saw them, with the
  distortion (D) and rectifying rotation (R) in their CameraInfo; they are remapped to
  the rectified geometry of its P, as ROS's image_proc does. DESIGN.md's CameraInfo
  describes rectified images already (D zero, R identity, K = P's 3x3): there the
  rectifier is the identity.

rclpy's and rosbags' message objects have the same field names: one reader serves both.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Any

import numpy as np

COMPRESSED = "compressed"
RAW = "raw"
#: ``image_transport`` values a node accepts: ``auto`` keeps the first that delivers.
TRANSPORT_CHOICES = ("auto", COMPRESSED, RAW)
#: The nodes' ``image_transport`` parameter, described.
TRANSPORT_PARAMETER_HELP = (
    "stereo images: 'compressed' (sensor_msgs/CompressedImage on "
    "/stereo/*/image_raw/compressed, DESIGN.md), 'raw' (sensor_msgs/Image on "
    "/stereo/*/image_raw) or 'auto', the first of the two that delivers")

#: (left, right) image topics per transport.
STEREO_TOPICS: dict[str, tuple[str, str]] = {
    COMPRESSED: ("/stereo/left/image_raw/compressed", "/stereo/right/image_raw/compressed"),
    RAW: ("/stereo/left/image_raw", "/stereo/right/image_raw"),
}
MSGTYPES: dict[str, str] = {
    COMPRESSED: "sensor_msgs/msg/CompressedImage",
    RAW: "sensor_msgs/msg/Image",
}
IMAGE_TOPICS: frozenset[str] = frozenset(t for pair in STEREO_TOPICS.values() for t in pair)

# cv_bridge's mapping: OpenCV names a Bayer pattern by its second row. (Names, not
# constants: OpenCV is imported when an image is decoded, not by the topic tables.)
_BAYER = {
    "bayer_rggb8": "COLOR_BayerBG2BGR",
    "bayer_bggr8": "COLOR_BayerRG2BGR",
    "bayer_gbrg8": "COLOR_BayerGR2BGR",
    "bayer_grbg8": "COLOR_BayerGB2BGR",
}
# encoding -> (channels, bytes per channel)
_LAYOUT = {
    "mono8": (1, 1), "8UC1": (1, 1), "mono16": (1, 2), "16UC1": (1, 2),
    "rgb8": (3, 1), "bgr8": (3, 1), "8UC3": (3, 1), "rgba8": (4, 1), "bgra8": (4, 1),
    **{name: (1, 1) for name in _BAYER},
}
RAW_ENCODINGS = tuple(_LAYOUT)


def transport_of(topic: str) -> str | None:
    """``compressed`` or ``raw`` for a stereo image topic, None for any other topic."""
    for transport, pair in STEREO_TOPICS.items():
        if topic in pair:
            return transport
    return None


def side_of(topic: str) -> str | None:
    """``left`` or ``right`` for a stereo image topic, None for any other topic."""
    for left, right in STEREO_TOPICS.values():
        if topic in (left, right):
            return "left" if topic == left else "right"
    return None


def describe(msg: Any) -> str:
    """What an image message says it holds, for error messages."""
    if hasattr(msg, "encoding"):
        return (f"sensor_msgs/Image {msg.width}x{msg.height}, encoding '{msg.encoding}', "
                f"step {msg.step}, {len(msg.data)} bytes")
    return f"sensor_msgs/CompressedImage, format '{msg.format}', {len(msg.data)} bytes"


def decode_image(msg: Any, colour: bool = False) -> np.ndarray | None:
    """8-bit pixels of a ``sensor_msgs/CompressedImage`` or ``sensor_msgs/Image``.

    Args:
        msg: the message (rclpy's or rosbags').
        colour: BGR (H, W, 3) if True, else grey (H, W).

    Returns:
        uint8 array, or None when the message does not decode (empty or corrupt payload,
        an encoding not listed in :data:`RAW_ENCODINGS`, fewer bytes than its size says).
        16-bit raw images are scaled from their full range (65535 -> 255).
    """
    import cv2

    if hasattr(msg, "encoding"):
        return _decode_raw(msg, colour)
    data = np.frombuffer(bytes(msg.data), np.uint8)
    if data.size == 0:
        return None
    # OpenCV prints libjpeg warnings for truncated data and may still return an image;
    # a truncated JPEG decodes to grey padding, caught by the callers' exposure checks.
    return cv2.imdecode(data, cv2.IMREAD_COLOR if colour else cv2.IMREAD_GRAYSCALE)


def _decode_raw(msg: Any, colour: bool) -> np.ndarray | None:
    import cv2

    encoding = str(msg.encoding)
    if encoding not in _LAYOUT:
        return None
    channels, depth = _LAYOUT[encoding]
    height, width, step = int(msg.height), int(msg.width), int(msg.step)
    row = width * channels * depth
    data = np.frombuffer(bytes(msg.data), np.uint8)
    if height <= 0 or width <= 0 or step < row or data.size < height * step:
        return None
    rows = data[:height * step].reshape(height, step)[:, :row]
    if depth == 2:
        order = ">" if msg.is_bigendian else "<"
        pixels = np.ascontiguousarray(rows).view(f"{order}u2").reshape(height, width)
        grey = ((pixels.astype(np.uint32) * 255 + 32767) // 65535).astype(np.uint8)
        return cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR) if colour else grey
    pixels = np.ascontiguousarray(rows).reshape(height, width, channels)
    if encoding in _BAYER:
        bgr = cv2.cvtColor(pixels[:, :, 0], getattr(cv2, _BAYER[encoding]))
        return bgr if colour else cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    if channels == 1:
        grey = pixels[:, :, 0]
        return cv2.cvtColor(grey, cv2.COLOR_GRAY2BGR) if colour else grey
    code = {("rgb8", True): cv2.COLOR_RGB2BGR, ("rgb8", False): cv2.COLOR_RGB2GRAY,
            ("rgba8", True): cv2.COLOR_RGBA2BGR, ("rgba8", False): cv2.COLOR_RGBA2GRAY,
            ("bgra8", True): cv2.COLOR_BGRA2BGR, ("bgra8", False): cv2.COLOR_BGRA2GRAY,
            ("bgr8", False): cv2.COLOR_BGR2GRAY, ("8UC3", False): cv2.COLOR_BGR2GRAY}
    key = (encoding, colour)
    return cv2.cvtColor(pixels, code[key]) if key in code else pixels


def bag_transport(topics: Mapping[str, str], source: str) -> str:
    """The image transport whose stereo pair a bag carries (compressed first, the contract).

    Args:
        topics: the bag's topics, name -> message type (``pkg/msg/Type``).
        source: the bag, named in the error.

    Raises:
        ValueError: naming ``source`` and the topics it lacks or carries with another type.
    """
    for transport, pair in STEREO_TOPICS.items():
        if all(topics.get(t) == MSGTYPES[transport] for t in pair):
            return transport
    wrong = [f"{t} ({topics[t]}, expected {MSGTYPES[transport_of(t)]})"
             for t in sorted(IMAGE_TOPICS) if t in topics
             and topics[t] != MSGTYPES[transport_of(t)]]
    wanted = " or ".join(f"{' + '.join(pair)} ({MSGTYPES[tr]})"
                         for tr, pair in STEREO_TOPICS.items())
    has = ", ".join(sorted(topics)) or "no topics"
    what = f"wrong type: {'; '.join(wrong)}" if wrong else f"it has {has}"
    raise ValueError(f"{source}: no stereo image pair: needs {wanted}; {what}")


class TransportLock:
    """Which transport a node reads, when it subscribes to both.

    Args:
        choice: ``auto`` (the first transport that delivers an image), ``compressed`` or
            ``raw``.
        report: called once, with a one-line message, when images of the other transport
            arrive too (a bag that records both) and are ignored.

    Raises:
        ValueError: on any other choice, naming the nodes' parameter.
    """

    def __init__(self, choice: str = "auto",
                 report: Callable[[str], None] | None = None) -> None:
        if choice not in TRANSPORT_CHOICES:
            raise ValueError(f"parameter image_transport '{choice}': expected one of "
                             f"{', '.join(TRANSPORT_CHOICES)}")
        self.transport: str | None = None if choice == "auto" else choice
        self.ignored = 0
        self._report = report

    def subscribed(self) -> list[str]:
        """The transports to subscribe to."""
        return [self.transport] if self.transport else [COMPRESSED, RAW]

    def accept(self, topic: str) -> bool:
        """True if an image on ``topic`` is to be read (and the lock set, if it was not)."""
        transport = transport_of(topic)
        if self.transport is None:
            self.transport = transport
        if transport == self.transport:
            return True
        self.ignored += 1
        if self.ignored == 1 and self._report is not None:
            self._report(f"{topic}: images arrive in both transports; reading the "
                         f"{self.transport} ones only (parameter image_transport)")
        return False

    def subscribe(self, node: Any, callback: Callable[[str, Any], None], qos: Any) -> None:
        """Subscribe ``node`` (an rclpy Node) to the stereo topics of :meth:`subscribed`;
        ``callback(topic, msg)`` gets the images :meth:`accept` keeps."""
        from sensor_msgs.msg import CompressedImage, Image

        def deliver(topic: str, msg: Any) -> None:
            if self.accept(topic):
                callback(topic, msg)

        for transport in self.subscribed():
            msgtype = CompressedImage if transport == COMPRESSED else Image
            for topic in STEREO_TOPICS[transport]:
                node.create_subscription(msgtype, topic,
                                         lambda msg, t=topic: deliver(t, msg), qos)


#: Default of the nodes' and CLIs' stereo sync tolerance, seconds: left and right images
#: whose header stamps differ by at most this much are one pair. Cameras triggered
#: together but stamped by their own drivers differ by a few milliseconds; at the rover's
#: 5 deg/s, 5 ms turns the view by 0.2 px at 460 px focal length.
SYNC_TOLERANCE_S = 0.005
#: The nodes' stereo sync parameter, described.
SYNC_PARAMETER_HELP = (
    "left and right images whose header stamps differ by at most this many seconds are one "
    "stereo pair (stamped with the left's); 0: exact stamps only (stereo_image_proc's "
    "ExactTime). Never more than half the interval between one camera's frames")


class StereoHalves:
    """Stereo images waiting for their other half, paired by header stamp.

    Exact stamps pair first; otherwise a half pairs with the nearest waiting half of the
    other side within the tolerance (what stereo_image_proc's ``approximate_sync`` does for
    cameras that are triggered together and stamped apart). A pair is filed under the
    left image's stamp, the reference camera's. The tolerance in use never exceeds half
    the median interval between the recent frames of one side, so that a half cannot
    pair with its neighbour's partner.

    Args:
        tolerance_s: most difference between the two stamps of a pair, seconds; 0: exact.
        source: named in the error.

    Raises:
        ValueError: on a negative or non-finite tolerance, naming ``source``.
    """

    def __init__(self, tolerance_s: float = SYNC_TOLERANCE_S,
                 source: str = "stereo sync tolerance") -> None:
        if not np.isfinite(tolerance_s) or tolerance_s < 0:
            raise ValueError(f"{source}: {tolerance_s} s: expected a tolerance >= 0 seconds")
        self.tolerance_ns = round(float(tolerance_s) * 1e9)
        #: stamp (ns) -> {"left": msg, "right": msg}, one or both halves.
        self.slots: dict[int, dict[str, Any]] = {}
        #: Largest difference between the stamps of a pair so far, ns.
        self.max_offset_ns = 0
        self._recent: dict[str, list[int]] = {"left": [], "right": []}  # last stamps per side

    def tolerance_in_use_ns(self) -> int:
        """The tolerance applied: the parameter's, less than half the median interval
        between the recent frames of either side."""
        tol = self.tolerance_ns
        for recent in self._recent.values():
            gaps = np.diff(np.unique(recent))
            if len(gaps):
                tol = min(tol, (int(np.median(gaps)) - 1) // 2)
        return tol

    def add(self, side: str, stamp_ns: int, msg: Any) -> int | None:
        """File one half; returns the stamp of the slot it is in (the left's once paired),
        or None when that side already holds an image of this stamp (a duplicate, not
        filed)."""
        slot = self.slots.get(stamp_ns)
        if slot is not None and side in slot:
            return None
        self._recent[side] = (self._recent[side] + [stamp_ns])[-32:]
        if slot is not None:
            slot[side] = msg
            return stamp_ns
        other = "right" if side == "left" else "left"
        tol = self.tolerance_in_use_ns() if self.tolerance_ns else 0
        near = [s for s, sl in self.slots.items()
                if side not in sl and other in sl and abs(s - stamp_ns) <= tol]
        if not near:
            self.slots[stamp_ns] = {side: msg}
            return stamp_ns
        partner = min(near, key=lambda s: (abs(s - stamp_ns), s))
        slot = self.slots.pop(partner)
        slot[side] = msg
        self.max_offset_ns = max(self.max_offset_ns, abs(partner - stamp_ns))
        key = stamp_ns if side == "left" else partner
        self.slots[key] = slot
        return key

    def complete(self) -> list[int]:
        """Stamps of the slots holding both halves, oldest first."""
        return sorted(s for s, sl in self.slots.items() if len(sl) == 2)

    def pop(self, stamp_ns: int) -> dict[str, Any]:
        """Take a slot out: ``{"left": msg, "right": msg}`` or one of them."""
        return self.slots.pop(stamp_ns)

    def older_than(self, stamp_ns: int) -> list[int]:
        """Stamps of the slots older than ``stamp_ns``, oldest first."""
        return sorted(s for s in self.slots if s < stamp_ns)

    def lone_detail(self, stamp_ns: int) -> str:
        """Why a slot holds one half: the nearest stamp of the other side seen, when there
        is one within a second (the two cameras stamped further apart than the
        tolerance), else nothing."""
        slot = self.slots.get(stamp_ns, {})
        if len(slot) != 1:
            return ""
        side = next(iter(slot))
        other = "right" if side == "left" else "left"
        seen = [s for s in self._recent[other] if 0 < abs(s - stamp_ns) < 1_000_000_000]
        if not seen:
            return ""
        gap = min(abs(s - stamp_ns) for s in seen)
        return (f"; the nearest {other} image is {gap * 1e-6:.1f} ms from it, beyond the "
                f"stereo sync tolerance ({self.tolerance_in_use_ns() * 1e-6:.1f} ms)")

    def give_up(self, before_ns: int) -> list[str]:
        """Take out the slots older than ``before_ns`` (a half whose partner never came),
        oldest first; one line each for the bad-input count, naming its stamp and how far
        the nearest image of the other side was (:meth:`lone_detail`)."""
        lines = []
        for stamp in self.older_than(before_ns):
            lines.append(f"stereo pair at {stamp * 1e-9:.3f} s has one "
                         f"image{self.lone_detail(stamp)}")
            self.slots.pop(stamp)
        return lines


#: CameraInfo distortion models the rectification reads (OpenCV's pinhole model takes the
#: 4, 5, 8, 12 or 14 coefficients of plumb_bob / rational_polynomial; equidistant is
#: OpenCV's fisheye model, 4 coefficients).
PINHOLE_MODELS = ("plumb_bob", "rational_polynomial", "")
FISHEYE_MODELS = ("equidistant", "fisheye")


def _info_arrays(info: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    d = np.asarray(info.d, float).ravel()
    k = np.asarray(info.k, float).reshape(3, 3)
    r = np.asarray(info.r, float).reshape(3, 3)
    p = np.asarray(info.p, float).reshape(3, 4)
    return d, k, r, p


def describes_rectified(info: Any) -> bool:
    """True when a CameraInfo describes images that are rectified already: no distortion,
    no rectifying rotation (R identity, or all zeros: not set) and K equal to P's left 3x3;
    or when it carries no calibration (K all zeros) to rectify with."""
    d, k, r, p = _info_arrays(info)
    if not np.any(k):
        return True
    rotation_free = not np.any(r) or np.allclose(r, np.eye(3), atol=1e-9)
    return not np.any(d) and rotation_free and np.allclose(k, p[:, :3], rtol=1e-9, atol=1e-9)


class Rectifier:
    """Remaps one camera's images to the rectified geometry of its CameraInfo's P, as ROS's
    image_proc does: D, K and R describe the camera the image came from. The identity
    (images returned as they are) when the CameraInfo describes rectified images, as
    DESIGN.md's do.

    Args:
        info: the camera's sensor_msgs/CameraInfo.
        source: what the errors name it (its topic, for a node).

    Raises:
        ValueError: naming the distortion model when it is not one OpenCV reads, or the
            field that does not hold a calibration.
    """

    def __init__(self, info: Any, source: str = "camera_info") -> None:
        import cv2

        self.key = _info_key(info)
        self.maps: tuple[np.ndarray, np.ndarray] | None = None
        if describes_rectified(info):
            return
        d, k, r, p = _info_arrays(info)
        if not np.any(r):
            r = np.eye(3)
        size = (int(info.width), int(info.height))
        if size[0] <= 0 or size[1] <= 0:
            raise ValueError(f"{source}: width x height {size[0]}x{size[1]} is not an "
                             "image size")
        model = str(info.distortion_model)
        if model in PINHOLE_MODELS:
            if d.size not in (0, 4, 5, 8, 12, 14):
                raise ValueError(f"{source}: {d.size} distortion coefficients for model "
                                 f"'{model}' (OpenCV reads 4, 5, 8, 12 or 14)")
            self.maps = cv2.initUndistortRectifyMap(k, d, r, p[:, :3], size, cv2.CV_16SC2)
        elif model in FISHEYE_MODELS:
            if d.size < 4:
                raise ValueError(f"{source}: {d.size} distortion coefficients for model "
                                 f"'{model}' (4 expected)")
            self.maps = cv2.fisheye.initUndistortRectifyMap(k, d[:4], r, p[:, :3], size,
                                                            cv2.CV_16SC2)
        else:
            known = ", ".join(PINHOLE_MODELS[:2] + FISHEYE_MODELS)
            raise ValueError(f"{source}: distortion model '{model}' is not one this "
                             f"pipeline rectifies ({known})")

    @property
    def identity(self) -> bool:
        """True when images pass unchanged."""
        return self.maps is None

    def __call__(self, image: np.ndarray) -> np.ndarray:
        """The rectified image (the same array when :attr:`identity`)."""
        if self.maps is None:
            return image
        import cv2

        return cv2.remap(image, self.maps[0], self.maps[1], cv2.INTER_LINEAR)


def _info_key(info: Any) -> tuple:
    return (str(info.distortion_model), int(info.width), int(info.height),
            *(tuple(np.asarray(getattr(info, f), float).ravel()) for f in "dkrp"))


class StereoRectifiers:
    """The rectifier of each side's latest CameraInfo, as a node or CLI holds them: made
    again only when the calibration changes, and said once (``report``) each time one
    that is not the identity is made.

    Args:
        report: called with a one-line message naming the side's CameraInfo.
        parameter: the caller's parameter that turns rectification off, named in it.
    """

    def __init__(self, report: Callable[[str], None], parameter: str) -> None:
        self._report = report
        self._parameter = parameter
        self.rectifiers: dict[str, Rectifier] = {}

    def __call__(self, side: str, info: Any, image: np.ndarray) -> np.ndarray:
        """``image`` of ``side`` (``left``/``right``) rectified by ``info``.

        Raises:
            ValueError: naming ``/stereo/<side>/camera_info`` when it cannot rectify
                (:class:`Rectifier`).
        """
        current = self.rectifiers.get(side)
        if current is None or current.key != _info_key(info):
            current = self.rectifiers[side] = Rectifier(info, f"/stereo/{side}/camera_info")
            if not current.identity:
                self._report(f"/stereo/{side}/camera_info has distortion "
                             f"'{info.distortion_model}' or a rectifying rotation: images "
                             f"are rectified to its P (parameter {self._parameter})")
        return current(image)
