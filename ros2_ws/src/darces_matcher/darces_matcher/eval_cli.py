"""``darces_eval``: the paper's matching evaluation (Sec. 7.2-7.3) on any GN file.

Example::

    darces_eval --gn gn.geojson --seed 0 --max-lns 2000 \\
        --methods darces,darces_original --json out.json

LNs are simulated from the GN (:mod:`darces_matcher.simulate`), every method
(:data:`METHODS`: the matcher, and the paper's original DARCES) matches the same LNs, and
the outcome of each LN is judged afterwards against the truth (DESIGN.md, Metrics):
*correct* when the recovered transform maps every true LN node (its drift-free odom
position) to within 2 m of its GN node, *false fix* when a reported fix is not
correct, *no fix* when the method abstained.

Because drift moves LN nodes by up to 1 % of the distance travelled (up to 10 m), even the
best possible rigid fit misses 2 m on some LNs. Each LN therefore also gets an *oracle*
fit (weighted least squares on the true correspondences that a semantic matcher can use:
true detections, right class, GN node not missed; the matcher's own weights),
reported as ``oracle_within_2m``, the ceiling of ``correct``; the noise-aware pair
*correct_match* / *false_match*: a fix whose error exceeds the oracle's by at most 2 m is
the right match fitted as well as the noise allows, otherwise it is a wrong match; and
``false_fix_10m``, fixes off by more than 10 m (DESIGN.md's global-pose false fix).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from darces_matcher.gn_generator import FAMILY, GnSpec, family_gn, generate_gn
from darces_matcher.hypotheses import fit_rigid_batch
from darces_matcher.matcher import MatchConfig, Matcher
from darces_matcher.simulate import (
    MAX_PAIR_M,
    MIN_PAIR_M,
    SimOptions,
    SimulatedLn,
    degrade_gn,
    iter_lns,
    transform_error,
)
from roi_network.network import RoiNetwork
from roi_network.records import xy
from roi_network.transform import Rigid2D

#: The methods compared, by name: this package's matcher, and the paper's original DARCES.
METHODS = {"darces": MatchConfig(), "darces_original": MatchConfig.original()}
#: DESIGN.md Metrics: a fix is correct when every LN node is mapped within this, metres.
CORRECT_M = 2.0
#: DESIGN.md Metrics (global pose): a false fix is an error above this, metres.
GROSS_M = 10.0


def oracle_error(
    sim: SimulatedLn, gn_pts: np.ndarray, gn_labels: np.ndarray, visible: np.ndarray | None = None
) -> float:
    """Transform error (m) of the weighted least-squares fit on the usable true pairs.

    Usable: the LN node is a true detection, has the class of its GN node and that node
    is in the GN given to the matchers (``visible``, a boolean mask over the full GN).
    """
    cfg = MatchConfig()
    true = sim.truth_gn >= 0
    true[true] = sim.records["label"][true] == gn_labels[sim.truth_gn[true]]
    if visible is not None:
        true[true] = visible[sim.truth_gn[true]]
    if true.sum() < 2:
        return float("inf")
    sigma = np.maximum(sim.sigma[true], cfg.ln_sigma_floor_m)
    weights = 1.0 / (sigma**2 + cfg.gn_sigma_m**2)
    yaw, t = fit_rigid_batch(xy(sim.records)[true][None], gn_pts[sim.truth_gn[true]][None],
                             weights[None])
    return transform_error(Rigid2D(float(yaw[0]), t[0, 0], t[0, 1]), sim, gn_pts)


class Tally:
    """Outcomes and times of one method."""

    def __init__(self) -> None:
        self.outcome: list[str] = []
        self.match: list[str] = []
        self.error_m: list[float] = []
        self.time_ms: list[float] = []
        self.gross: list[bool] = []
        self.oracle_fits: list[bool] = []
        self.reasons: list[str] = []

    def add(self, fix: bool, error: float, oracle: float, time_ms: float,
            reason: str = "") -> None:
        """Record one LN: whether the method fixed, its transform error and the oracle's,
        and the method's reason (why it abstained)."""
        self.time_ms.append(time_ms)
        self.oracle_fits.append(oracle <= CORRECT_M)
        self.reasons.append(reason)
        self.error_m.append(error if fix else float("nan"))
        if not fix:
            self.outcome.append("no_fix")
            self.match.append("no_fix")
            return
        self.outcome.append("correct" if error <= CORRECT_M else "false_fix")
        self.match.append("correct_match" if error <= oracle + CORRECT_M else "false_match")
        self.gross.append(error > GROSS_M)

    def summary(self, n: int | None = None) -> dict[str, Any]:
        """Counts, rates and times over the first ``n`` LNs (all by default)."""
        outcome = self.outcome[:n]
        match = self.match[:n]
        times = np.array(self.time_ms[:n])
        lns = len(outcome)
        out: dict[str, Any] = {"lns": lns}
        for key, values in (("correct", outcome), ("false_fix", outcome), ("no_fix", outcome),
                            ("correct_match", match), ("false_match", match)):
            count = values.count(key)
            out[key] = count
            out[f"{key}_rate"] = count / lns if lns else 0.0
        gross = sum(self.gross[: sum(o != "no_fix" for o in outcome)])
        out["false_fix_10m"] = gross
        out["false_fix_10m_rate"] = gross / lns if lns else 0.0
        out["time_ms"] = {
            "median": float(np.median(times)) if lns else None,
            "p95": float(np.percentile(times, 95)) if lns else None,
            "mean": float(np.mean(times)) if lns else None,
        }
        # Abstentions on LNs the oracle places within 2 m: the no fixes that a matcher
        # could have avoided.
        fits = self.oracle_fits[:n]
        missed = sum(f and o == "no_fix" for f, o in zip(fits, outcome, strict=True))
        out["oracle_fit"] = sum(fits)
        out["no_fix_oracle_fit"] = missed
        out["no_fix_oracle_fit_rate"] = missed / sum(fits) if sum(fits) else 0.0
        reasons: dict[str, int] = {}
        for o, r in zip(outcome, self.reasons[:n], strict=True):
            if o == "no_fix":
                reasons[r] = reasons.get(r, 0) + 1
        out["no_fix_reasons"] = dict(sorted(reasons.items(), key=lambda kv: -kv[1]))
        errors = [e for e in self.error_m[:n] if np.isfinite(e)]
        out["fix_error_m"] = {
            "median": float(np.median(errors)) if errors else None,
            "p95": float(np.percentile(errors, 95)) if errors else None,
        }
        return out


def evaluate(
    gn: RoiNetwork,
    methods: Sequence[str],
    options: SimOptions,
    *,
    seed: int = 0,
    max_lns: int | None = None,
    gn_misses: float = 0.0,
    baseline_max_lns: int | None = None,
    progress: bool = False,
) -> dict[str, Any]:
    """Run the evaluation and return the report (see :func:`main` for the fields).

    Args:
        gn: the true GN, ``map``.
        methods: names from :data:`METHODS`.
        options: LN simulation options.
        seed: random seed of the LNs (and of the GN misses).
        max_lns: evaluate at most this many LNs.
        gn_misses: share of GN ROIs hidden from the methods.
        baseline_max_lns: evaluate methods other than ``darces`` on the first this many
            LNs only (slow baselines); ``darces`` is also summarised on that subset.
        progress: print a progress line to stderr every 1000 LNs.
    """
    gn_pts = xy(gn.records)
    gn_labels = gn.records["label"]
    visible, kept = degrade_gn(gn, gn_misses, seed) if gn_misses > 0 else (gn, None)
    visible_mask = None
    if kept is not None:
        visible_mask = np.zeros(len(gn), dtype=bool)
        visible_mask[kept] = True
    built: dict[str, Matcher] = {}
    build_s: dict[str, float] = {}
    for name in methods:
        t0 = time.perf_counter()
        built[name] = Matcher(visible, METHODS[name])
        build_s[name] = time.perf_counter() - t0
    tallies = {name: Tally() for name in methods}
    oracle_ok = 0
    n_lns = 0
    t_start = time.perf_counter()

    def run(name: str, sim: SimulatedLn, oracle: float) -> None:
        t0 = time.perf_counter()
        result = built[name].match(sim.records)
        elapsed = 1e3 * (time.perf_counter() - t0)
        fix = result.is_fix and result.map_T_odom is not None
        error = transform_error(result.map_T_odom, sim, gn_pts) if fix else float("inf")
        tallies[name].add(fix, error, oracle, elapsed, result.reason)

    for n_lns, sim in enumerate(iter_lns(gn, options, seed, max_lns), start=1):
        oracle = oracle_error(sim, gn_pts, gn_labels, visible_mask)
        oracle_ok += oracle <= CORRECT_M
        in_subset = baseline_max_lns is None or n_lns <= baseline_max_lns
        # The methods take turns going first, so that none is systematically timed
        # right after another (warm or cold caches, the other job's load).
        active = [name for name in methods if name == "darces" or in_subset]
        shift = n_lns % len(active) if active else 0
        for name in active[shift:] + active[:shift]:
            run(name, sim, oracle)
        if progress and n_lns % 1000 == 0:
            print(f"[darces_eval] {n_lns} LNs, {time.perf_counter() - t_start:.0f} s",
                  file=sys.stderr)
    report: dict[str, Any] = {
        "gn": {"rois": len(gn), "visible_rois": len(visible)},
        "lns": n_lns,
        "oracle_within_2m": oracle_ok,
        "oracle_within_2m_rate": oracle_ok / n_lns if n_lns else 0.0,
        "methods": {},
        "index_build_s": build_s,
        "timing": "wall time of match() per LN in one process; methods interleaved per "
                  "LN in rotating order",
        "wall_s": time.perf_counter() - t_start,
    }
    for name, tally in tallies.items():
        report["methods"][name] = tally.summary()
    if baseline_max_lns is not None and "darces" in tallies:
        report["methods"]["darces"]["same_subset_as_baselines"] = tallies["darces"].summary(
            baseline_max_lns
        )
    return report


def _parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="darces_eval",
        description="Evaluate LN->GN matching with the paper's protocol (Sec. 7.2-7.3).",
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--gn", type=Path, help="GN GeoJSON file (map frame)")
    src.add_argument("--synthetic", metavar="NAME|N",
                     help="use a generated GN instead (seed --gn-seed): a member of the "
                          f"evaluation family ({', '.join(FAMILY)}), or N for a clustered "
                          "GN of N ROIs")
    p.add_argument("--gn-seed", type=int, default=0, help="seed of --synthetic (default 0)")
    p.add_argument("--seed", type=int, default=0, help="seed of the LN simulation")
    p.add_argument("--max-lns", type=int, default=None, help="evaluate at most N LNs")
    p.add_argument("--outliers", type=float, default=0.0,
                   help="false LN detections, as a share of true LN nodes (0.3 = 30%%)")
    p.add_argument("--label-flips", type=float, default=0.0,
                   help="share of true LN nodes with the wrong class")
    p.add_argument("--gn-misses", type=float, default=0.0,
                   help="share of GN ROIs never detected in orbit (hidden from the methods)")
    p.add_argument("--noise", type=float, default=0.01,
                   help="VO error bound as a share of distance travelled (paper: 0.01)")
    p.add_argument("--min-nodes", type=int, default=SimOptions.min_nodes,
                   help="fewest nodes of a trajectory (paper: 19)")
    p.add_argument("--max-nodes", type=int, default=SimOptions.max_nodes,
                   help="most nodes of a trajectory (paper: 29)")
    p.add_argument("--walks-per-pair", type=int, default=SimOptions.walks_per_pair,
                   help="random-walk trajectories tried per start/end pair")
    p.add_argument("--methods", default="darces,darces_original",
                   help=f"comma-separated subset of {','.join(METHODS)}")
    p.add_argument("--baseline-max-lns", type=int, default=None,
                   help="evaluate methods other than darces on the first N LNs only")
    p.add_argument("--json", type=Path, required=True, help="write the report here")
    p.add_argument("--progress", action="store_true", help="progress lines on stderr")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    """Console entry point; returns the process exit code.

    The JSON report holds ``options``, ``gn``, ``lns``, ``oracle_within_2m(_rate)``,
    ``index_build_s`` and, per method, ``lns``, ``correct``, ``false_fix``, ``no_fix``,
    ``correct_match``, ``false_match`` (counts and ``*_rate``), ``time_ms``
    (median, p95, mean) and ``fix_error_m`` (median, p95).
    """
    args = _parser().parse_args(argv)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    unknown = [m for m in methods if m not in METHODS]
    if unknown or not methods:
        print(f"darces_eval: unknown method(s) {unknown} (known: {', '.join(METHODS)})",
              file=sys.stderr)
        return 2
    for name in ("outliers", "label_flips", "gn_misses", "noise"):
        value = getattr(args, name)
        if not 0.0 <= value < 1.0:
            print(f"darces_eval: --{name.replace('_', '-')} must be in [0, 1), got {value}",
                  file=sys.stderr)
            return 2
    try:
        if args.gn is not None:
            from roi_network.geojson import read_geojson

            gn = read_geojson(args.gn)
        elif args.synthetic.isdigit():
            gn = generate_gn(GnSpec(n_rois=int(args.synthetic)), seed=args.gn_seed)
        else:
            gn = family_gn(args.synthetic, seed=args.gn_seed)
    except (OSError, ValueError) as exc:
        print(f"darces_eval: cannot read the GN: {exc}", file=sys.stderr)
        return 1
    if len(gn) < 3:
        print(f"darces_eval: the GN holds {len(gn)} ROIs, at least 3 are needed", file=sys.stderr)
        return 1
    options = SimOptions(noise_fraction=args.noise, outliers=args.outliers,
                         label_flips=args.label_flips, walks_per_pair=args.walks_per_pair,
                         min_nodes=args.min_nodes, max_nodes=args.max_nodes)
    if not 3 <= options.min_nodes <= options.max_nodes:
        print(f"darces_eval: need 3 <= --min-nodes <= --max-nodes, got {options.min_nodes}, "
              f"{options.max_nodes}", file=sys.stderr)
        return 2
    report = evaluate(gn, methods, options, seed=args.seed, max_lns=args.max_lns,
                      gn_misses=args.gn_misses, baseline_max_lns=args.baseline_max_lns,
                      progress=args.progress)
    if report["lns"] == 0:
        print(f"darces_eval: the paper protocol found no LN on {report_gn_name(args)}: no "
              f"route of {options.min_nodes}-{options.max_nodes} nodes joins two ROIs "
              f"{MIN_PAIR_M:.0f}-{MAX_PAIR_M:.0f} m apart (a GN smaller "
              f"than a route, or too sparse); nothing written", file=sys.stderr)
        return 1
    report["options"] = {
        "gn": report_gn_name(args),
        "min_nodes": options.min_nodes, "max_nodes": options.max_nodes,
        "seed": args.seed, "max_lns": args.max_lns, "outliers": args.outliers,
        "label_flips": args.label_flips, "gn_misses": args.gn_misses, "noise": args.noise,
        "walks_per_pair": args.walks_per_pair, "methods": methods,
        "baseline_max_lns": args.baseline_max_lns,
    }
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(report, indent=2) + "\n")
    print(f"{report['lns']} LNs on a {len(gn)}-ROI GN; oracle within 2 m: "
          f"{100 * report['oracle_within_2m_rate']:.2f} %")
    for name, r in report["methods"].items():
        pct = {k: 100 * v for k, v in r.items() if k.endswith("_rate")}
        print(f"{name:16s} lns {r['lns']:6d}  correct {pct['correct_rate']:6.2f} %  "
              f"false fix {pct['false_fix_rate']:5.2f} %  no fix {pct['no_fix_rate']:5.2f} %"
              f"  | correct match {pct['correct_match_rate']:6.2f} %  false match "
              f"{pct['false_match_rate']:5.2f} %  | >10 m {pct['false_fix_10m_rate']:5.2f} %"
              f"  | median {r['time_ms']['median']:.2f} ms"
              f"  p95 {r['time_ms']['p95']:.2f} ms")
    return 0


def report_gn_name(args: argparse.Namespace) -> str:
    """The GN as the report names it: its path, or ``synthetic:NAME:seedS``."""
    return str(args.gn) if args.gn else f"synthetic:{args.synthetic}:seed{args.gn_seed}"


if __name__ == "__main__":
    sys.exit(main())
