"""Detection in one raster window: metric maps, candidates, features, classification.

Pure functions on one :class:`~orbital_gn.raster.OrthoWindow`; :mod:`orbital_gn.tiling` runs
them over overlapping windows. A window is its *core* (the pixels it answers for) plus a
halo of :func:`halo_px` pixels, wide enough that every metric, region and feature of a
candidate whose centroid lies in the core is exactly what the whole raster would give.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np

from orbital_gn.raster import OrthoInfo, OrthoWindow, Sun
from orbital_gn.recipe import ENTROPY_WINDOW_M, MIN_PROBABILITY, Recipe
from roi_detector.candidates import (
    MetricMoments,
    MetricStats,
    Region,
    candidate_mask,
    candidate_regions,
    ellipse_from_cov,
    metric_moments,
    shadow_shift_px,
    sun_direction_px,
    threshold_excess,
)
from roi_detector.classifier import BinaryClassifier
from roi_detector.features import candidate_features, entropy_pixels, feature_halo_px
from roi_detector.metrics import (
    entropy_halo_px,
    hessian_eigenvalues,
    hessian_halo_px,
    local_contrast,
    weighted_entropy,
    weighted_entropy_at,
)
from roi_network import LABEL_NAMES, ROCK, ROI_DTYPE

#: scipy's Gaussian truncation used for the local-contrast background (sigmas).
_CONTRAST_TRUNCATE = 4.0


def entropy_size_px(gsd_m: float) -> int:
    """The odd side in pixels (3..15) of the :data:`~orbital_gn.recipe.ENTROPY_WINDOW_M`
    neighbourhood."""
    n = round(ENTROPY_WINDOW_M / gsd_m)
    n = n if n % 2 == 1 else n + 1
    return int(min(max(n, 3), 15))


def metrics_halo_px(recipe: Recipe, gsd_m: float) -> int:
    """Context the metric maps need for exact values at a pixel."""
    halo = entropy_halo_px(entropy_size_px(gsd_m))
    for sigmas in recipe.hessian_sigmas_m.values():
        halo = max(halo, *(hessian_halo_px(s / gsd_m) for s in sigmas))
    for s in recipe.contrast_sigma_m.values():
        halo = max(halo, math.ceil(_CONTRAST_TRUNCATE * s / gsd_m) + 1)
    return halo


def halo_px(recipe: Recipe, gsd_m: float) -> int:
    """Window halo (pixels) that makes tiled detection equal to whole-raster detection:
    the largest ROI extent, plus the features' context, plus the metrics' context."""
    max_extent = max(r.max_extent_m for r in recipe.rules.rules)
    return (math.ceil(max_extent / gsd_m) + 1 + feature_halo_px()
            + metrics_halo_px(recipe, gsd_m))


def paleness(rgb01: np.ndarray) -> np.ndarray:
    """HSV value minus saturation, x 255: high on pale, unsaturated surfaces (outcrops on
    reddish soil); equal to the gray level on a 1-band image. (H, W) float32."""
    hsv = cv2.cvtColor(np.ascontiguousarray(rgb01, dtype=np.float32), cv2.COLOR_RGB2HSV)
    return (hsv[..., 2] - hsv[..., 1]) * np.float32(255.0)


def class_metrics(gray: np.ndarray, recipe: Recipe, label: int, gsd_m: float,
                  rgb01: np.ndarray | None = None) -> dict[str, np.ndarray]:
    """Metric maps the rule of class ``label`` thresholds, for a (H, W) uint8 gray window
    (and its (H, W, 3) RGB in [0, 1] when the recipe's contrast channel is ``paleness``).

    With several Hessian scales, ``hessian_min`` is the strongest dark-blob response over
    them (max of the smaller eigenvalue) and ``hessian_max`` the strongest bright-blob one.
    """
    used = recipe.metrics_used(label)
    out: dict[str, np.ndarray] = {}
    if "hessian_max" in used:
        lmax, lmin = None, None
        for s in recipe.hessian_sigmas_m[label]:
            a, b = hessian_eigenvalues(gray, s / gsd_m)
            lmax = a if lmax is None else np.minimum(lmax, a)
            lmin = b if lmin is None else np.maximum(lmin, b)
        out["hessian_max"], out["hessian_min"] = lmax, lmin
    if "entropy" in used:
        out["entropy"] = weighted_entropy(gray, entropy_size_px(gsd_m))
    if "contrast" in used:
        channel = recipe.contrast_channel.get(label, "gray")
        image = paleness(rgb01) if channel == "paleness" else gray
        out["contrast"] = local_contrast(image, recipe.contrast_sigma_m[label] / gsd_m)
    return out


def window_moments(win: OrthoWindow, core: tuple[int, int, int, int], recipe: Recipe,
                   gsd_m: float) -> dict[int, dict[str, MetricMoments]]:
    """Per class, the moments of its metrics over the valid pixels of the window's core.

    Args:
        core: (row0, col0, row1, col1) of the core in window coordinates.
    """
    r0, c0, r1, c1 = core
    out = {}
    for rule in recipe.rules.rules:
        m = class_metrics(win.gray, recipe, rule.label, gsd_m, win.rgb01)
        m = {k: v[r0:r1, c0:c1] for k, v in m.items()}
        out[rule.label] = metric_moments(m, win.valid[r0:r1, c0:c1])
    return out


def _sparse_entropy(gray: np.ndarray, regions: list[Region], size: int) -> np.ndarray:
    """Weighted entropy only where the features read it (around the candidates)."""
    out = np.zeros(gray.shape, np.float32)
    if not regions:
        return out
    pix = [entropy_pixels(r, gray.shape) for r in regions]
    rows = np.concatenate([p[0] for p in pix])
    cols = np.concatenate([p[1] for p in pix])
    flat = np.unique(rows * gray.shape[1] + cols)
    rows, cols = np.divmod(flat, gray.shape[1])
    out[rows, cols] = weighted_entropy_at(gray, rows, cols, size)
    return out


@dataclass
class Candidates:
    """Candidates of one class found in a window's core.

    Attributes:
        label: ROI class.
        records: ROI records (``map`` frame, id 0, score = candidate excess in sigmas).
        features: (N, F) float32 classifier features.
        row, col: (N,) centroids in raster pixel coordinates.
    """

    label: int
    records: np.ndarray
    features: np.ndarray
    row: np.ndarray
    col: np.ndarray


def _owned(reg: Region, core_abs: tuple[int, int, int, int], row0: int, col0: int) -> bool:
    # The pixel holding the centroid, from integer sums: the same in every tiling.
    rr, cc = np.nonzero(reg.footprint)
    n = rr.size
    sr = int(rr.sum()) + n * (reg.bbox[0] + row0)
    sc = int(cc.sum()) + n * (reg.bbox[1] + col0)
    pr, pc = (2 * sr + n) // (2 * n), (2 * sc + n) // (2 * n)
    return core_abs[0] <= pr < core_abs[2] and core_abs[1] <= pc < core_abs[3]


def window_candidates(win: OrthoWindow, core: tuple[int, int, int, int], info: OrthoInfo,
                      stats: dict[int, dict[str, MetricStats]], recipe: Recipe,
                      origin: tuple[float, float], sun: Sun | None = None) -> list[Candidates]:
    """Candidates (paper Sec. 4.2) whose centroid lies in the window's core, with features.

    Args:
        win: the window (core + halo).
        core: (row0, col0, row1, col1) of the core in window coordinates.
        info: the raster (transform, GSD).
        stats: per class, metric statistics over the whole raster.
        recipe: the detection recipe.
        origin: map-frame origin (easting, northing), metres.
        sun: sun direction; required by a ``sun_aware`` recipe (rock centres moved back
            towards the sun, ``sun`` features), ignored otherwise.

    Raises:
        ValueError: a ``sun_aware`` recipe without ``sun``.
    """
    if recipe.sun_aware and sun is None:
        raise ValueError(f"recipe {recipe.name!r} needs the sun direction")
    gsd = info.gsd_m
    core_abs = (core[0] + win.row0, core[1] + win.col0, core[2] + win.row0, core[3] + win.col0)
    t = info.transform
    jac = np.array([[t.a, t.b], [t.d, t.e]])
    sun_dir = sun_direction_px(sun.azimuth_deg, jac) if recipe.sun_aware else None
    out = []
    all_regions: list[tuple[int, list[Region]]] = []
    for rule in recipe.rules.rules:
        # 2. Metric maps.
        m = class_metrics(win.gray, recipe, rule.label, gsd, win.rgb01)
        # 4. Candidates.
        mask = candidate_mask(rule, m, stats[rule.label], win.valid)
        excess = threshold_excess(rule, m, stats[rule.label])
        regions = candidate_regions(mask, rule, info.pixel_area_m2, excess, gsd)
        regions = [r for r in regions if _owned(r, core_abs, win.row0, win.col0)]
        all_regions.append((rule.label, regions))
    entropy = _sparse_entropy(win.gray, [r for _, rs in all_regions for r in rs],
                              entropy_size_px(gsd))
    for label, regions in all_regions:
        # 5. Features.
        feats = candidate_features(regions, win.rgb01, win.gray, entropy, recipe.feature_groups,
                                   sun_dir)
        rec = np.zeros(len(regions), ROI_DTYPE)
        rows = np.array([r.row + win.row0 for r in regions], np.float64)
        cols = np.array([r.col + win.col0 for r in regions], np.float64)
        if label == ROCK and sun_dir is not None and recipe.shadow_kappa:
            # 6. Sun shift.
            # The dark region is the rock's shaded face plus its cast shadow: its centroid
            # lies down-sun of the rock; move it back (ownership above used the region's
            # own centroid, so tiling still decides the same way).
            for i, reg in enumerate(regions):
                dc, dr = shadow_shift_px(reg.cov_px, sun_dir, sun.elevation_deg,
                                         recipe.shadow_kappa)
                rows[i] += dr
                cols[i] += dc
        for i, reg in enumerate(regions):
            # Pixel centres are at +0.5 in the affine's corner convention.
            x = t.a * (cols[i] + 0.5) + t.b * (rows[i] + 0.5) + t.c
            y = t.d * (cols[i] + 0.5) + t.e * (rows[i] + 0.5) + t.f
            major, minor, angle = ellipse_from_cov(jac @ reg.cov_px @ jac.T)
            rec[i]["x"], rec[i]["y"] = x - origin[0], y - origin[1]
            rec[i]["label"] = label
            rec[i]["area_m2"] = reg.area_m2
            rec[i]["major_m"], rec[i]["minor_m"], rec[i]["angle_rad"] = major, minor, angle
            rec[i]["score"] = reg.score
        out.append(Candidates(label, rec, feats, rows, cols))
    return out


def classify(cands: Candidates, classifiers: dict[str, BinaryClassifier],
             recipe: Recipe) -> np.ndarray:
    """Records of the candidates the class' binary classifier accepts, scored by its vote.

    Without a classifier for the class (``classifiers`` empty: candidate-only mode, for
    evaluating the detector alone; or a class the model could not train), every candidate
    is kept with score 1.
    """
    name = f"{LABEL_NAMES[cands.label]}_orbital"
    if name not in classifiers:  # candidate-only mode, or a class the model could not train
        rec = cands.records.copy()
        rec["score"] = 1.0
        return rec
    proba = classifiers[name].predict_proba(cands.features)
    keep = proba >= MIN_PROBABILITY
    rec = cands.records[keep].copy()
    rec["score"] = proba[keep]
    return rec
