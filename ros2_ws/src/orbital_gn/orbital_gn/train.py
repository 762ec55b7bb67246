"""Training the orbital binary classifiers ("Rock Orbital", "Outcrop Orbital") from bags.

Training code: it reads each bag's truth catalogue to label the candidates the detector
finds in the bag's ``orbital.tif`` (a candidate is positive when it matches a truth ROI of
its class by DESIGN.md's rule). The bags' seeds are recorded in the model's provenance,
and a bag whose seed is an evaluation seed is refused.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Final

import numpy as np
import yaml

from orbital_gn.evaluate import match
from orbital_gn.prepare import map_origin_of, resolve_sun
from orbital_gn.raster import open_ortho
from orbital_gn.recipe import Recipe
from orbital_gn.tiling import default_tile_px, detect_candidates, raster_stats
from roi_detector.classifier import BinaryClassifier, save_classifiers
from roi_detector.features import feature_names
from roi_network import LABEL_NAMES, MapFrame, RoiNetwork
from roi_network.geojson import read_geojson

#: Seeds the project evaluates on (atacama_1km and quick seed 1): never trained on.
EVALUATION_SEEDS: Final = (1, 2, 3)


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


def labelled_candidates(bag: Path, recipe: Recipe, scheduler: str | None = None,
                        workers: int = 2) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Per class, (features, 0/1 labels) of the candidates found in ``bag/orbital.tif``."""
    ortho, truth_path = bag / "orbital.tif", bag / "truth" / "rois.geojson"
    for p in (ortho, truth_path):
        if not p.is_file():
            raise TrainingError(f"{bag}: {p.relative_to(bag)} is missing")
    info = open_ortho(ortho)
    # As prepare does: the sun direction from the image's own metadata (never world.yaml).
    sun, _ = resolve_sun(info, recipe)
    truth = read_geojson(truth_path)
    origin = map_origin_of(info)
    stats, _ = raster_stats(info, recipe, scheduler, workers)
    cands = detect_candidates(info, recipe, stats, origin, default_tile_px(info), scheduler,
                              workers, sun=sun)
    out = {}
    for c in cands:
        net = RoiNetwork(c.records, "map", MapFrame(info.crs, origin))
        det_match, _ = match(net, truth, c.label)
        out[c.label] = (c.features, (det_match >= 0).astype(np.uint8))
    return out


def train_model(bags: list[str | os.PathLike[str]], recipe: Recipe, out: str | os.PathLike[str],
                scheduler: str | None = None, workers: int = 2,
                allow_eval_seeds: bool = False) -> dict[str, Any]:
    """Train one binary classifier per class on the bags and save the model file.

    Returns:
        The provenance written into the model (bags, seeds, sample counts).

    A class whose candidates all carry one label gets no classifier (recorded in the
    provenance); ``prepare`` then keeps all its candidates.

    Raises:
        TrainingError: a bag is missing files or has an evaluation seed, or no class could
            be trained.
    """
    feats: dict[int, list[np.ndarray]] = {}
    labels: dict[int, list[np.ndarray]] = {}
    seeds = []
    for bag in map(Path, bags):
        seed = bag_seed(bag)
        if seed in EVALUATION_SEEDS and not allow_eval_seeds:
            raise TrainingError(f"{bag}: seed {seed} is an evaluation seed "
                                f"{EVALUATION_SEEDS}; train on other seeds (e.g. 101, 102)")
        seeds.append(seed)
        for label, (x, y) in labelled_candidates(bag, recipe, scheduler, workers).items():
            feats.setdefault(label, []).append(x)
            labels.setdefault(label, []).append(y)
    names = feature_names(recipe.feature_groups)
    classifiers = {}
    counts = {}
    for label in feats:
        x, y = np.concatenate(feats[label]), np.concatenate(labels[label])
        name = f"{LABEL_NAMES[label]}_orbital"
        counts[name] = {"samples": int(y.size), "positive": int(y.sum())}
        if y.size and 0 < y.sum() < y.size:
            classifiers[name] = BinaryClassifier(name, names, recipe.classifier).fit(x, y)
        else:
            # One class only (e.g. the paper's outcrop rule finds few candidates): no
            # classifier; prepare then keeps every candidate of the class (recorded).
            counts[name]["untrained"] = "candidates of one label only"
    if not classifiers:
        raise TrainingError(f"no classifier could be trained from {list(map(str, bags))}: "
                            f"{counts}")
    provenance = {
        "recipe": recipe.to_dict(),
        "training": {"bags": [str(Path(b).resolve()) for b in bags], "seeds": seeds,
                     "samples": counts,
                     "labelling": "candidate matches a truth ROI of its class (DESIGN.md rule)"},
    }
    save_classifiers(out, classifiers, provenance)
    return provenance
