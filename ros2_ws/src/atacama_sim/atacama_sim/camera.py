"""Pinhole stereo camera model on a pan-tilt mast: intrinsics, projection, and the mast.

Frames: ``base_link`` (x forward, y left, z up, origin on the ground plane under the rover
centre), optical camera frames (z forward, x right, y down). The right camera is the left
one shifted by the baseline along the left camera's +x (rectified pair: same rotation).

The pair rides on a pan-tilt mast (:func:`mast_kinematics`): a pan joint about base_link's
z at ``(mast_x_m, 0, mast_height_m - PAN_TO_TILT_M)``, a tilt joint ``PAN_TO_TILT_M`` above
it about the pan link's y (positive looks down), the left optical frame ``baseline_m / 2``
along the tilt link's +y. Every camera pose is ``roi_network.mast.MastKinematics.base_T_left``
of the joint angles; at the drive angles (pan 0, tilt ``tilt_deg``) it is the camera that
``CameraConfig`` describes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from atacama_sim.config import CameraConfig
from roi_network.mast import MastKinematics

#: Height of the tilt joint above the pan joint, m (the head sits on the pan link).
PAN_TO_TILT_M = 0.24
#: Pan joint limits, rad: all around, the cable wrap stops at +-180 deg.
PAN_LIMITS = (-np.pi, np.pi)
#: Tilt joint limits, rad (positive looks down): 29 deg up to 69 deg down.
TILT_LIMITS = (-0.5, 1.2)
#: Joint names in ``/joint_states``, rover.yaml's ``mast.*`` and the URDF.
PAN_JOINT = "mast_pan"
TILT_JOINT = "mast_tilt"
#: The optical frame in the tilt link at zero angles: z forward (link x), x right (link -y),
#: y down (link -z).
LINK_T_OPTICAL = np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])


def mast_kinematics(cfg: CameraConfig) -> MastKinematics:
    """The pan-tilt mast carrying the pair, as ``rover.yaml``'s ``mast.*`` states it."""
    pan_origin = np.eye(4)
    pan_origin[:3, 3] = [cfg.mast_x_m, 0.0, cfg.mast_height_m - PAN_TO_TILT_M]
    tilt_origin = np.eye(4)
    tilt_origin[2, 3] = PAN_TO_TILT_M
    head = np.eye(4)
    head[:3, :3] = LINK_T_OPTICAL
    head[1, 3] = cfg.baseline_m / 2
    return MastKinematics(PAN_JOINT, pan_origin, np.array([0.0, 0.0, 1.0]), PAN_LIMITS,
                          TILT_JOINT, tilt_origin, np.array([0.0, 1.0, 0.0]), TILT_LIMITS,
                          head)


def drive_angles(cfg: CameraConfig) -> tuple[float, float]:
    """Pan and tilt of the drive pose, rad: straight ahead, ``tilt_deg`` down."""
    return 0.0, float(np.radians(cfg.tilt_deg))


@dataclass(frozen=True)
class StereoRig:
    """Intrinsics of the rectified pair, and its extrinsics at the mast's drive pose
    (``R_base_cam``, ``t_base_left``; other poses: ``base_T_left`` of
    :meth:`camera_pose`)."""

    width: int
    height: int
    fx: float
    fy: float
    cx: float
    cy: float
    baseline: float
    R_base_cam: np.ndarray  # (3, 3): optical axes expressed in base_link
    t_base_left: np.ndarray  # (3,): left optical centre in base_link

    @classmethod
    def from_config(cls, cfg: CameraConfig) -> StereoRig:
        fx = (cfg.width / 2) / np.tan(np.radians(cfg.hfov_deg) / 2)
        drive = mast_kinematics(cfg).base_T_left(*drive_angles(cfg))
        return cls(cfg.width, cfg.height, float(fx), float(fx), (cfg.width - 1) / 2,
                   (cfg.height - 1) / 2, cfg.baseline_m, drive[:3, :3], drive[:3, 3])

    @property
    def K(self) -> np.ndarray:  # noqa: N802 (the conventional name)
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    @property
    def t_base_right(self) -> np.ndarray:
        return self.t_base_left + self.R_base_cam[:, 0] * self.baseline

    def camera_pose(self, R_wb: np.ndarray, t_wb: np.ndarray, right: bool = False,
                    base_T_left: np.ndarray | None = None,
                    ) -> tuple[np.ndarray, np.ndarray]:
        """World pose (R_wc, centre) of the left (or right) optical frame, the left camera
        at ``base_T_left`` (4x4 in base_link, from the mast's joint angles) or at the
        drive pose."""
        if base_T_left is None:
            r_bc, t_bc = self.R_base_cam, self.t_base_left
        else:
            r_bc, t_bc = base_T_left[:3, :3], base_T_left[:3, 3]
        if right:
            t_bc = t_bc + r_bc[:, 0] * self.baseline
        return R_wb @ r_bc, t_wb + R_wb @ t_bc

    def project(self, R_wc: np.ndarray, c_w: np.ndarray,
                pts_w: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pixel coordinates (N, 2) and depth Z (N,) of world points (N, 3)."""
        pc = (np.asarray(pts_w) - c_w) @ R_wc
        z = pc[:, 2]
        u = self.fx * pc[:, 0] / z + self.cx
        v = self.fy * pc[:, 1] / z + self.cy
        return np.column_stack([u, v]), z

    def gl_projection(self, near: float, far: float) -> np.ndarray:
        """OpenGL clip matrix of optical-frame points, so that fragment centres fall on
        OpenCV pixel centres (u, v) after flipping the read-back rows."""
        w, h = self.width, self.height
        return np.array([
            [2 * self.fx / w, 0, 2 * (self.cx + 0.5) / w - 1, 0],
            [0, -2 * self.fy / h, 1 - 2 * (self.cy + 0.5) / h, 0],
            [0, 0, (far + near) / (far - near), -2 * far * near / (far - near)],
            [0, 0, 1, 0]])


def quat_xyzw(R: np.ndarray) -> np.ndarray:
    """Quaternion (x, y, z, w) of a rotation matrix."""
    return Rotation.from_matrix(R).as_quat()
