"""``roi_detector``: the rover ROI pipeline offline (same library code as the nodes).

    roi_detector train BAG_DIR... --out models/rover.npz [--method per_pair]
    roi_detector ln BAG_DIR --odometry DIR/vo.tum --out DIR/ln.geojson [--covariance FILE]
    roi_detector eval DIR/ln.geojson BAG_DIR [--json OUT] [--plot OUT.png]
    roi_detector truth-odometry BAG_DIR --out DIR/truth_odom.tum   (evaluation helper)
    roi_detector [--ros-args ...]                                   (the roi_detector node)

``train``, ``eval`` and ``truth-odometry`` read the bag's truth files (training and
evaluation only); ``ln`` reads the stereo images, rover.yaml, the odometry file and the
model, never the truth. Each LN node's covariance comes from the odometry's covariance at
its observations, as in the nodes: ``ln`` reads it from ``vo_covariance.txt`` beside the
odometry file (what ``rover_vo odometry`` and ``globloc run`` write), or ``--covariance``;
a TUM file alone carries none, and ``--drift`` then models it.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from roi_detector.inputs import POSE_COVARIANCE_FILE, PairSpacing
from roi_detector.local_network_build import (
    DEFAULT_DRIFT_FRAC,
    build_ln,
    odometry_covariance_file,
)
from roi_detector.rover_pipeline import METHODS, RoverConfig, installed_model
from roi_network import images


def _cmd_ln(args) -> int:
    from roi_detector.local_network import LnConfig
    from roi_detector.tracking import TrackerConfig

    cfg = RoverConfig(method=args.method, tracker=TrackerConfig(min_obs=args.min_obs),
                      ln=LnConfig(min_obs=args.min_obs), working_fx_px=args.working_fx)
    cov_file = odometry_covariance_file(args.odometry, args.covariance)
    ln, stats = build_ln(args.bag, args.odometry, args.model, cfg, args.every, args.drift,
                         odometry_cov=cov_file, rectify=not args.no_rectify,
                         sync_tolerance_s=args.stereo_sync_tolerance,
                         spacing=PairSpacing(min_travel_m=args.min_pair_travel))
    if not stats["pairs"]:
        skipped = ", ".join(f"{k} {v}" for k, v in sorted(stats["bad_input"].items()))
        raise ValueError(f"{args.bag}: no stereo pair read ({skipped or 'no stereo images'}): "
                         f"{args.out} not written")
    meta = {"source_bag": str(Path(args.bag).resolve()), "odometry": str(args.odometry),
            "odometry_covariance": str(cov_file) if cov_file is not None
            else f"{args.drift:g} of the distance travelled, 1 sigma (--drift)",
            "model": args.model or str(installed_model()), **stats}
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    ln.save(args.out, meta)
    spaced = (f" ({stats['pairs_spaced_out']} more not read: under --min-pair-travel "
              f"{args.min_pair_travel:g} m from the last)" if stats["pairs_spaced_out"] else "")
    if stats.get("pairs_not_placed"):
        spaced += (f" ({stats['pairs_not_placed']} not placed: no /joint_states within "
                   "the tolerance of their stamps)")
    if stats["not_a_rock"]:
        spaced += " (rock regions not a rock: " + ", ".join(
            f"{k} {v}" for k, v in sorted(stats["not_a_rock"].items())) + ")"
    print(f"roi_detector ln: {stats['pairs']} stereo pairs{spaced}, "
          f"{stats['detections']} detections, "
          f"{stats['tracks']} tracks -> {len(ln)} LN nodes in {args.out} "
          f"({stats['detect_s_per_pair']:.3f} s/pair detection); node covariance from "
          f"{meta['odometry_covariance']}")
    return 0


def _cmd_eval(args) -> int:
    from roi_detector.evaluation import evaluate_ln

    report = evaluate_ln(args.ln, args.bag, plot=args.plot)
    text = json.dumps(report, indent=2)
    if args.json:
        Path(args.json).write_text(text + "\n")
    print(text)
    return 0


def _cmd_train(args) -> int:
    from roi_detector.training import train_rock_rovers, train_rover_model

    if args.method == "per_pair":
        summary = train_rover_model(args.bags, args.out, every=args.every, k=args.k)
    else:
        summary = train_rock_rovers(args.bags, args.out, k=args.k, jobs=args.jobs,
                                    working_fx_px=args.working_fx, cache=args.cache)
    print(json.dumps(summary, indent=2))
    return 0


def _cmd_truth_odometry(args) -> int:
    from roi_detector.truth import Truth

    Truth.load(args.bag).write_odom_tum(args.out)
    print(f"wrote {args.out}")
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``roi_detector`` command; bad input exits 1 with one line.

    With no sub-command (or ROS arguments first, as ``globloc run`` starts it) it runs the
    roi_detector node.
    """
    argv = sys.argv[1:] if argv is None else argv
    if not argv or argv[0] in ("--ros-args", "--"):
        from roi_detector.detector_node import main as node_main

        return node_main(["roi_detector", *argv])
    ap = argparse.ArgumentParser(prog="roi_detector", description=__doc__.split("\n")[0])
    sub = ap.add_subparsers(dest="cmd", required=True)
    p = sub.add_parser("ln", help="the LN a drive builds (odom)")
    p.add_argument("bag")
    p.add_argument("--odometry", required=True, help="TUM file, base_link in odom")
    p.add_argument("--out", required=True)
    p.add_argument("--model", default=None, help="rover model .npz ('none': no classifier)")
    p.add_argument("--every", type=int, default=1, help="use one stereo pair in N")
    p.add_argument("--method", default="elevation_map", choices=METHODS,
                   help="elevation_map (default: ROIs found in the drive's fused height "
                   "map) or per_pair (the paper's: detect per pair, then track)")
    p.add_argument("--min-obs", type=int, default=3,
                   help="observations (per_pair) or detection rounds in a row "
                   "(elevation_map) that make an LN node")
    p.add_argument("--working-fx", type=float, default=RoverConfig().working_fx_px,
                   metavar="PX",
                   help="the angular resolution the detector works at, as a focal length in "
                   "pixels: finer stereo pairs are resampled to it (the pixel parameters and "
                   "the committed Rock Rovers are set at it; default %(default)g; 0: as they "
                   "come)")
    p.add_argument("--no-rectify", action="store_true",
                   help="read every image as rectified, whatever its CameraInfo's distortion "
                   "(D) and rectifying rotation (R) say (default: remap to its P, as the "
                   "node's parameter rectify does)")
    p.add_argument("--stereo-sync-tolerance", type=float, default=images.SYNC_TOLERANCE_S,
                   metavar="S", help="left and right images whose stamps differ by at most "
                   "this many seconds are one pair (default %(default)g; 0: exact stamps; "
                   "the node's parameter stereo_sync_tolerance_s)")
    p.add_argument("--min-pair-travel", type=float, default=PairSpacing().min_travel_m,
                   metavar="M", help="read a stereo pair once the rover moved this far since "
                   f"the last read (or turned {PairSpacing().min_turn_deg:g} deg, or "
                   f"{PairSpacing().max_interval_s:g} s passed): a field camera's stream "
                   "thinned to the spacing the detector is set at (default %(default)g; 0: "
                   "every pair; the node's parameter min_pair_travel_m)")
    p.add_argument("--covariance", default=None, metavar="FILE",
                   help="the odometry's pose covariance (t and 36 numbers per odometry stamp, "
                   f"as rover_vo writes it; default: {POSE_COVARIANCE_FILE} beside the "
                   "odometry file, if there is one; 'none': use --drift)")
    p.add_argument("--drift", type=float, default=DEFAULT_DRIFT_FRAC,
                   help="with no covariance file: odometry 1-sigma error per metre travelled")
    p.set_defaults(func=_cmd_ln)
    p = sub.add_parser("eval", help="an LN's detections judged against the bag's truth")
    p.add_argument("ln")
    p.add_argument("bag")
    p.add_argument("--json", default=None)
    p.add_argument("--plot", default=None)
    p.set_defaults(func=_cmd_eval)
    p = sub.add_parser("train", help="train the rover classifiers (Rock Rover, Outcrop Rover)")
    p.add_argument("bags", nargs="+")
    p.add_argument("--out", required=True)
    p.add_argument("--method", default="elevation_map", choices=METHODS,
                   help="elevation_map (default): the far rocks' and map rocks' Rock Rovers "
                   "and the map outcrops' Outcrop Rover on the drives' far tracks and map "
                   "regions; per_pair: Rock Rover and Outcrop Rover on every pair's "
                   "candidates")
    p.add_argument("--every", type=int, default=2, help="per_pair: use one stereo pair in N")
    p.add_argument("--jobs", type=int, default=1,
                   help="elevation_map: bags run at a time, one process each")
    p.add_argument("--k", type=int, default=5,
                   help="kNN neighbours (per_pair's rovers, the map outcrops' Outcrop Rover)")
    p.add_argument("--working-fx", type=float, default=RoverConfig().working_fx_px,
                   metavar="PX",
                   help="elevation_map: the working resolution the samples are taken at (as "
                   "roi_detector ln --working-fx; the model records it and a detector at "
                   "another refuses it; default %(default)g)")
    p.add_argument("--cache", default=None, metavar="DIR",
                   help="elevation_map: keep each drive's samples in DIR/<bag name>.npz and "
                   "read them from there when taken with the same settings (empty it when "
                   "the detector changes)")
    p.set_defaults(func=_cmd_train)
    p = sub.add_parser("truth-odometry", help="truth trajectory re-expressed in odom (TUM)")
    p.add_argument("bag")
    p.add_argument("--out", required=True)
    p.set_defaults(func=_cmd_truth_odometry)
    args = ap.parse_args(argv)
    try:
        return args.func(args)
    except (OSError, ValueError) as exc:
        print(f"roi_detector {args.cmd}: error: {exc}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    sys.exit(main())
