"""DARCES matching of a Local Network onto the Global Network (paper Sec. 6).

:class:`Matcher` holds the GN index (built once) and fits LNs onto it::

    matcher = Matcher(gn, MatchConfig())
    result = matcher.match(ln_records)          # LN in odom, GN in map
    if result.status == "fix":
        map_T_odom = result.map_T_odom          # roi_network.transform.Rigid2D

``MatchConfig.original()`` gives the paper's baseline, the original DARCES (no triangle
orientation, no class labels). The settings live in :mod:`~darces_matcher.config`, the
outcome in :mod:`~darces_matcher.result`; both are importable from here too.

:meth:`Matcher.match` reads as the method's steps in order. Each step's part of
:class:`Matcher` lives in its own module, as a class that :class:`Matcher` inherits:

* :mod:`~darces_matcher.tolerances` (step 1): the LN's nodes, their error model,
  tolerances d_D, gates and weights;
* :mod:`~darces_matcher.search` (steps 2-3): control triplets, then rounds of triangle
  hypotheses, votes, refit of the distinct best and the decision;
* :mod:`~darces_matcher.semantics` (step 4): soft semantics, the label-blind polish and
  search;
* :mod:`~darces_matcher.refit` (step 5): the probabilistic (EM) refit of a fix, decided
  again;
* :mod:`~darces_matcher.tracking`: tracking near a prior once localized
  (:meth:`Matcher.track`, :meth:`Matcher.match_or_track`).
"""

from __future__ import annotations

import time
from dataclasses import replace

import numpy as np

from darces_matcher.config import MatchConfig
from darces_matcher.decision import ChanceModel
from darces_matcher.em_refit import gn_density
from darces_matcher.gn_index import GnIndex
from darces_matcher.refit import Refit
from darces_matcher.result import MatchResult, Status
from darces_matcher.search import Hypotheses, Search
from darces_matcher.semantics import SoftSemantics
from darces_matcher.timings import add_stage, elapsed_ms, with_total
from darces_matcher.tolerances import LnTolerances
from darces_matcher.tracking import PRIOR_CHI2, Tracking
from roi_network.network import RoiNetwork

__all__ = ["PRIOR_CHI2", "MatchConfig", "MatchResult", "Matcher", "Status"]


class Matcher(LnTolerances, Search, SoftSemantics, Refit, Tracking):
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
        #: (alignments examined, odds of the distinct alternatives, its hypotheses when
        #: the odds are by spent triangles) of the last search.
        self._last_search: tuple[float, list[float], Hypotheses | None] = (1.0, [], None)
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

        The method's steps, in order (docs/matcher.md details them in its own numbering):

        1. tolerances d_D, gates and weights from the LN error model (:meth:`_tolerances`,
           :mod:`~darces_matcher.tolerances`);
        2. control triplets (:func:`~darces_matcher.triplets.control_triplets`), from
           close nodes when no wide triangle exists (:meth:`_control_triplets`);
        3. then, per round of triplets: triangle hypotheses
           (:func:`~darces_matcher.hypotheses.triangle_hypotheses`), votes of the whole
           LN (:func:`~darces_matcher.vote.vote`), refit of the distinct best
           (:func:`~darces_matcher.vote.refine`) and the decision on the odds of a
           chance alignment (:func:`~darces_matcher.decision.decide`), until a fix
           (:meth:`_search`, :mod:`~darces_matcher.search`); failing that, the decision
           once more on the EM's alignment of the winner (:meth:`_decide_on_ml`);
        4. soft semantics: the label-blind search when the labelled one gives no fix
           (:meth:`_label_blind`, :mod:`~darces_matcher.semantics`);
        5. the probabilistic refit of a fix (:func:`~darces_matcher.em_refit.em_refit`)
           and the decision again on its alignment (:meth:`_em_refit`,
           :mod:`~darces_matcher.refit`).

        Steps 1-3 are one search (:meth:`_match`), labelled as configured; after it, the
        label-blind polish of its fix (without the EM refit), the EM refit, and the
        label-blind search when it gives no fix (or its fix's EM alignment is withheld).
        """
        cfg = self.config
        # 1-3. The search, labelled as configured.
        result = self._match(ln, ln_sigma, anchor_newest, odom_cov)
        if (result.is_fix and cfg.use_labels and cfg.label_fallback
                and cfg.polish_label_blind and not cfg.probabilistic_refit):
            # 4. Soft semantics without the EM: the label-blind polish of a labelled fix.
            # (The EM refit's class prior lets misclassified nodes join the fix: with it
            # the polish is redundant.)
            return self._polish(result)
        if result.is_fix and cfg.probabilistic_refit:
            # 5. The probabilistic refit of a fix and the decision on its alignment.
            result = self._em_refit(result)
            if not cfg.fallback_after_withheld:
                return result
            # A labelled fix whose EM alignment is withheld falls back to the
            # label-blind search as a labelled no-fix does.
        if result.is_fix or not (cfg.use_labels and cfg.label_fallback) or result.reason in (
            "too_few_nodes", "no_control_triplet"
        ) or not self._fallback_ok:
            return result
        # 4. Soft semantics: the label-blind search (then 5., the EM refit of its fix).
        return self._label_blind(result, ln, ln_sigma, anchor_newest, odom_cov)

    def _match(self, ln: np.ndarray | RoiNetwork, ln_sigma: np.ndarray | None,
               anchor_newest: bool = False,
               odom_cov: np.ndarray | None = None) -> MatchResult:
        """One search (labelled or not, as configured): steps 1-3 of :meth:`match`."""
        cfg = self.config
        t_start = time.perf_counter()
        timings: dict[str, float] = {}
        kept, sigma, pts, labels = self._finite_nodes(ln, ln_sigma, anchor_newest, odom_cov)
        if len(kept) < 3:
            return MatchResult("no_fix", "too_few_nodes",
                               timings_ms=with_total(t_start, timings))

        # 1. Tolerances d_D, gates and weights from the LN error model.
        tol = self._tolerances(sigma, labels)
        # Kept for the label-blind polish of a fix (:meth:`_polish`) and the EM refit
        # (:meth:`_em_refit`); a Matcher serves one match at a time.
        self._last = (kept, pts, labels, tol.gate, tol.weights)

        # 2. Control triplets: precise, well conditioned, spread over nodes.
        t0 = time.perf_counter()
        triplets, n_selective = self._control_triplets(pts, labels, tol.node_tol,
                                                       tol.edge_tol)
        timings["triplets"] = elapsed_ms(t0)
        if len(triplets) == 0:
            return MatchResult("no_fix", "no_control_triplet",
                               timings_ms=with_total(t_start, timings))

        # 3. Hypotheses, votes, refit of the distinct best and the decision, one round of
        # control triplets at a time, until a fix.
        result = self._search(pts, labels, kept, tol, triplets, n_selective, timings)
        if (result.reason == "insufficient_support" and result.map_T_odom is not None
                and cfg.decide_on_ml and cfg.probabilistic_refit and cfg.decision == "odds"):
            # No fix: the decision once more, on the EM's alignment of the winner.
            t0 = time.perf_counter()
            result = self._decide_on_ml(result, kept, pts, labels, tol.weights)
            add_stage(timings, "ml_decision", t0)
        result.timings_ms = with_total(t_start, timings)
        return result

    def _blind_matcher(self) -> Matcher:
        """The label-blind matcher of the fallback, its index built at first use."""
        if self._blind is None:
            self._blind = Matcher(self._gn, replace(self.config, use_labels=False,
                                                    label_fallback=False))
        return self._blind
