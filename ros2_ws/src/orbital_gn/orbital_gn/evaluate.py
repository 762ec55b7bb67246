"""Detection quality of a GN against a truth catalogue (evaluation only: reads truth).

DESIGN.md's rule: a detection matches a truth ROI of the same class when its centre lies
within max(1 m, half the truth major axis). Precision is the share of detections that match
some truth ROI; recall the share of truth ROIs matched by some detection. Rocks are also
binned by footprint (0.6-1, 1-2, 2-6 m^2): recall by the truth area; precision by the
matched truth's area, or the detection's own area when it matches nothing.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Final

import numpy as np
from scipy.spatial import cKDTree

from roi_network import LABEL_NAMES, OUTCROP, ROCK, RoiNetwork

#: Rock footprint bins, m^2 (the 0.6-1 bin is 3-4 pixels across at 0.25 m).
ROCK_BINS: Final = ((0.6, 1.0), (1.0, 2.0), (2.0, 6.0))


def crs_xy(net: RoiNetwork, records: np.ndarray | None = None) -> np.ndarray:
    """(N, 2) CRS coordinates (map frame + origin)."""
    r = net.records if records is None else records
    ox, oy = net.map_frame.origin if net.map_frame else (0.0, 0.0)
    return np.column_stack([r["x"] + ox, r["y"] + oy])


def match(gn: RoiNetwork, truth: RoiNetwork, label: int) -> tuple[np.ndarray, np.ndarray]:
    """For one class: (index of the matched truth ROI per detection or -1, matched flag per
    truth ROI). A detection takes the nearest truth ROI within its radius."""
    det = gn.records[gn.records["label"] == label]
    tr = truth.records[truth.records["label"] == label]
    det_match = np.full(det.size, -1)
    tr_hit = np.zeros(tr.size, bool)
    if det.size == 0 or tr.size == 0:
        return det_match, tr_hit
    dxy, txy = crs_xy(gn, det), crs_xy(truth, tr)
    radius = np.maximum(1.0, tr["major_m"] / 2.0)
    tree = cKDTree(txy)
    for i, p in enumerate(dxy):
        idx = tree.query_ball_point(p, float(radius.max()))
        if not idx:
            continue
        idx = np.asarray(idx)
        d = np.hypot(*(txy[idx] - p).T)
        ok = d <= radius[idx]
        if ok.any():
            j = idx[ok][np.argmin(d[ok])]
            det_match[i] = j
            tr_hit[j] = True
    return det_match, tr_hit


def _pr(n_det: int, n_tp: int, n_truth: int, n_hit: int) -> dict[str, Any]:
    return {"detections": n_det, "true_positives": n_tp, "truth": n_truth, "found": n_hit,
            "precision": n_tp / n_det if n_det else None,
            "recall": n_hit / n_truth if n_truth else None}


def _centre_error(gn: RoiNetwork, truth: RoiNetwork, det: np.ndarray, tr: np.ndarray,
                  det_match: np.ndarray) -> dict[str, float | None]:
    """Median and 90th percentile distance (m) from matched detections to their truth."""
    ok = det_match >= 0
    if not ok.any():
        return {"median": None, "p90": None}
    d = np.hypot(*(crs_xy(gn, det[ok]) - crs_xy(truth, tr[det_match[ok]])).T)
    return {"median": float(np.median(d)), "p90": float(np.percentile(d, 90))}


def route_xy(trajectory_tum: str | Path, truth: RoiNetwork) -> np.ndarray:
    """(N, 2) CRS positions of a TUM trajectory in the truth's map frame."""
    data = np.loadtxt(trajectory_tum, ndmin=2)
    ox, oy = truth.map_frame.origin if truth.map_frame else (0.0, 0.0)
    return np.column_stack([data[:, 1] + ox, data[:, 2] + oy])


def evaluate(gn: RoiNetwork, truth: RoiNetwork, route: np.ndarray | None = None,
             route_radius_m: float = 15.0) -> dict[str, Any]:
    """Precision and recall per class, per rock footprint bin, for rocks >= 1 m^2, and the
    share of truth ROIs within ``route_radius_m`` of the route that the GN holds."""
    out: dict[str, Any] = {"rule": "centre within max(1 m, half truth major axis), same class"}
    hits = {}
    for label in (ROCK, OUTCROP):
        det_match, tr_hit = match(gn, truth, label)
        hits[label] = tr_hit
        det = gn.records[gn.records["label"] == label]
        tr = truth.records[truth.records["label"] == label]
        name = LABEL_NAMES[label]
        out[name] = _pr(det.size, int((det_match >= 0).sum()), tr.size, int(tr_hit.sum()))
        out[name]["centre_error_m"] = _centre_error(gn, truth, det, tr, det_match)
        if label != ROCK:
            continue
        # A detection's bin: its matched truth's area, or its own when unmatched.
        det_area = np.where(det_match >= 0, tr["area_m2"][np.maximum(det_match, 0)],
                            det["area_m2"]) if det.size else np.zeros(0)
        bins = {}
        for lo, hi in ROCK_BINS:
            top = np.inf if hi == ROCK_BINS[-1][1] else hi
            in_d = (det_area >= lo) & (det_area < top)
            in_t = (tr["area_m2"] >= lo) & (tr["area_m2"] < top)
            bins[f"{lo:g}-{hi:g}"] = _pr(int(in_d.sum()), int((det_match[in_d] >= 0).sum()),
                                         int(in_t.sum()), int(tr_hit[in_t].sum()))
        out["rock_bins_m2"] = bins
        big_d, big_t = det_area >= 1.0, tr["area_m2"] >= 1.0
        out["rock_ge_1m2"] = _pr(int(big_d.sum()), int((det_match[big_d] >= 0).sum()),
                                 int(big_t.sum()), int(tr_hit[big_t].sum()))
    if route is not None and len(route):
        tree = cKDTree(route)
        near_all, held_all = 0, 0
        for label in (ROCK, OUTCROP):
            tr = truth.records[truth.records["label"] == label]
            if tr.size == 0:
                continue
            d, _ = tree.query(crs_xy(truth, tr))
            near = d <= route_radius_m
            near_all += int(near.sum())
            held_all += int(hits[label][near].sum())
        out["near_route"] = {"radius_m": route_radius_m, "truth": near_all, "in_gn": held_all,
                             "fraction": held_all / near_all if near_all else None}
    return out
