"""The estimator on the tiny bag's messages: tracking, zero velocity at stops, a pure
rotation from the IMU, and every kind of bad input (crafted from real messages)."""

from __future__ import annotations

import copy
import itertools
import logging

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rover_vo import messages as m
from rover_vo.estimator import BAD_INPUT_KINDS
from rover_vo.testing import run


def pair_stamps(messages):
    return sorted({m.stamp_ns(msg) for t, msg in messages if t == m.TOPIC_LEFT})


def with_stamp(msg, t_ns):
    out = copy.deepcopy(msg)
    out.header.stamp.sec, out.header.stamp.nanosec = divmod(int(t_ns), 1_000_000_000)
    return out


def jpeg(msg, image):
    out = copy.deepcopy(msg)
    out.data = np.frombuffer(cv2.imencode(".jpg", image)[1].tobytes(), np.uint8)
    return out


def imu_msg(template, t_ns, gyro, accel):
    out = with_stamp(template, t_ns)
    w, a = out.angular_velocity, out.linear_acceleration
    w.x, w.y, w.z = (float(v) for v in gyro)
    a.x, a.y, a.z = (float(v) for v in accel)
    return out


@pytest.fixture(scope="module")
def clean_prefix_run(tiny_messages, tiny_params):
    """The estimator over the first 15 pairs of the tiny stream."""
    return run(_prefix(tiny_messages), tiny_params)


def first(messages, topic):
    return next(msg for t, msg in messages if t == topic)


def test_tracks_the_tiny_bag(tiny_bag, tiny_messages, clean_run):
    est, outputs, _ = clean_run
    stamps = pair_stamps(tiny_messages)
    assert [o.stamp_ns for o in outputs] == stamps  # one pose per stereo pair, in order
    assert est.counts.vision >= len(stamps) // 2
    assert est.counts.bad.get("missing_camera_info", 0) == 0  # infos follow their images
    truth = np.loadtxt(tiny_bag / "truth" / "trajectory.tum")
    # Distance driven within 10 % of the truth's over the same stamps.
    t = np.array([o.state.t for o in outputs])
    p = np.array([np.interp(t, truth[:, 0], truth[:, k]) for k in (1, 2, 3)]).T
    true_len = np.sum(np.linalg.norm(np.diff(p, axis=0), axis=1))
    assert abs(outputs[-1].state.distance_m - true_len) < 0.1 * true_len
    # The covariance grows with the distance driven.
    sig = [np.trace(o.state.cov[:2, :2]) for o in outputs]
    assert sig[-1] > sig[len(sig) // 3] > sig[1] >= 0.0


def test_paper_mode_keeps_a_reference_until_the_rover_moved(tiny_messages, tiny_params,
                                                            clean_run):
    """Frame to frame, the last frame replaces the reference once it is
    frame_to_frame_min_travel_m (0.3 m) from it: each pair of a bag 0.45 m apart (the tiny
    bag: one keyframe per pair), every few pairs of a denser
    stream (asked here of 1 m on the tiny bag: fewer keyframes, the same poses within the
    VO's own error)."""
    import dataclasses

    from rover_vo.config import VoConfig

    est, outputs, _ = clean_run
    # One keyframe per pair (a failed frame starts one too), but for the end-of-drive pair
    # of the final stop, taken 1 s after the wheels stop, closer than 0.3 m to the last.
    assert est.counts.keyframes == est.counts.pairs - 1
    far = VoConfig(window=dataclasses.replace(VoConfig().window,
                                              frame_to_frame_min_travel_m=1.0))
    est1, outputs1, _ = run(tiny_messages, tiny_params, far)
    assert est1.counts.keyframes < est.counts.keyframes
    err = max(np.linalg.norm(a.state.p - b.state.p) for a, b in zip(outputs, outputs1,
                                                                      strict=True))
    assert err < 0.05 * outputs[-1].state.distance_m, err


def _standing_still_stream(messages, n_pairs=5, gyro_bias=(0.003, -0.002, 0.001),
                           yaw_rate=0.0, textureless_after_first=False):
    """Infos, then the same stereo pair every 10 s with 50 Hz IMU samples in between."""
    left, right = first(messages, m.TOPIC_LEFT), first(messages, m.TOPIC_RIGHT)
    imu0 = first(messages, m.TOPIC_IMU)
    t0 = m.stamp_ns(left)
    grey = np.full((480, 640, 3), 128, np.uint8)
    stream = [(m.TOPIC_LEFT_INFO, first(messages, m.TOPIC_LEFT_INFO)),
              (m.TOPIC_RIGHT_INFO, first(messages, m.TOPIC_RIGHT_INFO))]
    for k in range(n_pairs):
        t_pair = t0 + k * 10_000_000_000
        for j in range(500 if k else 60, 0, -1):  # 10 s of IMU before the pair
            t_imu = t_pair - (j - 1) * 20_000_000
            stream.append((m.TOPIC_IMU, imu_msg(imu0, t_imu, np.add(gyro_bias, [0, 0, yaw_rate]),
                                                [0.0, 0.0, 9.81])))
        lm, rm = with_stamp(left, t_pair), with_stamp(right, t_pair)
        if textureless_after_first and k:
            lm, rm = jpeg(lm, grey), jpeg(rm, grey)
        stream += [(m.TOPIC_LEFT, lm), (m.TOPIC_RIGHT, rm)]
    return stream


def test_zero_motion_at_stops(tiny_messages, tiny_params):
    est, outputs, _ = run(_standing_still_stream(tiny_messages), tiny_params)
    assert [o.source for o in outputs] == ["initial"] + ["zero_velocity"] * 4
    p0, R0 = outputs[0].state.p, outputs[0].state.R
    for o in outputs[1:]:
        assert np.linalg.norm(o.state.p - p0) == 0.0  # no drift at all while stopped
        assert Rotation.from_matrix(R0.T @ o.state.R).magnitude() < np.radians(0.01)
        np.testing.assert_allclose(o.state.cov, outputs[0].state.cov)
        assert np.linalg.norm(o.linear) == 0.0
    # Standing still, the gyro reads its bias: the estimate converges to it.
    np.testing.assert_allclose(est.propagator.bias, [0.003, -0.002, 0.001], atol=2e-5)


def test_pure_rotation_from_the_imu(tiny_messages, tiny_params):
    # The rover turns on the spot at 3 deg/s while its cameras see nothing usable: the
    # heading follows the gyro, the position stays, the covariance grows.
    rate = np.radians(3.0)
    stream = _standing_still_stream(tiny_messages, n_pairs=4, gyro_bias=(0, 0, 0),
                                    yaw_rate=rate, textureless_after_first=True)
    est, outputs, logs = run(stream, tiny_params)
    assert [o.source for o in outputs] == ["initial"] + ["imu_propagation"] * 3
    yaw = [Rotation.from_matrix(o.state.R).as_euler("ZYX")[0] for o in outputs]
    # The first 1.2 s of IMU precede the first pair; then 10 s between pairs.
    np.testing.assert_allclose(np.degrees(np.diff(yaw)), 30.0, atol=0.05)
    assert all(np.linalg.norm(o.state.p) < 1e-9 for o in outputs)
    yaw_var = [o.state.cov[5, 5] for o in outputs]
    assert yaw_var[0] < yaw_var[1] < yaw_var[2] < yaw_var[3]
    assert est.counts.bad["textureless"] == 3
    assert sum("textureless" in text for _, text in logs) == 1  # logged once per kind


def _prefix(messages, n_pairs=15):
    """The stream up to its ``n_pairs``-th stereo pair (the bad input tests need no more)."""
    end = pair_stamps(messages)[n_pairs - 1]
    return [(t, msg) for t, msg in messages if m.stamp_ns(msg) <= end]


def _mutate(messages, kind):
    """The stream with one kind of bad input injected (twice where it can be)."""
    stamps = pair_stamps(messages)
    hit = {stamps[6], stamps[12]}
    grey = np.full((480, 640, 3), 128, np.uint8)
    white = np.full((480, 640, 3), 255, np.uint8)
    out = []
    imu_seen = 0
    infos_seen = 0
    for topic, msg in messages:
        t = m.stamp_ns(msg)
        if kind == "missing_camera_info" and topic in (m.TOPIC_LEFT_INFO, m.TOPIC_RIGHT_INFO):
            infos_seen += 1
            if t < stamps[3]:
                continue
        if topic == m.TOPIC_IMU:
            imu_seen += 1
            if kind == "imu_gap" and stamps[6] - 2_000_000_000 < t < stamps[6]:
                continue
            if kind == "imu_nan" and imu_seen in (300, 900):
                bad = copy.deepcopy(msg)
                bad.angular_velocity.x = float("nan")
                out.append((topic, bad))
                continue
            if kind == "imu_duplicate" and imu_seen in (300, 900):
                out += [(topic, msg), (topic, msg)]
                continue
            if kind == "imu_out_of_order" and imu_seen in (300, 900):
                out += [(topic, msg), (topic, with_stamp(msg, t - 100_000_000))]
                continue
        if topic in (m.TOPIC_LEFT, m.TOPIC_RIGHT) and t in hit:
            if kind == "corrupt_image" and topic == m.TOPIC_LEFT:
                bad = copy.deepcopy(msg)
                bad.data = np.frombuffer(b"\xff\xd8 not a jpeg" * 10, np.uint8)
                msg = bad
            if kind == "missing_right" and topic == m.TOPIC_RIGHT:
                continue
            if kind == "textureless":
                msg = jpeg(msg, grey)
            if kind == "overexposed":
                msg = jpeg(msg, white)
            if kind == "stereo_duplicate" and topic == m.TOPIC_LEFT:
                out.append((topic, msg))
            if kind == "stereo_out_of_order" and topic == m.TOPIC_RIGHT:
                old = stamps[2]
                out += [(topic, msg), (m.TOPIC_LEFT, with_stamp(msg, old))]
                continue
        out.append((topic, msg))
    return out


EXPECT_PROPAGATED = {"corrupt_image", "missing_right", "textureless", "overexposed"}


@pytest.mark.parametrize("kind", [
    "corrupt_image", "missing_right", "missing_camera_info", "imu_gap", "imu_nan",
    "imu_duplicate", "imu_out_of_order", "stereo_duplicate", "stereo_out_of_order",
    "textureless", "overexposed",
])
def test_bad_input_is_counted_and_the_pose_continues(kind, tiny_messages, tiny_params,
                                                     clean_prefix_run):
    assert kind in BAD_INPUT_KINDS
    _, clean, _ = clean_prefix_run
    est, outputs, logs = run(_mutate(_prefix(tiny_messages), kind), tiny_params)
    assert est.counts.bad[kind] >= 1
    warnings = [level for level, text in logs if f"'{kind}'" in text]
    assert warnings == [logging.WARNING]  # logged once per kind
    assert outputs[-1].stamp_ns == clean[-1].stamp_ns  # the odometry went on to the end
    stamps = [o.stamp_ns for o in outputs]
    assert stamps == sorted(set(stamps))  # time order, no duplicate pose
    if kind in EXPECT_PROPAGATED:
        for o_prev, o in itertools.pairwise(outputs):
            if o.source == "imu_propagation":  # IMU-propagated, covariance growing
                assert np.trace(o.state.cov) > np.trace(o_prev.state.cov)
        assert sum(o.source == "imu_propagation" for o in outputs) >= 2
    # The clean run's end point is not far: bad input costs accuracy, not the track.
    assert np.linalg.norm(outputs[-1].state.p - clean[-1].state.p) < 3.0
