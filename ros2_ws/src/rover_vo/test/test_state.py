"""The odometry error state: random walks plus the two systematic errors."""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from rover_vo.state import OdomState, step_noise, systematic_prior


def drive(state: OdomState, steps: int, step_m: float, yaw_per_step: float = 0.0) -> OdomState:
    dR = Rotation.from_euler("z", yaw_per_step).as_matrix()
    Q = step_noise(step_m, 0.01, 0.02)
    for _ in range(steps):
        state = state.compose(state.t + 0.1, dR, np.array([step_m, 0.0, 0.0]), Q)
    return state


def test_scale_error_grows_along_track_linearly():
    """With a scale prior the along-track sigma is at least scale_sigma x distance; without
    it, only the random walk's sqrt growth."""
    free = drive(OdomState(0.0), 1000, 0.5)
    scaled = drive(OdomState(0.0, P=systematic_prior(0.003, 0.0)), 1000, 0.5)
    along_free, along = np.sqrt(free.cov[0, 0]), np.sqrt(scaled.cov[0, 0])
    assert scaled.distance_m == 500.0
    assert along >= 0.003 * 500.0 and along_free < 0.5 * along
    # The cross-track and heading blocks do not see a scale error on a straight line.
    np.testing.assert_allclose(scaled.cov[1:, 1:], free.cov[1:, 1:], rtol=1e-9, atol=1e-12)


def test_heading_rate_bias_grows_heading_sigma_linearly():
    rate = 0.05  # deg / 100 m
    biased = drive(OdomState(0.0, P=systematic_prior(0.0, rate)), 2000, 0.5)
    free = drive(OdomState(0.0), 2000, 0.5)
    extra = np.degrees(np.sqrt(biased.cov[5, 5] - free.cov[5, 5]))
    np.testing.assert_allclose(extra, rate * 10.0, rtol=1e-6)  # 1000 m
    assert biased.cov[1, 1] > free.cov[1, 1]  # and the cross-track error with it


def test_published_covariance_is_the_pose_block_and_symmetric():
    s = drive(OdomState(0.0, P=systematic_prior(0.003, 0.05)), 200, 0.45, yaw_per_step=0.01)
    assert s.P.shape == (8, 8) and s.cov.shape == (6, 6)
    np.testing.assert_array_equal(s.cov, s.P[:6, :6])
    np.testing.assert_allclose(s.P, s.P.T)
    assert np.all(np.linalg.eigvalsh(s.P) > -1e-12)
    c = s.copy()
    c.P[0, 0] += 1.0
    assert s.P[0, 0] != c.P[0, 0]
