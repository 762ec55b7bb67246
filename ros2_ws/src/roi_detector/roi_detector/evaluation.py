"""An LN's detections judged against a bag's truth (evaluation only: reads truth files).

DESIGN.md's rule: an LN node matches a truth ROI of the same class when its centre is
within max(1 m, half the truth major axis). The LN is in odom; odom is the first truth
position and heading, gravity-aligned (how both the truth odometry and rover_vo start).
Detection metrics only: what the matcher makes of an LN is judged where the matcher is
run (``bench/roi_bench.py``).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from roi_detector.camera_poses import moved_pair_poses
from roi_detector.inputs import load_rover_params
from roi_detector.truth import Truth, match_to_truth
from roi_network.geojson import read_geojson
from roi_network.records import LABEL_NAMES, OUTCROP, ROCK, xy


def _rate(num: int, den: int) -> float | None:
    return None if den == 0 else num / den


def evaluate_ln(ln_path: str, bag_dir: str, plot: str | None = None,
                radius_m: float = 15.0, view_depth_m: float = 20.0,
                min_views: int = 3) -> dict:
    """Recall, precision, classification accuracy and node error of an LN file.

    Args:
        ln_path: LN GeoJSON (odom) written by ``roi_detector ln`` or ln_builder.
        bag_dir: the bag directory with ``truth/``.
        plot: optional PNG path: truth ROIs, route and LN nodes in map.
        radius_m, view_depth_m, min_views: which truth ROIs the recalls count
            (:func:`counted_rois`).
    """
    truth = Truth.load(bag_dir)
    ln = read_geojson(ln_path).records
    wanted, in_view = counted_rois(truth, bag_dir, radius_m, view_depth_m, min_views)
    report: dict = {"ln": str(ln_path), "bag": str(bag_dir),
                    "in_view_rule": f">= {min_views} stereo pairs with the centre in the "
                    f"left image at most {view_depth_m:g} m deep",
                    **count_ln(ln, truth, wanted, in_view)}
    if plot:
        _plot(plot, truth, match_nodes(ln, truth)[0], ln, wanted)
    return report


def counted_rois(truth: Truth, bag_dir: str | Path, radius_m: float = 15.0,
                 view_depth_m: float = 20.0, min_views: int = 3
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The truth ROIs the two recalls count, as masks over ``truth.rois``.

    Args:
        truth: the bag's truth.
        bag_dir: the bag directory (its ``rover.yaml`` gives the camera).
        radius_m: the issue's recall counts truth ROIs above the rover thresholds this
            close to the route, metres.
        view_depth_m, min_views: the second recall (``recall_in_view``) counts only those
            whose centre was in the left image, at most ``view_depth_m`` deep, in at
            least ``min_views`` stereo pairs (:meth:`Truth.views`; on a mast, its
            panoramas' pairs too): a fixed forward camera never sees many ROIs within
            15 m of the route.
    """
    wanted = truth.counted(radius_m)
    params = load_rover_params(Path(bag_dir) / "rover.yaml")
    in_view = wanted & (truth.views(params, view_depth_m,
                                    moved=moved_pair_poses(bag_dir, params)) >= min_views)
    return wanted, in_view


def count_ln(ln: np.ndarray, truth: Truth, wanted: np.ndarray, in_view: np.ndarray) -> dict:
    """An LN's nodes (records, ``odom``) counted against the truth by DESIGN.md's rule:
    per class, its nodes, the true ones and the counted truth ROIs found (``wanted``,
    ``in_view``: :func:`counted_rois`); the classification accuracy and the true nodes'
    position error."""
    t = truth.rois
    pts, j_any = match_nodes(ln, truth)
    report: dict = {"ln_nodes": len(ln), "truth_wanted": int(wanted.sum()),
                    "truth_in_view": int(in_view.sum()), "per_class": {}}
    for label in (ROCK, OUTCROP):
        name = LABEL_NAMES[label]
        mine = ln["label"] == label
        tp_nodes = true_nodes(ln, t, j_any, label)
        found = set(j_any[tp_nodes].tolist())
        wanted_c = np.flatnonzero(wanted & (t["label"] == label))
        hits = sum(1 for i in wanted_c if i in found)
        view_c = np.flatnonzero(in_view & (t["label"] == label))
        hits_view = sum(1 for i in view_c if i in found)
        report["per_class"][name] = {
            "ln_nodes": int(mine.sum()), "true_nodes": int(tp_nodes.sum()),
            "precision": _rate(int(tp_nodes.sum()), int(mine.sum())),
            "truth_wanted": len(wanted_c), "truth_found": int(hits),
            "recall": _rate(hits, len(wanted_c)),
            "truth_in_view": len(view_c), "truth_in_view_found": int(hits_view),
            "recall_in_view": _rate(hits_view, len(view_c)),
        }
    matched = j_any >= 0
    correct = matched & (t["label"][np.clip(j_any, 0, None)] == ln["label"])
    report["classification_accuracy"] = _rate(int(correct.sum()), int(matched.sum()))
    report["nodes_matching_any_truth"] = int(matched.sum())
    tp = np.flatnonzero(correct)
    if len(tp):
        err = np.linalg.norm(pts[tp, :2] - xy(t)[j_any[tp]], axis=1)
        report["node_error_m"] = {"median": float(np.median(err)), "p90":
                                  float(np.percentile(err, 90)), "max": float(err.max()),
                                  "n": len(err)}
        sig = np.sqrt(0.5 * (ln["cov_xx"][tp] + ln["cov_yy"][tp]))
        report["node_error_over_sigma_median"] = float(np.median(err / np.maximum(sig, 1e-6)))
    return report


def match_nodes(ln: np.ndarray, truth: Truth) -> tuple[np.ndarray, np.ndarray]:
    """LN node positions in map (N, 3) and, per node, the truth ROI it matches by position
    alone (DESIGN.md's rule; -1 for none): the class is judged by :func:`true_nodes`."""
    pts = truth.odom_to_map(np.column_stack([ln["x"], ln["y"], ln["z"]])) if len(ln) else \
        np.zeros((0, 3))
    j_any, _ = match_to_truth(pts[:, :2], truth.rois)
    return pts, j_any


def true_nodes(ln: np.ndarray, truth_rois: np.ndarray, j_any: np.ndarray,
               label: int) -> np.ndarray:
    """Mask of the LN nodes of class ``label`` that match a truth ROI of that class."""
    truth_of = np.where(j_any >= 0, truth_rois["label"][np.clip(j_any, 0, None)], 0)
    return (ln["label"] == label) & (j_any >= 0) & (truth_of == label)


def _plot(path: str, truth: Truth, pts: np.ndarray, ln: np.ndarray, wanted: np.ndarray) -> None:
    """Top-down map (OpenCV drawing): route, truth ROIs (circles, thick: counted), LN
    nodes (crosses); rocks red, outcrops cyan; 5 px per metre, north up."""
    import cv2

    t = truth.rois
    route = truth.trajectory.p[:, :2]
    pad = 20.0
    lo = route.min(axis=0) - pad
    hi = route.max(axis=0) + pad
    scale = min(5.0, 1600.0 / max(hi - lo))
    size = np.ceil((hi - lo) * scale).astype(int) + 1
    img = np.full((size[1], size[0], 3), 255, np.uint8)

    def px(p):
        q = (np.asarray(p)[..., :2] - lo) * scale
        return np.column_stack([q[..., 0], size[1] - 1 - q[..., 1]]).round().astype(np.int32)

    cv2.polylines(img, [px(route)], False, (150, 150, 150), 1, cv2.LINE_AA)
    colours = {ROCK: (40, 40, 220), OUTCROP: (200, 170, 0)}
    for label, col in colours.items():
        m = t["label"] == label
        for (u, v), w, r in zip(px(xy(t)[m]), wanted[m], t["major_m"][m], strict=True):
            cv2.circle(img, (int(u), int(v)), max(3, int(0.5 * r * scale)), col,
                       2 if w else 1, cv2.LINE_AA)
        n = ln["label"] == label
        for u, v in px(pts[n]):
            cv2.drawMarker(img, (int(u), int(v)), col, cv2.MARKER_CROSS, 8, 2)
    cv2.putText(img, "truth ROI: circle (thick: counted in recall); LN node: cross; "
                "rock red, outcrop cyan", (8, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.45, (0, 0, 0), 1,
                cv2.LINE_AA)
    tmp = Path(path).with_name(Path(path).name + ".tmp.png")
    cv2.imwrite(str(tmp), img)
    tmp.replace(path)
