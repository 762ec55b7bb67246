"""Training of the rover classifiers on training bags (reads truth: training code only).

Every candidate of every ``every``-th stereo pair is labelled by DESIGN.md's matching
rule: its base_link centre, placed in map with the truth pose of its pair, matches a
truth ROI (rois.geojson) within max(1 m, half the truth major axis), and takes that ROI's
class; otherwise it is a negative for both classifiers.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from roi_detector.inputs import BadInput, load_rover_params, read_stereo_frames
from roi_detector.rover_classifier import features_of, save_rover_model, train_classifiers
from roi_detector.rover_pipeline import RoverConfig, RoverDetector
from roi_detector.truth import Truth, match_to_truth


def labelled_candidates(bag_dir: str, feature_sets: tuple[str, ...], every: int = 2,
                        cfg: RoverConfig | None = None, log=print) -> dict:
    """Features (per feature set) and truth labels of every candidate of a bag."""
    cfg = cfg or RoverConfig()
    params = load_rover_params(Path(bag_dir) / "rover.yaml")
    truth = Truth.load(bag_dir)
    bad = BadInput(lambda m: log(f"{bag_dir}: {m}"))
    det = RoverDetector(params["base_to_left_camera"], None, cfg, bad)
    xs: dict[str, list] = {fs: [] for fs in feature_sets}
    labels, stamps = [], []
    for frame in read_stereo_frames(bag_dir, bad, every=every):
        cands, metrics = det.candidates(frame)
        if not cands:
            continue
        pts = truth.base_to_map(frame.stamp_ns * 1e-9, np.array([c.center for c in cands]))
        if pts is None:
            continue
        j, _ = match_to_truth(pts[:, :2], truth.rois)
        labels.append(np.where(j >= 0, truth.rois["label"][np.clip(j, 0, None)], 0))
        stamps.append(np.full(len(cands), frame.stamp_ns))
        for fs in feature_sets:
            xs[fs].append(features_of(frame.left, cands, metrics, fs))
    return {"x": {fs: np.concatenate(v) if v else None for fs, v in xs.items()},
            "y": np.concatenate(labels) if labels else np.zeros(0, int),
            "stamps": np.concatenate(stamps) if stamps else np.zeros(0, int)}


def train_rover_model(bags: list[str], out: str, every: int = 2, k: int = 5,
                      feature_set: str = "stereo") -> dict:
    """Train Rock Rover and Outcrop Rover on ``bags`` and write the model to ``out``."""
    t0 = time.perf_counter()
    x, y = [], []
    for bag in bags:
        data = labelled_candidates(bag, (feature_set,), every)
        if data["x"][feature_set] is not None:
            x.append(data["x"][feature_set])
            y.append(data["y"])
    if not x:
        raise ValueError(f"no candidates in {bags}: nothing to train on")
    xa, ya = np.concatenate(x), np.concatenate(y)
    finite = np.isfinite(xa).all(axis=1)
    xa, ya = xa[finite], ya[finite]
    clfs = train_classifiers(xa, ya, feature_set, k=k)
    seeds = []
    for bag in bags:
        try:
            import yaml

            w = yaml.safe_load((Path(bag) / "world.yaml").read_text())
            seeds.append(w.get("seed", w.get("world", {}).get("seed")))
        except Exception:
            seeds.append(None)
    summary = {"bags": [str(Path(b).resolve()) for b in bags], "seeds": seeds,
               "every": every, "k": k, "feature_set": feature_set, "threshold": 0.5,
               "samples": len(ya), "rocks": int((ya == 1).sum()),
               "outcrops": int((ya == 2).sum()), "negatives": int((ya == 0).sum()),
               "train_s": round(time.perf_counter() - t0, 1),
               "command": f"roi_detector train {' '.join(bags)} --out {out} --every {every}"}
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    save_rover_model(out, clfs, summary)
    return summary
