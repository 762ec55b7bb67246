#!/usr/bin/env python3
"""What the false rock nodes of built LNs stand on.

A rock node is false when no catalogued rock lies within DESIGN.md's matching radius of it
(:func:`roi_detector.evaluation.true_nodes`). The catalogue holds the ROIs above the
thresholds; the simulator's world also holds sub-threshold "clutter" rocks
(``atacama_sim.rocks``: up to ``clutter_diameter_m`` across, a quarter to 0.6 of that
tall), which are not in it. This regenerates the bag's clutter from its ``world.yaml``
(same config, same seed) and puts each false rock node in the first category that fits:

* ``class``: it matches a catalogued ROI of the other class (an outcrop);
* ``clutter rock``: a clutter rock at least ``--tall`` (0.25 m, the paper's rover
  height threshold) tall within ``--near`` (0.5 m) of it: a real rock over the height
  threshold and under the area one (0.6 m^2);
* ``catalogued rock off-centre``: a catalogued rock within ``--off`` (3 m), outside its
  matching radius (the rock placed off, or a second node on it);
* ``low clutter``: only clutter rocks under ``--tall`` within ``--near``;
* ``none``: terrain, or nothing the world holds.

Evaluation code: it reads each bag's truth and world.yaml. Usage (after ``source
env.sh``)::

    python bench/roi_false_nodes.py --name committed \\
        BAG_DIR=bench/results/roi_fifteenth_a_work/..._ln.geojson ...
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from pathlib import Path

import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
CATEGORIES = ("class", "clutter rock", "catalogued rock off-centre", "low clutter", "none")


def categorise(matches_other_class: bool, nearest_rock_m: float, clutter_m: np.ndarray,
               clutter_h: np.ndarray, near: float = 0.5, tall: float = 0.25,
               off: float = 3.0) -> str:
    """The category of one false rock node (module docstring), from its distance to the
    nearest catalogued rock (m; inf: none) and to each clutter rock ((C,) m, their (C,)
    heights, m)."""
    if matches_other_class:
        return "class"
    close = clutter_m <= near
    if np.any(close & (clutter_h >= tall)):
        return "clutter rock"
    if nearest_rock_m <= off:
        return "catalogued rock off-centre"
    return "low clutter" if np.any(close) else "none"


def world_clutter(bag: Path) -> tuple[np.ndarray, np.ndarray]:
    """The clutter rocks of a bag's world, regenerated from its world.yaml: (C, 2) map
    positions and (C,) heights, m."""
    import yaml

    from atacama_sim.config import make_config
    from atacama_sim.rocks import generate_rocks
    from atacama_sim.terrain import Terrain

    path = bag / "world.yaml"
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no world.yaml (a simulator bag is needed)")
    config = yaml.safe_load(path.read_text())["config"]
    overrides = {k: v for k, v in config.items() if k not in ("preset", "seed")}
    cfg = make_config(config["preset"], config["seed"], overrides)
    terrain = Terrain.generate(cfg.terrain, cfg.site.extent_m, cfg.seed)
    clutter = generate_rocks(cfg.rocks, terrain, cfg.seed).clutter
    return clutter[:, :2].astype(float), clutter[:, 5].astype(float)


def false_nodes(bag: Path, ln_path: Path, **tests: float) -> list[dict]:
    """One row per false rock node of the LN at ``ln_path`` built on ``bag``."""
    from roi_detector.evaluation import match_nodes, true_nodes
    from roi_detector.truth import Truth
    from roi_network.geojson import read_geojson
    from roi_network.records import ROCK, xy

    truth = Truth.load(str(bag))
    ln = read_geojson(ln_path).records
    pts, j_any = match_nodes(ln, truth)
    true = true_nodes(ln, truth.rois, j_any, ROCK)
    cat_xy, cat_label = xy(truth.rois), truth.rois["label"]
    clutter_xy, clutter_h = world_clutter(bag)
    rows = []
    for i in np.flatnonzero((ln["label"] == ROCK) & ~true):
        d_cat = np.linalg.norm(cat_xy - pts[i, :2], axis=1)
        d_rock = d_cat[cat_label == ROCK]
        d_clutter = np.linalg.norm(clutter_xy - pts[i, :2], axis=1)
        k = int(np.argmin(d_clutter))
        other = bool(j_any[i] >= 0 and cat_label[j_any[i]] != ROCK)
        rows.append({
            "bag": bag.name, "node": int(ln["id"][i]),
            "height_m": float(ln["height_m"][i]), "area_m2": float(ln["area_m2"][i]),
            "score": float(ln["score"][i]),
            "nearest_catalogued_m": float(d_cat.min()),
            "nearest_clutter_m": float(d_clutter[k]), "nearest_clutter_h_m": float(clutter_h[k]),
            "category": categorise(other, float(d_rock.min(initial=np.inf)), d_clutter,
                                   clutter_h, **tests)})
    return rows


def markdown(name: str, command: str, rows: list[dict]) -> str:
    counts = Counter(r["category"] for r in rows)
    lines = [f"# roi_false_nodes: {name}", "", f"Command: `{command}`", "",
             f"{len(rows)} false rock nodes: " + ", ".join(
                 f"{c} {counts[c]}" for c in CATEGORIES if counts[c]), "",
             "| bag | node | category | height (m) | area (m^2) | score | nearest catalogued "
             "ROI (m) | nearest clutter rock (m, its height) |",
             "|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['bag']} | {r['node']} | {r['category']} | {r['height_m']:.2f} | "
                     f"{r['area_m2']:.2f} | {r['score']:.2f} | {r['nearest_catalogued_m']:.1f} "
                     f"| {r['nearest_clutter_m']:.2f} ({r['nearest_clutter_h_m']:.2f}) |")
    lines += ["", "Categories: bench/roi_false_nodes.py's docstring. Heights and areas as the "
              "map measured them."]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("lns", nargs="+", metavar="BAG_DIR=LN", help="an LN built on a bag")
    p.add_argument("--name", required=True,
                   help="writes bench/results/roi_false_nodes_NAME.md/.json")
    p.add_argument("--near", type=float, default=0.5)
    p.add_argument("--tall", type=float, default=0.25)
    p.add_argument("--off", type=float, default=3.0)
    args = p.parse_args(argv)
    rows = []
    for spec in args.lns:
        bag, sep, ln = spec.partition("=")
        if not sep or not bag or not ln:
            p.error(f"{spec!r}: expected BAG_DIR=LN_GEOJSON")
        if not Path(ln).is_file():
            p.error(f"{ln}: not found")
        try:
            rows += false_nodes(Path(bag), Path(ln), near=args.near, tall=args.tall,
                                off=args.off)
        except FileNotFoundError as exc:
            p.error(str(exc))
    command = "python bench/roi_false_nodes.py " + " ".join(sys.argv[1:] if argv is None
                                                              else argv)
    md = markdown(args.name, command, rows)
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / f"roi_false_nodes_{args.name}.md").write_text(md)
    (RESULTS / f"roi_false_nodes_{args.name}.json").write_text(json.dumps(rows, indent=1))
    print(md.split("\n")[4])
    return 0


if __name__ == "__main__":
    sys.exit(main())
