#!/usr/bin/env python3
"""Rock recall against rock precision of built LNs as the Rock Rovers' threshold rises.

Every rock node of an LN carries the score its Rock Rover gave it (the map rocks' or the
far rocks'; ``score`` in the GeoJSON). Dropping the rock nodes under a threshold t gives
the LN that a threshold of t would have kept, to a first approximation: the detector
reports a map rock while its latest score is above the threshold, and the LN holds that
latest score; what a threshold *under* the one the LN was built with would add is not
in the LN, so the sweep starts there. Two detectors (or two models) compared on the same
bags are then compared along their whole curve, not at one operating point: a variant
that finds more rocks at less precision may only have moved along the same curve.

Counts by DESIGN.md's matching rule (:func:`roi_detector.evaluation.count_ln`, what
``roi_detector eval`` counts, without its matcher run), summed over the bags; each bag's
truth is read once. Evaluation code: it reads each bag's truth.

Usage::

    W=bench/results/roi_fifteenth_a_work
    python bench/roi_score_sweep.py --name low \\
        --ln base=bags/quick=$W/quick_elevation_map_truth_odometry_ln.geojson \\
        --ln low=bags/quick=OTHER_WORK/quick_elevation_map_truth_odometry_ln.geojson
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
THRESHOLDS = (0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 0.98)


def keep_rocks_over(records: np.ndarray, threshold: float) -> np.ndarray:
    """LN records (:data:`~roi_network.records.ROI_DTYPE`) without the rock nodes scored
    under ``threshold`` (nodes of other classes, and rocks with no score, NaN, kept)."""
    from roi_network.records import ROCK

    score = records["score"]
    drop = (records["label"] == ROCK) & np.isfinite(score) & (score < threshold)
    return records[~drop]


def parse_ln(spec: str) -> tuple[str, str, Path]:
    """``VARIANT=BAG_DIR=LN`` -> (variant, bag dir, LN path)."""
    parts = spec.split("=")
    if len(parts) != 3 or not all(parts):
        raise ValueError(f"--ln {spec!r}: expected VARIANT=BAG_DIR=LN_GEOJSON")
    return parts[0], parts[1], Path(parts[2])


def markdown(name: str, command: str, rows: list[dict]) -> str:
    """The table of (variant, threshold) rows: counted rocks found and rock nodes true."""
    lines = [f"# roi_score_sweep: {name}", "", f"Command: `{command}`", "",
             "| variant | threshold | bags | rocks found | rock recall | true rock nodes "
             "| rock precision |", "|---|---|---|---|---|---|---|"]
    for r in rows:
        recall = r["found"] / r["wanted"] if r["wanted"] else float("nan")
        precision = r["true"] / r["nodes"] if r["nodes"] else float("nan")
        lines.append(f"| {r['variant']} | {r['threshold']:g} | {r['bags']} | "
                     f"{r['found']}/{r['wanted']} | {recall:.1%} | {r['true']}/{r['nodes']} "
                     f"| {precision:.1%} |")
    lines += ["", "Rock nodes scored under the threshold dropped from each LN as built "
              "(module docstring of bench/roi_score_sweep.py); counts summed over the bags, "
              "DESIGN.md's matching rule, truth ROIs above the rover thresholds within "
              "15 m of the route."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--name", required=True, help="writes bench/results/roi_sweep_NAME.md/.json")
    p.add_argument("--ln", action="append", required=True, metavar="VARIANT=BAG_DIR=LN",
                   help="an LN GeoJSON built on a bag, under a variant's name (repeat)")
    p.add_argument("--thresholds", default=",".join(f"{t:g}" for t in THRESHOLDS))
    args = p.parse_args(argv)
    from roi_detector.evaluation import count_ln, counted_rois
    from roi_detector.truth import Truth
    from roi_network.geojson import read_geojson

    try:
        specs = [parse_ln(s) for s in args.ln]
        thresholds = [float(t) for t in args.thresholds.split(",")]
    except ValueError as exc:
        p.error(str(exc))
    for _, bag, ln in specs:
        if not ln.is_file():
            p.error(f"--ln: {ln} not found")
        if not (Path(bag) / "truth").is_dir():
            p.error(f"--ln: {bag} has no truth/ directory")
    by_variant: dict[str, list[tuple[str, Path]]] = defaultdict(list)
    for variant, bag, ln in specs:
        by_variant[variant].append((bag, ln))
    lns = {ln: read_geojson(ln).records for _, _, ln in specs}
    truths = {}
    for bag in dict.fromkeys(bag for _, bag, _ in specs):
        truth = Truth.load(bag)
        truths[bag] = (truth, *counted_rois(truth, bag))
    rows = []
    for variant, runs in by_variant.items():
        for t in thresholds:
            row = {"variant": variant, "threshold": t, "bags": len(runs), "found": 0,
                   "wanted": 0, "true": 0, "nodes": 0}
            for bag, ln in runs:
                rock = count_ln(keep_rocks_over(lns[ln], t), *truths[bag])["per_class"]["rock"]
                row["found"] += rock["truth_found"]
                row["wanted"] += rock["truth_wanted"]
                row["true"] += rock["true_nodes"]
                row["nodes"] += rock["ln_nodes"]
            rows.append(row)
            print(f"{variant} t={t:g}: rocks {row['found']}/{row['wanted']}, true rock "
                  f"nodes {row['true']}/{row['nodes']}", flush=True)
    command = "python bench/roi_score_sweep.py " + " ".join(sys.argv[1:] if argv is None
                                                              else argv)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"roi_sweep_{args.name}.md").write_text(markdown(args.name, command, rows))
    (RESULTS / f"roi_sweep_{args.name}.json").write_text(json.dumps(rows, indent=1))
    print(f"wrote {RESULTS / f'roi_sweep_{args.name}.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
