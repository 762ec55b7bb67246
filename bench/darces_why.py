#!/usr/bin/env python3
"""Why the matcher leaves an LN unfixed: the search or the decision.

For every LN of a family GN (the paper protocol, ``darces_bench.family_options``; 30 %
outliers and 10 % label flips unless ``--clean``) that the oracle fits within 2 m and
the matcher leaves without a fix, this looks at the hypotheses of each search the
matcher ran (labelled, then label-blind) and sorts the LN into one of:

* ``no right hypothesis``: no hypothesis of any search was the true alignment (every
  LN node within its verification gate of where the truth maps it, median over the
  nodes): the search failed (no clean control triplet, or its candidates over the cap);
* ``right alignment best, odds short``: the best refined candidate of a search was the
  true alignment, and the decision withheld it (``insufficient_support``);
* ``right hypothesis, not the best``: it was among the hypotheses, not the winner;
* the matcher's reason otherwise (``unsupported_refit``, ``label_mismatch``,
  ``imprecise``, ...).

With ``--misfits`` it looks at the other miss instead: the fixes that are false matches
(error more than 2 m over the oracle's). For each, the annealing-free EM of the matcher's
mixture model (:mod:`darces_matcher.em_refit`) is run from the true alignment and its
local maximum compared with the fix's:

* ``the model's maximum``: the fix's likelihood is at least that of the maximum next to
  the truth: no estimator on this likelihood places the LN closer; what the oracle
  knows beyond it is the pairs;
* ``a better maximum near the truth``: the search or the refit stopped at a lesser one.

It also asks whether each fix, right or false, says how far off it may be: the error of
its alignment at the LN's newest true node (the one the rover is at; at every true node
too) against the fix's covariance, inside 3 sigma or not (chi-square, 2 degrees of
freedom, 11.83).

Evaluation code: it reads the simulation's truth; the matcher does not.

Usage::

    python bench/darces_why.py thomas_strong --lns 100
    python bench/darces_why.py matern_1000 --lns 100 --json OUT.json
    python bench/darces_why.py matern_400 --lns 200 --misfits
    python bench/darces_why.py matern_400 --lns 400 --misfits --complete-covariance \
        --json bench/results/darces_why_misfits_matern_400_complete.json
"""

from __future__ import annotations

import argparse
import json
import sys
from collections import Counter
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

from darces_bench import family_options

from darces_matcher.eval_cli import CORRECT_M, oracle_error, transform_error
from darces_matcher.gn_generator import FAMILY, family_gn
from darces_matcher.matcher import MatchConfig, Matcher
from darces_matcher.simulate import iter_lns
from darces_matcher.vote import alignment_jacobian, transform_points
from roi_network.records import xy
from roi_network.transform import Rigid2D


class _Recorder(Matcher):
    """A Matcher that keeps, per search, the LN positions, gates, hypotheses' mapped LN
    and refined candidates of its last round (its label-blind matcher records into the
    same list)."""

    def __init__(self, gn, config: MatchConfig | None = None,
                 log: list[dict[str, Any]] | None = None) -> None:
        self.log: list[dict[str, Any]] = log if log is not None else []
        super().__init__(gn, config)

    def _blind_matcher(self) -> Matcher:
        if self._blind is None:
            self._blind = _Recorder(self._gn, replace(self.config, use_labels=False,
                                                      label_fallback=False), self.log)
        return self._blind

    def _match(self, ln, ln_sigma, anchor_newest=False, odom_cov=None):
        self.log.append({"labels": self.config.use_labels, "rounds": []})
        return super()._match(ln, ln_sigma, anchor_newest, odom_cov)

    def _refine_distinct(self, pts, groups, node_tol, weights, pool, cache=None):
        refined, leftover = super()._refine_distinct(pts, groups, node_tol, weights, pool,
                                                     cache)
        self.log[-1]["rounds"].append({"pts": pts, "gate": node_tol,
                                       "mapped": pool.mapped.copy(),
                                       "candidates": [(r.yaw, r.t.copy()) for r in refined]})
        return refined, leftover


def _is_truth(mapped: np.ndarray, truth_mapped: np.ndarray, gate: np.ndarray) -> np.ndarray:
    """Whether each of (H, N, 2) mapped LNs is the true alignment (median node within
    its gate of where the truth maps it)."""
    return np.median(np.linalg.norm(mapped - truth_mapped, axis=-1) / gate, axis=-1) < 1.0


def classify(reason: str, searches: list[dict[str, Any]], truth: Rigid2D) -> str:
    """The category of one unfixed LN (module docstring)."""
    if reason not in ("insufficient_support", "no_hypothesis", "no_control_triplet"):
        return reason
    right_best = right_any = False
    for search in searches:
        if not search["rounds"]:
            continue
        last = search["rounds"][-1]
        truth_mapped = transform_points(truth.yaw, np.array([truth.tx, truth.ty]), last["pts"])
        right_any |= bool(_is_truth(last["mapped"], truth_mapped, last["gate"]).any())
        if last["candidates"]:
            yaw, t = last["candidates"][0]
            best = transform_points(yaw, t, last["pts"])
            right_best |= bool(_is_truth(best[None], truth_mapped, last["gate"])[0])
    if right_best:
        return "right alignment best, odds short"
    if right_any:
        return "right hypothesis, not the best"
    return "no right hypothesis"


def misfit(matcher: Matcher, result, sim, gn_pts: np.ndarray) -> dict[str, Any]:
    """The likelihood of a false match's alignment against the maximum next to the truth
    (module docstring), from the LN as the matcher's last search prepared it."""
    _, pts, labels, _, weights = matcher._last
    var = 1.0 / weights
    fix = matcher._em_fit(pts, labels, var, result.map_T_odom, 0.0)
    near = matcher._em_fit(pts, labels, var, sim.map_T_odom, 0.0)
    return {"log_lik_fix": fix.log_likelihood, "log_lik_near_truth": near.log_likelihood,
            "error_near_truth_m": transform_error(Rigid2D(near.yaw, near.t[0], near.t[1]),
                                                  sim, gn_pts),
            "category": "the model's maximum"
            if fix.log_likelihood >= near.log_likelihood - 1e-6
            else "a better maximum near the truth"}


#: chi-square, 2 degrees of freedom, 99.73 % (3 sigma)
CHI2_2D_3SIGMA = 11.83


def alignment_chi2(result, sim, gn_pts: np.ndarray) -> tuple[float, float]:
    """The error of a fix's alignment at the LN's true nodes against its covariance:
    chi-square (2 dof) at the newest true node (the largest drift sigma, where the rover
    is) and the largest over the true nodes. Each node at its drift-free odom position
    (the true alignment's inverse of its GN node), its predicted covariance J C J^T with
    C the fix's (x, y, yaw) covariance."""
    true = np.flatnonzero(sim.truth_gn >= 0)
    g = gn_pts[sim.truth_gn[true]]
    odom = sim.map_T_odom.inverse().apply(g)
    err = result.map_T_odom.apply(odom) - g
    jac = alignment_jacobian(odom, result.map_T_odom.yaw)
    cov = jac @ result.covariance @ jac.transpose(0, 2, 1)
    chi2 = np.einsum("ni,ni->n", err, np.linalg.solve(cov, err[:, :, None])[:, :, 0])
    return float(chi2[np.argmax(sim.sigma[true])]), float(chi2.max())


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("gn", help=f"family GN ({', '.join(FAMILY)})")
    p.add_argument("--lns", type=int, default=100, help="LNs to match")
    p.add_argument("--seed", type=int, default=7, help="LN seed")
    p.add_argument("--clean", action="store_true", help="no outliers or label flips")
    p.add_argument("--misfits", action="store_true",
                   help="look at the false matches instead of the unfixed LNs")
    p.add_argument("--complete-covariance", action="store_true",
                   help="fixes report the complete-data covariance "
                   "(MatchConfig.association_covariance False, before 2026-11-28)")
    p.add_argument("--json", type=Path, help="write the per-LN rows here")
    args = p.parse_args(argv)
    if args.gn not in FAMILY:
        p.error(f"unknown GN {args.gn!r} (known: {', '.join(FAMILY)})")
    gn = family_gn(args.gn, seed=1)
    extra = {} if args.clean else {"outliers": 0.3, "label_flips": 0.1}
    options = family_options(FAMILY[args.gn].density_per_km2, **extra)
    gn_pts, gn_labels = xy(gn.records), gn.records["label"]
    matcher = _Recorder(gn, MatchConfig(association_covariance=not args.complete_covariance))
    rows = []
    # Per fix (misfits mode): false match or not, chi-square at the newest / every node.
    consistency: list[tuple[bool, float, float]] = []
    for k, sim in enumerate(iter_lns(gn, options, seed=args.seed, max_lns=args.lns)):
        matcher.log.clear()
        result = matcher.match(sim.records)
        oracle = oracle_error(sim, gn_pts, gn_labels)
        if args.misfits:
            if not result.is_fix:
                continue
            error = transform_error(result.map_T_odom, sim, gn_pts)
            newest, worst = alignment_chi2(result, sim, gn_pts)
            consistency.append((error > oracle + CORRECT_M, newest, worst))
            if error <= oracle + CORRECT_M:
                continue
            rows.append({"ln": k, "error_m": error, "oracle_m": oracle,
                         "reason": result.reason,
                         "p_false": float(result.false_match_probability),
                         "chi2_newest": newest, "chi2_max": worst,
                         **misfit(matcher, result, sim, gn_pts)})
            continue
        if result.is_fix or oracle > CORRECT_M:
            continue
        rows.append({"ln": k, "reason": result.reason,
                     "p_false": float(result.false_match_probability),
                     "category": classify(result.reason, matcher.log, sim.map_T_odom)})
    counts = Counter(r["category"] for r in rows)
    what = "false matches" if args.misfits else "unfixed that the oracle fits"
    print(f"{args.gn} ({'clean' if args.clean else 'stress'}, {args.lns} LNs, seed "
          f"{args.seed}): {len(rows)} {what}")
    for category, n in counts.most_common():
        if args.misfits:
            mine = [r for r in rows if r["category"] == category]
            gap = [r["log_lik_near_truth"] - r["log_lik_fix"] for r in mine]
            print(f"  {category}: {n} (error {min(r['error_m'] for r in mine):.1f}-"
                  f"{max(r['error_m'] for r in mine):.1f} m, oracle "
                  f"{min(r['oracle_m'] for r in mine):.1f}-"
                  f"{max(r['oracle_m'] for r in mine):.1f} m; the maximum next to the truth "
                  f"{min(r['error_near_truth_m'] for r in mine):.1f}-"
                  f"{max(r['error_near_truth_m'] for r in mine):.1f} m off, "
                  f"{min(gap):+.2f}..{max(gap):+.2f} nats)")
            continue
        pf = [r["p_false"] for r in rows if r["category"] == category
              and np.isfinite(r["p_false"])]
        span = f" (p_false {min(pf):.2g}-{max(pf):.2g})" if pf else ""
        print(f"  {category}: {n}{span}")
    summary = {}
    for name, false in (("right fixes", False), ("false matches", True)):
        mine = np.array([c[1:] for c in consistency if c[0] == false]).reshape(-1, 2)
        if not len(mine):
            continue
        inside = np.mean(mine <= CHI2_2D_3SIGMA, axis=0)
        summary[name] = {"fixes": len(mine), "newest_inside_3sigma": float(inside[0]),
                         "every_node_inside_3sigma": float(inside[1])}
        print(f"  {name}: {len(mine)}, the alignment inside its 3 sigma at the newest node "
              f"{inside[0]:.1%}, at every node {inside[1]:.1%}")
    if args.json:
        args.json.write_text(json.dumps({"gn": args.gn, "lns": args.lns, "seed": args.seed,
                                         "stress": not args.clean,
                                         "misfits": args.misfits,
                                         "complete_covariance": args.complete_covariance,
                                         "rows": rows,
                                         "consistency": summary},
                                        indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
