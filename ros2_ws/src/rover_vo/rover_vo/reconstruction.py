"""3D reconstruction of stereo corners (paper Sec. 3: 3D reconstruction).

Rectified pair: a left corner (u, v) with disparity d = u_left - u_right lies at depth
Z = fx * B / d on the left optical axis (left optical frame: z forward, x right, y down).
"""

from __future__ import annotations

import numpy as np


def triangulate_disparity(uv: np.ndarray, disparity: np.ndarray, fx: float, fy: float,
                          cx: float, cy: float, baseline_m: float) -> np.ndarray:
    """Left optical frame points (m) of corners ``uv`` (N, 2) px with ``disparity`` (N,) px."""
    z = fx * baseline_m / disparity
    x = (uv[:, 0] - cx) * z / fx
    y = (uv[:, 1] - cy) * z / fy
    return np.column_stack([x, y, z])


def ground_disparity(v: np.ndarray, fy: float, cy: float, camera_height_m: float,
                     tilt_rad: float, fx: float, baseline_m: float,
                     far_disparity_px: float = 3.0) -> np.ndarray:
    """Disparity (px) of flat ground seen in image row ``v``: the stereo search's start.

    A camera ``camera_height_m`` above flat ground, optical axis ``tilt_rad`` below the
    horizon. Rows at or above the horizon get ``far_disparity_px``.
    """
    # Angle of the row's ray below the horizon.
    below = tilt_rad + np.arctan((v - cy) / fy)
    below = np.maximum(below, 1e-3)
    # Depth along the optical axis of the ground point on that ray.
    rng = camera_height_m / np.sin(below)
    z = rng * np.cos(below - tilt_rad)
    return np.where(below > 2e-3, np.maximum(fx * baseline_m / z, far_disparity_px),
                    far_disparity_px)
