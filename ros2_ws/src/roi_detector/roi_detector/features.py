"""Per-candidate features of the paper's Sec. 4.3: RGB, HSV, gray, Gabor and entropy.

Imagery-agnostic: the caller supplies the image (RGB, or a 1-band image replicated into
three channels), its uint8 gray (:func:`roi_detector.metrics.to_gray_u8`), the weighted
entropy map (:func:`roi_detector.metrics.weighted_entropy`) and the candidate regions
(:func:`roi_detector.candidates.candidate_regions`). Each candidate gives one fixed-length
float32 vector whose entries are named by :func:`feature_names`.

Statistics are taken over the region's own pixels and over a ring around it (the ground
next to the candidate), so that features describe the candidate against its surroundings
rather than the absolute brightness of the scene.
"""

from __future__ import annotations

from functools import cache
from typing import Final

import cv2
import numpy as np
from scipy import ndimage

from roi_detector.candidates import Region

#: Feature groups, in vector order. ``shape`` (log area, elongation, fill) is not in the
#: paper's list; the paper's recipe uses :data:`PAPER_GROUPS`.
GROUPS: Final = ("rgb", "hsv", "gray", "gabor", "entropy", "shape")
PAPER_GROUPS: Final = ("rgb", "hsv", "gray", "gabor", "entropy")
#: ``sun`` (ours, needs the sun direction): a rock is a dark region (its shaded face and
#: cast shadow) with its sunlit face on the sun side; soil patches are dark all round.
SUN_GROUPS: Final = (*GROUPS, "sun")
_ORDER: Final = SUN_GROUPS
#: Gabor filter bank: wavelengths (pixels) x orientations (radians).
GABOR_WAVELENGTHS_PX: Final = (4.0, 8.0)
GABOR_THETAS: Final = (0.0, np.pi / 4, np.pi / 2, 3 * np.pi / 4)
#: Width of the surrounding ring, pixels.
RING_PX: Final = 3

_GROUP_NAMES: Final[dict[str, tuple[str, ...]]] = {
    "rgb": tuple(f"{c}_{s}" for s in ("mean", "std", "contrast") for c in "rgb"),
    "hsv": ("hue_cos_s", "hue_sin_s", "sat_mean", "sat_contrast", "val_mean", "val_std",
            "val_contrast"),
    "gray": ("gray_mean", "gray_std", "gray_min", "gray_max", "gray_ring_mean",
             "gray_ring_std", "gray_contrast"),
    "gabor": tuple(f"gabor_l{int(lam)}_t{round(np.degrees(t))}"
                   for lam in GABOR_WAVELENGTHS_PX for t in GABOR_THETAS)
    + tuple(f"gabor_l{int(lam)}_ring" for lam in GABOR_WAVELENGTHS_PX),
    "entropy": ("entropy_mean", "entropy_max", "entropy_ring_mean"),
    "shape": ("log_area_m2", "elongation", "fill"),
    "sun": ("sun_ring_contrast", "sun_lit_max", "sun_shade_min", "sun_axis_ratio"),
}


def feature_names(groups: tuple[str, ...] = GROUPS) -> tuple[str, ...]:
    """Names of the feature vector's entries for ``groups`` (in :data:`SUN_GROUPS` order)."""
    for g in groups:
        if g not in _GROUP_NAMES:
            raise ValueError(f"unknown feature group {g!r} (known: {_ORDER})")
    return tuple(n for g in _ORDER if g in groups for n in _GROUP_NAMES[g])


@cache
def _gabor_kernels(wavelength_px: float) -> tuple[tuple[np.ndarray, np.ndarray], ...]:
    sigma = 0.56 * wavelength_px  # one-octave bandwidth
    half = int(np.ceil(2.5 * sigma))
    out = []
    for theta in GABOR_THETAS:
        even = cv2.getGaborKernel((2 * half + 1,) * 2, sigma, theta, wavelength_px, 1.0, 0.0)
        odd = cv2.getGaborKernel((2 * half + 1,) * 2, sigma, theta, wavelength_px, 1.0,
                                 np.pi / 2)
        even -= even.mean()  # zero DC: the response ignores brightness
        out.append((even.astype(np.float32), odd.astype(np.float32)))
    return tuple(out)


def feature_halo_px() -> int:
    """Pixels of context around a region's bbox that :func:`region_features` reads."""
    sigma = 0.56 * max(GABOR_WAVELENGTHS_PX)
    return int(np.ceil(2.5 * sigma)) + RING_PX + 2


def entropy_pixels(region: Region, shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    """(rows, cols) of the pixels whose entropy :func:`region_features` reads (the region
    and its ring), so that a caller can compute the entropy there only
    (:func:`roi_detector.metrics.weighted_entropy_at`)."""
    h, w = shape
    m = RING_PX + 2
    r0, c0, r1, c1 = region.bbox
    pr0, pc0, pr1, pc1 = max(r0 - m, 0), max(c0 - m, 0), min(r1 + m, h), min(c1 + m, w)
    inside = np.zeros((pr1 - pr0, pc1 - pc0), bool)
    inside[r0 - pr0:r1 - pr0, c0 - pc0:c1 - pc0] = region.footprint
    near = ndimage.binary_dilation(inside, np.ones((3, 3), bool), iterations=RING_PX + 1)
    rr, cc = np.nonzero(near)
    return rr + pr0, cc + pc0


def _hsv(rgb01: np.ndarray) -> np.ndarray:
    return cv2.cvtColor(rgb01.astype(np.float32), cv2.COLOR_RGB2HSV)  # H deg, S, V in [0,1]


def _sun_features(region: Region, gray: np.ndarray, ring: np.ndarray,
                  origin: tuple[int, int], sun_dir_px: tuple[float, float]) -> list[float]:
    """The ``sun`` group: the ring's sun-side half against its shadow-side half.

    ``sun_ring_contrast``: mean gray of the ring's sun-side half minus its other half (a
    rock's lit face is on the sun side, its cast shadow on the other); ``sun_lit_max`` /
    ``sun_shade_min``: brightest sun-side / darkest shadow-side ring pixel minus the ring
    mean; ``sun_axis_ratio``: the region's spread along the sun axis over its spread
    across it (a cast shadow stretches the region along the sun azimuth).
    """
    dc, dr = sun_dir_px
    rr, cc = np.nonzero(ring)
    along = (cc + origin[1] - region.col) * dc + (rr + origin[0] - region.row) * dr
    g = gray[ring]
    sunny, shady = g[along > 0], g[along <= 0]
    mean = float(g.mean())
    sun_mean = float(sunny.mean()) if sunny.size else mean
    shade_mean = float(shady.mean()) if shady.size else mean
    u = np.array([dc, dr])
    v = np.array([-dr, dc])
    var_along, var_across = float(u @ region.cov_px @ u), float(v @ region.cov_px @ v)
    return [sun_mean - shade_mean,
            (float(sunny.max()) if sunny.size else mean) - mean,
            (float(shady.min()) if shady.size else mean) - mean,
            float(np.sqrt(var_along / max(var_across, 1e-9)))]


def region_features(region: Region, rgb01: np.ndarray, gray_u8: np.ndarray,
                    entropy: np.ndarray, groups: tuple[str, ...] = GROUPS,
                    sun_dir_px: tuple[float, float] | None = None) -> np.ndarray:
    """The feature vector of one candidate.

    Args:
        region: a candidate region whose bbox indexes the arrays below.
        rgb01: (H, W, 3) float32 RGB in [0, 1] (a 1-band image replicated three times).
        gray_u8: (H, W) uint8 gray.
        entropy: (H, W) float32 weighted entropy, bits.
        groups: feature groups to compute (:data:`SUN_GROUPS` lists them all).
        sun_dir_px: unit vector (d col, d row) towards the sun in image coordinates;
            needed by the ``sun`` group.

    Returns:
        float32 vector, length ``len(feature_names(groups))``.

    Raises:
        ValueError: the ``sun`` group without ``sun_dir_px``.
    """
    if "sun" in groups and sun_dir_px is None:
        raise ValueError("feature group 'sun' needs the sun direction (sun_dir_px)")
    h, w = gray_u8.shape
    m = feature_halo_px()
    r0, c0, r1, c1 = region.bbox
    pr0, pc0, pr1, pc1 = max(r0 - m, 0), max(c0 - m, 0), min(r1 + m, h), min(c1 + m, w)
    inside = np.zeros((pr1 - pr0, pc1 - pc0), bool)
    inside[r0 - pr0:r1 - pr0, c0 - pc0:c1 - pc0] = region.footprint
    near = ndimage.binary_dilation(inside, np.ones((3, 3), bool), iterations=1)
    ring = ndimage.binary_dilation(inside, np.ones((3, 3), bool), iterations=RING_PX + 1) & ~near
    if not ring.any():
        ring = ~inside if (~inside).any() else inside
    rgb = rgb01[pr0:pr1, pc0:pc1].astype(np.float32)
    gray = gray_u8[pr0:pr1, pc0:pc1].astype(np.float32) / 255.0
    out: list[float] = []
    for g in _ORDER:
        if g not in groups:
            continue
        if g == "rgb":
            fin, fring = rgb[inside], rgb[ring]
            out += [*fin.mean(0), *fin.std(0), *(fin.mean(0) - fring.mean(0))]
        elif g == "hsv":
            hsv = _hsv(rgb)
            hin, hring = hsv[inside], hsv[ring]
            hue = np.radians(hin[:, 0])
            out += [float(np.mean(np.cos(hue) * hin[:, 1])),
                    float(np.mean(np.sin(hue) * hin[:, 1])),
                    float(hin[:, 1].mean()), float(hin[:, 1].mean() - hring[:, 1].mean()),
                    float(hin[:, 2].mean()), float(hin[:, 2].std()),
                    float(hin[:, 2].mean() - hring[:, 2].mean())]
        elif g == "gray":
            gin, gring = gray[inside], gray[ring]
            out += [float(gin.mean()), float(gin.std()), float(gin.min()), float(gin.max()),
                    float(gring.mean()), float(gring.std()), float(gin.mean() - gring.mean())]
        elif g == "gabor":
            rings = []
            for lam in GABOR_WAVELENGTHS_PX:
                energy_sum = np.zeros_like(gray)
                for even, odd in _gabor_kernels(lam):
                    e = cv2.filter2D(gray, cv2.CV_32F, even, borderType=cv2.BORDER_REFLECT_101)
                    o = cv2.filter2D(gray, cv2.CV_32F, odd, borderType=cv2.BORDER_REFLECT_101)
                    energy = np.sqrt(e * e + o * o)
                    energy_sum += energy
                    out.append(float(energy[near].mean()))
                rings.append(float(energy_sum[ring].mean()) / len(GABOR_THETAS))
            out += rings
        elif g == "entropy":
            ent = entropy[pr0:pr1, pc0:pc1]
            out += [float(ent[inside].mean()), float(ent[inside].max()), float(ent[ring].mean())]
        elif g == "shape":
            evals = np.linalg.eigvalsh(region.cov_px)
            elong = float(np.sqrt(evals[1] / max(evals[0], 1e-9)))
            fill = region.n_px / float(max((r1 - r0) * (c1 - c0), 1))
            out += [float(np.log(max(region.area_m2, 1e-6))), elong, fill]
        elif g == "sun":
            out += _sun_features(region, gray, ring, (pr0, pc0), sun_dir_px)
    return np.asarray(out, dtype=np.float32)


def candidate_features(regions: list[Region], rgb01: np.ndarray, gray_u8: np.ndarray,
                       entropy: np.ndarray, groups: tuple[str, ...] = GROUPS,
                       sun_dir_px: tuple[float, float] | None = None) -> np.ndarray:
    """(N, F) float32 feature matrix of ``regions`` (F = ``len(feature_names(groups))``);
    ``sun_dir_px`` as in :func:`region_features`."""
    n_feat = len(feature_names(groups))
    if not regions:
        return np.zeros((0, n_feat), np.float32)
    return np.stack([region_features(r, rgb01, gray_u8, entropy, groups, sun_dir_px)
                     for r in regions])
