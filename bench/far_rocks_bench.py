"""Far rocks (roi_detector.far_rocks) on bags, truth odometry: what the triangulated dark
blobs add to the elevation map's rocks, and what their false nodes are.

Per bag, the rover pipeline runs with its far rocks, every pair, the
truth trajectory as odometry (detection geometry alone), and the rover model (default:
the committed one; ``--model none``: the rules alone), and reports:

- far rocks alone (every triangulated rock, near a map ROI or not): nodes, nodes matching
  a truth rock (DESIGN.md's rule), counted truth rocks they find; for the candidates the
  rules pass (Sec. 4.2) and for those the far rocks' Rock Rover keeps (Sec. 4.3);
- the map's rocks alone and the map's with the far rocks it lacks (what the LN gets),
  rules alone and classified: rock nodes, true nodes, counted rocks found;
- each false far rock's nearest sub-threshold clutter rock of the simulated world (its
  size), when the bag's world can be rebuilt from its ``world.yaml`` preset and seed.

Evaluation code: reads truth/ and the simulator's world. Usage (repository root, after
``source env.sh``)::

    python bench/far_rocks_bench.py bags/quick bags/atacama_1km_s1 [--name NAME] [--model M]

Writes bench/results/far_rocks_NAME.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"


def run_bag(bag: str, model: str | None = None, log=print) -> dict:
    """Far rocks, map rocks and their union on one bag (see the module)."""
    from roi_detector.evaluation import match_nodes, true_nodes
    from roi_detector.rover_pipeline import (
        DriveMapper,
        RoverConfig,
        far_rock_records,
        load_classifier,
    )
    from roi_detector.training import drive_with_truth_odometry
    from roi_network.records import ROCK

    cfg = RoverConfig()
    classifier = load_classifier(model, cfg)
    mapper = DriveMapper(cfg, classifier=classifier)
    t0 = time.perf_counter()
    truth, stats = drive_with_truth_odometry(bag, mapper, log, describe=True)
    seconds = time.perf_counter() - t0
    n, union = stats["pairs"], mapper.current_tracks()
    counted = truth.counted() & (truth.rois["label"] == ROCK)

    def score(rec: np.ndarray) -> dict:
        rec = rec[rec["label"] == ROCK]
        _, j = match_nodes(rec, truth)
        ok = true_nodes(rec, truth.rois, j, ROCK)
        found = sorted({int(k) for k in j[ok] if counted[k]})
        return {"nodes": len(rec), "true_nodes": int(ok.sum()),
                "counted_found": len(found), "counted": int(counted.sum())}

    far = mapper.far.rocks()
    far_rec = far_rock_records(far)
    rules = mapper.far.rocks(classified=False)
    report = {"bag": bag, "pairs": n, "seconds": round(seconds, 1),
              "model": None if classifier is None else classifier.meta.get("path"),
              "far_alone": score(far_rec), "far_rules": score(far_rock_records(rules)),
              "map": score(mapper.map.to_records()), "map_and_far": score(union),
              "map_and_far_rules": score(mapper._map_and_far_records(rules))}
    report["false_far"] = _false_far(bag, far, far_rec, truth)
    return report


def _false_far(bag: str, far, far_rec: np.ndarray, truth) -> list[dict]:
    """Each false far rock: where, what it measured, the nearest big clutter rock."""
    from roi_detector.evaluation import match_nodes

    pts, j = match_nodes(far_rec, truth)
    clutter = _clutter(bag)
    out = []
    for r, p, jj in zip(far, pts, j, strict=False):
        if jj >= 0:
            continue
        row = {"map_xy": [round(float(p[0]), 1), round(float(p[1]), 1)],
               "width_m": round(r.width_m, 2), "height_m": round(r.height_m, 2),
               "views": r.n_views, "nearest_m": round(r.nearest_m, 1)}
        if clutter is not None:
            d = np.hypot(clutter[:, 0] - p[0], clutter[:, 1] - p[1])
            k = int(np.argmin(d))
            row["clutter"] = {"distance_m": round(float(d[k]), 2),
                              "size_m": [round(float(v), 2) for v in clutter[k, 2:5]]}
        out.append(row)
    return out


def _clutter(bag: str) -> np.ndarray | None:
    """(N, 5) x, y, size x, size y, height of the world's clutter rocks wider than 0.4 m,
    rebuilt from the bag's preset and seed; None when that is not possible."""
    try:
        import yaml

        from atacama_sim.config import make_config
        from atacama_sim.rocks import INST, generate_rocks
        from atacama_sim.terrain import Terrain

        world = yaml.safe_load((Path(bag) / "world.yaml").read_text())["config"]
        cfg = make_config(world["preset"], int(world["seed"]))
        terrain = Terrain.generate(cfg.terrain, cfg.site.extent_m, cfg.seed)
        c = generate_rocks(cfg.rocks, terrain, cfg.seed).clutter
    except Exception as exc:
        print(f"{bag}: clutter not rebuilt ({exc})", file=sys.stderr)
        return None
    big = np.maximum(c[:, INST["sx"]], c[:, INST["sy"]]) > 0.4
    return np.column_stack([c[big, INST["x"]], c[big, INST["y"]], c[big, INST["sx"]],
                            c[big, INST["sy"]], c[big, INST["sz"]]])


def _totals(reports: list[dict], key: str) -> dict:
    return {k: sum(r[key][k] for r in reports)
            for k in ("nodes", "true_nodes", "counted_found", "counted")}


def markdown(reports: list[dict], command: str) -> str:
    """The results table."""
    model = reports[0].get("model") if reports else None
    lines = ["# Far rocks (triangulated dark blobs) beside the elevation map", "",
             f"Command: `{command}`. Truth odometry, every pair; rover model: "
             f"{model or 'none (the rules alone)'}. *far*: every triangulated far rock, "
             "the candidates the rules pass (*rules*) and those the far rocks' Rock Rover "
             "keeps (*classified*); *map*: the elevation map's rocks alone; *map + far*: "
             "with the far rocks no map ROI stands near (what the LN gets with "
             "`far_rocks` on). Cells: nodes matching a truth rock by DESIGN.md's rule / "
             "rock nodes, then counted truth rocks found (above the rover thresholds, "
             "within 15 m of the route) / counted.", "",
             "| bag | far, rules | far, classified | map | map + far, rules "
             "| map + far, classified |", "|---|---|---|---|---|---|"]

    def cell(d: dict) -> str:
        return f"{d['true_nodes']} / {d['nodes']}; {d['counted_found']} / {d['counted']}"

    keys = ("far_rules", "far_alone", "map", "map_and_far_rules", "map_and_far")
    for r in reports:
        lines.append(f"| {Path(r['bag']).name} | " + " | ".join(cell(r[k]) for k in keys)
                     + " |")
    if len(reports) > 1:
        lines.append("| **all** | " + " | ".join(cell(_totals(reports, k)) for k in keys)
                     + " |")
    lines += ["", "False far rocks and the nearest sub-threshold clutter rock of the world "
              "(size x, size y, height, m):", ""]
    for r in reports:
        for f in r["false_far"]:
            c = f.get("clutter")
            near = f"clutter {c['distance_m']} m away, {c['size_m']}" if c else "-"
            lines.append(f"- {Path(r['bag']).name} at {f['map_xy']}: measured "
                         f"{f['width_m']} m wide, {f['height_m']} m high, "
                         f"{f['views']} views, nearest {f['nearest_m']} m; {near}")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("bags", nargs="+")
    ap.add_argument("--name", default="bags")
    ap.add_argument("--model", default=None,
                    help="rover model (.npz; default: the committed one; 'none': rules alone)")
    args = ap.parse_args(argv)
    reports = [run_bag(b, args.model) for b in args.bags]
    command = "python bench/far_rocks_bench.py " + " ".join(args.bags) + \
        f" --name {args.name}" + (f" --model {args.model}" if args.model else "")
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"far_rocks_{args.name}.json").write_text(
        json.dumps({"command": command, "bags": reports}, indent=1) + "\n")
    (RESULTS / f"far_rocks_{args.name}.md").write_text(markdown(reports, command))
    print(markdown(reports, command))
    return 0


if __name__ == "__main__":
    sys.exit(main())
