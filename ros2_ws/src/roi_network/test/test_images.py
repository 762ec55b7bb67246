"""roi_network.images: both image transports decode to the same pixels; a bag's transport."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from sensor_msgs.msg import CompressedImage, Image

from roi_network import images
from roi_network.images import TransportLock, bag_transport, decode_image


@pytest.fixture(scope="module")
def bgr() -> np.ndarray:
    rng = np.random.default_rng(3)
    img = rng.integers(0, 256, (48, 64, 3), dtype=np.uint8)
    img[:, :8] = (10, 120, 240)  # a coloured band: channel order matters
    return img


def raw(pixels: np.ndarray, encoding: str, step: int | None = None,
        bigendian: bool = False) -> Image:
    h, w = pixels.shape[:2]
    row = pixels.reshape(h, -1).view(np.uint8) if pixels.dtype == np.uint16 else \
        pixels.reshape(h, -1)
    step = step or row.shape[1]
    padded = np.zeros((h, step), np.uint8)
    padded[:, :row.shape[1]] = row
    return Image(height=h, width=w, encoding=encoding, is_bigendian=int(bigendian), step=step,
                 data=padded.tobytes())


def test_raw_encodings_decode_to_the_same_pixels(bgr):
    rgb = bgr[:, :, ::-1]
    grey = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    for msg in (raw(rgb, "rgb8"), raw(bgr, "bgr8"), raw(bgr, "8UC3"),
                raw(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGBA), "rgba8"),
                raw(cv2.cvtColor(bgr, cv2.COLOR_BGR2BGRA), "bgra8"),
                raw(rgb, "rgb8", step=64 * 3 + 5)):  # rows padded past the pixels
        np.testing.assert_array_equal(decode_image(msg, colour=True), bgr)
        np.testing.assert_array_equal(decode_image(msg), grey)
    for msg in (raw(grey, "mono8"), raw(grey, "8UC1")):
        np.testing.assert_array_equal(decode_image(msg), grey)
        np.testing.assert_array_equal(decode_image(msg, colour=True)[:, :, 1], grey)
    wide = grey.astype(np.uint16) * 257  # 16 bits, full range
    for bigendian in (False, True):
        data = wide.astype(">u2" if bigendian else "<u2")
        msg = raw(data.view(np.uint16), "mono16", bigendian=bigendian)
        np.testing.assert_array_equal(decode_image(msg), grey)


def test_bayer_is_demosaiced_in_ros_order():
    # A flat red scene seen through an RGGB mosaic: red at (even row, even column).
    mosaic = np.zeros((32, 32), np.uint8)
    mosaic[0::2, 0::2] = 200
    out = decode_image(raw(mosaic, "bayer_rggb8"), colour=True)
    inner = out[4:-4, 4:-4].reshape(-1, 3).mean(axis=0)
    assert inner[2] > 150 and inner[0] < 30 and inner[1] < 30  # BGR: red, not blue


def test_compressed_payloads_decode(bgr):
    for ext in (".png", ".jpg"):
        ok, buf = cv2.imencode(ext, bgr)
        assert ok
        msg = CompressedImage(format=ext[1:], data=buf.tobytes())
        out = decode_image(msg, colour=True)
        assert out.shape == bgr.shape
        if ext == ".png":
            np.testing.assert_array_equal(out, bgr)
        assert decode_image(msg).shape == bgr.shape[:2]


def test_undecodable_messages_give_none(bgr):
    assert decode_image(CompressedImage(format="jpeg")) is None
    assert decode_image(CompressedImage(format="jpeg", data=b"not a jpeg")) is None
    assert decode_image(raw(bgr, "yuv422")) is None  # not a listed encoding
    short = raw(bgr, "bgr8")
    short.data = short.data[:-10]
    assert decode_image(short) is None
    narrow = raw(bgr, "bgr8")
    narrow.step = 64 * 3 - 1
    assert decode_image(narrow) is None
    assert "encoding 'yuv422'" in images.describe(raw(bgr, "yuv422"))
    assert "format 'jpeg'" in images.describe(CompressedImage(format="jpeg"))


def test_bag_transport_prefers_the_contract_and_names_what_is_missing():
    comp = dict.fromkeys(images.STEREO_TOPICS["compressed"], images.MSGTYPES["compressed"])
    rawt = dict.fromkeys(images.STEREO_TOPICS["raw"], images.MSGTYPES["raw"])
    assert bag_transport(comp, "b") == "compressed"
    assert bag_transport(rawt, "b") == "raw"
    assert bag_transport({**comp, **rawt}, "b") == "compressed"
    half = {"/stereo/left/image_raw": images.MSGTYPES["raw"], "/imu/data": "x"}
    with pytest.raises(ValueError, match=r"bag.mcap: no stereo image pair.*it has /imu/data"):
        bag_transport(half, "bag.mcap")
    wrong = {**rawt, "/stereo/right/image_raw": "sensor_msgs/msg/CompressedImage"}
    with pytest.raises(ValueError, match="wrong type: /stereo/right/image_raw"):
        bag_transport(wrong, "b")


def test_transport_lock_keeps_the_first_that_delivers():
    reports = []
    lock = TransportLock(report=reports.append)
    assert lock.subscribed() == ["compressed", "raw"]
    assert lock.accept("/stereo/right/image_raw")
    assert not lock.accept("/stereo/left/image_raw/compressed")
    assert lock.accept("/stereo/left/image_raw") and lock.ignored == 1
    assert not lock.accept("/stereo/right/image_raw/compressed") and lock.ignored == 2
    assert reports == ["/stereo/left/image_raw/compressed: images arrive in both "
                       "transports; reading the raw ones only (parameter image_transport)"]
    fixed = TransportLock("compressed")
    assert fixed.subscribed() == ["compressed"]
    assert not fixed.accept("/stereo/left/image_raw")
    with pytest.raises(ValueError, match="image_transport 'jpeg'"):
        TransportLock("jpeg")
    assert images.side_of("/stereo/right/image_raw/compressed") == "right"
    assert images.side_of("/imu/data") is None


def _info(d=(), model="plumb_bob", r=None, width=160, height=120):
    from sensor_msgs.msg import CameraInfo

    k = [120.0, 0.0, 80.0, 0.0, 120.0, 60.0, 0.0, 0.0, 1.0]
    return CameraInfo(width=width, height=height, distortion_model=model, d=list(d), k=k,
                      r=list(r if r is not None else np.eye(3).ravel()),
                      p=[120.0, 0.0, 80.0, 0.0, 0.0, 120.0, 60.0, 0.0, 0.0, 0.0, 1.0, 0.0])


def test_rectifier_undoes_a_lens_distortion():
    from roi_network.images import Rectifier, StereoRectifiers, describes_rectified
    from roi_network.testing import _distortion_maps

    rng = np.random.default_rng(5)
    scene = cv2.GaussianBlur(rng.integers(0, 256, (120, 160), dtype=np.uint8), (0, 0), 2.0)
    scene = cv2.normalize(scene, None, 0, 255, cv2.NORM_MINMAX)
    info = _info(d=(-0.28, 0.09, 0.0, 0.0, 0.0))
    distorted = cv2.remap(scene, *_distortion_maps(info), cv2.INTER_LINEAR)
    rect = Rectifier(info)
    assert not rect.identity and not describes_rectified(info)
    inner = np.s_[20:-20, 25:-25]
    before = np.abs(distorted[inner].astype(float) - scene[inner]).mean()
    after = np.abs(rect(distorted)[inner].astype(float) - scene[inner]).mean()
    assert after < 2.0 < 5 * after < before, (before, after)
    # DESIGN.md's CameraInfo (the simulator's): rectified already, images untouched.
    plain = _info()
    assert describes_rectified(plain) and Rectifier(plain).identity
    assert Rectifier(plain)(scene) is scene
    # The same calibration keeps its rectifier; another makes a new one: each said once.
    said = []
    sides = StereoRectifiers(said.append, "rectify")
    np.testing.assert_array_equal(sides("left", info, distorted), rect(distorted))
    kept = sides.rectifiers["left"]
    sides("left", info, distorted)
    assert sides.rectifiers["left"] is kept and len(said) == 1
    sides("left", _info(d=(-0.1, 0.0, 0.0, 0.0, 0.0)), distorted)
    assert sides.rectifiers["left"] is not kept and len(said) == 2
    assert said[0].startswith("/stereo/left/camera_info has distortion 'plumb_bob'")
    assert sides("right", plain, scene) is scene and len(said) == 2
    with pytest.raises(ValueError, match="/stereo/right/camera_info: distortion model"):
        sides("right", _info(d=(0.1,), model="kannala"), scene)
    # A rectifying rotation alone is rectified too; a model OpenCV has not, refused.
    tilt = cv2.Rodrigues(np.array([0.0, 0.02, 0.0]))[0].ravel()
    assert not Rectifier(_info(r=tilt)).identity
    assert not Rectifier(_info(d=(0.1, 0.0, 0.0, 0.0), model="equidistant")).identity
    with pytest.raises(ValueError, match="distortion model 'kannala'"):
        Rectifier(_info(d=(0.1,), model="kannala"))
    with pytest.raises(ValueError, match="3 distortion coefficients"):
        Rectifier(_info(d=(0.1, 0.0, 0.0)))


def test_stereo_halves_pair_exact_stamps_first_and_within_the_tolerance():
    ms = 1_000_000
    halves = images.StereoHalves(0.005)
    # Exact stamps pair, in either arrival order.
    assert halves.add("right", 0, "r0") == 0 and halves.add("left", 0, "l0") == 0
    assert halves.complete() == [0] and halves.pop(0) == {"left": "l0", "right": "r0"}
    # Cameras stamped apart: the right 3 ms late, then 2 ms early; the pair is filed
    # under the left's stamp whichever half came first.
    assert halves.add("left", 100 * ms, "l1") == 100 * ms
    assert halves.add("right", 103 * ms, "r1") == 100 * ms
    assert halves.add("right", 198 * ms, "r2") == 198 * ms
    assert halves.add("left", 200 * ms, "l2") == 200 * ms
    assert halves.complete() == [100 * ms, 200 * ms]
    assert halves.pop(200 * ms) == {"left": "l2", "right": "r2"}
    assert halves.max_offset_ns == 3 * ms
    # Beyond the tolerance: two lone halves, and the one left says how far its partner was.
    halves.pop(100 * ms)
    halves.add("left", 300 * ms, "l3")
    halves.add("right", 314 * ms, "r3")
    assert halves.complete() == [] and halves.older_than(301 * ms) == [300 * ms]
    assert "14.0 ms" in halves.lone_detail(300 * ms)
    # Given up: taken out, one line each, the stamp and the partner's offset named.
    lines = halves.give_up(301 * ms)
    assert lines == ["stereo pair at 0.300 s has one image; the nearest right image is "
                     "14.0 ms from it, beyond the stereo sync tolerance (5.0 ms)"]
    assert list(halves.slots) == [314 * ms]
    halves.add("left", 300 * ms, "l3")  # back, for the duplicate check below
    # A second image of one side at one stamp is refused, not filed over the first.
    assert halves.add("left", 300 * ms, "again") is None
    assert halves.slots[300 * ms] == {"left": "l3"}


def test_stereo_halves_exact_only_and_never_across_frames():
    ms = 1_000_000
    exact = images.StereoHalves(0.0)
    exact.add("left", 0, "l")
    exact.add("right", 1, "r")  # 1 ns apart: not a pair with a zero tolerance
    assert exact.complete() == []
    # A 100 ms tolerance on a 20 Hz pair of cameras stamped 10 ms apart, whose right
    # image of frame 2 is lost and whose right of frame 3 comes before its left: the
    # tolerance in use drops under half the frame interval, so the left of frame 2 stays
    # alone instead of taking frame 3's right.
    wide = images.StereoHalves(0.1)
    for k in range(6):
        halves = [("left", k * 50 * ms), ("right", k * 50 * ms + 10 * ms)]
        for side, t in (halves[:1] if k == 2 else halves[::-1] if k == 3 else halves):
            wide.add(side, t, f"{side}{k}")
    assert wide.tolerance_in_use_ns() < 25 * ms
    pairs = [wide.pop(s) for s in wide.complete()]
    assert [p["left"][4:] for p in pairs] == [p["right"][5:] for p in pairs]
    assert [p["left"] for p in pairs] == ["left0", "left1", "left3", "left4", "left5"]
    assert wide.slots == {100 * ms: {"left": "left2"}}
    for bad in (-0.1, float("nan")):
        with pytest.raises(ValueError, match="stereo_sync_tolerance_s"):
            images.StereoHalves(bad, "parameter stereo_sync_tolerance_s")
