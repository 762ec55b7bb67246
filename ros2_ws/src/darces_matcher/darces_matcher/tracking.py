"""Localization while driving: fitting an LN near a known alignment, and the localized
fix.

:func:`track` fits an LN near a prior alignment (the annealed EM from it, decided on the
odds against the alignments inside the prior's 3-sigma ellipsoid,
:func:`prior_search_size`). :func:`localized_fix` is the last step of
:meth:`~darces_matcher.matcher.Matcher.match_or_track` once the rover is localized: the
fix refitted under the LN's correlated drift (:mod:`~darces_matcher.drift_fit`) when the
odometry covariance of each node is known, else its covariance widened to its
jackknife's.
"""

from __future__ import annotations

import time

import numpy as np

from darces_matcher.config import MatchConfig
from darces_matcher.drift_fit import drift_consistent_fit
from darces_matcher.gn_index import GnIndex
from darces_matcher.gn_model import GnModel
from darces_matcher.ln_drift import chain_covariance
from darces_matcher.refit import (
    ANNEAL_START_M,
    em_covariance,
    em_fit,
    odds_verdict,
    reported_covariance,
)
from darces_matcher.result import MatchResult
from darces_matcher.timings import add_stage, elapsed_ms, with_total
from darces_matcher.tolerances import LnNodes, fit_spread, records_var
from darces_matcher.vote import covering_covariance, jackknife_covariance, predicted_variance
from roi_network.transform import Rigid2D, wrap_angle

#: The prior's region in :func:`track`: chi-square of 3 degrees of freedom at 99.7 %
#: (3 sigma).
PRIOR_CHI2 = 14.16
#: Node terms left out of a tracked fit's odds: none. The EM moves the alignment
#: continuously inside the prior, it is not fitted to three nodes as a control
#: triangle's is, and the count of alignments examined (``TRACK_CELL_FRACTION``) already
#: charges that freedom.
TRACK_SPENT_NODES = 0
#: Side of a distinct alignment's cell in node sigmas (:func:`prior_search_size`): 0.25
#: counts 64x the alignments of 1-sigma cells, so that the EM's optimisation inside a
#: cell gains little.
TRACK_CELL_FRACTION = 0.25
#: Per inlier pair, the probability under the drift model of a deletion statistic above
#: the drift fit's gate (chi-square 2: the gate is -2 ln p).
DRIFT_OUTLIER_P = 1e-3


def track(model: GnModel, nodes: LnNodes, prior: Rigid2D, prior_covariance: np.ndarray,
          cfg: MatchConfig) -> MatchResult:
    """Fit an LN near a known alignment: localization while driving, after a fix.

    The global search must find the LN anywhere on the GN, at any heading: it needs a
    control triangle of three true nodes and odds that beat every alignment it
    examined. Once the rover is localized the alignment is known to within
    ``prior_covariance``, and the fit need only look there: the annealed EM
    (:mod:`~darces_matcher.em_refit`) runs from ``prior``, its widest width the prior's
    spread over the LN, and its alignment is decided on the same odds against chance
    (:mod:`~darces_matcher.decision`), the alignments examined being the distinct ones
    inside the prior's 3-sigma ellipsoid (:func:`prior_search_size`) instead of the
    triangle hypotheses of a global search. A fit that leaves that ellipsoid is no fix
    (``outside_prior``): the count would not cover it.

    Args:
        model: the labelled GN.
        nodes: the LN's nodes (:func:`~darces_matcher.tolerances.ln_nodes`).
        prior: the current estimate of ``map_T_odom``.
        prior_covariance: (3, 3) finite, positive definite covariance of its (x, y, yaw),
            m^2 and rad^2 (:class:`~darces_matcher.localization.MapOdomFilter`'s).
        cfg: the matcher's settings.

    Returns:
        A :class:`MatchResult` with reason ``"ok_tracked"`` on a fix.
    """
    t_start = time.perf_counter()
    p = prior_covariance
    if len(nodes) < 3:
        return MatchResult("no_fix", "too_few_nodes", timings_ms=with_total(t_start, {}))
    pts, labels = nodes.pts, nodes.labels
    var = nodes.sigma**2 + cfg.gn_sigma_m**2
    # The prior's 1-sigma spread over the LN: where the EM must start looking.
    spread = float(np.sqrt(predicted_variance(pts, prior.yaw, p).max()))
    fit = em_fit(model, cfg, pts, labels, var, prior, max(ANNEAL_START_M, spread))
    # The count of alignments charges the EM's freedom: no node is spent (a triangle
    # fixes the global search's alignments, not this one's).
    n_tested = prior_search_size(pts, var, p, TRACK_CELL_FRACTION)
    verdict = odds_verdict(model, cfg, fit, pts, labels, var, n_tested, [],
                           spent=TRACK_SPENT_NODES)
    fitted = Rigid2D(fit.yaw, fit.t[0], fit.t[1])
    d = np.array([fit.t[0] - prior.tx, fit.t[1] - prior.ty,
                  wrap_angle(fit.yaw - prior.yaw)])
    covariance = em_covariance(pts, var, fit)
    position_sigma = fit_spread(nodes, fit.yaw, covariance)
    # The precision test of the global search stands: without it two wrong pairs far
    # from the rest of the LN (inside their gates) may turn the alignment.
    if d @ np.linalg.solve(p, d) > PRIOR_CHI2:
        status, reason = "no_fix", "outside_prior"
    elif not verdict.accept:
        status, reason = "no_fix", "insufficient_support"
    elif position_sigma > cfg.max_position_sigma_m:
        status, reason = "no_fix", "imprecise"
    else:
        status, reason = "fix", "ok_tracked"
    if status == "fix":
        covariance = reported_covariance(model, cfg, pts, labels, var, fit, covariance)
    return MatchResult(
        status=status, reason=reason, map_T_odom=fitted, covariance=covariance,
        inliers=np.column_stack([nodes.kept[fit.ln], fit.gn]).astype(np.int64),
        support=len(fit.ln), margin=len(fit.ln), position_sigma_m=position_sigma,
        log_odds=verdict.log_odds, false_match_probability=verdict.p_false,
        timings_ms=with_total(t_start, {}),
    )


def check_prior_covariance(prior_covariance: np.ndarray) -> np.ndarray:
    """The prior covariance as a (3, 3) float array.

    Raises:
        ValueError: if it is not a finite, positive definite (3, 3) matrix.
    """
    p = np.asarray(prior_covariance, dtype=float)
    if p.shape != (3, 3) or not np.all(np.isfinite(p)) or not np.all(
            np.linalg.eigvalsh(0.5 * (p + p.T)) > 0.0):
        raise ValueError("Matcher.track: prior_covariance must be a finite, positive "
                         f"definite (3, 3) matrix, got {p.tolist()}")
    return p


def localized_fix(result: MatchResult, nodes: LnNodes, index: GnIndex,
                  cfg: MatchConfig) -> MatchResult:
    """A localized fix made robust to its weakest pairs.

    With the odometry covariance of each node (:attr:`LnNodes.odom_cov`), the fix's
    inlier pairs are refitted under the LN's correlated drift (:func:`drift_fit`). Else
    its covariance is widened to cover the jackknife's of its inlier pairs, each weighted
    by its node's variance as the fit took it (relative to the newest node, which weighs
    most: a fit whose position at the rover rests on that one pair is as uncertain as
    the pair's pull). Anything but a fix as it is.
    """
    if not result.is_fix:
        return result
    if nodes.odom_cov is not None:
        return drift_fit(result, nodes, index, cfg)
    at, gn = pair_rows(result, nodes.kept)
    weights = 1.0 / (nodes.sigma[at] ** 2 + cfg.gn_sigma_m**2)
    spread = jackknife_covariance(nodes.pts[at], index.pts[gn], weights)
    result.covariance = covering_covariance(result.covariance, spread)
    return result


def pair_rows(result: MatchResult, kept: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A fix's inlier pairs as (rows among the finite nodes ``kept``, GN indices)."""
    row = np.full(int(kept.max()) + 1 if len(kept) else 0, -1, dtype=np.int64)
    row[kept] = np.arange(len(kept))
    pairs = np.asarray(result.inliers, dtype=np.int64).reshape(-1, 2)
    return row[pairs[:, 0]], pairs[:, 1]


def drift_fit(result: MatchResult, nodes: LnNodes, index: GnIndex,
              cfg: MatchConfig) -> MatchResult:
    """A fix's inlier pairs refitted under the LN's correlated drift relative to its
    newest node (:func:`~darces_matcher.drift_fit.drift_consistent_fit`: generalized
    least squares with the odometry chain's joint covariance,
    :func:`~darces_matcher.ln_drift.chain_covariance`), the pairs the drift cannot
    explain dropped one by one (``DRIFT_OUTLIER_P``): the fix's alignment, pairs and
    covariance (widened to cover its jackknife) become that fit's. The decision stands.
    """
    t0 = time.perf_counter()
    P = nodes.odom_cov
    pts, var = nodes.pts, records_var(nodes.records)
    at, gn = pair_rows(result, nodes.kept)
    if len(at) < 3:
        return result
    anchor = int(np.argmax(P[:, 0, 0] + P[:, 1, 1]))  # the newest node
    own = np.maximum(var - 0.5 * (P[:, 0, 0] + P[:, 1, 1]), cfg.ln_sigma_floor_m**2)
    cov = chain_covariance(pts, P, own, anchor)
    idx = np.column_stack([2 * at, 2 * at + 1]).ravel()
    T = result.map_T_odom
    fitted = drift_consistent_fit(
        pts[at], index.pts[gn], cov[np.ix_(idx, idx)], cfg.gn_sigma_m**2,
        T.yaw, np.array([T.tx, T.ty]), gate=-2.0 * np.log(DRIFT_OUTLIER_P))
    fit = fitted.fit
    if not np.all(np.isfinite(fit.covariance)):
        return result
    result.map_T_odom = Rigid2D(fit.yaw, float(fit.t[0]), float(fit.t[1]))
    result.covariance = covering_covariance(fit.covariance, fitted.jackknife)
    result.inliers = np.asarray(result.inliers, dtype=np.int64).reshape(-1, 2)[fitted.kept]
    result.support = len(fitted.kept)
    result.drift_dropped = len(fitted.dropped)
    add_stage(result.timings_ms, "drift_fit", t0)
    result.timings_ms["total"] = result.timings_ms.get("total", 0.0) + elapsed_ms(t0)
    return result


def prior_search_size(pts: np.ndarray, var: np.ndarray, prior_covariance: np.ndarray,
                      cell_fraction: float = 1.0) -> float:
    """Distinct alignments of an LN inside a prior's 3-sigma ellipsoid.

    The ellipsoid ``d^T P^-1 d <= PRIOR_CHI2`` in (x, y, yaw) has volume
    4/3 pi PRIOR_CHI2^(3/2) sqrt(det P); two alignments of the LN are told apart
    when they differ by a node's 1-sigma error s (median over the nodes) in
    translation or by s / r in heading (r the LN's RMS radius about its centroid):
    a cell of s^2 (s / r). Both volumes are invariant to where the rotation is
    taken about. At least 1.

    Args:
        pts: (N, 2) LN positions, ``odom``, metres.
        var: (N,) per-axis position variance of each node, m^2.
        prior_covariance: (3, 3) covariance of the prior's (x, y, yaw).
        cell_fraction: the cell's side in units of s (finer cells: more alignments).
    """
    s = cell_fraction * float(np.sqrt(np.median(var)))
    r = max(float(np.sqrt(np.mean(np.sum((pts - pts.mean(axis=0)) ** 2, axis=1)))), s)
    det = max(float(np.linalg.det(prior_covariance)), 0.0)
    volume = 4.0 / 3.0 * np.pi * PRIOR_CHI2**1.5 * np.sqrt(det)
    return max(1.0, volume / (s * s * (s / r)))
