"""Whether one sensor_msgs/CameraInfo of a rectified stereo pair can be used (no rclpy).

Every consumer of the stereo topics (rover_vo, roi_detector, ``globloc rover-yaml``) checks
each CameraInfo with :func:`camera_info_problem` and names the field and its value the same
way (``K[0] (fx) = 0``), so that one bad calibration reads alike in every node's log.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: What the checked entries of K and P are.
K_NAMES = {0: "fx", 4: "fy"}
P_NAMES = {0: "fx", 3: "-fx * baseline", 5: "fy"}
#: Sizes of the matrices (D: any length).
SIZES = {"K": 9, "R": 9, "P": 12, "D": None}


def camera_info_problem(info: Any, side: str) -> str | None:
    """What makes one CameraInfo unusable, naming the field and its value
    (``K[0] (fx) = 0``), or None.

    Checked: width and height positive; K, R, P of 9, 9, 12 finite numbers, D finite;
    K's and P's focal lengths positive (a K of zeros, no calibration of the raw camera,
    is taken as rectified images described by P, as
    :func:`roi_network.images.describes_rectified` reads it); the right camera's
    ``P[3] = -fx * baseline`` negative (the right camera on the left one's +x).

    Args:
        info: sensor_msgs/CameraInfo (rosbags or rclpy: lower-case ``k``, ``d``, ...).
        side: ``left`` or ``right``.
    """
    if side not in ("left", "right"):
        raise ValueError(f"side must be 'left' or 'right', got {side!r}")
    for field in ("width", "height"):
        if int(getattr(info, field)) <= 0:
            return f"{field} = {getattr(info, field)}"
    values = {}
    for field, size in SIZES.items():
        try:
            v = np.asarray(getattr(info, field.lower()), dtype=float).ravel()
        except (TypeError, ValueError):
            return f"{field} is not a list of numbers"
        if size is not None and v.size != size:
            return f"{field} has {v.size} values, expected {size}"
        bad = np.flatnonzero(~np.isfinite(v))
        if bad.size:
            return f"{field}[{bad[0]}] = {v[bad[0]]}"
        values[field] = v
    K, P = values["K"], values["P"]
    if np.any(K):
        for i, name in K_NAMES.items():
            if not K[i] > 0:
                return f"K[{i}] ({name}) = {K[i]:g}"
    for i in (0, 5):
        if not P[i] > 0:
            return f"P[{i}] ({P_NAMES[i]}) = {P[i]:g}"
    if side == "right" and P[3] == 0:
        return f"P[3] ({P_NAMES[3]}) = 0: no baseline"
    if side == "right" and not P[3] < 0:
        return (f"P[3] ({P_NAMES[3]}) = {P[3]:g} > 0: the right camera sits left of the "
                "left one; are the left and right topics swapped?")
    return None
