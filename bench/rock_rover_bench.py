"""The two Rock Rovers (Sec. 4.3) trained on one set of drives and judged on held-out ones.

Does a larger or different training set help the elevation_map method's classifiers? For
each bag (training and held-out alike): the map's rock regions and the far tracks the
pipeline measures on it, with their features and truth labels (truth trajectory as the
odometry; :func:`roi_detector.training.far_rock_samples`, cached as
``far_classifier_bench.py`` caches them). Then, for each training set (``--train``, and
``--train`` plus ``--add`` when given), both classifiers are trained as ``roi_detector
train`` trains them (:func:`roi_detector.training.train_rock_rovers`: boosted trees,
every measured far track) and decide the held-out bags' samples at the pipeline's
thresholds (``map_rock_min_score``, ``FarRockConfig.min_score``):

- map rock regions kept, true and false (a region is true when it matches a truth rock by
  DESIGN.md's rule; the LN reports a region while its latest score is above the
  threshold, and these are the regions at their latest measurement);
- far tracks kept among those the classifier decides (they pass the geometric tests),
  true and false, and the counted truth rocks (above the rover thresholds, within 15 m
  of the route) a kept true track finds.

These are the classifiers' decisions on the samples, not the LN: ``roi_bench.py`` measures
the LN a model gives. Training and evaluation code: reads truth/. Usage (repository root,
after ``source env.sh``)::

    python bench/rock_rover_bench.py --train bags/train_quick_s101 ... \\
        --add bags/train_1km_s120 bags/train_1km_s121 --eval bags/quick bags/train_1km_s113

Writes bench/results/rock_rover_NAME.{json,md} (``--name``, default ``eval``).
"""

from __future__ import annotations

import argparse
import json
import sys
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from far_classifier_bench import samples

RESULTS = Path(__file__).resolve().parent / "results"


def _load(bag: str, cache: Path) -> dict:
    data = samples(bag, cache)
    if "map_x" not in data:
        raise SystemExit(f"{cache / Path(bag).name}.npz: a cache without the map's rock "
                         "regions (an older cache); delete it to sample the bag "
                         "again")
    return data


def fit(data: list[dict]):
    """Both Rock Rovers, trained as ``roi_detector train`` trains them
    (:func:`roi_detector.training.fit_rock_rovers` on every far track)."""
    from roi_detector.training import fit_rock_rovers

    return fit_rock_rovers(np.concatenate([d["x"] for d in data]),
                           np.concatenate([d["y"] for d in data]),
                           np.concatenate([d["map_x"] for d in data]),
                           np.concatenate([d["map_y"] for d in data]))


def judge(far, rocks, d: dict) -> dict:
    """The held-out bag's samples kept by the two classifiers (module docstring)."""
    from roi_detector.elevation_map import ElevationMapConfig
    from roi_detector.far_rocks import FarRockConfig

    row = {}
    if len(d["map_y"]):
        kept = rocks.predict_proba(d["map_x"]) > ElevationMapConfig().map_rock_min_score
    else:
        kept = np.zeros(0, bool)
    row["map_true"] = int((d["map_y"] == 1).sum())
    row["map_true_kept"] = int((kept & (d["map_y"] == 1)).sum())
    row["map_false"] = int((d["map_y"] == 0).sum())
    row["map_false_kept"] = int((kept & (d["map_y"] == 0)).sum())
    dec = d["decidable"]
    kept = dec & (far.predict_proba(np.nan_to_num(d["x"])) > FarRockConfig().min_score)
    row["far_true"] = int((dec & (d["y"] == 1)).sum())
    row["far_true_kept"] = int((kept & (d["y"] == 1)).sum())
    row["far_false"] = int((dec & (d["y"] == 0)).sum())
    row["far_false_kept"] = int((kept & (d["y"] == 0)).sum())
    row["far_counted_found"] = len(set(d["counted_j"][kept & (d["counted_j"] >= 0)].tolist()))
    row["counted_rocks"] = d["n_counted"]
    return row


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--train", nargs="+", required=True, help="training bags")
    ap.add_argument("--add", nargs="+", default=[], help="bags added to --train (a 2nd row)")
    ap.add_argument("--eval", nargs="+", required=True, help="held-out bags")
    ap.add_argument("--cache", type=Path, default=Path("out/far_classifier"))
    ap.add_argument("--name", default="eval")
    ap.add_argument("--jobs", type=int, default=2, help="bags sampled at a time")
    a = ap.parse_args(argv)
    overlap = set(a.eval) & set(a.train + a.add)
    if overlap:
        ap.error(f"held-out bags also in training: {sorted(overlap)}")
    bags = a.train + a.add + a.eval
    for bag in bags:
        if not (Path(bag) / "truth").is_dir():
            ap.error(f"{bag}: no truth/ directory (a bag directory made by atacama_sim)")
    with ProcessPoolExecutor(max(1, a.jobs)) as pool:
        loaded = dict(zip(bags, pool.map(_load, bags, [a.cache] * len(bags)), strict=True))
    sets = [("train", a.train)] + ([("train + add", a.train + a.add)] if a.add else [])
    report = {"command": "python bench/rock_rover_bench.py " + " ".join(sys.argv[1:]
                                                                         if argv is None
                                                                         else argv),
              "train": a.train, "add": a.add, "eval": a.eval, "rows": []}
    for label, names in sets:
        far, rocks, n = fit([loaded[b] for b in names])
        for bag in a.eval:
            report["rows"].append({"trained_on": label, "bag": Path(bag).name, **n,
                                   **judge(far, rocks, loaded[bag])})
    RESULTS.mkdir(exist_ok=True)
    out = RESULTS / f"rock_rover_{a.name}"
    out.with_suffix(".json").write_text(json.dumps(report, indent=1) + "\n")
    lines = [f"# rock_rover_bench: {a.name}", "", f"Command: `{report['command']}`", "",
             "| trained on | bag | map rocks kept | false map rocks kept | far rock tracks "
             "kept | false far tracks kept | counted rocks a kept far track finds |",
             "|---|---|---|---|---|---|---|"]
    for label, _ in sets:
        rows = [r for r in report["rows"] if r["trained_on"] == label]
        tot = {k: sum(r[k] for r in rows) for k in rows[0] if isinstance(rows[0][k], int)}
        for r in [*rows, {**tot, "bag": "**all**"}]:
            lines.append(f"| {label} ({rows[0]['map_samples']} map regions, "
                         f"{rows[0]['far_samples']} far tracks) | {r['bag']} | "
                         f"{r['map_true_kept']}/{r['map_true']} | "
                         f"{r['map_false_kept']}/{r['map_false']} | "
                         f"{r['far_true_kept']}/{r['far_true']} | "
                         f"{r['far_false_kept']}/{r['far_false']} | "
                         f"{r['far_counted_found']}/{r['counted_rocks']} |")
    out.with_suffix(".md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
