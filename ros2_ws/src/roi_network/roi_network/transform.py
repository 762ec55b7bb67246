"""Rigid 2D transforms (rotation + translation, never a reflection).

``T = Rigid2D(yaw, tx, ty)`` maps a point ``p`` of its source frame to
``R(yaw) @ p + (tx, ty)`` in its target frame. Naming follows ROS: the transform that
takes ``odom`` coordinates to ``map`` coordinates is ``map_T_odom`` (the pose of ``odom``
in ``map``), and ``map_T_odom @ odom_T_base == map_T_base``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike


def wrap_angle(angle: float | np.ndarray) -> float | np.ndarray:
    """Wrap an angle (radians, scalar or array) to [-pi, pi)."""
    return (angle + np.pi) % (2.0 * np.pi) - np.pi


@dataclass(frozen=True)
class Rigid2D:
    """A proper rigid motion of the plane.

    Attributes:
        yaw: rotation angle, radians, counter-clockwise, wrapped to [-pi, pi).
        tx: translation along x, metres.
        ty: translation along y, metres.
    """

    yaw: float = 0.0
    tx: float = 0.0
    ty: float = 0.0

    def __post_init__(self) -> None:
        for name in ("yaw", "tx", "ty"):
            value = float(getattr(self, name))
            if not math.isfinite(value):
                raise ValueError(f"Rigid2D: field '{name}' is not finite ({value})")
            object.__setattr__(self, name, value)
        object.__setattr__(self, "yaw", wrap_angle(self.yaw))

    @classmethod
    def identity(cls) -> Rigid2D:
        """The identity transform."""
        return cls()

    @classmethod
    def from_matrix(cls, matrix: ArrayLike) -> Rigid2D:
        """Build from a 3x3 homogeneous (or 2x3) matrix whose 2x2 block is a rotation.

        Raises:
            ValueError: if the block is not a rotation (a reflection, a scale or a shear).
        """
        m = np.asarray(matrix, dtype=float)
        if m.shape not in ((3, 3), (2, 3)):
            raise ValueError(f"Rigid2D.from_matrix: expected a 3x3 or 2x3 matrix, got {m.shape}")
        r = m[:2, :2]
        if not np.allclose(r.T @ r, np.eye(2), atol=1e-6) or np.linalg.det(r) < 0:
            raise ValueError("Rigid2D.from_matrix: the 2x2 block is not a proper rotation")
        return cls(math.atan2(r[1, 0], r[0, 0]), m[0, 2], m[1, 2])

    @property
    def rotation(self) -> np.ndarray:
        """The 2x2 rotation matrix."""
        c, s = math.cos(self.yaw), math.sin(self.yaw)
        return np.array([[c, -s], [s, c]])

    @property
    def translation(self) -> np.ndarray:
        """The translation (tx, ty), metres."""
        return np.array([self.tx, self.ty])

    @property
    def matrix(self) -> np.ndarray:
        """The 3x3 homogeneous matrix."""
        m = np.eye(3)
        m[:2, :2] = self.rotation
        m[:2, 2] = self.translation
        return m

    def __matmul__(self, other: Rigid2D) -> Rigid2D:
        """Compose: ``(a @ b).apply(p) == a.apply(b.apply(p))``."""
        if not isinstance(other, Rigid2D):
            return NotImplemented
        tx, ty = self.apply(other.translation)
        return Rigid2D(self.yaw + other.yaw, tx, ty)

    def inverse(self) -> Rigid2D:
        """The inverse transform."""
        tx, ty = -(self.rotation.T @ self.translation)
        return Rigid2D(-self.yaw, tx, ty)

    def apply(self, points: ArrayLike) -> np.ndarray:
        """Transform points, shape (2,) or (N, 2), metres."""
        p = np.asarray(points, dtype=float)
        if p.shape[-1] != 2:
            raise ValueError(f"Rigid2D.apply: points must have shape (2,) or (N, 2), got {p.shape}")
        return p @ self.rotation.T + self.translation

    @classmethod
    def fit(
        cls, src: ArrayLike, dst: ArrayLike, weights: ArrayLike | None = None
    ) -> Rigid2D:
        """Weighted least-squares rigid transform with ``fit(src, dst).apply(src) ~ dst``.

        The closed-form Kabsch/Umeyama solution without scale; the rotation is forced
        proper (det = +1), so a mirrored point set gets the best rotation, never a
        reflection.

        Args:
            src: (N, 2) points in the source frame, N >= 2.
            dst: (N, 2) corresponding points in the target frame.
            weights: optional (N,) non-negative weights, not all zero.

        Raises:
            ValueError: on mismatched shapes, fewer than 2 points, bad weights, or
                coincident source points (rotation undetermined).
        """
        a = np.asarray(src, dtype=float)
        b = np.asarray(dst, dtype=float)
        if a.ndim != 2 or a.shape[1] != 2 or a.shape != b.shape:
            raise ValueError(f"Rigid2D.fit: src {a.shape} and dst {b.shape} must both be (N, 2)")
        if len(a) < 2:
            raise ValueError("Rigid2D.fit: need at least 2 correspondences")
        w = np.ones(len(a)) if weights is None else np.asarray(weights, dtype=float)
        if w.shape != (len(a),) or (w < 0).any() or not np.isfinite(w).all() or w.sum() <= 0:
            raise ValueError("Rigid2D.fit: weights must be (N,) finite, >= 0, not all zero")
        w = w / w.sum()
        ca, cb = w @ a, w @ b
        a0, b0 = a - ca, b - cb
        cov = (a0 * w[:, None]).T @ b0  # sum_i w_i a_i b_i^T
        # Rotation angle maximising sum w_i b_i . R a_i, in closed form for 2D; a proper
        # rotation by construction, so no reflection can come out of it.
        sin = cov[0, 1] - cov[1, 0]
        cos = cov[0, 0] + cov[1, 1]
        if math.hypot(sin, cos) < 1e-12 * max(1.0, float(np.abs(a0).max(initial=0.0)) ** 2):
            raise ValueError("Rigid2D.fit: source points coincide, rotation is undetermined")
        yaw = math.atan2(sin, cos)
        c, s = math.cos(yaw), math.sin(yaw)
        t = cb - np.array([[c, -s], [s, c]]) @ ca
        return cls(yaw, t[0], t[1])
