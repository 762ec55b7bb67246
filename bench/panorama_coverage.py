"""Which counted rocks the rover's stereo camera sees, with and without panoramas at its
stops: a geometric study of the simulator's drive/stop schedule (no rendering).

For each preset and seed the world's truth catalogue, route and trajectory are rebuilt
(atacama_sim's own code: the same stops, frames and mast motion a bag gets) and every
stereo frame's left camera is posed through the mast (``MastKinematics.base_T_left`` at
the frame's joint angles). A counted rock (label 1, within ``roi_range_m`` of the route:
the planner's ``rois_passed``) is *seen* at range R when its centre (catalogue x, y and
z + height / 2) projects inside the 640 x 480 image of some frame with the camera at most
R metres from it (no occlusion: terrain and other rocks are not tested). Schedules:

- ``forward``: the fixed forward camera alone, today's stops (no panorama);
- ``S m``: a panorama at every stop between drive segments, stops every S m on average
  (``route.stop_every_m`` = (0.6 S, 1.4 S)), at the
  panorama shape given (tilt, overlap -> positions);
- ``ceiling``: what any schedule on the route could reach: the rock seen from the nearest
  camera position of the drive, in any direction (a panorama at every frame).

Rover time: the schedule's duration minus the forward schedule's on the same route.
Evaluation code: reads the truth catalogue. Usage (repository root, ``source env.sh``)::

    python bench/panorama_coverage.py                       # the study as committed
    python bench/panorama_coverage.py --quick-seeds 1 --km-seeds 1 --out /tmp/pano

Writes OUT/coverage.md and OUT/coverage.json (default
bench/results/studies/panorama_shape/).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
OUT = ROOT / "bench" / "results" / "studies" / "panorama_shape"
#: Stop spacings studied, m (the middle of ``route.stop_every_m``).
SPACINGS = (15.0, 20.0, 30.0, 45.0, 65.0)
#: Panorama shapes studied at the shape spacing: (tilt deg, overlap deg).
SHAPES = ((10.0, 10.0), (15.0, 10.0), (20.0, 10.0), (25.0, 10.0), (30.0, 10.0),
          (20.0, 20.0))
#: Ranges at which a rock counts as seen, m.
RANGES = (15.0, 20.0)
#: The spread of the stops around a spacing S: ``stop_every_m`` = (0.6 S, 1.4 S).
SPREAD = (0.6, 1.4)


def git_state() -> dict[str, Any]:
    """HEAD and whether the tree has uncommitted changes."""
    def git(*args: str) -> str:
        return subprocess.run(["git", *args], cwd=ROOT, capture_output=True, text=True,
                              check=False).stdout.strip()

    return {"commit": git("rev-parse", "HEAD") or "unknown",
            "dirty": bool(git("status", "--porcelain", "--", "ros2_ws/src/atacama_sim",
                              "bench/panorama_coverage.py"))}


class Site:
    """One preset and seed: terrain, counted rocks and route, built once."""

    def __init__(self, preset: str, seed: int) -> None:
        from atacama_sim.config import make_config
        from atacama_sim.rocks import generate_rocks
        from atacama_sim.route import plan_route
        from atacama_sim.terrain import Terrain

        self.preset, self.seed = preset, seed
        self.cfg = make_config(preset, seed)
        self.terrain = Terrain.generate(self.cfg.terrain, self.cfg.site.extent_m, seed)
        cat = generate_rocks(self.cfg.rocks, self.terrain, seed).catalogue
        self.route = plan_route(self.cfg.route, cat, self.terrain.extent, seed)
        passed = cat[self.route.rois_passed]
        rocks = passed[passed["label"] == 1]
        self.ids = rocks["id"].astype(int)
        self.points = np.column_stack([rocks["x"], rocks["y"],
                                       rocks["z"] + rocks["height_m"] / 2])

    def schedule(self, spacing: float | None, tilt: float = 20.0,
                 overlap: float = 10.0) -> dict[str, Any]:
        """Frames, coverage and time of one schedule (``spacing`` None: forward only)."""
        from atacama_sim.camera import StereoRig, mast_kinematics
        from atacama_sim.panorama import mast_motion, panorama_stop_s
        from atacama_sim.route import camera_indices, drive

        cfg = self.cfg
        route_cfg = cfg.route
        mast = dataclasses.replace(cfg.mast, panoramas=spacing is not None, tilt_deg=tilt,
                                   overlap_deg=overlap)
        if spacing is not None:
            route_cfg = dataclasses.replace(route_cfg, stop_every_m=(spacing * SPREAD[0],
                                                                     spacing * SPREAD[1]))
        else:
            route_cfg = dataclasses.replace(route_cfg, stop_every_m=(40.0, 90.0))
        rate = cfg.imu.rate_hz
        traj = drive(self.route, route_cfg, self.terrain, rate, self.seed,
                     panorama_stop_s(mast, cfg.camera, rate))
        motion = mast_motion(traj, mast, cfg.camera, rate)
        fwd = camera_indices(traj, route_cfg.frame_spacing_m, route_cfg.stop_frame_period_s,
                             rate, motion.busy)
        pano = motion.frames
        rig = StereoRig.from_config(cfg.camera)
        kin = mast_kinematics(cfg.camera)
        best = {"forward": self._nearest(traj, fwd, motion, kin, rig),
                "panorama": self._nearest(traj, pano, motion, kin, rig)}
        both = np.minimum(best["forward"], best["panorama"])
        out = {"stops": len(motion.panoramas) if spacing is not None else None,
               "panoramas": len(motion.panoramas),
               "positions": len(motion.panoramas[0].frames) if motion.panoramas else 0,
               "frames": int(len(fwd) + len(pano)), "panorama_frames": len(pano),
               "duration_s": round(float(traj.t[-1]), 1),
               "counted": len(self.ids)}
        for r in RANGES:
            out[f"seen_{r:g}m"] = int(np.sum(both <= r))
            out[f"seen_{r:g}m_forward_frames"] = int(np.sum(best["forward"] <= r))
        out["missed_15m"] = [int(i) for i in self.ids[both > 15.0]]
        if spacing is None:  # the ceiling: the nearest camera position of the drive
            near = np.full(len(self.ids), np.inf)
            rot = traj.rotations()[fwd].as_matrix()
            for j, k in enumerate(fwd):
                c_w = rig.camera_pose(rot[j], traj.p[k])[1]
                near = np.minimum(near, np.linalg.norm(self.points - c_w, axis=1))
            out["ceiling"] = {f"seen_{r:g}m": int(np.sum(near <= r)) for r in RANGES}
        return out

    def _nearest(self, traj, idx: np.ndarray, motion, kin, rig) -> np.ndarray:
        """Per counted rock, the smallest camera range over the frames ``idx`` that hold
        it in the image (inf: never in view)."""
        best = np.full(len(self.ids), np.inf)
        if len(idx) == 0 or len(self.ids) == 0:
            return best
        rot = traj.rotations()[idx].as_matrix()
        for j, k in enumerate(idx):
            b_t_l = kin.base_T_left(float(motion.pan[k]), float(motion.tilt[k]))
            r_wc, c_w = rig.camera_pose(rot[j], traj.p[k], base_T_left=b_t_l)
            uv, z = rig.project(r_wc, c_w, self.points)
            inside = (z > 0) & (uv[:, 0] >= 0) & (uv[:, 0] <= rig.width - 1) & \
                (uv[:, 1] >= 0) & (uv[:, 1] <= rig.height - 1)
            rng = np.linalg.norm(self.points - c_w, axis=1)
            best = np.where(inside, np.minimum(best, rng), best)
        return best


def study(quick_seeds: list[int], km_seeds: list[int], shape_spacing: float,
          log=print) -> dict[str, Any]:
    """Every schedule on every site; the per-site rows and their sums."""
    sites = [("quick", s) for s in quick_seeds] + [("atacama_1km", s) for s in km_seeds]
    rows = []
    for preset, seed in sites:
        t0 = time.perf_counter()
        site = Site(preset, seed)
        base = site.schedule(None)
        ceiling = base.pop("ceiling")
        rows.append({"preset": preset, "seed": seed, "schedule": "forward", "tilt_deg": None,
                     "overlap_deg": None, **base, "added_s": 0.0})
        rows.append({"preset": preset, "seed": seed, "schedule": "ceiling", "tilt_deg": None,
                     "overlap_deg": None, **base, **ceiling, "seen_15m_forward_frames": 0,
                     "panoramas": 0, "frames": 0, "panorama_frames": 0, "positions": 0,
                     "missed_15m": [], "added_s": 0.0})
        runs = [(s, 20.0, 10.0) for s in SPACINGS]
        runs += [(shape_spacing, t, o) for t, o in SHAPES if (t, o) != (20.0, 10.0)]
        for spacing, tilt, overlap in runs:
            r = site.schedule(spacing, tilt, overlap)
            rows.append({"preset": preset, "seed": seed, "schedule": f"{spacing:g} m",
                         "tilt_deg": tilt, "overlap_deg": overlap, **r,
                         "added_s": round(r["duration_s"] - base["duration_s"], 1)})
        log(f"{preset} seed {seed}: {len(site.ids)} counted rocks, "
            f"{time.perf_counter() - t0:.1f} s")
    return {"rows": rows}


def _key(row: dict) -> tuple:
    return row["schedule"], row["tilt_deg"], row["overlap_deg"]


def summary(rows: list[dict], preset: str | None = None) -> list[dict]:
    """Sums over sites per schedule (of one preset, or all)."""
    out: dict[tuple, dict] = {}
    for r in rows:
        if preset and r["preset"] != preset:
            continue
        s = out.setdefault(_key(r), {"schedule": r["schedule"], "tilt_deg": r["tilt_deg"],
                                     "overlap_deg": r["overlap_deg"],
                                     "positions": r["positions"], "sites": 0, "counted": 0,
                                     "seen_15m": 0, "seen_20m": 0, "frames": 0,
                                     "panorama_frames": 0, "panoramas": 0,
                                     "duration_s": 0.0, "added_s": 0.0})
        s["sites"] += 1
        for k in ("counted", "seen_15m", "seen_20m", "frames", "panorama_frames",
                  "panoramas", "duration_s", "added_s"):
            s[k] += r[k]
    return list(out.values())


def _pct(a: int, b: int) -> str:
    return f"{100 * a / b:.1f}" if b else "-"


def markdown(result: dict[str, Any]) -> str:
    prov = result["provenance"]
    rows = result["rows"]
    dirty = " (with uncommitted changes)" if prov["dirty"] else ""
    lines = ["# Panorama coverage: counted rocks in view, forward camera vs panoramas", "",
             f"Commit `{prov['commit'][:12]}`{dirty}; `{prov['command']}`; "
             f"{prov['machine']['cpus']} CPUs, Python {prov['machine']['python']}; "
             f"{prov['date']}; {prov['seconds']:.0f} s.", "",
             "Geometric, no rendering (bench/panorama_coverage.py): a counted rock (label 1, "
             "within 15 m of the route) is seen at range R when its centre projects inside "
             "some stereo frame's left image with the camera at most R m from it; no "
             "occlusion test. *forward*: the fixed forward camera, today's stops "
             "(40-90 m apart). *S m*: a 360 deg panorama at every stop between drive "
             "segments, stops 0.6 S to 1.4 S apart; tilt and overlap of the panorama "
             "row as given (positions = ceil(360 / (70 - overlap))). Added time: rover "
             "time over the forward schedule on the same routes (longer stops to hold the "
             "panorama, more stops). Frames: stereo pairs in the bag. *ceiling*: seen from "
             "the nearest camera position of the drive in any direction, the most any "
             "schedule could reach (a rock up to 15 m beside the route is seen within 15 m "
             "only from a stop nearly abeam of it).", ""]
    for preset in ("quick", "atacama_1km", None):
        summ = summary(rows, preset)
        if not summ:
            continue
        n_sites = summ[0]["sites"]
        lines += [f"## {preset or 'all sites'} ({n_sites} seeds, "
                  f"{summ[0]['counted']} counted rocks)", "",
                  "| schedule | tilt deg | overlap deg | positions | seen <= 15 m % | "
                  "seen <= 20 m % | panoramas | frames (panorama) | added time s "
                  "(% of the drive) |",
                  "|---|---|---|---|---|---|---|---|---|"]
        for s in summ:
            dur = s["duration_s"] - s["added_s"]
            lines.append(
                f"| {s['schedule']} | {s['tilt_deg'] if s['tilt_deg'] is not None else '-'} "
                f"| {s['overlap_deg'] if s['overlap_deg'] is not None else '-'} "
                f"| {s['positions'] or '-'} | {_pct(s['seen_15m'], s['counted'])} "
                f"| {_pct(s['seen_20m'], s['counted'])} | {s['panoramas']} "
                f"| {s['frames']} ({s['panorama_frames']}) "
                f"| {s['added_s']:.0f} ({_pct(s['added_s'], dur)}) |")
        lines.append("")
    lines += ["## Per site", "",
              "| preset | seed | schedule | tilt | overlap | counted | seen <= 15 m | "
              "seen <= 20 m | forward frames alone <= 15 m | panoramas | frames | "
              "added s | missed within 15 m (ids) |",
              "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['preset']} | {r['seed']} | {r['schedule']} | "
                     f"{r['tilt_deg'] if r['tilt_deg'] is not None else '-'} | "
                     f"{r['overlap_deg'] if r['overlap_deg'] is not None else '-'} | "
                     f"{r['counted']} | {r['seen_15m']} | {r['seen_20m']} | "
                     f"{r['seen_15m_forward_frames']} | {r['panoramas']} | {r['frames']} | "
                     f"{r['added_s']:.0f} | {', '.join(map(str, r['missed_15m'])) or '-'} |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--quick-seeds", type=int, nargs="*", default=[1, 2, 3, 4, 5])
    parser.add_argument("--km-seeds", type=int, nargs="*", default=[1, 2, 3])
    parser.add_argument("--shape-spacing", type=float, default=30.0,
                        help="stop spacing at which the panorama shapes are compared, m")
    parser.add_argument("--out", type=Path, default=OUT)
    args = parser.parse_args(argv)
    t0 = time.perf_counter()
    started = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    result = study(args.quick_seeds, args.km_seeds, args.shape_spacing,
                   log=lambda m: print(m, file=sys.stderr))
    result["provenance"] = {
        **git_state(), "command": " ".join(["python bench/panorama_coverage.py",
                                            *(argv if argv is not None else sys.argv[1:])]),
        "machine": {"cpus": os.cpu_count(), "python": platform.python_version()},
        "date": started, "seconds": time.perf_counter() - t0}
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "coverage.json").write_text(json.dumps(result, indent=1) + "\n")
    (args.out / "coverage.md").write_text(markdown(result))
    print(markdown(result))
    return 0


if __name__ == "__main__":
    sys.exit(main())
