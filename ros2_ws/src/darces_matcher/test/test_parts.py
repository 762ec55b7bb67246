"""Building blocks: GN index, triplets, batched fit, simulation protocol, generator."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from darces_matcher.gn_generator import GnSpec, generate_gn
from darces_matcher.gn_index import GnIndex, label_code, triangle_sides
from darces_matcher.hypotheses import apply_batch, fit_rigid_batch
from darces_matcher.simulate import (
    SimOptions,
    TrajectoryEnumerator,
    degrade_gn,
    iter_lns,
    start_end_pairs,
)
from darces_matcher.triplets import control_triplets
from darces_matcher.vote import (
    _readmit,
    covering_covariance,
    fit_rigid,
    jackknife_covariance,
    leave_one_out_fits,
    leave_one_out_residual,
    pose_covariance,
    predicted_variance,
    transform_points,
    triplet_votes,
)
from roi_network.network import RoiNetwork
from roi_network.records import ROCK, empty_records, xy
from roi_network.transform import Rigid2D


def test_exhaustive_index_holds_every_non_degenerate_triangle() -> None:
    gn = generate_gn(GnSpec(n_rois=30), seed=0)
    index = GnIndex(gn, min_height_m=0.0)
    assert index.stats.n_triangles == math.comb(30, 3)
    assert np.all(np.diff(index.keys) >= 0)
    # Counter-clockwise, longest side first.
    p = index.pts[index.tri]
    u, v = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    cross = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    assert np.all(cross > 0)
    sides = triangle_sides(index.tri, index.pts)
    assert np.all(sides[:, 0] >= sides[:, 1:].max(axis=1) - 1e-4)


def test_congruent_finds_the_triangle_itself() -> None:
    gn = generate_gn(GnSpec(n_rois=60), seed=1)
    index = GnIndex(gn)
    rows = np.array([0, 17, len(index.tri) - 1])
    tri = index.tri[rows]
    codes = label_code(index.labels[tri], True)
    found, query = index.congruent(triangle_sides(tri, index.pts), np.full((3, 3), 0.5), codes)
    for q, row in enumerate(rows):
        assert row in found[query == q]


def test_local_index_respects_side_limit() -> None:
    gn = generate_gn(GnSpec(n_rois=2000, aspect=1.0), seed=1)
    index = GnIndex(gn, max_side_m=60.0)
    assert index.stats.max_side_m == 60.0
    assert triangle_sides(index.tri, index.pts).max() <= 60.0 + 1e-3
    assert index.stats.memory_bytes > 0 and index.stats.build_s > 0


@settings(max_examples=40, deadline=None)
@given(
    yaw=st.floats(-math.pi, math.pi),
    tx=st.floats(-1e4, 1e4),
    ty=st.floats(-1e4, 1e4),
    seed=st.integers(0, 1000),
)
def test_fit_rigid_batch_matches_rigid2d_fit(yaw: float, tx: float, ty: float, seed: int) -> None:
    rng = np.random.default_rng(seed)
    src = rng.uniform(-500, 500, (5, 2))
    truth = Rigid2D(yaw, tx, ty)
    dst = truth.apply(src) + rng.normal(0, 0.5, (5, 2))
    w = rng.uniform(0.1, 2.0, 5)
    yaw_b, t_b = fit_rigid_batch(src[None], dst[None], w[None])
    ref = Rigid2D.fit(src, dst, w)
    assert abs(math.remainder(yaw_b[0] - ref.yaw, 2 * math.pi)) < 1e-9
    assert np.allclose(t_b[0], ref.translation, atol=1e-6)
    mapped = apply_batch(yaw_b, t_b, src)[0]
    assert np.allclose(mapped, ref.apply(src), atol=1e-6)


def test_fit_never_reflects() -> None:
    src = np.array([[0.0, 0.0], [10.0, 0.0], [0.0, 5.0]])
    mirrored = src * np.array([-1.0, 1.0])
    yaw, t = fit_rigid_batch(src[None], mirrored[None])
    fitted = apply_batch(yaw, t, src)[0]
    # A proper rotation cannot reproduce the mirror image.
    assert np.abs(fitted - mirrored).max() > 1.0


def test_control_triplets_are_ccw_and_non_degenerate() -> None:
    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 300, (20, 2))
    tol = rng.uniform(0.5, 3, 20)
    trip = control_triplets(pts, tol, 10, min_side_m=10.0, max_side_m=np.inf,
                            min_height_ratio=1.0, max_uses_per_node=3)
    assert 0 < len(trip) <= 10
    p = pts[trip]
    u, v = p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]
    cross = u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0]
    assert np.all(cross > 0)
    assert np.bincount(trip.ravel()).max() <= 3


def test_control_triplets_none_for_collinear() -> None:
    pts = np.column_stack([np.arange(8) * 20.0, np.zeros(8)])
    trip = control_triplets(pts, np.ones(8), 5, min_side_m=10.0, max_side_m=np.inf,
                            min_height_ratio=1.0, max_uses_per_node=3)
    assert trip.shape == (0, 3)


def test_control_triplets_keep_the_dense_ones_aside() -> None:
    rng = np.random.default_rng(4)
    pts = rng.uniform(0, 300, (20, 2))
    tol = np.ones(20)
    counts: dict[tuple[int, ...], float] = {}

    def cost(trips: np.ndarray) -> np.ndarray:
        # A made-up count per triplet: 0 (a vertex without counterpart), selective
        # (<= 100), dense (<= 3,000) or beyond even the dense cap.
        out = np.array([[0, 50, 400, 2000, 9000][int(t.sum()) % 5] for t in trips], float)
        counts.update({tuple(t): c for t, c in zip(trips.tolist(), out, strict=True)})
        return out

    dense: list[np.ndarray] = []
    trip = control_triplets(pts, tol, 6, min_side_m=10.0, max_side_m=np.inf,
                            min_height_ratio=1.0, max_uses_per_node=3, cost=cost,
                            max_cost=100, max_dense_cost=3000, dense_out=dense)
    assert len(dense) == 1
    assert 0 < len(trip) <= 6 and 0 < len(dense[0]) <= 6
    assert all(counts[tuple(t)] == 50 for t in trip.tolist())
    kept = [counts[tuple(t)] for t in dense[0].tolist()]
    assert all(100 < k <= 3000 for k in kept)
    assert kept == sorted(kept)
    # Without dense_out nothing changes.
    assert np.array_equal(trip, control_triplets(
        pts, tol, 6, min_side_m=10.0, max_side_m=np.inf, min_height_ratio=1.0,
        max_uses_per_node=3, cost=cost, max_cost=100))


def test_a_hypothesis_on_the_neighbouring_rock_votes_for_its_alignment() -> None:
    rng = np.random.default_rng(5)
    ln = rng.uniform(0, 200, (10, 2))
    gate = np.full(10, 2.5)
    fix_mapped = ln + np.array([1000.0, 500.0])
    fix_ln, fix_gn = np.arange(10), np.arange(10) + 100
    # Hypothesis 0 (triplet 0): the fix's own pairs. 1 (triplet 1): same alignment to
    # within 1 m, one vertex on another GN node (the neighbouring rock). 2 (triplet 2):
    # one vertex on another node and the alignment 20 m off at some node.
    ln_idx = np.array([[0, 1, 2], [3, 4, 5], [6, 7, 8]])
    gn_idx = np.array([[100, 101, 102], [103, 104, 999], [106, 107, 998]])
    source = np.array([0, 1, 2])
    mapped = np.stack([fix_mapped, fix_mapped + 1.0, fix_mapped.copy()])
    mapped[2, 9] += 20.0
    votes = triplet_votes(ln_idx, gn_idx, source, mapped, fix_ln, fix_gn, fix_mapped,
                          gate, same_ratio=1.0)  # every node within its gate: the matcher's
    assert votes == 2
    # (1 m, 1 m) is 0.57 gates at every node: the same alignment at 0.6 gates, not at 0.5.
    assert triplet_votes(ln_idx, gn_idx, source, mapped, fix_ln, fix_gn, fix_mapped,
                         gate, same_ratio=0.6) == 2
    assert triplet_votes(ln_idx, gn_idx, source, mapped, fix_ln, fix_gn, fix_mapped,
                         gate, same_ratio=0.5) == 1
    # By pairs alone (no alignment tolerance), only the first votes.
    assert triplet_votes(ln_idx, gn_idx, source, mapped, fix_ln, fix_gn, fix_mapped,
                         gate, same_ratio=0.0) == 1
    assert triplet_votes(ln_idx[:0], gn_idx[:0], source[:0], mapped[:0], fix_ln, fix_gn,
                         fix_mapped, gate, same_ratio=1.0) == 0


def test_simulation_follows_the_protocol() -> None:
    gn = generate_gn(GnSpec(n_rois=120), seed=3)
    pts = xy(gn.records)
    options = SimOptions()
    pairs = start_end_pairs(pts)
    d = np.linalg.norm(pts[pairs[:, 0]] - pts[pairs[:, 1]], axis=1)
    assert np.all((d >= 600) & (d <= 1000))
    enum = TrajectoryEnumerator(pts, options, seed=0)
    n_traj = 0
    for s, e in pairs[:200]:
        for traj in enum.trajectories(int(s), int(e)):
            n_traj += 1
            assert traj[0] == s and traj[-1] == e
            assert 19 <= len(traj) <= 29
            assert len(set(traj.tolist())) == len(traj)
            assert np.linalg.norm(np.diff(pts[traj], axis=0), axis=1).sum() < 1000
    assert n_traj > 0
    lns = list(iter_lns(gn, options, seed=5, max_lns=10))
    again = list(iter_lns(gn, options, seed=5, max_lns=10))
    assert len(lns) == 10
    for sim, twin in zip(lns, again, strict=True):
        assert np.array_equal(sim.records, twin.records)
        n = len(sim.trajectory)
        assert len(sim.records) == n - round(0.2 * n)
        # Drift never exceeds 1 % of the distance travelled (< 1 km).
        odom_true = sim.map_T_odom.inverse().apply(pts[sim.truth_gn])
        assert np.linalg.norm(xy(sim.records) - odom_true, axis=1).max() <= 10.0
        assert np.allclose(sim.sigma**2, sim.records["cov_xx"], rtol=1e-5, atol=1e-9)


def test_stress_options() -> None:
    gn = generate_gn(GnSpec(n_rois=120), seed=3)
    sim = next(iter_lns(gn, SimOptions(outliers=0.3, label_flips=0.1), seed=1))
    true = sim.truth_gn >= 0
    n_true = int(true.sum())
    assert (~true).sum() == round(0.3 * n_true)
    flipped = sim.records["label"][true] != gn.records["label"][sim.truth_gn[true]]
    assert flipped.sum() == round(0.1 * n_true)
    degraded, kept = degrade_gn(gn, 0.25, seed=0)
    assert len(degraded) == len(gn) - 30
    assert np.array_equal(degraded.records["id"], gn.records["id"][kept])


@pytest.mark.parametrize("n", [10, 174, 3000])
def test_generator_size_and_labels(n: int) -> None:
    gn = generate_gn(GnSpec(n_rois=n), seed=0)
    assert len(gn) == n and gn.frame_id == "map"
    assert set(np.unique(gn.records["label"])) <= {1, 2}
    w, h = GnSpec(n_rois=n).extent_m
    assert xy(gn.records).min() >= 0 and gn.records["x"].max() <= w and gn.records["y"].max() <= h


def test_class_lifted_queries_match_per_class_trees() -> None:
    """The single class-lifted KD-tree answers exactly like one tree per class."""
    gn = generate_gn(GnSpec(n_rois=150), seed=4)
    index = GnIndex(gn)
    rng = np.random.default_rng(0)
    labels = rng.choice(np.array(sorted(index.label_trees)), size=40)
    pts = index.pts[rng.integers(0, len(index.pts), 40)] + rng.normal(0, 6, (40, 2))
    batch = np.stack([pts, pts + 3.0])
    lifted = index.label_groups(labels)
    per_class = index._per_class_groups(labels)
    for k in (1, 3):
        for radius in (5.0, 40.0):
            d1, i1 = index.nearest_same_label(batch, lifted, radius, k=k)
            d2, i2 = index.nearest_same_label(batch, per_class, radius, k=k)
            np.testing.assert_allclose(d1, d2)
            np.testing.assert_array_equal(i1, i2)
            found = i1 >= 0
            lab = np.broadcast_to(labels[:, None] if k > 1 else labels, i1.shape)
            assert np.all(index.labels[i1[found]] == lab[found])
    # A radius the lift cannot separate falls back to the per-class trees.
    d3, i3 = index.nearest_same_label(pts, lifted, 1e9)
    d4, i4 = index.nearest_same_label(pts, per_class, 1e9)
    np.testing.assert_array_equal(i3, i4)
    np.testing.assert_allclose(d3, d4)


@settings(max_examples=30, deadline=None)
@given(st.floats(-math.pi, math.pi), st.integers(3, 25), st.integers(0, 10_000))
def test_single_fit_and_leave_one_out_match_the_batched_fit(yaw: float, k: int,
                                                            seed: int) -> None:
    rng = np.random.default_rng(seed)
    src = rng.uniform(-400, 400, (k, 2))
    dst = transform_points(yaw, np.array([1500.0, -300.0]), src) + rng.normal(0, 2, (k, 2))
    w = rng.uniform(0.05, 5.0, k)
    yaw_b, t_b = fit_rigid_batch(src[None], dst[None], w[None])
    yaw_1, t_1 = fit_rigid(src, dst, w)
    assert abs(math.remainder(yaw_1 - yaw_b[0], 2 * math.pi)) < 1e-9
    np.testing.assert_allclose(t_1, t_b[0], atol=1e-6)
    # Leave-one-out residuals: the fit of the other pairs, done one by one.
    miss = leave_one_out_residual(src, dst, w)
    for i in range(k):
        rest = np.arange(k) != i
        y_i, t_i = fit_rigid(src[rest], dst[rest], w[rest])
        expected = np.linalg.norm(transform_points(y_i, t_i, src[i:i + 1])[0] - dst[i])
        assert abs(miss[i] - expected) < 1e-6


@settings(max_examples=20, deadline=None)
@given(st.floats(-math.pi, math.pi), st.integers(4, 25), st.integers(0, 10_000))
def test_leave_one_out_fits_and_jackknife_covariance(yaw: float, k: int, seed: int) -> None:
    rng = np.random.default_rng(seed)
    src = rng.uniform(-400, 400, (k, 2))
    dst = transform_points(yaw, np.array([1500.0, -300.0]), src) + rng.normal(0, 2, (k, 2))
    w = rng.uniform(0.05, 5.0, k)
    yaws, ts = leave_one_out_fits(src, dst, w)
    theta = []
    for i in range(k):
        rest = np.arange(k) != i
        y_i, t_i = fit_rigid(src[rest], dst[rest], w[rest])
        assert abs(math.remainder(yaws[i] - y_i, 2 * math.pi)) < 1e-9
        np.testing.assert_allclose(ts[i], t_i, atol=1e-6)
        theta.append([t_i[0], t_i[1], math.remainder(y_i - yaws[0], 2 * math.pi)])
    d = np.array(theta) - np.mean(theta, axis=0)
    np.testing.assert_allclose(jackknife_covariance(src, dst, w), (k - 1) / k * d.T @ d,
                               rtol=1e-6, atol=1e-12)


def test_jackknife_agrees_with_the_weights_on_a_sound_fit_and_not_on_a_lone_pull() -> None:
    """Many pairs of one precision: the jackknife's position variance is about the
    analytic one. One precise pair far from the rest, displaced: the analytic covariance
    says that pair's position is known to its own sigma; the jackknife's covers the
    displacement. covering_covariance is at least both."""
    rng = np.random.default_rng(3)
    src = rng.uniform(-100, 100, (30, 2))
    ratios = []
    for _ in range(200):
        dst = src + rng.normal(0.0, 1.0, src.shape)
        w = np.ones(len(src))
        yaw, _ = fit_rigid(src, dst, w)
        a = pose_covariance(src, yaw, w)
        b = jackknife_covariance(src, dst, w)
        ratios.append(b[0, 0] / a[0, 0])
    assert 0.8 < np.mean(ratios) < 1.3
    src = np.vstack([rng.uniform(-50, 50, (12, 2)), [[400.0, 0.0]]])
    dst = src.copy()
    dst[-1] += [0.0, 12.0]  # the lone pair, 12 m off where the others put it
    w = np.r_[np.full(12, 1.0 / 3.4**2), 1.0 / 0.3**2]
    yaw, t = fit_rigid(src, dst, w)
    a = pose_covariance(src, yaw, w)
    c = covering_covariance(a, jackknife_covariance(src, dst, w))
    for cov in (a, jackknife_covariance(src, dst, w)):
        assert np.linalg.eigvalsh(c - cov).min() > -1e-9
    lone = src[-1:]
    pull = np.linalg.norm(transform_points(yaw, t, lone) - lone)  # vs the others' fit
    assert pull > 8.0
    assert np.sqrt(predicted_variance(lone, yaw, a)[0]) < 1.0
    assert np.sqrt(predicted_variance(lone, yaw, c)[0]) > pull / 3.0
    assert jackknife_covariance(src[:3], dst[:3], w[:3])[0, 0] == np.inf


def _readmit_case() -> tuple[GnIndex, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """A GN grid, an LN of its nodes, a precise first node and drifted others."""
    g = np.array([(x, y) for x in range(0, 400, 40) for y in range(0, 160, 40)], float)
    records = empty_records(len(g))
    records["x"], records["y"], records["label"] = g[:, 0], g[:, 1], ROCK
    index = GnIndex(RoiNetwork(records, "map"))
    ln = g[[0, 5, 10, 15, 20, 25, 30, 35]].copy()
    gate = np.array([2.5] + [12.0] * 7)
    weights = 1.0 / np.array([0.13] + [16.0] * 7)
    return index, ln, gate, weights, np.array([0, 5, 10, 15, 20, 25, 30, 35])


def test_readmit_takes_back_a_precise_node_just_outside_its_gate() -> None:
    index, ln, gate, weights, truth = _readmit_case()
    groups = index.label_groups(np.full(len(ln), ROCK))
    # A fit 3.5 m off at the precise first node (gate 2.5 m), within the others' gates.
    yaw, t = 0.0, np.array([3.5, 0.0])
    mapped = transform_points(yaw, t, ln)
    ln_in, gn_in = np.arange(1, len(ln)), truth[1:]
    _, t2, ln2, gn2 = _readmit(index, ln, groups, gate, weights, 30.0, yaw, t, ln_in,
                               gn_in, mapped)
    assert len(ln2) == len(ln)
    np.testing.assert_array_equal(gn2, truth)
    assert np.linalg.norm(t2) < 0.5


def test_readmit_leaves_fits_with_outliers_alone() -> None:
    index, ln, gate, weights, truth = _readmit_case()
    # One more LN node far from every GN node: an outlier; then nothing is readmitted.
    ln = np.vstack([ln, [20.0, 20.0]])
    gate = np.append(gate, 2.5)
    weights = np.append(weights, 1.0 / 0.13)
    groups = index.label_groups(np.full(len(ln), ROCK))
    yaw, t = 0.0, np.array([3.5, 0.0])
    ln_in, gn_in = np.arange(1, len(ln) - 1), truth[1:]
    out = _readmit(index, ln, groups, gate, weights, 30.0, yaw, t, ln_in, gn_in,
                   transform_points(yaw, t, ln))
    np.testing.assert_array_equal(out[2], ln_in)
    np.testing.assert_array_equal(out[1], t)


def test_pose_covariance_is_the_inverse_information() -> None:
    # The closed-form inverse against numpy's, on random weighted point sets.
    rng = np.random.default_rng(0)
    for _ in range(50):
        pts = rng.normal(size=(7, 2)) * 300 + rng.normal(size=2) * 500
        w, yaw = rng.uniform(0.01, 10, 7), rng.uniform(-3, 3)
        c, s = math.cos(yaw), math.sin(yaw)
        rx, ry = c * pts[:, 0] - s * pts[:, 1], s * pts[:, 0] + c * pts[:, 1]
        sw, swx, swy, sww = w.sum(), w @ rx, w @ ry, w @ (rx * rx + ry * ry)
        info = np.array([[sw, 0, -swy], [0, sw, swx], [-swy, swx, sww]])
        np.testing.assert_allclose(pose_covariance(pts, yaw, w), np.linalg.inv(info),
                                   rtol=1e-6, atol=1e-15)
    # One repeated point: rotation undetermined, infinitely loose.
    cov = pose_covariance(np.array([[1.0, 2.0]] * 3), 0.3, np.ones(3))
    assert np.all(np.isinf(np.diag(cov)))
