"""Candidate ROI extraction of the paper's Sec. 4.2: sigma thresholds on the metric
distributions, geometric thresholds, connected regions -> region properties.

Imagery-agnostic. The caller supplies per-pixel metric maps (:mod:`roi_detector.metrics`)
under the names of :data:`METRICS`, the statistics of their distributions (over the whole
image: a tiled caller computes them once and passes them to every tile), and the ground
area of a pixel (a scalar for an orthoimage; a per-pixel map for a perspective image).

The paper's two rule sets are :data:`ORBITAL_PAPER` and :data:`ROVER_PAPER`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final, Literal

import numpy as np
from scipy import ndimage

from roi_network.records import OUTCROP, ROCK

#: Metric map names a rule may threshold.
#: ``entropy``: weighted local entropy (Eq. 2); ``hessian_max`` / ``hessian_min``: the larger
#: / smaller eigenvalue of the scale-normalised Hessian. A term on ``hessian`` tests both
#: eigenvalues against the pooled distribution of all eigenvalues: ``above`` needs the
#: smaller one above the threshold (both extreme: a dark blob), ``below`` needs the larger
#: one below it (a bright blob). ``contrast``: grey level minus the local background
#: (:func:`roi_detector.metrics.local_contrast`; not in the paper).
METRICS: Final = ("entropy", "hessian_max", "hessian_min", "hessian", "contrast")


@dataclass(frozen=True)
class ThresholdTerm:
    """One texture constraint: ``metric`` more than ``k_sigma`` standard deviations above
    (or below) the mean of its distribution.

    Attributes:
        metric: one of :data:`METRICS`.
        direction: ``"above"`` (value > mean + k sigma) or ``"below"`` (value < mean - k sigma).
        k_sigma: number of standard deviations (paper: 2).
    """

    metric: str
    direction: Literal["above", "below"]
    k_sigma: float = 2.0

    def __post_init__(self) -> None:
        if self.metric not in METRICS:
            raise ValueError(f"ThresholdTerm.metric: {self.metric!r} not in {METRICS}")
        if self.direction not in ("above", "below"):
            raise ValueError(f"ThresholdTerm.direction: {self.direction!r} not above/below")


@dataclass(frozen=True)
class ClassRule:
    """Candidate rule of one class (paper Sec. 4.2).

    Attributes:
        label: ROI class (``roi_network.ROCK`` or ``OUTCROP``).
        min_area_m2: geometric constraint, region area strictly above this, m^2.
        terms: texture constraints.
        combine: ``"and"`` (all terms) or ``"or"`` (any term).
        min_height_m: rover rule only (height above ground, checked by the caller who has
            depth); ``None`` for orbital imagery.
        max_extent_m: regions whose bounding box is wider than this are rejected (not a
            rock or outcrop; also what makes tiled processing exact: a tiler's halo must be
            at least this wide), metres.
    """

    label: int
    min_area_m2: float
    terms: tuple[ThresholdTerm, ...]
    combine: Literal["and", "or"] = "and"
    min_height_m: float | None = None
    max_extent_m: float = 16.0

    def __post_init__(self) -> None:
        if self.label not in (ROCK, OUTCROP):
            raise ValueError(f"ClassRule.label: {self.label} is not ROCK or OUTCROP")
        if self.combine not in ("and", "or"):
            raise ValueError(f"ClassRule.combine: {self.combine!r} not and/or")
        if not self.terms:
            raise ValueError("ClassRule.terms: at least one texture constraint is needed")


@dataclass(frozen=True)
class RuleSet:
    """The candidate rules of one imagery (one rule per class)."""

    name: str
    rules: tuple[ClassRule, ...] = field(default_factory=tuple)

    def rule(self, label: int) -> ClassRule:
        """The rule of class ``label``."""
        for r in self.rules:
            if r.label == label:
                return r
        raise KeyError(f"RuleSet {self.name}: no rule for label {label}")


#: Paper Sec. 4.2, orbital: rock > 0.6 m^2, > 2 sigma on entropy AND on the Hessian
#: eigenvalues; outcrop > 8 m^2, < -2 sigma on the Hessian eigenvalues.
ORBITAL_PAPER: Final = RuleSet("orbital_paper", (
    ClassRule(ROCK, 0.6, (ThresholdTerm("entropy", "above"), ThresholdTerm("hessian", "above")),
              "and", max_extent_m=8.0),
    ClassRule(OUTCROP, 8.0, (ThresholdTerm("hessian", "below"),), "and", max_extent_m=16.0),
))

#: Paper Sec. 4.2, rover: rock > 0.6 m^2 and higher than 0.25 m, fusion (OR) of > 2 sigma and
#: < -2 sigma on the Hessian eigenvalues; outcrop > 5.5 m^2, < -2 sigma on the Hessian
#: eigenvalues OR < -2 sigma on entropy.
ROVER_PAPER: Final = RuleSet("rover_paper", (
    ClassRule(ROCK, 0.6, (ThresholdTerm("hessian", "above"), ThresholdTerm("hessian", "below")),
              "or", min_height_m=0.25, max_extent_m=8.0),
    ClassRule(OUTCROP, 5.5, (ThresholdTerm("hessian", "below"), ThresholdTerm("entropy", "below")),
              "or", max_extent_m=16.0),
))


@dataclass(frozen=True)
class MetricStats:
    """Mean and standard deviation of one metric's distribution (over valid pixels)."""

    mean: float
    std: float


@dataclass(frozen=True)
class MetricMoments:
    """Sums that combine exactly over image windows: count, sum and sum of squares."""

    count: int = 0
    total: float = 0.0
    total_sq: float = 0.0

    def __add__(self, other: MetricMoments) -> MetricMoments:
        return MetricMoments(self.count + other.count, self.total + other.total,
                             self.total_sq + other.total_sq)

    def stats(self) -> MetricStats:
        """The distribution's mean and (population) standard deviation."""
        if self.count == 0:
            return MetricStats(0.0, 0.0)
        mean = self.total / self.count
        var = max(self.total_sq / self.count - mean * mean, 0.0)
        return MetricStats(mean, float(np.sqrt(var)))


def metric_moments(metrics: dict[str, np.ndarray],
                   valid: np.ndarray | None = None) -> dict[str, MetricMoments]:
    """Moments of each metric map over the ``valid`` pixels (a window's share).

    ``hessian`` pools both eigenvalue maps. Sums are float64.
    """
    out: dict[str, MetricMoments] = {}
    for name, m in _with_pooled_hessian(metrics).items():
        vals = [np.asarray(a, dtype=np.float64) for a in (m if isinstance(m, tuple) else (m,))]
        if valid is not None:
            vals = [a[valid] for a in vals]
        out[name] = MetricMoments(sum(int(a.size) for a in vals),
                                  float(sum(a.sum() for a in vals)),
                                  float(sum(np.square(a).sum() for a in vals)))
    return out


def metric_stats(metrics: dict[str, np.ndarray],
                 valid: np.ndarray | None = None) -> dict[str, MetricStats]:
    """Mean and standard deviation of each metric over the ``valid`` pixels of one image."""
    return {k: v.stats() for k, v in metric_moments(metrics, valid).items()}


def _with_pooled_hessian(metrics: dict[str, np.ndarray]) -> dict[str, np.ndarray | tuple]:
    out: dict[str, np.ndarray | tuple] = dict(metrics)
    if "hessian_max" in metrics and "hessian_min" in metrics:
        out["hessian"] = (metrics["hessian_max"], metrics["hessian_min"])
    return out


def term_mask(term: ThresholdTerm, metrics: dict[str, np.ndarray],
              stats: dict[str, MetricStats]) -> np.ndarray:
    """Pixels that pass one texture constraint (bool map)."""
    if term.metric not in stats:
        raise KeyError(f"term_mask: no statistics for metric '{term.metric}'")
    s = stats[term.metric]
    if term.metric == "hessian":
        # Both eigenvalues extreme: the smaller above, or the larger below.
        value = metrics["hessian_min"] if term.direction == "above" else metrics["hessian_max"]
    else:
        if term.metric not in metrics:
            raise KeyError(f"term_mask: metric map '{term.metric}' is missing")
        value = metrics[term.metric]
    if term.direction == "above":
        return value > s.mean + term.k_sigma * s.std
    return value < s.mean - term.k_sigma * s.std


def candidate_mask(rule: ClassRule, metrics: dict[str, np.ndarray],
                   stats: dict[str, MetricStats],
                   valid: np.ndarray | None = None) -> np.ndarray:
    """Pixels that pass a class rule's texture constraints (bool map, same shape as metrics).

    Args:
        rule: the class rule.
        metrics: metric maps by name (:data:`METRICS`; ``hessian`` needs ``hessian_max`` and
            ``hessian_min``), all of one shape (H, W).
        stats: statistics of each thresholded metric over the whole image.
        valid: optional (H, W) bool map of usable pixels (not nodata).
    """
    masks = [term_mask(t, metrics, stats) for t in rule.terms]
    mask = np.logical_and.reduce(masks) if rule.combine == "and" else np.logical_or.reduce(masks)
    if valid is not None:
        mask &= valid
    return mask


@dataclass(frozen=True)
class Region:
    """One connected candidate region, in image coordinates.

    Image coordinates: ``col`` to the right, ``row`` down, pixel centres at integers.

    Attributes:
        row, col: centroid, pixels (area-weighted when a per-pixel area map is given).
        area_m2: ground area (sum of the pixel areas), m^2.
        n_px: pixel count.
        cov_px: (2, 2) second central moments of the pixel positions, order (col, row),
            pixels^2 (a pixel's own extent, 1/12, included).
        bbox: (row0, col0, row1, col1), row1/col1 exclusive.
        score: mean excess of the deciding metric over its threshold, in standard
            deviations (>= 0), averaged over the region.
        label: class of the rule that found it.
        footprint: (row1 - row0, col1 - col0) bool, the region's own pixels in its bbox.
    """

    row: float
    col: float
    area_m2: float
    n_px: int
    cov_px: np.ndarray
    bbox: tuple[int, int, int, int]
    score: float
    label: int
    footprint: np.ndarray


def ellipse_from_cov(cov: np.ndarray) -> tuple[float, float, float]:
    """Full axis lengths and angle of the ellipse with second moments ``cov``.

    A uniform ellipse of semi-axes a >= b has variances a^2/4 and b^2/4 along its axes, so
    the full axes are 4 sqrt(eigenvalue) (skimage's ``major_axis_length`` convention).

    Args:
        cov: (2, 2) covariance of (x, y) positions, in any length unit squared.

    Returns:
        (major, minor, angle): full axis lengths in that unit, and the major axis' angle
        from +x towards +y, radians in (-pi/2, pi/2].
    """
    cov = np.asarray(cov, dtype=np.float64)
    evals, evecs = np.linalg.eigh(cov)
    major, minor = 4.0 * np.sqrt(max(evals[1], 0.0)), 4.0 * np.sqrt(max(evals[0], 0.0))
    vx, vy = evecs[:, 1]
    angle = float(np.arctan2(vy, vx))
    if angle <= -np.pi / 2:
        angle += np.pi
    elif angle > np.pi / 2:
        angle -= np.pi
    return float(major), float(minor), angle


def candidate_regions(mask: np.ndarray, rule: ClassRule, pixel_area_m2: float | np.ndarray,
                      excess: np.ndarray | None = None,
                      pixel_size_m: float | None = None) -> list[Region]:
    """Connected regions (8-connectivity) of a candidate mask that pass the geometric rule.

    Args:
        mask: (H, W) bool candidate map (:func:`candidate_mask`).
        rule: the class rule (``min_area_m2``, ``max_extent_m``, ``label``).
        pixel_area_m2: ground area of one pixel, m^2: a scalar (orthoimage) or an (H, W)
            map (perspective image; pixels with no ground area, e.g. sky, as 0).
        excess: optional (H, W) map of the deciding metric's excess over its threshold in
            standard deviations (:func:`threshold_excess`); its region mean is the score.
        pixel_size_m: side of a pixel on the ground, metres, for ``max_extent_m``; when
            ``None``, sqrt of a scalar ``pixel_area_m2`` (with a map, the extent test is
            skipped: the caller checks metric extents itself).

    Returns:
        Regions with area > ``rule.min_area_m2`` and bounding box no wider than
        ``rule.max_extent_m``, in raster order of their first pixel.
    """
    labels, n = ndimage.label(mask, structure=np.ones((3, 3), bool))
    if n == 0:
        return []
    scalar_area = np.ndim(pixel_area_m2) == 0
    if pixel_size_m is None and scalar_area:
        pixel_size_m = float(np.sqrt(pixel_area_m2))
    max_extent_px = (rule.max_extent_m / pixel_size_m) if pixel_size_m else np.inf
    regions = []
    for i, sl in enumerate(ndimage.find_objects(labels)):
        if sl is None:
            continue
        r0, r1, c0, c1 = sl[0].start, sl[0].stop, sl[1].start, sl[1].stop
        if max(r1 - r0, c1 - c0) > max_extent_px:
            continue
        own = labels[sl] == i + 1
        rr, cc = np.nonzero(own)
        if scalar_area:
            w = np.full(rr.size, float(pixel_area_m2))
        else:
            w = np.asarray(pixel_area_m2, dtype=np.float64)[sl][own]
        area = float(w.sum())
        if not area > rule.min_area_m2:
            continue
        rows, cols = rr + r0, cc + c0
        wn = w / area
        mr, mc = float(wn @ rows), float(wn @ cols)
        dc, dr = cols - mc, rows - mr
        cov = np.array([[wn @ (dc * dc), wn @ (dc * dr)], [wn @ (dc * dr), wn @ (dr * dr)]])
        cov += np.eye(2) / 12.0
        score = float(excess[sl][own].mean()) if excess is not None else 0.0
        regions.append(Region(mr, mc, area, int(rr.size), cov, (r0, c0, r1, c1), score,
                              rule.label, own))
    return regions


def sun_direction_px(azimuth_deg: float, jacobian: np.ndarray) -> tuple[float, float]:
    """Unit vector towards the sun in image coordinates (d col, d row).

    Args:
        azimuth_deg: sun azimuth, degrees clockwise from the map's north (+y).
        jacobian: (2, 2) d(x, y)/d(col, row) of the image's georeference (a north-up
            orthoimage at g m/px: [[g, 0], [0, -g]]).
    """
    az = np.radians(azimuth_deg)
    d = np.linalg.solve(np.asarray(jacobian, np.float64), [np.sin(az), np.cos(az)])
    d /= np.linalg.norm(d)
    return float(d[0]), float(d[1])


def shadow_shift_px(cov_px: np.ndarray, sun_dir_px: tuple[float, float], elevation_deg: float,
                    kappa: float) -> tuple[float, float]:
    """How far a dark rock region's centroid lies from the rock, back towards the sun.

    Seen from above, a rock lit at elevation e is a dark region made of its shaded face
    and its cast shadow, which stretches away from the sun by about h / tan(e) for a rock
    h high; rocks are about as high as they are wide, and the region's width across the
    sun axis is the rock's, so the centroid sits ``kappa * s / tan(e)`` down-sun of the
    rock, s the region's standard deviation across the sun axis. ``kappa`` is measured on
    training imagery (orbital: the recipe's ``shadow_kappa``).

    Args:
        cov_px: (2, 2) region covariance, order (col, row), pixels^2.
        sun_dir_px: unit vector (d col, d row) towards the sun.
        elevation_deg: sun elevation above the horizon, degrees (0, 90].
        kappa: dimensionless gain.

    Returns:
        (d col, d row), pixels, to add to the centroid.
    """
    if not 0.0 < elevation_deg <= 90.0:
        raise ValueError(f"sun elevation must be in (0, 90] degrees, got {elevation_deg}")
    dc, dr = sun_dir_px
    across = np.array([-dr, dc])
    s = float(np.sqrt(max(across @ np.asarray(cov_px) @ across, 0.0)))
    shift = kappa * s / np.tan(np.radians(elevation_deg))
    return shift * dc, shift * dr


def threshold_excess(rule: ClassRule, metrics: dict[str, np.ndarray],
                     stats: dict[str, MetricStats]) -> np.ndarray:
    """Per pixel, how far the rule's weakest (``and``) or strongest (``or``) term is past its
    threshold, in standard deviations (negative where it fails). float32 (H, W)."""
    parts = []
    for t in rule.terms:
        s = stats[t.metric]
        if t.metric == "hessian":
            v = metrics["hessian_min"] if t.direction == "above" else metrics["hessian_max"]
        else:
            v = metrics[t.metric]
        z = (v - s.mean) / max(s.std, 1e-12)
        parts.append((z - t.k_sigma) if t.direction == "above" else (-z - t.k_sigma))
    stack = np.stack(parts)
    out = stack.min(axis=0) if rule.combine == "and" else stack.max(axis=0)
    return out.astype(np.float32)
