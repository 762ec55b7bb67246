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

#: The image is cut into GRID_COLS x GRID_ROWS cells, each given an equal share of the
#: corners.
GRID_COLS, GRID_ROWS = 8, 6
#: Shi-Tomasi threshold, relative to the best corner of a cell.
QUALITY_LEVEL = 0.005
#: Minimum spacing between corners (px).
MIN_DISTANCE_PX = 12.0
#: Lucas-Kanade window side (px) and pyramid levels above the full image.
LK_WINDOW_PX, LK_LEVELS = 15, 3
#: Lucas-Kanade stops after this many iterations per level, or once the update is under
#: LK_EPSILON_PX (px).
LK_ITERATIONS, LK_EPSILON_PX = 10, 0.03
#: Forward-backward consistency bound of a track (px).
FB_MAX_PX = 0.5
#: A stereo match may lie this far off its rectified row (px).
STEREO_MAX_DY_PX = 1.0
#: Smaller disparities (farther points) are not matched (px).
MIN_DISPARITY_PX = 1.0

LK = {"winSize": (LK_WINDOW_PX, LK_WINDOW_PX), "maxLevel": LK_LEVELS,
      "criteria": (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, LK_ITERATIONS,
                   LK_EPSILON_PX)}


def _shape(image) -> tuple[int, int]:
    return (image[0] if isinstance(image, list | tuple) else image).shape[:2]


def detect_corners(image: np.ndarray, max_corners: int) -> np.ndarray:
    """Shi-Tomasi corners spread over a grid.

    Args:
        image: 8-bit grey image.
        max_corners: corners at most, shared equally by the grid's cells.

    Returns:
        (M, 2) float32 corners (px).
    """
    h, w = image.shape
    per_cell = max(1, max_corners // (GRID_COLS * GRID_ROWS))
    out = []
    # A per-cell budget keeps corners spread over the image: clustered corners constrain
    # rotation poorly and all vanish together when the rover turns.
    for r in range(GRID_ROWS):
        for c in range(GRID_COLS):
            y0, y1 = r * h // GRID_ROWS, (r + 1) * h // GRID_ROWS
            x0, x1 = c * w // GRID_COLS, (c + 1) * w // GRID_COLS
            pts = cv2.goodFeaturesToTrack(image[y0:y1, x0:x1], per_cell, QUALITY_LEVEL,
                                          MIN_DISTANCE_PX, blockSize=5)
            if pts is not None:
                out.append(pts.reshape(-1, 2) + np.array([x0, y0], np.float32))
    if not out:
        return np.zeros((0, 2), np.float32)
    pts = np.concatenate(out).astype(np.float32)
    # Sub-pixel corner positions: the drift budget (0.5 %) is spent in tenths of pixels.
    cv2.cornerSubPix(image, pts.reshape(-1, 1, 2), (4, 4), (-1, -1),
                     (cv2.TERM_CRITERIA_EPS | cv2.TERM_CRITERIA_COUNT, 20, 0.01))
    return pts


def track(prev: np.ndarray, curr: np.ndarray, pts: np.ndarray,
          predicted: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Pyramidal Lucas-Kanade from ``prev`` to ``curr`` with a forward-backward check.

    Args:
        prev, curr: 8-bit grey images.
        pts: (N, 2) corners in ``prev`` (px).
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
    p1, st1, _ = cv2.calcOpticalFlowPyrLK(prev, curr, p0, p1, flags=flags, **LK)
    back = p0.copy()
    p0b, st2, _ = cv2.calcOpticalFlowPyrLK(curr, prev, p1, back,
                                           flags=cv2.OPTFLOW_USE_INITIAL_FLOW, **LK)
    p1, p0b = p1.reshape(-1, 2), p0b.reshape(-1, 2)
    h, w = _shape(curr)
    ok = (st1.ravel() == 1) & (st2.ravel() == 1)
    ok &= np.linalg.norm(p0b - pts, axis=1) < FB_MAX_PX
    ok &= (p1[:, 0] >= 0) & (p1[:, 0] <= w - 1) & (p1[:, 1] >= 0) & (p1[:, 1] <= h - 1)
    return p1, ok


def stereo_match(left: np.ndarray, right: np.ndarray, pts: np.ndarray, fx: float,
                 baseline_m: float,
                 disparity_guess: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Match left corners in the rectified right image (same row, smaller u).

    The search starts at ``disparity_guess`` (default: a point 5 m ahead) and LK follows
    the row; matches off the row by more than ``STEREO_MAX_DY_PX`` or with a disparity
    outside ``[MIN_DISPARITY_PX, fx * baseline / 0.5 m]`` are rejected.

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
    pr, ok = track(left, right, pts, predicted=guess)
    disparity = pts[:, 0] - pr[:, 0]
    ok &= np.abs(pr[:, 1] - pts[:, 1]) <= STEREO_MAX_DY_PX
    ok &= (disparity >= MIN_DISPARITY_PX) & (disparity <= fx * baseline_m / 0.5)
    return disparity.astype(float), ok
