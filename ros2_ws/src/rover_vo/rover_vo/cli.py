"""``rover_vo``: offline visual odometry on a bag directory and its evaluation.

    rover_vo odometry BAG_DIR --out DIR [--params FILE] [--mode paper|vo|keyframes]
        -> DIR/vo.tum (TUM: t x y z qx qy qz qw, base_link in odom), DIR/vo_report.json,
           DIR/vo_covariance.txt (each pose's 6x6 covariance)
    rover_vo eval DIR/vo.tum BAG_DIR/truth/trajectory.tum [--json OUT] [--plot OUT.png]

``odometry`` runs the same estimator as the node on the same messages (read with rosbags,
in bag order). It never reads ``truth/``.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import time
from pathlib import Path

import numpy as np

from roi_network.files import write_atomic
from roi_network.trajectory import POSE_COVARIANCE_FILE, write_pose_covariance
from rover_vo.bag import BagError, read_messages, rover_params
from rover_vo.config import (
    MODES,
    VoConfig,
    config_from_flat,
    flat_parameters,
    read_ros_params,
)
from rover_vo.estimator import VoEstimator
from rover_vo.tum import write_tum


def peak_rss_mb() -> float:
    """Peak resident set size of this process (MB): ``VmHWM`` of ``/proc/self/status``.

    Not ``getrusage``'s ``ru_maxrss``: Linux carries that across ``fork`` and ``execve``,
    so a process started by a big parent (the bench) reports the parent's peak.
    ``ru_maxrss`` is the fallback where ``/proc`` is missing.
    """
    try:
        with open("/proc/self/status", encoding="ascii") as f:
            for line in f:
                if line.startswith("VmHWM:"):
                    return int(line.split()[1]) / 1024.0
    except OSError:
        pass
    import resource

    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0


def run_odometry(bag_dir: str | Path, config: VoConfig, progress: bool = False) -> dict:
    """Run the estimator over a bag; returns the outputs and figures for the report.

    Returns:
        ``{"outputs": [VoOutput], "status": {...}, "seconds": float, "cpu_seconds": float,
        "rss_mb": [(pair index, MB)], "params": {...}}``.
    """
    import psutil

    params = rover_params(bag_dir)
    est = VoEstimator(config, params)
    outputs = []
    proc = psutil.Process()
    rss = []
    t0, c0 = time.perf_counter(), time.process_time()
    feed_cpu = 0.0
    for topic, msg in read_messages(bag_dir):
        c = time.process_time()
        new = est.feed(topic, msg)
        feed_cpu += time.process_time() - c
        outputs += new
        if new and len(outputs) % 100 == 0:
            rss.append((len(outputs), proc.memory_info().rss / 2**20))
            if progress:
                print(f"  {len(outputs)} pairs, {est.state.distance_m:.0f} m", file=sys.stderr)
    outputs += est.finish()
    return {"outputs": outputs, "status": est.status(), "seconds": time.perf_counter() - t0,
            "cpu_seconds": time.process_time() - c0, "estimator_cpu_seconds": feed_cpu,
            "rss_mb": rss,
            "config": flat_parameters(est.cfg)}


def cmd_odometry(args: argparse.Namespace) -> int:
    bag = Path(args.bag_dir)
    if args.threads:
        import cv2

        cv2.setNumThreads(args.threads)
    values = read_ros_params(args.params) if args.params else {}
    if args.mode:
        values["mode"] = args.mode
    config = config_from_flat(values)
    result = run_odometry(bag, config, progress=args.progress)
    outputs = result["outputs"]
    if not outputs:
        raise BagError(f"{bag}: no stereo pair gave a pose (see the warnings above)")
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    write_tum(out / "vo.tum", [o.state for o in outputs],
              header=f"rover_vo {config.mode}: base_link in odom, from {bag}")
    write_pose_covariance(out / POSE_COVARIANCE_FILE, [o.state.t for o in outputs],
                          [o.state.cov for o in outputs], note=f"rover_vo {config.mode}")
    sources: dict[str, int] = {}
    for o in outputs:
        sources[o.source] = sources.get(o.source, 0) + 1
    final = outputs[-1].state
    rss = [r for _, r in result["rss_mb"]]
    report = {
        "bag": str(bag), "mode": config.mode, "pairs": len(outputs),
        "distance_m": round(final.distance_m, 3),
        "wall_s": round(result["seconds"], 3), "cpu_s": round(result["cpu_seconds"], 3),
        "pairs_per_cpu_s": round(len(outputs) / max(result["cpu_seconds"], 1e-9), 3),
        "estimator_cpu_s": round(result["estimator_cpu_seconds"], 3),
        "estimator_pairs_per_cpu_s": round(
            len(outputs) / max(result["estimator_cpu_seconds"], 1e-9), 3),
        "peak_rss_mb": round(peak_rss_mb(), 1),
        "rss_mb_first_last": [round(rss[0], 1), round(rss[-1], 1)] if rss else None,
        "sources": sources, "status": result["status"],
        "final_position_sigma_m": round(float(np.sqrt(np.trace(final.cov[:2, :2]))), 4),
        "final_yaw_sigma_deg": round(float(np.degrees(np.sqrt(final.cov[5, 5]))), 4),
        "threads": {"OMP_NUM_THREADS": os.environ.get("OMP_NUM_THREADS"),
                    "opencv": _cv_threads()},
        "config": result["config"],
    }
    write_atomic(out / "vo_report.json", json.dumps(report, indent=2) + "\n")
    print(f"{out / 'vo.tum'}: {len(outputs)} poses over {final.distance_m:.1f} m, "
          f"{report['pairs_per_cpu_s']:.1f} pairs per CPU second")
    return 0


def _cv_threads() -> int:
    import cv2

    return int(cv2.getNumThreads())


def cmd_eval(args: argparse.Namespace) -> int:
    from rover_vo.evaluation import evaluate, plot_trajectories

    metrics = evaluate(args.estimate, args.truth)
    d = metrics.as_dict()
    if args.json:
        write_atomic(args.json, json.dumps(d, indent=2) + "\n")
    if args.plot:
        plot_trajectories(args.estimate, args.truth, args.plot)
    print(f"distance {d['distance_m']:.1f} m: drift {d['kitti_drift_pct']:.3f} % (KITTI, "
          f"{d['segments']} segments), heading {d['heading_drift_deg_per_100m']:.3f} deg/100 m, "
          f"APE {d['ape_rmse_m']:.3f} m RMSE, final {d['final_error_m']:.2f} m "
          f"({d['final_error_pct']:.3f} %)")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="rover_vo", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    o = sub.add_parser("odometry", help="offline VO on a bag directory -> vo.tum, report")
    o.add_argument("bag_dir", help="bag directory (with rosbag/ and rover.yaml)")
    o.add_argument("--out", required=True, help="output directory")
    o.add_argument("--params", help="ROS params YAML (rover_vo: ros__parameters: ...)")
    o.add_argument("--mode", choices=MODES, help="overrides the params (default: paper)")
    o.add_argument("--progress", action="store_true", help="print progress to stderr")
    o.add_argument("--threads", type=int, default=0,
                   help="OpenCV threads (0: OpenCV's default); set OMP_NUM_THREADS too")
    o.set_defaults(func=cmd_odometry)
    e = sub.add_parser("eval", help="evaluate a TUM estimate against the truth (evo)")
    e.add_argument("estimate", help="vo.tum")
    e.add_argument("truth", help="BAG_DIR/truth/trajectory.tum")
    e.add_argument("--json", help="write the metrics here")
    e.add_argument("--plot", help="write a top-view PNG here")
    e.set_defaults(func=cmd_eval)
    return p


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="rover_vo: %(message)s")
    from rover_vo.evaluation import EvalError

    try:
        return args.func(args)
    except (BagError, EvalError, ValueError, OSError) as exc:
        print(f"rover_vo: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
