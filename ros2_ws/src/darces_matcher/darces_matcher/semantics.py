"""Step 4 of :meth:`~darces_matcher.matcher.Matcher.match`: soft semantics.

Labels are hard where they are cheap and selective (control triplets, hypotheses, votes)
and soft where a misclassified node would otherwise be lost: the label-blind polish of a
labelled fix (without the EM refit, whose class prior lets such nodes join), and the
label-blind search when the labelled one gives no fix, kept only if its inliers mostly
agree on class.
"""

from __future__ import annotations

import time
from typing import TYPE_CHECKING

import numpy as np

from darces_matcher.config import MatchConfig
from darces_matcher.gn_index import GnIndex
from darces_matcher.result import MatchResult
from darces_matcher.timings import elapsed_ms
from darces_matcher.vote import associate, pose_covariance, refine, transform_points
from roi_network.network import RoiNetwork
from roi_network.records import as_records
from roi_network.transform import Rigid2D

if TYPE_CHECKING:
    from darces_matcher.matcher import Matcher


class SoftSemantics:
    """The soft semantics of :class:`~darces_matcher.matcher.Matcher` (a mixin: it uses
    the matcher's settings, GN index and labels, the LN as its last search prepared it
    (``_last``) and its label-blind matcher)."""

    config: MatchConfig
    index: GnIndex
    _gn_labels: np.ndarray
    _last: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]

    def _label_blind(
        self, result: MatchResult, ln: np.ndarray | RoiNetwork, ln_sigma: np.ndarray | None,
        anchor_newest: bool = False, odom_cov: np.ndarray | None = None,
    ) -> MatchResult:
        """The label-blind search of an LN whose labelled search gave ``result``, no fix.

        Misclassified nodes cannot vote in the labelled search; search again on geometry
        only, and keep that fix if its inliers mostly agree on class (a class-swapped LN
        finds its geometric match but fails this check).
        """
        cfg = self.config
        blind: Matcher = self._blind_matcher()
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
            result.timings_ms["polish"] = elapsed_ms(t0)
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
            result.timings_ms["polish"] = elapsed_ms(t0)
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
        result.timings_ms["polish"] = elapsed_ms(t0)
        result.timings_ms["total"] += result.timings_ms["polish"]
        return result
