"""Candidate rocks and outcrops in one rover stereo pair (paper Sec. 4.2, rover thresholds).

Appearance masks come from the left image, geometry from the stereo pair: every candidate
region is measured in 3D (base_link) against a local ground fit around it, and kept only
above the rover's geometric thresholds:

- rock: area on the ground > 0.6 m^2 and higher than 0.25 m above the ground; the
  pixels standing > ``SEED_HEIGHT_M`` above the local ground, grown down to
  ``GROW_HEIGHT_M`` (on this imagery a better rock mask than the paper's fusion of the
  Hessian eigenvalue masks).
- outcrop: area > 5.5 m^2; texture mask the OR of the < -2 sigma Hessian mask and the
  < -2 sigma weighted-entropy mask.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import ndimage

from roi_detector.candidates import ROVER_PAPER, candidate_mask, metric_stats
from roi_detector.metrics import hessian_eigenvalues, weighted_entropy
from roi_detector.stereo import StereoCamera, fit_plane, local_ground_height, range_sigma_m
from roi_network.records import OUTCROP, ROCK

#: Image scale, Hessian scale (pixels at that scale) and entropy window of the metrics.
METRIC_SCALE = 0.5
HESSIAN_SIGMA_PX = 2.0
ENTROPY_SIZE_PX = 7


#: Larger "rocks" are terrain swells or several rocks and clutter merged (not in the
#: paper; the world's largest rock footprint is 6 m^2), m^2.
ROCK_MAX_AREA_M2 = 8.0
#: Skip regions cut by the left, right or bottom image border (partly seen: their area
#: and centre are wrong; they are measured whole in another pair).
SKIP_BORDER_REGIONS = True
#: Rock seeds: pixels this high above the local ground, m.
SEED_HEIGHT_M = 0.25
#: Rock regions grow over pixels this high, m.
GROW_HEIGHT_M = 0.08
#: A region with fewer valid stereo points has no usable depth.
MIN_POINTS = 15
#: A region whose top stands higher than this is no outcrop (outcrops are slabs at most
#: 0.3 m thick; rocks stand higher), m.
MAX_OUTCROP_HEIGHT_M = 0.6
#: Neighbouring pixels whose depths differ by more than this fraction of the depth
#: belong to different objects.
DEPTH_JUMP_FRAC = 0.04


@dataclass(frozen=True)
class RoverThresholds:
    """Rover candidate thresholds (paper Sec. 4.2).

    Attributes:
        rock_min_area_m2: rock footprint area on the ground, m^2 (paper: 0.6).
        rock_min_height_m: rock height above the local ground, m (paper: 0.25).
        max_depth_m: candidates whose median depth is farther are not measured well
            enough (range sigma ~0.5 m at 16 m), m.
        outcrop_min_area_m2: outcrop area on the ground, m^2 (paper: 5.5).
    """

    rock_min_area_m2: float = 0.6
    rock_min_height_m: float = 0.25
    max_depth_m: float = 16.0
    outcrop_min_area_m2: float = 5.5


@dataclass
class Candidate:
    """One candidate ROI of one stereo pair, measured in base_link.

    Attributes:
        label: proposed class (ROCK or OUTCROP): the mask family it came from.
        mask: bool pixels of the region inside ``bbox`` (bbox-sized).
        bbox: (x0, y0, x1, y1) pixel box of the region in the left image (exclusive ends).
        center: (3,) base_link centre, metres (top-down footprint centre, on the ground).
        area_m2: footprint area on the ground plane, m^2.
        height_m: top of the region above its local ground plane, m.
        major_m, minor_m: full axes of the footprint's second-moment ellipse, m.
        angle_rad: major axis from base_link +x, counter-clockwise, rad.
        depth_m: median optical depth of its points, m.
        range_sigma_m: 1-sigma stereo range error at that depth, m.
        bearing: (2,) unit base_link x-y direction from the camera to the centre.
        score: classifier score in [0, 1] (set by classification), else 0.
    """

    label: int
    mask: np.ndarray
    bbox: tuple[int, int, int, int]
    center: np.ndarray
    area_m2: float
    height_m: float
    major_m: float
    minor_m: float
    angle_rad: float
    depth_m: float
    range_sigma_m: float
    bearing: np.ndarray
    score: float = 0.0
    features: np.ndarray | None = field(default=None, repr=False)


def metric_images(gray_full: np.ndarray, scale: float = METRIC_SCALE) -> dict[str, np.ndarray]:
    """Hessian eigenvalue and weighted-entropy maps (shared library) of the left image.

    Computed at ``scale`` (half resolution by default: a rover candidate covers hundreds
    of pixels, and the weighted entropy costs one box filter per grey level). The
    downscaled gray image rides along as ``_gray`` for the features.
    """
    g = cv2.resize(gray_full, None, fx=scale, fy=scale, interpolation=cv2.INTER_AREA)
    hmax, hmin = hessian_eigenvalues(g, HESSIAN_SIGMA_PX)
    return {"hessian_max": hmax, "hessian_min": hmin,
            "entropy": weighted_entropy(g, ENTROPY_SIZE_PX), "_gray": g}


def paper_mask(label: int, metrics: dict[str, np.ndarray], shape: tuple[int, int]) -> np.ndarray:
    """The paper's rover texture mask of one class (shared ROVER_PAPER rule), full size."""
    maps = {k: v for k, v in metrics.items() if not k.startswith("_")}
    m = candidate_mask(ROVER_PAPER.rule(label), maps, metric_stats(maps)).astype(np.uint8)
    m = cv2.resize(m, (shape[1], shape[0]), interpolation=cv2.INTER_NEAREST)
    m = cv2.morphologyEx(m, cv2.MORPH_CLOSE, np.ones((7, 7), np.uint8))
    return ndimage.binary_fill_holes(m > 0)


def footprint_ellipse(xy: np.ndarray) -> tuple[float, float, float]:
    """Full axes (major, minor, metres) and angle (rad from +x) of the points' ellipse.

    A uniform ellipse of full axes (A, B) has second moments A^2/16 and B^2/16.
    """
    if len(xy) < 3:
        return 0.0, 0.0, 0.0
    w, v = np.linalg.eigh(np.cov(xy.T))
    w = np.clip(w, 0.0, None)
    return 4 * float(np.sqrt(w[1])), 4 * float(np.sqrt(w[0])), float(np.arctan2(v[1, 1], v[0, 1]))


def measure_region(mask: np.ndarray, bbox: tuple[int, int, int, int], label: int,
                   points: np.ndarray, height: np.ndarray,
                   camera: StereoCamera) -> Candidate | None:
    """Measure one region in 3D; None when it has too few valid stereo points.

    The ground plane is fitted to the ring of pixels around the region (the local
    ground), its height is the 95th percentile of its points above that plane, and its
    footprint is the convex hull of its points projected on the ground.

    Args:
        mask: the region's pixels inside ``bbox`` (bool, bbox-sized).
        bbox: (x0, y0, x1, y1) in the full image, x1/y1 exclusive.
        points, height: full-image stereo points (base_link) and heights above ground.
    """
    x0, y0, x1, y1 = bbox
    hh, ww = height.shape
    m = 6  # ring width, pixels
    X0, Y0, X1, Y1 = max(x0 - m, 0), max(y0 - m, 0), min(x1 + m, ww), min(y1 + m, hh)
    pts_w, h_w = points[Y0:Y1, X0:X1], height[Y0:Y1, X0:X1]
    big = np.zeros(h_w.shape, bool)
    big[y0 - Y0:y1 - Y0, x0 - X0:x1 - X0] = mask
    finite = np.isfinite(pts_w[..., 2])
    ok = big & finite
    if ok.sum() < MIN_POINTS:
        return None
    pts = pts_w[ok]
    ring = cv2.dilate(big.astype(np.uint8), np.ones((2 * m - 1, 2 * m - 1), np.uint8)) > 0
    ring &= ~big & finite & (np.abs(h_w) < 0.15)
    plane = fit_plane(pts_w[ring]) if ring.sum() >= 20 else None
    if plane is None:
        above = h_w[ok].astype(float)
        ground_z = pts[:, 2] - above
    else:
        ground_z = plane[0] * pts[:, 0] + plane[1] * pts[:, 1] + plane[2]
        above = pts[:, 2] - ground_z
    top = float(np.percentile(above, 95))
    xy = pts[:, :2].astype(np.float32)
    hull = cv2.convexHull(xy)
    area = float(cv2.contourArea(hull))
    if label == ROCK:
        # The top of a rock sits over its footprint centre; its visible flank is biased
        # towards the rover, so the centre is taken from the upper part of its points.
        upper = above >= 0.5 * top
        cxy = pts[upper, :2].mean(axis=0) if upper.sum() >= 5 else pts[:, :2].mean(axis=0)
    else:
        mo = cv2.moments(hull)
        cxy = (np.array([mo["m10"], mo["m01"]]) / mo["m00"]) if mo["m00"] > 0 else xy.mean(0)
    cz = float(np.median(ground_z))
    major, minor, angle = footprint_ellipse(pts[:, :2])
    depth = float(np.median((pts - camera.t_base_cam) @ camera.r_base_cam[:, 2]))
    d = np.asarray(cxy, float) - camera.t_base_cam[:2]
    bearing = d / max(float(np.hypot(*d)), 1e-9)
    return Candidate(label, mask, bbox, np.array([cxy[0], cxy[1], cz]), area, top, major,
                     minor, angle, depth, float(range_sigma_m(depth, camera)), bearing)


def _regions(mask: np.ndarray, min_px: int) -> list[tuple[np.ndarray, tuple]]:
    """Connected regions of ``mask``: (bbox-sized mask, (x0, y0, x1, y1)) each."""
    lab, n = ndimage.label(mask)
    if n == 0:
        return []
    sizes = np.bincount(lab.ravel())
    objects = ndimage.find_objects(lab)
    out = []
    for i in np.flatnonzero(sizes[1:] >= min_px) + 1:
        sl = objects[i - 1]
        out.append((lab[sl] == i, (sl[1].start, sl[0].start, sl[1].stop, sl[0].stop)))
    return out


def rock_mask(height: np.ndarray, depth: np.ndarray | None = None) -> np.ndarray:
    """Pixels that may belong to a rock: those standing above the local ground (see the
    module), cut where the depth jumps."""
    from skimage.filters import apply_hysteresis_threshold

    h = np.nan_to_num(height, nan=0.0)
    m = apply_hysteresis_threshold(h, GROW_HEIGHT_M, SEED_HEIGHT_M)
    if depth is not None:
        # Two rocks one behind the other touch in the image: cut the mask where the
        # depth jumps, so each is measured on its own.
        z = np.nan_to_num(depth, nan=0.0)
        jump = np.maximum(np.abs(np.diff(z, axis=0, prepend=z[:1])),
                          np.abs(np.diff(z, axis=1, prepend=z[:, :1])))
        m &= ~(jump > DEPTH_JUMP_FRAC * np.maximum(z, 1.0))
    return cv2.morphologyEx(m.astype(np.uint8), cv2.MORPH_OPEN,
                            np.ones((3, 3), np.uint8)).astype(bool)


def rover_candidates(gray: np.ndarray, points: np.ndarray, camera: StereoCamera,
                     cfg: RoverThresholds, metrics: dict[str, np.ndarray] | None,
                     on_no_depth=None) -> list[Candidate]:
    """Rock and outcrop candidates of one stereo pair, above the rover thresholds.

    Args:
        gray: left image, uint8 (H, W).
        points: (H, W, 3) base_link stereo points, NaN where invalid.
        camera: the stereo model.
        cfg: thresholds and recipes.
        metrics: :func:`metric_images` of the left image; None skips the outcrop
            family.
        on_no_depth: called once per region that has no valid depth (bad-input count).
    """
    height = local_ground_height(points)
    depth = (points - camera.t_base_cam) @ camera.r_base_cam[:, 2]
    out: list[Candidate] = []
    families = [(ROCK, rock_mask(height, depth))]
    if metrics is not None:
        families.append((OUTCROP, paper_mask(OUTCROP, metrics, gray.shape)))
    # Appearance masks also fire on the sky and the far field (smooth, low entropy):
    # only pixels with a stereo point within range can be part of a candidate.
    valid = np.isfinite(points[..., 2])
    h, w = valid.shape
    for label, mask in families:
        for region, bbox in _regions(mask & valid, min_px=10):
            # Cut by the image border: partly seen, so its area and centre are wrong; it
            # is measured whole in another pair.
            if SKIP_BORDER_REGIONS and (bbox[0] == 0 or bbox[2] == w or bbox[3] == h):
                continue
            c = measure_region(region, bbox, label, points, height, camera)
            if c is None:
                if on_no_depth is not None:
                    on_no_depth()
                continue
            if c.depth_m > cfg.max_depth_m:
                continue
            if label == ROCK and not (cfg.rock_min_area_m2 < c.area_m2 < ROCK_MAX_AREA_M2
                                      and c.height_m > cfg.rock_min_height_m):
                continue
            if label == OUTCROP and (c.area_m2 < cfg.outcrop_min_area_m2
                                     or c.height_m > MAX_OUTCROP_HEIGHT_M):
                continue
            out.append(c)
    return out
