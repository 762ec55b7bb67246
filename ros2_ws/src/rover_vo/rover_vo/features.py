"""Feature extraction, stereo matching and temporal tracking (paper Sec. 3: feature
extraction). OpenCV does the work: Shi-Tomasi corners on a grid, pyramidal Lucas-Kanade
along the rectified rows for stereo, and Lucas-Kanade from a motion-predicted position for
tracking, each with a forward-backward check.

Pixels are (u, v) in the rectified image: u right, v down, origin at the first pixel's
centre.
"""

from __future__ import annotations

import cv2
import numpy as np

from rover_vo.config import FeatureOptions


def _lk(opts: FeatureOptions) -> dict:
    criteria = (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, opts.lk_iterations,
                opts.lk_epsilon_px)
    return {"winSize": (opts.lk_window_px, opts.lk_window_px), "maxLevel": opts.lk_levels,
            "criteria": criteria}


def _shape(image) -> tuple[int, int]:
    return (image[0] if isinstance(image, list | tuple) else image).shape[:2]


def detect_corners(image: np.ndarray, opts: FeatureOptions,
                   existing: np.ndarray | None = None) -> np.ndarray:
    """Shi-Tomasi corners spread over a grid, away from ``existing`` ones.

    Args:
        image: 8-bit grey image.
        opts: feature options.
        existing: (N, 2) corners already tracked (px); new ones keep ``min_distance_px``
            from them.

    Returns:
        (M, 2) float32 corners (px).
    """
    h, w = image.shape
    mask = np.full((h, w), 255, np.uint8)
    if existing is not None and len(existing):
        for u, v in np.round(existing).astype(int):
            cv2.circle(mask, (int(u), int(v)), int(opts.min_distance_px), 0, -1)
    cells = opts.grid_cols * opts.grid_rows
    per_cell = max(1, opts.max_corners // cells)
    out = []
    # A per-cell budget keeps corners spread over the image: clustered corners constrain
    # rotation poorly and all vanish together when the rover turns.
    for r in range(opts.grid_rows):
        for c in range(opts.grid_cols):
            y0, y1 = r * h // opts.grid_rows, (r + 1) * h // opts.grid_rows
            x0, x1 = c * w // opts.grid_cols, (c + 1) * w // opts.grid_cols
            pts = cv2.goodFeaturesToTrack(image[y0:y1, x0:x1], per_cell, opts.quality_level,
                                          opts.min_distance_px, mask=mask[y0:y1, x0:x1],
                                          blockSize=5)
            if pts is not None:
                out.append(pts.reshape(-1, 2) + np.array([x0, y0], np.float32))
    if not out:
        return np.zeros((0, 2), np.float32)
    pts = np.concatenate(out).astype(np.float32)
    # Sub-pixel corner positions: the drift budget (0.5 %) is spent in tenths of pixels.
    cv2.cornerSubPix(image, pts.reshape(-1, 1, 2), (4, 4), (-1, -1),
                     (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.01))
    return pts


def track(prev: np.ndarray, curr: np.ndarray, pts: np.ndarray, opts: FeatureOptions,
          predicted: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pyramidal Lucas-Kanade from ``prev`` to ``curr`` with a forward-backward check.

    Args:
        prev, curr: 8-bit grey images.
        pts: (N, 2) corners in ``prev`` (px).
        opts: feature options.
        predicted: (N, 2) predicted positions in ``curr`` (from the IMU rotation and the
            previous motion), the starting point of the search; None: start at ``pts``.

    Returns:
        ``(tracked (N, 2) px, ok (N,) bool)``.
    """
    n = len(pts)
    if n == 0:
        return np.zeros((0, 2), np.float32), np.zeros(0, bool)
    p0 = pts.reshape(-1, 1, 2).astype(np.float32)
    flags = 0
    p1 = None
    if predicted is not None:
        p1 = predicted.reshape(-1, 1, 2).astype(np.float32).copy()
        flags = cv2.OPTFLOW_USE_INITIAL_FLOW
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(prev, curr, p0, p1, flags=flags, **_lk(opts))
    back = p0.copy()
    p0b, st2, _ = cv2.calcOpticalFlowPyrLK(curr, prev, p1, back,
                                           flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **_lk(opts))
    p1, p0b = p1.reshape(-1, 2), p0b.reshape(-1, 2)
    h, w = _shape(curr)
    ok = (st1.ravel() == 1) & (st2.ravel() == 1)
    ok &= np.linalg.norm(p0b - pts, axis=1) < opts.fb_max_px
    ok &= (p1[:, 0] >= 0) & (p1[:, 0] <= w - 1) & (p1[:, 1] >= 0) & (p1[:, 1] <= h - 1)
    return p1, ok


def stereo_match(left: np.ndarray, right: np.ndarray, pts: np.ndarray, opts: FeatureOptions,
                 fx: float, baseline_m: float,
                 disparity_guess: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Match left corners in the rectified right image (same row, smaller u).

    The search starts at ``disparity_guess`` (default: a point 5 m ahead) and LK follows
    the row; matches off the row by more than ``stereo_max_dy_px`` or with a disparity
    outside ``[min_disparity_px, fx * baseline / 0.5 m]`` are rejected.

    Returns:
        ``(disparity (N,) px, ok (N,) bool)``.
    """
    n = len(pts)
    if n == 0:
        return np.zeros(0), np.zeros(0, bool)
    guess = pts.copy()
    if disparity_guess is None:
        disparity_guess = np.full(n, fx * baseline_m / 5.0)
    guess[:, 0] -= disparity_guess
    pr, ok = track(left, right, pts, opts, predicted=guess)
    disparity = pts[:, 0] - pr[:, 0]
    ok &= np.abs(pr[:, 1] - pts[:, 1]) <= opts.stereo_max_dy_px
    ok &= (disparity >= opts.min_disparity_px) & (disparity <= fx * baseline_m / 0.5)
    return disparity.astype(float), ok
