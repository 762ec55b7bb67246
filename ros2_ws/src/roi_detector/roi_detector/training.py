"""Training of the rover classifiers on training bags (reads truth: training code only).

Labels follow DESIGN.md's matching rule: a candidate placed in map with the truth poses
matches a truth ROI (rois.geojson) within max(1 m, half the truth major axis) and takes
that ROI's class; otherwise it is a negative.

- elevation_map method (default): the far rocks' Rock Rover (boosted trees), on every
  measured far track of a drive run with the truth trajectory as odometry
  (:func:`far_rock_samples`); and, from the same drive, the map rocks' Rock Rover (boosted
  trees), on every rock region of the elevation map found in at least ``min_rounds``
  detection rounds, at its latest measurement (:func:`map_rock_samples`); and the map
  outcrops' Outcrop Rover (the paper's PCA + kNN), on every outcrop region of that map
  (the outcrop rule's candidates) found in at least ``min_rounds`` rounds, at its kept
  measurement (:func:`map_outcrop_samples`).
- per_pair method: Rock Rover and Outcrop Rover, on every candidate of every
  ``every``-th stereo pair (:func:`labelled_candidates`).
"""

from __future__ import annotations

import json
import tempfile
import time
from pathlib import Path

import numpy as np

from roi_detector.camera_poses import PairPoses
from roi_detector.classifier import BinaryClassifier, ClassifierConfig
from roi_detector.elevation_map import MAP_OUTCROP_FEATURES, MAP_OUTCROP_RULE, MAP_ROCK_FEATURES
from roi_detector.evaluation import match_nodes, true_nodes
from roi_detector.far_rocks import far_feature_names
from roi_detector.inputs import BadInput, load_rover_params, read_stereo_frames
from roi_detector.local_network_build import build_ln
from roi_detector.rover_classifier import (
    FAR_ROCK_CLASSIFIER,
    MAP_OUTCROP_CLASSIFIER,
    MAP_ROCK_CLASSIFIER,
    features_of,
    save_rover_model,
    train_classifiers,
)
from roi_detector.rover_pipeline import (
    DriveMapper,
    RoverConfig,
    RoverDetector,
    at_working_resolution,
    far_rock_records,
)
from roi_detector.truth import Truth, match_to_truth
from roi_network.records import OUTCROP, ROCK, xy

#: The Rock Rovers' classifier (far rocks' and map rocks'): boosted trees.
ROCK_ROVER_KIND = "gradient_boosting"
#: The map outcrops' Outcrop Rover's classifier: the paper's PCA + kNN.
OUTCROP_KIND = "knn"
#: The far-track population the far rocks' Rock Rover is trained on (every measured
#: track, as it decides at run time), recorded in the model.
FAR_POPULATION = "measured"


def labelled_candidates(bag_dir: str, feature_sets: tuple[str, ...], every: int = 2,
                        cfg: RoverConfig | None = None, log=print) -> dict:
    """Features (per feature set) and truth labels of every candidate of a bag."""
    cfg = cfg or RoverConfig()
    params = load_rover_params(Path(bag_dir) / "rover.yaml")
    truth = Truth.load(bag_dir)
    bad = BadInput(lambda m: log(f"{bag_dir}: {m}"))
    det = RoverDetector(params["base_to_left_camera"], None, cfg, bad)
    poses = PairPoses(params, bad, strict=True)
    xs: dict[str, list] = {fs: [] for fs in feature_sets}
    labels, stamps = [], []
    for frame in read_stereo_frames(bag_dir, bad, every=every,
                                    joints=poses if poses.has_mast else None):
        cam = poses.pose(frame.stamp_ns * 1e-9)
        if cam is None:  # a mast's pair the joint states cannot place: counted
            continue
        # The features are taken from the image the candidates were found in.
        frame = at_working_resolution(frame, cfg.working_fx_px)
        cands, metrics = det.candidates(frame, cam if poses.has_mast else None)
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
    summary = {"method": "per_pair", "bags": [str(Path(b).resolve()) for b in bags],
               "seeds": _seeds(bags),
               "every": every, "k": k, "feature_set": feature_set, "threshold": 0.5,
               "working_fx_px": RoverConfig().working_fx_px,
               "samples": len(ya), "rocks": int((ya == 1).sum()),
               "outcrops": int((ya == 2).sum()), "negatives": int((ya == 0).sum()),
               "train_s": round(time.perf_counter() - t0, 1),
               "command": f"roi_detector train {' '.join(bags)} --out {out} --method "
                          f"per_pair --every {every}"}
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    save_rover_model(out, clfs, summary)
    return summary


def drive_with_truth_odometry(bag_dir: str, mapper: DriveMapper, log=print,
                              describe: bool = False) -> tuple[Truth, dict]:
    """Run the pipeline over a bag with its truth trajectory (re-expressed in odom) as the
    odometry, filling ``mapper`` (built with its config and model): detection geometry
    alone. Returns the bag's truth and
    :func:`~roi_detector.local_network_build.build_ln`'s stats."""
    truth = Truth.load(bag_dir)
    with tempfile.TemporaryDirectory() as tmp:
        odom = Path(tmp) / "truth_odom.tum"
        truth.write_odom_tum(odom)
        _, stats = build_ln(bag_dir, str(odom), None, mapper.cfg,
                            log=lambda m: log(f"{bag_dir}: {m}"), mapper=mapper,
                            describe=describe)
    return truth, stats


def far_rock_samples(bag_dir: str, log=print,
                     working_fx_px: float = RoverConfig().working_fx_px) -> dict:
    """The far tracks of a drive (truth trajectory as the odometry, every pair): every
    measured track, with its :func:`~roi_detector.far_rocks.far_rock_features`, whether
    it matches a truth rock, whether it is a candidate (the rules passed), and its
    position in map.

    Returns:
        dict with ``x`` (N, F) float32, ``y`` (N,) 0/1, ``candidate`` (N,) bool,
        ``xy_map`` (N, 2), ``near_rock_m`` (N,) (:func:`near_rock_distance`); the same
        drive's map rocks (:func:`map_rock_samples`) as ``map_x``, ``map_y``; and its map
        outcrops (:func:`map_outcrop_samples`) as ``outcrop_x``, ``outcrop_y``, and
        whether the map reports each (``outcrop_reported``).
    """
    # No classifier: every track is measured and described, and every map ROI reported,
    # whatever a model would say.
    mapper = DriveMapper(RoverConfig(working_fx_px=working_fx_px))
    truth, _ = drive_with_truth_odometry(bag_dir, mapper, log, describe=True)
    tracks = [r for r in mapper.far.measured if r.features is not None]
    n_feat = len(far_feature_names())
    map_x, map_y = map_rock_samples(mapper.map, truth)
    outcrop_x, outcrop_y, reported = map_outcrop_samples(mapper.map, truth)
    maps = {"map_x": map_x, "map_y": map_y, "outcrop_x": outcrop_x, "outcrop_y": outcrop_y,
            "outcrop_reported": reported}
    if not tracks:
        return {"x": np.zeros((0, n_feat), np.float32), "y": np.zeros(0, np.uint8),
                "candidate": np.zeros(0, bool), "xy_map": np.zeros((0, 2)),
                "near_rock_m": np.zeros(0), **maps}
    rec = far_rock_records(tracks)
    pts, j = match_nodes(rec, truth)
    y = true_nodes(rec, truth.rois, j, ROCK).astype(np.uint8)
    return {"x": np.stack([r.features for r in tracks]), "y": y,
            "candidate": np.array([r.candidate for r in tracks]), "xy_map": pts[:, :2],
            "near_rock_m": near_rock_distance(pts[:, :2], truth), **maps}


def map_rock_samples(emap, truth: Truth) -> tuple[np.ndarray, np.ndarray]:
    """The rock regions of a drive's elevation map (an :class:`ElevationMap` filled with
    the truth trajectory as odometry) found in at least ``min_rounds`` detection rounds:
    their :data:`~roi_detector.elevation_map.MAP_ROCK_FEATURES` at their latest
    measurement (N, F) and whether each matches a truth rock (N,) 0/1 (DESIGN.md's
    rule, the LN's placement)."""
    x, y, _ = _map_region_samples(emap, truth, ROCK, len(MAP_ROCK_FEATURES))
    return x, y


def map_outcrop_samples(emap, truth: Truth) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The outcrop regions of a drive's elevation map (filled with the truth trajectory
    as odometry) found in at least ``min_rounds`` detection rounds: their
    :data:`~roi_detector.elevation_map.MAP_OUTCROP_FEATURES` at their kept measurement
    (N, F), whether each matches a truth outcrop (N,) 0/1 (DESIGN.md's rule), and
    whether the map reports it, its score aside (N,) bool (``ElevationMap.persists``)."""
    return _map_region_samples(emap, truth, OUTCROP, len(MAP_OUTCROP_FEATURES))


def _map_region_samples(emap, truth: Truth, label: int,
                        n_features: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The map's regions of class ``label`` with features, found in at least
    ``min_rounds`` rounds: features (N, ``n_features``), whether each matches a truth ROI
    of that class (N,) 0/1, whether the map's persistence test passes it (N,) bool."""
    found = [r for r in emap.rois if r.label == label and r.features is not None
             and r.rounds >= emap.cfg.min_rounds]
    if not found:
        return (np.zeros((0, n_features), np.float32), np.zeros(0, np.uint8),
                np.zeros(0, bool))
    rec = emap.to_records(found)
    _, j = match_nodes(rec, truth)
    return (np.stack([r.features for r in found]).astype(np.float32),
            true_nodes(rec, truth.rois, j, label).astype(np.uint8),
            np.array([emap.persists(r) for r in found], bool))


def near_rock_distance(xy_map: np.ndarray, truth: Truth) -> np.ndarray:
    """Distance (m) from each of (N, 2) map positions to the nearest truth rock (inf
    when the catalogue holds none)."""
    from scipy.spatial import cKDTree

    rocks = truth.rois[truth.rois["label"] == ROCK]
    if not len(rocks) or not len(xy_map):
        return np.full(len(xy_map), np.inf)
    return cKDTree(xy(rocks)).query(np.asarray(xy_map, float))[0]


def _seeds(bags: list[str]) -> list:
    seeds = []
    for bag in bags:
        try:
            import yaml

            w = yaml.safe_load((Path(bag) / "world.yaml").read_text())
            seeds.append(w.get("config", {}).get("seed", w.get("seed")))
        except Exception:
            seeds.append(None)
    return seeds


def drive_samples(bag: str, working_fx_px: float = RoverConfig().working_fx_px,
                  cache: str | Path | None = None, log=print) -> dict:
    """:func:`far_rock_samples` of a drive, kept in ``cache`` (a directory; None: none)
    as ``<bag name>.npz`` with the settings they were taken with, and read from there
    when those settings match (re-taken, and overwritten, when they do not). A cache
    does not know the code: empty it when the detector changes."""
    settings = {"population": FAR_POPULATION, "working_fx_px": float(working_fx_px),
                "outcrops": MAP_OUTCROP_RULE}
    path = None if cache is None else Path(cache) / f"{Path(bag).name}.npz"
    if path is not None and path.is_file():
        try:
            with np.load(path) as z:
                if json.loads(str(z["settings"])) == settings:
                    return {k: z[k] for k in z.files if k != "settings"}
        except (OSError, ValueError, KeyError) as e:
            log(f"{path}: not a samples cache ({e}): taking the samples again")
    data = far_rock_samples(bag, log, working_fx_px)
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.stem + ".tmp.npz")
        np.savez(tmp, settings=json.dumps(settings), **data)
        tmp.replace(path)
    return data


def _drive_samples_quiet(bag: str, working_fx_px: float, cache: str | None) -> dict:
    return drive_samples(bag, working_fx_px, cache, lambda m: None)


def fit_rock_rovers(far_x: np.ndarray, far_y: np.ndarray, map_x: np.ndarray,
                    map_y: np.ndarray, k: int = 5, kind: str = ROCK_ROVER_KIND,
                    where: str = "the drives") -> tuple:
    """The two Rock Rovers fitted on their samples: the far rocks' on the far tracks
    ``far_x``, ``far_y`` (those with a non-finite feature left out), the map rocks' on the
    map's rock regions ``map_x``, ``map_y``.

    Returns:
        (far rocks' classifier, map rocks' classifier, counts: ``far_samples``,
        ``far_rocks``, ``map_samples``, ``map_rocks``).

    Raises:
        ValueError: either sample set lacks rocks or non-rocks (``where`` names the
            drives).
    """
    finite = np.isfinite(far_x).all(axis=1)
    far_x, far_y = far_x[finite], far_y[finite]
    if len(np.unique(far_y)) < 2:
        raise ValueError(f"far-rock candidates of {where}: {len(far_y)} samples, not both "
                         "rocks and non-rocks: nothing to train on")
    if len(np.unique(map_y)) < 2:
        raise ValueError(f"map rock regions of {where}: {len(map_y)} samples, not both rocks "
                         "and non-rocks: nothing to train on")
    cfg = ClassifierConfig(n_components=8, k=k, kind=kind)
    far = BinaryClassifier(FAR_ROCK_CLASSIFIER, far_feature_names(), cfg).fit(far_x, far_y)
    rocks = BinaryClassifier(MAP_ROCK_CLASSIFIER, MAP_ROCK_FEATURES, cfg).fit(map_x, map_y)
    return far, rocks, {"far_samples": len(far_y), "far_rocks": int(far_y.sum()),
                        "map_samples": len(map_y), "map_rocks": int(map_y.sum())}


def fit_outcrop_rover(x: np.ndarray, y: np.ndarray, k: int = 5,
                      kind: str = OUTCROP_KIND) -> BinaryClassifier | None:
    """The map outcrops' Outcrop Rover fitted on map outcrop regions ``x``, ``y``
    (:func:`map_outcrop_samples`); None when they are not both outcrops and non-outcrops
    (drives that pass no outcrop, or whose every candidate is one)."""
    if len(np.unique(y)) < 2:
        return None
    cfg = ClassifierConfig(n_components=8, k=k, kind=kind)
    return BinaryClassifier(MAP_OUTCROP_CLASSIFIER, MAP_OUTCROP_FEATURES, cfg).fit(x, y)


def train_rock_rovers(bags: list[str], out: str, k: int = 5, log=print, jobs: int = 1,
                      working_fx_px: float = RoverConfig().working_fx_px,
                      cache: str | None = None) -> dict:
    """Train the elevation_map method's classifiers on the drives of ``bags`` (``jobs``
    bags at a time, each in its own process) and write them to ``out``: the far rocks'
    Rock Rover on every measured far track and the map rocks' on the map's rock regions
    (:func:`map_rock_samples`), as :data:`ROCK_ROVER_KIND`; the map outcrops' Outcrop
    Rover on the map's outcrop regions (:func:`map_outcrop_samples`), as
    :data:`OUTCROP_KIND` with ``k`` neighbours, left out, with a log line, when those are
    not both outcrops and non-outcrops. The model records the outcrop rule
    (:data:`~roi_detector.elevation_map.MAP_OUTCROP_RULE`) and ``working_fx_px``.
    ``cache``: a directory that keeps each drive's samples (:func:`drive_samples`)."""
    t0 = time.perf_counter()
    x, y, mx, my, ox, oy = [], [], [], [], [], []
    if jobs > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(jobs) as pool:
            n = len(bags)
            samples = list(pool.map(_drive_samples_quiet, bags, [working_fx_px] * n,
                                    [cache] * n))
    else:
        samples = [drive_samples(bag, working_fx_px, cache, log) for bag in bags]
    for bag, data in zip(bags, samples, strict=True):
        log(f"{bag}: {len(data['y'])} far tracks, {int(data['y'].sum())} "
            f"rocks; {int(data['candidate'].sum())} candidates; {len(data['map_y'])} map "
            f"rock regions, {int(data['map_y'].sum())} rocks; {len(data['outcrop_y'])} map "
            f"outcrop regions, {int(data['outcrop_y'].sum())} outcrops")
        mx.append(data["map_x"])
        my.append(data["map_y"])
        ox.append(data["outcrop_x"])
        oy.append(data["outcrop_y"])
        x.append(data["x"])
        y.append(data["y"])
    clf, map_clf, n = fit_rock_rovers(np.concatenate(x), np.concatenate(y),
                                      np.concatenate(mx), np.concatenate(my), k,
                                      where=str(bags))
    ox, oy = np.concatenate(ox), np.concatenate(oy)
    outcrop_clf = fit_outcrop_rover(ox, oy, k)
    if outcrop_clf is None:
        log(f"no map outcrops' Outcrop Rover: {len(oy)} outcrop regions, {int(oy.sum())} "
            "of them outcrops, not both outcrops and non-outcrops")
    summary = {"method": "elevation_map", "bags": [str(Path(b).resolve()) for b in bags],
               "seeds": _seeds(bags), "kind": ROCK_ROVER_KIND, "k": k,
               "threshold": RoverConfig().far.min_score,
               "population": FAR_POPULATION, "working_fx_px": working_fx_px,
               "samples": n["far_samples"],
               "rocks": n["far_rocks"], "negatives": n["far_samples"] - n["far_rocks"],
               "map_rock_samples": n["map_samples"], "map_rocks": n["map_rocks"],
               "map_rock_threshold": RoverConfig().elevation_map.map_rock_min_score,
               "map_outcrop_samples": len(oy), "map_outcrops": int(oy.sum()),
               "map_outcrop_rule": dict(MAP_OUTCROP_RULE), "map_outcrop_kind": OUTCROP_KIND,
               "train_s": round(time.perf_counter() - t0, 1),
               "samples_cache": None if cache is None else str(cache),
               "command": f"roi_detector train {' '.join(bags)} --out {out} "
                          f"--working-fx {working_fx_px:g}"}
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    classifiers = {FAR_ROCK_CLASSIFIER: clf, MAP_ROCK_CLASSIFIER: map_clf}
    if outcrop_clf is not None:
        classifiers[MAP_OUTCROP_CLASSIFIER] = outcrop_clf
    save_rover_model(out, classifiers, summary)
    return summary
