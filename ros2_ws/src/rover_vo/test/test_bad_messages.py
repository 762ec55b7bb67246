"""One bad message is one skipped message: counted, named once with its topic, stamp and
field, and the odometry goes on. On a short drive of the flat world (4 pairs 1 s apart),
each case crafted from its good messages."""

from __future__ import annotations

import copy
import logging

import cv2
import numpy as np
import pytest
import vo_flatworld as fw

from rover_vo import cli
from rover_vo import messages as m
from rover_vo.estimator import BAD_INPUT_KINDS
from rover_vo.testing import run

SHORT = fw.Schedule(period_s=1.0).drive(4)
RAW_LEFT, RAW_RIGHT = "/stereo/left/image_raw", "/stereo/right/image_raw"


@pytest.fixture(scope="module")
def stream():
    return fw.stream(SHORT)


@pytest.fixture(scope="module")
def clean(stream):
    est, outputs, _ = run(stream, fw.rover_params())
    assert len(outputs) == len(SHORT.frames) and not est.counts.bad
    return outputs


def pair_ns(k):
    return fw.START_NS + round(SHORT.frames[k].t * 1e9)


def said(logs, kind):
    """The warnings of one kind (logged once: the first)."""
    return [text for level, text in logs if level == logging.WARNING and f"'{kind}'" in text]


def changed(stream, topic, k, change):
    """The stream with ``change(copy)`` applied to ``topic``'s message of pair ``k``."""
    out = []
    for t, msg in stream:
        if t == topic and m.stamp_ns(msg) == pair_ns(k):
            msg = copy.deepcopy(msg)
            msg = change(msg) or msg
        out.append((t, msg))
    return out


def same_poses(a, b):
    assert [o.stamp_ns for o in a] == [o.stamp_ns for o in b]
    for x, y in zip(a, b, strict=True):
        assert np.array_equal(x.state.p, y.state.p)


def zero_fx(msg):
    msg.k = np.array(msg.k, float)
    msg.k[0] = 0.0


def test_fx_zero_in_one_camera_info_skips_that_message(stream, clean):
    est, outputs, logs = run(changed(stream, m.TOPIC_LEFT_INFO, 2, zero_fx), fw.rover_params())
    same_poses(outputs, clean)  # the other CameraInfos carry the same calibration
    assert est.counts.bad == {"bad_camera_info": 1}
    t = m.seconds(pair_ns(2))
    assert said(logs, "bad_camera_info") == [
        f"/stereo/left/camera_info at {t:.3f} s: K[0] (fx) = 0: message skipped (first "
        "'bad_camera_info'; further ones are counted in /vo/status, not logged)"]


def test_fx_zero_in_every_camera_info_says_why(stream, tmp_path, capsys):
    bad = stream
    for k in range(len(SHORT.frames)):
        bad = changed(bad, m.TOPIC_LEFT_INFO, k, zero_fx)
    est, outputs, logs = run(bad, fw.rover_params())
    assert outputs == []
    status = est.status()
    assert status["bad_input.bad_camera_info"] == len(SHORT.frames)
    assert status["bad_input.missing_camera_info"] == len(SHORT.frames)
    assert status["state"] == "initializing"
    # /vo/status's reason: the CameraInfo and its field, not the image.
    assert "/stereo/left/camera_info (the last one: /stereo/left/camera_info at" in (
        status["last_bad_input"])
    assert "K[0] (fx) = 0" in status["last_bad_input"]
    assert not any("texture" in text for _, text in logs)
    # The offline CLI: no pose, and the one line says why.
    bag = fw.write_bag(bad, tmp_path / "fx0")
    assert cli.main(["odometry", str(bag), "--out", str(tmp_path / "out")]) == 1
    err = capsys.readouterr().err
    assert "no stereo pair gave a pose (4 pairs read)" in err
    assert "K[0] (fx) = 0" in err and "Traceback" not in err


def resized(width):
    def change(msg):
        img = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_GRAYSCALE)
        msg.data = cv2.imencode(".jpg", cv2.resize(img, (width, img.shape[0])))[1].ravel()
    return change


def test_right_images_of_another_size_than_the_left_are_named(stream):
    """Right images and the right CameraInfo at 600x480 beside the left's 640x480: the
    right image is named, with the left's size, not a CameraInfo that agrees with it."""
    bad = stream
    for k in range(len(SHORT.frames)):
        bad = changed(bad, m.TOPIC_RIGHT, k, resized(600))
        bad = changed(bad, m.TOPIC_RIGHT_INFO, k, lambda msg: setattr(msg, "width", 600))
    est, outputs, logs = run(bad, fw.rover_params())
    assert est.counts.bad["bad_image_size"] == len(SHORT.frames) and outputs == []
    t = m.seconds(pair_ns(0))
    assert said(logs, "bad_image_size")[0].startswith(
        f"{m.TOPIC_RIGHT} at {t:.3f} s: image is 600x480 beside the left one's 640x480")


def test_an_image_of_another_size_than_its_camera_info_is_named(stream, clean):
    est, outputs, logs = run(changed(stream, m.TOPIC_LEFT, 2, resized(600)), fw.rover_params())
    assert est.counts.bad == {"bad_image_size": 1}
    assert [o.source for o in outputs][2] == "imu_propagation"  # the pair not used
    t = m.seconds(pair_ns(2))
    assert said(logs, "bad_image_size")[0].startswith(
        f"{m.TOPIC_LEFT} at {t:.3f} s: image is 600x480, its CameraInfo "
        "(/stereo/left/camera_info) says 640x480: pair not used")


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf")])
@pytest.mark.parametrize("field", m.IMU_FIELDS)
def test_a_non_finite_imu_field_is_named_and_the_sample_skipped(stream, clean, field, value):
    imus = [msg for t, msg in stream if t == m.TOPIC_IMU]
    target = imus[len(imus) // 2]
    part, axis = field.split(".")
    out = []
    for t, msg in stream:
        if msg is target:
            msg = copy.deepcopy(msg)
            setattr(getattr(msg, part), axis, value)
        out.append((t, msg))
    est, outputs, logs = run(out, fw.rover_params())
    assert est.counts.bad == {"imu_nan": 1}
    assert len(outputs) == len(clean)
    assert said(logs, "imu_nan")[0].startswith(
        f"{m.TOPIC_IMU} at {m.stamp_s(target):.3f} s: {field} = {value}: sample skipped")


def test_stamps_going_back_in_time_are_skipped_and_named(stream, clean):
    """An IMU sample 0.1 s older than the one before it, and a left image older than the
    left image before it: each skipped, named, the poses those of the clean stream."""
    out = []
    back_imu = back_left = None
    for t, msg in stream:
        out.append((t, msg))
        if t == m.TOPIC_IMU and back_imu is None and m.stamp_ns(msg) > pair_ns(1) + 5e8:
            back_imu = copy.deepcopy(msg)
            back_imu.header.stamp.nanosec -= 100_000_000  # 0.1 s back, within the second
            out.append((t, back_imu))
        if t == m.TOPIC_LEFT and m.stamp_ns(msg) == pair_ns(3):
            back_left = copy.deepcopy(msg)
            back_left.header.stamp.sec -= 1
            back_left.header.stamp.nanosec = 500_000_000  # between pairs 1 and 2
            out.append((t, back_left))
    est, outputs, logs = run(out, fw.rover_params())
    same_poses(outputs, clean)
    assert est.counts.bad == {"imu_out_of_order": 1, "stereo_out_of_order": 1}
    assert said(logs, "imu_out_of_order")[0].startswith(
        f"{m.TOPIC_IMU} at {m.stamp_s(back_imu):.3f} s: stamp before the previous sample's")
    assert said(logs, "stereo_out_of_order")[0].startswith(
        f"{m.TOPIC_LEFT} at {m.stamp_s(back_left):.3f} s: stamp before the previous left "
        f"image's ({m.seconds(pair_ns(3)):.3f} s): image skipped")


def as_raw(msg, encoding="mono8"):
    """The CompressedImage's pixels as a sensor_msgs/Image of ``encoding``'s name."""
    img = cv2.imdecode(np.frombuffer(bytes(msg.data), np.uint8), cv2.IMREAD_GRAYSCALE)
    image = fw.Messages().T["sensor_msgs/msg/Image"]
    return image(header=msg.header, height=img.shape[0], width=img.shape[1],
                 encoding=encoding, is_bigendian=0, step=img.shape[1], data=img.ravel())


@pytest.mark.parametrize("encoding", ["rgb16", "yuv422"])
def test_an_image_of_a_third_encoding_is_named(stream, encoding):
    raw = []
    for t, msg in stream:
        if t in (m.TOPIC_LEFT, m.TOPIC_RIGHT):
            wrong = t == m.TOPIC_LEFT and m.stamp_ns(msg) == pair_ns(2)
            t = RAW_LEFT if t == m.TOPIC_LEFT else RAW_RIGHT
            msg = as_raw(msg, encoding if wrong else "mono8")
        raw.append((t, msg))
    est, outputs, logs = run(raw, fw.rover_params())
    assert "unsupported_encoding" in BAD_INPUT_KINDS
    assert est.counts.bad == {"unsupported_encoding": 1}
    assert [o.source for o in outputs][2] == "imu_propagation"
    assert len(outputs) == len(SHORT.frames)
    assert said(logs, "unsupported_encoding")[0].startswith(
        f"{RAW_LEFT} at {m.seconds(pair_ns(2)):.3f} s: encoding '{encoding}' is not one "
        "rover_vo reads (mono8, ")
