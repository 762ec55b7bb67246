"""Zero-velocity detection at stops (OpenVINS ``UpdaterZeroVelocity``, detector part).

The rover stands still when the corners of the last image have not moved in the new one
(median displacement under a fraction of a pixel, tracked from their old position) and,
with an IMU, the bias-corrected gyro stayed quiet over the interval. Vision
decides because a rover driving at constant speed on smooth ground has a quiet IMU too.
"""

from __future__ import annotations

import numpy as np

from rover_vo.config import ImuOptions
from rover_vo.features import track
from rover_vo.propagator import ImuInterval


def image_motion_px(prev: np.ndarray, curr: np.ndarray, pts: np.ndarray,
                    max_points: int = 120) -> float:
    """Median displacement (px) of up to ``max_points`` corners tracked with no prediction.

    Returns inf when fewer than half of them track.
    """
    if len(pts) == 0:
        return float("inf")
    step = max(1, len(pts) // max_points)
    sub = pts[::step]
    moved, ok = track(prev, curr, sub)
    if ok.sum() < max(5, len(sub) // 2):
        return float("inf")
    return float(np.median(np.linalg.norm(moved[ok] - sub[ok], axis=1)))


def is_stationary(flow_px: float, imu: ImuInterval | None, opts: ImuOptions) -> bool:
    """Standing still: the image did not move, and the gyro (``imu``, None without one)
    was quiet."""
    if not flow_px < opts.zero_velocity_flow_px:
        return False
    if imu is not None:
        return imu.max_rate < opts.zero_velocity_gyro_rad_s
    return True
