"""Rover ROI detection, tracking and LN benchmarks; results in RESULTS/roi_<name>.{json,md}.

For each bag: the LN built by ``roi_detector ln`` (same library code) with the truth
trajectory re-expressed in odom as odometry (detection geometry alone) and, when a
``vo.tum`` is given per bag, with rover_vo odometry (its nodes' covariance from the
``vo_covariance.txt`` beside it when there is one, as ``roi_detector ln`` takes it; the
truth odometry carries none: 1 % of the distance); judged by ``roi_detector eval``'s counts
(DESIGN.md's matching rule): recall of the truth ROIs above the rover thresholds within
15 m of the route, precision, classification accuracy, LN node error, and
``Matcher(gn).match(ln)`` against the truth GN. Speed: detection time per stereo pair
with OpenCV and BLAS on one thread (``--threads 1``).

Usage (from the repository root, after ``source env.sh``)::

    python bench/roi_bench.py --name eval bags/atacama_1km_s1 bags/atacama_1km_s2 --jobs 2
    python bench/roi_bench.py --name recipes --every 2 --recipes bags/quick
    python bench/roi_bench.py --name cameras_other --as-they-come bags/quick_cam1024_s7
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

#: Where result files go: $BENCH_RESULTS (`make bench`: bench/results/current/), else
#: out/bench/results/.
RESULTS = Path(os.environ.get("BENCH_RESULTS")
               or Path(__file__).resolve().parents[1] / "out" / "bench" / "results")
#: Scratch space of the runs (caches, LNs, plots): $BENCH_WORK, else out/bench/work/.
WORK = Path(os.environ.get("BENCH_WORK")
            or Path(__file__).resolve().parents[1] / "out" / "bench" / "work")


def _one_thread() -> None:
    # Before numpy/OpenCV start their pools: "pairs per second on one core".
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        os.environ[var] = "1"


def run_bag(bag: str, model: str | None, every: int, cfg, tag: str, work: Path,
            vo: str | None = None, gn: str | None = None) -> dict:
    """LN + evaluation of one bag with one configuration."""
    from roi_detector.evaluation import evaluate_ln
    from roi_detector.local_network_build import build_ln, odometry_covariance_file
    from roi_detector.truth import Truth
    from roi_network.geojson import read_geojson

    name = Path(bag).name
    work.mkdir(parents=True, exist_ok=True)
    odom = work / f"{name}_truth_odom.tum"
    Truth.load(bag).write_odom_tum(odom)
    out = {"bag": name, "config": tag, "every": every}
    for kind, path in (("truth_odometry", str(odom)), ("vo_odometry", vo)):
        if path is None:
            out[kind] = {"status": "not run (no rover_vo odometry file given)"}
            continue
        # The odometry's own covariance when rover_vo (or globloc run) wrote one beside
        # it, as roi_detector ln takes it; the truth odometry has none (1 % drift model).
        cov_file = odometry_covariance_file(path, None)
        t0 = time.perf_counter()
        ln, stats = build_ln(bag, path, model, cfg, every=every, log=lambda m: None,
                             odometry_cov=cov_file)
        stats["odometry_covariance"] = str(cov_file) if cov_file else "1 % drift model"
        wall = time.perf_counter() - t0
        ln_path = work / f"{name}_{tag}_{kind}_ln.geojson"
        ln.save(ln_path, stats)
        rep = evaluate_ln(str(ln_path), bag, plot=str(work / f"{name}_{tag}_{kind}.png"))
        truth, nodes = Truth.load(bag), read_geojson(ln_path).records
        rep["matcher"] = {"truth_gn": match_ln(nodes, read_geojson(
            Path(bag) / "truth" / "rois.geojson"), truth)}
        if gn:
            rep["matcher"]["gn"] = match_ln(nodes, read_geojson(gn), truth)
        rep["stats"] = stats
        rep["wall_s"] = round(wall, 1)
        out[kind] = rep
        print(f"{name} {tag} {kind}: {_line(rep)}", flush=True)
    return out


def _true_map_t_odom(truth):
    """The truth's map_T_odom (the first truth pose, 2D)."""
    from scipy.spatial.transform import Rotation

    from roi_network.transform import Rigid2D

    tr = truth.trajectory
    yaw = Rotation.from_quat(tr.q[0]).as_euler("ZYX")[0]
    return Rigid2D(float(yaw), float(tr.p[0, 0]), float(tr.p[0, 1]))


def match_ln(ln, gn, truth) -> dict:
    """``Matcher(gn).match(ln)`` on LN records (odom): fix or not, and its error at the
    LN nodes (m) against the truth's map_T_odom."""
    import numpy as np

    from roi_network.records import xy

    try:
        from darces_matcher.matcher import Matcher
    except ImportError:
        return {"status": "darces_matcher not installed"}
    if len(ln) < 3:
        return {"status": "no_fix", "reason": "too_few_nodes"}
    res = Matcher(gn).match(ln)
    out = {"status": res.status, "reason": res.reason, "support": int(res.support)}
    if res.status == "fix":
        true_t = _true_map_t_odom(truth)
        # The 2D map_T_odom ignores the first pose's roll and pitch: compare where both
        # place the LN nodes.
        p = xy(ln)
        err = np.linalg.norm(res.map_T_odom.apply(p) - true_t.apply(p), axis=1)
        out["error_m_mean"] = float(err.mean())
        out["error_m_max"] = float(err.max())
        out["yaw_error_deg"] = float(np.degrees(np.angle(np.exp(1j * (res.map_T_odom.yaw -
                                                                        true_t.yaw)))))
        out["false_fix"] = bool(err.mean() > 10.0)
    return out


def _line(rep: dict) -> str:
    pc = rep["per_class"]
    ne = rep.get("node_error_m", {})
    m = rep["matcher"]["truth_gn"]
    return (f"rock R {pc['rock']['truth_found']}/{pc['rock']['truth_wanted']} "
            f"(in view {pc['rock']['truth_in_view_found']}/{pc['rock']['truth_in_view']}) "
            f"P {pc['rock']['true_nodes']}/{pc['rock']['ln_nodes']}; outcrop R "
            f"{pc['outcrop']['truth_found']}/{pc['outcrop']['truth_wanted']} "
            f"(in view {pc['outcrop']['truth_in_view_found']}/"
            f"{pc['outcrop']['truth_in_view']}) P "
            f"{pc['outcrop']['true_nodes']}/{pc['outcrop']['ln_nodes']}; class acc "
            f"{rep['classification_accuracy']}; node err median {ne.get('median')}; matcher "
            f"{m.get('status')} {m.get('reason', '')} err {m.get('error_m_mean')}; "
            f"{rep['stats']['detect_s_per_pair']:.3f} s/pair")


def _pct(x) -> str:
    return "-" if x is None else f"{100 * x:.1f} %"


def write_markdown(path: Path, results: list[dict], meta: dict) -> None:
    """The results as a table per configuration and odometry."""
    lines = [f"# roi_bench: {meta['name']}", "",
             f"Command: `{meta['command']}`  ", f"Date: {meta['date']}; machine: "
             f"{meta['machine']}", "",
             "| bag | config | odometry | rock recall (in view) | rock precision | "
             "outcrop recall (in view) | outcrop precision | class. acc. | LN nodes | "
             "node err median / p90 (m) | matcher (truth GN) | matcher (detected GN) | "
             "s/pair (1 thread) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        for kind in ("truth_odometry", "vo_odometry"):
            rep = r[kind]
            if "per_class" not in rep:
                lines.append(f"| {r['bag']} | {r['config']} | {kind} | {rep['status']} |"
                             " | | | | | | | | |")
                continue
            pc = rep["per_class"]
            ne = rep.get("node_error_m", {})

            def _m(m):
                if m is None:
                    return "-"
                return m["status"] + (f", {m['error_m_mean']:.2f} m" if "error_m_mean" in m
                                      else f" ({m.get('reason', '')})")
            err = (f"{ne['median']:.2f} / {ne['p90']:.2f}" if ne else "-")
            lines.append(
                f"| {r['bag']} | {r['config']} | {kind} | "
                f"{pc['rock']['truth_found']}/{pc['rock']['truth_wanted']} "
                f"({pc['rock']['truth_in_view_found']}/{pc['rock']['truth_in_view']}) | "
                f"{_pct(pc['rock']['precision'])} ({pc['rock']['true_nodes']}/"
                f"{pc['rock']['ln_nodes']}) | "
                f"{pc['outcrop']['truth_found']}/{pc['outcrop']['truth_wanted']} "
                f"({pc['outcrop']['truth_in_view_found']}/{pc['outcrop']['truth_in_view']}) | "
                f"{_pct(pc['outcrop']['precision'])} ({pc['outcrop']['true_nodes']}/"
                f"{pc['outcrop']['ln_nodes']}) | {_pct(rep['classification_accuracy'])} | "
                f"{rep['ln_nodes']} | {err} | {_m(rep['matcher']['truth_gn'])} | "
                f"{_m(rep['matcher'].get('gn'))} | "
                f"{rep['stats']['detect_s_per_pair']:.3f} |")
    lines += ["", "Recall: truth ROIs above the rover thresholds within 15 m of the route found "
              "by an LN node of their class (DESIGN.md's rule: centre within max(1 m, half "
              "the truth major axis)); in view: the same over the truth ROIs whose centre "
              "was in the left image, at most 20 m deep, in >= 3 stereo pairs; precision: "
              "LN nodes of a class that match a truth ROI of that class; classification "
              "accuracy: LN nodes matching a truth ROI that carry its class. s/pair: "
              "detection (+ classification, elevation map) per stereo pair, one thread, on "
              "the shared 2-core machine (other jobs running)."]
    tmp = path.with_name(path.name + ".tmp")
    tmp.write_text("\n".join(lines) + "\n")
    tmp.replace(path)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("bags", nargs="+")
    ap.add_argument("--name", default="eval")
    ap.add_argument("--every", type=int, default=1,
                    help="one stereo pair in N (the elevation map wants every view)")
    ap.add_argument("--model", default=None, help="rover model (.npz); default: committed")
    ap.add_argument("--vo", action="append", default=[],
                    help="BAG_NAME=DIR/vo.tum: rover_vo odometry of a bag")
    ap.add_argument("--gn", action="append", default=[],
                    help="BAG_NAME=GN.geojson: also match the LN against this (detected) GN")
    ap.add_argument("--recipes", action="store_true",
                    help="also the paper's per_pair method")
    ap.add_argument("--as-they-come", action="store_true",
                    help="also the detector on the stereo pairs as they come (working_fx_px "
                    "0), beside the default, which resamples a camera finer than its "
                    "working resolution")
    ap.add_argument("--threads", type=int, default=1)
    ap.add_argument("--jobs", type=int, default=1,
                    help="bags run side by side, one process each (default 1)")
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error("--jobs must be at least 1")
    if args.threads == 1:
        _one_thread()
    import cv2

    cv2.setNumThreads(args.threads)
    from roi_detector.rover_pipeline import RoverConfig

    configs = [("elevation_map", RoverConfig(), args.model)]
    if args.recipes:
        configs.append(("per_pair", RoverConfig(method="per_pair"), args.model))
    if args.as_they_come:
        configs.append(("elevation_map_as_they_come", RoverConfig(working_fx_px=0.0),
                        args.model))
    vo = dict(v.split("=", 1) for v in args.vo)
    gns = dict(v.split("=", 1) for v in args.gn)
    work = WORK / f"roi_{args.name}"
    runs = [(bag, model, args.every, cfg, tag, work, vo.get(Path(bag).name),
             gns.get(Path(bag).name)) for bag in args.bags for tag, cfg, model in configs]
    if args.jobs == 1:
        results = [run_bag(*r) for r in runs]
    else:
        # One process per bag (forked after the thread limits above), results in order.
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=args.jobs) as pool:
            results = list(pool.map(run_bag, *zip(*runs, strict=True)))
    meta = {"name": args.name, "command": "python bench/roi_bench.py " + " ".join(
        argv if argv is not None else sys.argv[1:]), "date": time.strftime("%Y-%m-%d %H:%M"),
            "machine": f"{os.cpu_count()} cores, shared with other jobs"}
    RESULTS.mkdir(parents=True, exist_ok=True)
    out = RESULTS / f"roi_{args.name}.json"
    out.write_text(json.dumps({"meta": meta, "results": results}, indent=1) + "\n")
    write_markdown(RESULTS / f"roi_{args.name}.md", results, meta)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
