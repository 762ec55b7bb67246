"""The camera on a pan-tilt mast (roi_network.mast): pairs taken off the reference's camera
pose are not motion measurements, a stop with a panorama neither drifts nor jumps, a new
drive tilt gets a new reference, and a /joint_states stream that never comes, names other
joints, is stamped away from the images or stops, leaves the odometry going on at the
last known (or the drive) pose, said once. All on the flat world of ``vo_flatworld.py``."""

from __future__ import annotations

import copy
import logging
import math

import numpy as np
import pytest
import vo_flatworld as fw
from scipy.spatial.transform import Rotation

from roi_network.mast import MastError, same_pose
from roi_network.trajectory import read_tum_rows
from rover_vo import cli
from rover_vo import messages as m
from rover_vo.arrivals import WAIT_PERIODS
from rover_vo.config import VoConfig
from rover_vo.estimator import JOINT_STATE_PERIOD_S, MAST_SETTLE_FRAMES, VoEstimator
from rover_vo.evaluation import stop_drift
from rover_vo.testing import run

PANO = fw.panorama_schedule()


@pytest.fixture(scope="module")
def pano_stream():
    """The stop with a panorama: 6 pairs driving, 2 standing, 6 views, 2 standing, 6
    driving."""
    return fw.stream(PANO)


@pytest.fixture(scope="module")
def pano_run(pano_stream):
    return run(pano_stream, fw.rover_params())


def _stamp(t_s):
    return fw.START_NS + round(t_s * 1e9)


def _errors(outputs, schedule):
    truth = fw.truth_x(schedule)
    return np.array([[o.state.p[0] - truth[o.stamp_ns], o.state.p[1], o.state.p[2]]
                     for o in outputs])


def _yaw_deg(o):
    return math.degrees(Rotation.from_matrix(o.state.R).as_euler("ZYX")[0])


def _stop(outputs, schedule):
    """The outputs of the stop: from the last driving pair to the first one after."""
    xs = [f.x for f in schedule.frames]
    stop_x = max(x for x in xs if xs.count(x) > 2)
    stamps = {_stamp(f.t) for f in schedule.frames if f.x == stop_x}
    return [o for o in outputs if o.stamp_ns in stamps]


def test_a_panorama_is_waited_out_and_tracking_resumes(pano_run):
    est, outputs, _ = pano_run
    pan_stamps = {_stamp(f.t) for f in PANO.frames if f.pan != 0.0}
    assert len(outputs) == len(PANO.frames)
    assert est.counts.mast_moved == len(pan_stamps) == 6
    status = est.status()
    assert status["mast_moved_frames"] == 6 and status["frames_without_joint_states"] == 0
    for o in outputs:
        if o.stamp_ns in pan_stamps:
            assert o.source == "zero_velocity"  # the gyro is quiet: the rover stands
    # No reference was taken at a view: one per vision frame, and the first.
    assert est.counts.keyframes == est.counts.vision + 1
    stop = _stop(outputs, PANO)
    assert len(stop) == 11
    moved = max(np.linalg.norm(o.state.p - stop[0].state.p) for o in stop)
    assert moved < 1e-9  # neither drift nor a jump through the stop
    assert max(abs(_yaw_deg(o) - _yaw_deg(stop[0])) for o in stop) < 0.01
    # Tracking resumed against the reference before the panorama: the drive after it is
    # measured (vision) and the track stays on the truth.
    after = [o for o in outputs if o.stamp_ns > stop[-1].stamp_ns]
    assert [o.source for o in after] == ["vision"] * 6
    err = _errors(outputs, PANO)
    assert np.abs(err).max() < 0.02, err


def test_without_the_mast_the_views_are_read_as_motion(pano_stream):
    """The same bag with rover.yaml's fixed camera: the views are taken for rover motion
    (what the mast model prevents)."""
    est, outputs, _ = run([(t, msg) for t, msg in pano_stream if t != m.TOPIC_JOINT_STATES],
                          fw.rover_params(mast=False))
    stop = _stop(outputs, PANO)
    assert max(np.linalg.norm(o.state.p - stop[0].state.p) for o in stop) > 0.5
    assert est.counts.mast_moved == 0


def test_a_view_with_the_gyro_turning_is_propagated_in_place(pano_stream):
    """At a view only the IMU says whether the rover stands: with the gyro turning, the
    heading follows it and the position stays."""
    first_view = next(f.t for f in PANO.frames if f.pan != 0.0)
    rate = 0.05  # rad/s about z, over the 5 s before the first view
    stream = []
    for topic, msg in pano_stream:
        t = (m.stamp_ns(msg) - fw.START_NS) * 1e-9
        if topic == m.TOPIC_IMU and first_view - 5.0 < t <= first_view:
            msg = copy.deepcopy(msg)
            msg.angular_velocity.z += rate
        stream.append((topic, msg))
    _, outputs, _ = run(stream, fw.rover_params())
    i = next(k for k, o in enumerate(outputs) if o.stamp_ns == _stamp(first_view))
    before, view = outputs[i - 1], outputs[i]
    assert view.source == "imu_propagation"
    assert np.linalg.norm(view.state.p - before.state.p) < 1e-9
    assert _yaw_deg(view) - _yaw_deg(before) == pytest.approx(math.degrees(rate * 5.0),
                                                              abs=0.1)


NEW_TILT = math.radians(30.0)
RETILT = fw.Schedule().drive(5).stand(1).stand(4, 0.0, NEW_TILT).drive(6, tilt=NEW_TILT)


@pytest.fixture(scope="module")
def retilt_stream():
    """Drive, stop, the mast tilts 10 deg further down for good, drive on."""
    return fw.stream(RETILT)


@pytest.fixture(scope="module")
def retilt_run(retilt_stream):
    return run(retilt_stream, fw.rover_params())


def test_an_unusable_pair_back_at_the_drive_pose_keeps_the_rover_standing(pano_stream):
    """The first pair after the views is unusable (no texture): the rover, standing while
    its mast moved, is propagated in place, not on by the last drive step."""
    back = next(f.t for f in PANO.frames if f.t > 25.0 and f.pan == 0.0)
    grey = np.full((fw.H, fw.W), 128, np.uint8)
    msgs = fw.Messages()
    stream = [(t, msgs.image(m.stamp_ns(msg), grey))
              if t in m.IMAGE_TOPICS and m.stamp_ns(msg) == _stamp(back) else (t, msg)
              for t, msg in pano_stream]
    est, outputs, _ = run(stream, fw.rover_params())
    assert est.counts.bad["textureless"] == 1
    stop = _stop(outputs, PANO)
    assert max(np.linalg.norm(o.state.p - stop[0].state.p) for o in stop) < 1e-9
    assert np.abs(_errors(outputs, PANO)).max() < 0.02


def test_a_new_drive_tilt_gets_a_new_reference(retilt_run):
    """The mast settles at a new tilt for good: the pairs there are waited out until
    MAST_SETTLE_FRAMES of them, then a new reference with the new camera pose, and the
    drive on is measured with it."""
    est, outputs, _ = retilt_run
    assert est.counts.mast_reanchors == 1
    assert est.counts.mast_moved == MAST_SETTLE_FRAMES
    assert same_pose(est.kf.base_T_left, fw.KIN.base_T_left(0.0, NEW_TILT), 1e-6, 1e-6)
    assert [o.source for o in outputs[-6:]] == ["vision"] * 6
    err = _errors(outputs, RETILT)
    assert np.abs(err).max() < 0.02, err  # the old camera pose would pitch the steps 10 deg


# -- /joint_states that do not serve ------------------------------------------------------
def _prefix(stream, t_s):
    return [(t, msg) for t, msg in stream if m.stamp_ns(msg) <= _stamp(t_s)]


@pytest.fixture(scope="module")
def drive_stream(pano_stream):
    """The drive up to the stop (no view): the camera at the drive pose throughout."""
    return _prefix(pano_stream, 20.0)


@pytest.fixture(scope="module")
def drive_run(drive_stream):
    return run(drive_stream, fw.rover_params())


def _same_poses(a, b):
    assert [o.stamp_ns for o in a] == [o.stamp_ns for o in b]
    assert max(np.linalg.norm(x.state.p - y.state.p) for x, y in zip(a, b, strict=True)) < 1e-9


def _warnings(logs, word):
    return [text for level, text in logs if level == logging.WARNING and word in text]


def test_no_joint_states_at_all_the_drive_pose_is_used(drive_stream, drive_run):
    stream = [(t, msg) for t, msg in drive_stream if t != m.TOPIC_JOINT_STATES]
    est, outputs, logs = run(stream, fw.rover_params())
    _same_poses(outputs, drive_run[1])  # the drive pose is rover.yaml's base_to_left_camera
    assert est.status()["frames_without_joint_states"] == len(outputs)
    said = _warnings(logs, "/joint_states")
    assert len(said) == 1 and "base_to_left_camera" in said[0], logs


def test_pairs_do_not_wait_for_joint_states_that_never_come(drive_stream):
    """Fed as a node is, without the end of a bag: a silent /joint_states holds a pair back
    for WAIT_PERIODS joint-state periods (10 Hz until two have come: 0.5 s) of the other
    inputs' stamps at most."""
    est = VoEstimator(VoConfig(), fw.rover_params(), lambda *_: None)
    waits = []
    for topic, msg in drive_stream:
        if topic != m.TOPIC_JOINT_STATES:
            waits += [(m.stamp_ns(msg) - o.stamp_ns) * 1e-9 for o in est.feed(topic, msg)]
    pairs = [f for f in PANO.frames if _stamp(f.t) <= m.stamp_ns(drive_stream[-1][1]) - 6e8]
    assert len(waits) == len(pairs)
    limit = WAIT_PERIODS * JOINT_STATE_PERIOD_S + 0.02  # and the IMU sample that shows it
    assert max(waits) <= limit, waits


def _renamed(stream, names):
    out = []
    for topic, msg in stream:
        if topic == m.TOPIC_JOINT_STATES:
            msg = copy.deepcopy(msg)
            msg.name = list(names)
        out.append((topic, msg))
    return out


def test_unknown_joint_names_are_named(drive_stream, drive_run):
    stream = _renamed(drive_stream, ["pan", "tilt"])
    with pytest.raises(MastError, match=r"'mast_pan' and 'mast_tilt'.*'pan', 'tilt'"):
        est = VoEstimator(VoConfig(), fw.rover_params(), lambda *_: None,
                          raise_joint_state_errors=True)
        for topic, msg in stream:
            est.feed(topic, msg)
    # The node's way: counted, said once, the odometry goes on at the drive pose.
    est, outputs, logs = run(stream, fw.rover_params())
    _same_poses(outputs, drive_run[1])
    assert est.counts.bad["bad_joint_state"] == sum(t == m.TOPIC_JOINT_STATES
                                                    for t, _ in stream)
    assert len(_warnings(logs, "'bad_joint_state'")) == 1
    assert est.status()["frames_without_joint_states"] == len(outputs)


def test_joint_stamps_away_from_the_images_are_no_joint_state(drive_stream, drive_run):
    """Joint states at 1 Hz, stamped 0.5 s off every pair (tolerance 0.1 s)."""
    stream = [(t, msg) for t, msg in drive_stream if t != m.TOPIC_JOINT_STATES
              or (m.stamp_ns(msg) - fw.START_NS) % 1_000_000_000 == 500_000_000]
    assert sum(t == m.TOPIC_JOINT_STATES for t, _ in stream) >= 15
    est, outputs, logs = run(stream, fw.rover_params())
    _same_poses(outputs, drive_run[1])
    assert est.counts.bad["stale_joint_states"] == len(outputs)
    assert est.status()["frames_without_joint_states"] == len(outputs)
    assert len(_warnings(logs, "'stale_joint_states'")) == 1


def test_a_mast_that_stops_publishing_keeps_its_last_angles(retilt_stream, retilt_run):
    """/joint_states stops while the rover drives at the new tilt: the odometry goes on at
    the last angles (the same poses; the drive pose would be a mast move), said once."""
    stop_s = RETILT.frames[-5].t - 0.5
    stream = [(t, msg) for t, msg in retilt_stream if t != m.TOPIC_JOINT_STATES
              or m.stamp_ns(msg) <= _stamp(stop_s)]
    est, outputs, logs = run(stream, fw.rover_params())
    _same_poses(outputs, retilt_run[1])
    assert est.counts.mast_moved == MAST_SETTLE_FRAMES
    assert est.status()["frames_without_joint_states"] == 5
    said = _warnings(logs, "/joint_states")
    assert len(said) == 1 and "last known joint angles" in said[0], logs


# -- the offline CLI and the evaluation --------------------------------------------------
def _truth_tum(schedule, path):
    """The truth at 10 Hz: the rover's x between the pairs, at rest on the ground."""
    t = np.arange(0.0, schedule.t + 1e-9, 0.1)
    x = np.interp(t, [f.t for f in schedule.frames], [f.x for f in schedule.frames])
    rows = [f"{fw.START_NS * 1e-9 + s:.9f} {v:.6f} 0 0 0 0 0 1" for s, v in zip(t, x,
                                                                               strict=True)]
    path.write_text("\n".join(rows) + "\n")
    return path


def test_offline_cli_reads_the_joint_states_and_measures_the_stop(pano_stream, tmp_path,
                                                                  capsys):
    bag = fw.write_bag(pano_stream, tmp_path / "flat_pano")
    assert cli.main(["odometry", str(bag), "--out", str(tmp_path / "vo")]) == 0
    printed = capsys.readouterr().out
    assert "mast: 6 pairs off the reference's camera pose" in printed
    import json

    report = json.loads((tmp_path / "vo" / "vo_report.json").read_text())
    assert report["mast"] and report["status"]["mast_moved_frames"] == 6
    # The stop as the evaluation measures it (a straight drive: evo's alignment of the
    # whole track is degenerate, so the stop figures alone).
    truth = read_tum_rows(_truth_tum(PANO, tmp_path / "truth.tum"))
    (stop,) = stop_drift(read_tum_rows(tmp_path / "vo" / "vo.tum"), truth)
    assert stop.poses == 9  # 1 s inside the stop's ends: its last drive pair is out
    assert stop.position_mm < 0.01 and stop.excursion_mm < 0.01 and abs(stop.yaw_deg) < 0.01
    assert stop.error_mm < 0.01 and abs(stop.yaw_error_deg) < 0.01


def test_offline_cli_exits_naming_unknown_joints(drive_stream, tmp_path, capsys):
    bag = fw.write_bag(_renamed(drive_stream, ["pan", "tilt"]), tmp_path / "renamed")
    assert cli.main(["odometry", str(bag), "--out", str(tmp_path / "vo")]) == 1
    err = capsys.readouterr().err
    assert "rosbag" in err and "'mast_pan'" in err and "field 'name'" in err, err


def test_stop_drift_sees_a_jump_that_comes_back_and_not_the_creep():
    """The truth drives along x at 1 m/s, stands from 5 s to 20 s; the estimate's last
    pair before the stop is at 4.5 s (the rover crept 0.5 m after it; the estimate is
    5 cm behind there), then it creeps at 1 mm/s through the stop and jumps 0.3 m at
    10-12 s and back."""
    truth = np.array([[t, min(t, 5.0) if t < 20 else 5.0 + (t - 20), 0, 0, 0, 0, 0, 1]
                      for t in np.arange(300) / 10.0])
    est = np.array([[4.5, 4.45, 0, 0, 0, 0, 0, 1]] + [
        [t, 5.0 + (0.3 if 10 <= t < 12 else 0.0) + 0.001 * (t - 6), 0, 0, 0, 0, 0, 1]
        for t in np.arange(6.0, 19.5, 1.0)])
    (d,) = stop_drift(est, truth)
    assert d.start_s == pytest.approx(5.0, abs=0.11) and d.end_s == pytest.approx(20.0,
                                                                               abs=0.11)
    assert d.position_mm == pytest.approx(1.0 * (d.poses - 1), abs=1e-6)  # 1 mm/s
    assert d.excursion_mm == pytest.approx(300 + 1.0 * 5, abs=1.0)
    # From the 4.5 s pose: the truth moved 0.5 m, the estimate 0.563 m.
    assert d.poses == 14 and d.error_mm == pytest.approx(63.0, abs=1e-3)
    assert d.yaw_error_deg == pytest.approx(0.0, abs=1e-9)


def test_a_standing_vision_pair_keeps_the_drive_step_for_the_resume():
    """A pair at a stop that the gyro does not call still (a blip) is measured by vision:
    its step is far below the drive speed, so the rover's last drive step, not that standing
    one, is what a lost track after the stop is retried with."""
    s = fw.Schedule().drive(6).stand(3)
    last = s.frames[-1].t
    stream = []
    for topic, msg in fw.stream(s):
        t = (m.stamp_ns(msg) - fw.START_NS) * 1e-9
        if topic == m.TOPIC_IMU and last - 1.0 < t <= last:
            msg = copy.deepcopy(msg)
            msg.angular_velocity.z += 0.02  # above the zero-velocity gyro threshold
        stream.append((topic, msg))
    est, outputs, _ = run(stream, fw.rover_params())
    assert outputs[-1].source == "vision" and outputs[-2].source == "zero_velocity"
    assert np.linalg.norm(est.last_step[1]) < 0.02  # the standing step
    assert np.linalg.norm(est.drive_step) == pytest.approx(0.35, abs=0.02)
    assert est.status()["drive_step_predictions"] == 0
