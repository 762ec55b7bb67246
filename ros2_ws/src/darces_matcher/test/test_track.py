"""Matcher.track: fitting an LN near a known alignment (localization while driving)."""

from __future__ import annotations

import numpy as np
import pytest

from darces_matcher.matcher import MatchConfig, Matcher
from darces_matcher.simulate import SimOptions, iter_lns, ln_prefix, transform_error
from darces_matcher.vote import predicted_variance
from roi_network.network import RoiNetwork
from roi_network.records import ROCK, empty_records, xy
from roi_network.transform import Rigid2D


@pytest.fixture(scope="module")
def lns(gn: RoiNetwork) -> list:
    return list(iter_lns(gn, SimOptions(), seed=7, max_lns=12))


def _prior(truth: Rigid2D, centre_odom: np.ndarray, offset: np.ndarray, sigma_m: float,
           sigma_yaw: float) -> tuple[Rigid2D, np.ndarray]:
    """``truth`` moved by ``offset`` (dx, dy in map, dyaw about the LN's centre), and a
    covariance of ``sigma_m`` / ``sigma_yaw`` about that centre (the lever arm to the
    odom origin included, as MapOdomFilter's covariance has it)."""
    c = truth.apply(centre_odom)
    rot = Rigid2D(float(offset[2]), 0.0, 0.0).rotation
    t = rot @ (np.array([truth.tx, truth.ty]) - c) + c + offset[:2]
    lever = t - c
    g = np.array([[1.0, 0.0, -lever[1]], [0.0, 1.0, lever[0]], [0.0, 0.0, 1.0]])
    cov = g @ np.diag([sigma_m**2, sigma_m**2, sigma_yaw**2]) @ g.T
    return Rigid2D(truth.yaw + float(offset[2]), t[0], t[1]), cov


def test_track_pulls_a_wrong_prior_onto_the_ln(gn, matcher, lns) -> None:
    gn_pts = xy(gn.records)
    rng = np.random.default_rng(0)
    for sim in lns:
        offset = np.r_[rng.normal(0.0, 2.0, 2), rng.normal(0.0, np.radians(1.0))]
        prior, cov = _prior(sim.map_T_odom, xy(sim.records).mean(axis=0), offset, 2.0,
                            np.radians(1.0))
        before = transform_error(prior, sim, gn_pts)
        result = matcher.track(sim.records, prior, cov)
        assert result.status == "fix" and result.reason == "ok_tracked", result.reason
        after = transform_error(result.map_T_odom, sim, gn_pts)
        # As good as the global search's fits of the same LNs (test_matcher: < 6 m), and
        # closer than the prior wherever the prior was more than a metre off.
        assert after < 6.0
        assert after < max(before, 1.0)
        # Inliers are mostly true correspondences (a far, drifted node may pair with a
        # neighbour of its ROI, as in the global search's EM refit).
        pairs = result.inliers
        assert len(pairs) >= 6
        assert np.mean(sim.truth_gn[pairs[:, 0]] == pairs[:, 1]) >= 0.8
        assert np.all(np.linalg.eigvalsh(result.covariance) > 0)
        assert np.isfinite(result.log_odds) and result.false_match_probability <= 1e-2


def test_track_refuses_a_prior_far_from_the_truth(gn, matcher, lns) -> None:
    for sim in lns:
        prior, cov = _prior(sim.map_T_odom, xy(sim.records).mean(axis=0),
                            np.array([60.0, -40.0, 0.0]), 2.0, np.radians(1.0))
        result = matcher.track(sim.records, prior, cov)
        assert result.status == "no_fix"
        assert result.reason in ("insufficient_support", "outside_prior")


def test_a_looser_prior_searches_more_alignments(gn, matcher, lns) -> None:
    sim = lns[0]
    pts = xy(sim.records)
    var = sim.sigma**2 + matcher.config.gn_sigma_m**2
    sizes = []
    for sigma_m in (0.5, 2.0, 8.0):
        _, cov = _prior(sim.map_T_odom, pts.mean(axis=0), np.zeros(3), sigma_m,
                        np.radians(1.0))
        sizes.append(matcher.prior_search_size(pts, var, cov))
    # Volume of the prior: sigma_m^2 for the same heading sigma.
    assert sizes[1] / sizes[0] == pytest.approx(16.0, rel=1e-6)
    assert sizes[2] / sizes[1] == pytest.approx(16.0, rel=1e-6)
    # A single alignment at least, however tight the prior.
    _, tiny = _prior(sim.map_T_odom, pts.mean(axis=0), np.zeros(3), 1e-6, 1e-9)
    assert matcher.prior_search_size(pts, var, tiny) == 1.0


def test_track_keeps_the_odds_threshold(gn, lns) -> None:
    """A prefix of three nodes: the odds a fix needs grow with the prior's volume, so a
    tight prior fixes a short LN that a loose one leaves without a fix."""
    matcher = Matcher(gn, MatchConfig())
    fixed, p_false = {}, {}
    for sigma_m in (0.5, 60.0):
        count, ps = 0, []
        for sim in lns:
            short = ln_prefix(sim, 3)
            prior, cov = _prior(short.map_T_odom, xy(short.records).mean(axis=0),
                                np.zeros(3), sigma_m, np.radians(0.2))
            result = matcher.track(short.records, prior, cov)
            count += result.is_fix
            ps.append(result.false_match_probability)
        fixed[sigma_m], p_false[sigma_m] = count, np.array(ps)
    assert fixed[0.5] >= fixed[60.0] + len(lns) // 2
    assert np.all(p_false[0.5] <= p_false[60.0])


def test_track_bad_input(gn, matcher, lns) -> None:
    sim = lns[0]
    with pytest.raises(ValueError, match="prior_covariance"):
        matcher.track(sim.records, sim.map_T_odom, np.eye(2))
    with pytest.raises(ValueError, match="prior_covariance"):
        matcher.track(sim.records, sim.map_T_odom, np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="prior_covariance"):
        matcher.track(sim.records, sim.map_T_odom, np.full((3, 3), np.nan))
    few = matcher.track(sim.records[:2], sim.map_T_odom, np.eye(3))
    assert few.status == "no_fix" and few.reason == "too_few_nodes"


def test_without_a_prior_only_the_search_runs_and_with_one_tracking_too(gn, lns) -> None:
    # Five-node prefixes: without a prior match_or_track is the search; with one, the
    # search (node sigmas relative to the newest node) and tracking both run, and where
    # the search gives no fix the prior decides.
    matcher = Matcher(gn)
    gn_pts = xy(gn.records)
    tracked = 0
    for sim in lns:
        short = ln_prefix(sim, 5)
        prior, cov = _prior(short.map_T_odom, xy(short.records).mean(axis=0), np.zeros(3),
                            0.5, np.radians(0.2))
        alone = matcher.match(short.records)
        without = matcher.match_or_track(short.records)
        assert without.status == alone.status and without.reason == alone.reason
        assert "search" not in without.timings_ms
        # The search as match_or_track runs it once localized (anchor_newest).
        searched = matcher.match(short.records, None, True)
        result = matcher.match_or_track(short.records, prior, cov)
        assert "search" in result.timings_ms
        assert result.timings_ms["total"] >= result.timings_ms["search"]
        if searched.is_fix:
            assert result.is_fix
            continue
        if result.is_fix:
            tracked += 1
            assert result.reason == "ok_tracked"
            assert transform_error(result.map_T_odom, short, gn_pts) < 6.0
    assert tracked >= 1


def test_once_localized_the_likelier_of_search_and_track_is_kept(gn, lns) -> None:
    """With a prior (the rover localized), the global search and tracking near the prior
    both decide; the fix less likely a chance alignment is kept: near a right prior the
    tracked one (a smaller search), far from it the search's (tracking finds nothing)."""
    matcher = Matcher(gn, MatchConfig())
    gn_pts = xy(gn.records)
    kinds = set()
    for sim in lns[:6]:
        searched = matcher.match(sim.records, None, True)
        assert searched.is_fix
        near, cov = _prior(sim.map_T_odom, xy(sim.records).mean(axis=0), np.zeros(3), 0.5,
                           np.radians(0.2))
        tracked = matcher.track(sim.records, near, cov, None, True)
        result = matcher.match_or_track(sim.records, near, cov)
        assert result.is_fix and "search" in result.timings_ms
        best = min((searched, tracked), key=lambda r: r.false_match_probability
                   if r.is_fix else np.inf)
        assert result.reason == best.reason
        assert result.false_match_probability == pytest.approx(best.false_match_probability)
        assert transform_error(result.map_T_odom, sim, gn_pts) < 6.0
        kinds.add(result.reason)
        far, cov = _prior(sim.map_T_odom, xy(sim.records).mean(axis=0),
                          np.array([60.0, -40.0, 0.0]), 2.0, np.radians(1.0))
        result = matcher.match_or_track(sim.records, far, cov)
        assert result.is_fix and result.reason == searched.reason
        assert result.timings_ms["total"] >= result.timings_ms["search"]
        assert transform_error(result.map_T_odom, sim, gn_pts) < 6.0
    assert "ok_tracked" in kinds  # a tight, right prior wins at least once


def _bent_ln(gn: RoiNetwork, sim, drift_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The ROIs of a simulated route, placed in ``odom`` by an odometry whose heading
    drifts by ``drift_deg`` over the route (a bend about its start), node covariance
    growing as 1 % of the distance travelled: (records in route order, odom positions,
    map positions)."""
    from roi_network.records import empty_records

    route = xy(gn.records)[sim.trajectory]
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(route, axis=0), axis=1))])
    a = np.radians(drift_deg) * s / s[-1]
    d = route - route[0]
    bent = route[0] + np.column_stack([np.cos(a) * d[:, 0] - np.sin(a) * d[:, 1],
                                       np.sin(a) * d[:, 0] + np.cos(a) * d[:, 1]])
    odom = sim.map_T_odom.inverse().apply(bent)
    rec = empty_records(len(route))
    rec["x"], rec["y"] = odom[:, 0], odom[:, 1]
    rec["id"] = np.arange(len(route))
    rec["label"] = gn.records["label"][sim.trajectory]
    rec["cov_xx"] = rec["cov_yy"] = (0.01 * s) ** 2 + 0.04
    return rec, odom, route


def test_once_localized_the_fit_places_the_rover_not_the_ln_start(gn: RoiNetwork) -> None:
    """A 1 km LN whose odometry heading drifted 3 deg: one rigid alignment cannot hold
    at both ends. Anchored at the LN's least uncertain node (its start) the fit places
    the rover, at the newest node, about 15 m off; once localized the matcher anchors
    the node sigmas at the newest node and judges the fit's precision there."""
    from darces_matcher.simulate import SimOptions, iter_lns

    newest = Matcher(gn)
    prior_cov = np.diag([15.0**2, 15.0**2, np.radians(2.0) ** 2])
    placed = 0
    sims = list(iter_lns(gn, SimOptions(noise_fraction=0.0), seed=7, max_lns=8))
    for sim in sims:
        rec, odom, route = _bent_ln(gn, sim, 3.0)
        first = newest.match(rec)  # the first fix: no prior, the least uncertain anchor
        assert first.is_fix, first.reason
        assert np.linalg.norm(first.map_T_odom.apply(odom[-1:]) - route[-1]) > 8.0
        # Tracking with the node sigmas relative to the start fits the start too.
        same = newest.track(rec, first.map_T_odom, prior_cov)
        assert np.linalg.norm(same.map_T_odom.apply(odom[-1:]) - route[-1]) > 8.0
        result = newest.match_or_track(rec, first.map_T_odom, prior_cov)
        if result.is_fix:
            placed += 1
            assert np.linalg.norm(result.map_T_odom.apply(odom[-1:]) - route[-1]) < 1.0
            # Judged where the rover is: the newest node's predicted error.
            assert result.position_sigma_m <= newest.config.max_position_sigma_m
    assert placed >= 6
    # The newest node's own sigma is the floor; the start's is the drift between them.
    sigma = newest.node_sigma(rec, None, anchor_newest=True)
    assert sigma[-1] == pytest.approx(0.2, abs=1e-6)
    assert sigma[0] == pytest.approx(np.sqrt(rec["cov_xx"][-1] - rec["cov_xx"][0] + 0.04),
                                     rel=1e-5)


def test_the_first_fix_is_judged_precise_where_the_rover_is(gn: RoiNetwork) -> None:
    """The global search's fit is judged precise by its predicted error at the LN's
    newest node (``position_sigma_m``), not the largest over the LN; the covariance
    reported covers the complete-data one that this test judges."""
    from darces_matcher.simulate import SimOptions, iter_lns
    from darces_matcher.vote import predicted_variance

    matcher = Matcher(gn)
    lower = 0
    for sim in iter_lns(gn, SimOptions(noise_fraction=0.0), seed=7, max_lns=4):
        rec, odom, _ = _bent_ln(gn, sim, 1.0)
        c = matcher.match(rec)
        assert c.is_fix, c.reason
        yaw = c.map_T_odom.yaw
        at_rover = np.sqrt(predicted_variance(odom[-1:], yaw, c.covariance).max())
        over_ln = np.sqrt(predicted_variance(odom, yaw, c.covariance).max())
        assert c.position_sigma_m <= at_rover + 1e-9
        lower += c.position_sigma_m < over_ln - 1e-6
    assert lower >= 1


def _lone_newest_case() -> tuple:
    """An LN like the held-out train_1km_s113's at 822 m: twelve rocks seen early (a
    100 m cluster), then, 400 m on, one newest rock with no GN counterpart (a false
    detection) 12 m from a GN rock. Relative to the newest node (``anchor_newest``) the
    old nodes' sigma is 3.4 m and the newest's the 0.2 m floor; the prior's heading is
    known to 2 deg."""
    rng = np.random.default_rng(5)
    cluster = rng.uniform(-50.0, 50.0, (12, 2))
    background = rng.uniform(-600.0, 600.0, (150, 2))
    background = background[np.linalg.norm(background, axis=1) > 80.0]
    newest_truth = np.array([400.0, 30.0])
    background = background[np.linalg.norm(background - newest_truth, axis=1) > 30.0]
    decoy = newest_truth + np.array([3.0, 11.6])
    gn_pts = np.vstack([cluster, background, decoy])
    records = empty_records(len(gn_pts))
    records["x"], records["y"], records["label"] = gn_pts[:, 0], gn_pts[:, 1], ROCK
    gn = RoiNetwork(records, "map")
    truth = Rigid2D(0.3, 120.0, -40.0)  # map_T_odom
    odom = Rigid2D.fit(truth.apply(np.eye(2)), np.eye(2))  # odom_T_map
    ln = empty_records(13)
    ln_map = np.vstack([cluster + rng.normal(0.0, 0.4, cluster.shape), newest_truth])
    ln_xy = odom.apply(ln_map)
    ln["x"], ln["y"], ln["label"], ln["id"] = ln_xy[:, 0], ln_xy[:, 1], ROCK, np.arange(13)
    ln["cov_xx"] = ln["cov_yy"] = np.r_[np.full(12, 0.05), 11.6]
    matcher = Matcher(gn)
    prior, cov = _prior(truth, xy(ln)[:12].mean(axis=0), np.zeros(3), 3.0, np.radians(2.0))
    result = matcher.match_or_track(ln, prior, cov)
    return result, truth, xy(ln)[12]


def test_a_localized_fix_that_rests_on_one_pair_is_no_more_precise_than_that_pair(
        monkeypatch) -> None:
    """The jackknife covariance (tracking.localized_fix): a lone precise node paired with
    a decoy pulls the tracked fit 12 m off at the rover. The analytic covariance claims
    that position to a few tenths of a metre; the covariance handed to the filter covers
    the error. The decision itself is the same."""
    from darces_matcher import tracking

    outcome = {}
    for jackknife in (False, True):
        with monkeypatch.context() as patch:
            if not jackknife:
                # The analytic covariance alone.
                patch.setattr(tracking, "covering_covariance", lambda cov, _: cov)
            result, truth, newest = _lone_newest_case()
        assert result.reason == "ok_tracked"
        error = np.linalg.norm(result.map_T_odom.apply(newest) - truth.apply(newest))
        var = predicted_variance(newest[None], result.map_T_odom.yaw, result.covariance)
        outcome[jackknife] = (error, float(np.sqrt(var[0])), result.position_sigma_m)
    assert outcome[True][0] == pytest.approx(outcome[False][0])
    assert outcome[True][2] == pytest.approx(outcome[False][2])
    error, sigma, _ = outcome[False]
    assert error > 8.0 and error > 3.0 * sigma, outcome
    error, sigma, _ = outcome[True]
    assert error <= 3.0 * sigma, outcome
