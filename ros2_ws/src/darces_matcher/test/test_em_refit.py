"""The probabilistic (EM) refit: annealing, recovery from a misplaced start, outliers."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from darces_matcher.em_refit import EmModel, anneal_schedule, em_refit, gn_density
from darces_matcher.gn_generator import GnSpec, generate_gn
from darces_matcher.matcher import MatchConfig, Matcher
from roi_network.records import xy
from roi_network.transform import Rigid2D


def test_anneal_schedule_halves_down_to_half_a_metre_then_zero() -> None:
    assert anneal_schedule(4.0) == [4.0, 2.0, 1.0, 0.5, 0.0]
    assert anneal_schedule(0.0) == [0.0]


def test_gn_density_is_count_over_hull_area() -> None:
    square = np.array([[0.0, 0.0], [100.0, 0.0], [100.0, 100.0], [0.0, 100.0], [50.0, 50.0]])
    assert math.isclose(gn_density(square), 5 / 1e4)
    # A collinear GN has no hull: the bounding box (at least 1 m wide) stands in.
    line = np.column_stack([np.linspace(0, 100, 5), np.zeros(5)])
    assert math.isclose(gn_density(line), 5 / 100.0)


def _scene(outliers: int = 0):
    gn = generate_gn(GnSpec(n_rois=120), seed=3)
    pts, labels = xy(gn.records), gn.records["label"].astype(np.int64)
    tree = cKDTree(pts)
    # An LN of 14 GN nodes along x, the first one precise, the others drifted (sigma 2 m),
    # seen in an odom frame; positions noiseless so the true fit is exact.
    nodes = np.argsort(pts[:, 0])[::8][:14]
    map_T_odom = Rigid2D(0.7, -250.0, 40.0)
    ln = map_T_odom.inverse().apply(pts[nodes])
    ln_labels = labels[nodes]
    sigma = np.full(len(nodes), 2.0)
    sigma[0] = 0.2
    if outliers:
        rng = np.random.default_rng(1)
        fake = ln[rng.integers(1, len(nodes), outliers)] + rng.uniform(-20, 20, (outliers, 2))
        ln = np.vstack([ln, fake])
        ln_labels = np.concatenate([ln_labels, np.ones(outliers, dtype=np.int64)])
        sigma = np.concatenate([sigma, np.full(outliers, 2.0)])
    var = sigma**2 + 0.3**2
    model = EmModel(tree, labels, ln, ln_labels, var, 0.3 / 0.7 * gn_density(pts), 0.1)
    return model, nodes, map_T_odom


def test_em_recovers_the_fit_from_a_start_metres_off() -> None:
    model, nodes, truth = _scene()
    # Start 6 m and 1.5 deg off: the precise node is far outside a 2.5 m gate, and the
    # plain EM (no annealing) stays where it starts.
    start_yaw, start_t = truth.yaw + math.radians(1.5), np.array([truth.tx + 6.0, truth.ty])
    _, plain_t, _ = model.run(start_yaw, start_t, [0.0], 8)
    assert np.linalg.norm(plain_t - [truth.tx, truth.ty]) > 5.0
    fit = em_refit(model, start_yaw, start_t, anneal_start_m=4.0, iterations=4)
    # The mixture's maximum, not a hard least-squares fit: the GN neighbours of the
    # sigma = 2 m nodes keep a little weight, a few centimetres (3 % of sigma) here.
    mapped = Rigid2D(fit.yaw, *fit.t).apply(model.pts[: len(nodes)])
    assert np.abs(mapped - model.gn_pts[nodes]).max() < 0.1
    # Every LN node paired with its own GN node, one to one.
    assert np.array_equal(fit.ln, np.arange(len(nodes)))
    assert np.array_equal(fit.gn, nodes)
    _, _, start_loglik, _ = model.hard_pairs(start_yaw, start_t)
    assert fit.log_likelihood > start_loglik


def test_em_keeps_false_detections_from_moving_an_exact_fit() -> None:
    model, nodes, truth = _scene(outliers=5)
    fit = em_refit(model, truth.yaw, np.array([truth.tx, truth.ty]),
                   anneal_start_m=4.0, iterations=4)
    # The true pairs are all kept; a false detection is paired only when it happens to
    # land near an unclaimed GN node, and then it barely moves the fit.
    true = fit.ln < len(nodes)
    assert np.array_equal(fit.gn[true], nodes[fit.ln[true]])
    assert true.sum() == len(nodes)
    # Every true node is likely matched; the matched share informs the covariance.
    assert fit.matched[: len(nodes)].min() > 0.5
    assert np.all((fit.matched >= 0.0) & (fit.matched <= 1.0))
    mapped = Rigid2D(fit.yaw, *fit.t).apply(model.pts[: len(nodes)])
    assert np.abs(mapped - model.gn_pts[nodes]).max() < 0.5


def test_original_darces_has_no_probabilistic_refit() -> None:
    from darces_matcher.simulate import SimOptions, iter_lns

    gn = generate_gn(GnSpec(n_rois=120), seed=3)
    sim = next(iter(iter_lns(gn, SimOptions(noise_fraction=0.0), seed=7, max_lns=1)))
    assert "em_refit" in Matcher(gn).match(sim.records).timings_ms
    original = Matcher(gn, MatchConfig.original()).match(sim.records)
    assert original.is_fix and "em_refit" not in original.timings_ms


def test_em_priors_out_of_range_are_named() -> None:
    gn = generate_gn(GnSpec(n_rois=30), seed=0)
    with pytest.raises(ValueError, match="outlier_prior"):
        Matcher(gn, MatchConfig(outlier_prior=1.0))
    with pytest.raises(ValueError, match="label_confusion"):
        Matcher(gn, MatchConfig(label_confusion=0.7))


def test_a_fix_whose_likeliest_refit_explains_too_few_nodes_is_withheld(monkeypatch) -> None:
    # The EM's fit must pass the decision again: its alignment must beat chance (here it
    # moved 40 m: every node lands on nothing).
    import darces_matcher.refit as refit_module
    from darces_matcher.em_refit import EmFit
    from darces_matcher.simulate import SimOptions, iter_lns

    gn = generate_gn(GnSpec(n_rois=120), seed=3)
    sim = next(iter(iter_lns(gn, SimOptions(noise_fraction=0.0), seed=7, max_lns=1)))
    odds = Matcher(gn)
    assert odds.match(sim.records).status == "fix"

    def moved_away(model, yaw, t, **_):
        n = len(model.pts)
        return EmFit(yaw, np.asarray(t) + 40.0, np.arange(3), sim.truth_gn[:3], 0.0,
                     np.full(n, 3 / n))

    monkeypatch.setattr(refit_module, "em_refit", moved_away)
    result = odds.match(sim.records)
    assert (result.status, result.reason) == ("no_fix", "insufficient_support")
    assert result.false_match_probability > 0.5


def _pair_scene(twin_m: float | None):
    """Ten rocks 40 m apart on a line along x; with ``twin_m``, each has a twin that
    far along y. An LN of the ten (sigma 1 m per axis) at the true alignment."""
    rocks = np.column_stack([np.arange(10) * 40.0, np.zeros(10)])
    gn = rocks if twin_m is None else np.vstack([rocks, rocks + np.array([0.0, twin_m])])
    labels = np.ones(len(gn), dtype=np.int64)
    truth = Rigid2D(0.3, 100.0, -20.0)
    ln = truth.inverse().apply(rocks)
    var = np.full(len(ln), 1.0)
    model = EmModel(cKDTree(gn), labels, ln, np.ones(len(ln), dtype=np.int64), var,
                    0.3 / 0.7 * 10 / 1e5, 0.1)
    return model, truth


def test_the_association_covariance_widens_where_rocks_share_a_node() -> None:
    from darces_matcher.refit import em_covariance

    # Isolated rocks: one partner each, nothing missing: the complete-data covariance.
    model, truth = _pair_scene(None)
    t = np.array([truth.tx, truth.ty])
    fit = em_refit(model, truth.yaw, t, anneal_start_m=0.0, iterations=4)
    complete = em_covariance(model.pts, model.var, fit)
    louis = model.association_covariance(fit.yaw, fit.t)
    np.testing.assert_allclose(louis, complete, rtol=0.05, atol=1e-9)
    # Each rock with a twin 1.5 m across the line (1.5 sigma): every node may pair with
    # either, so across the line the data say less than the complete data would.
    model, truth = _pair_scene(1.5)
    fit = em_refit(model, truth.yaw, t, anneal_start_m=0.0, iterations=4)
    complete = em_covariance(model.pts, model.var, fit)
    louis = model.association_covariance(fit.yaw, fit.t)
    assert np.all(np.isfinite(louis))
    # In the map, across the line is y (the alignment's translation is in map axes).
    assert louis[1, 1] > 1.5 * complete[1, 1]
    assert louis[0, 0] == pytest.approx(complete[0, 0], rel=0.2)
