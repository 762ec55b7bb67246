"""The LN's drift relative to its anchor node (darces_matcher.ln_drift) and its use by the
matcher: the heading error at the anchor is absorbed by the alignment's rotation."""

from __future__ import annotations

import numpy as np
import pytest

from darces_matcher.ln_drift import PLANAR, NodeOdometry, planar_covariance, turn_variance
from darces_matcher.matcher import MatchConfig, Matcher
from roi_network.network import MapFrame, RoiNetwork
from roi_network.records import ROCK, empty_records


def _cov6(P3: np.ndarray) -> np.ndarray:
    """A ROS 36-value pose covariance holding the (x, y, yaw) block ``P3``."""
    c = np.eye(6) * 1e-6
    c[np.ix_(PLANAR, PLANAR)] = P3
    return c.ravel()


def _drive(n_steps: int, sigma_heading: float, sigma_step: float, P0: np.ndarray,
           rng: np.random.Generator | None = None, n_samples: int = 0):
    """A straight 1 m-step drive along x: the covariance (EKF, (n+1, 3, 3)) and, with a
    generator, ``n_samples`` noisy trajectories' (x, y, yaw) errors ((S, n+1, 3))."""
    P = [P0]
    Q = np.diag([sigma_step**2, sigma_step**2, sigma_heading**2])
    F = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 1.0], [0.0, 0.0, 1.0]])  # a step along x
    for _ in range(n_steps):
        P.append(F @ P[-1] @ F.T + Q)
    if rng is None:
        return np.array(P), None
    e = rng.multivariate_normal(np.zeros(3), P0, size=n_samples)
    err = [e]
    for _ in range(n_steps):
        w = rng.normal(0.0, [sigma_step, sigma_step, sigma_heading], size=(n_samples, 3))
        th = e[:, 2]
        e = np.stack([e[:, 0] + np.cos(th) - 1.0 + w[:, 0], e[:, 1] + np.sin(th) + w[:, 1],
                      th + w[:, 2]], axis=1)
        err.append(e)
    return np.array(P), np.stack(err, axis=1)


def test_planar_covariance_takes_x_y_yaw() -> None:
    P3 = np.array([[4.0, 1.0, 0.1], [1.0, 9.0, 0.2], [0.1, 0.2, 0.01]])
    np.testing.assert_allclose(planar_covariance(_cov6(P3)), P3)


def test_turn_variance_is_the_anchor_heading_times_the_lever() -> None:
    pts = np.array([[0.0, 0.0], [100.0, 0.0], [0.0, 50.0]])
    P = np.zeros((3, 3, 3))
    P[:, 2, 2] = [1e-4, 4e-4, 9e-4]  # the heading variance grows along the drive
    P[:, 0, 0] = P[:, 1, 1] = [1.0, 2.0, 3.0]
    tv = turn_variance(pts, P, anchor=0)
    # Per axis: half of sigma_theta^2 * lever^2, with the anchor's heading.
    np.testing.assert_allclose(tv, [0.0, 0.5 * 1e-4 * 100**2, 0.5 * 1e-4 * 50**2])
    # Anchored at the last node, each earlier node's own heading turns the anchor.
    tv = turn_variance(pts, P, anchor=2)
    np.testing.assert_allclose(tv, [0.5 * 1e-4 * 50**2, 0.5 * 4e-4 * (100**2 + 50**2), 0.0])


def test_the_model_matches_monte_carlo_drift_after_an_alignment() -> None:
    """Relative to the anchor, with its position and heading errors absorbed, the nodes'
    per-axis error variance is the records' growth less the turn: not the growth alone."""
    rng = np.random.default_rng(3)
    P0 = np.diag([4.0, 4.0, np.radians(1.0) ** 2])  # error accumulated before the LN
    sh, ss = np.radians(0.02), 0.01
    P, _ = _drive(300, sh, ss, P0, None)
    nodes = np.arange(100, 301, 25)
    pts = np.stack([nodes.astype(float), np.zeros(len(nodes))], axis=1)
    Pn = P[nodes]
    var_records = 0.5 * (Pn[:, 0, 0] + Pn[:, 1, 1])
    growth = var_records - var_records[0]
    model = growth - turn_variance(pts, Pn, anchor=0)
    _, err = _drive(300, sh, ss, P0, rng, n_samples=3000)
    e = err[:, nodes]
    lever = np.stack([-(pts[:, 1] - pts[0, 1]), pts[:, 0] - pts[0, 0]], axis=1)
    rel = e[:, :, :2] - e[:, :1, :2] - e[:, :1, 2:] * lever
    empirical = 0.5 * np.mean(np.sum(rel**2, axis=2), axis=0)
    np.testing.assert_allclose(model[1:], empirical[1:], rtol=0.15)
    # The growth alone holds the anchor's 1 deg heading error over 200 m: ~3.5 m.
    assert np.all(growth[-3:] > 5.0 * empirical[-3:])


def test_node_odometry_takes_the_mean_over_the_messages_a_node_moved_in() -> None:
    no = NodeOdometry()
    for t, s in ((0.0, 1.0), (1.0, 2.0), (2.0, 3.0), (3.0, 4.0)):
        no.add_odometry(t, _cov6(np.diag([s, s, 1e-4 * s])))
    no.add_odometry(2.5, _cov6(np.eye(3)))  # out of order: ignored
    no.add_odometry(3.5, np.full(36, np.nan))  # not finite: ignored
    no.add_ln(1.0, np.array([1]), np.array([[0.0, 0.0]]))
    no.add_ln(2.0, np.array([1, 2]), np.array([[0.0, 0.0], [5.0, 0.0]]))  # 1 did not move
    no.add_ln(3.0, np.array([1, 2]), np.array([[0.0, 0.0], [5.1, 0.0]]))  # 2 moved
    P = no.covariances(np.array([1, 2]))
    np.testing.assert_allclose(P[:, 0, 0], [2.0, 3.5])
    assert no.covariances(np.array([1, 3])) is None  # never seen


def test_a_late_start_leaves_the_nodes_of_the_first_ln_unknown() -> None:
    """A restarted matcher receives the whole latched LN at once: when its nodes were seen
    is unknown, and it must not take them all as seen now."""
    no = NodeOdometry()
    no.add_odometry(10.0, _cov6(np.eye(3)))
    no.add_ln(10.0, np.array([1, 2]), np.zeros((2, 2)))
    no.add_ln(11.0, np.array([1, 2, 3]), np.array([[0.0, 0], [0, 0], [9, 9]]))
    assert no.covariances(np.array([1, 2, 3])) is None
    assert no.covariances(np.array([3])) is not None
    # Before any odometry: unknown as well.
    fresh = NodeOdometry()
    fresh.add_ln(1.0, np.array([7]), np.zeros((1, 2)))
    assert fresh.covariances(np.array([7])) is None


@pytest.fixture(scope="module")
def straight_ln():
    """Nine rocks along a straight 400 m drive that began 500 m earlier with a 1 deg
    heading error; the records carry the odometry covariance since the start."""
    P0 = np.diag([4.0, 4.0, np.radians(1.0) ** 2])
    P, _ = _drive(400, np.radians(0.02), 0.01, P0, None)
    steps = np.arange(0, 401, 50)
    rec = empty_records(len(steps))
    rec["x"], rec["y"] = steps.astype(float), 3.0 * (-1.0) ** (steps // 50)
    rec["id"] = np.arange(1, len(steps) + 1)
    rec["label"] = ROCK
    rec["cov_xx"], rec["cov_yy"] = P[steps, 0, 0], P[steps, 1, 1]
    rec["cov_xy"] = P[steps, 0, 1]
    return rec, P[steps]


def test_matcher_node_sigma_absorbs_the_anchor_heading(straight_ln) -> None:
    rec, P = straight_ln
    gn = RoiNetwork(rec.copy(), "map", MapFrame("EPSG:32719", (0.0, 0.0)))
    m = Matcher(gn, MatchConfig())
    before = m.node_sigma(rec, None)
    after = m.node_sigma(rec, None, odom_cov=P)
    assert after[0] == pytest.approx(before[0])  # the anchor keeps its own error
    assert np.all(after <= before + 1e-9)
    assert before[-1] > 5.0 and after[-1] < 0.4 * before[-1]
    # Anchored at the newest node (once localized): the oldest node's sigma drops too.
    before_n = m.node_sigma(rec, None, anchor_newest=True)
    after_n = m.node_sigma(rec, None, anchor_newest=True, odom_cov=P)
    assert after_n[-1] == pytest.approx(before_n[-1])
    assert after_n[0] < 0.6 * before_n[0]
