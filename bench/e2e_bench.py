"""End-to-end benchmark: the whole graph on bags, judged by ``globloc eval``, beside the
paper's end-of-route alignment. Results go to RESULTS/e2e_<tag>.{json,md}.

For each bag:

1. ``globloc run BAG --rate R`` (the graph of rover_bringup/config/graph.yaml, or
   ``--graph``), while the CPU time of every process of the run is sampled (psutil), so
   each stage's share of CPU is known;
2. ``globloc eval RUN_DIR --json``: final error, RMSE after the first fix, distance before
   the first fix, false fixes, 3-sigma consistency (docs/evaluation.md);
3. the paper's protocol on the same run: one DARCES fit of the whole final LN (the last
   /local_network) on the GN, then the whole VO trajectory (vo.tum) mapped with that one
   transform; its error at the end of the route and its RMSE over the route;
4. latency: for every /global_pose, its receive time at the recorder minus its stamp (the
   stereo pair's stamp, carried through VO), in bag seconds and divided by the rate in
   wall seconds; and whether the graph kept up (a /global_pose for every /vo/odometry
   after the first fix).

A bag the graph could not localize gets n/a, never a number made up; the results say
which nodes ran.

``--compare NODE:PARAM=VALUE`` (repeatable) runs every bag twice in the same bench: with
the params file as it is, and with those parameters set (one variant, named by
``--compare-label``); the results give both side by side and the spread of each, e.g.
the graph without rover_vo's sun heading::

    python bench/e2e_bench.py bags/quick --jobs 2 --tag sun \
        --compare rover_vo:imu.sun_heading=false --compare-label no_sun

Usage (from the repository root, after ``source env.sh``)::

    python bench/e2e_bench.py bags/atacama_1km_s1 bags/atacama_1km_s2 bags/atacama_1km_s3 \
        bags/quick --rate 5 --tag 1km
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from datetime import datetime
from pathlib import Path
from typing import Any

import numpy as np
import psutil
import yaml

from roi_network.files import write_atomic
from rover_bringup.evaluation import MAX_STAMP_DIFF_S, PAPER_FINAL_ERROR_M, read_tum
from rover_bringup.run_outputs import LOCAL_NETWORK, VO_TUM, read_records_csv

#: Where result files go: $BENCH_RESULTS (`make bench`: bench/results/current/), else
#: out/bench/results/.
RESULTS = Path(os.environ.get("BENCH_RESULTS")
               or Path(__file__).resolve().parents[1] / "out" / "bench" / "results")
#: Metrics of the continuous estimate aggregated over bags.
METRICS = ("final_error_m", "rmse_after_first_fix_m", "distance_before_first_fix_m",
           "false_fixes", "consistency_3sigma", "longest_stretch_without_fix_m",
           "error_at_stretch_end_m", "heading_final_error_deg", "heading_rmse_deg")
#: Any ROI this close to the route can be an LN node (far rocks are triangulated up to 30 m).
FAR_REACH_M = 30.0
#: ROS domain of the first of graphs run side by side (``--jobs``); the next take +1, +2...
DOMAIN_BASE = 40
#: Distances along the route at which the ROIs passed are counted (see rois_passed).
PASSED_MARKS_M = (100, 200, 300)


def parse_override(text: str) -> tuple[str, str, Any]:
    """``NODE:PARAM=VALUE`` as (node, parameter, value); the value is read as YAML (``false``
    a bool, ``3`` an int). Raises ValueError naming what is missing."""
    node, sep, rest = text.partition(":")
    name, eq, value = rest.partition("=")
    if not sep or not eq or not node or not name:
        raise ValueError(f"--compare {text!r}: expected NODE:PARAM=VALUE "
                         "(e.g. rover_vo:imu.sun_heading=false)")
    return node, name, yaml.safe_load(value)


def variant_params(base: Path, overrides: list[tuple[str, str, Any]], out: Path) -> Path:
    """The params file ``base`` with ``overrides`` set, written to ``out``."""
    from rover_bringup.graph import load_params

    doc = load_params(base)
    for node, name, value in overrides:
        doc.setdefault(node, {"ros__parameters": {}})["ros__parameters"][name] = value
    out.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(out, yaml.safe_dump(doc, sort_keys=False))
    return out


def _globloc() -> list[str]:
    return [sys.executable, "-m", "rover_bringup.cli"]


class CpuSampler:
    """CPU seconds per process name of a process tree, sampled every ``period_s``.

    A process is named by its ROS node name (``__node:=NAME``) or, for the tools,
    ``globloc_<subcommand>``; a restarted node's incarnations add up. The name is read at
    every sample: a child seen between its fork and its exec still carries its parent's
    command line (a node's CPU had been counted as ``globloc_run``'s).
    """

    def __init__(self, root: psutil.Process, period_s: float = 0.5) -> None:
        self.root, self.period_s = root, period_s
        self.cpu_s: dict[int, tuple[str, float]] = {}
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    @staticmethod
    def _name(cmdline: list[str]) -> str:
        for arg in cmdline:
            if arg.startswith("__node:="):
                return arg.split("=", 1)[1]
        if "rover_bringup.cli" in " ".join(cmdline):
            for sub in ("play", "record", "run"):
                if sub in cmdline:
                    return f"globloc_{sub}"
        return Path(cmdline[0]).name if cmdline else "?"

    def _sample(self) -> None:
        try:
            procs = [self.root, *self.root.children(recursive=True)]
        except psutil.Error:
            return
        for p in procs:
            try:
                with p.oneshot():
                    t = p.cpu_times()
                    cmd = p.cmdline()  # empty once the process exits: keep its name
                    name = self._name(cmd) if cmd else self.cpu_s.get(p.pid, ("?",))[0]
                    self.cpu_s[p.pid] = (name, t.user + t.system)
            except psutil.Error:
                continue

    def _run(self) -> None:
        while not self._stop.wait(self.period_s):
            self._sample()

    def __enter__(self) -> CpuSampler:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()

    def per_name(self) -> dict[str, float]:
        """CPU seconds per process name (the last sample of each process)."""
        out: dict[str, float] = {}
        for name, seconds in self.cpu_s.values():
            out[name] = out.get(name, 0.0) + seconds
        return out


def run_graph(bag: Path, out: Path, rate: float, run_id: str, extra: list[str],
              domain_id: int | None = None) -> tuple[Path, int, float, dict[str, float], str]:
    """``globloc run`` on one bag; returns (run dir, exit status, wall s, CPU s per process,
    stderr tail). ``domain_id``: the ROS domain of the graph (graphs run side by side each
    in their own), else the caller's."""
    t0 = time.monotonic()
    env = dict(os.environ)
    if domain_id is not None:
        env["ROS_DOMAIN_ID"] = str(domain_id)
    proc = subprocess.Popen([*_globloc(), "run", str(bag), "--out", str(out), "--rate",
                             str(rate), "--run-id", run_id, *extra],
                            stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                            env=env)
    with CpuSampler(psutil.Process(proc.pid)) as sampler:
        _, err = proc.communicate()
    wall = time.monotonic() - t0
    return out / bag.resolve().name / run_id, proc.returncode, wall, sampler.per_name(), err[-2000:]


def evaluate_run(run_dir: Path) -> dict[str, Any]:
    """``globloc eval RUN_DIR --json`` (also writes its report and plots)."""
    result = subprocess.run([*_globloc(), "eval", str(run_dir), "--json"],
                            capture_output=True, text=True, check=False)
    if result.returncode != 0:
        return {"error": result.stderr.strip()}
    return json.loads(result.stdout)


def _associate(t_est: np.ndarray, t_ref: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Indices (est, ref) of stamps within MAX_STAMP_DIFF_S of each other (nearest)."""
    k = np.clip(np.searchsorted(t_ref, t_est), 1, len(t_ref) - 1)
    k = np.where(np.abs(t_ref[k - 1] - t_est) < np.abs(t_ref[k] - t_est), k - 1, k)
    ok = np.abs(t_ref[k] - t_est) <= MAX_STAMP_DIFF_S
    return np.nonzero(ok)[0], k[ok]


def end_of_route_alignment(run_dir: Path, bag_dir: Path) -> dict[str, Any]:
    """The paper's protocol on a run: one DARCES fit of the final LN, the VO mapped with it.

    Args:
        run_dir: A run directory with ``local_network.csv`` (the last LN, odom) and
            ``vo.tum``.
        bag_dir: Its bag directory, with ``gn.geojson`` and ``truth/trajectory.tum``.

    Returns:
        ``status`` (``fix``, ``no_fix`` or ``n/a`` with ``why``), and on a fix the error
        at the end of the route and the RMSE of the aligned VO over the whole route, m.
    """
    from darces_matcher.matcher import Matcher
    from roi_network.geojson import read_geojson

    ln_path, gn_path = run_dir / LOCAL_NETWORK, bag_dir / "gn.geojson"
    truth_path = bag_dir / "truth" / "trajectory.tum"
    for path, what in ((ln_path, "no LN recorded"), (gn_path, "no GN"),
                       (run_dir / VO_TUM, "no odometry recorded"),
                       (truth_path, "no ground truth")):
        if not path.is_file():
            return {"status": "n/a", "why": f"{what} ({path})"}
    ln = read_records_csv(ln_path)
    vo = read_tum(run_dir / VO_TUM)
    if len(vo) == 0:
        return {"status": "n/a", "why": "no odometry recorded"}
    t0 = time.perf_counter()
    result = Matcher(read_geojson(gn_path)).match(ln)
    match_ms = 1e3 * (time.perf_counter() - t0)
    base = {"ln_size": len(ln), "reason": result.reason, "support": int(result.support),
            "match_ms": match_ms}
    if not result.is_fix:
        return {"status": "no_fix", **base}
    truth = read_tum(truth_path)
    aligned = result.map_T_odom.apply(vo[:, 1:3])
    i, k = _associate(vo[:, 0], truth[:, 0])
    if len(i) == 0:
        return {"status": "n/a", "why": "no odometry stamp matches the truth", **base}
    err = np.linalg.norm(aligned[i] - truth[k, 1:3], axis=1)
    return {"status": "fix", **base, "final_error_m": float(err[-1]),
            "rmse_m": float(np.sqrt(np.mean(err**2))), "max_error_m": float(err.max())}


def latency(run_dir: Path, rate: float) -> dict[str, Any]:
    """/global_pose receive time at the recorder minus its stamp, and keeping up."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    lat, n_odom_after, first = [], 0, None
    try:
        with Reader(run_dir / "outputs") as reader:
            conns = [c for c in reader.connections
                     if c.topic in ("/global_pose", "/vo/odometry")]
            for conn, log_ns, raw in reader.messages(connections=conns):
                msg = ts.deserialize_cdr(raw, conn.msgtype)
                stamp = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
                if conn.topic == "/global_pose":
                    first = stamp if first is None else first
                    lat.append(log_ns * 1e-9 - stamp)
                elif first is not None and stamp >= first:
                    n_odom_after += 1
    except Exception as exc:  # unreadable outputs: say so
        return {"error": f"cannot read {run_dir / 'outputs'}: {exc}"}
    if not lat:
        return {"global_poses": 0}
    a = np.array(lat)
    return {
        "global_poses": len(a),
        "odometry_after_first_fix": n_odom_after,
        "latency_bag_s": {"median": float(np.median(a)), "p95": float(np.percentile(a, 95)),
                          "max": float(a.max())},
        "latency_wall_s_p95": float(np.percentile(a, 95)) / rate if rate > 0 else None,
        "note": "recorder receive time in bag time (its sim time, which /clock at 100 Hz "
                "wall may hold up to R / 100 bag s behind); at rate R, wall latency = bag / R",
    }


def rois_passed(route_xy: np.ndarray, roi_xy: np.ndarray, marks_m=PASSED_MARKS_M
                ) -> dict[int, int]:
    """How many of the ROIs ``roi_xy`` (N, 2) the route ``route_xy`` (M, 2) has passed
    (reached its closest point to them) by each distance along it in ``marks_m``: what
    bounds how early any LN can hold enough ROIs for a fix."""
    route_xy, roi_xy = np.asarray(route_xy, float), np.asarray(roi_xy, float).reshape(-1, 2)
    along = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(route_xy, axis=0), axis=1))]
    if len(roi_xy) == 0:
        return {int(m): 0 for m in marks_m}
    from scipy.spatial import cKDTree

    _, k = cKDTree(route_xy).query(roi_xy)
    at = along[k]
    return {int(m): int(np.count_nonzero(at <= m)) for m in marks_m}


def counted_rois_passed(bag: Path) -> dict[str, Any] | None:
    """:func:`rois_passed` for the ROIs ``roi_detector eval``'s recall counts (above the
    rover thresholds, within 15 m of the route), from the bag's truth; None without it."""
    try:
        from roi_detector.truth import Truth

        truth = Truth.load(bag)
    except (OSError, ValueError):
        return None
    r = truth.rois
    counted = truth.counted(15.0)
    route, pts = truth.trajectory.p[:, :2], np.column_stack([r["x"], r["y"]])
    by = rois_passed(route, pts[counted])
    # Every truth ROI within the far rocks' reach (30 m), whatever its size: fewer than
    # three by a distance and no ROI-based fix can come before it.
    near = truth.near_route(FAR_REACH_M)
    return {"counted": int(counted.sum()), "by_m": by,
            "within_30m": int(near.sum()), "within_30m_by_m": rois_passed(route, pts[near])}


def _spread(values: list[float]) -> dict[str, float] | None:
    v = [x for x in values if x is not None]
    if not v:
        return None
    return {"n": len(v), "min": float(np.min(v)), "median": float(np.median(v)),
            "max": float(np.max(v))}


def bench_bag(bag: Path, args: argparse.Namespace, run_id: str,
              domain_id: int | None = None, params: Path | None = None,
              variant: str | None = None) -> dict[str, Any]:
    """Run, evaluate and compare on one bag (its graph in ROS domain ``domain_id``), with
    ``params`` (None: ``--params`` or the package's), labelled ``variant``."""
    params = params or args.params
    extra = [*(["--graph", str(args.graph)] if args.graph else []),
             *(["--params", str(params)] if params else [])]
    run_dir, status, wall, cpu, err = run_graph(bag, args.out, args.rate, run_id, extra,
                                                domain_id)
    entry: dict[str, Any] = {"bag": str(bag), "variant": variant, "run_dir": str(run_dir),
                             "run_status": status, "wall_s": wall}
    if not run_dir.is_dir():
        entry["error"] = err.strip().splitlines()[-1:] or ["globloc run failed"]
        return entry
    run = yaml.safe_load((run_dir / "run.yaml").read_text())
    entry["nodes"] = {n["name"]: n["status"] for n in run["nodes"]}
    entry["bag_duration_s"] = None
    total = sum(cpu.values()) or 1.0
    entry["cpu_s"] = {k: round(v, 2) for k, v in sorted(cpu.items())}
    entry["cpu_share"] = {k: round(v / total, 3) for k, v in sorted(cpu.items())}
    entry["continuous"] = evaluate_run(run_dir)
    if "route_duration_s" in entry["continuous"]:
        d = entry["continuous"]["route_duration_s"]
        entry["bag_duration_s"] = d
        entry["cpu_cores_used"] = total / wall if wall > 0 else None
        entry["realtime_factor_of_cpu"] = total / d if d else None
    entry["end_of_route"] = end_of_route_alignment(run_dir, Path(run["bag"]["dir"]))
    entry["latency"] = latency(run_dir, args.rate)
    entry["rois_passed"] = counted_rois_passed(Path(run["bag"]["dir"]))
    return entry


def _fmt(v: Any, digits: int = 2) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, float):
        return f"{v:.{digits}f}"
    return str(v)


def _label(e: dict[str, Any]) -> str:
    """A result's bag name, with its variant when it has one."""
    name = Path(e["bag"]).name
    return f"{name} ({e['variant']})" if e.get("variant") else name


def markdown(report: dict[str, Any]) -> str:
    """The results as a Markdown table per bag and the spread over bags."""
    lines = [f"# End-to-end benchmark `{report['tag']}`", "",
             f"{report['date']}; {report['machine']}; rate {report['rate']}; command: "
             f"`{report['command']}`", "",
             "| bag | localized | first fix after (m) | final error (m) | RMSE after fix (m) "
             "| false fixes | 3-sigma | longest stretch without a fix / error at its end (m) "
             "| heading final / RMSE (deg) | end-of-route (paper) final / RMSE (m) "
             "| nodes ran |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for e in report["bags"]:
        c = e.get("continuous", {})
        p = e.get("end_of_route", {})
        paper = (f"{_fmt(p.get('final_error_m'))} / {_fmt(p.get('rmse_m'))}"
                 if p.get("status") == "fix" else p.get("status", "n/a"))
        cons = c.get("consistency_3sigma")
        ran = ", ".join(k for k, v in e.get("nodes", {}).items() if v == "ran") or "none"
        lines.append(
            f"| {_label(e)} | {_fmt(c.get('localized'))} "
            f"| {_fmt(c.get('distance_before_first_fix_m'), 1)} "
            f"| {_fmt(c.get('final_error_m'))} | {_fmt(c.get('rmse_after_first_fix_m'))} "
            f"| {_fmt(c.get('false_fixes'))} "
            f"| {_fmt(None if cons is None else 100 * cons, 1)} % "
            f"| {_fmt(c.get('longest_stretch_without_fix_m'), 1)} / "
            f"{_fmt(c.get('error_at_stretch_end_m'))} "
            f"| {_fmt(c.get('heading_final_error_deg'))} / {_fmt(c.get('heading_rmse_deg'))} "
            f"| {paper} | {ran} |")
    for e in report["bags"]:
        lag = e.get("continuous", {}).get("fix_lag_s")
        if lag:
            lines.append(f"\n{_label(e)}: fixes reached the graph {lag['median']:.1f} s "
                         f"(median), at most {lag['max']:.1f} s (bag time) after their LN's "
                         "stamp; false fixes are judged from then (`globloc eval`).")
    marks = " / ".join(str(m) for m in PASSED_MARKS_M)
    lines += ["", f"ROIs the recall counts (above the rover thresholds, within 15 m of the "
              f"route) that the route has passed by {marks} m: what bounds the first fix:", ""]
    for e in report["bags"]:
        rp = e.get("rois_passed")
        if rp and not e.get("variant"):
            line = (f"- {Path(e['bag']).name}: "
                    + " / ".join(str(rp["by_m"][m]) for m in PASSED_MARKS_M)
                    + f" of {rp['counted']}")
            if "within_30m" in rp:
                line += ("; every truth ROI within 30 m of the route, whatever its size: "
                         + " / ".join(str(rp["within_30m_by_m"][m]) for m in PASSED_MARKS_M)
                         + f" of {rp['within_30m']}")
            lines.append(line)
    lines += ["", f"Paper (end-of-route alignment on its 1 km route): {PAPER_FINAL_ERROR_M} m."]
    compare = report.get("compare")
    spreads = [("" if compare is None else f" ({compare['base']})", report["spread"])]
    if compare is not None:
        spreads.append((f" ({compare['label']})", compare["spread"]))
    for label, spread in spreads:
        lines += ["", f"Spread over bags{label} (continuous estimate):", ""]
        for k, v in spread.items():
            lines.append(f"- {k}: " + (", ".join(f"{a} {_fmt(b)}" for a, b in v.items())
                                       if v else "n/a"))
    lines += ["", "CPU share per process (of the run's CPU seconds):", ""]
    for e in report["bags"]:
        if e.get("cpu_share"):
            lines.append(f"- {_label(e)}: " + ", ".join(
                f"{k} {100 * v:.0f} %" for k, v in e["cpu_share"].items()))
    return "\n".join(lines) + "\n"


def claim_tag(results: Path, tag: str):
    """An open lock file that reserves ``tag`` in ``results`` for this process (released
    when it ends, however it ends), or None when another process holds it: two benches
    under one tag would each write ``e2e_<tag>.*``, the second over the first."""
    import fcntl

    # Held open, not in a with-block: the lock lasts as long as the file is open.
    f = open(results / f".e2e_{tag}.lock", "w")  # noqa: SIM115
    try:
        fcntl.flock(f, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        f.close()
        return None
    return f


def main(argv: list[str] | None = None) -> int:
    """Command line: see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("bags", nargs="+", type=Path, help="bag directories bags/<name>/")
    ap.add_argument("--rate", type=float, default=5.0, help="playback rate (default 5)")
    ap.add_argument("--out", type=Path, default=Path("out/bench"), help="run output root")
    ap.add_argument("--tag", default="e2e", help="results name: RESULTS/e2e_<tag>.*")
    ap.add_argument("--graph", type=Path, help="graph file (default: the package's)")
    ap.add_argument("--params", type=Path, help="params file (default: the package's)")
    ap.add_argument("--results", type=Path, default=RESULTS, help="results directory")
    ap.add_argument("--jobs", type=int, default=1,
                    help="graphs run side by side, each in its own ROS domain (default 1)")
    ap.add_argument("--compare", action="append", default=[], metavar="NODE:PARAM=VALUE",
                    help="also run every bag with these parameters set (repeatable)")
    ap.add_argument("--compare-label", default="compared",
                    help="name of the --compare variant in the results")
    args = ap.parse_args(argv)
    if args.jobs < 1:
        ap.error("--jobs must be at least 1")
    try:
        overrides = [parse_override(text) for text in args.compare]
    except ValueError as exc:
        ap.error(str(exc))
    for bag in args.bags:
        if not bag.is_dir():
            print(f"e2e_bench: error: bag directory not found: {bag}", file=sys.stderr)
            return 1
    args.results.mkdir(parents=True, exist_ok=True)
    lock = claim_tag(args.results, args.tag)  # held until the process ends
    if lock is None:
        print(f"e2e_bench: error: another e2e_bench is running with --tag {args.tag} and "
              f"will write {args.results / f'e2e_{args.tag}'}.{{json,md}}: pick another "
              "tag", file=sys.stderr)
        return 1
    run_id = "bench-" + datetime.now().strftime("%Y%m%d-%H%M%S")
    runs: list[tuple[Path, Path | None, str | None]] = [(bag, None, None) for bag in args.bags]
    if args.compare:
        from rover_bringup.share import config_file

        params = variant_params(args.params or config_file("globloc.yaml"), overrides,
                                args.out / f"{run_id}-{args.compare_label}.params.yaml")
        # Interleaved: the two runs of a bag play side by side under --jobs 2.
        runs = [r for bag in args.bags
                for r in ((bag, None, None), (bag, params, args.compare_label))]

    def one(i: int, run: tuple[Path, Path | None, str | None]) -> dict[str, Any]:
        bag, params, variant = run
        print(f"e2e_bench: {bag}{f' ({variant})' if variant else ''} ...", file=sys.stderr,
              flush=True)
        # Side by side, each graph in a ROS domain of its own (they share topic names).
        domain = DOMAIN_BASE + i % args.jobs if args.jobs > 1 else None
        rid = f"{run_id}-{variant}" if variant else run_id
        return bench_bag(bag, args, rid, domain, params, variant)

    with ThreadPoolExecutor(max_workers=args.jobs) as pool:
        entries = list(pool.map(one, range(len(runs)), runs))

    def spread(group: list[dict[str, Any]]) -> dict[str, Any]:
        cont = [e.get("continuous", {}) for e in group]
        return {m: _spread([c.get(m) for c in cont]) for m in METRICS} | {
            "end_of_route_final_error_m": _spread(
                [e.get("end_of_route", {}).get("final_error_m") for e in group])}

    base = [e for e in entries if e["variant"] is None]
    report = {
        "tag": args.tag,
        "date": datetime.now().isoformat(timespec="seconds"),
        "machine": f"{platform.node()}, {os.cpu_count()} cores (shared with other jobs "
                   f"unless stated), Python {platform.python_version()}",
        "jobs": args.jobs,
        "command": "python bench/e2e_bench.py " + " ".join(sys.argv[1:] if argv is None
                                                            else argv),
        "rate": args.rate,
        "bags": entries,
        "spread": spread(base),
        "compare": None if not args.compare else {
            "base": "as configured", "label": args.compare_label,
            "overrides": [f"{n}:{k}={v}" for n, k, v in overrides],
            "spread": spread([e for e in entries if e["variant"] is not None])},
        "paper_final_error_m": PAPER_FINAL_ERROR_M,
    }
    write_atomic(args.results / f"e2e_{args.tag}.json", json.dumps(report, indent=2) + "\n")
    write_atomic(args.results / f"e2e_{args.tag}.md", markdown(report))
    print(markdown(report))
    return 0


if __name__ == "__main__":
    sys.exit(main())
