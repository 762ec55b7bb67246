"""No start-up wait: a pair is processed as soon as the IMU covers it (and, on a mast, a
joint state), each input waited for a few of its own periods at most
(``rover_vo.arrivals``). Fed as the node is fed (no end-of-bag flush), the first pose
comes within 0.5 s of bag time of the first pair."""

from __future__ import annotations

import numpy as np
import pytest
import vo_flatworld as fw

from rover_vo import messages as m
from rover_vo.arrivals import WAIT_FRAMES, WAIT_PERIODS, Arrivals
from rover_vo.config import VoConfig
from rover_vo.estimator import VoEstimator
from rover_vo.testing import run

#: A short drive: 4 pairs 1 s apart, IMU from 1 s before the first to 0.5 s after the last
#: (4.5 s of bag, less than the 5 s the odometry once waited for before its first pose).
SHORT = fw.Schedule(period_s=1.0).drive(4)


@pytest.fixture(scope="module")
def short_stream():
    return fw.stream(SHORT)


def live(messages, params, config=None):
    """Feed as the node does, never calling ``finish``: ``[(output, bag time it came)]``,
    the bag time being the stamp of the message that released it."""
    est = VoEstimator(config or VoConfig(), params, lambda *_: None)
    out = []
    for topic, msg in messages:
        out += [(o, m.stamp_ns(msg)) for o in est.feed(topic, msg)]
    return est, out


def _first_pair_ns(messages):
    return min(m.stamp_ns(msg) for t, msg in messages if t == m.TOPIC_LEFT)


def test_the_first_pose_comes_with_the_first_pairs_imu(tiny_messages, tiny_params, clean_run):
    """On the tiny bag (the simulator's, 50 Hz IMU): every pose within one IMU period of
    its pair, the first among them; the same poses as the offline run."""
    _, timed = live(tiny_messages, tiny_params)
    _, offline, _ = clean_run
    assert [o.stamp_ns for o, _ in timed] == [o.stamp_ns for o in offline]
    assert timed[0][0].stamp_ns == _first_pair_ns(tiny_messages)
    waits = [(when - o.stamp_ns) * 1e-9 for o, when in timed]
    assert max(waits) <= 0.02 + 1e-9, max(waits)  # measured: 0.00 s
    for (o, _), r in zip(timed, offline, strict=True):
        assert np.array_equal(o.state.p, r.state.p)


def test_a_short_bag_gives_every_pose_without_its_end(short_stream):
    """4.5 s of a mast rover (joint states at 10 Hz): each pair's pose comes at its IMU
    sample, all four before the bag ends."""
    _, timed = live(short_stream, fw.rover_params())
    assert len(timed) == len(SHORT.frames)
    waits = [(when - o.stamp_ns) * 1e-9 for o, when in timed]
    assert timed[0][0].stamp_ns == _first_pair_ns(short_stream)
    assert max(waits) < 0.5, waits
    _, flushed, _ = run(short_stream, fw.rover_params())
    for (o, _), r in zip(timed, flushed, strict=True):
        assert np.array_equal(o.state.p, r.state.p)


def test_a_dead_imu_holds_a_pair_a_few_imu_periods(short_stream):
    """The IMU stops after the first pair: the later pairs wait WAIT_PERIODS IMU periods
    (0.1 s at 50 Hz) of the joint states' stamps, then go on without the gyro (counted)."""
    cut = _first_pair_ns(short_stream) + 500_000_000
    stream = [(t, msg) for t, msg in short_stream if t != m.TOPIC_IMU or m.stamp_ns(msg) < cut]
    est, timed = live(stream, fw.rover_params())
    assert len(timed) == len(SHORT.frames)
    waits = [(when - o.stamp_ns) * 1e-9 for o, when in timed[1:]]
    assert max(waits) <= WAIT_PERIODS * 0.02 + 0.1 + 1e-6, waits  # + one joint period
    assert min(waits) > WAIT_PERIODS * 0.02 - 1e-6, waits
    assert est.counts.bad["imu_gap"] == len(SHORT.frames) - 1


def test_a_dead_right_camera_holds_a_left_image_two_frames(short_stream):
    stream = [(t, msg) for t, msg in short_stream if t != m.TOPIC_RIGHT]
    est, timed = live(stream, fw.rover_params())
    # The first left image waits for two newer ones; the last two are left at the end.
    assert est.counts.bad["missing_right"] == len(SHORT.frames) - WAIT_FRAMES
    assert timed == []  # no pose without a first stereo pair
    assert est.counts.pairs == len(SHORT.frames) - WAIT_FRAMES


def test_arrivals_period_and_overdue():
    a = Arrivals({"imu": 0.02})
    assert a.period("imu") == 0.02 and a.period("joints") is None
    for k in range(10):
        a.note("imu", 100.0 + 0.005 * k)  # 200 Hz
    a.note("imu", 99.0)  # older: the newest stays
    assert a.newest("imu") == pytest.approx(100.045)
    assert a.period("imu") == pytest.approx(0.005)
    assert a.covers("imu", 100.045) and not a.covers("imu", 100.05)
    a.note("left", 100.06)
    assert not a.overdue("imu", 100.05)  # 10 ms: two IMU periods
    a.note("left", 100.08)
    assert a.overdue("imu", 100.05)  # 30 ms: six
    assert a.newer("left", 100.06) == 1
    assert not Arrivals().overdue("imu", 0.0)  # nothing else has come
