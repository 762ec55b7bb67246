"""DARCES matching of a Local Network onto the Global Network (paper Sec. 6).

:class:`Matcher` holds the GN index (built once) and fits LNs onto it::

    matcher = Matcher(gn, MatchConfig())
    result = matcher.match(ln_records)          # LN in odom, GN in map
    if result.status == "fix":
        map_T_odom = result.map_T_odom          # roi_network.transform.Rigid2D

``MatchConfig.original()`` gives the paper's baseline, the original DARCES (no triangle
orientation, no class labels). The settings live in :mod:`~darces_matcher.config`, the
outcome in :mod:`~darces_matcher.result`; both are importable from here too.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from darces_matcher.config import MatchConfig
from darces_matcher.decision import SPENT_NODES, ChanceModel, Verdict, decide
from darces_matcher.drift_fit import drift_consistent_fit
from darces_matcher.em_refit import EmFit, EmModel, em_refit, gn_density
from darces_matcher.gn_index import GnIndex
from darces_matcher.hypotheses import (
    apply_batch,
    fit_rigid_batch,
    query_triangles,
    triangle_hypotheses,
)
from darces_matcher.ln_drift import chain_covariance, turn_variance
from darces_matcher.result import MatchResult, Status
from darces_matcher.triplets import control_triplets
from darces_matcher.vote import (
    associate,
    covering_covariance,
    displacement,
    fit_rigid,
    jackknife_covariance,
    pose_covariance,
    predicted_variance,
    refine,
    transform_points,
    triplet_votes,
    vote,
)
from roi_network.network import RoiNetwork
from roi_network.records import as_records, xy
from roi_network.transform import Rigid2D, wrap_angle

__all__ = ["PRIOR_CHI2", "MatchConfig", "MatchResult", "Matcher", "Status"]

#: The prior's region in :meth:`Matcher.track`: chi-square of 3 degrees of freedom at
#: 99.7 % (3 sigma).
PRIOR_CHI2 = 14.16


class Matcher:
    """DARCES matcher of LNs (``odom``) against one GN (``map``).

    Args:
        gn: the Global Network, ``map`` frame, at least 3 ROIs.
        config: matcher settings; defaults to the improved DARCES.

    Raises:
        ValueError: if the GN has fewer than 3 ROIs or non-finite positions, or an EM
            prior (outlier_prior, label_confusion) is out of range.
    """

    def __init__(self, gn: RoiNetwork, config: MatchConfig | None = None) -> None:
        self.config = config or MatchConfig()
        if not 0.0 <= self.config.outlier_prior < 1.0:
            raise ValueError(f"MatchConfig.outlier_prior must be in [0, 1), got "
                             f"{self.config.outlier_prior}")
        if not 0.0 < self.config.false_match_rate < 1.0:
            raise ValueError(f"MatchConfig.false_match_rate must be in (0, 1), got "
                             f"{self.config.false_match_rate}")
        if not 0.0 <= self.config.label_confusion <= 0.5:
            raise ValueError(f"MatchConfig.label_confusion must be in [0, 0.5], got "
                             f"{self.config.label_confusion}")
        self.index = GnIndex(
            gn,
            use_labels=self.config.use_labels,
            max_side_m=self.config.index_max_side_m,
            exhaustive_max_nodes=self.config.index_exhaustive_max_nodes,
            neighbours=self.config.index_neighbours or (
                40 if len(gn) <= 20000 else 14),
            quant_m=self.config.index_quant_m,
            mean_density_side=self.config.index_mean_density_side,
        )
        self._gn_labels = gn.records["label"].astype(np.int64)
        self._gn = gn
        self._blind: Matcher | None = None
        #: (alignments examined, odds of the distinct alternatives) of the last search.
        self._last_search: tuple[float, list[float]] = (1.0, [])
        #: Where the last LN's fit is judged precise (``max_position_sigma_m``), as
        #: indices into its finite nodes: None, every node; with ``anchor_newest``, the
        #: newest node (where the rover is).
        self._judged: np.ndarray | None = None
        #: GN ROIs per square metre: the EM's outlier density (a node with no
        #: counterpart is as likely anywhere).
        self.gn_density = gn_density(self.index.pts)
        self._fallback_ok = self.index.exhaustive or (
            len(gn) <= self.config.label_fallback_max_nodes)
        #: What a chance alignment looks like on this GN (the odds decision).
        self.chance = ChanceModel(self.index.tree, self._gn_labels,
                                  use_labels=self.config.use_labels,
                                  outlier_prior=self.config.outlier_prior,
                                  label_confusion=self.config.label_confusion,
                                  marginal=self.config.marginal_outliers,
                                  scale_sigmas=self.config.chance_scale_sigmas)
        if self.config.use_labels and self.config.label_fallback and self._fallback_ok:
            # The label-blind fallback's index, built now rather than at the first
            # fallback: a running matcher never stalls for it.
            self._blind_matcher()

    @property
    def max_candidates(self) -> int:
        """The effective ``MatchConfig.max_candidates``."""
        if self.config.max_candidates is not None:
            return self.config.max_candidates
        if self.config.index_neighbours is None and len(self.index.pts) <= 20000:
            # The 40-neighbour index holds ~8x the triangles of the 14-neighbour one: a
            # triplet with more than 3,000 candidates is unselective and costly (on a
            # 95 %-rock GN under stress, 30,000 gave a p95 of 8.7 s and 5 of 40 LNs no
            # fix; 3,000 gave 0.56 s and 4).
            return 3000
        return max(30000, int(0.3 * len(self.index.pts)))

    def node_sigma(self, records: np.ndarray, ln_sigma: np.ndarray | None,
                   anchor_newest: bool = False,
                   odom_cov: np.ndarray | None = None) -> np.ndarray:
        """1-sigma position error per axis of each LN node, metres.

        From ``ln_sigma`` when given, else from the records' covariance (cov_xx, cov_yy),
        relative to the least uncertain node when ``ln_sigma_relative`` (to the most
        uncertain one, the newest, with ``anchor_newest``); with ``odom_cov``, the (K, 3,
        3) odometry (x, y, yaw) covariance each node was observed with, less what the
        anchor's heading error explains (:func:`~darces_matcher.ln_drift.turn_variance`).
        Floored at ``ln_sigma_floor_m``.
        """
        if ln_sigma is None:
            var = _records_var(records)
            if self.config.ln_sigma_relative and len(var):
                floor2 = self.config.ln_sigma_floor_m**2
                anchor = int(np.argmax(var) if anchor_newest else np.argmin(var))
                if anchor_newest:
                    # Drift relative to the newest node, which keeps its own detection
                    # error (up to floor^2).
                    var = var.max() - var + min(var.max(), floor2)
                else:
                    # Never below min(var.min(), floor^2) >= 0: no clip needed.
                    var = var - max(var.min() - floor2, 0.0)
                if odom_cov is not None:
                    # The anchor's heading error: the alignment's rotation absorbs it.
                    var = np.maximum(var - turn_variance(xy(records), odom_cov, anchor),
                                     min(var.min(), floor2))
            sigma = np.sqrt(var)
        else:
            sigma = np.asarray(ln_sigma, dtype=float).reshape(len(records))
        return np.maximum(sigma, self.config.ln_sigma_floor_m)

    def _finite_nodes(
        self, ln: np.ndarray | RoiNetwork, ln_sigma: np.ndarray | None,
        anchor_newest: bool = False, odom_cov: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The LN nodes with finite positions: (indices into the input, 1-sigma error per
        axis, (K, 2) positions, class labels)."""
        records, kept, odom_cov = self._finite(ln, odom_cov)
        if ln_sigma is not None:
            ln_sigma = np.asarray(ln_sigma, dtype=float).reshape(len(records))[kept]
        # The nodes the matcher uses only: an ignored node must not set the least
        # uncertain node of ``ln_sigma_relative``.
        records = records[kept]
        sigma = self.node_sigma(records, ln_sigma, anchor_newest, odom_cov)
        self._judged = None
        if (anchor_newest or self.config.first_fix_judged_at_newest) and len(records):
            # The newest node: the most uncertain in the odometry's error.
            raw = _records_var(records) if ln_sigma is None else np.nan_to_num(ln_sigma)
            self._judged = np.array([int(np.argmax(raw))])
        return kept, sigma, xy(records), records["label"].astype(np.int64)

    @staticmethod
    def _finite(ln: np.ndarray | RoiNetwork, odom_cov: np.ndarray | None,
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """An LN's records, the indices of its nodes with finite positions, and those
        nodes' (K, 3, 3) odometry covariance (None when not given)."""
        records = as_records(ln.records if isinstance(ln, RoiNetwork) else ln)
        kept = np.flatnonzero(np.isfinite(xy(records)).all(axis=1))
        if odom_cov is not None:
            odom_cov = np.asarray(odom_cov, dtype=float).reshape(len(records), 3, 3)[kept]
        return records, kept, odom_cov

    def _spread(self, pts: np.ndarray, yaw: float, covariance: np.ndarray) -> float:
        """Largest predicted 1-sigma error per axis of a node mapped by a fit, m, over
        the nodes the fit is judged at (all, or the newest: see ``_judged``)."""
        at = pts if self._judged is None else pts[self._judged]
        return float(np.sqrt(predicted_variance(at, yaw, covariance).max()))

    def match(
        self, ln: np.ndarray | RoiNetwork, ln_sigma: np.ndarray | None = None,
        anchor_newest: bool = False, odom_cov: np.ndarray | None = None,
    ) -> MatchResult:
        """Fit an LN onto the GN.

        Args:
            ln: LN records (:data:`~roi_network.records.ROI_DTYPE`) or network, ``odom``.
            ln_sigma: optional (N,) 1-sigma position error per axis of each LN node,
                metres (the LN error model: VO drift grows with distance travelled);
                default: from the records' covariance.
            anchor_newest: the records' covariance is taken relative to the newest node
                (see ``MatchConfig.localized_anchor_newest``).
            odom_cov: optional (N, 3, 3) odometry (x, y, yaw) covariance each node was
                observed with (:class:`~darces_matcher.ln_drift.NodeOdometry`): the
                records' covariance is then taken relative to the anchor node with its
                heading error absorbed as well (:meth:`node_sigma`).

        Returns:
            The :class:`MatchResult`; never raises on a degenerate LN.

        The method's steps, in order (docs/matcher.md numbers them the same way):

        1. tolerances d_D, gates and weights from the LN error model (:meth:`_match`);
        2. control triplets (:func:`~darces_matcher.triplets.control_triplets`), from
           close nodes when no wide triangle exists;
        3. then, per round of triplets: triangle hypotheses
           (:func:`~darces_matcher.hypotheses.triangle_hypotheses`), votes of the whole
           LN (:func:`~darces_matcher.vote.vote`), refit of the distinct best
           (:func:`~darces_matcher.vote.refine`) and the decision on the odds of a
           chance alignment (:func:`~darces_matcher.decision.decide`), until a fix;
           failing that, the decision once more on the EM's alignment of the winner
           (:meth:`_decide_on_ml`);
        4. soft semantics: the label-blind search when the labelled one gives no fix
           (:meth:`_match_semantic`);
        5. the probabilistic refit of a fix (:func:`~darces_matcher.em_refit.em_refit`)
           and the decision again on its alignment (:meth:`_em_refit`).
        """
        return self._match_semantic(ln, ln_sigma, anchor_newest, odom_cov)

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
            return MatchResult("no_fix", "too_few_nodes", timings_ms=_since(t_start, {}))
        var = sigma**2 + cfg.gn_sigma_m**2
        # The prior's 1-sigma spread over the LN: where the EM must start looking.
        spread = float(np.sqrt(predicted_variance(pts, prior.yaw, p).max()))
        fit = self._em_fit(pts, labels, var, prior, max(cfg.anneal_start_m, spread))
        # The count of alignments charges the EM's freedom: no node is spent (a triangle
        # fixes the global search's alignments, not this one's).
        n_tested = self.prior_search_size(pts, var, p, cfg.track_cell_fraction)
        verdict = self._verdict(fit, pts, labels, var, n_tested, [], cfg.track_spent_nodes)
        fitted = Rigid2D(fit.yaw, fit.t[0], fit.t[1])
        d = np.array([fit.t[0] - prior.tx, fit.t[1] - prior.ty,
                      wrap_angle(fit.yaw - prior.yaw)])
        covariance = _em_covariance(pts, var, fit)
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
        return MatchResult(
            status=status, reason=reason, map_T_odom=fitted, covariance=covariance,
            inliers=np.column_stack([kept[fit.ln], fit.gn]).astype(np.int64),
            support=len(fit.ln), margin=len(fit.ln), position_sigma_m=position_sigma,
            log_odds=verdict.log_odds, false_match_probability=verdict.p_false,
            timings_ms=_since(t_start, {}),
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
        pts, var = xy(records)[kept], _records_var(records[kept])
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
        _add(result.timings_ms, "drift_fit", t0)
        result.timings_ms["total"] = result.timings_ms.get("total", 0.0) + _ms(t0)
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

    def _em_fit(self, pts: np.ndarray, labels: np.ndarray, var: np.ndarray, start: Rigid2D,
                anneal_start_m: float) -> EmFit:
        """The annealed EM (:func:`~darces_matcher.em_refit.em_refit`) of an LN (``odom``
        positions, labels, per-axis variances) from the alignment ``start``."""
        cfg = self.config
        w = cfg.outlier_prior
        model = EmModel(self.index.tree, self._gn_labels, pts, labels, var,
                        w / (1.0 - w) * self.gn_density,
                        cfg.label_confusion if cfg.use_labels else 0.5)
        return em_refit(model, start.yaw, np.array([start.tx, start.ty]),
                        anneal_start_m=anneal_start_m, iterations=cfg.em_iterations)

    def _verdict(self, fit: EmFit, pts: np.ndarray, labels: np.ndarray, var: np.ndarray,
                 n_tested: float, alternatives: Sequence[float],
                 spent: int = SPENT_NODES) -> Verdict:
        """The odds decision (:func:`~darces_matcher.decision.decide`) on an EM alignment,
        given the count of alignments examined and the distinct alternatives' log-odds;
        ``spent``: the largest node terms left out of its odds."""
        odds = self.chance.odds(fit.yaw, fit.t, pts, labels, var, spent)
        return decide(odds.log_odds, n_tested, alternatives, self.config.false_match_rate,
                      self._log_moments(labels, var))

    def _em_refit(self, result: MatchResult) -> MatchResult:
        """Maximum-likelihood refit of a fix (EM, :mod:`~darces_matcher.em_refit`).

        The decision (votes, alternatives) stands, except that the EM's alignment must
        pass it again: its odds against chance, with the same search size and
        alternatives (``decision="odds"``), or its hard pairs the support test
        (``"counts"``); else no fix (``insufficient_support``). The transform, its
        inlier pairs and covariance become the EM's if its predicted spread passes
        ``max_position_sigma_m``.
        """
        cfg = self.config
        t0 = time.perf_counter()
        # The LN as the labelled search prepared it (it always runs first; the
        # label-blind fallback prepares the same nodes, positions and weights).
        kept, pts, labels, _, weights = self._last
        var = 1.0 / weights
        fit = self._em_fit(pts, labels, var, result.map_T_odom, cfg.anneal_start_m)
        if cfg.decision == "odds":
            # The decision again, on the maximum-likelihood alignment.
            searched = self._blind if result.reason == "ok_label_blind" else self
            verdict = self._verdict(fit, pts, labels, var, *searched._last_search)
            result.log_odds = verdict.log_odds
            result.false_match_probability = verdict.p_false
            withheld = not verdict.accept
        else:
            withheld = len(fit.ln) < max(cfg.min_inliers, cfg.min_inlier_fraction * len(pts))
        if withheld:
            result.status, result.reason = "no_fix", "insufficient_support"
        else:
            covariance = _em_covariance(pts, var, fit)
            spread = self._spread(pts, fit.yaw, covariance)
            if spread <= cfg.max_position_sigma_m:
                result.map_T_odom = Rigid2D(fit.yaw, fit.t[0], fit.t[1])
                result.covariance, result.position_sigma_m = covariance, spread
                result.inliers = np.column_stack([kept[fit.ln], fit.gn]).astype(np.int64)
        ms = _ms(t0)
        result.timings_ms["em_refit"] = ms
        result.timings_ms["total"] = result.timings_ms.get("total", 0.0) + ms
        return result

    def _match_semantic(
        self, ln: np.ndarray | RoiNetwork, ln_sigma: np.ndarray | None,
        anchor_newest: bool = False, odom_cov: np.ndarray | None = None,
    ) -> MatchResult:
        """The labelled search, the label-blind polish of its fix, or the label-blind
        fallback when it gives none (soft semantics)."""
        result = self._match(ln, ln_sigma, anchor_newest, odom_cov)
        cfg = self.config
        if (result.is_fix and cfg.use_labels and cfg.label_fallback
                and cfg.polish_label_blind and not cfg.probabilistic_refit):
            # (The EM refit's class prior lets misclassified nodes join the fix: with it
            # the polish is redundant.)
            return self._polish(result)
        if result.is_fix and cfg.probabilistic_refit:
            result = self._em_refit(result)
            if not cfg.fallback_after_withheld:
                return result
            # A labelled fix whose EM alignment is withheld falls back to the
            # label-blind search as a labelled no-fix does.
        if result.is_fix or not (cfg.use_labels and cfg.label_fallback) or result.reason in (
            "too_few_nodes", "no_control_triplet"
        ) or not self._fallback_ok:
            return result
        # Soft semantics: misclassified nodes cannot vote in the labelled search; search
        # again on geometry only, and keep that fix if its inliers mostly agree on class
        # (a class-swapped LN finds its geometric match but fails this check).
        blind = self._blind_matcher()
        second = blind._match(ln, ln_sigma, anchor_newest, odom_cov)
        for stage, ms in second.timings_ms.items():
            key = "total" if stage == "total" else f"blind_{stage}"
            result.timings_ms[key] = result.timings_ms.get(key, 0.0) + ms
        if not second.is_fix:
            return result
        records = as_records(ln.records if isinstance(ln, RoiNetwork) else ln)
        ln_lab = records["label"].astype(np.int64)[second.inliers[:, 0]]
        agree = float(np.mean(ln_lab == self._gn_labels[second.inliers[:, 1]]))
        if agree < cfg.min_label_agreement:
            result.reason = "label_mismatch"
            return result
        second.reason = "ok_label_blind"
        second.timings_ms = result.timings_ms
        second.n_triplets += result.n_triplets
        second.n_hypotheses += result.n_hypotheses
        return self._em_refit(second) if cfg.probabilistic_refit else second

    def _polish(self, result: MatchResult) -> MatchResult:
        """Refit a labelled fix with label-blind association (misclassified nodes join).

        Kept only if it has at least the labelled support and its inliers mostly agree
        on class.
        """
        cfg = self.config
        t0 = time.perf_counter()
        kept, pts, labels, gate, weights = self._last
        groups = self.index.any_label_groups(len(pts))
        T = result.map_T_odom
        # Only worth it when a node outside the labelled inliers lands on a GN node of
        # another class (a misclassification); a clean LN skips the refit.
        out = np.ones(len(pts), dtype=bool)
        out[np.searchsorted(kept, result.inliers[:, 0])] = False
        if not out.any():
            # Every node is already an inlier: nothing to polish.
            result.timings_ms["polish"] = _ms(t0)
            result.timings_ms["total"] += result.timings_ms["polish"]
            return result
        t_fix = np.array([T.tx, T.ty])
        dist, _ = self.index.tree.query(transform_points(T.yaw, t_fix, pts[out]),
                                        distance_upper_bound=float(gate.max()))
        gain = False
        if (dist <= gate[out]).any():
            # Such a node may still only compete for a GN node the fix already uses: the
            # label-blind one-to-one association from the fix itself must gain a pair.
            ln_blind, _, _ = associate(self.index, transform_points(T.yaw, t_fix, pts),
                                       groups, gate)
            gain = len(ln_blind) > result.support
        if not gain:
            result.timings_ms["polish"] = _ms(t0)
            result.timings_ms["total"] += result.timings_ms["polish"]
            return result
        yaw, t, ln_in, gn_in = refine(
            self.index, pts, groups, gate, weights, float(T.yaw), t_fix,
            iterations=cfg.refine_iterations, n_sigma=cfg.n_sigma, max_gate=cfg.max_tol_m,
        )
        agree = labels[ln_in] == self._gn_labels[gn_in]
        if len(ln_in) > result.support and agree.mean() >= cfg.min_label_agreement:
            covariance = pose_covariance(pts[ln_in], yaw, weights[ln_in])
            spread = self._spread(pts, yaw, covariance)
            if spread <= cfg.max_position_sigma_m:
                result.map_T_odom = Rigid2D(yaw, t[0], t[1])
                result.covariance, result.position_sigma_m = covariance, spread
                result.inliers = np.column_stack([kept[ln_in], gn_in]).astype(np.int64)
                result.margin += len(ln_in) - result.support
                result.support = len(ln_in)
        result.timings_ms["polish"] = _ms(t0)
        result.timings_ms["total"] += result.timings_ms["polish"]
        return result

    def _blind_matcher(self) -> Matcher:
        """The label-blind matcher of the fallback, its index built at first use."""
        if self._blind is None:
            self._blind = Matcher(self._gn, replace(self.config, use_labels=False,
                                                    label_fallback=False))
        return self._blind

    def _match(self, ln: np.ndarray | RoiNetwork, ln_sigma: np.ndarray | None,
               anchor_newest: bool = False,
               odom_cov: np.ndarray | None = None) -> MatchResult:
        """One search (labelled or not, as configured); see :meth:`match`."""
        cfg = self.config
        t_start = time.perf_counter()
        timings: dict[str, float] = {}
        kept, sigma, pts, labels = self._finite_nodes(ln, ln_sigma, anchor_newest, odom_cov)
        if len(kept) < 3:
            return MatchResult("no_fix", "too_few_nodes", timings_ms=_since(t_start, timings))

        # d_D: node tolerance from the LN error model plus the GN position error.
        var = sigma**2 + cfg.gn_sigma_m**2
        node_tol = np.clip(cfg.n_sigma * np.sqrt(var), cfg.min_tol_m, cfg.max_tol_m)
        # Verification gate: the node tolerance, but never tighter than the fit itself is
        # known (a precise node must stay an inlier while the far ones move the fit).
        gate = np.maximum(node_tol, cfg.min_gate_m)
        groups = self.index.label_groups(labels)
        # The most precise nodes, which confirm hypotheses cheaply before the full vote.
        precise_nodes = np.argsort(node_tol, kind="stable")[: cfg.prefilter_nodes]
        precise = (precise_nodes, self.index.label_groups(labels[precise_nodes]))
        # An edge's length error is the difference of its end errors projected on it.
        edge_tol = cfg.n_sigma * np.sqrt(var[:, None] + var[None, :])
        edge_tol = np.clip(edge_tol, cfg.min_tol_m, 2 * cfg.max_tol_m)
        weights = 1.0 / (sigma**2 + cfg.gn_sigma_m**2)
        # Kept for the label-blind polish of a fix (:meth:`_polish`); a Matcher
        # serves one match at a time.
        self._last = (kept, pts, labels, gate, weights)

        # Control triplets: precise, well conditioned, spread over nodes.
        t0 = time.perf_counter()
        sides = [cfg.min_side_m]
        if cfg.min_side_floor_m is not None and cfg.min_side_floor_m < cfg.min_side_m:
            # No wide triangle (a short LN, or one inside a rock cluster): close nodes
            # still make a triangle whose orientation survives their tolerances.
            sides.append(cfg.min_side_floor_m)
        for min_side in sides:
            dense: list[np.ndarray] = []
            triplets = control_triplets(
                pts, node_tol, cfg.n_triplets,
                min_side_m=min_side, max_side_m=self.index.max_side_m,
                min_height_ratio=cfg.min_height_ratio,
                max_uses_per_node=cfg.max_uses_per_node,
                # Counting candidates pays off only where random congruent triangles
                # abound.
                cost=None if self.index.exhaustive else (
                    lambda trips: self._candidates(pts, labels, edge_tol, trips)),
                max_cost=self.max_candidates,
                max_dense_cost=cfg.dense_candidates_factor * self.max_candidates,
                dense_out=dense,
            )
            # The selective triplets first; those of a dense rock field, whose many
            # congruent GN triangles only the precise nodes' confirmation thins out,
            # only after every selective round has ended without a fix.
            n_selective = len(triplets)
            triplets = np.vstack([triplets, dense[0]])
            if len(triplets):
                break
        timings["triplets"] = _ms(t0)
        if len(triplets) == 0:
            return MatchResult("no_fix", "no_control_triplet", timings_ms=_since(t_start, timings))

        # Hypotheses and votes, one batch of control triplets at a time, best triplets
        # first; stop as soon as the decision is a clear fix.
        pool = _Pool()
        # Refined hypotheses by pool row: a later round refines the same best rows again.
        refined_cache: dict[int, _Refined] = {}
        result = MatchResult("no_fix", "no_hypothesis", n_triplets=len(triplets))
        tested = 0
        for first in range(0, len(triplets), cfg.triplet_batch):
            batch = triplets[first : first + cfg.triplet_batch]
            t0 = time.perf_counter()
            # Hypotheses: congruent GN triangles (edges within d_D, orientation, labels).
            ln_idx, gn_idx, source = triangle_hypotheses(
                self.index, pts, labels, edge_tol, batch,
                use_orientation=cfg.use_orientation, max_hypotheses=cfg.max_hypotheses,
            )
            source += first
            tested += len(source)
            _add(timings, "hypotheses", t0)
            t0 = time.perf_counter()
            # Each hypothesis gives a proper rigid transform (never a reflection).
            yaw, trans = fit_rigid_batch(pts[ln_idx], self.index.pts[gn_idx])
            # Cheap first look on the most precise nodes (huge GNs: many random triangles).
            if len(yaw) > cfg.prefilter_above:
                keep = self._confirmed(pts, gate, precise, yaw, trans, ln_idx)
                yaw, trans, source = yaw[keep], trans[keep], source[keep]
                ln_idx, gn_idx = ln_idx[keep], gn_idx[keep]
            # Verification: every hypothesis votes with the whole LN.
            mapped = apply_batch(yaw, trans, pts)
            support = vote(self.index, groups, gate, mapped)
            pool.add(yaw, trans, mapped, support, source, ln_idx, gn_idx)
            _add(timings, "vote", t0)
            if not len(pool.yaw):
                continue
            t0 = time.perf_counter()
            # Refit the best distinct transforms on all their inliers.
            candidates, leftover = self._refine_distinct(pts, groups, gate, weights, pool,
                                                         refined_cache)
            # Decision: enough support AND a clear margin over the best distinct alternative.
            done = min(first + cfg.triplet_batch, len(triplets))
            # The alignments the whole search examines (the union bound of the odds),
            # extrapolated from the rounds so far (over the selective triplets while
            # only those have been tried).
            n_tested = tested * (n_selective if done <= n_selective else len(triplets)) / done
            result = self._decide(candidates, leftover, pool, pts, labels, weights, kept,
                                  n_tested, gate)
            result.n_triplets = done
            _add(timings, "refine", t0)
            if result.is_fix:
                break
        result.n_hypotheses = len(pool.yaw)
        if (result.reason == "insufficient_support" and result.map_T_odom is not None
                and cfg.decide_on_ml and cfg.probabilistic_refit and cfg.decision == "odds"):
            t0 = time.perf_counter()
            result = self._decide_on_ml(result, kept, pts, labels, weights)
            _add(timings, "ml_decision", t0)
        result.timings_ms = _since(t_start, timings)
        return result

    def _decide_on_ml(self, result: MatchResult, kept: np.ndarray, pts: np.ndarray,
                      labels: np.ndarray, weights: np.ndarray) -> MatchResult:
        """The decision again, on the EM's maximum-likelihood alignment from the search's
        best (``MatchConfig.decide_on_ml``): a fix if its odds pass with the search's size
        and alternatives, and its spread the precision test."""
        cfg = self.config
        var = 1.0 / weights
        fit = self._em_fit(pts, labels, var, result.map_T_odom, cfg.anneal_start_m)
        verdict = self._verdict(fit, pts, labels, var, *self._last_search)
        covariance = _em_covariance(pts, var, fit)
        spread = self._spread(pts, fit.yaw, covariance)
        if not verdict.accept or result.votes < cfg.min_votes \
                or spread > cfg.max_position_sigma_m:
            if verdict.p_false < result.false_match_probability:
                # Still no fix; the diagnostics are the best odds the decision saw.
                result.map_T_odom = Rigid2D(fit.yaw, fit.t[0], fit.t[1])
                result.covariance, result.position_sigma_m = covariance, spread
                result.log_odds, result.false_match_probability = (verdict.log_odds,
                                                                   verdict.p_false)
            return result
        result.status, result.reason = "fix", "ok"
        result.map_T_odom = Rigid2D(fit.yaw, fit.t[0], fit.t[1])
        result.covariance, result.position_sigma_m = covariance, spread
        result.inliers = np.column_stack([kept[fit.ln], fit.gn]).astype(np.int64)
        result.support = len(fit.ln)
        result.margin = result.support - result.runner_up
        result.log_odds, result.false_match_probability = verdict.log_odds, verdict.p_false
        return result

    def _confirmed(
        self,
        pts: np.ndarray,
        gate: np.ndarray,
        precise: tuple[np.ndarray, list],
        yaw: np.ndarray,
        trans: np.ndarray,
        ln_idx: np.ndarray,
    ) -> np.ndarray:
        """Hypotheses confirmed by at least one precise LN node besides their own vertices.

        A random congruent GN triangle seldom also has a GN node of the right class where
        a fourth, precise LN node lands, the true one almost always does: a star
        tracker's fourth star. Only the survivors get the full vote.
        """
        nodes, groups = precise
        mapped = apply_batch(yaw, trans, pts[nodes])
        dist, _ = self.index.nearest_same_label(mapped, groups, float(gate[nodes].max()))
        hit = dist <= gate[nodes][None, :]
        own = (ln_idx[:, :, None] == nodes[None, None, :]).any(axis=1)
        return np.flatnonzero((hit & ~own).any(axis=1))

    def _candidates(
        self, pts: np.ndarray, labels: np.ndarray, edge_tol: np.ndarray, triplets: np.ndarray
    ) -> np.ndarray:
        """GN candidate count of each triplet, from the triangle index (selectivity)."""
        _, owner, sides, tol, codes = query_triangles(
            pts, labels, edge_tol, triplets,
            use_orientation=self.config.use_orientation, use_labels=self.index.use_labels,
        )
        per_query = self.index.count_candidates(sides, tol, codes)
        return np.bincount(owner, weights=per_query, minlength=len(triplets))

    def _log_moments(self, labels: np.ndarray, var: np.ndarray) -> dict[float, float] | None:
        """log E[LR^s] of the LN under chance for the Chernoff bounds of the decision, by
        order s (``MatchConfig.chernoff_orders``; not with the marginal odds), else None."""
        cfg = self.config
        if not cfg.chernoff_orders or cfg.marginal_outliers:
            return None
        return {s: self.chance.log_moment(labels, var, s) for s in cfg.chernoff_orders}

    def _decide(
        self,
        candidates: list[_Refined],
        leftover: int,
        pool: _Pool,
        pts: np.ndarray,
        labels: np.ndarray,
        weights: np.ndarray,
        kept: np.ndarray,
        n_tested: float,
        gate: np.ndarray,
    ) -> MatchResult:
        """Fix or no fix from the refined candidates (best first); ``gate``: the nodes'
        verification gates, metres."""
        cfg = self.config
        best = candidates[0]
        best_T = Rigid2D(best.yaw, best.t[0], best.t[1])
        # The runner-up is the best candidate that is a different fix: it shares less than
        # half of its correspondences with the winner.
        runner_up = max((len(c.ln) for c in candidates[1:] if not _same_fix(best, c)),
                        default=0)
        runner_up = max(runner_up, leftover)
        support = len(best.ln)
        # The triplets whose hypotheses are this fix: its pairs, or its alignment, every
        # node within its own gate of where the fix maps it. (Within ``distinct_ratio``
        # gates, the refinement's suppression radius, it also voted for a refit that had
        # moved 2 gates from its triangle: on thomas_strong, GN seed 3, a fix 75 m off.)
        votes = triplet_votes(pool.ln_idx, pool.gn_idx, pool.source, pool.mapped, best.ln,
                              best.gn, transform_points(best.yaw, best.t, pts), gate, 1.0)
        covariance = pose_covariance(pts[best.ln], best.yaw, weights[best.ln])
        spread = self._spread(pts, best.yaw, covariance)
        status: Status = "fix"
        reason = "ok"
        log_odds = p_false = float("nan")
        if cfg.decision == "odds":
            # The odds of the winner and of every distinct alternative against chance.
            var = 1.0 / weights
            alternatives = [self.chance.odds(c.yaw, c.t, pts, labels, var).log_odds
                            for c in candidates[1:] if not _same_fix(best, c)]
            self._last_search = (n_tested, alternatives)
            verdict = decide(self.chance.odds(best.yaw, best.t, pts, labels, var).log_odds,
                             n_tested, alternatives, cfg.false_match_rate,
                             self._log_moments(labels, var))
            log_odds, p_false = verdict.log_odds, verdict.p_false
            unsupported = not verdict.accept and not verdict.ambiguous
            ambiguous = not verdict.accept and verdict.ambiguous
        else:
            unsupported = support < max(cfg.min_inliers, cfg.min_inlier_fraction * len(pts))
            ambiguous = support - runner_up < cfg.min_margin
        if unsupported:
            status, reason = "no_fix", "insufficient_support"
        elif votes < cfg.min_votes:
            # The refit drifted away from every triangle hypothesis: not trustworthy.
            status, reason = "no_fix", "unsupported_refit"
        elif spread > cfg.max_position_sigma_m:
            # Right or wrong, a fit this loose cannot place the LN within metres.
            status, reason = "no_fix", "imprecise"
        elif ambiguous:
            status, reason = "no_fix", "ambiguous"
        return MatchResult(
            status=status, reason=reason, map_T_odom=best_T,
            covariance=covariance, position_sigma_m=spread,
            inliers=np.column_stack([kept[best.ln], best.gn]).astype(np.int64),
            votes=votes, support=support,
            runner_up=runner_up, margin=support - runner_up,
            log_odds=log_odds, false_match_probability=p_false,
        )

    def _refine_distinct(
        self,
        pts: np.ndarray,
        groups: list,
        node_tol: np.ndarray,
        weights: np.ndarray,
        pool: _Pool,
        cache: dict[int, _Refined] | None = None,
    ) -> tuple[list[_Refined], int]:
        """Refine the ``n_refine`` best mutually distinct hypotheses, best first.

        Non-maximum suppression: after refining the best remaining hypothesis, every
        hypothesis within ``distinct_ratio`` tolerances of it is set aside.

        Returns:
            The refined transforms, by decreasing support, then increasing residual, and
            the best raw support of the hypotheses left unrefined.
        """
        cfg = self.config
        alive = np.ones(len(pool.yaw), dtype=bool)
        refined = []
        for _ in range(cfg.n_refine):
            if not alive.any():
                break
            pick = int(np.flatnonzero(alive)[np.argmax(pool.support[alive])])
            # An alternative supported by little more than its own triangle is not worth
            # refining: its raw support stands for it.
            if refined and pool.support[pick] < cfg.min_refine_support:
                break
            if cache is not None and pick in cache:
                # Refined in an earlier round (the pool only grows): same input, same fit.
                refined.append(cache[pick])
            else:
                yaw, t, ln, gn = refine(
                    self.index, pts, groups, node_tol, weights, float(pool.yaw[pick]),
                    pool.t[pick], iterations=cfg.refine_iterations, n_sigma=cfg.n_sigma,
                    max_gate=cfg.max_tol_m,
                )
                residual = transform_points(yaw, t, pts[ln]) - self.index.pts[gn]
                cost = float(np.sum(weights[ln] * np.sum(residual**2, axis=1)))
                refined.append(_Refined(yaw, t, ln, gn, cost))
                if cache is not None:
                    cache[pick] = refined[-1]
            alive &= displacement(pool.mapped, pool.mapped[pick], node_tol) > cfg.distinct_ratio
        leftover = int(pool.support[alive].max(initial=0))
        return sorted(refined, key=lambda r: (-len(r.ln), r.cost)), leftover


@dataclass
class _Refined:
    """A refined transform: yaw (rad), t (m), inlier LN/GN indices, weighted cost."""

    yaw: float
    t: np.ndarray
    ln: np.ndarray
    gn: np.ndarray
    cost: float


class _Pool:
    """Hypotheses verified so far: transforms, mapped LN, support, source triplet and
    triangle correspondences (LN and GN indices)."""

    def __init__(self) -> None:
        self.yaw = np.zeros(0)
        self.t = np.zeros((0, 2))
        self.mapped = np.zeros((0, 0, 2))
        self.support = np.zeros(0, dtype=np.int64)
        self.source = np.zeros(0, dtype=np.int64)
        self.ln_idx = np.zeros((0, 3), dtype=np.int64)
        self.gn_idx = np.zeros((0, 3), dtype=np.int64)

    def add(self, yaw: np.ndarray, t: np.ndarray, mapped: np.ndarray, support: np.ndarray,
            source: np.ndarray, ln_idx: np.ndarray, gn_idx: np.ndarray) -> None:
        """Append a batch of verified hypotheses."""
        if not len(self.yaw):
            self.mapped = mapped
        else:
            self.mapped = np.concatenate([self.mapped, mapped])
        self.yaw = np.concatenate([self.yaw, yaw])
        self.t = np.concatenate([self.t, t])
        self.support = np.concatenate([self.support, support])
        self.source = np.concatenate([self.source, source])
        self.ln_idx = np.concatenate([self.ln_idx, ln_idx])
        self.gn_idx = np.concatenate([self.gn_idx, gn_idx])


def _same_fix(a: _Refined, b: _Refined) -> bool:
    """Whether two refined transforms share at least half of the smaller inlier set."""
    pairs_a = set(zip(a.ln.tolist(), a.gn.tolist(), strict=True))
    shared = sum((p in pairs_a) for p in zip(b.ln.tolist(), b.gn.tolist(), strict=True))
    return shared >= 0.5 * max(1, min(len(a.ln), len(b.ln)))


def _records_var(records: np.ndarray) -> np.ndarray:
    """Per-axis position variance of LN records from their covariance, m^2 (a missing or
    negative one as 0)."""
    var = 0.5 * (records["cov_xx"].astype(float) + records["cov_yy"].astype(float))
    return np.clip(np.nan_to_num(var), 0.0, None)


def _em_covariance(pts: np.ndarray, var: np.ndarray, fit: EmFit) -> np.ndarray:
    """(x, y, yaw) covariance of an EM fit, each node informing it by its probability of
    having a counterpart."""
    return pose_covariance(pts, fit.yaw, fit.matched / var)


def _ms(t0: float) -> float:
    return 1e3 * (time.perf_counter() - t0)


def _add(timings: dict[str, float], stage: str, t0: float) -> None:
    timings[stage] = timings.get(stage, 0.0) + _ms(t0)


def _since(t_start: float, timings: dict[str, float]) -> dict[str, float]:
    timings["total"] = _ms(t_start)
    return timings
