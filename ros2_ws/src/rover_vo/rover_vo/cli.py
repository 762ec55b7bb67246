"""``rover_vo``: offline visual odometry on a bag directory and its evaluation.

    rover_vo odometry BAG_DIR --out DIR [--params FILE] [--mode paper|vo]
        -> DIR/vo.tum (TUM: t x y z qx qy qz qw, base_link in odom), DIR/vo_report.json,
           DIR/vo_covariance.txt (each pose's 6x6 covariance)
    rover_vo eval DIR/vo.tum BAG_DIR/truth/trajectory.tum [--json OUT] [--plot OUT.png]

``odometry`` runs the same estimator as the node on the same messages
(:mod:`rover_vo.offline`). It never reads ``truth/``.
"""

from __future__ import annotations

import argparse
import json
import logging
import sys
from pathlib import Path

from roi_network.files import write_atomic
from rover_vo.bag import BagError
from rover_vo.config import MODES, config_from_flat, config_from_params_file
from rover_vo.offline import TUM_FILE, odometry


def cmd_odometry(args: argparse.Namespace) -> int:
    if args.threads:
        import cv2

        cv2.setNumThreads(args.threads)
    config = config_from_params_file(args.params) if args.params else config_from_flat({})
    if args.mode:
        config = config_from_flat({"mode": args.mode}, config)
    report = odometry(args.bag_dir, config, args.out, progress=args.progress)
    print(f"{Path(args.out) / TUM_FILE}: {report['pairs']} poses over "
          f"{report['distance_m']:.1f} m, {report['pairs_per_cpu_s']:.1f} pairs per CPU second")
    if report["mast"]:
        st = report["status"]
        print(f"mast: {st['mast_moved_frames']} pairs off the reference's camera pose (not "
              f"measured), {st['mast_reanchors']} new references at a new pose, "
              f"{st['frames_without_joint_states']} pairs without a joint state")
    return 0


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
    if d["stops"]:
        print(f"{d['stops']} stops: position change {d['stop_position_mm_mean']:.1f} mm mean, "
              f"{d['stop_position_mm_max']:.1f} mm max; yaw change "
              f"{d['stop_yaw_deg_max']:.3f} deg max; excursion "
              f"{d['stop_excursion_mm_max']:.1f} mm max; motion into and through a stop "
              f"off the truth's by {d['stop_error_mm_mean']:.1f} mm mean, "
              f"{d['stop_error_mm_max']:.1f} mm max, yaw {d['stop_yaw_error_deg_max']:.3f} "
              "deg max")
    return 0


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="rover_vo", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="command", required=True)
    o = sub.add_parser("odometry", help="offline VO on a bag directory -> vo.tum, report")
    o.add_argument("bag_dir", help="bag directory (with rosbag/ and rover.yaml)")
    o.add_argument("--out", required=True, help="output directory")
    o.add_argument("--params", help="ROS params YAML (rover_vo: ros__parameters: ...)")
    o.add_argument("--mode", choices=MODES, help="overrides the params (default: paper)")
    o.add_argument("--progress", action="store_true",
                   help="print a line to stderr every 100 poses or 10 s of bag time, "
                        "whichever comes first, and a final one")
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
