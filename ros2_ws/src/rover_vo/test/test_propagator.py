"""IMU propagation: a pure rotation, the gyro bias from vision and at rest, bad samples."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from rover_vo.propagator import Propagator, ordered_product

RATE = 50.0


def feed(prop, t0, t1, rate, bias, noise=0.0, seed=0):
    rng = np.random.default_rng(seed)
    for t in np.arange(t0, t1, 1 / RATE):
        g = np.asarray(rate) + bias + rng.normal(0, noise, 3)
        prop.add(float(t), g, np.array([0, 0, 9.81]))


def test_pure_rotation_is_integrated():
    prop = Propagator(np.eye(3), 1.7e-4, 2e-5, 5e-3)
    feed(prop, 0.0, 10.0, [0, 0, np.radians(9.0)], np.zeros(3))  # 9 deg/s yaw
    iv = prop.interval(1.0, 4.0)
    yaw = Rotation.from_matrix(iv.R).as_euler("xyz", degrees=True)
    np.testing.assert_allclose(yaw, [0, 0, 27.0], atol=1e-6)
    assert iv.n == 150 and iv.gap <= 0.02 + 1e-9
    np.testing.assert_allclose(iv.mean_accel, [0, 0, 9.81])


def test_extrinsic_rotation_maps_imu_into_base():
    base_R_imu = Rotation.from_euler("x", 90, degrees=True).as_matrix()  # imu y = base z
    prop = Propagator(base_R_imu, 1.7e-4, 2e-5, 5e-3)
    feed(prop, 0.0, 3.0, [0, np.radians(10.0), 0], np.zeros(3))
    iv = prop.interval(0.0, 2.0)
    np.testing.assert_allclose(Rotation.from_matrix(iv.R).as_rotvec(),
                               [0, 0, np.radians(20.0)], atol=1e-6)


def test_bias_from_vision_rotation_converges():
    bias = np.array([0.002, -0.003, 0.004])
    prop = Propagator(np.eye(3), 1.7e-4, 2e-5, 5e-3)
    feed(prop, 0.0, 60.0, [0, 0, 0.02], bias, noise=1.2e-3)
    for k in range(19):  # a vision rotation every 3 s, 0.01 deg noise
        t0, t1 = 3.0 * k, 3.0 * (k + 1)
        true = Rotation.from_rotvec([0, 0, 0.02 * (t1 - t0)]).as_matrix()
        prop.update_bias_from_rotation(t0, t1, true, np.eye(3) * np.radians(0.01) ** 2)
    np.testing.assert_allclose(prop.bias, bias, atol=2e-4)


def test_bias_at_rest_is_mean_gyro():
    bias = np.array([0.002, -0.003, 0.004])
    prop = Propagator(np.eye(3), 1.7e-4, 2e-5, 5e-3)
    feed(prop, 0.0, 20.0, np.zeros(3), bias, noise=1.2e-3)
    iv = prop.interval(0.0, 20.0)
    prop.update_bias_at_rest(20.0, iv, RATE)
    # The estimate is the mean of the samples (the 5 mrad/s prior weighs nothing).
    np.testing.assert_allclose(prop.bias, iv.mean_gyro, atol=1e-6)
    np.testing.assert_allclose(prop.bias, bias, atol=4 * 1.2e-3 / np.sqrt(iv.n))
    # With the bias known, standing still integrates to the white noise's random walk only
    # (1.7e-4 rad/sqrt(s) over 10 s: 5e-4 rad), not the 0.054 rad the raw bias would give.
    assert Rotation.from_matrix(prop.interval(5.0, 15.0).R).magnitude() < 2e-3


def test_bad_samples_are_refused_by_kind():
    prop = Propagator(np.eye(3), 1.7e-4, 2e-5, 5e-3)
    ok = np.zeros(3)
    assert prop.add(1.0, ok, ok) is None
    assert prop.add(1.0, ok, ok) == "imu_duplicate"
    assert prop.add(0.5, ok, ok) == "imu_out_of_order"
    assert prop.add(1.1, np.array([np.nan, 0, 0]), ok) == "imu_nan"
    assert prop.add(1.2, ok, ok) is None
    assert prop.t == [1.0, 1.2]


def test_gap_is_reported():
    prop = Propagator(np.eye(3), 1.7e-4, 2e-5, 5e-3)
    feed(prop, 0.0, 1.0, np.zeros(3), np.zeros(3))
    feed(prop, 3.0, 4.0, np.zeros(3), np.zeros(3))
    assert prop.interval(0.5, 3.5).gap > 1.9


def test_ordered_product_matches_sequential():
    r = Rotation.random(37, random_state=1)
    seq = Rotation.identity()
    for x in r:
        seq = seq * x
    assert (ordered_product(r) * seq.inv()).magnitude() < 1e-9
