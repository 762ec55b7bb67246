"""The rover_vo node in its own process on the tiny bag (played by ``globloc play``), and
the offline CLI agreeing with it."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import time

import numpy as np
import pytest
import rclpy
import vo_flatworld as fw
from diagnostic_msgs.msg import DiagnosticArray
from nav_msgs.msg import Odometry
from rclpy.qos import QoSProfile, ReliabilityPolicy

from roi_network.testing import write_raw_image_copy
from roi_network.trajectory import read_tum_rows
from rover_vo import messages as m
from rover_vo.bag import read_messages, rover_params
from rover_vo.testing import run

pytestmark = pytest.mark.ros
RELIABLE = QoSProfile(depth=200, reliability=ReliabilityPolicy.RELIABLE)


def _exe(name):
    exe = shutil.which(name)
    assert exe, f"{name} not on PATH (make setup; source env.sh)"
    return exe


def _played(topics, messages):
    """The topics to play: the VO's inputs, with /joint_states and /sun_sensor when the
    bag has them."""
    present = {t for t, _ in messages}
    return (*topics, *(t for t in (m.TOPIC_JOINT_STATES, m.TOPIC_SUN) if t in present))


@pytest.fixture(params=["compressed", "raw", "panorama"])
def bag_and_run(request, tiny_bag, clean_run, tiny_messages, tiny_params, tmp_path_factory):
    """The tiny bag with the contract's compressed images, a copy with raw
    sensor_msgs/Image through a distorting lens, D in its CameraInfo (what a camera
    driver records), and the flat world's stop with a mast panorama, each with its
    offline run, the topics to play and the rate."""
    if request.param == "compressed":
        return tiny_bag, clean_run, _played(m.INPUT_TOPICS, tiny_messages), 2
    if request.param == "panorama":
        bag = fw.write_bag(fw.stream(fw.panorama_schedule(period_s=2.0, drive=3, stand=1)),
                           tmp_path_factory.mktemp("pano") / "flat_pano")
        messages = list(read_messages(bag))
        return bag, run(messages, rover_params(bag)), _played(m.INPUT_TOPICS, messages), 4
    raw = write_raw_image_copy(tiny_bag, tmp_path_factory.mktemp("raw") / "tiny_raw",
                               distortion=(-0.28, 0.09, 0.0, 0.0, 0.0))
    messages = list(read_messages(raw))
    return raw, run(messages, tiny_params), _played(m.input_topics("raw"), messages), 2


def _stop(player, node, ctx) -> None:
    """Stop the player (if it still plays) and the node with SIGINT, and the test's rclpy
    context."""
    if player is not None and player.poll() is None:
        player.send_signal(signal.SIGINT)
        player.wait(timeout=10)
    node.send_signal(signal.SIGINT)
    node.wait(timeout=15)
    rclpy.try_shutdown(context=ctx)


def test_node_on_tiny_bag_agrees_with_offline(bag_and_run, ros_env, tmp_path):
    tiny_bag, (est, offline, _), topics, rate = bag_and_run
    offline_status = {k: str(v) for k, v in est.status().items() if k.startswith("bad_input.")}
    node = subprocess.Popen([_exe("rover_vo"), "--ros-args", "--params-file",
                             str(tiny_bag / "rover.yaml")],
                            env=ros_env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    player = None
    try:
        sub_node = rclpy.create_node("vo_test_listener", context=ctx)
        executor = rclpy.executors.SingleThreadedExecutor(context=ctx)
        executor.add_node(sub_node)
        odom: list[Odometry] = []
        status: list[DiagnosticArray] = []
        sub_node.create_subscription(Odometry, "/vo/odometry", odom.append, RELIABLE)
        sub_node.create_subscription(DiagnosticArray, "/vo/status", status.append, RELIABLE)
        # The node publishes its first pose on the first stereo pair: this listener must
        # have matched its publishers before the bag plays, or that pose is not delivered.
        deadline = time.monotonic() + 60
        while (min(sub_node.count_publishers(t) for t in ("/vo/odometry", "/vo/status")) < 1
               and time.monotonic() < deadline and node.poll() is None):
            executor.spin_once(timeout_sec=0.1)
        player = subprocess.Popen(
            [_exe("globloc"), "play", str(tiny_bag), "--rate", str(rate),
             "--wait-subscribers", "30", "--topics", *topics], env=ros_env, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True)
        deadline = time.monotonic() + 150
        while (len(odom) < len(offline) and time.monotonic() < deadline
               and node.poll() is None):
            executor.spin_once(timeout_sec=0.1)
        player.wait(timeout=60)
        assert node.poll() is None, node.stdout.read()
        values = {kv.key: kv.value for kv in status[-1].status[0].values}
        lost = {k: v for k, v in values.items()
                if k.startswith("bad_input.") and v != offline_status[k]}
        # Best-effort sensor topics: on a loaded machine DDS may drop a message; then the
        # node rightly differs from the offline run, and the test says so. (Raw images are
        # 0.9 MB: the player's Fast DDS profile keeps them in shared memory, else a quarter
        # of them were lost, docs/bringup.md.)
        assert not lost, f"the node saw bad input (messages lost in transport?): {lost}"
        assert len(odom) == len(offline), (len(odom), len(offline))
        for msg, out in zip(odom, offline, strict=True):
            stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
            assert stamp == out.stamp_ns
            assert (msg.header.frame_id, msg.child_frame_id) == ("odom", "base_link")
            p = msg.pose.pose.position
            # The same library code on the same messages: the same poses.
            assert np.linalg.norm([p.x - out.state.p[0], p.y - out.state.p[1],
                                   p.z - out.state.p[2]]) < 1e-6
            np.testing.assert_allclose(np.reshape(msg.pose.covariance, (6, 6)), out.state.cov,
                                       rtol=1e-6, atol=1e-12)
        assert odom[-1].pose.covariance[0] > odom[1].pose.covariance[0]
        for key in ("features", "stereo_matches", "inliers", "state", "bad_input.imu_gap"):
            assert key in values
    finally:
        _stop(player, node, ctx)
    log = node.stdout.read()
    assert node.returncode == 0, log
    # The rectification is said once per side, among the warnings of the same logger.
    raw = m.TOPIC_LEFT not in topics
    assert log.count("images are rectified to its P") == (2 if raw else 0), log

    if raw:
        return  # the CLI's files are checked once, on the contract's bag
    # The offline CLI on the same bag writes the same poses.
    out_dir = tmp_path / "vo"
    cli = subprocess.run([_exe("rover_vo"), "odometry", str(tiny_bag), "--out", str(out_dir)],
                         capture_output=True, text=True, check=False, timeout=120)
    assert cli.returncode == 0, cli.stderr
    tum = read_tum_rows(out_dir / "vo.tum")
    assert len(tum) == len(odom)
    positions = np.array([[o.pose.pose.position.x, o.pose.pose.position.y,
                           o.pose.pose.position.z] for o in odom])
    np.testing.assert_allclose(tum[:, 1:4], positions, atol=2e-6)  # TUM keeps 6 decimals
    report = json.loads((out_dir / "vo_report.json").read_text())
    assert report["pairs"] == len(odom) and report["mode"] == "paper"


def test_cli_errors_name_the_file(tmp_path):
    res = subprocess.run([_exe("rover_vo"), "odometry", str(tmp_path / "nope"), "--out",
                          str(tmp_path / "o")], capture_output=True, text=True, check=False)
    assert res.returncode == 1
    assert "nope" in res.stderr and "Traceback" not in res.stderr
    assert not (tmp_path / "o" / "vo.tum").exists()
    bad = tmp_path / "bad.tum"
    bad.write_text("not a trajectory\n")
    res = subprocess.run([_exe("rover_vo"), "eval", str(bad), str(bad)], capture_output=True,
                         text=True, check=False)
    assert res.returncode == 1 and "bad.tum" in res.stderr and "Traceback" not in res.stderr


def test_node_refuses_an_option_it_does_not_have(tiny_bag, ros_env, tmp_path, monkeypatch):
    from rover_vo.vo_node import VoNode

    params = tmp_path / "p.yaml"
    params.write_text("rover_vo:\n  ros__parameters:\n    window:\n"
                      "      keyframe_max_frames: 4\n")
    for key in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE"):
        monkeypatch.setenv(key, ros_env[key])
    ctx = rclpy.Context()
    rclpy.init(context=ctx, args=["--ros-args", "--params-file", str(tiny_bag / "rover.yaml"),
                                  "--params-file", str(params)])
    try:
        with pytest.raises(ValueError, match=r"unknown parameter 'window\.keyframe_max_frames'"):
            VoNode(context=ctx)
    finally:
        rclpy.try_shutdown(context=ctx)


def test_one_imu_callback_takes_every_queued_imu_message(tiny_bag, tiny_messages, ros_env,
                                                         monkeypatch):
    # rclpy's executor takes one message per subscription per wait (about a millisecond of
    # Python each): at 250 IMU messages/s on a loaded machine the node fell behind, its
    # queue overflowed and pairs were processed without their gyro (docs/rover_vo.md).
    from rclpy.executors import SingleThreadedExecutor
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Imu

    from rover_vo.vo_node import VoNode

    for key in ("ROS_DOMAIN_ID", "ROS_AUTOMATIC_DISCOVERY_RANGE"):
        monkeypatch.setenv(key, ros_env[key])
    ctx = rclpy.Context()
    rclpy.init(context=ctx, args=["--ros-args", "--params-file", str(tiny_bag / "rover.yaml")])
    try:
        node = VoNode(context=ctx)
        fed: list[str] = []
        feed = node.on_message
        node.on_message = lambda topic, msg: (fed.append(topic), feed(topic, msg))
        source = rclpy.create_node("imu_flood", context=ctx)
        qos = QoSProfile(depth=500, reliability=qos_profile_sensor_data.reliability)
        pub = source.create_publisher(Imu, m.TOPIC_IMU, qos)
        deadline = time.monotonic() + 20
        while pub.get_subscription_count() < 1 and time.monotonic() < deadline:
            time.sleep(0.05)
        imus = [msg for topic, msg in tiny_messages if topic == m.TOPIC_IMU][:300]
        for src in imus:
            msg = Imu()
            msg.header.stamp.sec, msg.header.stamp.nanosec = (src.header.stamp.sec,
                                                              src.header.stamp.nanosec)
            msg.header.frame_id = src.header.frame_id
            for part in ("angular_velocity", "linear_acceleration"):
                for axis in "xyz":
                    setattr(getattr(msg, part), axis, float(getattr(getattr(src, part), axis)))
            pub.publish(msg)
        time.sleep(1.0)  # delivered into the node's queue
        executor = SingleThreadedExecutor(context=ctx)
        executor.add_node(node)
        executor.spin_once(timeout_sec=5.0)
        # One callback: the message it was given and every other one queued behind it.
        assert len(fed) > 250, len(fed)
        assert set(fed) == {m.TOPIC_IMU}
        assert node.drain_imu() == 0
        executor.shutdown(timeout_sec=0)
        node.destroy_node()
        source.destroy_node()
    finally:
        rclpy.try_shutdown(context=ctx)



def test_node_gives_the_first_pose_at_once_and_skips_a_bad_camera_info(ros_env, tmp_path):
    """A 4.5 s bag (4 pairs 1 s apart, one left CameraInfo with fx = 0) played at its
    rate: every pair gets its pose, the first within 0.5 s of bag time of the first pair
    (the bag time of its arrival: the listener's clock less the least offset of an IMU
    message's arrival from its stamp), and /vo/status counts the skipped CameraInfo,
    which the log names once."""
    from rclpy.qos import qos_profile_sensor_data
    from sensor_msgs.msg import Imu

    schedule = fw.Schedule(period_s=1.0).drive(4)
    second = fw.START_NS + round(schedule.frames[1].t * 1e9)
    messages = []
    for topic, msg in fw.stream(schedule):
        if topic == m.TOPIC_LEFT_INFO and m.stamp_ns(msg) == second:
            msg.k = np.array(msg.k, float)
            msg.k[0] = 0.0
        messages.append((topic, msg))
    bag = fw.write_bag(messages, tmp_path / "short")
    node = subprocess.Popen([_exe("rover_vo"), "--ros-args", "--params-file",
                             str(bag / "rover.yaml")], env=ros_env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=int(ros_env["ROS_DOMAIN_ID"]))
    player = None
    try:
        listener = rclpy.create_node("vo_start_listener", context=ctx)
        executor = rclpy.executors.SingleThreadedExecutor(context=ctx)
        executor.add_node(listener)
        imu: list[tuple[int, int]] = []  # (stamp, arrival), ns
        odom: list[tuple[Odometry, int]] = []  # (message, arrival), ns
        status: list[DiagnosticArray] = []
        listener.create_subscription(
            Imu, m.TOPIC_IMU, lambda msg: imu.append((m.stamp_ns(msg), time.time_ns())),
            QoSProfile(depth=500, reliability=qos_profile_sensor_data.reliability))
        listener.create_subscription(Odometry, "/vo/odometry",
                                     lambda msg: odom.append((msg, time.time_ns())), RELIABLE)
        listener.create_subscription(DiagnosticArray, "/vo/status", status.append, RELIABLE)
        deadline = time.monotonic() + 60
        while (min(listener.count_publishers(t) for t in ("/vo/odometry", "/vo/status")) < 1
               and time.monotonic() < deadline and node.poll() is None):
            executor.spin_once(timeout_sec=0.1)
        player = subprocess.Popen(
            [_exe("globloc"), "play", str(bag), "--rate", "1", "--wait-subscribers", "30",
             "--topics", *_played(m.INPUT_TOPICS, messages)], env=ros_env,
            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
        deadline = time.monotonic() + 90
        while len(odom) < len(schedule.frames) and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        player.wait(timeout=60)
        assert node.poll() is None, node.stdout.read()
        assert len(odom) == len(schedule.frames), len(odom)
        first, arrival = odom[0]
        stamp = first.header.stamp.sec * 1_000_000_000 + first.header.stamp.nanosec
        assert stamp == fw.START_NS
        assert len(imu) > 100, len(imu)
        bag_time = arrival - min(wall - t for t, wall in imu)
        assert (bag_time - stamp) * 1e-9 < 0.5, (bag_time - stamp) * 1e-9
        values = {kv.key: kv.value for kv in status[-1].status[0].values}
        assert values["bad_input.bad_camera_info"] == "1"
    finally:
        _stop(player, node, ctx)
    log = node.stdout.read()
    t = m.seconds(second)
    assert log.count(f"/stereo/left/camera_info at {t:.3f} s: K[0] (fx) = 0") == 1, log
