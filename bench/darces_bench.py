"""DARCES matcher benchmarks; results go to RESULTS/darces_<mode>.{json,md}.

Modes:
    paper   the paper's protocol (Sec. 7.2-7.3) on a generated 174-ROI GN, every LN the
            protocol yields for darces, and the first ``--baseline-lns`` for the
            baseline (the original DARCES) in the same run.
    stress  the same with 30 % LN outliers and 10 % label flips.
    scale   GN sizes 10^3..10^6 with no position prior: index build time and memory
            apart, per-LN time (median, p95) and outcome rates.
    generality  the paper protocol (clean and stressed) on every GN of the evaluation
            family (``gn_generator.FAMILY``), the odds decision (``darces``: Chernoff
            and Markov bounds, decided again on the EM's alignment when the hard refit
            falls short) beside the paper's original DARCES (``darces_original``), in
            one table.
    firstfix    the paper protocol's LNs fed as prefixes, node by node (as the rover
            drives): nodes and distance at the first fix, and whether it is right.
    null    stressed LNs of each family GN against another GN of the same statistics:
            every fix would be a chance alignment (calibration of the odds decision).
    tracknull   the same LNs tracked (``Matcher.track``) from a prior placed at chance
            (``--prior-sigmas``): the track decision's calibration.
    quick   a perfect LN of the truth ROIs a bag's route passes (1 % drift, random odom
            frame), matched against the bag's truth ROIs, ``--trials`` times.

Usage (from the repository root, after ``source env.sh``)::

    python bench/darces_bench.py paper
    python bench/darces_bench.py stress
    python bench/darces_bench.py scale --sizes 1000,10000,100000,1000000 --scale-lns 100
    python bench/darces_bench.py paper --max-lns 2000 --baseline-lns 1000 \
        --methods darces,darces_original --tag odds
    python bench/darces_bench.py generality --max-lns 400
    python bench/darces_bench.py firstfix --max-lns 300
    python bench/darces_bench.py quick --bag /work/bags/quick --trials 20
    python bench/darces_bench.py tracknull --max-lns 100 --prior-sigmas 5,15
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import time
from pathlib import Path
from typing import Any

import numpy as np
import psutil

from darces_matcher.eval_cli import CORRECT_M, GROSS_M, evaluate, oracle_error
from darces_matcher.eval_cli import main as darces_eval
from darces_matcher.gn_generator import FAMILY, GnSpec, family_gn, generate_gn
from darces_matcher.matcher import MatchConfig, Matcher
from darces_matcher.simulate import (
    SimOptions,
    corridor_ln,
    iter_lns,
    ln_prefix,
    transform_error,
)
from roi_network.geojson import read_geojson, write_geojson
from roi_network.records import xy
from roi_network.transform import Rigid2D

#: Where result files go: $BENCH_RESULTS (`make bench`: bench/results/current/), else
#: out/bench/results/.
RESULTS = Path(os.environ.get("BENCH_RESULTS")
               or Path(__file__).resolve().parents[1] / "out" / "bench" / "results")
#: Scratch space of the runs (caches, LNs, plots): $BENCH_WORK, else out/bench/work/.
WORK = Path(os.environ.get("BENCH_WORK")
            or Path(__file__).resolve().parents[1] / "out" / "bench" / "work")
GN_FILE = WORK / "darces_gn174.geojson"


def _gn_file() -> Path:
    """The 174-ROI benchmark GN (generator seed 1), written once."""
    GN_FILE.parent.mkdir(parents=True, exist_ok=True)
    if not GN_FILE.exists():
        write_geojson(generate_gn(GnSpec(n_rois=174), seed=1), GN_FILE)
    return GN_FILE


def _eval(mode: str, extra: list[str], baseline_lns: int, tag: str = "") -> dict[str, Any]:
    name = f"{mode}_{tag}" if tag else mode
    out = RESULTS / f"darces_{name}.json"
    argv = ["--gn", str(_gn_file()), "--seed", "0", "--baseline-max-lns", str(baseline_lns),
            "--json", str(out), "--progress", *extra]
    t0 = time.perf_counter()
    darces_eval(argv)
    report = json.loads(out.read_text())
    report["command"] = "darces_eval " + " ".join(
        a if a != str(out) else f"darces_{name}.json" for a in argv
    ).replace(str(GN_FILE), "darces_gn174.geojson")
    report["bench_wall_s"] = time.perf_counter() - t0
    out.write_text(json.dumps(report, indent=2) + "\n")
    _write_eval_md(name, report)
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


def family_options(density_per_km2: float, **overrides: Any) -> SimOptions:
    """The paper protocol on a family GN: 600 m..1 km routes; 19..29 nodes where the GN
    is dense enough for such routes (>= 200 ROIs/km^2), else as many as a 1 km route
    through that density passes (24 x sqrt(density / 400) +/- 20 %, at least 6)."""
    if density_per_km2 >= 200.0:
        # Many start/end pairs: two walks each, so that a few hundred LNs see many routes.
        return SimOptions(walks_per_pair=2, **overrides)
    mid = max(7.5, 24.0 * np.sqrt(density_per_km2 / 400.0))
    return SimOptions(min_nodes=max(6, round(0.8 * mid)), max_nodes=round(1.2 * mid),
                      **overrides)


def _generality_stem(tag: str) -> Path:
    """The results' path without suffix: ``darces_generality`` or
    ``darces_generality_<tag>``; the GN rows are in ``<stem>_parts/``."""
    return RESULTS / (f"darces_generality_{tag}" if tag else "darces_generality")


def _generality_parts(tag: str) -> Path:
    """The directory of the GN rows of a generality table (one JSON file per GN)."""
    return WORK / f"{_generality_stem(tag).name}_parts"


def generality(names: list[str], n_lns: int, stress_lns: int, seed: int,
               methods: list[str] | None = None, tag: str = "") -> dict[str, Any]:
    """The paper protocol on every family GN, odds decision (Chernoff and Markov bounds)
    beside the original DARCES. ``tag``: a table of its own (:func:`_generality_stem`),
    e.g. one method on more LNs beside the main table."""
    methods = methods or ["darces", "darces_original"]
    parts = _generality_parts(tag)
    rows = []
    for name in names:
        gn = family_gn(name, seed=1)
        spec = FAMILY[name]
        row: dict[str, Any] = {"gn": name, "description": spec.description, "rois": len(gn),
                               "density_per_km2": spec.density_per_km2}
        for protocol, extra, count in (("clean", {}, n_lns),
                                       ("stress", {"outliers": 0.3, "label_flips": 0.1},
                                        stress_lns)):
            if count <= 0:
                continue
            options = family_options(spec.density_per_km2, **extra)
            report = evaluate(gn, methods, options, seed=seed, max_lns=count)
            row[protocol] = {"lns": report["lns"], "min_nodes": options.min_nodes,
                             "max_nodes": options.max_nodes,
                             "oracle_within_2m_rate": report["oracle_within_2m_rate"],
                             "methods": report["methods"]}
        rows.append(row)
        # Each GN's row as soon as it is measured: runs over parts of the family (one
        # process each) are merged into the table by ``generality --merge``.
        parts.mkdir(parents=True, exist_ok=True)
        _write_json_atomic(parts / f"{name}.json", {**row, "lns_per_gn": n_lns,
                                                     "stress_lns_per_gn": stress_lns,
                                                     "seed": seed})
        print(json.dumps({"gn": name, **{p: {m: {k: row[p]["methods"][m][k] for k in (
            "correct_match_rate", "false_match_rate", "no_fix_rate", "no_fix_oracle_fit_rate")}
            for m in methods} for p in ("clean", "stress") if p in row}}), flush=True)
    return merge_generality(tag)


def merge_generality(tag: str = "") -> dict[str, Any]:
    """The family table from every GN row measured so far (family order)."""
    stem, parts = _generality_stem(tag), _generality_parts(tag)
    rows = [json.loads((parts / f"{name}.json").read_text()) for name in FAMILY
            if (parts / f"{name}.json").exists()]
    counts = sorted({(r["lns_per_gn"], r["stress_lns_per_gn"], r["seed"]) for r in rows})
    tagged = f" --tag {tag}" if tag else ""
    # A tagged table's methods are its own choice: its command names them.
    methods = sorted({m for r in rows for p in ("clean", "stress") if p in r
                      for m in r[p]["methods"]})
    chosen = f" --methods {','.join(methods)}{tagged}" if tag else ""
    command = "; ".join(f"python bench/darces_bench.py generality --max-lns {n} "
                        f"--stress-lns {m} --seed {seed}{chosen} --gns "
                        + ",".join(r["gn"] for r in rows
                                   if (r["lns_per_gn"], r["stress_lns_per_gn"], r["seed"])
                                   == (n, m, seed))
                        for n, m, seed in counts)
    command += f"; python bench/darces_bench.py generality --merge{tagged}"
    report = {"mode": "generality", "gn_seed": 1, "rows": rows, "command": command,
              "timing": "wall time of match() per LN on a 2-core machine, other jobs "
                        "beside it (docs/matcher.md says which, per run)"}
    _write_json_atomic(stem.with_name(f"{stem.name}.json"), report)
    _write_generality_md(report, stem.with_name(f"{stem.name}.md"))
    return report


def _one_decimal(x: float | None) -> str:
    return "-" if x is None else f"{x:.1f}"


def _write_json_atomic(path: Path, report: dict[str, Any]) -> None:
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(report, indent=2) + "\n")
    tmp.replace(path)


def _write_generality_md(report: dict[str, Any], path: Path) -> None:
    lines = [
        "# darces_matcher benchmark: generality (evaluation family of GNs)",
        "",
        f"Command: `{report['command']}`. GNs: `darces_eval --synthetic NAME --gn-seed 1`. "
        "LNs: paper protocol (600 m..1 km, 1 % drift, 20 % missed; 2 walks per pair at "
        ">= 200 ROIs/km^2, else 16 and fewer nodes, see `family_options`); "
        "stress: 30 % outliers + 10 % label flips. `darces`: the odds decision, chance "
        "alignments bounded by Chernoff's inequality and Markov's, decided again on the "
        "EM's maximum-likelihood alignment when the hard refit falls short, control "
        "triplets over the candidate cap tried last and votes by alignment, the odds "
        "of the triangle hypothesis that found the alignment and a floor under the "
        "Chernoff bound; `original`: the paper's original DARCES (no orientation, no "
        "classes, fixed support/margin counts). "
        "no fix | oracle: abstentions among the LNs the oracle fits within 2 m. "
        f"{report['timing']}.",
        "",
        "| GN | ROIs | protocol | LNs (nodes) | oracle 2 m | method | correct match "
        "| false match | > 10 m | no fix | no fix, oracle fits | median ms | p95 ms "
        "| why no fix |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for row in report["rows"]:
        for protocol in ("clean", "stress"):
            if protocol not in row:
                continue
            p = row[protocol]
            if not p["lns"]:
                continue
            for method, m in p["methods"].items():
                why = ", ".join(f"{k} {v}" for k, v in m["no_fix_reasons"].items())
                lines.append(
                    f"| {row['gn']} | {row['rois']} | {protocol} "
                    f"| {p['lns']} ({p['min_nodes']}-{p['max_nodes']}) "
                    f"| {_pct(p['oracle_within_2m_rate'])} "
                    f"| {method.removeprefix('darces_') if method != 'darces' else method} "
                    f"| {_pct(m['correct_match_rate'])} | {_pct(m['false_match_rate'])} "
                    f"| {_pct(m['false_fix_10m_rate'])} | {_pct(m['no_fix_rate'])} "
                    f"| {_pct(m['no_fix_oracle_fit_rate'])} | {m['time_ms']['median']:.1f} "
                    f"| {m['time_ms']['p95']:.1f} | {why} |")
    lines += ["", "GN descriptions:", ""]
    lines += [f"- `{r['gn']}`: {r['description']}" for r in report["rows"]]
    path.write_text("\n".join(lines) + "\n")


def first_fix(gn, options: SimOptions, config: MatchConfig, n_lns: int, seed: int
              ) -> dict[str, Any]:
    """Feed each LN as prefixes (least travelled node first) until the first fix."""
    matcher = Matcher(gn, config)
    gn_pts, gn_labels = xy(gn.records), gn.records["label"]
    nodes, dist, outcomes = [], [], {"correct_match": 0, "false_match": 0, "gross": 0,
                                     "never": 0}
    count = 0
    for sim in iter_lns(gn, options, seed=seed, max_lns=n_lns):
        count += 1
        for n in range(3, len(sim.records) + 1):
            prefix = ln_prefix(sim, n)
            result = matcher.match(prefix.records)
            if not result.is_fix:
                continue
            error = transform_error(result.map_T_odom, prefix, gn_pts)
            oracle = oracle_error(prefix, gn_pts, gn_labels)
            right = error <= oracle + CORRECT_M
            outcomes["correct_match" if right else "false_match"] += 1
            outcomes["gross"] += error > GROSS_M
            nodes.append(n)
            # sigma = f s / 2 (simulate.py): the distance travelled to the n-th node.
            dist.append(float(2.0 * prefix.sigma.max() / options.noise_fraction))
            break
        else:
            outcomes["never"] += 1
    return {
        "lns": count, "fixed": len(nodes),
        "nodes_median": float(np.median(nodes)) if nodes else None,
        "nodes_p90": float(np.percentile(nodes, 90)) if nodes else None,
        "distance_m_median": float(np.median(dist)) if dist else None,
        "distance_m_p90": float(np.percentile(dist, 90)) if dist else None,
        **{f"{k}_rate": v / max(1, count) for k, v in outcomes.items()},
        **outcomes,
    }


def firstfix(names: list[str], n_lns: int, seed: int) -> dict[str, Any]:
    """First fix on the family GNs, odds decision beside the original DARCES."""
    rows = []
    for name in names:
        gn = family_gn(name, seed=1)
        options = family_options(FAMILY[name].density_per_km2)
        for method, config in (("darces", MatchConfig()),
                               ("darces_original", MatchConfig.original())):
            row = {"gn": name, "method": method, "rois": len(gn),
                   **first_fix(gn, options, config, n_lns, seed)}
            rows.append(row)
            print(json.dumps(row), flush=True)
    report = {"mode": "firstfix", "lns_per_gn": n_lns, "seed": seed, "rows": rows,
              "command": f"python bench/darces_bench.py firstfix --max-lns {n_lns} "
                         f"--seed {seed} --gns {','.join(names)}"}
    _write_json_atomic(RESULTS / "darces_firstfix.json", report)
    lines = ["# darces_matcher benchmark: first fix (LNs fed node by node)", "",
             f"Command: `{report['command']}`. Each LN of the paper protocol is matched "
             "after each node (least travelled first) until the first fix; *right* is a "
             "correct match on the nodes seen so far (error <= oracle + 2 m).", "",
             "| GN | method | LNs | first fix | nodes median | nodes p90 | distance median m "
             "| distance p90 m | right | wrong | > 10 m | never |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(
            f"| {r['gn']} | {r['method']} | {r['lns']} | {r['fixed']} "
            f"| {_one_decimal(r['nodes_median'])} | {_one_decimal(r['nodes_p90'])} "
            f"| {r['distance_m_median'] or 0:.0f} "
            f"| {r['distance_m_p90'] or 0:.0f} | {r['correct_match']} | {r['false_match']} "
            f"| {r['gross']} | {r['never']} |")
    (RESULTS / "darces_firstfix.md").write_text("\n".join(lines) + "\n")
    return report


def null(names: list[str], n_lns: int, seed: int) -> dict[str, Any]:
    """The chance hypothesis itself: stressed LNs of each family GN (seed 1) matched
    against another GN of the same statistics (seed 2). Every fix is a false match;
    ``false_match_probability`` should stay high."""
    rows = []
    for name in names:
        other = Matcher(family_gn(name, seed=2))
        options = family_options(FAMILY[name].density_per_km2, outliers=0.3, label_flips=0.1)
        p_false, fixes, count = [], 0, 0
        for sim in iter_lns(family_gn(name, seed=1), options, seed=seed, max_lns=n_lns):
            count += 1
            result = other.match(sim.records)
            fixes += result.is_fix
            p = result.false_match_probability
            p_false.append(1.0 if np.isnan(p) else p)
        rows.append({"gn": name, "lns": count, "fixes": fixes,
                     "min_false_match_probability": float(np.min(p_false)),
                     "below_0.1": int(np.sum(np.array(p_false) < 0.1))})
        print(json.dumps(rows[-1]), flush=True)
    report = {"mode": "null", "rows": rows, "accepted_false_match_rate":
              MatchConfig().false_match_rate,
              "command": f"python bench/darces_bench.py null --max-lns {n_lns} --seed {seed} "
                         f"--gns {','.join(names)}"}
    _write_json_atomic(RESULTS / "darces_null.json", report)
    return report


def tracknull(names: list[str], n_lns: int, seed: int, sigmas: list[float],
              wide_share: float = 0.0, wide_scale: float = 1.0) -> dict[str, Any]:
    """The chance hypothesis for tracking: stressed LNs of each family GN (seed 1) tracked
    on another GN of the same statistics (seed 2) from a prior placed at chance (the LN's
    centroid on a random GN ROI, a random heading) with x-y sigma S and 1 deg of heading.
    Every fix is a false match; the track decision as configured (0 spent nodes, quarter
    sigma cells). With ``wide_share``
    > 0 the LNs are of mixed precision: that share of their nodes (at random) has its
    covariance scaled by ``wide_scale`` (far-rock-like nodes beside precise ones); results
    go to ``darces_tracknull_mixed``."""
    configs = {"darces": MatchConfig()}
    rows = []
    for name in names:
        other = family_gn(name, seed=2)
        gxy = xy(other.records)
        matchers = {k: Matcher(other, c) for k, c in configs.items()}
        options = family_options(FAMILY[name].density_per_km2, outliers=0.3, label_flips=0.1)
        for sigma in sigmas:
            rng = np.random.default_rng(seed)
            tally = {k: {"fixes": 0, "p": [], "low_outside_prior": 0} for k in configs}
            count = 0
            for sim in iter_lns(family_gn(name, seed=1), options, seed=seed, max_lns=n_lns):
                count += 1
                records = sim.records
                if wide_share > 0:
                    records = records.copy()
                    wide = rng.random(len(records)) < wide_share
                    for f in ("cov_xx", "cov_xy", "cov_yy"):
                        records[f][wide] *= wide_scale
                pts = xy(records)
                yaw = rng.uniform(-np.pi, np.pi)
                rot = np.array([[np.cos(yaw), -np.sin(yaw)], [np.sin(yaw), np.cos(yaw)]])
                t = gxy[rng.integers(len(gxy))] - rot @ pts.mean(axis=0)
                cov = np.diag([sigma**2, sigma**2, np.radians(1.0) ** 2])
                for k, m in matchers.items():
                    r = m.track(records, Rigid2D(yaw, t[0], t[1]), cov, anchor_newest=True)
                    p = r.false_match_probability
                    p = 1.0 if not np.isfinite(p) else p
                    tally[k]["fixes"] += r.is_fix
                    if r.reason == "outside_prior":
                        tally[k]["low_outside_prior"] += p < 0.01
                    else:
                        tally[k]["p"].append(p)
            row = {"gn": name, "prior_sigma_m": sigma, "lns": count}
            for k, v in tally.items():
                row[k] = {"fixes": v["fixes"],
                          "min_false_match_probability_inside_prior": float(np.min(v["p"])),
                          "below_0.01_inside_prior": int(np.sum(np.array(v["p"]) < 0.01)),
                          "below_0.01_outside_prior": v["low_outside_prior"]}
            rows.append(row)
            print(json.dumps(row), flush=True)
    command = (f"python bench/darces_bench.py tracknull --max-lns {n_lns} --seed {seed} "
               f"--gns {','.join(names)} --prior-sigmas {','.join(str(s) for s in sigmas)}")
    name = "darces_tracknull"
    if wide_share > 0:
        command += f" --wide-share {wide_share:g} --wide-scale {wide_scale:g}"
        name = "darces_tracknull_mixed"
    report = {"mode": "tracknull", "rows": rows, "command": command,
              "wide_share": wide_share, "wide_scale": wide_scale,
              "accepted_false_match_rate": MatchConfig().false_match_rate}
    _write_json_atomic(RESULTS / f"{name}.json", report)
    lines = ["# darces_matcher benchmark: chance LNs tracked from a chance prior", "",
             f"Command: `{command}`. Stressed LNs (30 % outliers, 10 % flips) of each family "
             "GN (seed 1) tracked (`Matcher.track`) on another GN of the same statistics "
             "(seed 2) from a prior on a random GN ROI at a random heading (x-y sigma S, "
             "1 deg heading): every fix would be false. *darces*: the track decision (no "
             "node spent, quarter-sigma cells). p_false < 0.01 outside the prior: fits the "
             "EM took outside the prior's ellipsoid, refused (`outside_prior`)."
             + (f" Mixed precision: {wide_share:.0%} of each LN's nodes, at random, with "
                f"their covariance scaled {wide_scale:g}x." if wide_share > 0 else ""), "",
             "| GN | S m | LNs | darces: fixes | darces: min p_false inside | darces: < 0.01 "
             "inside / outside |",
             "|---|---|---|---|---|---|"]
    for r in rows:
        a = r["darces"]
        lines.append(
            f"| {r['gn']} | {r['prior_sigma_m']:g} | {r['lns']} | {a['fixes']} "
            f"| {a['min_false_match_probability_inside_prior']:.3g} "
            f"| {a['below_0.01_inside_prior']} / {a['below_0.01_outside_prior']} |")
    (RESULTS / f"{name}.md").write_text("\n".join(lines) + "\n")
    return report


def _route(tum: Path) -> np.ndarray:
    """(K, 2) positions of a TUM trajectory file (comment lines skipped), metres."""
    data = np.loadtxt(tum, comments="#", ndmin=2)
    return data[:, 1:3]


def quick(bag: Path, trials: int, radius_m: float, seed: int) -> dict[str, Any]:
    """Match perfect corridor LNs of a bag's route against its truth ROIs."""
    gn = read_geojson(bag / "truth" / "rois.geojson")
    route = _route(bag / "truth" / "trajectory.tum")
    gn_pts, gn_labels = xy(gn.records), gn.records["label"]
    out = {}
    for method, config in (("darces", MatchConfig()),
                           ("darces_original", MatchConfig.original())):
        matcher = Matcher(gn, config)
        fixes, errors, reasons, n_nodes = 0, [], {}, 0
        for k in range(trials):
            sim = corridor_ln(gn_pts, gn_labels, route, radius_m, 0.01,
                              np.random.default_rng([seed, k]))
            if sim is None:
                raise SystemExit(f"{bag}: fewer than 3 truth ROIs within {radius_m} m "
                                 "of the route")
            n_nodes = len(sim.records)
            result = matcher.match(sim.records)
            if result.is_fix:
                fixes += 1
                errors.append(transform_error(result.map_T_odom, sim, gn_pts))
            else:
                reasons[result.reason] = reasons.get(result.reason, 0) + 1
        out[method] = {"trials": trials, "fixes": fixes,
                       "max_error_m": max(errors) if errors else None,
                       "no_fix_reasons": reasons}
    report = {"mode": "quick", "bag": str(bag), "gn_rois": len(gn), "ln_nodes": n_nodes,
              "radius_m": radius_m, "methods": out,
              "command": f"python bench/darces_bench.py quick --bag {bag} --trials {trials}"}
    _write_json_atomic(RESULTS / "darces_quick.json", report)
    print(json.dumps(report, indent=2))
    return report


def main() -> None:
    """Command-line entry point."""
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("mode", choices=["paper", "stress", "scale", "generality", "firstfix",
                                    "quick", "null", "tracknull"])
    p.add_argument("--gns", default=",".join(FAMILY),
                   help="family GNs (generality, firstfix), comma-separated")
    p.add_argument("--stress-lns", type=int, default=None,
                   help="stressed LNs per GN (generality; default: --max-lns)")
    p.add_argument("--seed", type=int, default=7, help="LN seed (generality, firstfix)")
    p.add_argument("--methods", default=None,
                   help="paper/stress: methods of darces_eval (default: its own); "
                   "generality: methods (default darces,darces_original)")
    p.add_argument("--tag", default="",
                   help="paper/stress/generality: results go to "
                        "darces_<mode>_<tag>.{json,md}")
    p.add_argument("--merge", action="store_true",
                   help="generality: only rebuild the table from the GN rows measured")
    p.add_argument("--bag", type=Path, default=Path("/work/bags/quick"))
    p.add_argument("--trials", type=int, default=20)
    p.add_argument("--radius", type=float, default=15.0,
                   help="corridor half-width of the quick LN, metres")
    p.add_argument("--baseline-lns", type=int, default=1000,
                   help="LNs for the baselines (the first of the same stream)")
    p.add_argument("--max-lns", type=int, default=None, help="cap the LNs (paper/stress)")
    p.add_argument("--prior-sigmas", default="5,15",
                   help="tracknull: x-y sigmas of the chance priors, metres")
    p.add_argument("--wide-share", type=float, default=0.0,
                   help="tracknull: share of each LN's nodes given a wider covariance")
    p.add_argument("--wide-scale", type=float, default=16.0,
                   help="tracknull: covariance factor of those nodes")
    p.add_argument("--sizes", default="1000,10000,100000,1000000")
    p.add_argument("--scale-lns", type=int, default=100)
    args = p.parse_args()
    cap = ["--max-lns", str(args.max_lns)] if args.max_lns else []
    if args.methods:
        cap += ["--methods", args.methods]
    if args.mode == "paper":
        _eval("paper", cap, args.baseline_lns, args.tag)
    elif args.mode == "stress":
        _eval("stress", ["--outliers", "0.3", "--label-flips", "0.1", *cap], args.baseline_lns,
              args.tag)
    elif args.mode == "scale":
        scale([int(s) for s in args.sizes.split(",")], args.scale_lns)
    elif args.mode in ("generality", "firstfix", "null", "tracknull"):
        names = [n.strip() for n in args.gns.split(",") if n.strip()]
        unknown = [n for n in names if n not in FAMILY]
        if unknown:
            p.error(f"unknown GN(s) {unknown} (known: {', '.join(FAMILY)})")
        lns = args.max_lns or 400
        if args.mode == "generality" and args.merge:
            merge_generality(args.tag)
        elif args.mode == "generality":
            stress = lns if args.stress_lns is None else args.stress_lns
            generality(names, lns, stress, args.seed,
                       args.methods.split(",") if args.methods else None, args.tag)
        elif args.mode == "firstfix":
            firstfix(names, lns, args.seed)
        elif args.mode == "tracknull":
            tracknull(names, lns, args.seed,
                      [float(v) for v in args.prior_sigmas.split(",")],
                      args.wide_share, args.wide_scale)
        else:
            null(names, lns, args.seed)
    else:
        quick(args.bag, args.trials, args.radius, args.seed)


if __name__ == "__main__":
    main()
