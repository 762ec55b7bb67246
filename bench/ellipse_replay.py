#!/usr/bin/env python3
"""The graph's localization when the orbital map is a landing ellipse, not the route's crop.

    python bench/ellipse_replay.py RUN_DIR BAG_DIR --tile-bags BAG... [--tiles 7 ...]
        [--seeds 1,2,3] [--name NAME]

Every end-to-end figure so far was measured on the bag's own GN: the orbital crop around
the route, ~2 km^2 and ~150 ROIs on a 1 km bag. Before a drive, the rover does not know
where in its landing ellipse it is (Perseverance's was 7.7 km x 6.6 km, MSL's 20 km x
7 km), so the GN it matches against covers the whole ellipse, and every ROI outside the
route's crop is a place a chance alignment can land. This bench builds such a GN and
replays a run's LNs and odometry through the matcher and the map -> odom filter
(``bench/replay_matcher.py``: the darces_matcher node's logic without ROS) against it
and against the bag's own GN, side by side.

The ellipse GN is a square of ``--tiles`` x ``--tiles`` tiles, each the side of the bag's
GN (the square its ROIs span). The bag's own GN keeps its place and its coordinates (the
LNs and the truth are in its map frame); its tile sits at a random grid cell. Every other
tile is the square crop, at a random offset, of the GN of another bag of the same world
generator (``--tile-bags``: orbital_gn's detections on other seeds, so the distractors
have the statistics of the real one, not of a point process chosen for the test),
turned by a random multiple of 90 deg and mirrored at random. The bag's own GN is never a
tile, so no copy of the true constellation exists elsewhere.

Reported per GN and tiling seed: the first fix (distance along the route), the poses
more than 10 m off the truth after it, the final error, the RMSE, the 3-sigma
consistency, the median match time, and the filter's events. Evaluation only: the truth
judges the poses; the matcher and the filter do not read it.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from replay_matcher import read_run, replay, truth_along

from roi_network.geojson import read_geojson
from roi_network.network import RoiNetwork
from roi_network.records import xy

RESULTS = Path(__file__).resolve().parent / "results"


def _square(records: np.ndarray) -> tuple[np.ndarray, float]:
    """Lower-left corner and side of the square the records span, metres."""
    p = xy(records)
    lo = p.min(axis=0)
    return lo, float((p.max(axis=0) - lo).max())


def _crop(records: np.ndarray, side: float, rng: np.random.Generator) -> np.ndarray:
    """The records inside a ``side`` square at a random offset in their extent, moved to
    the square's own coordinates (0..side)."""
    p = xy(records)
    lo, hi = p.min(axis=0), p.max(axis=0)
    corner = lo + rng.uniform(0.0, 1.0, 2) * np.maximum(hi - lo - side, 0.0)
    inside = np.all((p >= corner) & (p < corner + side), axis=1)
    out = records[inside].copy()
    out["x"] -= corner[0]
    out["y"] -= corner[1]
    return out


def _dihedral(records: np.ndarray, side: float, rng: np.random.Generator) -> np.ndarray:
    """The tile (0..side square) turned by a random multiple of 90 deg about its centre,
    mirrored at random; footprint angles follow."""
    out = records.copy()
    x, y = out["x"] - side / 2, out["y"] - side / 2
    angle = out["angle_rad"].astype(float)
    if rng.random() < 0.5:
        x, angle = -x, np.pi - angle
    k = int(rng.integers(4))
    c, s = np.cos(k * np.pi / 2), np.sin(k * np.pi / 2)
    x, y = c * x - s * y, s * x + c * y
    out["x"], out["y"] = x + side / 2, y + side / 2
    out["angle_rad"] = np.mod(angle + k * np.pi / 2 + np.pi / 2, np.pi) - np.pi / 2
    return out


def ellipse_gn(own: RoiNetwork, tiles: list[np.ndarray], n: int, seed: int
               ) -> tuple[RoiNetwork, dict[str, Any]]:
    """The bag's GN inside an ``n`` x ``n`` grid of tiles of the other GNs (module
    docstring); returns the GN and its description."""
    if n < 1:
        raise ValueError(f"--tiles must be >= 1, got {n}")
    rng = np.random.default_rng(seed)
    corner, side = _square(own.records)
    home = rng.integers(n, size=2)
    parts = [own.records]
    for i in range(n):
        for j in range(n):
            if i == home[0] and j == home[1]:
                continue
            tile = _dihedral(_crop(tiles[int(rng.integers(len(tiles)))], side, rng), side, rng)
            tile["x"] += corner[0] + (i - home[0]) * side
            tile["y"] += corner[1] + (j - home[1]) * side
            parts.append(tile)
    rec = np.concatenate(parts)
    rec["id"] = np.arange(len(rec), dtype=rec["id"].dtype)
    area_km2 = (n * side) ** 2 / 1e6
    gn = RoiNetwork(rec, "map", map_frame=own.map_frame,
                    metadata={**own.metadata, "ellipse_replay": {"tiles": n, "seed": seed}})
    return gn, {"rois": len(rec), "area_km2": area_km2, "side_km": n * side / 1e3,
                "home_tile": [int(home[0]), int(home[1])], "tile_side_m": side}


def _row(label: str, gn_info: dict[str, Any], replayed: dict[str, Any]) -> dict[str, Any]:
    return {"gn": label, **gn_info, **replayed}


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run_dir", type=Path, help="a `globloc run` directory (outputs/ bag)")
    p.add_argument("bag_dir", type=Path, help="the bag it ran on (gn.geojson, truth/)")
    p.add_argument("--tile-bags", type=Path, nargs="+", required=True,
                   help="other bags whose gn.geojson tile the ellipse")
    p.add_argument("--tiles", type=int, nargs="+", default=[7],
                   help="grid sizes (tiles per side); 7 tiles of a 1 km bag's GN: ~100 km^2")
    p.add_argument("--seeds", default="1,2,3", help="tiling seeds, comma-separated")
    p.add_argument("--name", default=None, help="results go to ellipse_<name>.{md,json}")
    p.add_argument("--out", type=Path, default=RESULTS,
                   help="directory of the results (default: bench/results)")
    args = p.parse_args(argv)
    truth_path, gn_path = args.bag_dir / "truth" / "trajectory.tum", args.bag_dir / "gn.geojson"
    for path in (truth_path, gn_path, *(b / "gn.geojson" for b in args.tile_bags)):
        if not path.is_file():
            p.error(f"{path} not found")
    if any(b.resolve() == args.bag_dir.resolve() for b in args.tile_bags):
        p.error("the bag's own GN cannot be a tile (a copy of the true constellation)")
    if any(n < 1 for n in args.tiles):
        p.error(f"--tiles must be >= 1 per side, got {args.tiles}")
    seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    own = read_geojson(gn_path)
    tiles = [read_geojson(b / "gn.geojson").records for b in args.tile_bags]
    for b, t in zip(args.tile_bags, tiles, strict=True):
        if len(t) == 0:
            p.error(f"{b / 'gn.geojson'} holds no ROI")
    lns, odometry = read_run(args.run_dir)
    truth_xy, dist, oracle = truth_along(odometry, truth_path)
    _, side = _square(own.records)
    print(f"{args.run_dir}: {len(lns)} LNs, route {dist[-1]:.0f} m; own GN {len(own)} ROIs "
          f"on a {side:.0f} m square", flush=True)
    rows = []
    t0 = time.perf_counter()
    own_row = replay(lns, odometry, own, truth_xy, dist, "base", oracle)
    rows.append(_row("own", {"rois": len(own), "area_km2": side**2 / 1e6, "seed": None},
                     own_row))
    print(json.dumps(rows[-1]), f"({time.perf_counter() - t0:.0f} s)", flush=True)
    for n in args.tiles:
        for seed in seeds:
            gn, info = ellipse_gn(own, tiles, n, seed)
            t0 = time.perf_counter()
            replayed = replay(lns, odometry, gn, truth_xy, dist, "base", oracle)
            rows.append(_row(f"ellipse_{n}x{n}", {**info, "seed": seed}, replayed))
            print(json.dumps(rows[-1]), f"({time.perf_counter() - t0:.0f} s)", flush=True)
    command = ("python bench/ellipse_replay.py " + " ".join(map(str, [
        args.run_dir, args.bag_dir, "--tile-bags", *args.tile_bags, "--tiles", *args.tiles,
        "--seeds", args.seeds])))
    report = {"run_dir": str(args.run_dir), "bag": str(args.bag_dir),
              "tile_bags": [str(b) for b in args.tile_bags], "command": command, "rows": rows}
    name = args.name or args.bag_dir.name
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / f"ellipse_{name}.json").write_text(json.dumps(report, indent=1) + "\n")
    (args.out / f"ellipse_{name}.md").write_text(markdown(report))
    return 0


def markdown(report: dict[str, Any]) -> str:
    """The results table."""
    lines = [f"# The graph's LNs against a landing-ellipse GN: {report['bag']}", "",
             f"Command: `{report['command']}`", "",
             f"Run replayed: `{report['run_dir']}` (its /local_network and /vo/odometry "
             "through the matcher and the map -> odom filter, `bench/replay_matcher.py`). "
             f"Tiles: the GNs of {', '.join(Path(b).name for b in report['tile_bags'])}.",
             "",
             "| GN | seed | ROIs | area km^2 | first fix after m | poses > 10 m off | final error m"
             " | RMSE m | 3-sigma | match ms median | events |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]

    def f(v: Any, fmt: str) -> str:
        return "-" if v is None else format(v, fmt)

    for r in report["rows"]:
        events = ", ".join(f"{k} {v}" for k, v in sorted(r["events"].items())
                           if not k.startswith("none:"))
        lines.append(
            f"| {r['gn']} | {f(r.get('seed'), 'd')} | {r['rois']} | {r['area_km2']:.1f} | "
            f"{f(r['first_fix_after_m'], '.1f')} | {r['poses_over_10m']} | "
            f"{f(r['final_error_m'], '.2f')} | {f(r['rmse_m'], '.2f')} | "
            f"{f(r['consistency_3sigma'], '.3f')} | {f(r['match_ms_median'], '.1f')} | "
            f"{events} |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    raise SystemExit(main())
