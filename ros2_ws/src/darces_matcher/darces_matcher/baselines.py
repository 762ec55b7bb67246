"""Baselines run side by side with the matcher by ``darces_eval``.

* ``darces``: this package's improved DARCES (:class:`~darces_matcher.matcher.Matcher`).
* ``darces_counts``: the same matcher deciding by fixed support and margin counts, as
  before the odds decision (:meth:`MatchConfig.counts`).
* ``darces_markov``: the odds decision with Markov's bound alone on the chance
  alignments (``MatchConfig(chernoff_orders=())``, the odds decision's first pass).
* ``darces_hard``: the odds decided on the hard refit alone, as before 2026-11-26
  (``MatchConfig(decide_on_ml=False)``).
* ``darces_top3``: the odds decision before 2026-11-28, twelfth session: the three
  largest node terms left out in place of the terms of the control triangle that found
  the alignment, and no floor under the Chernoff bound
  (``MatchConfig(spent_by_triangle=False, min_chance_count=0)``).
* ``darces_original``: the paper's baseline, the original DARCES: same machinery without
  the orientation and semantic constraints (:meth:`MatchConfig.original`).
* ``kiss_matcher``: KISS-Matcher 1.0.2 (ROBIN max-clique pruning + graduated
  non-convexity, the TEASER++ approach), fed with every label-consistent LN-GN pair as a
  putative correspondence (plain ``solve`` fails on such input; ``prune_and_solve`` is its
  entry point for given correspondences). 2D points are lifted to z = 0.
"""

from __future__ import annotations

import time
from typing import Protocol

import numpy as np

from darces_matcher.matcher import MatchConfig, Matcher, MatchResult
from roi_network.network import RoiNetwork
from roi_network.records import xy
from roi_network.transform import Rigid2D

METHODS = ("darces", "darces_counts", "darces_markov", "darces_first_all", "darces_hard",
           "darces_top3",
           "darces_original", "kiss_matcher")


class LnMatcher(Protocol):
    """What ``darces_eval`` needs from a method."""

    def match(self, ln: np.ndarray, ln_sigma: np.ndarray | None = None) -> MatchResult:
        """Fit LN records (``odom``) onto the GN."""
        ...


class KissMatcherBaseline:
    """KISS-Matcher on label-consistent all-pairs correspondences.

    Args:
        gn: the Global Network, ``map``.
        noise_bound_m: ROBIN/GNC noise bound, metres (pairwise consistency tolerance);
            2 m was the best of 2, 4 and 8 m on the paper protocol.
        min_inliers: fewest final inliers for a fix; fewer or an invalid solution is a
            no fix.

    Raises:
        ImportError: if kiss-matcher is not installed.
    """

    def __init__(self, gn: RoiNetwork, noise_bound_m: float = 2.0, min_inliers: int = 6) -> None:
        import kiss_matcher  # optional dependency, imported only for this baseline

        self._km = kiss_matcher
        self.gn_pts = xy(gn.records)
        self.gn_labels = gn.records["label"]
        self.noise_bound_m = noise_bound_m
        self.min_inliers = min_inliers

    def match(self, ln: np.ndarray, ln_sigma: np.ndarray | None = None) -> MatchResult:
        """Fit LN records onto the GN; ``ln_sigma`` is unused (fixed noise bound)."""
        t0 = time.perf_counter()
        pts, labels = xy(ln), ln["label"]
        ln_i, gn_j = np.nonzero(labels[:, None] == self.gn_labels[None, :])
        if len(pts) < 3 or len(ln_i) < 3:
            return MatchResult("no_fix", "too_few_nodes",
                               timings_ms={"total": 1e3 * (time.perf_counter() - t0)})
        zeros = np.zeros((len(ln_i), 1), dtype=np.float32)
        src = list(np.hstack([pts[ln_i].astype(np.float32), zeros])[..., None])
        tgt = list(np.hstack([self.gn_pts[gn_j].astype(np.float32), zeros])[..., None])
        config = self._km.KISSMatcherConfig(
            voxel_size=self.noise_bound_m, use_voxel_sampling=False,
            enable_noise_bound_clamping=False,
        )
        solver = self._km.KISSMatcher(config)
        solution = solver.prune_and_solve(src, tgt)
        inliers = solver.get_num_final_inliers()
        rotation = np.asarray(solution.rotation)
        translation = np.asarray(solution.translation).ravel()
        timings = {"total": 1e3 * (time.perf_counter() - t0)}
        # A 3D solver may return a flip about a horizontal axis: a reflection in 2D.
        proper = rotation[2, 2] > 0.5
        if not solution.valid or not proper or inliers < self.min_inliers:
            return MatchResult("no_fix", "insufficient_support", support=inliers,
                               timings_ms=timings)
        yaw = float(np.arctan2(rotation[1, 0], rotation[0, 0]))
        return MatchResult("fix", "ok", Rigid2D(yaw, translation[0], translation[1]),
                           support=inliers, timings_ms=timings)


def make_method(name: str, gn: RoiNetwork) -> LnMatcher:
    """Build one of :data:`METHODS` on a GN.

    Raises:
        ValueError: on an unknown method name.
    """
    if name == "darces":
        return Matcher(gn, MatchConfig())
    if name == "darces_counts":
        return Matcher(gn, MatchConfig.counts())
    if name == "darces_markov":
        return Matcher(gn, MatchConfig(chernoff_orders=()))
    if name == "darces_first_all":
        return Matcher(gn, MatchConfig(first_fix_judged_at_newest=False))
    if name == "darces_hard":
        return Matcher(gn, MatchConfig(decide_on_ml=False))
    if name == "darces_top3":
        return Matcher(gn, MatchConfig(spent_by_triangle=False, min_chance_count=0.0))
    if name == "darces_original":
        return Matcher(gn, MatchConfig.original())
    if name == "kiss_matcher":
        return KissMatcherBaseline(gn)
    raise ValueError(f"unknown method '{name}' (known: {', '.join(METHODS)})")
