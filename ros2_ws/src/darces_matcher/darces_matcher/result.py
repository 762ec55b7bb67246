"""The outcome of matching one LN, :class:`MatchResult`."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from roi_network.transform import Rigid2D

Status = Literal["fix", "no_fix"]


@dataclass
class MatchResult:
    """Outcome of matching one LN.

    Attributes:
        status: ``"fix"`` or ``"no_fix"``.
        reason: why (``"ok"``, ``"too_few_nodes"``, ``"no_control_triplet"``,
            ``"no_hypothesis"``, ``"insufficient_support"``, ``"unsupported_refit"``,
            ``"imprecise"``, ``"ambiguous"``, ``"label_mismatch"``); a fix found by the
            label-blind fallback has reason ``"ok_label_blind"``; :meth:`Matcher.track`
            gives ``"ok_tracked"`` on a fix, ``"outside_prior"`` when its fit left the
            prior's 3-sigma region.
        map_T_odom: fitted transform (``odom`` -> ``map``) of the best hypothesis, also
            given on no_fix when there was one, for diagnostics; use it only on a fix.
        covariance: (3, 3) covariance of (x, y, yaw) of ``map_T_odom``, m^2 and rad^2.
        inliers: (K, 2) int pairs (LN index, GN index).
        votes: control triplets with a triangle hypothesis made of three of the winner's
            inlier correspondences.
        support: inliers of the winner.
        runner_up: inliers of the best distinct alternative (0 if none).
        margin: support - runner_up.
        position_sigma_m: largest predicted 1-sigma error per axis of a mapped LN node
            (of the newest node once localized, ``MatchConfig.localized_anchor_newest``)
            under the fit's complete-data covariance, the one the precision test judges,
            metres. ``covariance`` covers it and may be wider (the association's,
            ``MatchConfig.association_covariance``; the jackknife's once localized).
        n_triplets: control triplets tried.
        n_hypotheses: triangle hypotheses verified.
        timings_ms: wall time per stage, milliseconds.
        log_odds: natural log of the odds of the winner against a chance alignment
            (:mod:`~darces_matcher.decision`); NaN when not computed.
        false_match_probability: probability that the winner is a chance or wrong
            alignment, given the alignments searched and the distinct alternatives;
            NaN when not computed (``decision="counts"``, or no candidate).
        drift_dropped: inlier pairs a localized fix dropped as its LN's drift could not
            explain them (``MatchConfig.drift_fit``).
    """

    status: Status
    reason: str
    map_T_odom: Rigid2D | None = None
    covariance: np.ndarray | None = None
    inliers: np.ndarray = field(default_factory=lambda: np.zeros((0, 2), dtype=np.int64))
    votes: int = 0
    support: int = 0
    runner_up: int = 0
    margin: int = 0
    position_sigma_m: float = float("inf")
    n_triplets: int = 0
    n_hypotheses: int = 0
    timings_ms: dict[str, float] = field(default_factory=dict)
    log_odds: float = float("nan")
    false_match_probability: float = float("nan")
    drift_dropped: int = 0

    @property
    def is_fix(self) -> bool:
        """True when the matcher reports a fix."""
        return self.status == "fix"
