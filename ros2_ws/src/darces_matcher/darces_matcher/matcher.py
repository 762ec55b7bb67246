"""DARCES matching of a Local Network onto the Global Network (paper Sec. 6).

:class:`Matcher` holds the GN models (built once) and fits LNs onto them::

    matcher = Matcher(gn, MatchConfig())
    result = matcher.match(ln_records)          # LN in odom, GN in map
    if result.status == "fix":
        map_T_odom = result.map_T_odom          # roi_network.transform.Rigid2D

``MatchConfig.original()`` gives the paper's baseline, the original DARCES (no triangle
orientation, no class labels, the paper's voting). The settings live in
:mod:`~darces_matcher.config`, the outcome in :mod:`~darces_matcher.result`; both are
importable from here too.

:meth:`Matcher.match` runs the method's steps in order, each a function over explicit
values in the module named:

1. the LN's nodes and their error model: the finite nodes, each node's 1-sigma error
   relative to an anchor node, and where a fit is judged precise (the newest node)
   (:func:`~darces_matcher.tolerances.ln_nodes`);
2. tolerances d_D, gates and weights from that error model and the GN's
   (:func:`~darces_matcher.tolerances.tolerances`);
3. control triplets: precise, well conditioned, spread over the nodes, from close nodes
   when no wide triangle exists (:func:`~darces_matcher.search.select_triplets`);
4. per round of triplets: triangle hypotheses, votes of the whole LN, refit of the
   distinct best and the decision on the odds of a chance alignment, until a fix
   (:func:`~darces_matcher.search.search`); failing that, the decision once more on the
   EM's alignment of the winner (:func:`~darces_matcher.refit.decide_on_ml`);
5. the probabilistic (EM) refit of a fix and the decision again on its alignment
   (:func:`~darces_matcher.refit.refit_fix`);
6. soft semantics: when the labelled search gives no fix, steps 2-5 again blind to
   classes, the fix kept if its inliers mostly agree on class
   (:func:`~darces_matcher.semantics.label_blind_outcome`).

The original DARCES runs steps 1-4 label-blind, decided by the paper's fixed counts.

:meth:`Matcher.match_or_track` is the darces_matcher node's decision for each LN, once
the rover is localized (given a prior alignment):

1. the global search (:meth:`Matcher.match`), node sigmas relative to the newest node;
2. tracking near the prior (:func:`~darces_matcher.tracking.track`);
3. the fix less likely to be a chance alignment of the two;
4. that fix refitted under the LN's correlated drift, or its covariance widened to its
   jackknife's (:func:`~darces_matcher.tracking.localized_fix`).
"""

from __future__ import annotations

import time

import numpy as np

from darces_matcher.config import MatchConfig
from darces_matcher.gn_index import GnIndex
from darces_matcher.gn_model import GnModel, blind_search_ok, gn_model
from darces_matcher.refit import decide_on_ml, refit_fix
from darces_matcher.result import MatchResult, Status
from darces_matcher.search import Search, search, select_triplets
from darces_matcher.semantics import FINAL_REASONS, label_blind_outcome
from darces_matcher.timings import add_stage, elapsed_ms, with_total
from darces_matcher.tolerances import LnNodes, ln_nodes, node_sigma, tolerances
from darces_matcher.tracking import (
    PRIOR_CHI2,
    check_prior_covariance,
    localized_fix,
    prior_search_size,
    track,
)
from roi_network.network import RoiNetwork
from roi_network.transform import Rigid2D

__all__ = ["PRIOR_CHI2", "MatchConfig", "MatchResult", "Matcher", "Status"]


class Matcher:
    """DARCES matcher of LNs (``odom``) against one GN (``map``).

    Args:
        gn: the Global Network, ``map`` frame, at least 3 ROIs.
        config: matcher settings; defaults to the improved DARCES.

    Raises:
        ValueError: if the GN has fewer than 3 ROIs or non-finite positions.
    """

    def __init__(self, gn: RoiNetwork, config: MatchConfig | None = None) -> None:
        self.config = config or MatchConfig()
        original = self.config.original_darces
        #: The GN as the search takes it: labelled (label-blind for the original DARCES).
        self.model: GnModel = gn_model(gn, self.config, use_labels=not original)
        #: The label-blind GN of soft semantics (step 6), built now rather than at the
        #: first fallback so that a running matcher never stalls for it; None for the
        #: original DARCES or a GN too large for a second index.
        self.blind_model: GnModel | None = (
            gn_model(gn, self.config, use_labels=False)
            if not original and blind_search_ok(gn, self.model.index) else None)

    @property
    def index(self) -> GnIndex:
        """The GN index of the search."""
        return self.model.index

    def match(
        self, ln: np.ndarray | RoiNetwork, ln_sigma: np.ndarray | None = None,
        anchor_newest: bool = False, odom_cov: np.ndarray | None = None,
    ) -> MatchResult:
        """Fit an LN onto the GN: steps 1-6 of the module docstring.

        Args:
            ln: LN records (:data:`~roi_network.records.ROI_DTYPE`) or network, ``odom``.
            ln_sigma: optional (N,) 1-sigma position error per axis of each LN node,
                metres (the LN error model: VO drift grows with distance travelled);
                default: from the records' covariance.
            anchor_newest: the records' covariance is taken relative to the newest node
                (the rover localized: each node's sigma is then its drift relative to
                where the rover is now).
            odom_cov: optional (N, 3, 3) odometry (x, y, yaw) covariance each node was
                observed with (:class:`~darces_matcher.ln_drift.NodeOdometry`): the
                records' covariance is then taken relative to the anchor node with its
                heading error absorbed as well (:meth:`node_sigma`).

        Returns:
            The :class:`MatchResult`; never raises on a degenerate LN.
        """
        t_start = time.perf_counter()
        # 1. The LN's nodes and their error model.
        nodes = ln_nodes(ln, ln_sigma, self.config, anchor_newest, odom_cov)
        return self._match(nodes, t_start)

    def _match(self, nodes: LnNodes, t_start: float) -> MatchResult:
        """Steps 2-6 of :meth:`match` on the LN's nodes (step 1)."""
        # 2-4. The search: tolerances, control triplets, rounds of hypotheses and votes.
        found = self._search(self.model, nodes, t_start)
        result = found.result
        if self.config.original_darces:
            return result
        # 5. The probabilistic refit of a fix, decided again on its alignment.
        if result.is_fix:
            result = refit_fix(result, self.model, nodes, found, self.config)
        if result.is_fix or self.blind_model is None or result.reason in FINAL_REASONS:
            return result
        # 6. Soft semantics: no fix, so steps 2-4 again blind to classes, then 5.
        blind = self._search(self.blind_model, nodes, time.perf_counter())
        result = label_blind_outcome(result, blind.result, nodes, self.model.labels)
        if result.is_fix:
            result = refit_fix(result, self.model, nodes, blind, self.config)
        return result

    def _search(self, model: GnModel, nodes: LnNodes, t_start: float) -> Search:
        """Steps 2-4 of :meth:`match` on one GN model (labelled or label-blind)."""
        cfg = self.config
        timings: dict[str, float] = {}
        if len(nodes) < 3:
            return Search(MatchResult("no_fix", "too_few_nodes",
                                      timings_ms=with_total(t_start, timings)))
        # 2. Tolerances d_D, gates and weights from the LN error model.
        tol = tolerances(nodes, model.index, cfg)
        # 3. Control triplets: precise, well conditioned, spread over nodes.
        t0 = time.perf_counter()
        triplets, n_selective = select_triplets(model, nodes, tol, cfg)
        timings["triplets"] = elapsed_ms(t0)
        if len(triplets) == 0:
            return Search(MatchResult("no_fix", "no_control_triplet",
                                      timings_ms=with_total(t_start, timings)), tol)
        # 4. Hypotheses, votes, refit of the distinct best and the decision, one round of
        # control triplets at a time, until a fix.
        found = search(model, nodes, tol, triplets, n_selective, cfg, timings)
        result = found.result
        if (result.reason == "insufficient_support" and result.map_T_odom is not None
                and found.examined is not None):
            # No fix: the decision once more, on the EM's alignment of the winner.
            t0 = time.perf_counter()
            result = decide_on_ml(result, model, nodes, tol.weights, found.examined, cfg)
            add_stage(timings, "ml_decision", t0)
        result.timings_ms = with_total(t_start, timings)
        return Search(result, tol, found.examined)

    def track(
        self,
        ln: np.ndarray | RoiNetwork,
        prior: Rigid2D,
        prior_covariance: np.ndarray,
        ln_sigma: np.ndarray | None = None,
        anchor_newest: bool = False,
        odom_cov: np.ndarray | None = None,
    ) -> MatchResult:
        """Fit an LN near a known alignment (:func:`~darces_matcher.tracking.track`).

        Args:
            ln: LN records (:data:`~roi_network.records.ROI_DTYPE`) or network, ``odom``.
            prior: the current estimate of ``map_T_odom``.
            prior_covariance: (3, 3) covariance of its (x, y, yaw), m^2 and rad^2.
            ln_sigma, anchor_newest, odom_cov: as in :meth:`match`.

        Returns:
            A :class:`MatchResult` with reason ``"ok_tracked"`` on a fix.

        Raises:
            ValueError: if ``prior_covariance`` is not a finite, positive definite
                (3, 3) matrix.
        """
        p = check_prior_covariance(prior_covariance)
        nodes = ln_nodes(ln, ln_sigma, self.config, anchor_newest, odom_cov)
        return track(self.model, nodes, prior, p, self.config)

    def match_or_track(
        self,
        ln: np.ndarray | RoiNetwork,
        prior: Rigid2D | None = None,
        prior_covariance: np.ndarray | None = None,
        ln_sigma: np.ndarray | None = None,
        odom_cov: np.ndarray | None = None,
    ) -> MatchResult:
        """The darces_matcher node's decision for each LN: the global search and, when a
        prior alignment is given (the rover is localized), steps 1-4 of the module
        docstring. ``timings_ms["total"]`` covers both; ``"search"`` is the global
        search's share when tracking ran.

        Raises:
            ValueError: if a prior is given with a ``prior_covariance`` that is not a
                finite, positive definite (3, 3) matrix.
        """
        t_start = time.perf_counter()
        localized = prior is not None
        nodes = ln_nodes(ln, ln_sigma, self.config, localized, odom_cov)
        # 1. The global search; once localized, node sigmas relative to the newest node.
        result = self._match(nodes, t_start)
        if not localized:
            return result
        # 2. Tracking near the prior.
        tracked = track(self.model, nodes, prior, check_prior_covariance(prior_covariance),
                        self.config)
        # 3. The fix less likely to be a chance alignment.
        likelier = tracked.is_fix and \
            tracked.false_match_probability < result.false_match_probability
        kept = result if result.is_fix and not likelier else tracked
        searched_ms = result.timings_ms.get("total", 0.0)
        kept.timings_ms["total"] = searched_ms + tracked.timings_ms.get("total", 0.0)
        kept.timings_ms["search"] = searched_ms
        # 4. The fix refitted under the LN's drift, or its covariance widened.
        return localized_fix(kept, nodes, self.index, self.config)

    def node_sigma(self, records: np.ndarray, ln_sigma: np.ndarray | None,
                   anchor_newest: bool = False,
                   odom_cov: np.ndarray | None = None) -> np.ndarray:
        """1-sigma position error per axis of each LN node, metres
        (:func:`~darces_matcher.tolerances.node_sigma`)."""
        return node_sigma(records, ln_sigma, self.config.ln_sigma_floor_m, anchor_newest,
                          odom_cov)

    @staticmethod
    def prior_search_size(pts: np.ndarray, var: np.ndarray, prior_covariance: np.ndarray,
                          cell_fraction: float = 1.0) -> float:
        """Distinct alignments of an LN inside a prior's 3-sigma ellipsoid
        (:func:`~darces_matcher.tracking.prior_search_size`)."""
        return prior_search_size(pts, var, prior_covariance, cell_fraction)
