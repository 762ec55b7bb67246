"""Every benchmark the README and docs quote, in one go, into bench/results/current/.

``make bench`` runs the quick tier, ``make bench TIER=full`` the full one::

    python bench/run_all.py --tier quick            # the demo bag, small matcher tables
    python bench/run_all.py --tier full             # + atacama_1km seeds 1-3, committed sizes
    python bench/run_all.py --tier full --dry-run   # print the commands, run nothing

Steps, in order (each one a bench script of bench/, run as its own process):

1. bags: generate an evaluation bag that is missing (``atacama_sim generate``) and its GN
   (``orbital_gn prepare``), as ``make demo`` does;
2. e2e: ``e2e_bench.py`` on the evaluation bags (the graph, ``globloc eval``, the paper's
   end-of-route protocol);
3. vo: ``vo_bench.py`` (quick: rover_vo's modes; full: also the third-party odometry);
4. roi: ``roi_bench.py`` on truth odometry and on the odometry of step 2's runs;
5. orbital: ``orbital_gn_bench.py quality`` (quick: the default recipe; full: every recipe)
   and ``matcher`` on each bag's GN;
6. matcher: ``darces_bench.py quick`` (perfect LNs of the demo bag) and ``generality``
   (quick: three family GNs, the default matcher; full: the whole family, the paper
   protocol and its stressed version);
7. heldout (full tier only): six held-out worlds of the quick preset (seeds 201-206, never
   used to train or tune), each with panoramas and fixed: their bags, roi on truth
   odometry, e2e on the first three;
8. sun (full tier only): e2e on the demo bag and the first three held-out worlds with
   panoramas, as configured and without rover_vo's sun heading, side by side.

The results directory is emptied first (``--only`` keeps it), so that every file in it
comes from one commit. Each result file then records the commit (and whether the tree
had changes), the command, the machine and the date; ``summary.md`` holds one table per
bench. A step that fails is reported and the others still run; the exit status is 1 if
any failed.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "bench"
RESULTS = BENCH / "results" / "current"
WORK = ROOT / "out" / "bench" / "work"
#: Run directories of the graph (``globloc run --out``).
RUNS = ROOT / "out" / "bench"
TIERS = ("quick", "full")
#: Evaluation bags per tier: (directory name, simulator preset, seed, generate options).
#: Each world comes twice: as the presets make it (stereo panoramas from the mast at drive
#: stops) and with ``--no-panoramas`` (the fixed forward camera), side by side in one run.
FIXED = ("--no-panoramas",)
EVAL_BAGS = {
    "quick": [("quick", "quick", 1, ()), ("quick_fixed", "quick", 1, FIXED)],
    "full": [("quick", "quick", 1, ()), ("quick_fixed", "quick", 1, FIXED),
             *[(f"atacama_1km_s{s}{suffix}", "atacama_1km", s, opts) for s in (1, 2, 3)
               for suffix, opts in (("", ()), ("_fixed", FIXED))]],
}
#: Held-out worlds of the full tier's ``heldout`` step: seeds never used to train or tune,
#: of the quick preset (400 m; a 1 km pair costs about 1.5 CPU-hours, the quick pair a
#: third of that), each with panoramas and fixed: all through roi_bench, the first
#: ``HELDOUT_E2E_SEEDS`` end to end (a quick pair plays for 14 min at 5x on 2 cores).
HELDOUT_SEEDS = (201, 202, 203, 204, 205, 206)
HELDOUT_E2E_SEEDS = 3
HELDOUT_BAGS = [(f"quick_s{s}{suffix}", "quick", s, opts) for s in HELDOUT_SEEDS
                for suffix, opts in (("", ()), ("_fixed", FIXED))]
#: The held-out runs' results name: e2e_heldout.*, roi_heldout.*.
HELDOUT_TAG = "heldout"
#: The sun heading end to end: the demo bag and the first ``SUN_HELDOUT_SEEDS`` held-out
#: worlds with panoramas, each run as configured and without rover_vo's sun heading, side
#: by side (``e2e_bench.py --compare``); results e2e_sun.*.
SUN_HELDOUT_SEEDS = 3
SUN_COMPARE = ("--compare", "rover_vo:imu.sun_heading=false", "--compare-label", "no_sun")
SUN_TAG = "sun"
#: Playback rate of the end-to-end runs (``globloc run --rate``).
RATE = 5.0
#: Graphs run side by side in the e2e step, each in its own ROS domain (2 cores keep up
#: with two graphs at 5x).
E2E_JOBS = 2
#: The e2e, roi results' name: e2e_<tag>.*, roi_<tag>.*.
TAG = "evaluation"
#: Family GNs of the quick tier's generality table: one sparse and clustered, one dense,
#: one strongly clustered (the rows the matcher finds hardest).
QUICK_FAMILY = "thomas_few,matern_1000,thomas_strong"
#: LNs per family GN, clean and stressed (the committed table's sizes; the quick tier too).
GENERALITY_LNS, GENERALITY_STRESS_LNS, GENERALITY_SEED = 120, 100, 7
#: Perfect-LN trials on the demo bag (darces_bench.py quick).
QUICK_TRIALS = 20
STEPS = ("bags", "e2e", "vo", "roi", "orbital", "matcher", "heldout", "sun")


@dataclass
class Command:
    """One process of a step; ``argv`` may depend on what earlier steps wrote."""

    step: str
    argv: list[str] | Callable[[], list[str]]
    #: Skipped when true at run time (e.g. the bag exists already).
    skip_if: Callable[[], bool] = field(default=lambda: False)
    why_skip: str = ""

    def resolve(self) -> list[str]:
        return self.argv() if callable(self.argv) else list(self.argv)


def _py(script: str, *args: str) -> list[str]:
    return [sys.executable, str(BENCH / script), *args]


def _rel(path: Path) -> str:
    try:
        return str(path.resolve().relative_to(ROOT))
    except ValueError:
        return str(path)


def shown(cmd: list[str]) -> str:
    """A command as a user would type it from the repository root."""
    words = ["python" if a == sys.executable else a.replace(f"{ROOT}/", "") for a in cmd]
    return " ".join(words)


def e2e_runs(results: Path, tag: str = TAG) -> dict[str, str]:
    """Bag name -> run directory of an e2e step (from its JSON)."""
    path = results / f"e2e_{tag}.json"
    if not path.is_file():
        return {}
    return {Path(b["bag"]).name: b["run_dir"] for b in json.loads(path.read_text())["bags"]
            if b.get("run_dir")}


def bag_commands(step: str, bags_dir: Path,
                 specs: list[tuple[str, str, int, tuple[str, ...]]]) -> list[Command]:
    """Generate each bag that is missing (``atacama_sim generate``) and its GN."""
    cmds: list[Command] = []
    for name, preset, seed, opts in specs:
        bag = bags_dir / name
        cmds.append(Command(step, ["atacama_sim", "generate", "--preset", preset, "--seed",
                                   str(seed), *opts, "--no-progress", "--out", str(bag)],
                            skip_if=lambda bag=bag: (bag / "rosbag").is_dir(),
                            why_skip=f"{_rel(bag)}/rosbag exists"))
        cmds.append(Command(step, ["orbital_gn", "prepare", str(bag / "orbital.tif"), "--out",
                                   str(bag / "gn.geojson"), "--preview", str(bag / "gn.png")],
                            skip_if=lambda bag=bag: (bag / "gn.geojson").is_file(),
                            why_skip=f"{_rel(bag)}/gn.geojson exists"))
    return cmds


def e2e_command(step: str, bags: list[Path], tag: str, results: Path,
                extra: tuple[str, ...] = ()) -> Command:
    """``e2e_bench.py`` on ``bags``, two graphs at a time, results e2e_<tag>.*; ``extra``:
    more of its options (``--compare`` runs two graphs per bag)."""
    paths = [str(b) for b in bags]
    jobs = min(E2E_JOBS, len(paths) * (2 if "--compare" in extra else 1))
    return Command(step, _py("e2e_bench.py", *paths, "--rate", f"{RATE:g}", "--jobs",
                             str(jobs), "--tag", tag, "--out", str(RUNS), "--results",
                             str(results), *extra))


def roi_command(step: str, bags: list[Path], tag: str, results: Path, dry_run: bool,
                with_vo: bool = True) -> Command:
    """``roi_bench.py`` on ``bags`` (two at a time), results roi_<tag>.*: on truth odometry
    and (``with_vo``) on the odometry of the e2e runs of the same tag."""

    def argv() -> list[str]:
        runs = {} if dry_run else e2e_runs(results, tag)
        extra: list[str] = []
        for bag in bags:
            run = runs.get(bag.name)
            vo = f"{run}/vo.tum" if run else f"<e2e run of {bag.name}>/vo.tum"
            if with_vo and (run or dry_run):
                extra += ["--vo", f"{bag.name}={vo}"]
            extra += ["--gn", f"{bag.name}={bag / 'gn.geojson'}"]
        return _py("roi_bench.py", "--name", tag, *map(str, bags), *extra, "--jobs",
                   str(min(E2E_JOBS, len(bags))))

    return Command(step, argv)


def plan(tier: str, bags_dir: Path, results: Path, dry_run: bool = False) -> list[Command]:
    """The commands of a tier, in order."""
    bags = [(bags_dir / name, preset, seed) for name, preset, seed, _ in EVAL_BAGS[tier]]
    options = {name: opts for name, _, _, opts in EVAL_BAGS[tier]}
    paths = [str(b) for b, _, _ in bags]
    # 1. bags and their GNs
    cmds = bag_commands("bags", bags_dir, EVAL_BAGS[tier])
    # 2. end to end
    cmds.append(e2e_command("e2e", [b for b, _, _ in bags], TAG, results))
    # 3. odometry
    vo_methods = [] if tier == "full" else ["--methods", *_vo_modes()]
    cmds.append(Command("vo", _py("vo_bench.py", "--bags", *paths, *vo_methods, "--force")))
    # 4. rover detection, on truth odometry and on the e2e runs' odometry
    cmds.append(roi_command("roi", [b for b, _, _ in bags], TAG, results, dry_run))
    # 5. orbital GN (a _fixed bag's world, orbital image and GN are its twin's)
    worlds = [(bag, p, s) for bag, p, s in bags if not options[bag.name]]
    recipes = [] if tier == "full" else ["--recipes", "sun_aware"]
    cmds.append(Command("orbital", _py("orbital_gn_bench.py", "quality", "--bags",
                                       *[str(b) for b, _, _ in worlds], *recipes)))
    for bag, _, _ in worlds:
        cmds.append(Command("orbital", _py("orbital_gn_bench.py", "matcher", "--bag", str(bag),
                                           "--gn", str(bag / "gn.geojson"))))
    # 6. matcher tables
    cmds.append(Command("matcher", _py("darces_bench.py", "quick", "--bag", str(bags[0][0]),
                                       "--trials", str(QUICK_TRIALS))))
    sizes = ["--max-lns", str(GENERALITY_LNS), "--stress-lns", str(GENERALITY_STRESS_LNS),
             "--seed", str(GENERALITY_SEED)]
    if tier == "quick":
        cmds.append(Command("matcher", _py("darces_bench.py", "generality", *sizes,
                                           "--gns", QUICK_FAMILY, "--methods", "darces")))
    else:
        cmds.append(Command("matcher", _py("darces_bench.py", "generality", *sizes)))
        cmds.append(Command("matcher", _py("darces_bench.py", "paper")))
        cmds.append(Command("matcher", _py("darces_bench.py", "stress")))
        # 7. held-out worlds: their bags, rover detection on truth odometry (what the
        # camera and the detector find), end to end
        cmds += bag_commands("heldout", bags_dir, HELDOUT_BAGS)
        held = [bags_dir / name for name, *_ in HELDOUT_BAGS]
        cmds.append(roi_command("heldout", held, HELDOUT_TAG, results, dry_run, with_vo=False))
        cmds.append(e2e_command("heldout", held[:2 * HELDOUT_E2E_SEEDS], HELDOUT_TAG, results))
        # 8. the sun heading end to end, with and without, on the worlds with panoramas
        specs = [EVAL_BAGS[tier][0], *(b for b in HELDOUT_BAGS if not b[3])][
            :1 + SUN_HELDOUT_SEEDS]
        cmds += bag_commands("sun", bags_dir, specs)
        sun = [bags_dir / name for name, *_ in specs]
        cmds.append(e2e_command("sun", sun, SUN_TAG, results, SUN_COMPARE))
    return cmds


def _vo_modes() -> list[str]:
    """rover_vo's own modes as vo_bench.py runs them (not the third-party odometry)."""
    sys.path.insert(0, str(BENCH))
    try:
        import vo_bench
    finally:
        sys.path.remove(str(BENCH))
    return list(vo_bench.MODES)


def git_state() -> dict[str, Any]:
    """HEAD and whether the tree (outside bench/results/current/) has changes."""
    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                              check=False).stdout.strip()

    head = git("rev-parse", "HEAD") or "unknown"
    changes = [line for line in git("status", "--porcelain").splitlines()
               if "bench/results/current/" not in line]
    return {"commit": head, "dirty": bool(changes)}


def provenance(tier: str, argv: list[str], started: str) -> dict[str, Any]:
    return {**git_state(), "command": " ".join(["python bench/run_all.py", *argv]),
            "tier": tier, "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                      "platform": platform.platform()},
            "date": started}


def _provenance_line(prov: dict[str, Any]) -> str:
    m = prov["machine"]
    dirty = " (with uncommitted changes)" if prov["dirty"] else ""
    return (f"Commit `{prov['commit'][:12]}`{dirty}; `{prov['command']}` (tier {prov['tier']}); "
            f"{m['cpus']} CPUs, Python {m['python']}; {prov['date']}.")


def stamp(results: Path, prov: dict[str, Any], since: float = 0.0) -> list[Path]:
    """Record ``prov`` in every result file written at or after ``since`` (a time stamp,
    s): a ``provenance`` key in a JSON object, a line under the title of a Markdown file.
    Files of an earlier ``--only`` run keep their own. Returns the files stamped."""
    done = []
    for path in sorted(results.iterdir()):
        if path.stat().st_mtime < since:
            continue
        if path.suffix == ".json":
            doc = json.loads(path.read_text())
            if not isinstance(doc, dict):
                continue
            doc["provenance"] = prov
            path.write_text(json.dumps(doc, indent=2) + "\n")
        elif path.suffix == ".md" and path.name != "summary.md":
            lines = path.read_text().splitlines()
            lines = [ln for ln in lines if not ln.startswith("Provenance: ")]
            at = 1 if lines and lines[0].startswith("#") else 0
            lines[at:at] = ["", "Provenance: " + _provenance_line(prov)]
            path.write_text("\n".join(lines) + "\n")
        else:
            continue
        done.append(path)
    return done


def _fmt(v: Any, digits: int = 2, scale: float = 1.0) -> str:
    if v is None:
        return "n/a"
    if isinstance(v, bool):
        return "yes" if v else "no"
    if isinstance(v, (int, float)):
        return f"{v * scale:.{digits}f}"
    return str(v)


def e2e_table(doc: dict[str, Any]) -> list[str]:
    """The README's figures per bag from e2e_bench.py's JSON."""
    lines = ["| bag | route (m) | first fix after (m) | final error (m) | RMSE after fix (m) "
             "| false fixes (> 10 m) | 3-sigma | paper's protocol: final error / RMSE (m) |",
             "|---|---|---|---|---|---|---|---|"]
    for e in doc["bags"]:
        c, p = e.get("continuous", {}), e.get("end_of_route", {})
        paper = (f"{_fmt(p.get('final_error_m'))} / {_fmt(p.get('rmse_m'))}"
                 if p.get("status") == "fix" else p.get("status", "n/a"))
        cons = c.get("consistency_3sigma")
        name = Path(e["bag"]).name + (f" ({e['variant']})" if e.get("variant") else "")
        lines.append(
            f"| {name} | {_fmt(c.get('route_length_m'), 0)} "
            f"| {_fmt(c.get('distance_before_first_fix_m'), 1)} | {_fmt(c.get('final_error_m'))} "
            f"| {_fmt(c.get('rmse_after_first_fix_m'))} | {_fmt(c.get('false_fixes'), 0)} "
            f"| {_fmt(cons, 1, 100.0)}{' %' if cons is not None else ''} | {paper} |")
    return lines


def darces_quick_table(doc: dict[str, Any]) -> list[str]:
    lines = [f"Perfect LNs ({doc.get('ln_nodes')} nodes, corridor {doc.get('radius_m')} m) of "
             f"`{Path(doc.get('bag', '')).name}` against its {doc.get('gn_rois')} truth ROIs.", "",
             "| method | trials | fixes | max error (m) |", "|---|---|---|---|"]
    for name, m in doc.get("methods", {}).items():
        lines.append(f"| {name} | {m['trials']} | {m['fixes']} | {_fmt(m.get('max_error_m'))} |")
    return lines


def first_table(md: str) -> list[str]:
    """The first Markdown table of a bench's own report."""
    out: list[str] = []
    for line in md.splitlines():
        if line.startswith("|"):
            out.append(line)
        elif out:
            break
    return out


#: summary.md's sections: (title, file, how to read it, the step that writes it).
SECTIONS = (
    ("End to end", f"e2e_{TAG}.json", e2e_table, "e2e"),
    ("End to end, held-out worlds", f"e2e_{HELDOUT_TAG}.json", e2e_table, "heldout"),
    ("End to end, with and without the sun heading", f"e2e_{SUN_TAG}.json", e2e_table, "sun"),
    ("Odometry (rover_vo)", "vo_bench.md", None, "vo"),
    ("Rover detection and LN (roi_detector)", f"roi_{TAG}.md", None, "roi"),
    ("Rover detection and LN, held-out worlds", f"roi_{HELDOUT_TAG}.md", None, "heldout"),
    ("Orbital GN: detection quality (orbital_gn)", "orbital_gn_quality.md", None, "orbital"),
    ("Matcher: perfect LNs of the demo bag", "darces_quick.json", darces_quick_table, "matcher"),
    ("Matcher: generality over the evaluation family", "darces_generality.md", None, "matcher"),
    ("Matcher: paper protocol", "darces_paper.md", None, "matcher"),
    ("Matcher: paper protocol, 30 % outliers + 10 % label flips", "darces_stress.md", None,
     "matcher"),
)


def summary(results: Path, prov: dict[str, Any], failed: list[str]) -> str:
    """One table per bench from the files in ``results``."""
    lines = ["# Benchmark summary", "", "Provenance: " + _provenance_line(prov), ""]
    if failed:
        lines += ["Failed: " + "; ".join(f"`{f}`" for f in failed), ""]
    sections = [*SECTIONS] + [
        (f"Orbital GN: the matcher on {p.stem.removeprefix('orbital_gn_matcher_')}'s GN",
         p.name, None, "orbital") for p in sorted(results.glob("orbital_gn_matcher_*.md"))]
    for title, name, reader, _ in sections:
        path = results / name
        if not path.is_file():
            continue
        text = path.read_text()
        table = reader(json.loads(text)) if reader else first_table(text)
        lines += [f"## {title}", "", *table, "", f"From [`{name}`]({name}).", ""]
    return "\n".join(lines)


def clear(results: Path) -> None:
    """Remove the result files (not directories) of an earlier run from ``results``."""
    if not results.is_dir():
        return
    if (results / "studies").exists():
        sys.exit(f"run_all: refusing to clear {results}: it holds studies/")
    for path in results.iterdir():
        if path.is_file() and not path.name.startswith("."):
            path.unlink()


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tier", choices=TIERS, default="quick")
    ap.add_argument("--dry-run", action="store_true", help="print the commands, run nothing")
    ap.add_argument("--only", help=f"comma-separated steps of {', '.join(STEPS)} (keeps the "
                    "other results)")
    ap.add_argument("--bags-dir", type=Path, default=ROOT / "bags")
    ap.add_argument("--results", type=Path, default=RESULTS)
    args = ap.parse_args(argv)
    only = set(STEPS) if not args.only else {s.strip() for s in args.only.split(",")}
    if only - set(STEPS):
        ap.error(f"--only: unknown steps {sorted(only - set(STEPS))} (known: {', '.join(STEPS)})")
    results = args.results.resolve()
    cmds = [c for c in plan(args.tier, args.bags_dir, results, args.dry_run) if c.step in only]
    env = dict(os.environ) | {"BENCH_RESULTS": str(results), "BENCH_WORK": str(WORK)}
    if args.dry_run:
        print(f"# BENCH_RESULTS={_rel(results)} BENCH_WORK={_rel(WORK)}")
        for c in cmds:
            note = f"  # skipped: {c.why_skip}" if c.skip_if() else ""
            print(f"[{c.step}] {shown(c.resolve())}{note}")
        return 0
    started = datetime.now(UTC).isoformat(timespec="seconds")
    t_start = time.time()
    state = git_state()
    if not args.only:
        clear(results)
    results.mkdir(parents=True, exist_ok=True)
    failed: list[str] = []
    for c in cmds:
        if c.skip_if():
            print(f"[run_all] {c.step}: skipped ({c.why_skip})", flush=True)
            continue
        cmd = c.resolve()
        print(f"[run_all] {c.step}: {shown(cmd)}", flush=True)
        if subprocess.run(cmd, cwd=ROOT, env=env, check=False).returncode != 0:
            failed.append(shown(cmd))
    prov = provenance(args.tier, argv, started)
    if git_state()["commit"] != state["commit"]:
        failed.append(f"HEAD moved during the run ({state['commit'][:12]} -> "
                      f"{prov['commit'][:12]}): results are not from one commit")
    prov["dirty"] = prov["dirty"] or state["dirty"]
    stamp(results, prov, since=t_start)
    (results / "summary.md").write_text(summary(results, prov, failed))
    for f in failed:
        print(f"[run_all] FAILED: {f}", file=sys.stderr)
    print(f"[run_all] results in {_rel(results)}; summary: {_rel(results / 'summary.md')}")
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main())
