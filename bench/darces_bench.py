"""DARCES matcher benchmarks; results go to bench/results/darces_<mode>.{json,md}.

Modes:
    paper   the paper's protocol (Sec. 7.2-7.3) on a generated 174-ROI GN, every LN the
            protocol yields for darces, and the first ``--baseline-lns`` for the
            baselines (original DARCES, KISS-Matcher) in the same run.
    stress  the same with 30 % LN outliers and 10 % label flips.
    scale   GN sizes 10^3..10^6 with no position prior: index build time and memory
            apart, per-LN time (median, p95) and outcome rates.

Usage (from the repository root, after ``source env.sh``)::

    python bench/darces_bench.py paper
    python bench/darces_bench.py stress
    python bench/darces_bench.py scale --sizes 1000,10000,100000,1000000 --scale-lns 100
"""

from __future__ import annotations

import argparse
import gc
import json
import time
from pathlib import Path
from typing import Any

import numpy as np
import psutil

from darces_matcher.eval_cli import main as darces_eval
from darces_matcher.eval_cli import oracle_error
from darces_matcher.gn_generator import GnSpec, generate_gn
from darces_matcher.matcher import Matcher
from darces_matcher.simulate import SimOptions, iter_lns, transform_error
from roi_network.geojson import write_geojson
from roi_network.records import xy

RESULTS = Path(__file__).resolve().parent / "results"
GN_FILE = RESULTS / "darces_gn174.geojson"


def _gn_file() -> Path:
    """The 174-ROI benchmark GN (generator seed 1), written once."""
    RESULTS.mkdir(parents=True, exist_ok=True)
    if not GN_FILE.exists():
        write_geojson(generate_gn(GnSpec(n_rois=174), seed=1), GN_FILE)
    return GN_FILE


def _eval(mode: str, extra: list[str], baseline_lns: int) -> dict[str, Any]:
    out = RESULTS / f"darces_{mode}.json"
    argv = ["--gn", str(_gn_file()), "--seed", "0", "--baseline-max-lns", str(baseline_lns),
            "--json", str(out), "--progress", *extra]
    t0 = time.perf_counter()
    darces_eval(argv)
    report = json.loads(out.read_text())
    report["command"] = "darces_eval " + " ".join(
        a if a != str(out) else f"bench/results/darces_{mode}.json" for a in argv
    ).replace(str(GN_FILE), "bench/results/darces_gn174.geojson")
    report["bench_wall_s"] = time.perf_counter() - t0
    out.write_text(json.dumps(report, indent=2) + "\n")
    _write_eval_md(mode, report)
    return report


def _pct(x: float) -> str:
    return f"{100 * x:.2f} %"


def _write_eval_md(mode: str, r: dict[str, Any]) -> None:
    lines = [
        f"# darces_matcher benchmark: {mode}",
        "",
        f"Command: `{r['command']}` (via `python bench/darces_bench.py {mode}`).",
        "",
        f"GN: {r['gn']['rois']} ROIs (visible to the matchers: {r['gn']['visible_rois']}). "
        f"LNs: {r['lns']}. Oracle fit within 2 m (ceiling of *correct*): "
        f"{_pct(r['oracle_within_2m_rate'])}.",
        "",
        "| method | LNs | correct (2 m) | false fix | no fix | correct match | false match "
        "| false fix > 10 m | time median | time p95 |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    rows = dict(r["methods"])
    if "same_subset_as_baselines" in rows.get("darces", {}):
        rows = {"darces": rows["darces"],
                "darces (baseline subset)": rows["darces"]["same_subset_as_baselines"],
                **{k: v for k, v in rows.items() if k != "darces"}}
    for name, m in rows.items():
        lines.append(
            f"| {name} | {m['lns']} | {_pct(m['correct_rate'])} | {_pct(m['false_fix_rate'])} "
            f"| {_pct(m['no_fix_rate'])} | {_pct(m['correct_match_rate'])} "
            f"| {_pct(m['false_match_rate'])} | {_pct(m['false_fix_10m_rate'])} "
            f"| {m['time_ms']['median']:.2f} ms | {m['time_ms']['p95']:.2f} ms |"
        )
    lines += ["", f"Options: `{json.dumps(r['options'])}`", ""]
    (RESULTS / f"darces_{mode}.md").write_text("\n".join(lines))


def scale(sizes: list[int], n_lns: int) -> dict[str, Any]:
    """Index build cost and per-LN matching cost against GN size (no position prior)."""
    process = psutil.Process()
    rows = []
    for n in sizes:
        gn = generate_gn(GnSpec(n_rois=n, aspect=1.0), seed=1)
        gc.collect()
        rss0 = process.memory_info().rss
        t0 = time.perf_counter()
        matcher = Matcher(gn)
        build_s = time.perf_counter() - t0
        rss1 = process.memory_info().rss
        gn_pts, labels = xy(gn.records), gn.records["label"]
        times, outcome = [], {"correct": 0, "correct_match": 0, "false_fix_10m": 0, "no_fix": 0,
                              "no_control_triplet": 0}
        count = 0
        for sim in iter_lns(gn, SimOptions(walks_per_pair=1), seed=0, max_lns=n_lns):
            count += 1
            t1 = time.perf_counter()
            result = matcher.match(sim.records)
            times.append(1e3 * (time.perf_counter() - t1))
            if not result.is_fix:
                outcome["no_fix"] += 1
                outcome["no_control_triplet"] += result.reason == "no_control_triplet"
                continue
            error = transform_error(result.map_T_odom, sim, gn_pts)
            outcome["correct"] += error <= 2.0
            outcome["correct_match"] += error <= oracle_error(sim, gn_pts, labels) + 2.0
            outcome["false_fix_10m"] += error > 10.0
        stats = matcher.index.stats
        row = {
            "rois": n, "area_km2": n / GnSpec().density_per_km2,
            "index_triangles": stats.n_triangles, "index_max_side_m": stats.max_side_m,
            "index_build_s": build_s, "index_memory_mb": stats.memory_bytes / 1e6,
            "rss_growth_mb": (rss1 - rss0) / 1e6, "lns": count,
            "time_ms_median": float(np.median(times)),
            "time_ms_p95": float(np.percentile(times, 95)),
            **{f"{k}_rate": v / count for k, v in outcome.items()},
        }
        rows.append(row)
        print(json.dumps(row), flush=True)
        del matcher, gn
    report = {"mode": "scale", "lns_per_size": n_lns, "rows": rows,
              "command": f"python bench/darces_bench.py scale --sizes "
                         f"{','.join(map(str, sizes))} --scale-lns {n_lns}"}
    (RESULTS / "darces_scale.json").write_text(json.dumps(report, indent=2) + "\n")
    lines = [
        "# darces_matcher benchmark: scale (no position prior)",
        "",
        f"Command: `{report['command']}`. GN: generated, 400 ROIs/km^2, square area; "
        "LNs: paper protocol (one walk per start/end pair, pairs in seeded order).",
        "",
        "| GN ROIs | area km^2 | triangles | max side m | build s | index MB | RSS growth MB "
        "| LNs | median ms | p95 ms | correct (2 m) | correct match | false fix > 10 m "
        "| no fix (of which no usable triplet) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in rows:
        lines.append(
            f"| {r['rois']} | {r['area_km2']:.1f} | {r['index_triangles']} "
            f"| {r['index_max_side_m']:.0f} | {r['index_build_s']:.2f} "
            f"| {r['index_memory_mb']:.0f} | {r['rss_growth_mb']:.0f} | {r['lns']} "
            f"| {r['time_ms_median']:.1f} | {r['time_ms_p95']:.1f} | {_pct(r['correct_rate'])} "
            f"| {_pct(r['correct_match_rate'])} | {_pct(r['false_fix_10m_rate'])} "
            f"| {_pct(r['no_fix_rate'])} ({_pct(r['no_control_triplet_rate'])}) |"
        )
    (RESULTS / "darces_scale.md").write_text("\n".join(lines) + "\n")
    return report


def main() -> None:
    """Command-line entry point."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("mode", choices=["paper", "stress", "scale"])
    p.add_argument("--baseline-lns", type=int, default=1000,
                   help="LNs for the baselines (the first of the same stream)")
    p.add_argument("--max-lns", type=int, default=None, help="cap the LNs (paper/stress)")
    p.add_argument("--sizes", default="1000,10000,100000,1000000")
    p.add_argument("--scale-lns", type=int, default=100)
    args = p.parse_args()
    cap = ["--max-lns", str(args.max_lns)] if args.max_lns else []
    if args.mode == "paper":
        _eval("paper", cap, args.baseline_lns)
    elif args.mode == "stress":
        _eval("stress", ["--outliers", "0.3", "--label-flips", "0.1", *cap], args.baseline_lns)
    else:
        scale([int(s) for s in args.sizes.split(",")], args.scale_lns)


if __name__ == "__main__":
    main()
