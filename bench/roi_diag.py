"""Per truth rock, or per truth outcrop (``--outcrops``), why the rover's elevation map did
or did not find it.

Runs the LN of a bag with the truth trajectory as odometry (``roi_detector ln``'s library
path, detection geometry alone) while recording every rock region the map's detection
rounds examined and the test that rejected it (``ElevationMap.trace``). Then, for each
truth rock the recall counts (above the rover thresholds, within 15 m of the route): its
closest approach to the route, the stereo pairs that had it in view, whether the LN holds
it, and the furthest stage any region near it reached, with what that region measured:

``none`` (no rock region near it: no dark cell stood high enough in a well-observed
map), ``small``, ``ring_unseen`` (the ground around it unobserved), ``low``
(height under the threshold), ``area``, ``flat`` (relief ratio), ``rock`` (a region passed
every test; if the LN still misses it, its centre fell outside the matching radius or the
ROI flickered across rounds).

And the far rocks' verdict (:mod:`roi_detector.far_rocks`, the rocks the map cannot
reach), from the closed far tracks whose triangulated rock lies within the matching
radius plus 1 m: ``none`` (no such track: no dark blob followed in enough pairs),
``geometry`` (the best of them failed the bearing spread, ray residual or nearest-range
test), ``refused`` (the Rock Rover, or without one the size thresholds, refused it),
``kept`` (a far rock; if the LN still misses it, it lay outside the matching radius or a
map rock hid it), with that track's measurement.

With ``--outcrops``, per truth outcrop the recall counts: what the map held in its truth
footprint at the detection round that had observed most of it (the share of the footprint
with colour samples, of it passing the outcrop rule's colour test and its height test, the
averaged saturation and value inside and in the soil ring around it), and the furthest
stage an outcrop ROI of the map near it reached: ``unseen`` (under a fifth of the
footprint ever observed), ``colour`` (observed, but under a fifth of it passed the colour
test), ``region`` (no outcrop region formed there: too small once opened, or too high),
``flicker`` (a region, not found in enough rounds), ``refused`` (the Outcrop Rover scored
it at most ``map_outcrop_min_score``), ``reported`` (the map reports it; if the LN still
misses it, its centre lies outside the matching radius). The stage is the map's at the
end of the drive, and the LN keeps a node once reported: an outcrop whose ROI later fell
under the hit ratio (``flicker``), or was merged into a neighbouring one (``region``), can
still be in the LN.

Evaluation code: reads truth/. Usage (from the repository root, after ``source env.sh``)::

    python bench/roi_diag.py bags/quick [--outcrops] [--json OUT.json]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
from pathlib import Path

import numpy as np

#: Stages a rock region goes through, in order (ElevationMap.trace verdicts).
STAGES = ("none", "small", "ring_unseen", "low", "area", "flat", "rock")


def furthest(verdicts: list[tuple[str, dict]]) -> tuple[str, dict]:
    """The furthest stage among the verdicts of the regions near one rock, and the last
    measurement at that stage."""
    if not verdicts:
        return "none", {}
    best = max(STAGES.index(v) for v, _ in verdicts)
    last = [m for v, m in verdicts if STAGES.index(v) == best][-1]
    return STAGES[best], last


def default_mapper(rule: str | None = None, model: str | None = None):
    """A DriveMapper with the committed defaults and model; or with the outcrop rule
    ``rule`` and the rover model ``model`` (trained on that rule's candidates)."""
    from roi_detector.cli import load_classifier
    from roi_detector.elevation_map import outcrop_rule
    from roi_detector.rover_pipeline import DriveMapper, RoverConfig

    cfg = RoverConfig() if rule is None else RoverConfig(elevation_map=outcrop_rule(rule))
    return DriveMapper(cfg, classifier=load_classifier(model, cfg))


def ln_on_truth(bag: str, truth, mapper, trace=None):
    """The LN ``mapper`` builds on ``bag`` with the truth trajectory as odometry
    (``roi_detector ln``'s library path)."""
    from roi_detector.cli import build_ln

    with tempfile.TemporaryDirectory() as tmp:
        odom = Path(tmp) / "truth_odom.tum"
        truth.write_odom_tum(odom)
        ln, _ = build_ln(bag, str(odom), None, mapper.cfg, log=lambda m: None,
                         mapper=mapper, trace=trace)
    return ln


def found_in_ln(ln, truth, label: int) -> set[int]:
    """Indices of the truth ROIs of class ``label`` that a node of ``ln`` matches."""
    from roi_detector.evaluation import match_nodes, true_nodes

    nodes = ln.network().records
    _, j = match_nodes(nodes, truth)
    return set(j[true_nodes(nodes, truth.rois, j, label)].tolist())


def truth_views(bag: str, truth) -> np.ndarray:
    """Per truth ROI, the stereo pairs that had it in view within 20 m."""
    from roi_detector.inputs import load_rover_params

    return truth.views(load_rover_params(Path(bag) / "rover.yaml"), 20.0)


def route_distance(truth, i: int) -> float:
    """The closest approach of the route to truth ROI ``i`` (m)."""
    from roi_network.records import xy

    return float(np.min(np.linalg.norm(truth.trajectory.p[:, :2] - xy(truth.rois[i:i + 1]),
                                       axis=1)))


def diagnose(bag: str) -> list[dict]:
    """One row per counted truth rock (see the module)."""
    from roi_detector.truth import Truth, match_rule_radius
    from roi_network.records import ROCK, xy

    truth = Truth.load(bag)
    events: list[tuple[str, np.ndarray, dict]] = []
    mapper = default_mapper()
    ln = ln_on_truth(bag, truth, mapper,
                     trace=lambda v, p, m: events.append((v, np.array(p), m)))

    def to_map(points_odom: list) -> np.ndarray:
        """(N, 2) map x-y of odom x-y points."""
        if not points_odom:
            return np.zeros((0, 2))
        pts = np.array(points_odom, float)
        return truth.odom_to_map(np.column_stack([pts, np.zeros(len(pts))]))[:, :2]

    far = mapper.far.measured
    far_map = to_map([f.xy for f in far])
    r = truth.rois
    counted = np.flatnonzero(truth.counted(15.0) & (r["label"] == ROCK))
    found = found_in_ln(ln, truth, ROCK)
    ev_map = to_map([p for _, p, _ in events])
    views = truth_views(bag, truth)
    rows = []
    for i in counted:
        gate = float(match_rule_radius(r["major_m"][i])) + 0.5
        near = np.linalg.norm(ev_map - xy(r[i:i + 1]), axis=1) < gate
        stage, measured = furthest([(events[k][0], events[k][2]) for k in np.flatnonzero(near)])
        d_far = np.linalg.norm(far_map - xy(r[i:i + 1]), axis=1)
        near_far = np.flatnonzero(d_far < gate + 0.5)
        far_stage, far_measured = far_verdict([far[k] for k in near_far], mapper.far.cfg,
                                              d_far[near_far])
        rows.append({"id": int(r["id"][i]), "area_m2": float(r["area_m2"][i]),
                     "height_m": float(r["height_m"][i]),
                     "route_distance_m": route_distance(truth, i),
                     "views": int(views[i]), "in_ln": bool(i in found), "stage": stage,
                     "measured": {k: (None if v is None else round(float(v), 3))
                                  for k, v in measured.items()},
                     "far_stage": far_stage, "far_measured": far_measured})
    return rows


#: Outcrop verdicts, in order (see the module).
OUTCROP_STAGES = ("unseen", "colour", "region", "flicker", "refused", "reported")


def high(z: np.ndarray, seen: np.ndarray, inside: np.ndarray, ring: np.ndarray,
         limit_m: float) -> float | None:
    """The share of the observed cells of ``inside`` standing at least ``limit_m`` above
    the median height of the ring's (None: either unobserved)."""
    if not (ring & seen).any() or not (inside & seen).any():
        return None
    return float(np.mean(z[inside & seen] - np.median(z[ring & seen]) >= limit_m))


_CELLS_ON_MAP: dict = {}


def _cells_on_map(emap, truth) -> np.ndarray:
    """Map x, y of every cell centre of ``emap`` by the truth odometry (kept while the
    map's window stays put: it moves only when the rover nears its border)."""
    key = (emap.n, emap.cfg.cell_m, *np.asarray(emap.origin, float).tolist())
    if _CELLS_ON_MAP.get("key") != key or _CELLS_ON_MAP.get("truth") is not truth:
        n = emap.n
        ij = np.stack(np.meshgrid(np.arange(n), np.arange(n), indexing="ij"),
                      -1).reshape(-1, 2)
        cxy = emap._cell_xy(ij)
        _CELLS_ON_MAP.update(key=key, truth=truth, xy=truth.odom_to_map(
            np.column_stack([cxy, np.zeros(len(cxy))]))[:, :2])
    return _CELLS_ON_MAP["xy"]


def footprint_stats(emap, truth, outcrops: np.ndarray) -> list[dict | None]:
    """Per truth outcrop, what ``emap`` (an ElevationMap, just after a detection round)
    holds in its truth footprint (None: not inside the map's window)."""
    c = emap.cfg
    if emap.origin is None or not emap.nb.any():
        return [None] * len(outcrops)
    n = emap.n
    mxy = _cells_on_map(emap, truth)
    z, seen = emap.heights()
    have, sat, val = emap.averaged_colour(max(c.outcrop_colour_sigma_m, c.cell_m))
    pale = emap.outcrop_colour(have, sat, val)
    out: list[dict | None] = []
    for o in outcrops:
        d = mxy - np.array([o["x"], o["y"]])
        ca, sa = np.cos(o["angle_rad"]), np.sin(o["angle_rad"])
        u, v = d[:, 0] * ca + d[:, 1] * sa, -d[:, 0] * sa + d[:, 1] * ca
        a, b = 0.5 * float(o["major_m"]), 0.5 * float(o["minor_m"])
        rr = (u / a) ** 2 + (v / b) ** 2
        inside = (rr <= 1.0).reshape(n, n)
        ring = ((rr > 1.3**2) & (rr <= 2.0**2)).reshape(n, n)
        if inside.sum() < 4:
            out.append(None)
            continue
        obs = inside & have
        colour_ok = inside & pale
        ring_obs = ring & have
        out.append({
            "cells": int(inside.sum()), "observed": float(obs.mean() / inside.mean()),
            "colour_ok": float(colour_ok.sum() / inside.sum()),
            "high": high(z, seen, inside, ring, c.max_outcrop_height_m),
            "sat": float(np.median(sat[obs])) if obs.any() else None,
            "val": float(np.median(val[obs])) if obs.any() else None,
            "ring_sat": float(np.median(sat[ring_obs])) if ring_obs.any() else None,
            "ring_val": float(np.median(val[ring_obs])) if ring_obs.any() else None})
    return out


def diagnose_outcrops(bag: str, rule: str | None = None,
                      model: str | None = None) -> list[dict]:
    """One row per counted truth outcrop (see the module), with the committed defaults
    or the outcrop rule ``rule`` and the model ``model``."""
    from roi_detector.truth import Truth, match_rule_radius
    from roi_network.records import OUTCROP, xy

    truth = Truth.load(bag)
    r = truth.rois
    counted = np.flatnonzero(truth.counted(15.0) & (r["label"] == OUTCROP))
    mapper = default_mapper(rule, model)
    best: list[dict | None] = [None] * len(counted)
    detect = mapper.map.detect

    def probed(*a, **k):
        found = detect(*a, **k)
        for n, st in enumerate(footprint_stats(mapper.map, truth, r[counted])):
            if st is not None and (best[n] is None or st["observed"] > best[n]["observed"]
                                   or (st["observed"] == best[n]["observed"]
                                       and st["colour_ok"] > best[n]["colour_ok"])):
                best[n] = st
        return found

    mapper.map.detect = probed
    ln = ln_on_truth(bag, truth, mapper)
    emap = mapper.map
    floor = emap.cfg.map_outcrop_min_score
    rois = [q for q in emap.rois if q.label == OUTCROP]
    rois_map = truth.odom_to_map(np.array([[*q.xy, 0.0] for q in rois]))[:, :2] if rois \
        else np.zeros((0, 2))
    found = found_in_ln(ln, truth, OUTCROP)
    views = truth_views(bag, truth)
    rows = []
    for n, i in enumerate(counted):
        gate = float(match_rule_radius(r["major_m"][i])) + 0.5
        d = np.linalg.norm(rois_map - xy(r[i:i + 1]), axis=1)
        near = [(rois[k], float(d[k])) for k in np.flatnonzero(d < gate)]

        def stage(q) -> int:
            if not emap.persists(q):
                return 3
            return 4 if q.score <= floor else 5

        st = best[n]
        if near:
            q, dq = max(near, key=lambda e: (stage(e[0]), -e[1]))
            verdict = OUTCROP_STAGES[stage(q)]
            roi = {"off_m": round(dq, 2), "area_m2": round(q.area_m2, 1),
                   "rounds": q.rounds, "examined": q.examined,
                   "score": None if not np.isfinite(q.score) else round(q.score, 2)}
        else:
            roi = {}
            verdict = ("unseen" if st is None or st["observed"] < 0.2 else
                       "colour" if st["colour_ok"] < 0.2 else "region")
        rows.append({"id": int(r["id"][i]), "area_m2": float(r["area_m2"][i]),
                     "major_m": float(r["major_m"][i]), "minor_m": float(r["minor_m"][i]),
                     "route_distance_m": route_distance(truth, i),
                     "views": int(views[i]), "in_ln": bool(i in found), "stage": verdict,
                     "footprint": {k: (None if v is None else round(float(v), 2))
                                   for k, v in (st or {}).items()},
                     "roi": roi})
    return rows


def markdown_outcrops(bag: str, rows: list[dict]) -> str:
    """The outcrop rows as a Markdown table, with the count per stage."""
    lines = [f"# roi_diag --outcrops: {bag}", "",
             "| truth id | area m^2 | axes m | from route m | views | in LN | stage "
             "| footprint (best round) | map ROI |", "|---|---|---|---|---|---|---|---|---|"]
    for w in sorted(rows, key=lambda w: w["route_distance_m"]):
        fp = ", ".join(f"{k} {v}" for k, v in w["footprint"].items())
        ro = ", ".join(f"{k} {v}" for k, v in w["roi"].items())
        lines.append(f"| {w['id']} | {w['area_m2']:.1f} | {w['major_m']:.1f} x "
                     f"{w['minor_m']:.1f} | {w['route_distance_m']:.1f} | {w['views']} "
                     f"| {w['in_ln']} | {w['stage']} | {fp} | {ro} |")
    counts = {s: sum(w["stage"] == s for w in rows) for s in OUTCROP_STAGES}
    lines += ["", f"In the LN: {sum(w['in_ln'] for w in rows)} of {len(rows)}; stage: "
              + ", ".join(f"{s} {n}" for s, n in counts.items() if n)]
    return "\n".join(lines) + "\n"


#: Far-track verdicts, in order (see the module).
FAR_STAGES = ("none", "geometry", "refused", "kept")


def far_verdict(tracks: list, cfg, dist: np.ndarray) -> tuple[str, dict]:
    """The furthest far-rock verdict among the closed far tracks near one rock, and that
    track's measurement (the nearest one among equals)."""
    if not tracks:
        return "none", {}

    def stage(f) -> int:
        if f.passed:
            return 3
        decidable = bool(cfg.passes_geometry(f.parallax_deg, f.residual_px, f.nearest_m,
                                             classified=True))
        return 2 if decidable else 1

    order = sorted(range(len(tracks)), key=lambda k: (-stage(tracks[k]), dist[k]))
    f, d = tracks[order[0]], float(dist[order[0]])
    return FAR_STAGES[stage(f)], {
        "off_m": round(d, 2), "views": f.n_views, "spread_deg": round(f.parallax_deg, 1),
        "residual_px": round(f.residual_px, 2), "nearest_m": round(f.nearest_m, 1),
        "height_m": round(f.height_m, 2), "area_m2": round(f.area_m2, 2),
        "score": None if not np.isfinite(f.score) else round(f.score, 2)}


def markdown(bag: str, rows: list[dict]) -> str:
    """The rows as a Markdown table, with the count per stage."""
    lines = [f"# roi_diag: {bag}", "",
             "| truth id | area m^2 | height m | from route m | views | in LN "
             "| furthest stage | measured | far rocks | far track |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for w in sorted(rows, key=lambda w: w["route_distance_m"]):
        m = ", ".join(f"{k} {v}" for k, v in w["measured"].items())
        fm = ", ".join(f"{k} {v}" for k, v in w.get("far_measured", {}).items())
        lines.append(f"| {w['id']} | {w['area_m2']:.2f} | {w['height_m']:.2f} "
                     f"| {w['route_distance_m']:.1f} | {w['views']} | {w['in_ln']} "
                     f"| {w['stage']} | {m} | {w.get('far_stage', '-')} | {fm} |")
    counts = {s: sum(w["stage"] == s for w in rows) for s in STAGES}
    far_counts = {s: sum(w.get("far_stage") == s for w in rows) for s in FAR_STAGES}
    lines += ["", f"In the LN: {sum(w['in_ln'] for w in rows)} of {len(rows)}; furthest stage: "
              + ", ".join(f"{s} {n}" for s, n in counts.items() if n)
              + "; far rocks: " + ", ".join(f"{s} {n}" for s, n in far_counts.items() if n)]
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("bag", help="bag directory with truth/")
    ap.add_argument("--outcrops", action="store_true",
                    help="per truth outcrop instead of per truth rock")
    ap.add_argument("--outcrop-rule", default=None, metavar="RULE",
                    help="with --outcrops: the map's outcrop rule in place of the default's")
    ap.add_argument("--model", default=None,
                    help="with --outcrops: the rover model (default: committed), trained on "
                    "--outcrop-rule's candidates")
    ap.add_argument("--json", type=Path, help="write the rows here")
    args = ap.parse_args(argv)
    if (args.outcrop_rule or args.model) and not args.outcrops:
        ap.error("--outcrop-rule and --model go with --outcrops")
    if args.outcrops:
        rows = diagnose_outcrops(args.bag, args.outcrop_rule, args.model)
        sys.stdout.write(markdown_outcrops(args.bag, rows))
    else:
        rows = diagnose(args.bag)
        sys.stdout.write(markdown(args.bag, rows))
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
