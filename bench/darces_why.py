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

Evaluation code: it reads the simulation's truth; the matcher does not.

Usage::

    python bench/darces_why.py thomas_strong --lns 100
    python bench/darces_why.py matern_1000 --lns 100 --json OUT.json
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

from darces_matcher.eval_cli import CORRECT_M, oracle_error
from darces_matcher.gn_generator import FAMILY, family_gn
from darces_matcher.matcher import MatchConfig, Matcher
from darces_matcher.simulate import iter_lns
from darces_matcher.vote import transform_points
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


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("gn", help=f"family GN ({', '.join(FAMILY)})")
    p.add_argument("--lns", type=int, default=100, help="LNs to match")
    p.add_argument("--seed", type=int, default=7, help="LN seed")
    p.add_argument("--clean", action="store_true", help="no outliers or label flips")
    p.add_argument("--json", type=Path, help="write the per-LN rows here")
    args = p.parse_args(argv)
    if args.gn not in FAMILY:
        p.error(f"unknown GN {args.gn!r} (known: {', '.join(FAMILY)})")
    gn = family_gn(args.gn, seed=1)
    extra = {} if args.clean else {"outliers": 0.3, "label_flips": 0.1}
    options = family_options(FAMILY[args.gn].density_per_km2, **extra)
    gn_pts, gn_labels = xy(gn.records), gn.records["label"]
    matcher = _Recorder(gn)
    rows = []
    for k, sim in enumerate(iter_lns(gn, options, seed=args.seed, max_lns=args.lns)):
        matcher.log.clear()
        result = matcher.match(sim.records)
        oracle = oracle_error(sim, gn_pts, gn_labels)
        if result.is_fix or oracle > CORRECT_M:
            continue
        rows.append({"ln": k, "reason": result.reason,
                     "p_false": float(result.false_match_probability),
                     "category": classify(result.reason, matcher.log, sim.map_T_odom)})
    counts = Counter(r["category"] for r in rows)
    print(f"{args.gn} ({'clean' if args.clean else 'stress'}, {args.lns} LNs, seed "
          f"{args.seed}): {len(rows)} unfixed that the oracle fits")
    for category, n in counts.most_common():
        pf = [r["p_false"] for r in rows if r["category"] == category
              and np.isfinite(r["p_false"])]
        span = f" (p_false {min(pf):.2g}-{max(pf):.2g})" if pf else ""
        print(f"  {category}: {n}{span}")
    if args.json:
        args.json.write_text(json.dumps({"gn": args.gn, "lns": args.lns, "seed": args.seed,
                                         "stress": not args.clean, "rows": rows},
                                        indent=2) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
