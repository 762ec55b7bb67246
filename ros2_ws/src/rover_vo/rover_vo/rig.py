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
