"""A bag whose stereo images are raw sensor_msgs/Image (a field bag's usual transport)
gives the odometry the contract's compressed images give."""

from __future__ import annotations

import numpy as np
import pytest

from roi_network.testing import write_raw_image_copy
from rover_vo import messages as m
from rover_vo.bag import BagError, read_messages
from rover_vo.testing import run


@pytest.fixture(scope="module")
def raw_bag(tiny_bag, tmp_path_factory):
    return write_raw_image_copy(tiny_bag, tmp_path_factory.mktemp("raw") / "tiny_raw")


def test_raw_images_give_the_same_odometry(raw_bag, tiny_params, clean_run):
    messages = list(read_messages(raw_bag))
    topics = {t for t, _ in messages} - {m.TOPIC_JOINT_STATES, m.TOPIC_SUN}  # mast, sun
    assert set(m.input_topics("raw")) == topics
    est, outputs, _ = run(messages, tiny_params)
    ref_est, reference, _ = clean_run
    assert [o.stamp_ns for o in outputs] == [o.stamp_ns for o in reference]
    # The same pixels; grey from RGB, where the JPEG decoder gives its luma: rounding only.
    err = [np.linalg.norm(o.state.p - r.state.p) for o, r in zip(outputs, reference,
                                                                   strict=True)]
    assert max(err) < 0.02, max(err)  # 7 mm measured (seed 7, 45 deg)
    bad = {k: v for k, v in est.status().items() if k.startswith("bad_input.")}
    assert bad == {k: v for k, v in ref_est.status().items() if k.startswith("bad_input.")}


def test_a_bag_without_a_stereo_pair_is_named(tiny_bag, tmp_path):
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    (tmp_path / "b").mkdir()
    with Writer(tmp_path / "b" / "rosbag", version=9) as writer:
        writer.add_connection("/stereo/left/image_raw", "sensor_msgs/msg/Image",
                              typestore=store)
    with pytest.raises(BagError, match=r"no stereo image pair.*it has /stereo/left/image_raw"):
        list(read_messages(tmp_path / "b"))


def test_a_distorting_lens_is_rectified_by_its_camera_info(tiny_bag, tiny_params, tmp_path):
    """A camera driver's raw images keep the lens distortion, with D in their CameraInfo.
    Rectified to P, the pairs match in stereo as the rectified bag's do; read as they come,
    the rows of the two images no longer correspond and a third of the matches are lost
    (measured: 449 / 430 / 313 stereo matches and 63 / 61 / 37 inliers per pair)."""
    import dataclasses

    from rover_vo.config import VoConfig
    from rover_vo.estimator import VoEstimator

    def per_pair(messages, cfg):
        logs = []
        est = VoEstimator(cfg, tiny_params, lambda _level, text: logs.append(text))
        counts = []
        for topic, msg in messages:
            if est.feed(topic, msg):
                status = est.status()
                counts.append((int(status["stereo_matches"]), int(status["inliers"])))
        return np.mean(counts, axis=0), logs

    distorted = list(read_messages(write_raw_image_copy(
        tiny_bag, tmp_path / "distorted", distortion=(-0.28, 0.09, 0.0, 0.0, 0.0))))
    reference, _ = per_pair(read_messages(tiny_bag), VoConfig())
    rectified, logs = per_pair(distorted, VoConfig())
    as_they_come, logs_off = per_pair(distorted, VoConfig(features=dataclasses.replace(
        VoConfig().features, rectify=False)))
    assert np.all(rectified > 0.9 * reference), (reference, rectified)
    assert np.all(as_they_come < 0.8 * reference), (reference, as_they_come)
    assert sum("rectified to its P" in text for text in logs) == 2  # once per side
    assert not any("rectified" in text for text in logs_off)


def test_cameras_stamped_apart_pair_within_the_tolerance(tiny_bag, tiny_params, clean_run,
                                                         tmp_path):
    """Right images stamped 3 +- 1 ms after their left ones (two drivers): paired as the
    simulator's exact stamps are, at the left's stamp; with exact stamps only, no pair
    forms and each lone half is counted, with how far its partner was."""
    import dataclasses

    from roi_network.testing import write_stamp_offset_copy
    from rover_vo.config import VoConfig

    apart = list(read_messages(write_stamp_offset_copy(tiny_bag, tmp_path / "apart", 0.003,
                                                       jitter_s=0.001)))
    est, outputs, _ = run(apart, tiny_params)
    _, reference, _ = clean_run
    assert [o.stamp_ns for o in outputs] == [o.stamp_ns for o in reference]
    err = [np.linalg.norm(o.state.p - r.state.p) for o, r in zip(outputs, reference,
                                                                   strict=True)]
    assert max(err) < 1e-6, max(err)  # the same pixels, paired alike
    assert est.halves.max_offset_ns >= 2_000_000
    exact = VoConfig(features=dataclasses.replace(VoConfig().features,
                                                  stereo_sync_tolerance_s=0.0))
    est0, _, logs0 = run(apart, tiny_params, exact)
    status = est0.status()
    assert status["bad_input.missing_right"] == len(reference)
    assert status["vision_frames"] == 0
    assert any("beyond the stereo sync tolerance (0.0 ms)" in text for _, text in logs0)
