"""The odds decision with the outlier share integrated out (``marginal_outliers``) beside
the fixed share, and more control triplets, on LNs with many false nodes.

    python bench/darces_marginal.py --gns poisson_85,thomas_mid --lns 25

First fix (``darces_bench.first_fix``: each LN of the paper protocol fed node by node,
least travelled first) on family GNs, with 0, 50 and 67 % false LN nodes (``outliers``
1.0 and 2.0 of SimOptions, the latter with 10 % label flips), and the null test (LNs of
the GN of seed 1 against the GN of seed 2, prefixes of 6 and 10 nodes and the whole LN,
50 % false nodes and 10 % label flips: every fix is wrong). Writes
``bench/results/darces_marginal.{json,md}``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
import darces_bench as bench

from darces_matcher.matcher import MatchConfig, Matcher
from darces_matcher.simulate import iter_lns, ln_prefix

RESULTS = Path(__file__).parent / "results"
CONFIGS = {
    "fixed": {},
    "marginal": {"marginal_outliers": True},
    "marginal_t48": {"marginal_outliers": True, "n_triplets": 48},
}
PROTOCOLS = {
    "clean": {},
    "50% false": {"outliers": 1.0},
    "67% false, 10% flips": {"outliers": 2.0, "label_flips": 0.1},
}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--gns", default="poisson_85,thomas_mid")
    p.add_argument("--lns", type=int, default=25)
    p.add_argument("--seed", type=int, default=7)
    args = p.parse_args()
    rows, nulls = [], []
    for name in args.gns.split(","):
        gn = bench.family_gn(name, seed=1)
        density = bench.FAMILY[name].density_per_km2
        for protocol, extra in PROTOCOLS.items():
            options = bench.family_options(density, **extra)
            for config, over in CONFIGS.items():
                t0 = time.perf_counter()
                r = bench.first_fix(gn, options, MatchConfig(**over), args.lns, args.seed)
                row = {"gn": name, "protocol": protocol, "config": config,
                       "wall_s": time.perf_counter() - t0,
                       **{k: r[k] for k in ("lns", "fixed", "nodes_median", "correct_match",
                                            "false_match", "gross", "never")}}
                rows.append(row)
                print(json.dumps(row), flush=True)
        other = bench.family_gn(name, seed=2)
        options = bench.family_options(density, outliers=1.0, label_flips=0.1)
        for config, over in CONFIGS.items():
            matcher = Matcher(other, MatchConfig(**over))
            fixes = count = 0
            p_min = 1.0
            for sim in iter_lns(gn, options, seed=args.seed, max_lns=args.lns):
                for k in (6, 10, len(sim.records)):
                    res = matcher.match(ln_prefix(sim, min(k, len(sim.records))).records)
                    count += 1
                    fixes += res.is_fix
                    if not np.isnan(res.false_match_probability):
                        p_min = min(p_min, res.false_match_probability)
            nulls.append({"gn": name, "config": config, "matches": count, "fixes": fixes,
                          "min_false_match_probability": p_min})
            print(json.dumps(nulls[-1]), flush=True)
    command = (f"python bench/darces_marginal.py --gns {args.gns} --lns {args.lns} "
               f"--seed {args.seed}")
    report = {"command": command, "first_fix": rows, "null": nulls}
    RESULTS.mkdir(exist_ok=True)
    (RESULTS / "darces_marginal.json").write_text(json.dumps(report, indent=1) + "\n")
    lines = ["# Odds with the outlier share integrated out", "", f"Command: `{command}`.", "",
             "First fix (LNs fed node by node; right = within the oracle + 2 m):", "",
             "| GN | LNs | configuration | LNs | fixed | nodes median | right | wrong | never |",
             "|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['gn']} | {r['protocol']} | {r['config']} | {r['lns']} | "
                     f"{r['fixed']} | {r['nodes_median']} | {r['correct_match']} | "
                     f"{r['false_match']} | {r['never']} |")
    lines += ["", "Null test (LNs of another GN; every fix is wrong):", "",
              "| GN | configuration | matches | fixes | least false-match probability |",
              "|---|---|---|---|---|"]
    for n in nulls:
        lines.append(f"| {n['gn']} | {n['config']} | {n['matches']} | {n['fixes']} | "
                     f"{n['min_false_match_probability']:.2f} |")
    (RESULTS / "darces_marginal.md").write_text("\n".join(lines) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
