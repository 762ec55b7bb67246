"""The far rocks' Rock Rover (Sec. 4.3), left one training bag out.

For each training bag, the far tracks the pipeline measures on it (truth trajectory as
odometry, every pair; :func:`roi_detector.training.far_rock_samples`, population
``measured``) with their features and truth labels; then, for each bag left out, a
classifier trained on the other bags decides the left-out bag's tracks. Compared:

- the rules alone (Sec. 4.2: the candidates);
- the paper's order: the rules, then the classifier on the candidates, the paper's
  PCA + kNN trained on the
  other bags' candidates or on every track they measured;
- the classifier in place of the size thresholds: it decides every track that passes
  the geometric tests (the pipeline's way), kNN or
  boosted trees (what ``roi_detector train`` fits), trained on every measured track.

Two questions about the training set, on the default recipe (boosted trees, every
measured track), each as more rows:

- ``--learning-curve N...``: trained on N of the other bags only (the N that follow the
  left-out one, in the order given): would more training bags find more rocks?
- ``--ignore-near M...``: the training tracks labelled false that lie within M m of a
  truth rock left out of training (neither label; ``roi_detector train`` and every
  other row train on every track): a track 1-2.5 m off its rock is a rock to its
  features and false to the matching rule.

Reported per row and score threshold: true and false tracks kept, their precision, and
the counted truth rocks (above the rover thresholds, within 15 m of the route) that a
kept true track finds.

Training and evaluation code: reads truth/. The samples of each bag are cached in
``--cache`` (default out/far_classifier/<bag name>.npz); a cached bag is not run again.
Usage (repository root, after ``source env.sh``)::

    python bench/far_classifier_bench.py bags/train_quick_s101 ... bags/train_quick_s112

Writes bench/results/NAME.{json,md} (``--name``, default far_classifier).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
THRESHOLDS = (0.3, 0.5, 0.7)


def samples(bag: str, cache: Path) -> dict:
    """The bag's measured far tracks (cached), with the counted truth rock each true one
    finds (-1: none) and whether it passes the geometric tests; and its map rock regions
    (``map_x``, ``map_y``) when the cache holds them (older caches do not)."""
    from roi_detector.far_rocks import FarRockConfig, far_feature_names
    from roi_detector.training import far_rock_samples, near_rock_distance
    from roi_detector.truth import Truth, match_to_truth
    from roi_network.records import ROCK

    path = cache / f"{Path(bag).name}.npz"
    if path.is_file():
        with np.load(path) as z:
            data = {k: z[k] for k in ("x", "y", "candidate", "xy_map", "map_x", "map_y")
                    if k in z}
    else:
        data = far_rock_samples(bag, lambda m: print(f"{bag}: {m}", file=sys.stderr))
        cache.mkdir(parents=True, exist_ok=True)
        np.savez(path, **data)
    truth = Truth.load(bag)
    counted = truth.counted() & (truth.rois["label"] == ROCK)
    j, _ = match_to_truth(data["xy_map"], truth.rois)
    data["counted_j"] = np.where((data["y"] == 1) & (j >= 0) & counted[np.clip(j, 0, None)],
                                 j, -1)
    data["n_counted"] = int(counted.sum())
    data["near_rock_m"] = near_rock_distance(data["xy_map"], truth)
    names, cfg = far_feature_names(), FarRockConfig()
    x = data["x"]
    geometry = (x[:, names.index("far_parallax_deg")], x[:, names.index("far_residual_px")],
                np.exp(x[:, names.index("far_log_nearest_m")]))
    # The rules' geometric tests, and those of a track the classifier decides.
    data["geometric"] = cfg.passes_geometry(*geometry)
    data["decidable"] = cfg.passes_geometry(*geometry, classified=True)
    return data


def leave_one_out(data: dict[str, dict], trained_on: str, kind: str, k: int = 5,
                  n_train: int | None = None, ignore_near_m: float | None = None) -> list:
    """Per left-out bag, the classifier's score of each of its tracks (trained on the
    other bags' candidates or every track they measured; on the ``n_train`` bags that
    follow it only, when given; without the false tracks within ``ignore_near_m`` of a
    truth rock, none when None: ``roi_detector train`` trains on every track)."""
    from roi_detector.classifier import BinaryClassifier, ClassifierConfig
    from roi_detector.far_rocks import far_feature_names
    names = far_feature_names()
    near_m = 0.0 if ignore_near_m is None else ignore_near_m
    scores = []
    keys = list(data)
    for i, out in enumerate(keys):
        # The n_train bags that follow the left-out one; all the others in their order.
        others = (keys[i + 1:] + keys[:i])[:n_train] if n_train else keys[:i] + keys[i + 1:]
        rest = [data[b] for b in others]
        pick = [(np.ones(len(d["y"]), bool) if trained_on == "measured" else d["candidate"])
                & ((d["y"] == 1) | ~(d["near_rock_m"] < near_m)) for d in rest]
        x = np.concatenate([d["x"][m] for d, m in zip(rest, pick, strict=True)])
        y = np.concatenate([d["y"][m] for d, m in zip(rest, pick, strict=True)])
        ok = np.isfinite(x).all(axis=1)
        clf = BinaryClassifier("far_rock_rover", names,
                               ClassifierConfig(n_components=8, k=k, kind=kind))
        clf.fit(x[ok], y[ok])
        scores.append(clf.predict_proba(np.nan_to_num(data[out]["x"])))
    return scores


def tally(data: dict[str, dict], keep: list) -> dict:
    """True and false tracks kept, and the counted rocks they find."""
    tk = fk = found = 0
    for d, m in zip(data.values(), keep, strict=True):
        tk += int((m & (d["y"] == 1)).sum())
        fk += int((m & (d["y"] == 0)).sum())
        found += len(set(d["counted_j"][m & (d["counted_j"] >= 0)].tolist()))
    return {"true_kept": tk, "false_kept": fk, "precision": round(tk / max(tk + fk, 1), 3),
            "counted_found": found}


#: (label, classified, trained on, kind, tracks decided): the rows after the rules alone.
#: Decided: the candidates, or the tracks that pass the rules' geometric tests
#: ("geometric", bearing spread >= ``min_parallax_deg`` included) or those of a track the
#: classifier decides ("decidable", the pipeline's: ``classified_min_parallax_deg``).
RECIPES = (("paper's order", "candidates", "candidates", "knn", "candidate"),
           ("paper's order", "candidates", "measured", "knn", "candidate"),
           ("in place of the size thresholds", "measured", "measured", "knn", "decidable"),
           ("in place of the size thresholds, spread >= 4 deg", "measured", "measured",
            "gradient_boosting", "geometric"),
           ("in place of the size thresholds", "measured", "measured", "gradient_boosting",
            "decidable"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("bags", nargs="+")
    ap.add_argument("--cache", type=Path, default=Path("out/far_classifier"))
    ap.add_argument("--name", default="far_classifier",
                    help="results file name (bench/results/NAME.{json,md})")
    ap.add_argument("--learning-curve", type=int, nargs="+", default=[], metavar="N",
                    help="also the default recipe trained on N of the other bags")
    ap.add_argument("--ignore-near", type=float, nargs="+", default=[], metavar="M",
                    help="also the default recipe without the false training tracks "
                         "within M m of a truth rock")
    args = ap.parse_args(argv)
    if any(n < 1 or n > len(args.bags) - 1 for n in args.learning_curve):
        ap.error(f"--learning-curve: N in 1..{len(args.bags) - 1} (the other bags)")
    if any(not np.isfinite(m) or m < 0 for m in args.ignore_near):
        ap.error("--ignore-near: M >= 0 m")
    data = {b: samples(b, args.cache) for b in args.bags}
    n_cand = sum(int(d["candidate"].sum()) for d in data.values())
    n_true = sum(int(d["y"][d["candidate"]].sum()) for d in data.values())
    n_counted = sum(d["n_counted"] for d in data.values())
    rules = {"recipe": "rules alone", "classified": "-", "trained_on": "-", "kind": "-",
             "threshold": None, **tally(data, [d["candidate"] for d in data.values()])}
    rows = [rules]
    # Every recipe, then the training set's questions on the default one (the last).
    label, classified, trained_on, kind, decided = RECIPES[-1]
    runs = ([(recipe, {}) for recipe in RECIPES]
            + [((f"{label}, trained on {n} bags", classified, trained_on, kind, decided),
                {"n_train": n}) for n in args.learning_curve]
            + [((f"{label}, false tracks within {m:g} m of a rock not trained on" if m
                 else f"{label}, trained on every track", classified, trained_on, kind,
                 decided), {"ignore_near_m": m}) for m in args.ignore_near])
    for (name, classified, trained_on, kind, decided), kw in runs:
        scores = leave_one_out(data, trained_on, kind, **kw)
        for th in THRESHOLDS:
            keep = [d[decided] & (sc > th) for d, sc in zip(data.values(), scores, strict=True)]
            rows.append({"recipe": name, "classified": classified, "trained_on": trained_on,
                         "kind": kind, "threshold": th, **tally(data, keep)})
    report = {"command": "python bench/far_classifier_bench.py " + " ".join(args.bags)
              + (f" --cache {args.cache}" if args.cache != ap.get_default("cache") else "")
              + (f" --name {args.name}" if args.name != ap.get_default("name") else "")
              + (" --learning-curve " + " ".join(map(str, args.learning_curve))
                 if args.learning_curve else "")
              + (" --ignore-near " + " ".join(f"{m:g}" for m in args.ignore_near)
                 if args.ignore_near else ""),
              "bags": {Path(b).name: {"measured": len(d["y"]), "rocks": int(d["y"].sum()),
                                      "candidates": int(d["candidate"].sum()),
                                      "true_candidates": int(d["y"][d["candidate"]].sum()),
                                      "counted": d["n_counted"]}
                       for b, d in data.items()},
              "candidates": n_cand, "true_candidates": n_true, "counted": n_counted,
              "rules_precision": round(n_true / max(n_cand, 1), 3), "rows": rows}
    n_tracks = sum(len(d["y"]) for d in data.values())
    n_rocks = sum(int(d["y"].sum()) for d in data.values())
    lines = ["# The far rocks' Rock Rover, left one training bag out", "",
             f"Command: `{report['command']}`. Truth odometry, every pair. "
             f"{len(data)} bags: {n_tracks} measured far tracks ({n_rocks} of them match a "
             f"truth rock), {n_cand} candidates (the rules passed), {n_true} of them rocks; "
             f"{n_counted} counted truth rocks (above the rover thresholds, within 15 m of "
             "the route). Each bag's tracks are decided by a classifier trained on the "
             "other bags: kNN is the paper's (standardise, PCA to 8, k = 5); "
             "gradient_boosting is scikit-learn's histogram gradient boosting, classes "
             "weighted. *decides*: the candidates (after the rules, the paper's order) or "
             "every track that passes the geometric tests (views, ray residual, nearest "
             "range; the bearing spread as the row says), in place of the size "
             "thresholds.", "",
             "| recipe | decides | trained on | kind | score > | true kept | false kept "
             "| precision | counted rocks found |", "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        th = "-" if r["threshold"] is None else r["threshold"]
        lines.append(f"| {r['recipe']} | {r['classified']} | {r['trained_on']} | {r['kind']} "
                     f"| {th} | {r['true_kept']} | {r['false_kept']} | {r['precision']:.0%} "
                     f"| {r['counted_found']} / {n_counted} |")
    md = "\n".join(lines) + "\n"
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"{args.name}.json").write_text(json.dumps(report, indent=1) + "\n")
    (RESULTS / f"{args.name}.md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
