"""Replay a run's LN and odometry through the matcher and the map -> odom filter, offline.

    python bench/replay_matcher.py RUN_DIR BAG_DIR [--variants base,notrack,triplets48]
        [--gn GN.geojson] [--cov-scale S] [--events] [--json OUT]

RUN_DIR is a ``globloc run`` directory (its ``outputs/`` bag holds every /local_network
and /vo/odometry message of the run); BAG_DIR the bag it ran on (``gn.geojson``,
``truth/trajectory.tum``). The darces_matcher node's logic without ROS: each LN that grew
is matched (``Matcher.match_or_track``, as the node does: the global search, then tracking
near the estimate when localized and the variant tracks), folded into
``MapOdomFilter``, and every odometry pose mapped into ``map``. The LN and the odometry
are the run's own, so a matcher or filter setting is judged in seconds on the LNs the
perception really built, instead of a 10-25 min run.
(The node also re-matches an LN that changed without growing every 10 s; the replay does
not, so its refinements are fewer.)

Evaluation only, after the run: the truth gives each pose's horizontal error, and with
``--events`` each decision is printed with the fit's error at the rover against the
"oracle" alignment (the rigid fit of the whole odometry onto the truth). ``--gn`` replaces
the GN (e.g. ``BAG_DIR/truth/rois.geojson``, the truth catalogue: what a perfect orbital
detector would give); ``--cov-scale`` scales the LN nodes' covariance.
Each LN goes with the odometry covariance its nodes were observed with
(``darces_matcher.ln_drift.NodeOdometry``, fed as the node feeds it); the variant
``records_only`` leaves it out (the records' covariance alone).
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

from darces_matcher.ln_drift import NodeOdometry
from darces_matcher.localization import FilterConfig, MapOdomFilter, global_pose, yaw_quaternion
from darces_matcher.matcher import MatchConfig, Matcher
from roi_network.geojson import read_geojson
from roi_network.pointcloud import from_pointcloud2
from roi_network.records import xy
from roi_network.transform import Rigid2D

#: name -> (MatchConfig overrides, track when localized)
VARIANTS: dict[str, tuple[dict, bool]] = {
    "base": ({}, True),
    "notrack": ({}, False),
    "triplets48": ({"n_triplets": 48}, True),
}
#: variants that do not read the odometry covariance each node was observed with
#: (darces_matcher.ln_drift): the records' covariance alone
RECORDS_ONLY = ("records_only",)
VARIANTS["records_only"] = ({}, True)
#: chi-square, 2 degrees of freedom, 99.73 % (3 sigma)
_CHI2_2D_3SIGMA = 11.83


def read_run(run_dir: Path, cov_scale: float = 1.0) -> tuple[list, list]:
    """(stamp, LN records) per /local_network and (stamp, x, y, yaw, covariance (36,))
    per /vo/odometry message of the run's outputs bag."""
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    bag = run_dir / "outputs"
    if not (bag / "metadata.yaml").is_file():
        raise SystemExit(f"replay_matcher: no outputs bag in {run_dir} ({bag}/metadata.yaml)")
    store = get_typestore(Stores.ROS2_JAZZY)
    lns, odometry = [], []
    with Reader(bag) as reader:
        conns = [c for c in reader.connections
                 if c.topic in ("/local_network", "/vo/odometry")]
        for conn, _, raw in reader.messages(connections=conns):
            msg = store.deserialize_cdr(raw, conn.msgtype)
            t = msg.header.stamp.sec + 1e-9 * msg.header.stamp.nanosec
            if conn.topic == "/local_network":
                rec = from_pointcloud2(msg)
                for name in ("cov_xx", "cov_xy", "cov_yy"):
                    rec[name] = rec[name] * cov_scale
                lns.append((t, rec))
            else:
                p, q = msg.pose.pose.position, msg.pose.pose.orientation
                odometry.append((t, p.x, p.y, 2.0 * np.arctan2(q.z, q.w),
                                 np.array(msg.pose.covariance, dtype=float)))
    if not lns or not odometry:
        raise SystemExit(f"replay_matcher: {bag} holds {len(lns)} /local_network and "
                         f"{len(odometry)} /vo/odometry messages; both are needed")
    return lns, odometry


def truth_along(odometry: list, truth_path: Path) -> tuple[np.ndarray, np.ndarray, Rigid2D]:
    """At each odometry message of :func:`read_run`: the truth position (map, x-y), the
    distance travelled along the truth, and the oracle alignment (the rigid fit of the
    whole odometry onto the truth), from the bag's ``truth/trajectory.tum``."""
    truth = np.loadtxt(truth_path, comments="#", ndmin=2)
    stamps = np.array([o[0] for o in odometry])
    odom_xy = np.array([[o[1], o[2]] for o in odometry])
    k = np.clip(np.searchsorted(truth[:, 0], stamps), 0, len(truth) - 1)
    truth_xy = truth[k, 1:3]
    dist = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(truth_xy, axis=0), axis=1))]
    return truth_xy, dist, Rigid2D.fit(odom_xy, truth_xy)


def replay(lns: list, odometry: list, gn, truth_xy: np.ndarray, dist: np.ndarray,
           variant: str, oracle: Rigid2D, events_out=None) -> dict:
    """One variant over the run; returns its figures (see the module docstring)."""
    overrides, track = VARIANTS[variant]
    matcher = Matcher(gn, MatchConfig(**overrides))
    filt = MapOdomFilter(FilterConfig())
    nodes = NodeOdometry()
    gn_xy = xy(gn.records)
    li, last_size, first = 0, 0, None
    errors, chi2, ms, events = [], [], [], {}
    for i, (t, x, y, yaw, cov) in enumerate(odometry):
        here = np.array([x, y])
        while li < len(lns) and lns[li][0] <= t:
            rec = lns[li][1]
            nodes.add_ln(lns[li][0], rec["id"], xy(rec))
            li += 1
            if len(rec) <= last_size:
                continue
            odom_cov = None if variant in RECORDS_ONLY else nodes.covariances(rec["id"])
            last_size = len(rec)
            t0 = time.perf_counter()
            estimate = filt.alignment if track else None
            if estimate is None:
                result = matcher.match_or_track(rec, odom_cov=odom_cov)
            else:
                result = matcher.match_or_track(rec, estimate.map_T_odom, estimate.covariance,
                                                odom_cov=odom_cov)
            ms.append(1e3 * (time.perf_counter() - t0))
            event = filt.update(result, xy(rec), gn_xy)
            key = f"{event}:{result.reason}"
            events[key] = events.get(key, 0) + 1
            if event == "first_fix" and first is None:
                first = float(dist[i])
            if events_out is not None:
                line = (f"{dist[i]:7.1f} m  {key:32s} LN {len(rec):3d} support {result.support:3d}"
                        f" dropped {result.drift_dropped}")
                if result.map_T_odom is not None:
                    off = np.linalg.norm(result.map_T_odom.apply(here) - oracle.apply(here))
                    now = np.linalg.norm(result.map_T_odom.apply(here) - truth_xy[i])
                    line += (f"  fit off oracle {off:6.2f} m, "
                             f"{np.degrees(result.map_T_odom.yaw - oracle.yaw):+.2f} deg, "
                             f"off truth at the rover {now:6.2f} m")
                if np.isfinite(result.log_odds):
                    line += (f"  log-odds {result.log_odds:5.1f}, "
                             f"p_false {result.false_match_probability:.2g}")
                print(line, file=events_out)
        nodes.add_odometry(t, cov)
        filt.predict(here)
        if filt.localized:
            pos, _, c = global_pose(filt.alignment, np.array([x, y, 0.0]), yaw_quaternion(yaw),
                                    cov.reshape(6, 6))
            d = pos[:2] - truth_xy[i]
            errors.append(float(np.hypot(*d)))
            chi2.append(float(d @ np.linalg.solve(c[:2, :2], d)))
    e = np.array(errors)
    return {
        "variant": variant, "first_fix_after_m": first, "poses": len(e),
        "final_error_m": float(e[-1]) if len(e) else None,
        "rmse_m": float(np.sqrt(np.mean(e**2))) if len(e) else None,
        "max_error_m": float(e.max()) if len(e) else None,
        "poses_over_10m": int((e > 10.0).sum()),
        "consistency_3sigma": float(np.mean(np.array(chi2) <= _CHI2_2D_3SIGMA)) if len(e) else None,
        "match_ms_median": float(np.median(ms)) if ms else None,
        "events": events,
    }


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("run_dir", type=Path)
    p.add_argument("bag_dir", type=Path)
    p.add_argument("--variants", default="base",
                   help=f"comma-separated subset of {','.join(VARIANTS)}")
    p.add_argument("--gn", type=Path, default=None, help="default: BAG_DIR/gn.geojson")
    p.add_argument("--cov-scale", type=float, default=1.0)
    p.add_argument("--events", action="store_true", help="print every decision")
    p.add_argument("--json", type=Path, default=None)
    args = p.parse_args(argv)
    unknown = [v for v in args.variants.split(",") if v not in VARIANTS]
    if unknown:
        p.error(f"unknown variant(s) {unknown} (known: {', '.join(VARIANTS)})")
    truth_path = args.bag_dir / "truth" / "trajectory.tum"
    gn_path = args.gn or args.bag_dir / "gn.geojson"
    for path in (truth_path, gn_path):
        if not path.is_file():
            p.error(f"{path} not found")
    lns, odometry = read_run(args.run_dir, args.cov_scale)
    truth_xy, dist, oracle = truth_along(odometry, truth_path)
    gn = read_geojson(gn_path)
    print(f"{args.run_dir}: {len(lns)} LNs, {len(odometry)} odometry poses, route "
          f"{dist[-1]:.0f} m; GN {gn_path} ({len(gn)} ROIs)", flush=True)
    rows = []
    for variant in args.variants.split(","):
        rows.append(replay(lns, odometry, gn, truth_xy, dist, variant, oracle,
                           sys.stdout if args.events else None))
        print(json.dumps(rows[-1]), flush=True)
    if args.json:
        args.json.write_text(json.dumps({"run_dir": str(args.run_dir), "gn": str(gn_path),
                                         "cov_scale": args.cov_scale, "rows": rows},
                                        indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
