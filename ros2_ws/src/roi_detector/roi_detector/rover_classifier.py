"""The "Rock Rover" and "Outcrop Rover" binary classifiers (paper Sec. 4.3), rover side.

Appearance metrics, texture masks, features and the PCA + kNN classifiers are the shared
library's (:mod:`roi_detector.metrics`, :mod:`~roi_detector.candidates`,
:mod:`~roi_detector.features`, :mod:`~roi_detector.classifier`); this module adapts a
rover candidate (a region of the left image measured in 3D) to them, and adds the
stereo geometry to the feature vector in the default recipe (``feature_set="stereo"``):
log footprint area, height above the ground, log depth, footprint elongation. The paper's
recipe (``feature_set="paper"``) uses the paper's feature groups only.

Features are computed at the metrics' scale (half resolution, see
:func:`~roi_detector.rover_candidates.metric_images`).
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from roi_detector.candidates import Region
from roi_detector.classifier import (
    BinaryClassifier,
    ClassifierConfig,
    load_classifiers,
    save_classifiers,
)
from roi_detector.features import GROUPS, PAPER_GROUPS, feature_names, region_features
from roi_detector.rover_candidates import METRIC_SCALE, Candidate
from roi_network.records import OUTCROP, ROCK

GEOMETRY_NAMES = ("geo_log_area_m2", "geo_height_m", "geo_log_depth_m", "geo_elongation")
#: The per_pair method's classifiers.
CLASSIFIER_NAMES = {ROCK: "rock_rover", OUTCROP: "outcrop_rover"}
#: The elevation_map method's: Rock Rover on the far rocks' candidates
#: (:func:`roi_detector.far_rocks.far_rock_features`).
FAR_ROCK_CLASSIFIER = "far_rock_rover"
#: The name of the map rocks' Rock Rover in a rover model (elevation_map method): it
#: decides which rock regions of the elevation map are rocks, on their
#: :data:`~roi_detector.elevation_map.MAP_ROCK_FEATURES`.
MAP_ROCK_CLASSIFIER = "map_rock_rover"
#: The name of the map outcrops' Outcrop Rover in a rover model (elevation_map method): it
#: decides which outcrop regions of the elevation map are outcrops, on their
#: :data:`~roi_detector.elevation_map.MAP_OUTCROP_FEATURES`.
MAP_OUTCROP_CLASSIFIER = "map_outcrop_rover"


def _region(c: Candidate) -> Region:
    """The shared library's Region of a candidate (same grid as the metric images)."""
    x0, y0, x1, y1 = c.bbox
    rows, cols = np.nonzero(c.mask)
    pos = np.column_stack([cols + x0, rows + y0]).astype(float)
    cov = np.cov(pos.T) + np.eye(2) / 12 if len(pos) > 1 else np.eye(2) / 12
    return Region(float(pos[:, 1].mean()), float(pos[:, 0].mean()), c.area_m2, len(pos),
                  cov, (y0, x0, y1, x1), 0.0, c.label, c.mask)


def candidate_feature_vector(c: Candidate, rgb01: np.ndarray, gray_small: np.ndarray,
                             entropy: np.ndarray, feature_set: str) -> np.ndarray:
    """One candidate's features (``feature_set``: "stereo" or "paper")."""
    reg = _region(c)
    if feature_set == "paper":
        return region_features(reg, rgb01, gray_small, entropy, PAPER_GROUPS)
    f = region_features(reg, rgb01, gray_small, entropy, GROUPS)
    geo = [np.log(max(c.area_m2, 1e-3)), c.height_m, np.log(max(c.depth_m, 0.1)),
           c.major_m / max(c.minor_m, 1e-3)]
    return np.concatenate([f, np.asarray(geo, np.float32)])


def names_for(feature_set: str) -> tuple[str, ...]:
    """Feature names of a feature set."""
    if feature_set == "paper":
        return feature_names(PAPER_GROUPS)
    if feature_set == "stereo":
        return feature_names(GROUPS) + GEOMETRY_NAMES
    raise ValueError(f"feature_set: unknown '{feature_set}' (expected 'stereo' or 'paper')")


def features_of(left_bgr: np.ndarray, cands: list[Candidate], metrics: dict[str, np.ndarray],
                feature_set: str) -> np.ndarray:
    """(N, F) features of a pair's candidates."""
    if not cands:
        return np.zeros((0, len(names_for(feature_set))), np.float32)
    small = cv2.resize(left_bgr, None, fx=METRIC_SCALE, fy=METRIC_SCALE,
                       interpolation=cv2.INTER_AREA)
    rgb01 = cv2.cvtColor(small, cv2.COLOR_BGR2RGB).astype(np.float32) / 255.0
    return np.stack([candidate_feature_vector(c, rgb01, metrics["_gray"], metrics["entropy"],
                                              feature_set) for c in cands])


class RoverClassifier:
    """The rover model: Rock Rover and Outcrop Rover on a pair's candidates (per_pair
    method), and/or Rock Rover on the far rocks' candidates (elevation_map method).

    per_pair: a candidate is kept when one classifier's vote share is above
    ``threshold``; its class is the more confident classifier's, its score that vote
    share.
    """

    def __init__(self, classifiers: dict[str, BinaryClassifier], feature_set: str,
                 threshold: float = 0.5, meta: dict | None = None) -> None:
        self.classifiers = classifiers
        self.feature_set = feature_set
        self.threshold = threshold
        self.meta = meta or {}

    @property
    def per_pair(self) -> bool:
        """The model holds the per_pair method's classifiers."""
        return all(n in self.classifiers for n in CLASSIFIER_NAMES.values())

    @property
    def far_rocks(self) -> bool:
        """The model holds the far rocks' Rock Rover."""
        return FAR_ROCK_CLASSIFIER in self.classifiers

    @property
    def map_rocks(self) -> bool:
        """The model holds the map rocks' Rock Rover."""
        return MAP_ROCK_CLASSIFIER in self.classifiers

    @property
    def map_outcrops(self) -> bool:
        """The model holds the map outcrops' Outcrop Rover."""
        return MAP_OUTCROP_CLASSIFIER in self.classifiers

    def map_outcrop_proba(self, x: np.ndarray) -> np.ndarray:
        """(N,) probability that map outcrop regions of features ``x`` are outcrops."""
        return self.classifiers[MAP_OUTCROP_CLASSIFIER].predict_proba(x)

    def map_rock_proba(self, x: np.ndarray) -> np.ndarray:
        """(N,) probability that map rock regions of features ``x`` are rocks."""
        return self.classifiers[MAP_ROCK_CLASSIFIER].predict_proba(x)

    def far_rock_proba(self, x: np.ndarray) -> np.ndarray:
        """(N,) Rock Rover vote share of far-rock candidates' features."""
        return self.classifiers[FAR_ROCK_CLASSIFIER].predict_proba(x)

    def classify(self, left_bgr: np.ndarray, cands: list[Candidate],
                 metrics: dict[str, np.ndarray]) -> list[Candidate]:
        """The candidates the classifiers accept, with class and score set."""
        x = features_of(left_bgr, cands, metrics, self.feature_set)
        p_rock = self.classifiers[CLASSIFIER_NAMES[ROCK]].predict_proba(x)
        p_out = self.classifiers[CLASSIFIER_NAMES[OUTCROP]].predict_proba(x)
        kept = []
        for c, pr, po, f in zip(cands, p_rock, p_out, x, strict=True):
            best, p = (ROCK, pr) if pr >= po else (OUTCROP, po)
            if p > self.threshold:
                c.label, c.score, c.features = best, float(p), f
                kept.append(c)
        return kept

    @classmethod
    def load(cls, path: str | Path) -> RoverClassifier:
        """Read a model written by :func:`save_rover_model`.

        Raises:
            ModelFileError (ValueError): naming the file and what is wrong.
        """
        from roi_detector.classifier import ModelFileError

        classifiers, meta = load_classifiers(path)
        per_pair = [n for n in CLASSIFIER_NAMES.values() if n in classifiers]
        elevation_map = (FAR_ROCK_CLASSIFIER, MAP_ROCK_CLASSIFIER, MAP_OUTCROP_CLASSIFIER)
        if not any(n in classifiers for n in elevation_map) \
                and len(per_pair) < len(CLASSIFIER_NAMES):
            raise ModelFileError(
                f"{path}: not a rover model (holds {sorted(classifiers)}; expected "
                f"{', '.join(repr(n) for n in elevation_map)} and/or "
                f"{sorted(CLASSIFIER_NAMES.values())})")
        if 0 < len(per_pair) < len(CLASSIFIER_NAMES):
            raise ModelFileError(f"{path}: per_pair classifiers incomplete (holds {per_pair})")
        prov = meta.get("provenance", {})
        return cls(classifiers, prov.get("feature_set", "stereo"),
                   float(prov.get("threshold", 0.5)), {**meta, "path": str(path)})


def train_classifiers(x: np.ndarray, truth_labels: np.ndarray, feature_set: str,
                      k: int = 5) -> dict[str, BinaryClassifier]:
    """Fit Rock Rover and Outcrop Rover on features ``x`` and truth labels (0: neither)."""
    names = names_for(feature_set)
    out = {}
    for label, name in CLASSIFIER_NAMES.items():
        clf = BinaryClassifier(name, names, ClassifierConfig(n_components=8, k=k))
        out[name] = clf.fit(x, (truth_labels == label).astype(np.uint8))
    return out


def save_rover_model(path: str | Path, classifiers: dict[str, BinaryClassifier],
                     provenance: dict) -> None:
    """Write the rover model (shared library format) atomically."""
    save_classifiers(path, classifiers, provenance)
