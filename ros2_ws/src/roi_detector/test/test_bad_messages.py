"""One bad message is one skipped message: counted, named once with its topic, stamp and
field, and the run goes on, in ``roi_detector ln`` and the inputs the node shares.

The bag is made at test time: a few raw mono8 stereo pairs of a still camera (a field
camera's 752x480 shrunk to 94x60) with DESIGN.md's rectified CameraInfo, and a bad
message of each kind put in it.
"""

from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import numpy as np

from roi_detector.inputs import (
    BadInput,
    FrameMaker,
    StampOrder,
    read_stereo_frames,
)
from roi_network.camera_info import camera_info_problem

W, H = 94, 60
FX, BASELINE = 55.0, 0.11
T0 = 1403715273_000_000_000  # a EuRoC-like stamp, ns
PERIOD = 100_000_000  # 10 Hz


def _info(side: str, stamp_ns: int, fx: float = FX, width: int = W, height: int = H):
    tx = -FX * BASELINE if side == "right" else 0.0
    return SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=stamp_ns // 10**9,
                                                     nanosec=stamp_ns % 10**9)),
        width=width, height=height, distortion_model="plumb_bob", d=[0.0] * 5,
        k=[fx, 0, W / 2, 0, FX, H / 2, 0, 0, 1], r=list(np.eye(3).ravel()),
        p=[FX, 0, W / 2, tx, 0, FX, H / 2, 0, 0, 0, 1, 0], binning_x=0, binning_y=0,
        roi=SimpleNamespace(width=0, height=0))


def _image(stamp_ns: int, width: int = W, height: int = H, encoding: str = "mono8",
           seed: int = 0):
    pixels = np.random.default_rng(seed).integers(0, 256, (height, width), np.uint8)
    return SimpleNamespace(
        header=SimpleNamespace(stamp=SimpleNamespace(sec=stamp_ns // 10**9,
                                                     nanosec=stamp_ns % 10**9)),
        height=height, width=width, encoding=encoding, is_bigendian=0, step=width,
        data=pixels.tobytes())


def test_a_camera_info_the_pipeline_cannot_use_is_named_by_topic_stamp_and_field():
    t = T0 + 712_000_000
    assert camera_info_problem(_info("left", t), "left") is None
    assert camera_info_problem(_info("left", t, fx=0.0), "left") == "K[0] (fx) = 0"
    nan = _info("left", t)
    nan.p[5] = float("nan")
    assert camera_info_problem(nan, "left") == "P[5] = nan"
    no_baseline = _info("left", t)  # a left P on the right topic
    assert camera_info_problem(no_baseline, "right") == "P[3] (-fx * baseline) = 0: no baseline"
    swapped = _info("left", t)
    swapped.p[3] = FX * BASELINE
    assert "swapped" in camera_info_problem(swapped, "right")
    assert camera_info_problem(_info("left", t, width=0), "left") == "width = 0"
    lines = []
    bad = BadInput(lines.append)
    maker = FrameMaker(bad)
    assert maker.set_info("left", _info("left", t)) and maker.set_info("right", _info("right", t))
    # One bad message: skipped, the side keeps its CameraInfo, pairs are still read.
    assert not maker.set_info("left", _info("left", t + PERIOD, fx=0.0))
    assert lines == [f"bad camera_info: /stereo/left/camera_info at "
                     f"{(t + PERIOD) * 1e-9:.3f} s: K[0] (fx) = 0 (skipped; further "
                     "'bad camera_info' counted, not logged)"]
    assert "1403715273.812 s: K[0] (fx) = 0" in lines[0]
    frame = maker.frame(t, _image(t), _image(t, seed=1))
    assert frame is not None and frame.left_k[0] == FX
    # None usable on a side: what is missing says so.
    maker = FrameMaker(BadInput(lines.append))
    maker.set_info("left", _info("left", t, fx=0.0))
    maker.set_info("right", _info("right", t))
    assert not maker.ready
    assert maker.missing() == ("no usable CameraInfo on /stereo/left/camera_info "
                               "(1 refused as bad camera_info)")


def test_images_of_another_size_or_encoding_are_named_not_their_good_partner():
    t = T0
    lines = []
    bad = BadInput(lines.append)
    maker = FrameMaker(bad)
    # The right camera's 640x480 beside the left's 752x480 (each as its CameraInfo says).
    maker.set_info("left", _info("left", t, width=752, height=480))
    maker.set_info("right", _info("right", t, width=640, height=480))
    assert maker.frame(t, _image(t, 752, 480), _image(t, 640, 480)) is None
    assert bad.counts == {"image size mismatch": 1}
    assert lines[-1].startswith(f"image size mismatch: /stereo/right/image_raw at "
                                f"{t * 1e-9:.3f} s: 640x480 beside the left image's 752x480")
    assert "undecodable" not in lines[-1]
    # The right CameraInfo says 752x480 and its image is 640x480: that image is named.
    bad.counts.clear()
    maker.set_info("right", _info("right", t, width=752, height=480))
    assert maker.frame(t, _image(t, 752, 480), _image(t, 640, 480)) is None
    assert bad.counts == {"image size mismatch": 1}
    assert ("/stereo/right/image_raw at 1403715273.000 s: 640x480, its "
            "/stereo/right/camera_info says 752x480") in lines[-1]
    # A third encoding (neither mono8 nor rgb8 of the rest): skipped and named; a
    # payload shorter than its size says: undecodable, named with what it holds.
    maker = FrameMaker(bad := BadInput(lines.append))
    maker.set_info("left", _info("left", t))
    maker.set_info("right", _info("right", t))
    assert maker.frame(t, _image(t), _image(t, encoding="yuv422")) is None
    assert "unsupported image encoding: /stereo/right/image_raw at 1403715273.000 s: " \
           "encoding 'yuv422' is not one this pipeline reads (mono8," in lines[-1]
    short = _image(t)
    short.data = short.data[:100]
    assert maker.frame(t, short, _image(t)) is None
    assert "undecodable image: /stereo/left/image_raw at 1403715273.000 s: " \
           "sensor_msgs/Image 94x60, encoding 'mono8', step 94, 100 bytes" in lines[-1]
    assert bad.counts == {"unsupported image encoding": 1, "undecodable image": 1}


def test_a_message_stamped_before_the_one_before_it_is_skipped_and_named():
    lines = []
    order = StampOrder(BadInput(lines.append))
    assert order("/stereo/left/image_raw", T0) and order("/stereo/left/image_raw", T0 + PERIOD)
    assert order("/stereo/right/image_raw", T0)  # each topic in its own order
    assert not order("/stereo/left/image_raw", T0 + PERIOD // 2)
    assert order("/stereo/left/image_raw", T0 + 2 * PERIOD)
    assert lines == ["stamp out of order: /stereo/left/image_raw at 1403715273.050 s: "
                     "stamped before the message before it (1403715273.100 s) (skipped; "
                     "further 'stamp out of order' counted, not logged)"]


def write_bag(out: Path, n: int = 12, info=None, image=None) -> Path:
    """A bag directory (``rosbag/``, ``rover.yaml``) of ``n`` still stereo pairs:
    ``info(side, i, stamp)`` and ``image(side, i, stamp)`` give each message's fields
    (None: DESIGN.md's CameraInfo, a 94x60 mono8 image), and return None to leave it
    out; with it a TUM odometry file of the still rover, ``out/odom.tum``."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    T = store.types
    out.mkdir(parents=True)

    def header(stamp, frame):
        return T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](
            sec=stamp // 10**9, nanosec=stamp % 10**9), frame_id=frame)

    with Writer(out / "rosbag", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}
        for side in ("left", "right"):
            conns[side, "image"] = writer.add_connection(
                f"/stereo/{side}/image_raw", "sensor_msgs/msg/Image", typestore=store)
            conns[side, "info"] = writer.add_connection(
                f"/stereo/{side}/camera_info", "sensor_msgs/msg/CameraInfo", typestore=store)
        for i in range(n):
            stamp = T0 + i * PERIOD
            for side in ("left", "right"):
                im = (image or (lambda s, i, t: {}))(side, i, stamp)
                if im is not None:
                    f = {"stamp": stamp, "width": W, "height": H, "encoding": "mono8",
                         **im}
                    pixels = np.random.default_rng(i).integers(
                        0, 256, (f["height"], f["width"]), np.uint8)
                    msg = T["sensor_msgs/msg/Image"](
                        header=header(f["stamp"], f"{side}_camera_optical"),
                        height=f["height"], width=f["width"], encoding=f["encoding"],
                        is_bigendian=0, step=f["width"], data=pixels.ravel())
                    writer.write(conns[side, "image"], stamp + 1000,
                                 store.serialize_cdr(msg, "sensor_msgs/msg/Image"))
                fields = (info or (lambda s, i, t: {}))(side, i, stamp)
                if fields is not None:
                    ci = _info(side, stamp, **fields)
                    msg = T["sensor_msgs/msg/CameraInfo"](
                        header=header(stamp, f"{side}_camera_optical"), height=ci.height,
                        width=ci.width, distortion_model=ci.distortion_model,
                        d=np.zeros(5), k=np.asarray(ci.k, float), r=np.eye(3).ravel(),
                        p=np.asarray(ci.p, float), binning_x=0, binning_y=0,
                        roi=T["sensor_msgs/msg/RegionOfInterest"](
                            x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
                    writer.write(conns[side, "info"], stamp + 2000,
                                 store.serialize_cdr(msg, "sensor_msgs/msg/CameraInfo"))
    (out / "rover.yaml").write_text(
        "/**:\n  ros__parameters:\n    base_to_left_camera: [0.4, 0.1, 1.2, 0.5792279653, "
        "-0.5792279653, 0.4055797877, -0.4055797877]\n")
    (out / "odom.tum").write_text("".join(
        f"{(T0 + i * PERIOD) * 1e-9 - 1:.9f} 0 0 0 0 0 0 1\n" for i in range(n + 20)))
    return out


def _frames(bag: Path, **kwargs):
    lines = []
    bad = BadInput(lines.append)
    frames = list(read_stereo_frames(bag, bad, log=lambda m: None, **kwargs))
    return [f.stamp_ns for f in frames], bad.counts, lines


STAMPS = [T0 + i * PERIOD for i in range(12)]


def test_the_bag_reader_skips_each_bad_message_and_reads_the_rest(tmp_path):
    good = write_bag(tmp_path / "good")
    stamps, counts, lines = _frames(good)
    assert stamps == STAMPS and not counts and not lines
    # One left CameraInfo with fx = 0: that message skipped; every pair read.
    bag = write_bag(tmp_path / "one_fx0", info=lambda s, i, t: (
        {"fx": 0.0} if (s, i) == ("left", 7) else {}))
    stamps, counts, lines = _frames(bag)
    assert stamps == STAMPS and dict(counts) == {"bad camera_info": 1}
    assert lines[0].startswith("bad camera_info: /stereo/left/camera_info at "
                               "1403715273.700 s: K[0] (fx) = 0")
    # fx = 0 in every left CameraInfo: no pair read, each counted, the reason named once.
    bag = write_bag(tmp_path / "all_fx0", info=lambda s, i, t: {"fx": 0.0} if s == "left"
                    else {})
    stamps, counts, lines = _frames(bag)
    assert stamps == [] and dict(counts) == {"bad camera_info": 12, "no camera_info": 12}
    assert len(lines) == 2 and "K[0] (fx) = 0" in lines[0]
    assert ("no camera_info: stereo pair at 1403715273.000 s: no usable CameraInfo on "
            "/stereo/left/camera_info (") in lines[1]
    # Right images 80x60 beside the left's 94x60 (the right CameraInfo says so too):
    # every pair skipped, the right image named.
    bag = write_bag(tmp_path / "sizes", image=lambda s, i, t: (
        {"width": 80} if s == "right" else {}), info=lambda s, i, t: (
        {"width": 80} if s == "right" else {}))
    stamps, counts, lines = _frames(bag)
    assert stamps == [] and dict(counts) == {"image size mismatch": 12}
    assert lines == ["image size mismatch: /stereo/right/image_raw at 1403715273.000 s: "
                     "80x60 beside the left image's 94x60 (skipped; further 'image size "
                     "mismatch' counted, not logged)"]
    # Two right images of 80x60 whose CameraInfo says 94x60: those two pairs skipped.
    bag = write_bag(tmp_path / "sizes_info", image=lambda s, i, t: (
        {"width": 80} if s == "right" and i in (3, 4) else {}))
    stamps, counts, lines = _frames(bag)
    assert stamps == STAMPS[:3] + STAMPS[5:] and dict(counts) == {"image size mismatch": 2}
    assert "/stereo/right/image_raw at 1403715273.300 s: 80x60, its " \
           "/stereo/right/camera_info says 94x60" in lines[0]
    # An image of a third encoding, and one stamped before the image before it.
    bag = write_bag(tmp_path / "encoding_and_order", image=lambda s, i, t: (
        {"encoding": "yuv422"} if (s, i) == ("left", 2) else
        {"stamp": t - 3 * PERIOD // 2} if (s, i) == ("right", 6) else {}))
    stamps, counts, lines = _frames(bag)
    assert dict(counts) == {"unsupported image encoding": 1, "stamp out of order": 1,
                            "missing pair half": 1}
    assert stamps == [s for k, s in enumerate(STAMPS) if k not in (2, 6)]
    assert any(line.startswith("unsupported image encoding: /stereo/left/image_raw at "
                               "1403715273.200 s: encoding 'yuv422'") for line in lines)
    assert any(line.startswith("stamp out of order: /stereo/right/image_raw at "
                               "1403715273.450 s: stamped before the message before it "
                               "(1403715273.500 s)") for line in lines)


def test_roi_detector_ln_goes_on_past_one_bad_camera_info_and_says_when_none_is_usable(
        tmp_path, run_cli):
    bag = write_bag(tmp_path / "one", info=lambda s, i, t: (
        {"fx": 0.0} if (s, i) == ("left", 7) else {}))
    out = tmp_path / "one.geojson"
    r = run_cli("ln", bag, "--odometry", bag / "odom.tum", "--out", out, "--model", "none",
                "--min-pair-travel", "0")
    assert r.returncode == 0, r.stderr
    assert out.is_file() and "roi_detector ln: 12 stereo pairs" in r.stdout
    assert r.stdout.count("/stereo/left/camera_info at 1403715273.700 s: K[0] (fx) = 0") == 1
    assert "Traceback" not in r.stdout + r.stderr
    bag = write_bag(tmp_path / "all", info=lambda s, i, t: {"fx": 0.0} if s == "left" else {})
    out = tmp_path / "all.geojson"
    r = run_cli("ln", bag, "--odometry", bag / "odom.tum", "--out", out, "--model", "none",
                "--min-pair-travel", "0")
    assert r.returncode == 1 and not out.exists()
    assert "no stereo pair read (bad camera_info 12, no camera_info 12)" in r.stderr
    assert "/stereo/left/camera_info at 1403715273.000 s: K[0] (fx) = 0" in r.stdout


def _ros_info(side: str, stamp_ns: int, fx: float = FX):
    from sensor_msgs.msg import CameraInfo

    ci = _info(side, stamp_ns, fx)
    msg = CameraInfo(width=W, height=H, distortion_model="plumb_bob", d=[0.0] * 5,
                     k=[float(v) for v in ci.k], r=[float(v) for v in ci.r],
                     p=[float(v) for v in ci.p])
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    return msg


def _ros_image(stamp_ns: int, width: int = W, seed: int = 0):
    from sensor_msgs.msg import Image

    pixels = np.random.default_rng(seed).integers(0, 256, (H, width), np.uint8)
    msg = Image(height=H, width=width, encoding="mono8", step=width, data=pixels.tobytes())
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    return msg


def test_the_node_counts_each_bad_message_on_its_status_and_goes_on():
    """The roi_detector node's callbacks, fed in this process (no DDS): fx = 0 in every
    left CameraInfo reads no pair and /rois/status says so; a usable one then lets the
    pairs through; a right image of another size and an image stamped before the one
    before it are counted and named once."""
    import rclpy

    from roi_detector.detector_node import RoiDetectorNode

    rclpy.init(args=["--ros-args", "-p", "model_path:=none", "-p",
                     "base_to_left_camera:=[0.4, 0.1, 1.2, 0.5792279653, -0.5792279653, "
                     "0.4055797877, -0.4055797877]"])
    try:
        node = RoiDetectorNode()
        statuses, logs = [], []
        node.status_pub.publish = statuses.append
        node.bad._report = logs.append

        def status():
            return {kv.key: kv.value for kv in statuses[-1].status[0].values}

        def pair(k, right_width=W, left_stamp=None):
            t = T0 + k * PERIOD
            node.on_image("/stereo/left/image_raw", _ros_image(left_stamp or t, seed=k))
            node.on_image("/stereo/right/image_raw", _ros_image(t, right_width, seed=k + 1))
            node.on_info("left", _ros_info("left", t, fx=0.0 if k < 40 else FX))
            node.on_info("right", _ros_info("right", t))

        for k in range(40):
            pair(k)
        assert node.n_pairs == 0 and statuses
        s = status()
        assert s["pairs"] == "0" and int(s["skipped: no camera_info"]) >= 9
        assert int(s["skipped: bad camera_info"]) >= 30
        assert "no pair read (bad camera_info" in statuses[-1].status[0].message
        assert logs[0] == ("bad camera_info: /stereo/left/camera_info at 1403715273.000 s: "
                           "K[0] (fx) = 0 (skipped; further 'bad camera_info' counted, not "
                           "logged)")
        assert sum("K[0] (fx)" in line for line in logs) == 1
        # The calibration comes right: the pairs of the last 2 s and those after it wait
        # for their odometry, then are read (every one: no pair spacing here).
        from nav_msgs.msg import Odometry

        from roi_detector.inputs import PairSpacing

        node.spacing = PairSpacing(min_travel_m=0.0)
        for k in range(40, 44):
            pair(k)
        pair(44, right_width=80)  # the right image 80x60 beside the left's 94x60
        pair(45, left_stamp=T0 + 20 * PERIOD)  # stamped before the left image before it
        assert [w[2] for w in node.waiting] == [T0 + k * PERIOD for k in range(20, 45)]
        for k in range(50):
            o = Odometry()
            o.header.stamp.sec, o.header.stamp.nanosec = divmod(T0 + k * PERIOD, 10**9)
            o.pose.pose.orientation.w = 1.0
            node.on_odometry(o)
        assert node.n_pairs == 24 and not node.waiting
        s = status()
        assert s["pairs"] == "24" and s["skipped: image size mismatch"] == "1"
        assert s["skipped: stamp out of order"] == "1"
        said = [line.split(" (skipped")[0] for line in logs]
        assert ("stamp out of order: /stereo/left/image_raw at 1403715275.000 s: stamped "
                "before the message before it (1403715277.400 s)") in said
        # (its right CameraInfo, of the pair before, says 94x60)
        assert ("image size mismatch: /stereo/right/image_raw at 1403715277.400 s: 80x60, "
                "its /stereo/right/camera_info says 94x60") in said
        node.destroy_node()
    finally:
        rclpy.shutdown()
