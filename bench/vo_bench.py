"""rover_vo benchmark: accuracy (evo), speed and memory of the two modes and of a
third-party odometry (KISS-ICP on the stereo point clouds) on the same bags, in one run.

For each bag: ``rover_vo odometry BAG --mode M --threads 1`` in its own process (with
OMP_NUM_THREADS=1) for M in paper, vo, and ``paper_no_sun`` (mode paper with the sun
heading off, ``imu.sun_heading: false``; only on a bag whose rover.yaml has a sun sensor); then
KISS-ICP 1.3.0 on the point clouds of OpenCV SGBM disparities of the same stereo pairs
(base_link); then every trajectory through ``rover_vo.evaluation.evaluate`` (evo:
KITTI-style drift over 100..800 m, heading drift per 100 m, heading error from the start,
aligned APE, final error), and for rover_vo the covariance
against the actual error (is it honest?).

Each method's run on each bag is cached in WORK/vo_runs/<bag>/<method>/ (rerun with
--force); the summary of every cached run of the given bags goes to
RESULTS/vo_bench.{json,md} (``--tag T``: vo_bench_T.*).

Usage (repository root, after ``source env.sh``)::

    python bench/vo_bench.py --bags /work/bags/quick /work/bags/atacama_1km_s1 ...
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

from roi_network.files import write_atomic
from roi_network.trajectory import read_pose_covariance_rows, read_tum_rows
from rover_vo.evaluation import evaluate, grid_heading_error_deg, plot_trajectories

#: Where result files go: $BENCH_RESULTS (`make bench`: bench/results/current/), else
#: out/bench/results/.
RESULTS = Path(os.environ.get("BENCH_RESULTS")
               or Path(__file__).resolve().parents[1] / "out" / "bench" / "results")
#: Scratch space of the runs (caches, LNs, plots): $BENCH_WORK, else out/bench/work/.
WORK = Path(os.environ.get("BENCH_WORK")
            or Path(__file__).resolve().parents[1] / "out" / "bench" / "work")
MODES = ("paper", "vo", "paper_no_sun")
#: Methods that are a mode with parameters: (mode, rover_vo parameters).
PARAMETRIZED = {"paper_no_sun": ("paper", {"imu.sun_heading": False})}
ONE_CORE = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"}


def has_sun_sensor(bag: Path) -> bool:
    """Whether the bag's rover.yaml states a sun sensor."""
    from rover_vo.bag import rover_params

    return any(k.startswith("sun_sensor.") for k in rover_params(bag))


def run_mode(bag: Path, method: str, out: Path) -> dict:
    """``rover_vo odometry`` in its own process on one core; returns its report."""
    env = dict(os.environ) | ONE_CORE
    mode, params = PARAMETRIZED.get(method, (method, {}))
    cmd = ["rover_vo", "odometry", str(bag), "--out", str(out), "--mode", mode,
           "--threads", "1"]
    if params:
        import yaml

        out.mkdir(parents=True, exist_ok=True)
        write_atomic(out / "params.yaml", yaml.safe_dump(
            {"rover_vo": {"ros__parameters": params}}))
        cmd += ["--params", str(out / "params.yaml")]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    report = json.loads((out / "vo_report.json").read_text())
    report["process_wall_s"] = round(time.perf_counter() - t0, 2)
    report["warnings"] = [line for line in proc.stderr.splitlines() if line.strip()][:20]
    return report


def kiss_icp_odometry(bag: Path, out: Path, max_range_m: float = 30.0) -> dict:
    """KISS-ICP (PRBonn, 1.3.0) on the stereo point clouds of the bag; writes out/vo.tum.

    Each pair gives an SGBM disparity at half resolution (320x240, 48 disparities), its
    points within ``max_range_m`` in base_link (extrinsics from rover.yaml), registered by
    ``KissICP.register_frame`` with deskewing off (a stereo pair is a snapshot).
    """
    import cv2
    from kiss_icp.config import KISSConfig
    from kiss_icp.kiss_icp import KissICP
    from rgbd_baseline import stereo_pairs

    from rover_vo.state import OdomState
    from rover_vo.tum import write_tum

    cv2.setNumThreads(1)
    cfg = KISSConfig()
    cfg.data.deskew = False
    cfg.data.max_range = max_range_m
    cfg.data.min_range = 1.0
    cfg.registration.max_num_threads = 1
    cfg.mapping.voxel_size = max_range_m / 100.0  # what kiss_icp.config.load_config sets
    odometry = KissICP(cfg)
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=48, blockSize=5,
                                 P1=8 * 25, P2=32 * 25, uniquenessRatio=10,
                                 speckleWindowSize=50, speckleRange=2)
    states = []
    cpu = 0.0
    for t_ns, left, right, rig in stereo_pairs(bag):
        c0 = time.process_time()
        small_l, small_r = cv2.pyrDown(left), cv2.pyrDown(right)
        disp = sgbm.compute(small_l, small_r).astype(np.float32) / 16.0
        v, u = np.nonzero(disp > 1.0)
        d = disp[v, u] * 2.0  # full-resolution disparity
        u, v = u * 2.0 + 0.5, v * 2.0 + 0.5
        z = rig.fx * rig.baseline_m / d
        pts_c = np.column_stack([(u - rig.cx) * z / rig.fx, (v - rig.cy) * z / rig.fy, z])
        pts_b = pts_c @ rig.base_T_left[:3, :3].T + rig.base_T_left[:3, 3]
        odometry.register_frame(pts_b.astype(np.float64), np.zeros(len(pts_b)))
        cpu += time.process_time() - c0
        T = odometry.last_pose
        states.append(OdomState(t_ns * 1e-9, T[:3, :3].copy(), T[:3, 3].copy()))
    out.mkdir(parents=True, exist_ok=True)
    write_tum(out / "vo.tum", states, header=f"KISS-ICP 1.3.0 on SGBM stereo clouds of {bag}")
    report = {"pairs": len(states), "cpu_s": round(cpu, 2),
              "pairs_per_cpu_s": round(len(states) / max(cpu, 1e-9), 3)}
    write_atomic(out / "vo_report.json", json.dumps(report, indent=2) + "\n")
    return report


def rgbd_odometry(bag: Path, out: Path) -> dict:
    """OpenCV contrib's dense RGB-D odometry on SGBM depth (bench/rgbd_baseline.py), in its
    own process with the contrib ``cv2`` first on the path; writes out/vo.tum."""
    import rgbd_baseline

    site = rgbd_baseline.ensure_contrib()
    env = dict(os.environ) | ONE_CORE
    env["PYTHONPATH"] = os.pathsep.join([str(site), env.get("PYTHONPATH", "")])
    cmd = [sys.executable, str(Path(rgbd_baseline.__file__)), str(bag), str(out)]
    proc = subprocess.run(cmd, env=env, capture_output=True, text=True, check=False)
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed:\n{proc.stderr[-2000:]}")
    return json.loads((out / "vo_report.json").read_text())


def covariance_honesty(run: Path, truth: Path) -> dict:
    """Horizontal error (first pose aligned) against the published covariance.

    Returns the mean normalised squared error over 2 DOF (2 if honest), the share of poses
    inside their 95 % ellipse (0.95 if honest), and the final 1-sigma vs final error.
    """
    from scipy.spatial.transform import Rotation

    est = read_tum_rows(run / "vo.tum")
    _, cov = read_pose_covariance_rows(run / "vo_covariance.txt")
    ref = read_tum_rows(truth)
    idx = np.clip(np.searchsorted(ref[:, 0], est[:, 0] - 1e-4), 0, len(ref) - 1)
    ref = ref[idx]
    keep = np.abs(ref[:, 0] - est[:, 0]) < 0.02
    est, ref, cov = est[keep], ref[keep], cov[keep]
    R0e = Rotation.from_quat(est[0, 4:]).as_matrix()
    R0r = Rotation.from_quat(ref[0, 4:]).as_matrix()
    A = R0r @ R0e.T  # odom -> map rotation with the first poses aligned
    p = (est[:, 1:4] - est[0, 1:4]) @ A.T + ref[0, 1:4]
    err = (p - ref[:, 1:4])[:, :2]
    C = cov[:, :3, :3]
    C = (A @ C @ A.T)[:, :2, :2]
    ok = np.linalg.det(C) > 1e-12
    nees = np.einsum("ni,nij,nj->n", err[ok], np.linalg.inv(C[ok]), err[ok])
    return {"mean_nees_2dof": round(float(np.mean(nees)), 3),
            "share_in_95pct_ellipse": round(float(np.mean(nees < 5.991)), 3),
            "final_sigma_xy_m": round(float(np.sqrt(np.trace(C[-1]))), 3),
            "final_error_xy_m": round(float(np.linalg.norm(err[-1])), 3)}


def bench_method(bag: Path, method: str, force: bool) -> dict:
    """One method on one bag, cached in WORK/vo_runs/<bag>/<method>/row.json."""
    out = WORK / "vo_runs" / bag.name / method
    truth = bag / "truth" / "trajectory.tum"
    row_path = out / "row.json"
    if row_path.is_file() and not force:
        return json.loads(row_path.read_text())
    if method == "paper_no_sun" and not has_sun_sensor(bag):
        return {}
    print(f"[vo_bench] {bag.name}: {method}", file=sys.stderr)
    # A finished run whose summary was not written (an interrupted bench) is reused.
    done = (out / "vo.tum").is_file() and (out / "vo_report.json").is_file() and not force
    if method in THIRD_PARTY:
        report = (json.loads((out / "vo_report.json").read_text()) if done
                  else THIRD_PARTY[method](bag, out))
        row = {"metrics": evaluate(out / "vo.tum", truth).as_dict(), "report": report}
    else:
        report = (json.loads((out / "vo_report.json").read_text()) if done
                  else run_mode(bag, method, out))
        report.setdefault("process_wall_s", None)
        row = {"metrics": evaluate(out / "vo.tum", truth).as_dict(),
               "honesty": covariance_honesty(out, truth),
               "report": {k: report[k] for k in (
                   "pairs", "distance_m", "cpu_s", "pairs_per_cpu_s",
                   "estimator_pairs_per_cpu_s", "peak_rss_mb", "rss_mb_first_last",
                   "sources", "process_wall_s")},
               "bad_input": {k: v for k, v in report["status"].items()
                             if k.startswith("bad_input.") and v}}
        sun = sun_figures(report["status"], out / "vo.tum", truth)
        if sun:
            row["sun"] = sun
    plot_trajectories(out / "vo.tum", truth, out / "trajectory.png",
                      title=f"{method} on {bag.name}")
    write_atomic(row_path, json.dumps(row, indent=2) + "\n")
    return row


def sun_figures(status: dict, est: Path, truth: Path) -> dict:
    """A sun-heading run's updates and its absolute heading at the end against the truth:
    the error, the filter's sigma, and whether the error is within 3 sigma. Empty for a
    run whose sun heading never set the odom frame's grid yaw."""
    grid_yaw = status.get("sun.odom_grid_yaw_deg")
    if grid_yaw is None or not np.isfinite(float(grid_yaw)):
        return {}
    err = grid_heading_error_deg(est, truth, float(grid_yaw))
    sigma = status.get("sun.heading_sigma_deg")
    return {"updates": status.get("sun.updates"), "rejected": status.get("sun.rejected"),
            "in_motion": status.get("sun.in_motion"),
            "grid_heading_error_deg_final": round(err, 4), "heading_sigma_deg": sigma,
            "within_3sigma": None if not sigma else bool(abs(err) <= 3.0 * float(sigma))}


def collect(bag: Path) -> dict:
    """Every cached method row of a bag."""
    rows = {}
    for method in (*MODES, *THIRD_PARTY):
        row_path = WORK / "vo_runs" / bag.name / method / "row.json"
        if row_path.is_file():
            rows[method] = json.loads(row_path.read_text())
    return {"bag": str(bag), "rows": rows}


def markdown(summaries: list[dict], meta: dict) -> str:
    lines = [
        "# rover_vo benchmark",
        "",
        f"Made by `{meta['command']}` on {meta['date']} ({meta['machine']}).",
        f"**Speed was measured while the machine was shared** (load average "
        f"{meta['loadavg']}): one process per run, OpenCV and OpenMP limited to one thread.",
        "",
        "| bag | method | distance m | drift % (KITTI 100-800 m) | heading deg/100 m | "
        "heading error from start, max / final deg | "
        "rot deg/100 m | APE RMSE m | final error % | pairs/CPU s (estimator) | peak RSS MB |"
        " NEES xy (2 = honest) | in 95 % ellipse |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for s in summaries:
        name = Path(s["bag"]).name
        for method, row in s["rows"].items():
            m, r = row["metrics"], row["report"]
            h = row.get("honesty", {})
            speed = f"{r['pairs_per_cpu_s']:.1f}"
            if "estimator_pairs_per_cpu_s" in r:
                speed += f" ({r['estimator_pairs_per_cpu_s']:.1f})"
            lines.append(
                f"| {name} | {method} | {m['distance_m']:.0f} | {m['kitti_drift_pct']:.3f} | "
                f"{m['heading_drift_deg_per_100m']:.3f} | "
                f"{m.get('heading_error_deg_max', float('nan')):.2f} / "
                f"{m.get('heading_error_deg_final', float('nan')):.2f} | "
                f"{m['kitti_rot_deg_per_100m']:.3f} | "
                f"{m['ape_rmse_m']:.2f} | {m['final_error_pct']:.3f} | {speed} | "
                f"{r.get('peak_rss_mb', '')} | {h.get('mean_nees_2dof', '')} | "
                f"{h.get('share_in_95pct_ellipse', '')} |")
    lines += sun_table(summaries)
    lines += spread(summaries)
    lines += ["", "Methods: `paper` = frame to frame + IMU (the paper's mode, the default); `vo` ="
              " frame to frame, vision alone; `paper_no_sun` = `paper` with the sun heading off"
              " (`imu.sun_heading: false`, bags with a sun sensor); `kiss_icp` = KISS-ICP"
              " 1.3.0"
              " on SGBM stereo point clouds of the same pairs; `opencv_rgbd` = OpenCV 4.14 contrib"
              " `rgbd.RgbdOdometry` (dense photometric, Steinbruecker et al. 2011) on the left"
              " image and SGBM depth, half resolution. pairs/CPU s counts reading the"
              " bag (rosbags deserialisation of 50 Hz IMU); in brackets the estimator alone.",
              ""]
    return "\n".join(lines)


def sun_table(summaries: list[dict]) -> list[str]:
    """The sun heading's runs: updates and the absolute (grid) heading at the end."""
    rows = [(Path(s["bag"]).name, method, row["sun"]) for s in summaries
            for method, row in s["rows"].items() if row.get("sun")]
    if not rows:
        return []
    lines = ["", "Sun heading at the end of the route (absolute heading: the odometry's yaw plus "
             "the odom frame's grid yaw the sun set, against the truth):", "",
             "| bag | method | updates (at stops) | rejected | samples in motion (not used) | "
             "grid heading error deg | sigma deg | within 3 sigma |",
             "|---|---|---|---|---|---|---|---|"]
    for name, method, sun in rows:
        within = {True: "yes", False: "no", None: ""}[sun.get("within_3sigma")]
        lines.append(f"| {name} | {method} | {sun.get('updates')} | {sun.get('rejected')} | "
                     f"{sun.get('in_motion')} | {sun['grid_heading_error_deg_final']:+.2f} | "
                     f"{sun.get('heading_sigma_deg')} | {within} |")
    return lines


def spread(summaries: list[dict]) -> list[str]:
    """Per method, min / median / max over the bags of a preset (``<preset>_s<seed>``)."""
    groups: dict[tuple[str, str], list[dict]] = {}
    for s in summaries:
        name = Path(s["bag"]).name
        preset = name.rsplit("_s", 1)[0] if "_s" in name else name
        for method, row in s["rows"].items():
            groups.setdefault((preset, method), []).append(row)
    lines = ["", "Spread over seeds (min / median / max):", "",
             "| preset | method | seeds | drift % | heading deg/100 m | "
             "heading error from start, max deg | final error % | NEES xy |",
             "|---|---|---|---|---|---|---|---|"]
    for (preset, method), rows in groups.items():
        if len(rows) < 2:
            continue

        def mmm(values: list[float]) -> str:
            v = np.asarray([x for x in values if x is not None], dtype=float)
            if len(v) == 0:
                return ""
            return f"{v.min():.3f} / {np.median(v):.3f} / {v.max():.3f}"

        lines.append(
            f"| {preset} | {method} | {len(rows)} | "
            f"{mmm([r['metrics']['kitti_drift_pct'] for r in rows])} | "
            f"{mmm([r['metrics']['heading_drift_deg_per_100m'] for r in rows])} | "
            f"{mmm([r['metrics'].get('heading_error_deg_max') for r in rows])} | "
            f"{mmm([r['metrics']['final_error_pct'] for r in rows])} | "
            f"{mmm([r.get('honesty', {}).get('mean_nees_2dof') for r in rows])} |")
    return lines


THIRD_PARTY = {"kiss_icp": kiss_icp_odometry, "opencv_rgbd": rgbd_odometry}


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--bags", nargs="+", required=True, type=Path)
    p.add_argument("--methods", nargs="+", default=[*MODES, *THIRD_PARTY],
                   choices=[*MODES, *THIRD_PARTY], help="methods to run (cached ones are reused)")
    p.add_argument("--force", action="store_true", help="recompute cached runs")
    p.add_argument("--summary-only", action="store_true", help="only rebuild the summary")
    p.add_argument("--tag", help="results name: RESULTS/vo_bench_<tag>.* (default vo_bench.*)")
    args = p.parse_args()
    name = f"vo_bench_{args.tag}" if args.tag else "vo_bench"
    if not args.summary_only:
        for bag in args.bags:
            for method in args.methods:
                bench_method(bag, method, args.force)
    summaries = [collect(b) for b in args.bags]
    meta = {"command": "python bench/vo_bench.py " + " ".join(sys.argv[1:]),
            "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime()),
            "machine": f"{platform.machine()}, {os.cpu_count()} cores",
            "loadavg": " ".join(f"{x:.1f}" for x in os.getloadavg())}
    RESULTS.mkdir(parents=True, exist_ok=True)
    write_atomic(RESULTS / f"{name}.json", json.dumps({"meta": meta, "bags": summaries},
                                                       indent=2) + "\n")
    write_atomic(RESULTS / f"{name}.md", markdown(summaries, meta))
    print((RESULTS / f"{name}.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
