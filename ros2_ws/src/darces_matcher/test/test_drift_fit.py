"""The LN's correlated drift: ln_drift.chain_covariance and the drift_fit module."""

from __future__ import annotations

import numpy as np
import pytest

from darces_matcher.drift_fit import deletion_statistics, drift_consistent_fit, gls_fit
from darces_matcher.ln_drift import _step, chain_covariance
from darces_matcher.vote import fit_rigid, pose_covariance, predicted_variance

GN_VAR = 0.3**2
OWN_VAR = 0.2**2


def _drive(k: int = 30, length: float = 600.0, seed: int = 0):
    """Nodes along a bending 600 m drive (odom = truth here) and a VO chain's (x, y, yaw)
    covariance at each: each step adds position noise (0.035 m^2 per axis per metre) and a heading
    random walk of ~0.5 deg per 100 m (3.5 m per axis at 350 m)."""
    s = np.linspace(0.0, length, k)
    pts = np.column_stack([s, 60.0 * np.sin(s / 150.0)])
    steps = []
    P = [np.diag([0.01, 0.01, 1e-6])]
    for j in range(k - 1):
        d = np.linalg.norm(pts[j + 1] - pts[j])
        Q = np.diag([0.035 * d, 0.035 * d, np.radians(0.5) ** 2 * d / 100])
        F = _step(pts[j + 1] - pts[j])
        P.append(F @ P[-1] @ F.T + Q)
        steps.append((F, Q))
    return pts, np.array(P), steps


def _sample_errors(steps, P0, rng, n):
    """n draws of every node's odometry pose error along the chain."""
    k = len(steps) + 1
    e = np.zeros((n, k, 3))
    e[:, 0] = rng.multivariate_normal(np.zeros(3), P0, n)
    for j, (F, Q) in enumerate(steps):
        e[:, j + 1] = e[:, j] @ F.T + rng.multivariate_normal(np.zeros(3), Q, n)
    return e


def test_chain_covariance_is_the_chain_s_own_relative_to_any_anchor_in_any_order() -> None:
    """Against 40,000 draws of the chain: the errors relative to the anchor (its pose
    error, a rigid motion, taken out), whatever the order the nodes are given in."""
    pts, P, steps = _drive(k=9)
    rng = np.random.default_rng(1)
    e = _sample_errors(steps, P[0], rng, 40000)
    perm = rng.permutation(len(pts))
    inv = np.argsort(perm)
    idx = np.column_stack([2 * inv, 2 * inv + 1]).ravel()
    for anchor in (0, 4, 8):
        d = pts - pts[anchor]
        J = np.stack([np.array([[1.0, 0.0, -v[1]], [0.0, 1.0, v[0]]]) for v in d])
        rel = e[..., :2] - np.einsum("kab,nb->nka", J, e[:, anchor])
        empirical = np.cov(rel.reshape(len(rel), -1).T)
        cov = chain_covariance(pts[perm], P[perm], np.zeros(len(pts)),
                               int(np.flatnonzero(perm == anchor)[0]))[np.ix_(idx, idx)]
        scale = np.abs(empirical).max()
        assert np.abs(cov - empirical).max() < 0.03 * scale, anchor
        # The anchor has no error relative to itself; the far end the most.
        assert cov[2 * anchor, 2 * anchor] == pytest.approx(0.0, abs=1e-12)
    # Two old nodes share their drift relative to the newest: strongly correlated.
    cov = chain_covariance(pts, P, np.zeros(len(pts)), len(pts) - 1)
    corr = cov[0, 2] / np.sqrt(cov[0, 0] * cov[2, 2])
    assert corr > 0.8


def _ln(seed: int, k: int = 30):
    """An LN of a drive (odom) with chain-drifted nodes, its GN counterparts (map) and
    the chain covariance relative to the newest node."""
    pts, P, steps = _drive(k=k)
    rng = np.random.default_rng(seed)
    e = _sample_errors(steps, P[0], rng, 1)[0]
    truth_yaw, truth_t = 0.7, np.array([250.0, -80.0])
    c, s = np.cos(truth_yaw), np.sin(truth_yaw)
    gn = pts @ np.array([[c, s], [-s, c]]) + truth_t + rng.normal(0.0, np.sqrt(GN_VAR), pts.shape)
    ln = pts + e[:, :2] + rng.normal(0.0, np.sqrt(OWN_VAR), pts.shape)
    cov = chain_covariance(ln, P, np.full(k, OWN_VAR), k - 1)
    # The alignment valid at the newest node: the truth moved by that node's pose error.
    return ln, gn, cov, P, pts, (truth_yaw, truth_t)


def test_the_gls_fit_is_calibrated_at_the_rover_and_the_independent_fit_is_not() -> None:
    """Over 60 drives: the GLS fit's error at the newest node against its covariance is
    chi-square 2 on average; the independent-sigma fit (each node its own drift to the
    newest) claims far less than its error."""
    gls_z, ind_z = [], []
    for seed in range(60):
        ln, gn, cov, _, pts, (yaw, t) = _ln(seed)
        newest = ln[-1]
        c, s = np.cos(yaw), np.sin(yaw)
        true_rover = pts[-1] @ np.array([[c, s], [-s, c]]) + t
        fit = gls_fit(ln, gn, cov, GN_VAR, yaw, t)
        c2, s2 = np.cos(fit.yaw), np.sin(fit.yaw)
        at = newest @ np.array([[c2, s2], [-s2, c2]]) + fit.t
        var = predicted_variance(newest[None], fit.yaw, fit.covariance)[0]
        gls_z.append(np.sum((at - true_rover) ** 2) / (2 * var))
        w = 1.0 / (np.diag(cov)[0::2] + GN_VAR)
        y2, t2 = fit_rigid(ln, gn, w)
        c2, s2 = np.cos(y2), np.sin(y2)
        at2 = newest @ np.array([[c2, s2], [-s2, c2]]) + t2
        var2 = predicted_variance(newest[None], y2, pose_covariance(ln, y2, w))[0]
        ind_z.append(np.sum((at2 - true_rover) ** 2) / (2 * var2))
    assert 0.6 < np.mean(gls_z) < 1.6, np.mean(gls_z)
    assert np.mean(ind_z) > 3.0, np.mean(ind_z)


def test_a_wrong_old_pair_is_dropped_and_good_pairs_are_kept() -> None:
    """A node 300 m back paired with a GN rock 4 m from its own: within its independent
    drift sigma to the newest node (metres), but not within its drift relative to its
    neighbours. The drift fit drops it and keeps every good pair (over 20 drives)."""
    gate = -2.0 * np.log(1e-3)
    dropped_good, caught = 0, 0
    for seed in range(20):
        ln, gn, cov, _, _, (yaw, t) = _ln(seed)
        bad = 12
        gn = gn.copy()
        gn[bad] += np.array([2.4, -3.2])
        sigma_bad = np.sqrt(cov[2 * bad, 2 * bad])
        assert sigma_bad > 2.0  # its drift to the newest node, on its own
        out = drift_consistent_fit(ln, gn, cov, GN_VAR, yaw, t, gate)
        caught += bad in out.dropped
        dropped_good += int(np.sum(out.dropped != bad))
        # Every pair is kept or dropped, never both.
        assert np.array_equal(np.sort(np.r_[out.kept, out.dropped]), np.arange(len(ln)))
    assert caught >= 18, caught
    assert dropped_good <= 2, dropped_good


def test_deletion_statistics_are_chi_square_2_on_good_pairs() -> None:
    stats = []
    for seed in range(30):
        ln, gn, cov, _, _, (yaw, t) = _ln(seed)
        fit = gls_fit(ln, gn, cov, GN_VAR, yaw, t)
        stat, loo = deletion_statistics(ln, gn, cov, GN_VAR, fit)
        stats.append(stat)
        assert loo.shape == (len(ln), 3)
    stats = np.concatenate(stats)
    assert 1.7 < stats.mean() < 2.3, stats.mean()  # chi-square 2 has mean 2


def test_the_leave_one_out_alignments_are_the_refits_without_the_pair() -> None:
    ln, gn, cov, _, _, (yaw, t) = _ln(3, k=12)
    fit = gls_fit(ln, gn, cov, GN_VAR, yaw, t)
    _, loo = deletion_statistics(ln, gn, cov, GN_VAR, fit)
    for i in (0, 5, 11):
        rest = np.delete(np.arange(len(ln)), i)
        idx = np.column_stack([2 * rest, 2 * rest + 1]).ravel()
        refit = gls_fit(ln[rest], gn[rest], cov[np.ix_(idx, idx)], GN_VAR, fit.yaw, fit.t)
        assert loo[i, :2] == pytest.approx(refit.t, abs=0.02)  # linearized in yaw
        assert loo[i, 2] == pytest.approx(refit.yaw, abs=1e-4)


def test_a_localized_fix_drops_an_old_pair_its_drift_cannot_explain(monkeypatch) -> None:
    """Matcher.match_or_track with the nodes' odometry covariance, localized: an old
    node's GN rock is missing and a decoy lies 5 m from it. Each old node's drift to the
    newest is metres on its own, so the search and the EM pair the decoy; relative to its
    neighbours the pair is off by far more than their drift, and the drift fit drops it
    (tracking.drift_fit), and the fix, now the drift fit's, places the rover as well as
    the other pairs allow."""
    from darces_matcher import tracking
    from darces_matcher.matcher import Matcher
    from roi_network.network import RoiNetwork
    from roi_network.records import ROCK, empty_records
    from roi_network.transform import Rigid2D

    outcome = {}
    for seed in range(6):
        ln, gn_true, cov, P, _, (yaw, t) = _ln(seed)
        k, bad = len(ln), 12
        rng = np.random.default_rng(100 + seed)
        lo, hi = gn_true.min(axis=0) - 100.0, gn_true.max(axis=0) + 100.0
        back = rng.uniform(lo, hi, (300, 2))
        d = np.linalg.norm(back[:, None] - gn_true[None], axis=2).min(axis=1)
        back = back[d > 15.0]
        decoy = gn_true[bad] + np.array([3.0, -4.0])
        gn_pts = np.vstack([np.delete(gn_true, bad, axis=0), decoy[None], back])
        g = empty_records(len(gn_pts))
        g["x"], g["y"], g["label"] = gn_pts[:, 0], gn_pts[:, 1], ROCK
        gn = RoiNetwork(g, "map")
        rec = empty_records(k)
        rec["x"], rec["y"], rec["label"], rec["id"] = ln[:, 0], ln[:, 1], ROCK, np.arange(k)
        rec["cov_xx"] = rec["cov_yy"] = 0.5 * (P[:, 0, 0] + P[:, 1, 1]) + OWN_VAR
        prior_cov = np.diag([3.0**2, 3.0**2, np.radians(2.0) ** 2])
        # The prior: the alignment that maps the newest node onto its rock.
        fit0 = gls_fit(ln, gn_true, cov, GN_VAR, yaw, t)
        prior = Rigid2D(fit0.yaw, float(fit0.t[0]), float(fit0.t[1]))
        lever = prior.apply(ln[-1:])[0] - np.array([prior.tx, prior.ty])
        G = np.array([[1.0, 0.0, -lever[1]], [0.0, 1.0, lever[0]], [0.0, 0.0, 1.0]])
        prior_cov = np.linalg.inv(G) @ prior_cov @ np.linalg.inv(G).T
        m = Matcher(gn)
        for drift in (False, True):
            with monkeypatch.context() as patch:
                if not drift:
                    patch.setattr(tracking, "drift_fit", lambda result, *_: result)
                r = m.match_or_track(rec, prior, prior_cov, odom_cov=P)
            assert r.is_fix, (seed, drift, r.reason)
            paired_decoy = bool(np.any((r.inliers[:, 0] == bad)
                                       & (r.inliers[:, 1] == k - 1)))
            err = float(np.linalg.norm(r.map_T_odom.apply(ln[-1:])[0] - gn_true[-1]))
            outcome.setdefault(drift, []).append((paired_decoy, r.drift_dropped, err))
    # Without the drift fit the decoy is among the pairs of most fixes; with it, of none.
    assert sum(p for p, _, _ in outcome[False]) >= 4, outcome
    assert not any(p for p, _, _ in outcome[True]), outcome
    assert all(n >= 1 for _, n, _ in outcome[True]), outcome
    assert np.median([e for _, _, e in outcome[True]]) < 1.5, outcome
