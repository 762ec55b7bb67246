"""Training the orbital binary classifiers ("Rock Orbital", "Outcrop Orbital").

Training code: the candidates the detector finds in an image are labelled by a truth
catalogue (a candidate is positive when it matches a truth ROI of its class by DESIGN.md's
rule). The truth is either a simulator bag's ``truth/rois.geojson`` (the whole image is
labelled), or a person's label file (:mod:`orbital_gn.labels`: candidates outside its
region are not used; unlabelled ground inside it is negative). Bags' seeds are recorded in
the model's provenance, and a bag whose seed is an evaluation seed is refused.

The model also stores, per training image, its domain profile
(:func:`orbital_gn.domain.image_profile` and :func:`~orbital_gn.domain.detection_profile`
of the trained classifiers' detections there), which ``prepare`` compares its image with.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import numpy as np
import yaml

from orbital_gn.domain import check_gsd, detection_profile, image_profile
from orbital_gn.evaluate import crs_xy, match
from orbital_gn.labels import Region, read_labels
from orbital_gn.prepare import map_origin_of, resolve_sun
from orbital_gn.raster import open_ortho
from orbital_gn.recipe import MIN_PROBABILITY, Recipe
from orbital_gn.tiling import default_tile_px, detect_candidates, raster_stats
from roi_detector.classifier import BinaryClassifier, load_classifiers, save_classifiers
from roi_detector.features import feature_names
from roi_network import LABEL_NAMES, MapFrame, RoiNetwork
from roi_network.geojson import read_geojson

#: Seeds the project evaluates on (atacama_1km and quick seed 1): never trained on.
EVALUATION_SEEDS: Final = (1, 2, 3)


@dataclass(frozen=True)
class TrainingImage:
    """One training image and its truth.

    Attributes:
        image: the orthoimage.
        labels: a label file (:mod:`orbital_gn.labels`), or None for a bag's truth.
        region: the label file's region file (None: the label file's extent).
        bag: the bag directory when the truth is ``bag/truth/rois.geojson``.
    """

    image: Path
    labels: Path | None = None
    region: Path | None = None
    bag: Path | None = None

    @classmethod
    def of_bag(cls, bag: str | os.PathLike[str]) -> TrainingImage:
        """A simulator bag (``orbital.tif`` + ``truth/rois.geojson``).

        Raises:
            TrainingError: a file is missing (names the bag).
        """
        bag = Path(bag)
        for p in (bag / "orbital.tif", bag / "truth" / "rois.geojson"):
            if not p.is_file():
                raise TrainingError(f"{bag}: {p.relative_to(bag)} is missing (a training bag "
                                    "holds orbital.tif and truth/; for an image with a label "
                                    "file use --image ORTHO.tif --labels LABELS.geojson)")
        return cls(bag / "orbital.tif", bag=bag)

    @property
    def name(self) -> str:
        return str(self.bag if self.bag else self.image)


class TrainingError(ValueError):
    """Training cannot proceed; the message names the bag or file."""


def bag_seed(bag: Path) -> int | None:
    """The generator seed recorded in ``bag/world.yaml`` (None when absent)."""
    world = bag / "world.yaml"
    if not world.is_file():
        return None
    cfg = yaml.safe_load(world.read_text()) or {}
    seed = (cfg.get("config") or {}).get("seed")
    return int(seed) if seed is not None else None


def _region_fraction(region: Region | None, info, n: int = 128) -> float:
    """Share of the image inside the region (an n x n grid of pixel centres)."""
    if region is None:
        return 1.0
    t = info.transform
    c, r = np.meshgrid((np.arange(n) + 0.5) * info.width / n,
                       (np.arange(n) + 0.5) * info.height / n)
    xy = np.column_stack([t.a * c.ravel() + t.b * r.ravel() + t.c,
                          t.d * c.ravel() + t.e * r.ravel() + t.f])
    return float(region.contains(xy).mean())


@dataclass
class LabelledImage:
    """Candidates of one training image with their labels, and the image's profile.

    Attributes:
        source: the image and its truth.
        samples: per class, (features, 0/1 labels) of the candidates in the region.
        profile: :func:`orbital_gn.domain.image_profile`, plus ``region_km2`` (valid
            labelled ground) and the labels counted.
        notes: user-facing lines (labels skipped).
    """

    source: TrainingImage
    samples: dict[int, tuple[np.ndarray, np.ndarray]]
    profile: dict[str, Any]
    notes: list[str]


def labelled_candidates(src: TrainingImage | str | os.PathLike[str], recipe: Recipe,
                        scheduler: str | None = None, workers: int = 2) -> LabelledImage:
    """The candidates found in a training image, labelled by its truth."""
    src = src if isinstance(src, TrainingImage) else TrainingImage.of_bag(src)
    info = open_ortho(src.image)
    check_gsd(info, recipe)
    # As prepare does: the sun direction from the image's own metadata (never world.yaml).
    sun, _ = resolve_sun(info, recipe)
    origin = map_origin_of(info)
    notes: list[str] = []
    if src.labels is not None:
        ls = read_labels(src.labels, info, origin, src.region)
        truth, region = ls.truth, ls.region
        notes += ls.notes()
        counted = ls.counts
    else:
        truth, region = read_geojson(src.bag / "truth" / "rois.geojson"), None
        counted = {"rock": int((truth.records["label"] == 1).sum()),
                   "outcrop": int((truth.records["label"] == 2).sum())}
    stats, _ = raster_stats(info, recipe, scheduler, workers)
    cands = detect_candidates(info, recipe, stats, origin, default_tile_px(info), scheduler,
                              workers, sun=sun)
    profile = image_profile(info, scheduler, workers)
    profile["region_km2"] = round(profile["area_km2"] * profile["valid_fraction"]
                                  * _region_fraction(region, info), 6)
    profile["labels"] = counted
    out = {}
    for c in cands:
        net = RoiNetwork(c.records, "map", MapFrame(info.crs, origin))
        det_match, _ = match(net, truth, c.label)
        y = (det_match >= 0).astype(np.uint8)
        x = c.features
        if region is not None:
            inside = region.contains(crs_xy(net))
            x, y = x[inside], y[inside]
        out[c.label] = (x, y)
    return LabelledImage(src, out, profile, notes)


def _sources(items) -> list[TrainingImage]:
    return [s if isinstance(s, TrainingImage) else TrainingImage.of_bag(s) for s in items]


def _domain_profiles(images: list[LabelledImage],
                     classifiers: dict[str, BinaryClassifier]) -> list[dict[str, Any]]:
    """Each training image's profile with the classifiers' (in-sample) detections."""
    out = []
    for im in images:
        n_cands, scores = {}, {}
        for label, (x, _) in im.samples.items():
            n_cands[label] = len(x)
            clf = classifiers.get(f"{LABEL_NAMES[label]}_orbital")
            if clf is not None and len(x):
                p = clf.predict_proba(x)
                scores[label] = p[p >= MIN_PROBABILITY]
        out.append(im.profile | detection_profile(n_cands, scores, im.profile["region_km2"]))
    return out


def _provenance_images(images: list[LabelledImage]) -> list[dict[str, Any]]:
    return [{"image": str(im.source.image.resolve()),
             "labels": str(im.source.labels.resolve()) if im.source.labels else
             str((im.source.bag / "truth" / "rois.geojson").resolve()),
             "region": str(im.source.region.resolve()) if im.source.region else None,
             "labels_kind": "label file" if im.source.labels else "simulator truth"}
            for im in images]


def train_model(sources: list, recipe: Recipe, out: str | os.PathLike[str],
                scheduler: str | None = None, workers: int = 2,
                allow_eval_seeds: bool = False, notes: list[str] | None = None
                ) -> dict[str, Any]:
    """Train one binary classifier per class on the training images and save the model.

    Args:
        sources: :class:`TrainingImage` items, or bag directories.
        recipe: the detection recipe.
        out: the model file (.npz).
        scheduler, workers: as :func:`orbital_gn.prepare.prepare_gn`'s.
        allow_eval_seeds: accept a bag of an evaluation seed (tests only).
        notes: when given, user-facing lines (labels skipped) are appended to it.

    Returns:
        The provenance written into the model (images, seeds, sample counts, domain).

    A class whose candidates all carry one label gets no classifier (recorded in the
    provenance); ``prepare`` then keeps all its candidates.

    Raises:
        TrainingError: a bag is missing files or has an evaluation seed, or no class could
            be trained.
        orbital_gn.labels.LabelFileError: a label or region file cannot be used.
    """
    srcs = _sources(sources)
    seeds = []
    for s in srcs:
        seed = bag_seed(s.bag) if s.bag else None
        if seed in EVALUATION_SEEDS and not allow_eval_seeds:
            raise TrainingError(f"{s.bag}: seed {seed} is an evaluation seed "
                                f"{EVALUATION_SEEDS}; train on other seeds (e.g. 101, 102)")
        seeds.append(seed)
    images = [labelled_candidates(s, recipe, scheduler, workers) for s in srcs]
    for im in images:
        if notes is not None:
            notes += im.notes
    names = feature_names(recipe.feature_groups)
    classifiers = {}
    counts = {}
    for label in sorted({lab for im in images for lab in im.samples}):
        x = np.concatenate([im.samples[label][0] for im in images if label in im.samples])
        y = np.concatenate([im.samples[label][1] for im in images if label in im.samples])
        name = f"{LABEL_NAMES[label]}_orbital"
        counts[name] = {"samples": int(y.size), "positive": int(y.sum())}
        if y.size and 0 < y.sum() < y.size:
            classifiers[name] = BinaryClassifier(name, names, recipe.classifier).fit(x, y)
        else:
            # One class only (e.g. the paper's outcrop rule finds few candidates): no
            # classifier; prepare then keeps every candidate of the class (recorded).
            counts[name]["untrained"] = "candidates of one label only"
    if not classifiers:
        raise TrainingError(f"no classifier could be trained from "
                            f"{[s.name for s in srcs]}: {counts}")
    provenance = {
        "recipe": recipe.to_dict(),
        "training": {"bags": [str(s.bag.resolve()) for s in srcs if s.bag],
                     "images": _provenance_images(images), "seeds": seeds,
                     "samples": counts,
                     "labelling": "candidate matches a truth ROI of its class (DESIGN.md "
                     "rule); with a label file, only candidates inside its region"},
        "domain": {"images": _domain_profiles(images, classifiers)},
    }
    save_classifiers(out, classifiers, provenance)
    return provenance


def profile_model(model: str | os.PathLike[str], sources: list,
                  out: str | os.PathLike[str], scheduler: str | None = None,
                  workers: int = 2) -> dict[str, Any]:
    """Store the domain profiles of a trained model's training images in it, leaving its
    classifiers as they are (a model trained before models carried them).

    Returns:
        The model's new provenance.
    """
    classifiers, meta = load_classifiers(model)
    prov = dict(meta.get("provenance", {}))
    from orbital_gn.recipe import RECIPES

    recipe = RECIPES[prov["recipe"]["name"]]
    images = [labelled_candidates(s, recipe, scheduler, workers) for s in _sources(sources)]
    prov["domain"] = {"images": _domain_profiles(images, classifiers),
                      "profiled": "after training, on the training worlds regenerated from "
                      "their seeds"}
    save_classifiers(out, classifiers, prov)
    return prov
