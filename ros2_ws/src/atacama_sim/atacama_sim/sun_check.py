"""How a bag's ``/sun_sensor`` compares with the ephemeris (evaluation: reads the truth).

``python -m atacama_sim.sun_check BAG_DIR`` prints, as JSON: the sensor's output rate,
the share of its samples with an output and the outages by reason (world.yaml), and its
error against the sun computed from the bag's own records alone: rover.yaml's site and
mount, the truth trajectory, ``roi_network.sun`` (angle between the measured and the true
vector, and each of the two angles' error, raw and less world.yaml's recorded biases).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from scipy.spatial.transform import Rotation

from roi_network import sun as ephemeris
from roi_network.params import node_parameters


def _truth_sun(params: dict[str, Any], origin: list[float], tum: np.ndarray,
               stamps_s: np.ndarray) -> np.ndarray:
    """True unit sun vectors in the sensor frame at ``stamps_s`` (truth pose at each)."""
    from pyproj import CRS, Transformer

    crs = CRS.from_user_input(params["site.crs"])
    to_ll = Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True).transform
    mount = np.asarray(params["sun_sensor.base_to_sensor"], float)
    r_bs = Rotation.from_quat(mount[3:]).as_matrix()
    out = np.zeros((len(stamps_s), 3))
    for i, t in enumerate(stamps_s):
        j = int(np.argmin(np.abs(tum[:, 0] - t)))
        if abs(tum[j, 0] - t) > 1e-4:
            raise ValueError(f"truth/trajectory.tum: no pose at sun sensor stamp {t:.3f}")
        r_wb = Rotation.from_quat(tum[j, 4:8]).as_matrix()
        p = tum[j, 1:4] + r_wb @ mount[:3]
        lon, lat = to_ll(p[0] + origin[0], p[1] + origin[1])
        pos = ephemeris.sun_position(params["site.body"], lat, lon, float(t))
        s_map = ephemeris.grid_north(params["site.crs"], lon, lat).enu_to_grid(pos.enu())
        out[i] = r_bs.T @ r_wb.T @ s_map
    return out


def _angles(v: np.ndarray) -> np.ndarray:
    return np.degrees(np.column_stack([np.arctan2(v[:, 0], v[:, 2]),
                                       np.arctan2(v[:, 1], v[:, 2])]))


def _spread(x: np.ndarray) -> dict[str, float]:
    return {"median": round(float(np.median(x)), 4), "p95": round(float(np.percentile(x, 95)), 4),
            "max": round(float(np.max(x)), 4), "rms": round(float(np.sqrt(np.mean(x ** 2))), 4)}


def sun_sensor_report(bag_dir: str | Path) -> dict[str, Any]:
    """The figures of the module docstring for ``bag_dir``.

    Raises:
        ValueError: naming the file that lacks what is needed (no /sun_sensor message, no
            truth pose at a stamp).
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    bag = Path(bag_dir)
    params = node_parameters(yaml.safe_load((bag / "rover.yaml").read_text()), "any")
    derived = yaml.safe_load((bag / "world.yaml").read_text())["derived"]
    tum = np.loadtxt(bag / "truth/trajectory.tum")
    stamps, vecs = [], []
    with AnyReader([bag / "rosbag"],
                   default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        conns = [c for c in reader.connections if c.topic == "/sun_sensor"]
        for conn, t, raw in reader.messages(connections=conns):
            m = reader.deserialize(raw, conn.msgtype)
            stamps.append(t * 1e-9)
            vecs.append([m.vector.x, m.vector.y, m.vector.z])
    if not stamps:
        raise ValueError(f"{bag / 'rosbag'}: no /sun_sensor message")
    stamps_s, meas = np.asarray(stamps), np.asarray(vecs)
    truth = _truth_sun(params, derived["map_origin"], tum, stamps_s)
    angle = np.degrees(np.arccos(np.clip(np.sum(meas * truth, axis=1), -1.0, 1.0)))
    err = _angles(meas) - _angles(truth)
    sensor = derived["sun"]["sensor"]
    bias = np.asarray(sensor["bias_deg"])
    less_bias = err - bias
    duration = float(derived["route"]["duration_s"])
    dt = np.diff(stamps_s)
    return {
        "bag": str(bag),
        "duration_s": duration,
        "rate_hz": params["sun_sensor.rate_hz"],
        "messages": len(stamps_s),
        "output_rate_hz": round(len(stamps_s) / duration, 3),
        "median_interval_s": round(float(np.median(dt)), 4) if len(dt) else None,
        "longest_gap_s": round(float(np.max(dt)), 2) if len(dt) else None,
        "samples": sensor["samples"],
        "output_share": sensor["output_share"],
        "outages": {k: sensor[k] for k in ("below_horizon", "outside_fov",
                                           "shadowed_by_mast")},
        "sun_path": derived["sun"]["path"],
        "angle_error_deg": _spread(angle),
        "axis_error_deg": {"mean": [round(float(v), 4) for v in err.mean(axis=0)],
                           "std": [round(float(v), 4) for v in err.std(axis=0)]},
        "recorded_bias_deg": [float(b) for b in bias],
        "axis_error_less_bias_deg": {
            "mean": [round(float(v), 4) for v in less_bias.mean(axis=0)],
            "std": [round(float(v), 4) for v in less_bias.std(axis=0)],
            "max_abs": [round(float(v), 4) for v in np.abs(less_bias).max(axis=0)]},
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m atacama_sim.sun_check",
                                     description="A bag's /sun_sensor against the ephemeris.")
    parser.add_argument("bag", type=Path, help="bag directory (atacama_sim layout)")
    args = parser.parse_args(argv)
    try:
        report = sun_sensor_report(args.bag)
    except (OSError, ValueError, KeyError) as exc:
        print(f"sun_check: {exc}", file=sys.stderr)
        return 1
    print(json.dumps(report, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
