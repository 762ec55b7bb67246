"""The stereo rig and IMU extrinsics: rectified intrinsics from CameraInfo, mounting from
``rover.yaml`` (never from truth).

Frames: ``base_link`` (x forward, y left, z up), the left camera's optical frame (z forward,
x right, y down), ``imu_link``. ``base_T_left`` maps left-camera coordinates into base_link.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation


class RigError(ValueError):
    """A CameraInfo or extrinsic parameter that cannot describe a rectified stereo rig."""


def pose_matrix(xyz_quat: Any, name: str) -> np.ndarray:
    """4x4 transform of ``[x, y, z, qx, qy, qz, qw]`` (metres, unit quaternion).

    Raises:
        RigError: not 7 finite numbers, or a zero quaternion.
    """
    v = np.asarray(xyz_quat, dtype=float).ravel()
    if v.size != 7 or not np.all(np.isfinite(v)) or np.linalg.norm(v[3:]) < 1e-9:
        raise RigError(f"parameter '{name}': expected [x, y, z, qx, qy, qz, qw], got {xyz_quat!r}")
    T = np.eye(4)
    T[:3, :3] = Rotation.from_quat(v[3:]).as_matrix()
    T[:3, 3] = v[:3]
    return T


@dataclass(frozen=True)
class StereoRig:
    """A rectified stereo pair on the rover body.

    Attributes:
        fx, fy, cx, cy: rectified left intrinsics (px).
        baseline_m: right camera centre on the left camera's +x axis (m).
        width, height: image size (px).
        base_T_left: 4x4, left optical frame -> base_link.
        base_R_imu: 3x3, imu_link -> base_link.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    baseline_m: float
    width: int
    height: int
    base_T_left: np.ndarray
    base_R_imu: np.ndarray

    @property
    def camera_matrix(self) -> np.ndarray:
        """3x3 camera matrix (px)."""
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])


#: What the entries of a CameraInfo's K and P are, for the messages.
_K_NAMES = {0: "fx", 2: "cx", 4: "fy", 5: "cy"}
_P_NAMES = {0: "fx", 2: "cx", 3: "-fx * baseline", 5: "fy", 6: "cy"}


def _entries(info: Any, field: str, size: int | None) -> tuple[np.ndarray | None, str | None]:
    try:
        v = np.asarray(getattr(info, field.lower()), dtype=float).ravel()
    except (TypeError, ValueError):
        return None, f"{field} is not a list of numbers"
    if size is not None and v.size != size:
        return None, f"{field} has {v.size} values, expected {size}"
    bad = np.flatnonzero(~np.isfinite(v))
    if bad.size:
        return None, f"{field}[{bad[0]}] = {v[bad[0]]}"
    return v, None


def camera_info_problem(info: Any, side: str) -> str | None:
    """What makes one CameraInfo unusable, naming the field and its value
    (``K[0] (fx) = 0``), or None.

    Checked: width and height positive; K, R, P of 9, 9, 12 finite numbers, D finite;
    K's and P's focal lengths positive (a K of zeros, no calibration, is taken as
    rectified images described by P); the right camera's ``P[3] = -fx * baseline``
    negative.

    Args:
        info: sensor_msgs/CameraInfo (rosbags or rclpy).
        side: ``left`` or ``right``.
    """
    for field in ("width", "height"):
        if int(getattr(info, field)) <= 0:
            return f"{field} = {getattr(info, field)}"
    values = {}
    for field, size in (("K", 9), ("R", 9), ("P", 12), ("D", None)):
        v, problem = _entries(info, field, size)
        if problem is not None:
            return problem
        values[field] = v
    K, P = values["K"], values["P"]
    if np.any(K):
        for i in (0, 4):
            if not K[i] > 0:
                return f"K[{i}] ({_K_NAMES[i]}) = {K[i]:g}"
    for i in (0, 5):
        if not P[i] > 0:
            return f"P[{i}] ({_P_NAMES[i]}) = {P[i]:g}"
    if side == "right" and not P[3] < 0:
        return (f"P[3] ({_P_NAMES[3]}) = {P[3]:g}: expected < 0 for the right camera of a "
                "rectified pair")
    return None


def rig_from_camera_info(left_info: Any, right_info: Any, params: dict[str, Any]) -> StereoRig:
    """Build the rig from the two CameraInfo messages and the ``rover.yaml`` parameters.

    Args:
        left_info, right_info: sensor_msgs/CameraInfo (rosbags or rclpy objects), rectified:
            the right P has ``P[3] = -fx * baseline``.
        params: flat parameters; needs ``base_to_left_camera``, optional ``base_to_imu``.

    Raises:
        RigError: a field that does not describe a rectified pair (named in the message).
    """
    P_l = np.asarray(left_info.p, dtype=float).ravel()
    P_r = np.asarray(right_info.p, dtype=float).ravel()
    if P_l.size != 12 or P_r.size != 12:
        raise RigError("camera_info: field 'p' must hold 12 numbers")
    fx, fy, cx, cy = P_l[0], P_l[5], P_l[2], P_l[6]
    if not (np.all(np.isfinite(P_l)) and fx > 0 and fy > 0):
        raise RigError(f"/stereo/left/camera_info: field 'p' has no valid focal length: {P_l}")
    if not (np.isfinite(P_r[3]) and P_r[0] > 0):
        raise RigError(f"/stereo/right/camera_info: field 'p' is not valid: {P_r}")
    baseline = -P_r[3] / P_r[0]
    if not baseline > 0:
        raise RigError(f"/stereo/right/camera_info: P[3] = {P_r[3]} gives baseline {baseline} m"
                       " (expected P[3] = -fx * baseline < 0)")
    if "base_to_left_camera" not in params:
        raise RigError("parameter 'base_to_left_camera' is not set (the bag's rover.yaml)")
    base_T_left = pose_matrix(params["base_to_left_camera"], "base_to_left_camera")
    base_T_imu = pose_matrix(params.get("base_to_imu", [0, 0, 0, 0, 0, 0, 1]), "base_to_imu")
    return StereoRig(float(fx), float(fy), float(cx), float(cy), float(baseline),
                     int(left_info.width), int(left_info.height), base_T_left,
                     base_T_imu[:3, :3])
