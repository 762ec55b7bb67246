"""The map outcrops' Outcrop Rover, left one training drive out; results in
bench/results/outcrop_rover_<name>.{json,md}.

For each drive: its elevation map's outcrop regions under an outcrop rule (truth
trajectory as odometry; :func:`roi_detector.training.drive_samples`, kept in ``--cache``,
the directory ``roi_detector train --cache`` uses), labelled by DESIGN.md's matching rule.
Each drive's regions are scored by an Outcrop Rover fitted on the other drives' (boosted
trees, and the paper's PCA + kNN), and the bench counts, per score threshold, the regions
kept and refused among those the map reports (found in at least half of the rounds that
examined them), true and false. It also reports how each feature alone separates the
two (the area under its ROC curve, over every region).

Training and evaluation code: reads truth/.

Usage (from the repository root, after ``source env.sh``)::

    python bench/outcrop_rover_bench.py bags/train_quick_s101 ... bags/train_quick_s112 \\
        --cache out/rover_samples --jobs 2
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
THRESHOLDS = (0.3, 0.5, 0.7)
KINDS = (("gradient_boosting", 5), ("knn", 5), ("knn", 3))


def _samples(bag: str, cache: str | None) -> dict:
    from roi_detector.training import drive_samples

    return drive_samples(bag, cache=cache,
                         log=lambda m: print(f"{bag}: {m}", file=sys.stderr))


def left_one_out(xs: list[np.ndarray], ys: list[np.ndarray], kind: str,
                 k: int) -> list[np.ndarray]:
    """Each drive's regions scored by an Outcrop Rover fitted on the others' (an empty
    array for a drive with none; NaN for all of a drive when the others are one class)."""
    from roi_detector.training import fit_outcrop_rover

    out = []
    for i in range(len(xs)):
        rest = [j for j in range(len(xs)) if j != i]
        clf = fit_outcrop_rover(np.concatenate([xs[j] for j in rest]),
                                np.concatenate([ys[j] for j in rest]), k, kind)
        if clf is None or not len(xs[i]):
            out.append(np.full(len(xs[i]), np.nan))
        else:
            out.append(clf.predict_proba(xs[i]))
    return out


def feature_auc(x: np.ndarray, y: np.ndarray) -> list[float]:
    """Per feature, P(an outcrop's value > a non-outcrop's) (ties half)."""
    from scipy.stats import mannwhitneyu

    pos, neg = x[y == 1], x[y == 0]
    if not len(pos) or not len(neg):
        return [float("nan")] * x.shape[1]
    return [float(mannwhitneyu(pos[:, i], neg[:, i]).statistic / (len(pos) * len(neg)))
            for i in range(x.shape[1])]


def main(argv: list[str] | None = None) -> int:
    from roi_detector.elevation_map import MAP_OUTCROP_FEATURES, MAP_OUTCROP_RULE

    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("bags", nargs="+")
    ap.add_argument("--name", default="loo")
    ap.add_argument("--cache", default=None, metavar="DIR",
                    help="the drives' samples, as roi_detector train --cache keeps them")
    ap.add_argument("--jobs", type=int, default=1)
    args = ap.parse_args(argv)
    if len(args.bags) < 2:
        ap.error("at least two drives: each is scored by a rover fitted on the others")
    t0 = time.perf_counter()
    if args.jobs > 1:
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(args.jobs) as pool:
            data = list(pool.map(_samples, args.bags, [args.cache] * len(args.bags)))
    else:
        data = [_samples(b, args.cache) for b in args.bags]
    xs = [d["outcrop_x"] for d in data]
    ys = [d["outcrop_y"].astype(np.uint8) for d in data]
    # The regions the map reports (found in at least half the rounds that examined
    # them): the rest never reach the LN, whatever their score.
    rep = [d["outcrop_reported"].astype(bool) for d in data]
    y_all, r_all = np.concatenate(ys), np.concatenate(rep).astype(bool)
    per_bag = [{"bag": Path(b).name, "regions": len(y), "outcrops": int(y.sum()),
                "reported": int(r.sum()), "reported_outcrops": int((r & (y == 1)).sum())}
               for b, y, r in zip(args.bags, ys, rep, strict=True)]
    rows = []
    for kind, k in KINDS:
        s = np.concatenate(left_one_out(xs, ys, kind, k))
        for th in THRESHOLDS:
            kept = r_all & (s > th)
            rows.append({"kind": kind, "k": k, "threshold": th,
                         "true_kept": int((kept & (y_all == 1)).sum()),
                         "true": int((r_all & (y_all == 1)).sum()),
                         "false_kept": int((kept & (y_all == 0)).sum()),
                         "false": int((r_all & (y_all == 0)).sum())})
    auc = dict(zip(MAP_OUTCROP_FEATURES, feature_auc(np.concatenate(xs), y_all), strict=True))
    cmd = "python bench/outcrop_rover_bench.py " + " ".join(
        argv if argv is not None else sys.argv[1:])
    out = {"command": cmd, "date": time.strftime("%Y-%m-%d %H:%M"), "outcrops": MAP_OUTCROP_RULE,
           "per_bag": per_bag, "left_one_out": rows, "feature_auc": auc,
           "wall_s": round(time.perf_counter() - t0, 1)}
    RESULTS.mkdir(exist_ok=True)
    path = RESULTS / f"outcrop_rover_{args.name}.json"
    path.write_text(json.dumps(out, indent=1) + "\n")
    lines = [f"# outcrop_rover_bench: {args.name}", "", f"Command: `{cmd}`  ",
             f"Date: {out['date']}; outcrop rule: {MAP_OUTCROP_RULE}", "",
             "Per drive: outcrop regions found in >= min_rounds rounds (outcrops among them); "
             "reported by the map (outcrops among them).", "",
             "| drive | regions | outcrops | reported | reported outcrops |",
             "|---|---|---|---|---|"]
    lines += [f"| {b['bag']} | {b['regions']} | {b['outcrops']} | {b['reported']} | "
              f"{b['reported_outcrops']} |" for b in per_bag]
    lines += ["", "Left one drive out, over the regions the map reports:", "",
              "| classifier | threshold | outcrops kept | non-outcrops kept |", "|---|---|---|---|"]
    lines += [f"| {r['kind']}" + (f" (k {r['k']})" if r["kind"] == "knn" else "") +
              f" | {r['threshold']} | {r['true_kept']}/{r['true']} | "
              f"{r['false_kept']}/{r['false']} |" for r in rows]
    lines += ["", "Each feature alone (AUC: P(an outcrop's value > a non-outcrop's)):", "",
              "| feature | AUC |", "|---|---|"]
    lines += [f"| {n} | {a:.2f} |" for n, a in auc.items()]
    md = RESULTS / f"outcrop_rover_{args.name}.md"
    md.write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
