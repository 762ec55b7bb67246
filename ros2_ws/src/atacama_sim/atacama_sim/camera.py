"""Pinhole stereo camera model: intrinsics, mast extrinsics, projection.

Frames: ``base_link`` (x forward, y left, z up, origin on the ground plane under the rover
centre), optical camera frames (z forward, x right, y down). The right camera is the left
one shifted by the baseline along the left camera's +x (rectified pair: same rotation).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from atacama_sim.config import CameraConfig


@dataclass(frozen=True)
class StereoRig:
    """Intrinsics and extrinsics of the rectified pair."""

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
        th = np.radians(cfg.tilt_deg)
        z = np.array([np.cos(th), 0.0, -np.sin(th)])  # optical axis, tilted down
        x = np.array([0.0, -1.0, 0.0])  # image right = rover right
        y = np.cross(z, x)  # image down
        r = np.column_stack([x, y, z])
        t = np.array([cfg.mast_x_m, cfg.baseline_m / 2, cfg.mast_height_m])
        return cls(cfg.width, cfg.height, float(fx), float(fx), (cfg.width - 1) / 2,
                   (cfg.height - 1) / 2, cfg.baseline_m, r, t)

    @property
    def K(self) -> np.ndarray:  # noqa: N802 (the conventional name)
        return np.array([[self.fx, 0, self.cx], [0, self.fy, self.cy], [0, 0, 1.0]])

    @property
    def t_base_right(self) -> np.ndarray:
        return self.t_base_left + self.R_base_cam[:, 0] * self.baseline

    def camera_pose(self, R_wb: np.ndarray, t_wb: np.ndarray,
                    right: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """World pose (R_wc, centre) of the left (or right) optical frame."""
        t_bc = self.t_base_right if right else self.t_base_left
        return R_wb @ self.R_base_cam, t_wb + R_wb @ t_bc

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
