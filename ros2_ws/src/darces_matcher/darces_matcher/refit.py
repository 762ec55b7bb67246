"""Step 5 of :meth:`~darces_matcher.matcher.Matcher.match`: the probabilistic refit of a
fix (:func:`~darces_matcher.em_refit.em_refit`) and the decision again on its alignment
(:func:`refit_fix`); the same decision on the EM's alignment of a search's best when the
search gives no fix (:func:`decide_on_ml`, the end of step 4).

The EM (:mod:`~darces_matcher.em_refit`) and the odds (:mod:`~darces_matcher.decision`)
are their own modules; this one runs them on an LN as the search prepared it.
"""

from __future__ import annotations

import time
from collections.abc import Sequence

import numpy as np

from darces_matcher.config import MatchConfig
from darces_matcher.decision import MIN_CHANCE_COUNT, SPENT_NODES, Verdict, decide
from darces_matcher.em_refit import EmFit, EmModel, em_refit
from darces_matcher.gn_model import GnModel
from darces_matcher.result import MatchResult
from darces_matcher.search import MIN_VOTES, Examined, Hypotheses, Search
from darces_matcher.timings import elapsed_ms
from darces_matcher.tolerances import LnNodes, fit_spread
from darces_matcher.vote import covering_covariance, pose_covariance
from roi_network.transform import Rigid2D

#: Widest annealing width of the EM, metres (halved down to 0.5 m, then 0).
ANNEAL_START_M = 4.0
#: EM iterations per annealing level.
EM_ITERATIONS = 4


def refit_fix(result: MatchResult, model: GnModel, nodes: LnNodes, found: Search,
              cfg: MatchConfig) -> MatchResult:
    """Step 5: the maximum-likelihood refit of a fix (EM, :mod:`~darces_matcher.em_refit`)
    on ``model``, the labelled GN, whichever search ``found`` it.

    The decision (votes, alternatives) stands, except that the EM's alignment must pass
    it again: its odds against chance, with the same search size and alternatives; else
    no fix (``insufficient_support``). The transform, its inlier pairs and covariance
    become the EM's if its predicted spread passes ``max_position_sigma_m``.
    """
    t0 = time.perf_counter()
    pts, labels = nodes.pts, nodes.labels
    var = 1.0 / found.tol.weights
    fit = em_fit(model, cfg, pts, labels, var, result.map_T_odom, ANNEAL_START_M)
    # The decision again, on the maximum-likelihood alignment.
    examined = found.examined
    verdict = odds_verdict(model, cfg, fit, pts, labels, var, examined.n_tested,
                           examined.alternatives, examined.hypotheses)
    result.log_odds = verdict.log_odds
    result.false_match_probability = verdict.p_false
    if not verdict.accept:
        result.status, result.reason = "no_fix", "insufficient_support"
    else:
        covariance = em_covariance(pts, var, fit)
        spread = fit_spread(nodes, fit.yaw, covariance)
        if spread <= cfg.max_position_sigma_m:
            result.map_T_odom = Rigid2D(fit.yaw, fit.t[0], fit.t[1])
            result.covariance = reported_covariance(model, cfg, pts, labels, var, fit,
                                                    covariance)
            result.position_sigma_m = spread
            result.inliers = np.column_stack([nodes.kept[fit.ln], fit.gn]).astype(np.int64)
    ms = elapsed_ms(t0)
    result.timings_ms["em_refit"] = ms
    result.timings_ms["total"] = result.timings_ms.get("total", 0.0) + ms
    return result


def decide_on_ml(result: MatchResult, model: GnModel, nodes: LnNodes, tol_weights: np.ndarray,
                 examined: Examined, cfg: MatchConfig) -> MatchResult:
    """The decision again, on the EM's maximum-likelihood alignment from the search's
    best when the search ends without a fix for its odds on the hard refit
    (``insufficient_support``): the alignment a fix would get, whose odds the hard pairs
    understate where far nodes stand among clustered GN ROIs. A fix if its odds pass
    with the search's size and alternatives, and its spread the precision test."""
    pts, labels = nodes.pts, nodes.labels
    var = 1.0 / tol_weights
    fit = em_fit(model, cfg, pts, labels, var, result.map_T_odom, ANNEAL_START_M)
    verdict = odds_verdict(model, cfg, fit, pts, labels, var, examined.n_tested,
                           examined.alternatives, examined.hypotheses)
    covariance = em_covariance(pts, var, fit)
    spread = fit_spread(nodes, fit.yaw, covariance)
    if not verdict.accept or result.votes < MIN_VOTES \
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
    result.covariance = reported_covariance(model, cfg, pts, labels, var, fit, covariance)
    result.position_sigma_m = spread
    result.inliers = np.column_stack([nodes.kept[fit.ln], fit.gn]).astype(np.int64)
    result.support = len(fit.ln)
    result.margin = result.support - result.runner_up
    result.log_odds, result.false_match_probability = verdict.log_odds, verdict.p_false
    return result


def em_model(model: GnModel, cfg: MatchConfig, pts: np.ndarray, labels: np.ndarray,
             var: np.ndarray) -> EmModel:
    """The mixture model of an LN (``odom`` positions, labels, per-axis variances)
    against the GN (:class:`~darces_matcher.em_refit.EmModel`)."""
    w = cfg.outlier_prior
    return EmModel(model.index.tree, model.labels, pts, labels, var,
                   w / (1.0 - w) * model.density, model.label_confusion)


def em_fit(model: GnModel, cfg: MatchConfig, pts: np.ndarray, labels: np.ndarray,
           var: np.ndarray, start: Rigid2D, anneal_start_m: float) -> EmFit:
    """The annealed EM (:func:`~darces_matcher.em_refit.em_refit`) of an LN (``odom``
    positions, labels, per-axis variances) from the alignment ``start``."""
    return em_refit(em_model(model, cfg, pts, labels, var), start.yaw,
                    np.array([start.tx, start.ty]), anneal_start_m=anneal_start_m,
                    iterations=EM_ITERATIONS)


def reported_covariance(model: GnModel, cfg: MatchConfig, pts: np.ndarray,
                        labels: np.ndarray, var: np.ndarray, fit: EmFit,
                        covariance: np.ndarray) -> np.ndarray:
    """The covariance a fix reports: the complete-data one widened to cover the
    observed information's (Louis 1982,
    :meth:`~darces_matcher.em_refit.EmModel.association_covariance`), the complete-data
    information less what is missing for not knowing which rock each node pairs with;
    where the pairs leave a direction undetermined, the complete-data one as it is. In a
    clustered GN the maximum likelihood may sit 2-5 m from the truth with its pairs
    shifted by a rock each: the complete-data covariance alone would not cover it. The
    decision (odds, ``imprecise``) stays on the complete-data covariance."""
    louis = em_model(model, cfg, pts, labels, var).association_covariance(fit.yaw, fit.t)
    return covering_covariance(covariance, louis)


def odds_verdict(model: GnModel, cfg: MatchConfig, fit: EmFit, pts: np.ndarray,
                 labels: np.ndarray, var: np.ndarray, n_tested: float,
                 alternatives: Sequence[float], hypotheses: Hypotheses | None = None,
                 spent: int = SPENT_NODES) -> Verdict:
    """The odds decision (:func:`~darces_matcher.decision.decide`) on an EM alignment,
    given the count of alignments examined and the distinct alternatives' log-odds;
    ``hypotheses``: the search's, whose triangles that are this alignment give the
    terms left out of its odds; else ``spent``, the largest node terms left out."""
    chance = model.chance
    moments = chance.log_moments(labels, var)
    k = chance.odds(fit.yaw, fit.t, pts, labels, var, spent).log_odds
    verdict = decide(k, n_tested, alternatives, cfg.false_match_rate, moments,
                     MIN_CHANCE_COUNT)
    if hypotheses is None or verdict.accept:
        # The hypotheses' odds only raise the fit's: it passes on them too.
        return verdict
    k = max(k, float(hypotheses.log_odds(chance, [(fit.yaw, fit.t, fit.ln, fit.gn)],
                                         pts, labels, var)[0]))
    return decide(k, n_tested, alternatives, cfg.false_match_rate, moments,
                  MIN_CHANCE_COUNT)


def em_covariance(pts: np.ndarray, var: np.ndarray, fit: EmFit) -> np.ndarray:
    """(x, y, yaw) covariance of an EM fit, each node informing it by its probability of
    having a counterpart."""
    return pose_covariance(pts, fit.yaw, fit.matched / var)
