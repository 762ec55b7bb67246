"""Is an orthoimage like the model's training images, and is its GN physically plausible?

Three parts, none of which reads ground truth:

- :func:`image_profile`: what an image is like, from a few blocks spread over it: ground
  sample distance, bands and radiometry (grey level distribution, colour saturation), the
  texture statistics of the paper's metrics (Hessian eigenvalues at the rock and outcrop
  scales, weighted entropy, Sec. 4.1) and the share of valid pixels. ``train`` stores one
  profile per training image in the model, with the image's candidate and detection
  densities and mean detection score (:func:`detection_profile`).
- :func:`check_domain`: ``prepare`` compares its image's profile and its GN's densities
  and scores with the training images' range, and says ``ok``, ``warn`` or
  ``out_of_distribution`` with one reason per figure outside it (:data:`CHECKS`).
- :func:`rock_abundance`: the detected rocks against Golombek and Rapp's (1997) model of
  rock populations at Mars landing sites: cumulative fractional area
  F_k(D) = k exp(-q(k) D), q(k) = 1.79 + 0.152 / k, with k the total fraction of the
  surface covered by rocks (a few per cent at most landing sites). The k that explains the
  area covered by rocks of at least :data:`COMPLETE_ROCK_AREA_M2` and the number of such
  rocks against the model's are flagged outside :data:`K_WARN` / :data:`K_OUT` and
  :data:`SFD_WARN` / :data:`SFD_OUT`.

:func:`check_gsd` refuses an image whose pixels are too coarse for the smallest rock.
"""

from __future__ import annotations

import math
from typing import Any, Final

import dask
import numpy as np
from scipy.special import expn

from orbital_gn.raster import OrthoImageError, OrthoInfo
from orbital_gn.recipe import Recipe, blob_sigma_m
from roi_detector.metrics import (
    entropy_halo_px,
    hessian_eigenvalues,
    hessian_halo_px,
    weighted_entropy,
)
from roi_network import LABEL_NAMES, OUTCROP, ROCK

#: Blocks of the statistics grid the profile reads (evenly spread; all when fewer).
PROFILE_BLOCKS: Final = 8
#: A rock must span at least this many pixels across to be detected (the smallest rock of
#: the recipe at 0.25 m/px spans 3.5).
MIN_ROCK_PX: Final = 3.0
#: Rocks of this footprint and more are the ones the detector finds nearly all of: the
#: physical checks use them only (1.13 m across).
COMPLETE_ROCK_AREA_M2: Final = 1.0
#: Rock abundance k above which a GN is flagged ``warn``: the rockiest landing sites
#: (Viking 2, Pathfinder) are about 16-19 %.
K_WARN: Final = 0.20
#: ... and ``out_of_distribution``: thermal-inertia rock abundances rarely exceed 30 %.
K_OUT: Final = 0.35
#: The size-frequency check counts rocks of at least this many times the complete
#: footprint (2 m^2, 1.6 m across) among the complete ones ...
LARGER_ROCK_FACTOR: Final = 2.0
#: ... against the model: fewer of them (+1) than N_k(D1) / N_k(D0) gives for the fitted k
#: (+1), or more than the flattest curve of the model's family (k = :data:`K_FLATTEST`)
#: gives, by more than this factor is ``warn`` ...
SFD_WARN: Final = 3.0
#: ... and by more than this one ``out_of_distribution``.
SFD_OUT: Final = 10.0
#: The rockiest curve of Golombek and Rapp's family considered (its flattest
#: size-frequency).
K_FLATTEST: Final = 0.40
#: Fewest complete rocks for the size-frequency check to say anything.
SFD_MIN_ROCKS: Final = 20
#: Statuses in increasing doubt.
STATUSES: Final = ("ok", "warn", "out_of_distribution")

#: The figures compared with the training images' range: (name, how, warn, out, floor,
#: what). ``ratio``: the factor outside the range, (v + floor) / (bound + floor); ``diff``:
#: the distance outside it. Chosen so that every held-out simulator image is ``ok`` with
#: the committed model (docs/orbital_gn.md, Current results) while a factor 2 in a density
#: or 1.25 in the GSD is reported.
CHECKS: Final = (
    ("gsd_m", "ratio", 1.25, 2.0, 0.0, "ground sample distance, m/px"),
    ("gray_mean", "diff", 25.0, 60.0, 0.0, "mean grey level (0-255)"),
    ("gray_std", "ratio", 1.5, 3.0, 1.0, "grey level spread (0-255)"),
    ("saturation_mean", "diff", 0.10, 0.25, 0.0, "mean colour saturation (0-1)"),
    ("hessian_rock_std", "ratio", 1.5, 3.0, 0.5, "Hessian eigenvalue spread at the rock "
     "scale"),
    ("hessian_outcrop_std", "ratio", 1.5, 3.0, 0.5, "Hessian eigenvalue spread at the "
     "outcrop scale"),
    ("entropy_mean", "ratio", 1.25, 1.6, 0.05, "mean weighted entropy (bits)"),
    ("entropy_std", "ratio", 1.5, 3.0, 0.05, "weighted entropy spread (bits)"),
    ("rock_candidates_per_km2", "ratio", 2.0, 5.0, 20.0, "rock candidates per km^2"),
    ("outcrop_candidates_per_km2", "ratio", 2.0, 5.0, 20.0, "outcrop candidates per km^2"),
    ("rock_detections_per_km2", "ratio", 2.0, 5.0, 10.0, "rocks detected per km^2"),
    ("outcrop_detections_per_km2", "ratio", 2.0, 5.0, 5.0, "outcrops detected per km^2"),
    ("rock_score_mean", "diff", 0.10, 0.20, 0.0, "mean score of the detected rocks"),
    ("outcrop_score_mean", "diff", 0.10, 0.20, 0.0, "mean score of the detected outcrops"),
)


def check_gsd(info: OrthoInfo, recipe: Recipe) -> None:
    """Refuse an image whose pixels are too coarse for the recipe's smallest rock.

    Raises:
        OrthoImageError: naming the file, its GSD, the smallest rock it can show
            :data:`MIN_ROCK_PX` across, and the GSD needed.
    """
    area = recipe.rules.rule(ROCK).min_area_m2
    d = 2.0 * math.sqrt(area / math.pi)
    px = d / info.gsd_m
    if px >= MIN_ROCK_PX:
        return
    d_min = MIN_ROCK_PX * info.gsd_m
    raise OrthoImageError(
        f"{info.path}: ground sample distance {info.gsd_m:.3g} m/px is too coarse: a "
        f"{area:g} m^2 rock ({d:.2f} m across) spans {px:.2g} px, fewer than "
        f"{MIN_ROCK_PX:g}; the smallest rock this image shows {MIN_ROCK_PX:g} px across is "
        f"{math.pi * d_min**2 / 4:.3g} m^2 ({d_min:.3g} m); use an orthoimage of at most "
        f"{d / MIN_ROCK_PX:.2f} m/px")


# --- image profile -----------------------------------------------------------------------


def _sigmas_px(gsd_m: float) -> tuple[float, float]:
    return blob_sigma_m(0.6) / gsd_m, blob_sigma_m(8.0) / gsd_m


def _profile_task(info: OrthoInfo, tile) -> dict[str, Any]:
    import cv2

    from orbital_gn.detect import entropy_size_px
    from orbital_gn.tiling import _read_with_halo

    s_rock, s_out = _sigmas_px(info.gsd_m)
    size = entropy_size_px(info.gsd_m)
    halo = max(hessian_halo_px(s_rock), hessian_halo_px(s_out), entropy_halo_px(size))
    win, (r0, c0, r1, c1) = _read_with_halo(info, tile, halo)
    valid = win.valid[r0:r1, c0:c1]
    out: dict[str, Any] = {"pixels": int(valid.size), "valid": int(valid.sum())}
    hist = np.bincount(win.gray[r0:r1, c0:c1][valid], minlength=256)
    out["gray_hist"] = hist.astype(np.int64)
    hsv = cv2.cvtColor(np.ascontiguousarray(win.rgb01[r0:r1, c0:c1]), cv2.COLOR_RGB2HSV)
    sums = {"saturation": hsv[..., 1][valid]}
    for name, s in (("hessian_rock", s_rock), ("hessian_outcrop", s_out)):
        a, b = hessian_eigenvalues(win.gray, s)
        sums[name] = np.concatenate([a[r0:r1, c0:c1][valid], b[r0:r1, c0:c1][valid]])
    sums["entropy"] = weighted_entropy(win.gray, size)[r0:r1, c0:c1][valid]
    for k, v in sums.items():
        v = v.astype(np.float64)
        out[k] = (int(v.size), float(v.sum()), float(np.square(v).sum()))
    return out


def image_profile(info: OrthoInfo, scheduler: str | None = None, workers: int = 2,
                  progress=None) -> dict[str, Any]:
    """What an image is like (see the module doc), from :data:`PROFILE_BLOCKS` blocks."""
    from orbital_gn.tiling import _run, stats_tiles

    tasks = [dask.delayed(_profile_task, pure=True)(info, t)
             for t in stats_tiles(info, PROFILE_BLOCKS)]
    parts = _run(tasks, scheduler, workers, progress, "profile")
    pixels = sum(p["pixels"] for p in parts)
    valid = sum(p["valid"] for p in parts)
    prof: dict[str, Any] = {
        "image": info.path, "gsd_m": info.gsd_m,
        "bands": len(set(info.bands)), "colour": "gray" if len(set(info.bands)) == 1 else "rgb",
        "dtype": info.dtype, "valid_fraction": valid / pixels if pixels else 0.0,
        "area_km2": info.width * info.height * info.gsd_m**2 / 1e6,
    }
    if valid == 0:
        return prof
    hist = np.sum([p["gray_hist"] for p in parts], axis=0).astype(np.float64)
    levels = np.arange(256.0)
    mean = float((hist * levels).sum() / hist.sum())
    cdf = np.cumsum(hist) / hist.sum()
    prof |= {"gray_mean": mean,
             "gray_std": float(math.sqrt(max((hist * (levels - mean) ** 2).sum() / hist.sum(),
                                             0.0))),
             "gray_p01": int(np.searchsorted(cdf, 0.01)),
             "gray_p99": int(np.searchsorted(cdf, 0.99))}
    for k in ("saturation", "hessian_rock", "hessian_outcrop", "entropy"):
        n = sum(p[k][0] for p in parts)
        s = sum(p[k][1] for p in parts)
        s2 = sum(p[k][2] for p in parts)
        m = s / n
        sd = math.sqrt(max(s2 / n - m * m, 0.0))
        if k == "saturation":
            prof["saturation_mean"] = m
        elif k == "entropy":
            prof["entropy_mean"], prof["entropy_std"] = m, sd
        else:
            prof[f"{k}_std"] = sd
    return {k: (round(v, 6) if isinstance(v, float) else v) for k, v in prof.items()}


def detection_profile(n_candidates: dict[int, int], scores: dict[int, np.ndarray],
                      area_km2: float) -> dict[str, float]:
    """Densities of candidates and detections (per km^2 of valid ground) and the mean
    detection score, per class (``scores``: the detections' scores)."""
    out: dict[str, float] = {}
    for label in (ROCK, OUTCROP):
        name = LABEL_NAMES[label]
        s = np.asarray(scores.get(label, ()), float)
        if area_km2 > 0:
            out[f"{name}_candidates_per_km2"] = round(n_candidates.get(label, 0) / area_km2, 3)
            out[f"{name}_detections_per_km2"] = round(s.size / area_km2, 3)
        if s.size:
            out[f"{name}_score_mean"] = round(float(s.mean()), 4)
    return out


# --- physical sanity ---------------------------------------------------------------------


def q_of_k(k: float) -> float:
    """Golombek and Rapp's decay constant q(k) = 1.79 + 0.152 / k (1/m)."""
    return 1.79 + 0.152 / k


def fractional_area(k: float, d_m: float) -> float:
    """F_k(D): fraction of the surface covered by rocks of diameter >= ``d_m``."""
    return k * math.exp(-q_of_k(k) * d_m)


def cumulative_number(k: float, d_m: float) -> float:
    """N_k(D): rocks of diameter >= ``d_m`` per m^2, from dF = -(pi/4) D^2 dN."""
    q = q_of_k(k)
    return 4.0 * k * q / math.pi * float(expn(2, q * d_m)) / d_m


def fit_k(f_obs: float, d_m: float) -> float:
    """The k for which F_k(d_m) = ``f_obs`` (F grows with k); ``inf`` above F_1(d_m)."""
    if f_obs <= 0:
        return 0.0
    if f_obs > fractional_area(1.0, d_m):
        return math.inf
    lo, hi = 1e-6, 1.0
    for _ in range(80):
        mid = math.sqrt(lo * hi)
        lo, hi = (mid, hi) if fractional_area(mid, d_m) < f_obs else (lo, mid)
    return math.sqrt(lo * hi)


def rock_abundance(rock_areas_m2: np.ndarray, area_m2: float) -> dict[str, Any]:
    """The detected rocks against Golombek and Rapp's model (module doc).

    k is fitted to the area covered by the complete rocks (footprint >=
    :data:`COMPLETE_ROCK_AREA_M2`, diameter D0); the size-frequency is judged by the
    number of them that are also at least :data:`LARGER_ROCK_FACTOR` times that footprint
    (diameter D1): against N_k(D1) / N_k(D0) of the fitted k when fewer, of
    :data:`K_FLATTEST` when more.

    Args:
        rock_areas_m2: footprints of the detected rocks.
        area_m2: valid ground the detection covered.

    Returns:
        ``k`` (None with no complete rock), the covered fraction, the counts of complete
        and larger rocks, the model's counts of larger rocks for the fitted k and for
        :data:`K_FLATTEST`, the ratio (+1 each) to the nearer one, and the rocks per km^2.
    """
    a = np.asarray(rock_areas_m2, float)
    d0 = 2.0 * math.sqrt(COMPLETE_ROCK_AREA_M2 / math.pi)
    d1 = d0 * math.sqrt(LARGER_ROCK_FACTOR)
    big = a[a >= COMPLETE_ROCK_AREA_M2]
    out: dict[str, Any] = {"model": "Golombek & Rapp 1997: F_k(D) = k exp(-(1.79 + 0.152/k) D)",
                           "diameter_min_m": round(d0, 3), "rocks": int(big.size),
                           "rocks_per_km2": round(a.size / (area_m2 / 1e6), 2) if area_m2 else None}
    if area_m2 <= 0 or big.size == 0:
        return out | {"k": None}
    f = float(big.sum()) / area_m2
    k = fit_k(f, d0)
    out |= {"fractional_area": f, "k": None if not math.isfinite(k) else round(k, 5)}
    if math.isfinite(k) and k > 0:
        n1 = int((big >= COMPLETE_ROCK_AREA_M2 * LARGER_ROCK_FACTOR).sum())
        expected = big.size * cumulative_number(k, d1) / cumulative_number(k, d0)
        flattest = (big.size * cumulative_number(K_FLATTEST, d1)
                    / cumulative_number(K_FLATTEST, d0))
        ratio = ((n1 + 1.0) / (expected + 1.0) if n1 < expected else
                 max(1.0, (n1 + 1.0) / (flattest + 1.0)))
        out |= {"larger_diameter_m": round(d1, 3), "larger_rocks": n1,
                "larger_rocks_model": round(expected, 1),
                "larger_rocks_flattest": round(flattest, 1),
                "larger_rocks_ratio": round(ratio, 3)}
    return out


# --- the check ---------------------------------------------------------------------------


def _level(excess: float, warn: float, out: float) -> str:
    return "out_of_distribution" if excess > out else "warn" if excess > warn else "ok"


def _fmt(v: float) -> str:
    return f"{v:.3g}"


def check_domain(profile: dict[str, Any], training: list[dict[str, Any]] | None,
                 rocks: dict[str, Any] | None = None,
                 no_training: str = "the model stores no training-image profile (trained "
                 "before domain checks): the image cannot be compared with its training "
                 "images") -> dict[str, Any]:
    """The ``metadata.domain_check`` of a GN.

    Args:
        profile: the image's :func:`image_profile` merged with its
            :func:`detection_profile`.
        training: the model's per-image profiles (``None``: the model stores none).
        rocks: :func:`rock_abundance` of the GN's rocks (None: not checked).
        no_training: the reason given when ``training`` is None.

    Returns:
        ``status`` (the worst reason's level, ``ok`` without any), ``reasons`` (each
        ``check``, ``level``, ``value``, ``training_range`` and a ``message``), ``figures``
        (every figure with its training range), ``rock_abundance``.
    """
    reasons: list[dict[str, Any]] = []
    figures: dict[str, Any] = {}
    if not training:
        reasons.append({"check": "training_profile", "level": "warn", "value": None,
                        "message": no_training})
    else:
        colours = sorted({t.get("colour") for t in training})
        figures["colour"] = {"value": profile.get("colour"), "training": colours}
        if profile.get("colour") is not None and profile["colour"] not in colours:
            reasons.append({
                "check": "colour", "level": "warn", "value": profile.get("colour"),
                "training_range": colours,
                "message": f"the image is {profile.get('colour')} ({profile.get('bands')} "
                f"band(s) read) and the model was trained on {'/'.join(colours)} images: "
                "its colour features see other values"})
        for name, how, warn, out, floor, what in CHECKS:
            vals = [t[name] for t in training if t.get(name) is not None]
            v = profile.get(name)
            if v is None or not vals:
                continue
            lo, hi = min(vals), max(vals)
            figures[name] = {"value": v, "training_range": [lo, hi]}
            if lo <= v <= hi:
                continue
            bound = hi if v > hi else lo
            if how == "ratio":
                a, b = v + floor, bound + floor
                excess = max(a, b) / min(a, b) if min(a, b) > 0 else math.inf
                said = f"{excess:.2g} times"
                lvl = _level(excess, warn, out)
            else:
                excess = abs(v - bound)
                said = f"{excess:.3g}"
                lvl = _level(excess, warn, out)
            if lvl == "ok":
                continue
            side = "above" if v > hi else "below"
            reasons.append({
                "check": name, "level": lvl, "value": v, "training_range": [lo, hi],
                "message": f"{what} {_fmt(v)} is {said} {side} the training images' "
                f"{_fmt(lo)}-{_fmt(hi)}"})
    if rocks is not None:
        reasons += _physical_reasons(rocks)
    status = max((r["level"] for r in reasons), key=STATUSES.index, default="ok")
    return {"status": status, "reasons": reasons, "figures": figures,
            "training_images": [t.get("image") for t in training or []],
            "rock_abundance": rocks}


def _physical_reasons(rocks: dict[str, Any]) -> list[dict[str, Any]]:
    out = []
    k = rocks.get("k")
    if rocks.get("rocks") and k is None:
        out.append({"check": "rock_abundance", "level": "out_of_distribution", "value": None,
                    "message": f"rocks of at least {COMPLETE_ROCK_AREA_M2:g} m^2 cover "
                    f"{100 * rocks['fractional_area']:.1f} % of the ground: more than any "
                    "rock abundance k of Golombek and Rapp's model allows"})
    elif k is not None:
        lvl = _level(k, K_WARN, K_OUT)
        if lvl != "ok":
            out.append({"check": "rock_abundance", "level": lvl, "value": k,
                        "training_range": [0.0, K_WARN],
                        "message": f"the detected rocks imply a rock abundance k of "
                        f"{100 * k:.1f} % (Golombek and Rapp), above the rockiest Mars "
                        f"landing sites' (~{100 * K_WARN:.0f} %)"})
    ratio = rocks.get("larger_rocks_ratio")
    if ratio is not None and rocks["rocks"] >= SFD_MIN_ROCKS:
        excess = max(ratio, 1.0 / ratio)
        lvl = _level(excess, SFD_WARN, SFD_OUT)
        if lvl != "ok":
            if ratio > 1:
                model = (f"even its flattest size-frequency (k = {100 * K_FLATTEST:.0f} %) "
                         f"has {rocks['larger_rocks_flattest']:.0f}")
            else:
                model = (f"its size-frequency for the fitted k = {100 * k:.1f} % has "
                         f"{rocks['larger_rocks_model']:.0f}")
            out.append({"check": "rock_size_frequency", "level": lvl, "value": ratio,
                        "training_range": [1.0 / SFD_WARN, SFD_WARN],
                        "message": f"{rocks['larger_rocks']} of the {rocks['rocks']} rocks "
                        f"of at least {COMPLETE_ROCK_AREA_M2:g} m^2 are of "
                        f"{COMPLETE_ROCK_AREA_M2 * LARGER_ROCK_FACTOR:g} m^2 or more where "
                        f"Golombek and Rapp's model of rock populations {model}: "
                        f"{excess:.2g} times {'more' if ratio > 1 else 'fewer'}"})
    return out
