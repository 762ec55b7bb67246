"""Motion estimation on a synthetic stereo scene with known motion (no images needed)."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from rover_vo.config import MotionOptions
from rover_vo.motion import estimate_motion, refine_motion
from rover_vo.reconstruction import ground_disparity, triangulate_disparity

K = np.array([[772.5, 0, 319.5], [0, 772.5, 239.5], [0, 0, 1.0]])
B = 0.2


def project(X):
    return np.column_stack([K[0, 0] * X[:, 0] / X[:, 2] + K[0, 2],
                            K[1, 1] * X[:, 1] / X[:, 2] + K[1, 2]])


def scene(seed=0, n=300):
    rng = np.random.default_rng(seed)
    X = np.column_stack([rng.uniform(-4, 4, n), rng.uniform(-0.5, 1.6, n), rng.uniform(2, 20, n)])
    return rng, X


def observe(rng, X, R, t, noise_px=0.3):
    Xc = X @ R.T + t
    uv_l = project(Xc) + rng.normal(0, noise_px, (len(X), 2))
    uv_r = project(Xc - [B, 0, 0]) + rng.normal(0, noise_px, (len(X), 2))
    return uv_l, uv_r


def test_recovers_known_motion_with_outliers():
    rng, X = scene()
    R = Rotation.from_euler("xyz", [0.4, -2.0, 0.7], degrees=True).as_matrix()
    t = np.array([0.05, -0.02, -0.45])  # 0.45 m forward, as between two bag frames
    uv_l, uv_r = observe(rng, X, R, t)
    bad = rng.choice(len(X), 60, replace=False)  # 20 % gross outliers
    uv_l[bad] += rng.uniform(-40, 40, (60, 2))
    est = estimate_motion(X, uv_l, uv_r, K, B, MotionOptions())
    assert est is not None
    assert np.linalg.norm(est.t - t) < 0.01
    assert np.degrees(Rotation.from_matrix(est.R @ R.T).magnitude()) < 0.05
    assert not est.inliers[bad].any() or est.inliers[bad].mean() < 0.05
    assert est.inliers.sum() > 200
    # The covariance is a real one: positive definite, translation sigma in mm..cm.
    sig = np.sqrt(np.diag(est.cov))
    assert np.all(np.linalg.eigvalsh(est.cov) > 0)
    assert 1e-4 < sig[3:].max() < 0.05


def test_rotation_prior_pulls_toward_gyro():
    rng, X = scene(1, 40)
    R = Rotation.from_euler("y", 3.0, degrees=True).as_matrix()
    t = np.array([0.0, 0.0, -0.4])
    uv_l, uv_r = observe(rng, X, R, t, noise_px=1.5)
    free = refine_motion(X, uv_l, uv_r, K, B, np.eye(3), np.zeros(3), MotionOptions())
    prior = refine_motion(X, uv_l, uv_r, K, B, np.eye(3), np.zeros(3), MotionOptions(),
                          R_prior=R, prior_cov=np.eye(3) * np.radians(0.001) ** 2)
    err = lambda e: Rotation.from_matrix(e.R @ R.T).magnitude()  # noqa: E731
    assert err(prior) < 0.2 * err(free)
    assert np.trace(prior.cov[:3, :3]) < np.trace(free.cov[:3, :3])


def test_too_few_points_is_no_estimate():
    rng, X = scene(2, 10)
    uv_l, uv_r = observe(rng, X, np.eye(3), np.zeros(3))
    assert estimate_motion(X, uv_l, uv_r, K, B, MotionOptions()) is None


def test_triangulation_inverts_projection():
    rng, X = scene(3, 50)
    uv_l, uv_r = observe(rng, X, np.eye(3), np.zeros(3), noise_px=0.0)
    back = triangulate_disparity(uv_l, uv_l[:, 0] - uv_r[:, 0], K[0, 0], K[1, 1], K[0, 2],
                                 K[1, 2], B)
    np.testing.assert_allclose(back, X, rtol=1e-9, atol=1e-9)


def test_ground_disparity_of_flat_ground():
    # Camera 1.54 m up, tilted 20 deg down: the image centre row sees the ground at
    # 1.54 / sin(20 deg) = 4.50 m along the axis.
    d = ground_disparity(np.array([239.5, -400.0]), 772.5, 239.5, 1.54, np.radians(20.0),
                         772.5, B)
    assert abs(d[0] - 772.5 * B / (1.54 / np.sin(np.radians(20)))) < 1e-6
    assert d[1] == 3.0  # above the horizon
