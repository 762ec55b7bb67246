"""A restarted estimator continues the odom frame it saved (rover_vo.restart): the LN and
the map -> odom estimate built on that frame stay valid across a killed rover_vo."""

from __future__ import annotations

import json

import numpy as np
from scipy.spatial.transform import Rotation

from rover_vo import messages as m
from rover_vo.config import VoConfig
from rover_vo.estimator import VoEstimator
from rover_vo.restart import resume_from_file, save_state
from rover_vo.testing import run


def _pair_stamps(messages):
    return sorted({m.stamp_ns(msg) for t, msg in messages if t == m.TOPIC_LEFT})


def _truth_in_odom(tiny_bag, outputs):
    """Truth positions at the outputs' stamps, in the odom frame of the first output (the
    truth pose at the first pair is odom's origin, as the estimator starts there; its roll
    and pitch come from gravity, so only the yaw is taken out)."""
    truth = np.loadtxt(tiny_bag / "truth" / "trajectory.tum")
    t = np.array([o.state.t for o in outputs])
    p = np.array([np.interp(t, truth[:, 0], truth[:, k]) for k in (1, 2, 3)]).T
    q0 = [np.interp(outputs[0].state.t, truth[:, 0], truth[:, k]) for k in (4, 5, 6, 7)]
    yaw0 = Rotation.from_quat(q0).as_euler("ZYX")[0]
    return (p - p[0]) @ Rotation.from_euler("z", yaw0).as_matrix()


def test_a_restarted_estimator_continues_the_odom_frame(tiny_bag, tiny_messages, tiny_params,
                                                        tmp_path):
    stamps = _pair_stamps(tiny_messages)
    cut, back = stamps[len(stamps) // 2], stamps[len(stamps) // 2 + 3]  # 2 pairs unseen
    before = [(t, msg) for t, msg in tiny_messages if m.stamp_ns(msg) <= cut]
    after = [(t, msg) for t, msg in tiny_messages if m.stamp_ns(msg) >= back]
    est1, out1, _ = run(before, tiny_params)
    path = tmp_path / "rover_vo_state.json"
    save_state(path, est1.snapshot())

    logs = []
    est2 = VoEstimator(VoConfig(), tiny_params, lambda lvl, text: logs.append(text))
    assert resume_from_file(est2, path, logs.append)
    out2 = [o for topic, msg in after for o in est2.feed(topic, msg)] + est2.finish()
    assert out2[0].source == "resumed" and any("resumed the odom frame" in line for line in logs)
    # Tracking goes on from the new keyframe as it would from a fresh start.
    est_fresh, fresh, _ = run(after, tiny_params)
    assert est2.counts.vision >= est_fresh.counts.vision > 0

    # One odom frame: the resumed poses follow the truth as the first run's did.
    full = out1 + out2
    truth = _truth_in_odom(tiny_bag, full)
    est = np.array([o.state.p for o in full])
    err = np.linalg.norm(est[:, :2] - truth[:, :2], axis=1)
    # The resumed poses are as consistent with the truth as their covariance says (the
    # tiny route winds: its VO propagates half of the pairs on the gyro alone).
    sigma = np.array([np.sqrt(np.linalg.eigvalsh(o.state.cov[:2, :2]).max()) for o in full])
    assert np.all(err[len(out1):] < 3 * sigma[len(out1):] + 0.1), (err, sigma)
    # The gap nobody watched is in the covariance.
    assert sigma[len(out1)] > sigma[len(out1) - 1] + 0.05
    # A fresh estimator starts a new frame at the identity: metres off, and its
    # covariance (zero at the start) does not say so.
    fresh_err = np.linalg.norm(fresh[0].state.p[:2] - truth[len(out1), :2])
    assert fresh_err > 2.0 and fresh_err > err[len(out1)] + 1.0
    assert out2[-1].state.distance_m > out1[-1].state.distance_m


def test_an_unusable_state_file_is_kept_aside(tiny_params, tmp_path):
    path = tmp_path / "rover_vo_state.json"
    reports = []
    est = VoEstimator(VoConfig(), tiny_params, lambda lvl, text: None)
    assert not resume_from_file(est, path, reports.append)  # none yet: a new frame
    for text in ("{not json", json.dumps({"version": 99}), json.dumps({"version": 1, "t": 0})):
        path.write_text(text)
        assert not resume_from_file(est, path, reports.append)
        assert not path.exists()
        assert str(path) in reports[-1] and "a new odom frame starts" in reports[-1]
    assert len(list(tmp_path.glob("rover_vo_state.json.corrupt-*"))) >= 1
