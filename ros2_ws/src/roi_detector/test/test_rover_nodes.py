"""The roi_detector CLI and both nodes, each node in its own process, on a tiny bag.

The bag (atacama_sim preset ``tiny``, a 16 m drive through a dense rock field, so that a
rock stands in view long enough for the elevation map) is generated once per module;
the test driver
replays its stereo pairs over ROS 2 in lock-step with the node and publishes odometry
from the truth trajectory (re-expressed in odom), as rover_vo would.
"""

import functools
import json
import os
import shutil
import signal
import subprocess
import time
from pathlib import Path

import numpy as np
import pytest
import rclpy
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

from roi_detector.camera_poses import JOINT_WAIT_PAIRS
from roi_detector.inputs import PairSpacing
from roi_network.geojson import read_geojson
from roi_network.pointcloud import from_pointcloud2, to_pointcloud2
from roi_network.records import ROCK, empty_records
from roi_network.trajectory import pose_covariance_row

pytestmark = pytest.mark.ros

LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE,
                     durability=DurabilityPolicy.TRANSIENT_LOCAL)
RELIABLE = QoSProfile(depth=50, reliability=ReliabilityPolicy.RELIABLE)
BEST_EFFORT = QoSProfile(depth=20, reliability=ReliabilityPolicy.BEST_EFFORT)


@pytest.fixture(scope="module")
def tiny_bag(tmp_path_factory) -> Path:
    from atacama_sim.config import make_config
    from atacama_sim.generate import generate

    out = tmp_path_factory.mktemp("bags") / "tiny"
    generate(make_config("tiny", 1, {
        "rocks": {"major_per_km2": 6000.0, "cluster_sigma_m": 5.0},
        "route": {"length_m": 16.0, "roi_range_m": 6.0, "rois_target": (4, 10)}}),
        out, progress=False)
    return out


def _domain() -> int:
    """A ROS domain apart from the other packages' tests (40-99): 150-228 (Linux allows
    up to 232)."""
    return 150 + 2 * (os.getpid() % 39)


def _env(domain: int) -> dict[str, str]:
    env = dict(os.environ)
    env["ROS_DOMAIN_ID"] = str(domain)
    env["ROS_AUTOMATIC_DISCOVERY_RANGE"] = "LOCALHOST"
    env.pop("ROS_LOCALHOST_ONLY", None)
    env["PYTHONUNBUFFERED"] = "1"
    return env


def _start(args, domain, log: Path) -> subprocess.Popen:
    exe = shutil.which(args[0])
    assert exe, f"{args[0]} not on PATH (source env.sh)"
    return subprocess.Popen([exe, *args[1:]], env=_env(domain), stdout=log.open("w"),
                            stderr=subprocess.STDOUT)


def _driver(domain: int, name: str):
    """An rclpy context on ``domain`` with one node and its executor: ``(ctx, node, ex)``
    (the caller shuts the context down)."""
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node(name, context=ctx)
    ex = rclpy.executors.SingleThreadedExecutor(context=ctx)
    ex.add_node(node)
    return ctx, node, ex


def _spin_until(ex, proc: subprocess.Popen, log: Path, cond, timeout: float) -> bool:
    """Spin ``ex`` until ``cond()`` or ``timeout`` s; the node process ``proc`` must live
    (else its ``log`` is the failure)."""
    end = time.monotonic() + timeout
    while not cond() and time.monotonic() < end:
        assert proc.poll() is None, log.read_text()
        ex.spin_once(timeout_sec=0.05)
    return cond()


def _stop(proc: subprocess.Popen) -> None:
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


def test_cli_ln_and_eval_on_tiny(tiny_bag, tmp_path, run_cli):
    odom = tmp_path / "truth_odom.tum"
    # The installed console script once; the other commands in this process.
    r = subprocess.run([shutil.which("roi_detector"), "truth-odometry", str(tiny_bag),
                        "--out", str(odom)], capture_output=True, text=True, timeout=240)
    assert r.returncode == 0, r.stderr
    ln_path = tmp_path / "ln.geojson"
    # A 16 m drive: its rocks are in view in a few pairs only (min_obs 1).
    r = run_cli("ln", str(tiny_bag), "--odometry", str(odom), "--out", str(ln_path), "--model",
            "none", "--min-obs", "1")
    assert r.returncode == 0, r.stderr
    ln = read_geojson(ln_path)
    assert ln.frame_id == "odom" and len(ln) >= 1
    assert np.all(ln.records["cov_xx"] > 0) and np.all(ln.records["n_obs"] >= 1)
    r = run_cli("eval", str(ln_path), str(tiny_bag), "--json", str(tmp_path / "e.json"),
            "--plot", str(tmp_path / "e.png"))
    assert r.returncode == 0, r.stderr
    assert (tmp_path / "e.json").is_file() and (tmp_path / "e.png").stat().st_size > 1000
    report = json.loads((tmp_path / "e.json").read_text())
    assert report["per_class"]["rock"]["ln_nodes"] == int(
        (ln.records["label"] == ROCK).sum())
    assert "matcher" not in report  # detection metrics only
    # The odometry's own covariance beside it (as rover_vo and globloc run write it):
    # the nodes take it, in place of the drift model, and the file says so.
    poses = np.loadtxt(odom, comments="#", ndmin=2)
    cov = np.diag([9.0, 9.0, 1.0, 1e-3, 1e-3, 1e-3]).ravel()
    (tmp_path / "vo_covariance.txt").write_text("".join(
        pose_covariance_row(t, cov) + "\n" for t in poses[:, 0]))
    ln_cov = tmp_path / "ln_cov.geojson"
    r = run_cli("ln", str(tiny_bag), "--odometry", str(odom), "--out", str(ln_cov), "--model",
            "none", "--min-obs", "1")
    assert r.returncode == 0, r.stderr
    assert "vo_covariance.txt" in r.stdout
    with_cov = read_geojson(ln_cov).records
    assert len(with_cov) == len(ln.records)
    # 16 m at 1 %: the drift model gives the nodes centimetres; the file, 3 m.
    assert np.all(ln.records["cov_xx"] < 1.0) and np.all(with_cov["cov_xx"] > 1.0)
    # A covariance file that does not cover the odometry: a clear error, no LN.
    (tmp_path / "short_cov.txt").write_text(f"{poses[0, 0]:.9f} " + " ".join(
        f"{v:.6e}" for v in cov) + "\n")
    r = run_cli("ln", str(tiny_bag), "--odometry", str(odom), "--covariance",
            str(tmp_path / "short_cov.txt"), "--out", str(tmp_path / "y.geojson"),
            "--model", "none")
    assert r.returncode == 1 and "short_cov.txt: no covariance at odometry stamp" in r.stderr
    assert not (tmp_path / "y.geojson").exists()
    # Bad input: a clear one-line error, no output file.
    r = run_cli("ln", str(tiny_bag), "--odometry", str(tmp_path / "missing.tum"), "--out",
            str(tmp_path / "x.geojson"))
    assert r.returncode == 1 and "missing.tum" in r.stderr and "Traceback" not in r.stderr
    assert not (tmp_path / "x.geojson").exists()


def _bag_messages(bag: Path, deserialize: bool = False):
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    out: dict[str, list] = {}
    with AnyReader([bag / "rosbag"], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as r:
        conns = [c for c in r.connections
                 if c.topic.startswith("/stereo/") or c.topic == "/joint_states"]
        for conn, _t, raw in r.messages(connections=conns):
            out.setdefault(conn.topic, []).append(
                r.deserialize(raw, conn.msgtype) if deserialize else raw)
    return out


def test_roi_detector_and_ln_builder_nodes_on_tiny(tiny_bag, tmp_path):
    from nav_msgs.msg import Odometry
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import CameraInfo, CompressedImage, JointState, PointCloud2

    from roi_detector.truth import Truth

    domain = _domain()
    det = _start(["roi_detector", "--ros-args", "-p", "model_path:=none", "-p", "min_obs:=1",
                  "--params-file", str(tiny_bag / "rover.yaml")], domain,
                 tmp_path / "roi_detector.log")
    lnb = _start(["ln_builder", "--ros-args", "-p", f"ln_path:={tmp_path / 'ln.geojson'}",
                  "-p", "min_obs:=1"], domain, tmp_path / "ln_builder.log")
    ctx, node, ex = _driver(domain, "roi_test_driver")
    try:
        got = {"det": [], "tracks": [], "ln": [], "status": []}
        from diagnostic_msgs.msg import DiagnosticArray

        node.create_subscription(PointCloud2, "/rois/detections", got["det"].append, RELIABLE)
        node.create_subscription(PointCloud2, "/rois/tracks", got["tracks"].append, RELIABLE)
        node.create_subscription(PointCloud2, "/local_network", got["ln"].append, LATCHED)
        node.create_subscription(DiagnosticArray, "/rois/status", got["status"].append, 10)
        pubs = {t: node.create_publisher(CompressedImage if "image" in t else CameraInfo, t,
                                         BEST_EFFORT)
                for t in ("/stereo/left/image_raw/compressed",
                          "/stereo/right/image_raw/compressed",
                          "/stereo/left/camera_info", "/stereo/right/camera_info")}
        odom_pub = node.create_publisher(Odometry, "/vo/odometry", RELIABLE)
        joint_pub = node.create_publisher(JointState, "/joint_states", BEST_EFFORT)

        spin_until = functools.partial(_spin_until, ex, det, tmp_path / "roi_detector.log")

        assert spin_until(lambda: all(p.get_subscription_count() > 0 for p in pubs.values())
                          and odom_pub.get_subscription_count() > 0, 30)
        # Our writers see the node's readers before its readers have matched our writers:
        # best-effort samples sent in between are lost (CI once got no pair at all).
        spin_until(lambda: False, 2.0)
        msgs = _bag_messages(tiny_bag)
        lefts = [deserialize_message(bytes(r), CompressedImage)
                 for r in msgs["/stereo/left/image_raw/compressed"]]
        rights = [deserialize_message(bytes(r), CompressedImage)
                  for r in msgs["/stereo/right/image_raw/compressed"]]
        linfo = deserialize_message(bytes(msgs["/stereo/left/camera_info"][0]), CameraInfo)
        rinfo = deserialize_message(bytes(msgs["/stereo/right/camera_info"][0]), CameraInfo)
        # A bag with a mast records the joint angles at every pair's stamp (rover.yaml
        # then has the mast, and the node places each pair with them).
        joints = {(m.header.stamp.sec, m.header.stamp.nanosec): m for m in (
            deserialize_message(bytes(r), JointState) for r in msgs.get("/joint_states", []))}
        odom = Truth.load(tiny_bag).odom_track()
        def last_status():
            if not got["status"]:
                return {}
            return {kv.key: kv.value for kv in got["status"][-1].status[0].values}

        gap = set(range(24, 28))  # no odometry for these pairs (12 s): an odometry gap
        expected = 0
        # The node's pair spacing, replayed: which of the pairs with a pose it reads (the
        # drive's, 0.45 m apart, all; a standstill's, a few seconds apart, one per 5 s).
        spacing = PairSpacing()
        for k, (lm, rm) in enumerate(zip(lefts, rights, strict=True)):
            t = lm.header.stamp.sec + 1e-9 * lm.header.stamp.nanosec
            read = k not in gap and k != 8 and spacing.keep(t, odom.at(t))
            if k not in gap:
                r_ob, p_ob, _ = odom.at(t)
                from scipy.spatial.transform import Rotation

                o = Odometry()
                o.header.stamp = lm.header.stamp
                o.header.frame_id, o.child_frame_id = "odom", "base_link"
                o.pose.pose.position.x, o.pose.pose.position.y, o.pose.pose.position.z = p_ob
                q = Rotation.from_matrix(r_ob).as_quat()
                oo = o.pose.pose.orientation
                oo.x, oo.y, oo.z, oo.w = q
                o.pose.covariance = list(np.diag([1e-4, 1e-4, 1e-4, 1e-5, 1e-5, 1e-5]).ravel())
                odom_pub.publish(o)
            for p, info in ((pubs["/stereo/left/camera_info"], linfo),
                            (pubs["/stereo/right/camera_info"], rinfo)):
                info.header.stamp = lm.header.stamp
                p.publish(info)
            js = joints.get((lm.header.stamp.sec, lm.header.stamp.nanosec))
            if js is not None:
                joint_pub.publish(js)
            if k == 5:  # an undecodable image: counted, skipped
                lm.data = b"\x00" * 100
            if k == 8:  # a missing pair half: the right image only, never completed
                pubs["/stereo/right/image_raw/compressed"].publish(rm)
                continue
            pubs["/stereo/left/image_raw/compressed"].publish(lm)
            pubs["/stereo/right/image_raw/compressed"].publish(rm)
            if k == 5:
                # Best-effort images may be dropped on a loaded machine: the corrupt pair
                # is re-sent only if its count has not come back after 10 s, so the
                # node's count of it must be exactly 1 below.
                for _ in range(3):
                    if spin_until(lambda: "skipped: undecodable image" in last_status(), 10):
                        break
                    pubs["/stereo/left/image_raw/compressed"].publish(lm)
                    pubs["/stereo/right/image_raw/compressed"].publish(rm)
            if k != 5 and read:  # a pair is published once its pose is known
                expected += 1
            if k in gap or not read:  # no detection comes back: pace the images instead
                spin_until(lambda: False, 1.0)
            assert spin_until(lambda e=expected: len(got["det"]) >= e, 60), \
                (tmp_path / "roi_detector.log").read_text()
        assert spin_until(lambda: got["ln"] and got["tracks"], 60), (
            [(kv.key, kv.value) for kv in got["status"][-1].status[0].values],
            (tmp_path / "roi_detector.log").read_text())
        spin_until(lambda: False, 1.0)
        assert len(got["det"]) == expected
        assert all(m.header.frame_id == "base_link" for m in got["det"])
        assert all(m.header.frame_id == "odom" for m in got["tracks"])
        # /rois/detections holds the ROIs in each pair's view (records_in_view, tested on
        # its own); the drive's ROIs are on /rois/tracks.
        assert sum(len(from_pointcloud2(m)) for m in got["tracks"]) > 0
        ln = from_pointcloud2(got["ln"][-1])
        assert len(ln) >= 1 and np.all(ln["n_obs"] >= 1)
        assert spin_until(lambda: "skipped: odometry gap" in last_status(), 30), last_status()
        status = last_status()
        assert int(status["skipped: undecodable image"]) == 1
        assert int(status["skipped: odometry gap"]) >= 1
        assert status["pairs_spaced_out"] == str(spacing.skipped)
        assert det.poll() is None and lnb.poll() is None
        # The LN is on disk; a killed ln_builder restarts with it.
        saved = read_geojson(tmp_path / "ln.geojson")
        assert len(saved) == len(ln)
        lnb.send_signal(signal.SIGKILL)
        lnb.wait(timeout=10)
        got["ln"].clear()
        lnb = _start(["ln_builder", "--ros-args", "-p",
                      f"ln_path:={tmp_path / 'ln.geojson'}", "-p", "min_obs:=1"], domain,
                     tmp_path / "ln_builder2.log")
        late = rclpy.create_node("late_listener", context=ctx)
        ex.add_node(late)
        late.create_subscription(PointCloud2, "/local_network", got["ln"].append, LATCHED)
        assert spin_until(lambda: got["ln"], 20), (tmp_path / "ln_builder2.log").read_text()
        again = from_pointcloud2(got["ln"][-1])
        np.testing.assert_array_equal(np.sort(again["id"]), np.sort(ln["id"]))
        log = (tmp_path / "roi_detector.log").read_text()
        assert sum("undecodable image" in line for line in log.splitlines()) == 1
        assert "Traceback" not in log
    finally:
        rclpy.shutdown(context=ctx)
        _stop(det)
        _stop(lnb)


def test_ln_builder_corrupt_saved_ln(tmp_path):
    from sensor_msgs.msg import PointCloud2

    path = tmp_path / "ln.geojson"
    path.write_text("{ not json")
    domain = _domain() + 1
    proc = _start(["ln_builder", "--ros-args", "-p", f"ln_path:={path}"], domain,
                  tmp_path / "ln_builder.log")
    ctx, node, ex = _driver(domain, "ln_test_driver")
    try:
        got = []
        node.create_subscription(PointCloud2, "/local_network", got.append, LATCHED)
        pub = node.create_publisher(PointCloud2, "/rois/tracks", RELIABLE)
        end = time.monotonic() + 20
        while pub.get_subscription_count() == 0 and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        tracks = empty_records(3)
        tracks["id"] = [1, 2, 3]
        tracks["x"] = [0.0, 10.0, 20.0]
        tracks["label"] = ROCK
        tracks["n_obs"] = [3, 3, 1]
        tracks["cov_xx"] = tracks["cov_yy"] = 0.04
        pub.publish(to_pointcloud2(tracks, "odom"))
        bad = to_pointcloud2(tracks, "map")  # wrong frame: skipped, node lives
        pub.publish(bad)
        end = time.monotonic() + 20
        while not got and time.monotonic() < end:
            ex.spin_once(timeout_sec=0.05)
        assert got and len(from_pointcloud2(got[-1])) == 2
        assert proc.poll() is None
        assert len(list(tmp_path.glob("ln.geojson.corrupt-*"))) == 1
        assert len(read_geojson(path)) == 2
    finally:
        rclpy.shutdown(context=ctx)
        _stop(proc)
    log = (tmp_path / "ln_builder.log").read_text()
    assert "kept aside" in log and "Traceback" not in log


def test_roi_detector_refuses_an_unknown_method(tiny_bag, tmp_path):
    """A parameter value the node does not know stops it at start with a one-line error
    that names the parameter and the values it takes."""
    proc = _start(["roi_detector", "--ros-args", "-p", "model_path:=none",
                   "-p", "method:=smoothed", "--params-file", str(tiny_bag / "rover.yaml")],
                  _domain() + 2, tmp_path / "roi_detector.log")
    try:
        proc.wait(timeout=60)
    finally:
        _stop(proc)
    log = (tmp_path / "roi_detector.log").read_text()
    assert proc.returncode != 0
    assert "parameter 'method'" in log and "per_pair" in log and "Traceback" not in log


def test_cli_ln_reads_raw_images_alike(tiny_bag, tmp_path, run_cli):
    """A bag with raw sensor_msgs/Image stereo pairs (a field bag's usual transport) gives
    the LN its compressed twin gives: the same pixels, the same nodes."""
    from roi_network.testing import write_raw_image_copy, write_stamp_offset_copy

    raw_bag = write_raw_image_copy(tiny_bag, tmp_path / "raw")
    odom = tmp_path / "truth_odom.tum"
    assert run_cli("truth-odometry", str(tiny_bag), "--out", str(odom)).returncode == 0
    lns = []
    for bag in (tiny_bag, raw_bag):
        out = tmp_path / f"{bag.name}.geojson"
        r = run_cli("ln", str(bag), "--odometry", str(odom), "--out", str(out), "--model", "none",
                "--min-obs", "1")
        assert r.returncode == 0, r.stderr
        lns.append(read_geojson(out).records)
    assert len(lns[0]) >= 1
    np.testing.assert_array_equal(lns[0], lns[1])
    # Right images stamped 3 ms after their left ones (two drivers): the same LN; with
    # exact stamps only, every pair is counted as a lone half, with its partner's offset.
    apart = write_stamp_offset_copy(tiny_bag, tmp_path / "apart", 0.003)
    r = run_cli("ln", str(apart), "--odometry", str(odom), "--out", str(tmp_path / "a.geojson"),
            "--model", "none", "--min-obs", "1")
    assert r.returncode == 0, r.stderr
    np.testing.assert_array_equal(read_geojson(tmp_path / "a.geojson").records, lns[0])
    r = run_cli("ln", str(apart), "--odometry", str(odom), "--out", str(tmp_path / "e.geojson"),
            "--model", "none", "--min-obs", "1", "--stereo-sync-tolerance", "0")
    assert r.returncode == 1
    assert "the nearest right image is 3.0 ms from it" in r.stdout + r.stderr
    assert "no stereo pair read (missing pair half " in r.stderr
    assert not (tmp_path / "e.geojson").exists()
    # A distorting lens with D in its CameraInfo: rectified by default, and said so once
    # per side; --no-rectify reads the images as they come.
    distorted = write_raw_image_copy(tiny_bag, tmp_path / "distorted",
                                     distortion=(-0.28, 0.09, 0.0, 0.0, 0.0))
    for flags, said in (((), 2), (("--no-rectify",), 0)):
        r = run_cli("ln", str(distorted), "--odometry", str(odom), "--out",
                str(tmp_path / "d.geojson"), "--model", "none", "--min-obs", "1", *flags)
        assert r.returncode == 0, r.stderr
        assert (r.stdout + r.stderr).count("images are rectified to its P") == said


def test_roi_detector_node_reads_raw_images(tiny_bag, tmp_path):
    """The node takes raw sensor_msgs/Image pairs as it takes the contract's compressed
    ones; from a bag that carries both it reads the first transport that delivers, once.
    The pairs come from ``globloc play`` (whose Fast DDS profile keeps 0.9 MB images in
    shared memory), the odometry from the truth, all of it before the first pair."""
    from nav_msgs.msg import Odometry
    from scipy.spatial.transform import Rotation
    from sensor_msgs.msg import PointCloud2

    from roi_detector.truth import Truth
    from roi_network.testing import write_raw_image_copy

    both = write_raw_image_copy(tiny_bag, tmp_path / "both", keep_compressed=True)
    recorded = _bag_messages(tiny_bag, deserialize=True)
    stamps = sorted({int(m.header.stamp.sec) * 10**9 + int(m.header.stamp.nanosec)
                     for m in recorded["/stereo/left/image_raw/compressed"]})
    has_joints = "/joint_states" in recorded  # a mast's angles, played with the pairs
    odom = Truth.load(tiny_bag).odom_track()
    spacing = PairSpacing()  # the pairs the node reads (a standstill's: one per 5 s)
    read = [s for s in stamps if spacing.keep(s * 1e-9, odom.at(s * 1e-9))]
    domain = _domain() + 3
    det = _start(["roi_detector", "--ros-args", "-p", "model_path:=none",
                  "--params-file", str(tiny_bag / "rover.yaml")], domain,
                 tmp_path / "roi_detector.log")
    ctx, node, ex = _driver(domain, "roi_raw_driver")
    player = None
    try:
        got = []
        node.create_subscription(PointCloud2, "/rois/detections", got.append, RELIABLE)
        odom_pub = node.create_publisher(
            Odometry, "/vo/odometry", QoSProfile(depth=500,
                                                 reliability=ReliabilityPolicy.RELIABLE))

        spin_until = functools.partial(_spin_until, ex, det, tmp_path / "roi_detector.log")

        assert spin_until(lambda: odom_pub.get_subscription_count() > 0, 30)
        for t_ns in stamps:
            r_ob, p_ob, _ = odom.at(t_ns * 1e-9)
            o = Odometry()
            o.header.stamp.sec, o.header.stamp.nanosec = divmod(t_ns, 10**9)
            o.header.frame_id, o.child_frame_id = "odom", "base_link"
            o.pose.pose.position.x, o.pose.pose.position.y, o.pose.pose.position.z = p_ob
            oo = o.pose.pose.orientation
            oo.x, oo.y, oo.z, oo.w = Rotation.from_matrix(r_ob).as_quat()
            o.pose.covariance = list(np.diag([1e-4] * 3 + [1e-5] * 3).ravel())
            odom_pub.publish(o)
        spin_until(lambda: False, 1.0)
        player = subprocess.Popen(
            [shutil.which("globloc"), "play", str(both), "--rate", "2",
             "--wait-subscribers", "30", "--topics", "/stereo/left/image_raw",
             "/stereo/right/image_raw", "/stereo/left/image_raw/compressed",
             "/stereo/right/image_raw/compressed", "/stereo/left/camera_info",
             "/stereo/right/camera_info", *(["/joint_states"] if has_joints else [])],
            env=_env(domain), stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True)
        assert spin_until(lambda: len(got) >= len(read) or player.poll() is not None, 240)
        spin_until(lambda: len(got) >= len(read), 30)
        assert player.wait(timeout=60) == 0, player.stdout.read()
        assert [m.header.stamp.sec * 10**9 + m.header.stamp.nanosec for m in got] == read
        assert det.poll() is None
    finally:
        if player is not None and player.poll() is None:
            player.send_signal(signal.SIGINT)
            player.wait(timeout=10)
        rclpy.shutdown(context=ctx)
        _stop(det)
    log = (tmp_path / "roi_detector.log").read_text()
    assert "images arrive in both transports; reading the " in log
    assert "missing pair half" not in log and "undecodable" not in log
    assert "Traceback" not in log


def test_count_ln_counts_the_truth(tiny_bag):
    """count_ln (what `roi_detector eval` counts): the truth
    catalogue placed in odom finds every counted ROI at full precision; one counted rock
    left out and a node on no ROI lower the recall and the precision by one each."""
    from roi_detector.evaluation import count_ln, counted_rois
    from roi_detector.truth import Truth

    truth = Truth.load(tiny_bag)
    wanted, in_view = counted_rois(truth, tiny_bag)
    rocks = np.flatnonzero(wanted & (truth.rois["label"] == ROCK))
    assert len(rocks) >= 2, "the tiny bag's route passes too few rocks for this test"
    odom = truth.rois.copy()
    pos = np.column_stack([odom["x"], odom["y"], odom["z"]]) - truth.trajectory.p[0]
    odom["x"], odom["y"], odom["z"] = truth._odom_in_map().inv().apply(pos).T
    full = count_ln(odom, truth, wanted, in_view)["per_class"]["rock"]
    assert full["truth_found"] == full["truth_wanted"] == len(rocks)
    assert full["true_nodes"] == full["ln_nodes"] and full["precision"] == 1.0
    stray = odom[rocks[:1]].copy()
    stray["x"] += 1e4
    fewer = np.concatenate([np.delete(odom, rocks[0]), stray])
    part = count_ln(fewer, truth, wanted, in_view)["per_class"]["rock"]
    assert part["truth_found"] == len(rocks) - 1
    assert part["ln_nodes"] == full["ln_nodes"] and part["true_nodes"] == full["ln_nodes"] - 1


def _mast_copy(bag: Path, out: Path, joints=None, mast: bool = True) -> Path:
    """A copy of bag directory ``bag`` with a rover.yaml that has the simulator's mast
    (``mast``; else none) and, when ``joints`` is given, the /joint_states messages
    ``joints(stamp_ns)`` (a list of ``(stamp_ns, names, positions)``) before each stereo
    pair's images; the bag's own /joint_states left out."""
    import yaml
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    from roi_network.params import flatten

    out.mkdir(parents=True)
    for item in bag.iterdir():
        if item.is_file() and item.name != "rover.yaml":
            shutil.copy2(item, out / item.name)
    doc = yaml.safe_load((bag / "rover.yaml").read_text())
    params = flatten(next(v["ros__parameters"] for v in doc.values() if "ros__parameters" in v))
    params = {k: v for k, v in params.items() if not k.startswith("mast.")}
    if mast:
        from scipy.spatial.transform import Rotation

        optical = Rotation.from_matrix(np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]],
                                                float)).as_quat()
        params["mast"] = {
            "pan_joint": "mast_pan", "pan_origin": [0.4, 0.0, 1.3, 0.0, 0.0, 0.0, 1.0],
            "pan_axis": [0.0, 0.0, 1.0], "pan_limits": [-3.14159, 3.14159],
            "tilt_joint": "mast_tilt", "tilt_origin": [0.0, 0.0, 0.24, 0.0, 0.0, 0.0, 1.0],
            "tilt_axis": [0.0, 1.0, 0.0], "tilt_limits": [-0.5, 1.2],
            "head_to_left_camera": [0.0, 0.1, 0.0, *map(float, optical)]}
    (out / "rover.yaml").write_text(yaml.safe_dump({"/**": {"ros__parameters": params}}))
    store = get_typestore(Stores.ROS2_JAZZY)
    T = store.types
    with AnyReader([bag / "rosbag"], default_typestore=store) as reader, \
            Writer(out / "rosbag", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {c.id: writer.add_connection(c.topic, c.msgtype, typestore=store)
                 for c in reader.connections if c.topic != "/joint_states"}
        js = writer.add_connection("/joint_states", "sensor_msgs/msg/JointState",
                                   typestore=store) if joints is not None else None
        done = set()
        for conn, t_ns, data in reader.messages():
            if conn.id not in conns:
                continue
            if js is not None and conn.topic.startswith("/stereo/") and "image" in conn.topic:
                msg = reader.deserialize(data, conn.msgtype)
                stamp = msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec
                if stamp not in done:
                    done.add(stamp)
                    for s, names, pos in joints(stamp):
                        m = T["sensor_msgs/msg/JointState"](
                            header=T["std_msgs/msg/Header"](
                                stamp=T["builtin_interfaces/msg/Time"](
                                    sec=s // 10**9, nanosec=s % 10**9), frame_id=""),
                            name=list(names), position=np.asarray(pos, float),
                            velocity=np.zeros(0), effort=np.zeros(0))
                        writer.write(js, t_ns - 1000, store.serialize_cdr(
                            m, "sensor_msgs/msg/JointState"))
            writer.write(conns[conn.id], t_ns, data)
    return out


DRIVE = ["mast_pan", "mast_tilt"], [0.0, float(np.radians(20.0))]


def test_cli_ln_places_each_pair_by_the_joint_states_and_counts_what_it_cannot(
        tiny_bag, tmp_path, run_cli):
    """``roi_detector ln`` on a mast's bag: a mast held at the drive pose gives the fixed
    camera's LN; pairs with no joint state (none at all, too far in time, a mast that
    stopped publishing) are not placed, counted and named once; joint names the mast does
    not have are an error naming them."""
    odom = tmp_path / "truth_odom.tum"
    assert run_cli("truth-odometry", str(tiny_bag), "--out", str(odom)).returncode == 0

    def ln(bag, name):
        out = tmp_path / f"{name}.geojson"
        r = run_cli("ln", str(bag), "--odometry", str(odom), "--out", str(out), "--model",
                "none", "--min-obs", "1")
        return r, (read_geojson(out) if out.exists() else None)

    fixed, lnf = ln(_mast_copy(tiny_bag, tmp_path / "fixed", mast=False), "fixed")
    assert fixed.returncode == 0, fixed.stderr
    assert len(lnf) >= 1 and "not placed" not in fixed.stdout
    held, lnh = ln(_mast_copy(tiny_bag, tmp_path / "held", lambda s: [(s, *DRIVE)]), "held")
    assert held.returncode == 0, held.stderr
    a, b = lnf.records, lnh.records
    assert len(a) == len(b)
    np.testing.assert_allclose(np.column_stack([b["x"], b["y"]]),
                               np.column_stack([a["x"], a["y"]]), atol=1e-6)
    assert lnh.metadata["joint_states"] > 0 and lnh.metadata["pairs_not_placed"] == 0
    # No /joint_states at all: no pair placed, the run fails naming the topic once.
    r, _ = ln(_mast_copy(tiny_bag, tmp_path / "none", None), "none")
    assert r.returncode == 1 and "no stereo pair read (no joint states " in r.stderr
    assert (r.stdout + r.stderr).count("/joint_states") == 1
    # Joint samples 0.3 s from every pair: further than the tolerance.
    r, _ = ln(_mast_copy(tiny_bag, tmp_path / "late",
                         lambda s: [(s + 300_000_000, *DRIVE)]), "late")
    assert r.returncode == 1 and "stale joint states" in r.stderr
    # The mast stops publishing half way: the first half placed, the rest counted.
    stamps = sorted(int(s) for s in np.loadtxt(odom, comments="#", ndmin=2)[:, 0] * 1e9)
    half = stamps[len(stamps) // 2]
    r, lns = ln(_mast_copy(tiny_bag, tmp_path / "stops",
                           lambda s: [(s, *DRIVE)] if s < half else []), "stops")
    assert r.returncode == 0, r.stderr
    assert (r.stdout + r.stderr).count("stopped publishing") == 1
    stopped = lns.metadata["bad_input"]["joint states stopped"]
    assert stopped >= 1 and lns.metadata["pairs_not_placed"] == stopped
    assert f"{stopped} not placed" in r.stdout
    assert lns.metadata["pairs"] + lns.metadata["pairs_spaced_out"] + stopped == \
        lnf.metadata["pairs"] + lnf.metadata["pairs_spaced_out"]
    # Joint names the mast does not have: an error naming them, no LN.
    r, bad = ln(_mast_copy(tiny_bag, tmp_path / "names",
                           lambda s: [(s, ["pan", "tilt"], DRIVE[1])]), "names")
    assert r.returncode == 1 and bad is None
    assert "'mast_pan'" in r.stderr and "'pan', 'tilt'" in r.stderr


def test_roi_detector_node_places_pairs_by_the_joint_states_and_counts_bad_ones(
        tiny_bag, tmp_path):
    """The node on a mast's rover.yaml: pairs before any /joint_states are not placed
    (counted, the topic named once in the log); a message with joint names the mast does
    not have is logged once and dropped; pairs with their joint states are placed and
    published; when the mast stops publishing, the pairs are skipped and it is said once."""
    from nav_msgs.msg import Odometry
    from rclpy.serialization import deserialize_message
    from scipy.spatial.transform import Rotation
    from sensor_msgs.msg import CameraInfo, CompressedImage, JointState, PointCloud2

    from roi_detector.truth import Truth

    mast_bag = _mast_copy(tiny_bag, tmp_path / "mast_bag", None)
    domain = _domain() + 4
    det = _start(["roi_detector", "--ros-args", "-p", "model_path:=none",
                  "--params-file", str(mast_bag / "rover.yaml")], domain,
                 tmp_path / "roi_detector.log")
    ctx, node, ex = _driver(domain, "roi_mast_driver")
    try:
        from diagnostic_msgs.msg import DiagnosticArray

        got, status = [], []
        node.create_subscription(PointCloud2, "/rois/detections", got.append, RELIABLE)
        node.create_subscription(DiagnosticArray, "/rois/status", status.append, 10)
        pubs = {t: node.create_publisher(CompressedImage if "image" in t else CameraInfo, t,
                                         BEST_EFFORT)
                for t in ("/stereo/left/image_raw/compressed",
                          "/stereo/right/image_raw/compressed",
                          "/stereo/left/camera_info", "/stereo/right/camera_info")}
        odom_pub = node.create_publisher(Odometry, "/vo/odometry", RELIABLE)
        joint_pub = node.create_publisher(JointState, "/joint_states", RELIABLE)
        spin_until = functools.partial(_spin_until, ex, det, tmp_path / "roi_detector.log")
        assert spin_until(lambda: all(p.get_subscription_count() > 0 for p in pubs.values())
                          and joint_pub.get_subscription_count() > 0, 30)
        spin_until(lambda: False, 2.0)
        msgs = _bag_messages(tiny_bag)
        lefts = [deserialize_message(bytes(r), CompressedImage)
                 for r in msgs["/stereo/left/image_raw/compressed"]][:14]
        rights = [deserialize_message(bytes(r), CompressedImage)
                  for r in msgs["/stereo/right/image_raw/compressed"]][:14]
        linfo = deserialize_message(bytes(msgs["/stereo/left/camera_info"][0]), CameraInfo)
        rinfo = deserialize_message(bytes(msgs["/stereo/right/camera_info"][0]), CameraInfo)
        odom = Truth.load(tiny_bag).odom_track()

        def last_status():
            return {kv.key: kv.value for kv in status[-1].status[0].values} if status else {}

        def odometry(stamp, t):
            r_ob, p_ob, _ = odom.at(min(t, odom.t[-1]))
            o = Odometry()
            o.header.stamp = stamp
            o.header.frame_id, o.child_frame_id = "odom", "base_link"
            o.pose.pose.position.x, o.pose.pose.position.y, o.pose.pose.position.z = p_ob
            oo = o.pose.pose.orientation
            oo.x, oo.y, oo.z, oo.w = Rotation.from_matrix(r_ob).as_quat()
            o.pose.covariance = list(np.diag([1e-4] * 3 + [1e-5] * 3).ravel())
            return o

        def joints(stamp, names=("mast_pan", "mast_tilt")):
            m = JointState()
            m.header.stamp = stamp
            m.name = list(names)
            m.position = list(DRIVE[1])
            return m

        placed = range(3, 10)  # joint states for these pairs; none before, none after
        for k, (lm, rm) in enumerate(zip(lefts, rights, strict=True)):
            t = lm.header.stamp.sec + 1e-9 * lm.header.stamp.nanosec
            odom_pub.publish(odometry(lm.header.stamp, t))
            if k == placed[0]:
                joint_pub.publish(joints(lm.header.stamp, ("pan", "tilt")))
            if k in placed:
                joint_pub.publish(joints(lm.header.stamp))
            for p, info in ((pubs["/stereo/left/camera_info"], linfo),
                            (pubs["/stereo/right/camera_info"], rinfo)):
                info.header.stamp = lm.header.stamp
                p.publish(info)
            pubs["/stereo/left/image_raw/compressed"].publish(lm)
            pubs["/stereo/right/image_raw/compressed"].publish(rm)
            if k in placed:
                assert spin_until(lambda n=k - placed[0] + 1: len(got) >= n, 60), \
                    (tmp_path / "roi_detector.log").read_text()
            else:
                spin_until(lambda: False, 1.0)
        # The pairs after the last joint state are given up once two newer pairs came
        # with no joint message: all but the last two (they wait for a pair to come).
        assert spin_until(lambda: int(last_status().get("skipped: joint states stopped", 0))
                          == 14 - placed[-1] - 1 - JOINT_WAIT_PAIRS, 30), last_status()
        s = last_status()
        assert len(got) == len(placed)
        assert int(s["skipped: no joint states"]) == placed[0]
        assert int(s["skipped: bad joint states"]) == 1
        assert int(s["joint_states"]) == len(placed)
        assert det.poll() is None
    finally:
        rclpy.shutdown(context=ctx)
        _stop(det)
    log = (tmp_path / "roi_detector.log").read_text()
    assert log.count("no /joint_states message has come") == 1
    assert log.count("'pan', 'tilt'") == 1 and log.count("stopped publishing") == 1
    assert "Traceback" not in log
