"""The matcher's settings, :class:`MatchConfig` (docs/matcher.md, "Parameters").

The tunables of :class:`~darces_matcher.matcher.Matcher`; what a user does not tune is a
named constant next to the step that uses it. :meth:`MatchConfig.original` gives the
paper's original DARCES, the baseline.
"""

from __future__ import annotations

from dataclasses import dataclass, replace


@dataclass(frozen=True)
class MatchConfig:
    """The tunables of the matcher (see docs/matcher.md).

    Attributes:
        original_darces: the paper's original DARCES, the baseline: no triangle orientation, no
            class labels, the paper's fixed-count voting, no probabilistic refit, no
            control triangles shorter than 10 m, the precision test at every node.
        n_sigma: tolerance of a node in standard deviations of its position error.
            Larger: more robust to drift, more random hypotheses and votes.
        gn_sigma_m: 1-sigma position error of a GN node per axis (orbital), metres.
        ln_sigma_floor_m: smallest 1-sigma LN position error per axis (a node's own
            detection error), metres.
        n_triplets: control triplets tried per LN at most. More: robustness to outliers
            and misclassified nodes, at linear cost.
        max_position_sigma_m: largest predicted 1-sigma error per axis of the LN's
            newest node mapped by a fit (of every node with ``original_darces``) for a fix,
            metres.
        false_match_rate: the accepted share of wrong fixes, the one threshold of the
            odds decision.
        outlier_prior: share of LN nodes expected to have no GN counterpart (false
            detections, orbital misses), in the odds and the EM's mixture.
        label_confusion: probability that an LN node's class differs from its GN
            counterpart's, in the odds and the EM's mixture (0.5: classes ignored).
    """

    original_darces: bool = False
    n_sigma: float = 3.0
    gn_sigma_m: float = 0.3
    ln_sigma_floor_m: float = 0.2
    n_triplets: int = 12
    max_position_sigma_m: float = 2.0
    false_match_rate: float = 1e-2
    outlier_prior: float = 0.3
    label_confusion: float = 0.1

    def __post_init__(self) -> None:
        if not 0.0 <= self.outlier_prior < 1.0:
            raise ValueError(f"MatchConfig.outlier_prior must be in [0, 1), got "
                             f"{self.outlier_prior}")
        if not 0.0 < self.false_match_rate < 1.0:
            raise ValueError(f"MatchConfig.false_match_rate must be in (0, 1), got "
                             f"{self.false_match_rate}")
        if not 0.0 <= self.label_confusion <= 0.5:
            raise ValueError(f"MatchConfig.label_confusion must be in [0, 0.5], got "
                             f"{self.label_confusion}")

    @classmethod
    def original(cls, **overrides: object) -> MatchConfig:
        """The paper's original DARCES (``original_darces=True``), with ``overrides``."""
        return replace(cls(original_darces=True), **overrides)
