"""The far rocks' Rock Rover (the paper's PCA + kNN, Sec. 4.3), left one training bag out.

For each training bag, the far tracks the pipeline measures on it (truth trajectory as
odometry, every pair; :func:`roi_detector.training.far_rock_samples`, population
``measured``) with their features and truth labels; then, for each bag left out, the
classifier trained on the other bags (on their candidates, or on every measured track)
votes on the left-out bag's candidates. Reported per training population and vote
threshold: true candidates kept / true candidates, false kept / false, and the
candidates' rock precision before and after.

Training and evaluation code: reads truth/. The samples of each bag are cached in
``--cache`` (default out/far_classifier/<bag name>.npz); a cached bag is not run again.
Usage (repository root, after ``source env.sh``)::

    python bench/far_classifier_bench.py bags/train_quick_s101 ... bags/train_quick_s112

Writes bench/results/far_classifier.{json,md}.
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
    """The bag's measured far tracks (cached)."""
    from roi_detector.training import far_rock_samples

    path = cache / f"{Path(bag).name}.npz"
    if path.is_file():
        with np.load(path) as z:
            return {k: z[k] for k in ("x", "y", "candidate")}
    data = far_rock_samples(bag, lambda m: print(f"{bag}: {m}", file=sys.stderr), "measured")
    cache.mkdir(parents=True, exist_ok=True)
    np.savez(path, **data)
    return data


def leave_one_out(data: dict[str, dict], population: str, k: int = 5) -> dict:
    """Vote shares on each left-out bag's candidates, and their labels."""
    from roi_detector.classifier import BinaryClassifier, ClassifierConfig
    from roi_detector.far_rocks import far_feature_names

    names = far_feature_names()
    proba, labels = [], []
    for out in data:
        rest = [d for b, d in data.items() if b != out]
        pick = [np.ones(len(d["y"]), bool) if population == "measured" else d["candidate"]
                for d in rest]
        x = np.concatenate([d["x"][m] for d, m in zip(rest, pick, strict=True)])
        y = np.concatenate([d["y"][m] for d, m in zip(rest, pick, strict=True)])
        ok = np.isfinite(x).all(axis=1)
        clf = BinaryClassifier("far_rock_rover", names, ClassifierConfig(n_components=8, k=k))
        clf.fit(x[ok], y[ok])
        cand = data[out]["candidate"]
        proba.append(clf.predict_proba(data[out]["x"][cand]))
        labels.append(data[out]["y"][cand] == 1)
    return {"proba": np.concatenate(proba), "rock": np.concatenate(labels)}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("bags", nargs="+")
    ap.add_argument("--cache", type=Path, default=Path("out/far_classifier"))
    args = ap.parse_args(argv)
    data = {b: samples(b, args.cache) for b in args.bags}
    n_cand = sum(int(d["candidate"].sum()) for d in data.values())
    n_true = sum(int(d["y"][d["candidate"]].sum()) for d in data.values())
    rows = []
    for population in ("candidates", "measured"):
        r = leave_one_out(data, population)
        for th in THRESHOLDS:
            keep = r["proba"] > th
            tk, fk = int((keep & r["rock"]).sum()), int((keep & ~r["rock"]).sum())
            rows.append({"population": population, "threshold": th, "true_kept": tk,
                         "false_kept": fk, "precision": round(tk / max(tk + fk, 1), 3)})
    report = {"command": "python bench/far_classifier_bench.py " + " ".join(args.bags),
              "bags": {Path(b).name: {"measured": len(d["y"]), "rocks": int(d["y"].sum()),
                                      "candidates": int(d["candidate"].sum()),
                                      "true_candidates": int(d["y"][d["candidate"]].sum())}
                       for b, d in data.items()},
              "candidates": n_cand, "true_candidates": n_true,
              "rules_precision": round(n_true / max(n_cand, 1), 3), "rows": rows}
    lines = ["# The far rocks' Rock Rover, left one training bag out", "",
             f"Command: `{report['command']}`. Truth odometry, every pair. "
             f"{len(data)} bags: {sum(len(d['y']) for d in data.values())} measured far "
             f"tracks, {n_cand} candidates (the rules passed), {n_true} of them rocks "
             f"(precision of the rules alone {report['rules_precision']:.0%}). The "
             "classifier (standardise, PCA to 8, kNN k = 5) is trained on the other bags' "
             "candidates or on every track they measured, and votes on the left-out "
             "bag's candidates.", "",
             "| trained on | vote share > | true kept | false kept | precision |",
             "|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['population']} | {r['threshold']} | {r['true_kept']} / {n_true} "
                     f"| {r['false_kept']} / {n_cand - n_true} | {r['precision']:.0%} |")
    md = "\n".join(lines) + "\n"
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "far_classifier.json").write_text(json.dumps(report, indent=1) + "\n")
    (RESULTS / "far_classifier.md").write_text(md)
    print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
