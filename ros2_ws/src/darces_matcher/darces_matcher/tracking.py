"""Localization while driving: fitting an LN near a known alignment.

:meth:`Tracking.track` fits an LN near a prior alignment (the annealed EM from it, decided
on the odds against the alignments inside the prior's 3-sigma ellipsoid,
:meth:`Tracking.prior_search_size`); :meth:`Tracking.match_or_track` is the
darces_matcher node's decision for each LN: the global search
(:meth:`~darces_matcher.matcher.Matcher.match`) and, once localized, tracking, the
localized fix then refitted under the LN's correlated drift
(:mod:`~darces_matcher.drift_fit`) or its covariance widened to its jackknife's.
"""

from __future__ import annotations

import time

import numpy as np

from darces_matcher.config import MatchConfig
from darces_matcher.drift_fit import drift_consistent_fit
from darces_matcher.gn_index import GnIndex
from darces_matcher.ln_drift import chain_covariance
from darces_matcher.refit import em_covariance
from darces_matcher.result import MatchResult
from darces_matcher.timings import add_stage, elapsed_ms, with_total
from darces_matcher.tolerances import records_var
from darces_matcher.vote import (
    covering_covariance,
    fit_rigid,
    jackknife_covariance,
    pose_covariance,
    predicted_variance,
)
from roi_network.network import RoiNetwork
from roi_network.records import xy
from roi_network.transform import Rigid2D, wrap_angle

#: The prior's region in :meth:`Matcher.track`: chi-square of 3 degrees of freedom at
#: 99.7 % (3 sigma).
PRIOR_CHI2 = 14.16


class Tracking:
    """Tracking near a prior of :class:`~darces_matcher.matcher.Matcher` (a mixin: it
    uses the matcher's settings, GN index, global search, EM fit and odds decision)."""

    config: MatchConfig
    index: GnIndex

    def track(
        self,
        ln: np.ndarray | RoiNetwork,
        prior: Rigid2D,
        prior_covariance: np.ndarray,
        ln_sigma: np.ndarray | None = None,
        anchor_newest: bool = False,
        odom_cov: np.ndarray | None = None,
    ) -> MatchResult:
        """Fit an LN near a known alignment: localization while driving, after a fix.

        The global search (:meth:`match`) must find the LN anywhere on the GN, at any
        heading: it needs a control triangle of three true nodes and odds that beat
        every alignment it examined. Once the rover is localized the alignment is known
        to within ``prior_covariance``, and the fit need only look there: the annealed
        EM (:mod:`~darces_matcher.em_refit`) runs from ``prior``, its widest width the
        prior's spread over the LN, and its alignment is decided on the same odds
        against chance (:mod:`~darces_matcher.decision`), the alignments examined being
        the distinct ones inside the prior's 3-sigma ellipsoid
        (:meth:`prior_search_size`) instead of the triangle hypotheses of a global
        search. A fit that leaves that ellipsoid is no fix (``outside_prior``): the
        count would not cover it.

        Args:
            ln: LN records (:data:`~roi_network.records.ROI_DTYPE`) or network, ``odom``.
            prior: the current estimate of ``map_T_odom``.
            prior_covariance: (3, 3) covariance of its (x, y, yaw), m^2 and rad^2
                (:class:`~darces_matcher.localization.MapOdomFilter`'s).
            ln_sigma, anchor_newest, odom_cov: as in :meth:`match`.

        Returns:
            A :class:`MatchResult` with reason ``"ok_tracked"`` on a fix.

        Raises:
            ValueError: if ``prior_covariance`` is not a finite, positive definite
                (3, 3) matrix.
        """
        cfg = self.config
        t_start = time.perf_counter()
        p = np.asarray(prior_covariance, dtype=float)
        if p.shape != (3, 3) or not np.all(np.isfinite(p)) or not np.all(
                np.linalg.eigvalsh(0.5 * (p + p.T)) > 0.0):
            raise ValueError("Matcher.track: prior_covariance must be a finite, positive "
                             f"definite (3, 3) matrix, got {p.tolist()}")
        kept, sigma, pts, labels = self._finite_nodes(ln, ln_sigma, anchor_newest, odom_cov)
        if len(kept) < 3:
            return MatchResult("no_fix", "too_few_nodes", timings_ms=with_total(t_start, {}))
        var = sigma**2 + cfg.gn_sigma_m**2
        # The prior's 1-sigma spread over the LN: where the EM must start looking.
        spread = float(np.sqrt(predicted_variance(pts, prior.yaw, p).max()))
        fit = self._em_fit(pts, labels, var, prior, max(cfg.anneal_start_m, spread))
        # The count of alignments charges the EM's freedom: no node is spent (a triangle
        # fixes the global search's alignments, not this one's).
        n_tested = self.prior_search_size(pts, var, p, cfg.track_cell_fraction)
        verdict = self._verdict(fit, pts, labels, var, n_tested, [],
                                spent=cfg.track_spent_nodes)
        fitted = Rigid2D(fit.yaw, fit.t[0], fit.t[1])
        d = np.array([fit.t[0] - prior.tx, fit.t[1] - prior.ty,
                      wrap_angle(fit.yaw - prior.yaw)])
        covariance = em_covariance(pts, var, fit)
        position_sigma = self._spread(pts, fit.yaw, covariance)
        # The precision test of the global search stands: without it, on atacama_1km seed
        # 3's LN against the truth catalogue, two wrong pairs 600 m from the rest of the
        # LN (inside their 2.5 sigma gates) turned the alignment by 1.2 deg and the final
        # error grew from 15 to 24 m.
        if d @ np.linalg.solve(p, d) > PRIOR_CHI2:
            status, reason = "no_fix", "outside_prior"
        elif not verdict.accept:
            status, reason = "no_fix", "insufficient_support"
        elif position_sigma > cfg.max_position_sigma_m:
            status, reason = "no_fix", "imprecise"
        else:
            status, reason = "fix", "ok_tracked"
        if status == "fix":
            covariance = self._reported_covariance(pts, labels, var, fit, covariance)
        return MatchResult(
            status=status, reason=reason, map_T_odom=fitted, covariance=covariance,
            inliers=np.column_stack([kept[fit.ln], fit.gn]).astype(np.int64),
            support=len(fit.ln), margin=len(fit.ln), position_sigma_m=position_sigma,
            log_odds=verdict.log_odds, false_match_probability=verdict.p_false,
            timings_ms=with_total(t_start, {}),
        )

    def match_or_track(
        self,
        ln: np.ndarray | RoiNetwork,
        prior: Rigid2D | None = None,
        prior_covariance: np.ndarray | None = None,
        ln_sigma: np.ndarray | None = None,
        odom_cov: np.ndarray | None = None,
    ) -> MatchResult:
        """The global search (:meth:`match`) and, when a prior alignment is given (the
        rover is localized), :meth:`track` near it: the tracked fix when the search gives
        none, or (``MatchConfig.localized_keep_likelier``) when it is the less likely of
        the two to be a chance alignment. The darces_matcher node's decision for each LN.
        Once localized, node sigmas are relative to the newest node
        (``MatchConfig.localized_anchor_newest``). ``timings_ms["total"]`` covers both;
        ``"search"`` is the global search's share when tracking ran."""
        newest = prior is not None and self.config.localized_anchor_newest
        result = self.match(ln, ln_sigma, newest, odom_cov)
        if prior is None:
            if (result.is_fix and self.config.drift_fit_first and ln_sigma is None
                    and odom_cov is not None):
                return self._drift_fit(result, ln, newest, odom_cov)
            return result
        if result.is_fix and not self.config.localized_keep_likelier:
            return self._robust(result, ln, ln_sigma, newest, odom_cov)
        searched_ms = result.timings_ms.get("total", 0.0)
        tracked = self.track(ln, prior, prior_covariance, ln_sigma, newest, odom_cov)
        likelier = tracked.is_fix and \
            tracked.false_match_probability < result.false_match_probability
        kept = result if result.is_fix and not likelier else tracked
        kept.timings_ms["total"] = searched_ms + tracked.timings_ms.get("total", 0.0)
        kept.timings_ms["search"] = searched_ms
        return self._robust(kept, ln, ln_sigma, newest, odom_cov)

    def _robust(self, result: MatchResult, ln: np.ndarray | RoiNetwork,
                ln_sigma: np.ndarray | None, anchor_newest: bool,
                odom_cov: np.ndarray | None) -> MatchResult:
        """A localized fix refitted under the LN's correlated drift
        (``MatchConfig.drift_fit``, :meth:`_drift_fit`), or with its covariance widened
        to cover the jackknife's of its inlier pairs, each weighted by its node's
        variance as the fit took it (relative to the newest node with
        ``anchor_newest``; ``MatchConfig.jackknife_covariance``); anything else as it
        is."""
        if not result.is_fix:
            return result
        cfg = self.config
        if cfg.drift_fit and ln_sigma is None and odom_cov is not None:
            result = self._drift_fit(result, ln, anchor_newest, odom_cov)
            if cfg.drift_fit_mode == "gls":
                return result
        if not cfg.jackknife_covariance:
            return result
        at, gn, pts, weights = self._weighted_pairs(result, ln, ln_sigma, anchor_newest,
                                                    odom_cov)
        spread = jackknife_covariance(pts[at], self.index.pts[gn], weights)
        result.covariance = covering_covariance(result.covariance, spread)
        return result

    def _weighted_pairs(self, result: MatchResult, ln: np.ndarray | RoiNetwork,
                        ln_sigma: np.ndarray | None, anchor_newest: bool,
                        odom_cov: np.ndarray | None,
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """A fix's inlier pairs (rows among the finite nodes, GN indices), the finite
        nodes' positions, and each pair's weight by its node's sigma as the search takes
        it."""
        kept, sigma_kept, pts, _ = self._finite_nodes(ln, ln_sigma, anchor_newest, odom_cov)
        at, gn = self._pair_rows(result, kept)
        return at, gn, pts, 1.0 / (sigma_kept[at] ** 2 + self.config.gn_sigma_m**2)

    @staticmethod
    def _pair_rows(result: MatchResult, kept: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """A fix's inlier pairs as (rows among the finite nodes ``kept``, GN indices)."""
        row = np.full(int(kept.max()) + 1 if len(kept) else 0, -1, dtype=np.int64)
        row[kept] = np.arange(len(kept))
        pairs = np.asarray(result.inliers, dtype=np.int64).reshape(-1, 2)
        return row[pairs[:, 0]], pairs[:, 1]

    def _drift_fit(self, result: MatchResult, ln: np.ndarray | RoiNetwork,
                   anchor_newest: bool, odom_cov: np.ndarray) -> MatchResult:
        """A fix's inlier pairs refitted under the LN's correlated drift relative to its
        newest node (:func:`~darces_matcher.drift_fit.drift_consistent_fit`,
        ``MatchConfig.drift_fit``): pairs, and with ``drift_fit_mode="gls"`` alignment
        and covariance, become that fit's; with ``"screen"`` a fix that lost pairs is
        fitted again on the rest as the search fits (node sigmas as ``anchor_newest``
        anchors them)."""
        cfg = self.config
        t0 = time.perf_counter()
        records, kept, P = self._finite(ln, odom_cov)
        pts, var = xy(records)[kept], records_var(records[kept])
        at, gn = self._pair_rows(result, kept)
        if len(at) < 3:
            return result
        anchor = int(np.argmax(P[:, 0, 0] + P[:, 1, 1]))  # the newest node
        own = np.maximum(var - 0.5 * (P[:, 0, 0] + P[:, 1, 1]), cfg.ln_sigma_floor_m**2)
        cov = chain_covariance(pts, P, own, anchor)
        idx = np.column_stack([2 * at, 2 * at + 1]).ravel()
        T = result.map_T_odom
        fitted = drift_consistent_fit(
            pts[at], self.index.pts[gn], cov[np.ix_(idx, idx)], cfg.gn_sigma_m**2,
            T.yaw, np.array([T.tx, T.ty]), gate=-2.0 * np.log(cfg.drift_outlier_p))
        fit = fitted.fit
        if not np.all(np.isfinite(fit.covariance)):
            return result
        if cfg.drift_fit_mode == "gls":
            result.map_T_odom = Rigid2D(fit.yaw, float(fit.t[0]), float(fit.t[1]))
            result.covariance = (covering_covariance(fit.covariance, fitted.jackknife)
                                 if cfg.jackknife_covariance else fit.covariance)
        result.inliers = np.asarray(result.inliers, dtype=np.int64).reshape(-1, 2)[fitted.kept]
        result.support = len(fitted.kept)
        result.drift_dropped = len(fitted.dropped)
        if cfg.drift_fit_mode == "screen" and result.drift_dropped:
            at, gn, pts, weights = self._weighted_pairs(result, ln, None, anchor_newest,
                                                        odom_cov)
            yaw, t = fit_rigid(pts[at], self.index.pts[gn], weights)
            result.map_T_odom = Rigid2D(yaw, float(t[0]), float(t[1]))
            result.covariance = pose_covariance(pts[at], yaw, weights)
        add_stage(result.timings_ms, "drift_fit", t0)
        result.timings_ms["total"] = result.timings_ms.get("total", 0.0) + elapsed_ms(t0)
        return result

    @staticmethod
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
