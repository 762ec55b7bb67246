"""Incremental global localization from successive matches of a growing LN (no rclpy).

The matcher node re-matches the LN each time it grows. :class:`AlignmentTracker` decides
what each new match does to the published alignment ``map_T_odom``:

- no alignment yet: a fix becomes the alignment (``first_fix``);
- a fix consistent with the alignment (every LN node lands within ``consistency_m`` of
  where the alignment puts it) refines it (``refined``);
- a fix that contradicts it replaces it only if it is at least as well supported as the
  alignment was (``switched``); a weaker contradicting fix is reported (``conflict``) and
  the alignment is kept;
- no fix keeps the alignment (``kept``), or leaves the rover unlocalized (``none``).

:func:`compose_pose` then maps each odometry pose into ``map`` with the alignment and
propagates both covariances.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from scipy.spatial.transform import Rotation

from darces_matcher.matcher import MatchResult
from roi_network.transform import Rigid2D

Event = Literal["first_fix", "refined", "switched", "conflict", "kept", "none"]


@dataclass(frozen=True)
class Alignment:
    """The published map -> odom alignment.

    Attributes:
        map_T_odom: pose of ``odom`` in ``map``.
        covariance: (3, 3) covariance of (x, y, yaw), m^2 / rad^2.
        support: LN nodes matched when it was fitted.
        ln_size: LN nodes at that time.
    """

    map_T_odom: Rigid2D
    covariance: np.ndarray
    support: int
    ln_size: int


class AlignmentTracker:
    """Keeps the current alignment across re-matches of a growing LN.

    Args:
        consistency_m: two fixes agree when they place every LN node within this
            distance of each other, metres.
    """

    def __init__(self, consistency_m: float = 5.0) -> None:
        self.consistency_m = consistency_m
        self.alignment: Alignment | None = None
        self.switches = 0

    def update(self, result: MatchResult, ln_xy: np.ndarray) -> Event:
        """Fold one match result of the LN whose node positions (odom) are ``ln_xy``."""
        if not result.is_fix or result.map_T_odom is None:
            return "kept" if self.alignment else "none"
        new = Alignment(result.map_T_odom, result.covariance, result.support, len(ln_xy))
        if self.alignment is None:
            self.alignment = new
            return "first_fix"
        gap = np.linalg.norm(
            new.map_T_odom.apply(ln_xy) - self.alignment.map_T_odom.apply(ln_xy), axis=1
        )
        if gap.max(initial=0.0) <= self.consistency_m:
            self.alignment = new
            return "refined"
        if new.support >= self.alignment.support:
            self.alignment = new
            self.switches += 1
            return "switched"
        return "conflict"


def yaw_quaternion(yaw: float) -> np.ndarray:
    """Quaternion (x, y, z, w) of a rotation by ``yaw`` radians about z."""
    return np.array([0.0, 0.0, np.sin(yaw / 2.0), np.cos(yaw / 2.0)])


def compose_pose(
    alignment: Alignment,
    position: np.ndarray,
    quaternion: np.ndarray,
    covariance: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map an odometry pose (odom -> base_link) into ``map``.

    Args:
        alignment: the map -> odom alignment (2D: x, y, yaw).
        position: (3,) base_link position in ``odom``, metres.
        quaternion: (4,) orientation (x, y, z, w) in ``odom``.
        covariance: (6, 6) odometry pose covariance (x, y, z, roll, pitch, yaw), in odom.

    Returns:
        Position (3,), quaternion (4,) and (6, 6) covariance in ``map``. The covariance
        adds the alignment's (x, y, yaw) uncertainty, propagated through the lever arm
        of the position in ``odom``, to the odometry covariance rotated into ``map``.
    """
    t = alignment.map_T_odom
    xy = t.apply(np.asarray(position[:2], dtype=float))
    pos = np.array([xy[0], xy[1], float(position[2])])
    rot = Rotation.from_quat(yaw_quaternion(t.yaw)) * Rotation.from_quat(quaternion)
    # Odometry covariance: position block rotated by yaw (z, angles unchanged to first
    # order for a rotation about z).
    r6 = np.eye(6)
    r6[:2, :2] = t.rotation
    cov = r6 @ np.asarray(covariance, dtype=float).reshape(6, 6) @ r6.T
    # Alignment covariance: d(map xy)/d(tx, ty, yaw) = [I, dR/dyaw @ p_odom].
    p = np.asarray(position[:2], dtype=float)
    dr = np.array([[-np.sin(t.yaw), -np.cos(t.yaw)], [np.cos(t.yaw), -np.sin(t.yaw)]])
    jac = np.zeros((6, 3))
    jac[:2, :2] = np.eye(2)
    jac[:2, 2] = dr @ p
    jac[5, 2] = 1.0  # map yaw = alignment yaw + odom yaw
    cov += jac @ alignment.covariance @ jac.T
    return pos, rot.as_quat(), cov
