"""Detection recipes as typed configurations: the default (``sun_aware``), its fallback
for rasters without a known sun direction (``no_sun``) and the paper's (Sec. 4, orbital)
as the baseline.

Scales are in metres on the ground; :mod:`orbital_gn.detect` turns them into pixels with the
raster's ground sample distance, so one recipe serves any GSD.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Final

from roi_detector.candidates import ORBITAL_PAPER, ClassRule, RuleSet, ThresholdTerm
from roi_detector.classifier import ClassifierConfig
from roi_detector.features import GROUPS, PAPER_GROUPS, SUN_GROUPS
from roi_network import OUTCROP, ROCK

#: Side of the weighted-entropy neighbourhood, m (odd pixels; 5 px at 0.25 m, the paper's).
ENTROPY_WINDOW_M: Final = 1.25
#: A candidate enters the GN when its classifier vote share is at least this.
MIN_PROBABILITY: Final = 0.5


def blob_sigma_m(area_m2: float) -> float:
    """The Gaussian scale at which a disc of ``area_m2`` responds most: r / sqrt(2), m."""
    return math.sqrt(area_m2 / math.pi) / math.sqrt(2.0)


@dataclass(frozen=True)
class Recipe:
    """Everything that decides what a GN holds, apart from the trained classifiers.

    Attributes:
        name: recipe name (recorded in the GN metadata and the model file).
        rules: candidate rules, one per class (:mod:`roi_detector.candidates`).
        hessian_sigmas_m: per class label, the Hessian scales (m); with several, each
            eigenvalue map is the strongest scale-normalised response over them.
        contrast_sigma_m: per class label, scale of the local background for the
            ``contrast`` metric, metres (only for rules that use it).
        contrast_channel: per class label, the image the ``contrast`` metric is taken on:
            ``"gray"`` or ``"paleness"`` (HSV value minus saturation).
        feature_groups: classifier features (:data:`roi_detector.features.GROUPS`).
        classifier: classifier kind and hyper-parameters.
        sun_aware: the recipe needs the sun direction (``prepare --sun-azimuth
            --sun-elevation`` or the raster's metadata): rock centres are moved back
            towards the sun by :func:`roi_detector.candidates.shadow_shift_px` with gain
            ``shadow_kappa``, and the ``sun`` feature group may be used.
        shadow_kappa: gain of the shadow shift (dimensionless; 0: no shift).
    """

    name: str
    rules: RuleSet
    hessian_sigmas_m: dict[int, tuple[float, ...]]
    contrast_sigma_m: dict[int, float] = field(default_factory=dict)
    contrast_channel: dict[int, str] = field(default_factory=dict)
    feature_groups: tuple[str, ...] = GROUPS
    classifier: ClassifierConfig = field(default_factory=ClassifierConfig)
    sun_aware: bool = False
    shadow_kappa: float = 0.0

    def metrics_used(self, label: int) -> set[str]:
        """Names of the metric maps the rule of ``label`` thresholds."""
        names = set()
        for t in self.rules.rule(label).terms:
            names |= {"hessian_max", "hessian_min"} if t.metric.startswith("hessian") else {
                t.metric}
        return names

    def to_dict(self) -> dict:
        """JSON-serialisable description (GN and model provenance)."""
        return {
            "name": self.name,
            "rules": [{"class": {ROCK: "rock", OUTCROP: "outcrop"}[r.label],
                       "min_area_m2": r.min_area_m2, "max_extent_m": r.max_extent_m,
                       "combine": r.combine,
                       "terms": [[t.metric, t.direction, t.k_sigma] for t in r.terms]}
                      for r in self.rules.rules],
            "hessian_sigmas_m": {str(k): list(v) for k, v in self.hessian_sigmas_m.items()},
            "entropy_window_m": ENTROPY_WINDOW_M,
            "contrast_sigma_m": {str(k): v for k, v in self.contrast_sigma_m.items()},
            "contrast_channel": {str(k): v for k, v in self.contrast_channel.items()},
            "feature_groups": list(self.feature_groups),
            "classifier": {"kind": self.classifier.kind,
                           "n_components": self.classifier.n_components,
                           "k": self.classifier.k, "weights": self.classifier.weights},
            "min_probability": MIN_PROBABILITY,
            "sun_aware": self.sun_aware,
            "shadow_kappa": self.shadow_kappa,
        }


#: The paper's orbital recipe: its thresholds (Sec. 4.2), one Hessian scale per class set
#: from the class' smallest area, a 5-pixel (at 0.25 m) entropy neighbourhood, the paper's
#: five feature groups, PCA + plain kNN.
PAPER: Final = Recipe(
    name="paper",
    rules=ORBITAL_PAPER,
    hessian_sigmas_m={ROCK: (blob_sigma_m(0.6),), OUTCROP: (blob_sigma_m(8.0),)},
    feature_groups=PAPER_GROUPS,
    classifier=ClassifierConfig(n_components=8, k=5, weights="uniform"),
)

#: The default recipe without the sun direction, for rasters whose sun direction is
#: unknown (an orthoimage's metadata often lacks it): rocks are dark blobs with their
#: shadows (local contrast well below the background); outcrops are pale, unsaturated
#: surfaces (paleness above its local background). Candidates are generous (true ROIs are
#: ~1 % of them in the bags); gradient-boosted trees with class weights and shape features
#: remove the clutter. On the evaluation bags it holds rocks >= 1 m^2 at 88-92 % recall
#: (the paper's recipe 50-59 %, the default 91-94 %), with rock centres about 0.35 m off
#: (the default about 0.2 m).
NO_SUN: Final = Recipe(
    name="no_sun",
    rules=RuleSet("orbital_no_sun", (
        ClassRule(ROCK, 0.6, (ThresholdTerm("contrast", "below", 2.0),), "and",
                  max_extent_m=6.0),
        ClassRule(OUTCROP, 8.0, (ThresholdTerm("contrast", "above", 1.5),), "and",
                  max_extent_m=16.0),
    )),
    hessian_sigmas_m={},
    contrast_sigma_m={ROCK: 2.0, OUTCROP: 3.0},
    contrast_channel={ROCK: "gray", OUTCROP: "paleness"},
    feature_groups=GROUPS,
    classifier=ClassifierConfig(kind="gradient_boosting"),
)

#: The default: :data:`NO_SUN` with the sun direction. Each rock's dark region (shaded
#: face + cast shadow) lies down-sun of the rock, by about half a shadow length; its
#: centre is moved back towards
#: the sun (``shadow_kappa`` = 0.81: least squares of the needed shift on the rocks of
#: train_quick_s101 and s102 against s / tan(elevation), s the region's spread across
#: the sun axis), and the classifier also sees the ring's sun side against its shadow
#: side (feature group ``sun``).
SUN_AWARE: Final = replace(NO_SUN, name="sun_aware", feature_groups=SUN_GROUPS,
                           sun_aware=True, shadow_kappa=0.81)

RECIPES: Final = {"sun_aware": SUN_AWARE, "no_sun": NO_SUN, "paper": PAPER}
