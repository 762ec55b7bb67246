"""The offline GN preparation of the paper's orbital half: orthoimage -> Global Network.

``prepare_gn`` validates the raster, measures the metric distributions, detects candidates
in overlapping windows, classifies them with the model's binary classifiers, removes
rocks lying on an accepted outcrop, and returns the GN as a ``map``-frame
:class:`~roi_network.RoiNetwork` with its provenance. Nothing here reads ground truth.

Steps (docs/orbital_gn.md, Method): 1 read and validate, 2 metric maps, 3 distributions,
4 candidates, 5 features, 6 sun shift, 7 classification, 8 merge.
"""

from __future__ import annotations

import logging
import math
import os
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

from orbital_gn.detect import classify
from orbital_gn.domain import (
    check_domain,
    check_gsd,
    detection_profile,
    image_profile,
    rock_abundance,
)
from orbital_gn.raster import (
    SUN_TAGS,
    OrthoImageError,
    OrthoInfo,
    Sun,
    open_ortho,
    sha256_of,
    sun_from_tags,
)
from orbital_gn.recipe import RECIPES, Recipe
from orbital_gn.tiling import default_tile_px, detect_candidates, raster_stats
from roi_detector.classifier import BinaryClassifier, load_classifiers
from roi_network import LABEL_NAMES, OUTCROP, ROCK, MapFrame, RoiNetwork, empty_records

log = logging.getLogger("orbital_gn")

#: Below this share of valid pixels, ``prepare`` says how much of the image is nodata.
NODATA_WARN_FRACTION = 0.5


def default_model_path() -> Path:
    """The committed default model (``orbital_gn/models/orbital_default.npz``, the
    ``sun_aware`` recipe)."""
    return Path(str(resources.files("orbital_gn") / "models" / "orbital_default.npz"))


def no_sun_model_path() -> Path:
    """The committed model used instead of the default one when a raster's sun direction
    is unknown (``orbital_gn/models/orbital_no_sun.npz``, the ``no_sun`` recipe)."""
    return Path(str(resources.files("orbital_gn") / "models" / "orbital_no_sun.npz"))


@dataclass
class Model:
    """Trained classifiers with their recipe and provenance (``None`` classifiers: the
    candidate-only detector). ``without_sun``: a model file to use instead when the
    recipe needs the sun direction and the raster's is unknown (the default model's)."""

    recipe: Recipe
    classifiers: dict[str, BinaryClassifier] = field(default_factory=dict)
    meta: dict[str, Any] = field(default_factory=dict)
    path: str | None = None
    without_sun: str | None = None


def load_model(path: str | os.PathLike[str] | None) -> Model:
    """Load a model file (default: the committed one); its recipe is recorded inside.

    Raises:
        roi_detector.classifier.ModelFileError: naming the file.
    """
    from roi_detector.classifier import ModelFileError

    p = Path(path) if path is not None else default_model_path()
    classifiers, meta = load_classifiers(p)
    name = meta.get("provenance", {}).get("recipe", {}).get("name")
    if name not in RECIPES:
        raise ModelFileError(f"{p}: field 'provenance.recipe.name' is {name!r}, expected one "
                             f"of {sorted(RECIPES)}")
    fallback = None
    if path is None and RECIPES[name].sun_aware and no_sun_model_path().is_file():
        fallback = str(no_sun_model_path())
    return Model(RECIPES[name], classifiers, meta, str(p), fallback)


def map_origin_of(info: OrthoInfo) -> tuple[float, float]:
    """The map-frame origin: the raster's centre, rounded to the metre."""
    t = info.transform
    x = t.a * info.width / 2.0 + t.b * info.height / 2.0 + t.c
    y = t.d * info.width / 2.0 + t.e * info.height / 2.0 + t.f
    return float(round(x)), float(round(y))


def resolve_sun(info: OrthoInfo, recipe: Recipe, sun: Sun | None = None
                ) -> tuple[Sun | None, str]:
    """The sun direction a recipe needs, and where it came from.

    Given (``--sun-azimuth/--sun-elevation``, from the image product's metadata) it wins;
    else the raster's own metadata tags (:data:`orbital_gn.raster.SUN_TAGS`). A recipe that
    is not ``sun_aware`` needs none.

    Raises:
        OrthoImageError: a ``sun_aware`` recipe and no sun direction (names the file).
    """
    if not recipe.sun_aware:
        return None, "not used by the recipe"
    if sun is not None:
        return sun, "given (--sun-azimuth/--sun-elevation)"
    tagged = sun_from_tags(info.path)
    if tagged is not None:
        return tagged, f"raster metadata {'/'.join(SUN_TAGS)}"
    raise OrthoImageError(
        f"{info.path}: recipe {recipe.name!r} needs the sun direction and the raster's "
        f"metadata has no {'/'.join(SUN_TAGS)}; pass --sun-azimuth DEG (clockwise from "
        "north) --sun-elevation DEG (90 - incidence angle) from the image product's label, "
        "or use a model of the 'no_sun' recipe")


def suppress_rocks_on_outcrops(records: np.ndarray) -> np.ndarray:
    """Drop rocks whose centre lies inside an outcrop's footprint ellipse (one ROI, not two)."""
    rocks = records["label"] == ROCK
    outcrops = records[records["label"] == OUTCROP]
    if not rocks.any() or outcrops.size == 0:
        return records
    keep = np.ones(records.size, bool)
    rx, ry = records["x"][rocks], records["y"][rocks]
    inside = np.zeros(rx.size, bool)
    for o in outcrops:
        c, s = math.cos(o["angle_rad"]), math.sin(o["angle_rad"])
        dx, dy = rx - o["x"], ry - o["y"]
        u, v = dx * c + dy * s, -dx * s + dy * c
        a, b = max(o["major_m"] / 2, 1e-6), max(o["minor_m"] / 2, 1e-6)
        inside |= (u / a) ** 2 + (v / b) ** 2 <= 1.0
    keep[np.flatnonzero(rocks)[inside]] = False
    return records[keep]


def assign_ids(records: np.ndarray) -> np.ndarray:
    """Sort records (class, then north to south, west to east) and number them from 1:
    the same GN gets the same ids whatever the tiling."""
    order = np.lexsort((np.round(records["x"], 6), -np.round(records["y"], 6),
                        records["label"]))
    out = records[order].copy()
    out["id"] = np.arange(1, out.size + 1, dtype=np.uint32)
    return out


def prepare_gn(path: str | os.PathLike[str], model: Model, tile_px: int | None = None,
               scheduler: str | None = None, workers: int = 2, progress=None,
               origin: tuple[float, float] | None = None, sun: Sun | None = None
               ) -> tuple[RoiNetwork, list[str]]:
    """The GN of an orthoimage.

    Args:
        path: the orthoimage (any raster GDAL reads, projected CRS).
        model: classifiers and recipe (:func:`load_model`).
        tile_px: window core side, pixels (default: :func:`default_tile_px`).
        scheduler: ``None`` local processes, ``"sync"`` in-process, or a dask.distributed
            scheduler address.
        workers: local worker processes.
        progress: ``progress(what, total)`` -> object with ``update(n)`` and ``close()``.
        origin: map-frame origin (easting, northing); default :func:`map_origin_of`.
        sun: sun direction for a ``sun_aware`` recipe; default :func:`resolve_sun`'s.

    Returns:
        (GN in the ``map`` frame, warnings for the user).

    Raises:
        orbital_gn.raster.OrthoImageError: an unusable raster, or no sun direction for a
            ``sun_aware`` recipe (names the file).
    """
    # 1. Read and validate the raster.
    info = open_ortho(path)
    warnings: list[str] = []
    notes: list[str] = []  # warnings that do not mean the GN is empty
    if (model.recipe.sun_aware and sun is None and model.without_sun
            and sun_from_tags(info.path) is None):
        notes.append(f"{info.path}: no sun direction (no --sun-azimuth/--sun-elevation, "
                        f"no {'/'.join(SUN_TAGS)} metadata): using {model.without_sun} "
                        f"(recipe without the sun) instead of {model.path}")
        model = load_model(model.without_sun)
    recipe = model.recipe
    check_gsd(info, recipe)
    sun, sun_source = resolve_sun(info, recipe, sun)
    origin = origin if origin is not None else map_origin_of(info)
    metadata = _metadata(info, model, origin)
    metadata["sun"] = ({"azimuth_deg": sun.azimuth_deg, "elevation_deg": sun.elevation_deg,
                        "source": sun_source} if sun else {"source": sun_source})
    tile_px = tile_px or default_tile_px(info)
    min_side_m = min(info.width, info.height) * info.gsd_m
    smallest = min(r.min_area_m2 for r in recipe.rules.rules)
    records = empty_records(0)
    n_cands: dict[int, int] = {}
    profile: dict[str, Any] = {}
    if min_side_m**2 < smallest:
        warnings.append(f"{info.path}: the raster covers {info.width} x {info.height} px "
                        f"({min_side_m:.2f} m across): smaller than the smallest ROI "
                        f"({smallest} m^2); the GN is empty")
    else:
        # 2. Metric maps and 3. distributions (tiling pass 1; maps: detect.class_metrics).
        stats, n_valid = raster_stats(info, recipe, scheduler, workers, progress)
        if n_valid == 0:
            warnings.append(f"{info.path}: no valid pixel (all nodata); the GN is empty")
        else:
            profile = image_profile(info, scheduler, workers, progress)
            if profile["valid_fraction"] < NODATA_WARN_FRACTION:
                notes.append(
                    f"{info.path}: {100 * (1 - profile['valid_fraction']):.0f} % of the image "
                    "is nodata (nodata value, alpha band or mask): the GN covers "
                    f"{profile['area_km2'] * profile['valid_fraction']:.3g} of its "
                    f"{profile['area_km2']:.3g} km^2")
            if _flat(stats):
                warnings.append(f"{info.path}: the image has no texture (constant values); "
                                "the GN is empty")
            else:
                # 4.-6. Candidates, features and sun shift (tiling pass 2,
                # detect.window_candidates).
                cands = detect_candidates(info, recipe, stats, origin, tile_px, scheduler,
                                          workers, progress, sun)
                # 7. Classification.
                kept = [classify(c, model.classifiers, recipe) for c in cands]
                records = np.concatenate(kept) if kept else empty_records(0)
                # 8. Merge: rocks on an accepted outcrop dropped, ids assigned.
                records = assign_ids(suppress_rocks_on_outcrops(records))
                n_cands = {c.label: int(c.records.size) for c in cands}
                metadata["candidates"] = {LABEL_NAMES[c.label]: int(c.records.size)
                                          for c in cands}
            metadata["metric_stats"] = {
                LABEL_NAMES[label]: {k: [v.mean, v.std] for k, v in s.items()}
                for label, s in stats.items()}
    if records.size == 0 and not warnings:
        warnings.append(f"{info.path}: no ROI found; the GN is empty")
    metadata["tile_px"] = tile_px
    # The domain check: the image and its GN against the model's training images, and
    # the rocks against a rock-abundance model.
    domain = domain_check_of(model, profile, records, n_cands)
    metadata["domain_check"] = domain
    notes += [f"{info.path}: domain check {r['level']}: {r['message']}"
              for r in domain["reasons"]]
    return RoiNetwork(records, "map", MapFrame(info.crs, origin), metadata), notes + warnings


def training_profiles(model: Model) -> list[dict[str, Any]] | None:
    """The per-image profiles a model stores (None: a model without them)."""
    images = (model.meta.get("provenance", {}).get("domain") or {}).get("images")
    return images or None


def domain_check_of(model: Model, profile: dict[str, Any], records: np.ndarray,
                    n_candidates: dict[int, int]) -> dict[str, Any]:
    """``metadata.domain_check`` of a GN: :func:`orbital_gn.domain.check_domain` of the
    image's profile, its GN's densities and scores, and its rocks' abundance."""
    if not model.classifiers:
        return check_domain(profile, None, None, "candidates only (no model): neither "
                            "compared with training images nor checked for physical sense")
    area_km2 = profile.get("area_km2", 0.0) * profile.get("valid_fraction", 0.0)
    scores = {lab: records["score"][records["label"] == lab] for lab in (ROCK, OUTCROP)}
    full = dict(profile)
    if n_candidates:
        full |= detection_profile(n_candidates, scores, area_km2)
    rocks = rock_abundance(records["area_m2"][records["label"] == ROCK], area_km2 * 1e6)
    return check_domain(full, training_profiles(model), rocks)


def _flat(stats) -> bool:
    # float64 moments leave a rounding residue on a constant image: compare relatively.
    # The pooled "hessian" mixes two maps whose means differ slightly even then: skip it.
    return all(all(v.std <= 1e-6 * (1.0 + abs(v.mean)) for k, v in s.items() if k != "hessian")
               for s in stats.values())


def _metadata(info: OrthoInfo, model: Model, origin) -> dict[str, Any]:
    prov = model.meta.get("provenance", {})
    return {
        "source": "orbital_gn prepare",
        "source_image": os.path.abspath(info.path),
        "source_sha256": sha256_of(info.path),
        "gsd_m": info.gsd_m,
        "raster_size_px": [info.width, info.height],
        "recipe": model.recipe.to_dict(),
        "model": {"path": model.path, "training": prov.get("training"),
                  "library_versions": model.meta.get("library_versions")},
        "ellipse": "major_m/minor_m: full axis lengths; angle_rad: major axis from map +x "
                   "(east), counter-clockwise",
        "score": "classifier vote share (1.0 when run without classifiers)",
        "map_origin_rule": f"raster centre rounded to 1 m: {list(origin)}",
    }
