"""Benchmark of orbital_gn: detection quality, speed, memory, and the matcher on the GN.

    python bench/orbital_gn_bench.py quality [--bags B...] [--recipes paper,no_sun]
    python bench/orbital_gn_bench.py centres [--bags B...] [--recipes ...]
    python bench/orbital_gn_bench.py scale --ortho bags/X/orbital.tif --tiles 2 4 ...
    python bench/orbital_gn_bench.py matcher --bag BAG --gn GN.geojson... [--length M --step M]

Writes RESULTS/orbital_gn_<part>.json and a markdown table beside it. Every
``orbital_gn prepare`` runs as its own process (as a user runs it), with its wall time
and the peak resident memory of its process tree (main process + dask workers, sampled
every 0.2 s with psutil).

Models per recipe: ``sun_aware`` the committed default, ``no_sun`` the committed
no-sun fallback (``orbital_no_sun.npz``; both from ``make orbital-model``), ``paper``
trained by this script (``orbital_gn train --recipe paper``) on the same training bags
when it is missing.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path
from xml.sax.saxutils import escape

import psutil

ROOT = Path(__file__).resolve().parents[1]
#: Where result files go: $BENCH_RESULTS (`make bench`: bench/results/current/), else
#: out/bench/results/.
RESULTS = Path(os.environ.get("BENCH_RESULTS") or ROOT / "out" / "bench" / "results")
#: Scratch space (GNs, previews, the paper recipe's model): $BENCH_WORK/orbital_gn, else
#: out/bench/work/orbital_gn/.
WORK = Path(os.environ.get("BENCH_WORK") or ROOT / "out" / "bench" / "work") / "orbital_gn"
DEFAULT_BAGS = [str(ROOT / "bags" / n) for n in ("atacama_1km_s1", "atacama_1km_s2",
                                                 "atacama_1km_s3", "quick")]
#: The committed models' training set (``make orbital-model``).
TRAIN_BAGS = [str(ROOT / "bags" / n) for n in (
    "train_quick_s101", "train_quick_s102",
    *(f"train_orbital_1km_s{s}" for s in range(101, 107)))]


def _exe(name: str) -> str:
    exe = shutil.which(name)
    if exe is None:
        sys.exit(f"{name} not on PATH: source ./env.sh first")
    return exe


def run_measured(cmd: list[str]) -> dict:
    """Run ``cmd``; wall time and peak RSS (MiB) of its process tree."""
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    ps = psutil.Process(proc.pid)
    peak = 0
    while proc.poll() is None:
        try:
            rss = ps.memory_info().rss + sum(c.memory_info().rss
                                             for c in ps.children(recursive=True))
            peak = max(peak, rss)
        except psutil.Error:
            pass
        time.sleep(0.2)
    out, err = proc.communicate()
    elapsed = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}): {err.strip()}")
    return {"wall_s": round(elapsed, 2), "peak_rss_mib": round(peak / 2**20, 1),
            "stdout": out.strip()}


def _machine() -> str:
    """The machine line of a results file: cores and the load when the part started."""
    return (f"{psutil.cpu_count()} cores, load average {psutil.getloadavg()[0]:.1f} at "
            "start; 2 dask worker processes")


def raster_mpx(path: str) -> float:
    import rasterio
    with rasterio.open(path) as ds:
        return ds.width * ds.height / 1e6


def ensure_paper_model(train_bags: list[str]) -> Path:
    model = WORK / "models" / "orbital_paper.npz"
    if not model.exists():
        model.parent.mkdir(parents=True, exist_ok=True)
        print(f"training the paper recipe's model on {train_bags}", flush=True)
        run_measured([_exe("orbital_gn"), "train", *train_bags, "--out", str(model),
                      "--recipe", "paper"])
    return model


def cmd_quality(args) -> None:
    from orbital_gn.prepare import no_sun_model_path

    recipes = args.recipes.split(",")
    models = {"sun_aware": args.model or "default", "no_sun": str(no_sun_model_path())}
    if "paper" in recipes:
        models["paper"] = str(ensure_paper_model(args.train_bags))
    out_json = RESULTS / "orbital_gn_quality.json"
    results = json.loads(out_json.read_text()) if out_json.exists() and args.append else {}
    results.setdefault("runs", [])
    results["machine"] = _machine()
    for bag in map(Path, args.bags):
        ortho = bag / "orbital.tif"
        if not ortho.is_file():
            print(f"skip {bag}: no orbital.tif yet", flush=True)
            continue
        for recipe in recipes:
            gn = WORK / f"{bag.name}_{recipe}.geojson"
            gn.parent.mkdir(parents=True, exist_ok=True)
            cmd = [_exe("orbital_gn"), "prepare", str(ortho), "--out", str(gn), "--no-progress",
                   "--workers", "2"]
            if models[recipe] != "default":
                cmd += ["--model", models[recipe]]
            if recipe == "sun_aware":
                cmd += ["--preview", str(WORK / f"{bag.name}_{recipe}.png")]
            print(" ".join(cmd), flush=True)
            m = run_measured(cmd)
            ev_json = WORK / f"{bag.name}_{recipe}_eval.json"
            subprocess.run([_exe("orbital_gn"), "eval", "--gn", str(gn), "--truth",
                            str(bag / "truth" / "rois.geojson"), "--json", str(ev_json)],
                           check=True, capture_output=True)
            ev = json.loads(ev_json.read_text())
            mpx = raster_mpx(str(ortho))
            run = {"bag": bag.name, "recipe": recipe, "model": models[recipe], "mpx": mpx,
                   "wall_s": m["wall_s"], "mpx_per_s": round(mpx / m["wall_s"], 3),
                   "peak_rss_mib": m["peak_rss_mib"], "eval": ev, "command": " ".join(cmd)}
            results["runs"] = [r for r in results["runs"]
                               if (r["bag"], r["recipe"]) != (bag.name, recipe)] + [run]
            _write(out_json, results)
            print(f"  {bag.name} {recipe}: {m['wall_s']} s, rock P/R "
                  f"{ev['rock']['precision']}/{ev['rock']['recall']}, outcrop P/R "
                  f"{ev['outcrop']['precision']}/{ev['outcrop']['recall']}", flush=True)
    _write_quality_md(results, RESULTS / "orbital_gn_quality.md")


def _pct(v) -> str:
    return "n/a" if v is None else f"{100 * v:.1f}"


def _write_quality_md(results: dict, path: Path) -> None:
    lines = ["# orbital_gn detection quality (bench/orbital_gn_bench.py quality)", "",
             f"Machine: {results.get('machine', '')}.", "",
             "Precision / recall in %, DESIGN.md's matching rule (centre within max(1 m, half "
             "the truth major axis), same class). Rock bins by truth footprint.", "",
             "| bag | recipe | rock P | rock R | rock >=1 m^2 P | rock >=1 m^2 R | 0.6-1 R | "
             "1-2 R | 2-6 R | outcrop P | outcrop R | near route | time s | Mpx/s | peak RSS MiB |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in sorted(results["runs"], key=lambda r: (r["bag"], r["recipe"])):
        e = r["eval"]
        b = e.get("rock_bins_m2", {})
        nr = e.get("near_route", {})
        lines.append(
            f"| {r['bag']} | {r['recipe']} | {_pct(e['rock']['precision'])} | "
            f"{_pct(e['rock']['recall'])} | {_pct(e['rock_ge_1m2']['precision'])} | "
            f"{_pct(e['rock_ge_1m2']['recall'])} | {_pct(b.get('0.6-1', {}).get('recall'))} | "
            f"{_pct(b.get('1-2', {}).get('recall'))} | {_pct(b.get('2-6', {}).get('recall'))} | "
            f"{_pct(e['outcrop']['precision'])} | {_pct(e['outcrop']['recall'])} | "
            f"{_pct(nr.get('fraction'))} | {r['wall_s']} | {r['mpx_per_s']} | "
            f"{r['peak_rss_mib']} |")
    path.write_text("\n".join(lines) + "\n")


def cmd_centres(args) -> None:
    """Centre error of the matched detections of GNs already prepared by ``quality``
    (``out/bench_orbital_gn/<bag>_<recipe>.geojson``): median / p90 distance to the
    matched truth ROI, per class; bench/results/orbital_gn_centres.{json,md}."""
    from orbital_gn.evaluate import evaluate
    from roi_network.geojson import read_geojson

    rows = []
    for bag in map(Path, args.bags):
        truth = read_geojson(bag / "truth" / "rois.geojson")
        for recipe in args.recipes.split(","):
            gn_path = WORK / f"{bag.name}_{recipe}.geojson"
            if not gn_path.is_file():
                print(f"skip {gn_path}: run the quality bench first", flush=True)
                continue
            ev = evaluate(read_geojson(gn_path), truth)
            rows.append({"bag": bag.name, "recipe": recipe, "gn": str(gn_path),
                         "rock": ev["rock"]["centre_error_m"],
                         "outcrop": ev["outcrop"]["centre_error_m"]})
    _write(RESULTS / "orbital_gn_centres.json", {"runs": rows, "command": " ".join(sys.argv)})

    def f(v):
        return "n/a" if v is None else f"{v:.2f}"

    lines = ["# Centre error of matched detections (bench/orbital_gn_bench.py centres)", "",
             "Distance from each detection matching a truth ROI (DESIGN.md's rule) to that "
             "ROI's centre, metres.", "",
             "| bag | recipe | rocks median | rocks p90 | outcrops median | outcrops p90 |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['bag']} | {r['recipe']} | {f(r['rock']['median'])} | "
                     f"{f(r['rock']['p90'])} | {f(r['outcrop']['median'])} | "
                     f"{f(r['outcrop']['p90'])} |")
    (RESULTS / "orbital_gn_centres.md").write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


def _vrt_mosaic(ortho: Path, k: int, out: Path) -> Path:
    """A k x k mosaic of one raster as a GDAL VRT (no pixel copied to disk), with the
    source's metadata tags (the sun direction among them)."""
    import rasterio
    with rasterio.open(ortho) as ds:
        w, h, t, crs, n = ds.width, ds.height, ds.transform, ds.crs.to_wkt(), ds.count
        dtype = {"uint8": "Byte", "uint16": "UInt16", "float32": "Float32"}[ds.dtypes[0]]
        tags = ds.tags()
    meta = "<Metadata>" + "".join(f"<MDI key=\"{escape(k)}\">{escape(v)}</MDI>"
                                  for k, v in tags.items()) + "</Metadata>"
    bands = []
    for b in range(1, n + 1):
        srcs = "".join(
            f"<SimpleSource><SourceFilename relativeToVRT=\"0\">{ortho}</SourceFilename>"
            f"<SourceBand>{b}</SourceBand><SrcRect xOff=\"0\" yOff=\"0\" xSize=\"{w}\" "
            f"ySize=\"{h}\"/><DstRect xOff=\"{j * w}\" yOff=\"{i * h}\" xSize=\"{w}\" "
            f"ySize=\"{h}\"/></SimpleSource>" for i in range(k) for j in range(k))
        bands.append(f"<VRTRasterBand dataType=\"{dtype}\" band=\"{b}\">{srcs}</VRTRasterBand>")
    out.write_text(
        f"<VRTDataset rasterXSize=\"{k * w}\" rasterYSize=\"{k * h}\"><SRS>{escape(crs)}</SRS>"
        f"<GeoTransform>{t.c}, {t.a}, {t.b}, {t.f}, {t.d}, {t.e}</GeoTransform>" + meta
        + "".join(bands) + "</VRTDataset>")
    return out


def cmd_scale(args) -> None:
    out_json = RESULTS / "orbital_gn_scale.json"
    results = {"machine": _machine(),
               "source": str(args.ortho), "tile_px": args.tile_px, "runs": []}
    for k in args.tiles:
        vrt = _vrt_mosaic(Path(args.ortho).resolve(), k, WORK / f"mosaic_{k}x{k}.vrt")
        gn = WORK / f"mosaic_{k}x{k}.geojson"
        cmd = [_exe("orbital_gn"), "prepare", str(vrt), "--out", str(gn), "--no-progress",
               "--workers", "2", "--tile-px", str(args.tile_px)]
        print(" ".join(cmd), flush=True)
        m = run_measured(cmd)
        mpx = raster_mpx(str(vrt))
        results["runs"].append({"tiles": f"{k}x{k}", "mpx": round(mpx, 1),
                                "wall_s": m["wall_s"], "mpx_per_s": round(mpx / m["wall_s"], 3),
                                "peak_rss_mib": m["peak_rss_mib"], "command": " ".join(cmd),
                                "output": m["stdout"]})
        _write(out_json, results)
        print(f"  {mpx:.0f} Mpx: {m['wall_s']} s, peak RSS {m['peak_rss_mib']} MiB", flush=True)
    lines = ["# orbital_gn memory and speed against raster size (bench/orbital_gn_bench.py "
             "scale)", "", f"Machine: {results['machine']}. Source: {results['source']} "
             f"tiled k x k in a GDAL VRT; window core {args.tile_px} px for every size.", "",
             "| mosaic | Mpx | time s | Mpx/s | peak RSS MiB (process tree) |",
             "|---|---|---|---|---|"]
    for r in results["runs"]:
        lines.append(f"| {r['tiles']} | {r['mpx']} | {r['wall_s']} | {r['mpx_per_s']} | "
                     f"{r['peak_rss_mib']} |")
    (RESULTS / "orbital_gn_scale.md").write_text("\n".join(lines) + "\n")


def route_lns(bag: Path, length_m: float, step_m: float, radius_m: float, seed: int):
    """LNs a drive would build: the truth ROIs within ``radius_m`` of each ``length_m``
    stretch of the bag's route (starts every ``step_m``), displaced by 1 % VO drift of the
    distance travelled when each is passed, in a random odom frame. Yields (records in odom,
    true map_T_odom, true map positions)."""
    import numpy as np

    from roi_network.geojson import read_geojson
    from roi_network.transform import Rigid2D

    truth = read_geojson(bag / "truth" / "rois.geojson")
    traj = np.loadtxt(bag / "truth" / "trajectory.tum", ndmin=2)[:, 1:3]
    travelled = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(traj, axis=0).T))])
    rng = np.random.default_rng(seed)
    pts = np.column_stack([truth.records["x"], truth.records["y"]])
    for s0 in np.arange(0.0, travelled[-1] - length_m, step_m):
        sel = (travelled >= s0) & (travelled <= s0 + length_m)
        seg, dist = traj[sel], travelled[sel] - s0
        d = np.hypot(*(pts[:, None, :] - seg[None, :, :]).transpose(2, 0, 1))
        near = d.min(axis=1) <= radius_m
        if near.sum() < 5:
            continue
        passed = dist[np.argmin(d[near], axis=1)]
        ln = truth.records[near].copy()
        r = 0.01 * passed * np.sqrt(rng.random(near.sum()))
        a = rng.uniform(0, 2 * np.pi, near.sum())
        true_xy = pts[near]
        drifted = true_xy + np.column_stack([r * np.cos(a), r * np.sin(a)])
        map_T_odom = Rigid2D(rng.uniform(-np.pi, np.pi), *(true_xy[0] + rng.uniform(-500, 500, 2)))
        odom = map_T_odom.inverse().apply(drifted)
        ln["x"], ln["y"] = odom[:, 0], odom[:, 1]
        ln["cov_xx"] = ln["cov_yy"] = np.maximum((0.01 * passed) ** 2 / 4, 0.01)
        ln["score"] = 1.0
        yield ln[rng.permutation(ln.size)], map_T_odom, true_xy


def cmd_matcher(args) -> None:
    """The matcher on the detected GN and, for reference, on the truth catalogue, with the
    LNs a drive along the bag's route would build (truth ROIs near the route, 1 % drift).

    The paper protocol of ``darces_eval`` simulates LNs as walks over the GN's own nodes
    from pairs 600 m - 1 km apart with steps up to 150 m; on the 1 km bags' GNs (150-250
    ROIs in 1.5 km x 1.5 km, clustered) it finds no such walk, so this bench drives the
    bag's route instead (the rover sees truth ROIs; the GN is what orbital_gn detected).
    """
    import numpy as np

    from darces_matcher.matcher import Matcher
    from roi_network.geojson import read_geojson

    bag = Path(args.bag)
    gns = {Path(g).stem: Path(g) for g in args.gn}
    gns["truth"] = bag / "truth" / "rois.geojson"
    summary = {"bag": bag.name, "ln_length_m": args.length, "ln_step_m": args.step,
               "route_radius_m": 15.0, "drift": 0.01, "runs": {},
               "command": " ".join(sys.argv)}
    from scipy.spatial import cKDTree

    truth_net = read_geojson(gns["truth"])
    for name, path in gns.items():
        gn = read_geojson(path)
        matcher = Matcher(gn)
        counts = {"lns": 0, "fix": 0, "correct_2m": 0, "false_fix_10m": 0}
        times = []
        # Why a GN may fail the matcher: per LN, the share of its nodes the GN holds (a
        # node of the same class within DESIGN.md's radius), the position error of those,
        # and the GN nodes within 15 m of the LN's nodes that are no truth ROI (chance
        # partners).
        held_share, held_err, false_near = [], [], []
        gxy = np.column_stack([gn.records["x"], gn.records["y"]])
        gn_shift = np.subtract(gn.map_frame.origin, truth_net.map_frame.origin)
        gxy_t = gxy + gn_shift  # GN nodes in the truth's map frame
        txy = np.column_stack([truth_net.records["x"], truth_net.records["y"]])
        is_truth = np.zeros(len(gn), bool)
        if len(gn) and len(truth_net):
            d, j = cKDTree(txy).query(gxy_t)
            radius = np.maximum(1.0, truth_net.records["major_m"][j] / 2)
            is_truth = (d <= radius) & (truth_net.records["label"][j] == gn.records["label"])
        gtree = cKDTree(gxy_t) if len(gn) else None
        for ln, t_true, true_xy in route_lns(bag, args.length, args.step, 15.0, seed=0):
            if gtree is not None:
                d, j = gtree.query(true_xy)
                tj = cKDTree(txy).query(true_xy)[1]  # the truth ROI each LN node is
                radius = np.maximum(1.0, truth_net.records["major_m"][tj] / 2)
                ok = (d <= radius) & (gn.records["label"][j] == truth_net.records["label"][tj])
                held_share.append(float(ok.mean()))
                held_err.extend(d[ok].tolist())
                near = gtree.query_ball_point(true_xy, 15.0)
                idx = np.unique(np.concatenate([np.asarray(n, int) for n in near]))
                false_near.append(int((~is_truth[idx]).sum()) if idx.size else 0)
            t0 = time.perf_counter()
            res = matcher.match(ln)
            times.append(1e3 * (time.perf_counter() - t0))
            counts["lns"] += 1
            if res.status != "fix":
                continue
            counts["fix"] += 1
            # Error of the fix at the LN's drift-free positions (DESIGN.md's "correct").
            odom_true = t_true.inverse().apply(true_xy)
            err = np.hypot(*(res.map_T_odom.apply(odom_true) - true_xy).T).max()
            counts["correct_2m"] += int(err <= 2.0)
            counts["false_fix_10m"] += int(err > 10.0)
        n = max(counts["lns"], 1)
        summary["runs"][name] = {**counts, "gn_rois": len(gn),
                                 "ln_nodes_held_median": float(np.median(held_share))
                                 if held_share else None,
                                 "held_position_error_m_median": float(np.median(held_err))
                                 if held_err else None,
                                 "false_gn_nodes_near_ln_median": float(np.median(false_near))
                                 if false_near else None,
                                 "correct_rate": counts["correct_2m"] / n,
                                 "no_fix_rate": 1 - counts["fix"] / n,
                                 "false_fix_10m_rate": counts["false_fix_10m"] / n,
                                 "median_ms": float(np.median(times)) if times else None}
        print(name, summary["runs"][name], flush=True)
    _write(RESULTS / f"orbital_gn_matcher_{bag.name}.json", summary)
    lines = [f"# The matcher on the GN detected in {bag.name} vs its truth catalogue", "",
             f"`{summary['command']}`: LNs = truth ROIs within 15 m of each {args.length:g} m "
             f"stretch of the route (a start every {args.step:g} m), 1 % drift, random odom "
             "frame; darces_matcher.Matcher with its defaults. Correct: every LN node within "
             "2 m; false fix: off by more than 10 m.", "",
             "Held: LN nodes with a GN node of their class within max(1 m, half the truth "
             "major axis) (median over LNs); error: distance of those (median); false GN "
             "nodes: GN nodes matching no truth ROI within 15 m of an LN's nodes (median).", "",
             "| GN | ROIs | LNs | correct % | no fix % | false fix >10 m % | median ms | "
             "LN nodes held % | held error m | false GN nodes near LN |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for name, r in summary["runs"].items():
        held = r["ln_nodes_held_median"]
        err = r["held_position_error_m_median"]
        lines.append(f"| {name} | {r['gn_rois']} | {r['lns']} | {100 * r['correct_rate']:.1f} | "
                     f"{100 * r['no_fix_rate']:.1f} | {100 * r['false_fix_10m_rate']:.1f} | "
                     f"{r['median_ms'] and round(r['median_ms'], 1)} | "
                     f"{'n/a' if held is None else round(100 * held, 1)} | "
                     f"{'n/a' if err is None else round(err, 2)} | "
                     f"{r['false_gn_nodes_near_ln_median']} |")
    (RESULTS / f"orbital_gn_matcher_{bag.name}.md").write_text("\n".join(lines) + "\n")


def cmd_figure(args) -> None:
    """A full-resolution crop (x2) around the densest GN area: detections (rocks red,
    outcrops cyan) and truth ROIs (green), ellipses; bench/results/orbital_gn_<bag>_crop.png."""
    import cv2
    import numpy as np
    import rasterio
    from rasterio.windows import Window

    from roi_network.geojson import read_geojson

    bag = Path(args.bag)
    gn = read_geojson(args.gn)
    truth = read_geojson(bag / "truth" / "rois.geojson")
    with rasterio.open(bag / "orbital.tif") as ds:
        inv, t = ~ds.transform, ds.transform
        ox, oy = gn.map_frame.origin
        cols, rows = zip(*[inv * (x + ox, y + oy) for x, y in zip(gn.records["x"],
                                                                   gn.records["y"], strict=True)],
                         strict=True)
        h, _, _ = np.histogram2d(rows, cols, bins=ds.height // args.size,
                                 range=[[0, ds.height], [0, ds.width]])
        i, j = np.unravel_index(np.argmax(h), h.shape)
        r0, c0 = int(i * args.size), int(j * args.size)
        img = ds.read([1, 2, 3], window=Window(c0, r0, args.size, args.size))
    img = np.ascontiguousarray(np.moveaxis(img, 0, -1)[..., ::-1])
    img = cv2.resize(img, None, fx=2, fy=2, interpolation=cv2.INTER_NEAREST)
    for net, colours in ((truth, {1: (0, 220, 0), 2: (0, 220, 0)}),
                         (gn, {1: (40, 40, 255), 2: (255, 255, 0)})):
        nox, noy = net.map_frame.origin
        for r in net.records:
            c, rr = inv * (r["x"] + nox, r["y"] + noy)
            centre = (round((c - c0) * 2), round((rr - r0) * 2))
            axes = (max(1, round(r["major_m"] / t.a)), max(1, round(r["minor_m"] / t.a)))
            cv2.ellipse(img, centre, axes, -np.degrees(r["angle_rad"]), 0, 360,
                        colours[int(r["label"])], 1, cv2.LINE_AA)
    out = RESULTS / f"orbital_gn_{bag.name}_crop.png"
    cv2.imwrite(str(out), img)
    print(out)


def _write(path: Path, doc: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text(json.dumps(doc, indent=1) + "\n")
    tmp.replace(path)


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="cmd", required=True)
    q = sub.add_parser("quality")
    q.add_argument("--bags", nargs="+", default=DEFAULT_BAGS)
    q.add_argument("--train-bags", nargs="+", default=TRAIN_BAGS)
    q.add_argument("--recipes", default="sun_aware,no_sun,paper")
    q.add_argument("--model", help="model of the sun_aware recipe (default: committed one)")
    q.add_argument("--append", action="store_true", help="keep earlier runs of other bags")
    q.set_defaults(func=cmd_quality)
    c = sub.add_parser("centres")
    c.add_argument("--bags", nargs="+", default=DEFAULT_BAGS)
    c.add_argument("--recipes", default="sun_aware,no_sun,paper")
    c.set_defaults(func=cmd_centres)
    s = sub.add_parser("scale")
    s.add_argument("--ortho", required=True)
    s.add_argument("--tiles", type=int, nargs="+", default=[1, 2, 3])
    s.add_argument("--tile-px", type=int, default=1024, help="window core (fixed across sizes)")
    s.set_defaults(func=cmd_scale)
    m = sub.add_parser("matcher")
    m.add_argument("--bag", required=True, help="bag of the GN (its truth for reference)")
    m.add_argument("--gn", required=True, nargs="+", help="detected GN(s); one row each")
    m.add_argument("--length", type=float, default=400.0, help="LN route stretch, m")
    m.add_argument("--step", type=float, default=20.0, help="between LN starts, m")
    m.set_defaults(func=cmd_matcher)
    f = sub.add_parser("figure")
    f.add_argument("--bag", required=True)
    f.add_argument("--gn", required=True)
    f.add_argument("--size", type=int, default=320, help="crop side, raster pixels")
    f.set_defaults(func=cmd_figure)
    args = p.parse_args()
    WORK.mkdir(parents=True, exist_ok=True)
    args.func(args)


if __name__ == "__main__":
    main()
