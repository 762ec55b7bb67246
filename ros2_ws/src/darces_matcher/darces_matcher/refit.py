"""Step 5 of :meth:`~darces_matcher.matcher.Matcher.match`: the probabilistic refit of a
fix (:func:`~darces_matcher.em_refit.em_refit`) and the decision again on its alignment;
the same decision on the EM's alignment of a search's best when the search gives no fix
(``MatchConfig.decide_on_ml``, the end of step 3).

The EM (:mod:`~darces_matcher.em_refit`) and the odds (:mod:`~darces_matcher.decision`)
are their own modules; this one runs them on an LN as the search prepared it.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from darces_matcher.config import MatchConfig
from darces_matcher.decision import SPENT_NODES, ChanceModel, Verdict, decide
from darces_matcher.em_refit import EmFit, EmModel, em_refit
from darces_matcher.gn_index import GnIndex
from darces_matcher.result import MatchResult
from darces_matcher.timings import elapsed_ms
from darces_matcher.vote import covering_covariance, pose_covariance
from roi_network.transform import Rigid2D

if TYPE_CHECKING:
    from darces_matcher.matcher import Matcher
    from darces_matcher.search import Hypotheses


class Refit:
    """The EM refits of :class:`~darces_matcher.matcher.Matcher` (a mixin: it uses the
    matcher's settings, GN index and density, chance model, the LN as its last search
    prepared it (``_last``) and that search's size and alternatives)."""

    config: MatchConfig
    index: GnIndex
    chance: ChanceModel
    gn_density: float
    _gn_labels: np.ndarray
    _blind: Matcher | None
    _last: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]
    _last_search: tuple[float, list[float], Hypotheses | None]

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
            covariance = em_covariance(pts, var, fit)
            spread = self._spread(pts, fit.yaw, covariance)
            if spread <= cfg.max_position_sigma_m:
                result.map_T_odom = Rigid2D(fit.yaw, fit.t[0], fit.t[1])
                result.covariance = self._reported_covariance(pts, labels, var, fit,
                                                              covariance)
                result.position_sigma_m = spread
                result.inliers = np.column_stack([kept[fit.ln], fit.gn]).astype(np.int64)
        ms = elapsed_ms(t0)
        result.timings_ms["em_refit"] = ms
        result.timings_ms["total"] = result.timings_ms.get("total", 0.0) + ms
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
        covariance = em_covariance(pts, var, fit)
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
        result.covariance = self._reported_covariance(pts, labels, var, fit, covariance)
        result.position_sigma_m = spread
        result.inliers = np.column_stack([kept[fit.ln], fit.gn]).astype(np.int64)
        result.support = len(fit.ln)
        result.margin = result.support - result.runner_up
        result.log_odds, result.false_match_probability = verdict.log_odds, verdict.p_false
        return result

    def _em_model(self, pts: np.ndarray, labels: np.ndarray, var: np.ndarray) -> EmModel:
        """The mixture model of an LN (``odom`` positions, labels, per-axis variances)
        against the GN (:class:`~darces_matcher.em_refit.EmModel`)."""
        cfg = self.config
        w = cfg.outlier_prior
        return EmModel(self.index.tree, self._gn_labels, pts, labels, var,
                       w / (1.0 - w) * self.gn_density,
                       cfg.label_confusion if cfg.use_labels else 0.5)

    def _em_fit(self, pts: np.ndarray, labels: np.ndarray, var: np.ndarray, start: Rigid2D,
                anneal_start_m: float) -> EmFit:
        """The annealed EM (:func:`~darces_matcher.em_refit.em_refit`) of an LN (``odom``
        positions, labels, per-axis variances) from the alignment ``start``."""
        return em_refit(self._em_model(pts, labels, var), start.yaw,
                        np.array([start.tx, start.ty]), anneal_start_m=anneal_start_m,
                        iterations=self.config.em_iterations)

    def _reported_covariance(self, pts: np.ndarray, labels: np.ndarray, var: np.ndarray,
                             fit: EmFit, covariance: np.ndarray) -> np.ndarray:
        """The covariance a fix reports: the complete-data one widened to cover the
        association's (``MatchConfig.association_covariance``); where the pairs leave a
        direction undetermined, the complete-data one as it is."""
        if not self.config.association_covariance:
            return covariance
        louis = self._em_model(pts, labels, var).association_covariance(fit.yaw, fit.t)
        return covering_covariance(covariance, louis)

    def _verdict(self, fit: EmFit, pts: np.ndarray, labels: np.ndarray, var: np.ndarray,
                 n_tested: float, alternatives: Sequence[float],
                 hypotheses: Hypotheses | None = None, spent: int = SPENT_NODES) -> Verdict:
        """The odds decision (:func:`~darces_matcher.decision.decide`) on an EM alignment,
        given the count of alignments examined and the distinct alternatives' log-odds;
        ``hypotheses``: the search's, whose triangles that are this alignment give the
        terms left out of its odds (``MatchConfig.spent_by_triangle``); else ``spent``,
        the largest node terms left out."""
        cfg = self.config
        moments = self._log_moments(labels, var)
        k = self.chance.odds(fit.yaw, fit.t, pts, labels, var, spent).log_odds
        verdict = decide(k, n_tested, alternatives, cfg.false_match_rate, moments,
                         cfg.min_chance_count)
        if hypotheses is None or verdict.accept:
            # The hypotheses' odds only raise the fit's: it passes on them too.
            return verdict
        k = max(k, float(hypotheses.log_odds(self.chance, [(fit.yaw, fit.t, fit.ln, fit.gn)],
                                         pts, labels, var)[0]))
        return decide(k, n_tested, alternatives, cfg.false_match_rate, moments,
                      cfg.min_chance_count)

def em_covariance(pts: np.ndarray, var: np.ndarray, fit: EmFit) -> np.ndarray:
    """(x, y, yaw) covariance of an EM fit, each node informing it by its probability of
    having a counterpart."""
    return pose_covariance(pts, fit.yaw, fit.matched / var)
