"""Where a camera on a pan-tilt mast points: the one place that knows.

A rover's stereo head sits on a mast with a pan joint (about base_link's z) and a tilt joint
(about the pan link's y), as on MER, Curiosity and Perseverance. ``rover.yaml`` states the
kinematics as a URDF states its joints, each joint's origin in its parent link at zero angle
and its axis (:class:`MastKinematics`, parameters ``mast.*``); ``/joint_states``
(sensor_msgs/JointState) gives the angles over time. :class:`CameraPoser` keeps the joint
history and answers the left camera's pose in base_link at an image's stamp, interpolating
linearly between the joint samples that bracket it; a stamp further than
``tolerance_s`` from every usable sample gets no pose, with the reason.

A rover without a mast (``mast.pan_joint`` empty) has one fixed camera pose,
``base_to_left_camera``; :class:`CameraPoser` then answers that pose at every stamp and
needs no joint states. Consumers (rover_vo, roi_detector) never assume either case.

Poses are 4x4 homogeneous matrices ``base_T_left`` (left optical frame in base_link: the
matrix maps optical-frame points to base_link). The right camera of the rectified pair is
the left one moved ``baseline_m`` along the left camera's +x.

Method (docs/roi_network.md):
  1. compose the chain ``base_T_pan0 @ R(pan_axis, pan) @ pan_T_tilt0 @ R(tilt_axis, tilt)
     @ tilt_T_left`` (:meth:`MastKinematics.base_T_left`);
  2. keep the joint samples in stamp order (:meth:`CameraPoser.add`);
  3. at an image stamp, interpolate the angles between the bracketing samples when both are
     within the tolerance, else take the nearest one within it (:meth:`CameraPoser.pose_at`).
"""

from __future__ import annotations

import bisect
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

#: Default tolerance between an image stamp and the joint samples used for it, s: one
#: period of a 10 Hz joint-state stream (the simulator also writes a sample at every image).
JOINT_STATE_TOLERANCE_S = 0.1
#: Joint samples kept (at 10 Hz: 100 s of history; images arrive in stamp order).
HISTORY = 1000
#: Joint angles may exceed their limits by this much before a sample is refused, rad.
LIMIT_SLACK_RAD = 1e-3

#: ``rover.yaml`` parameter names of the mast, in the order written.
MAST_PARAMS = ("mast.pan_joint", "mast.pan_origin", "mast.pan_axis", "mast.pan_limits",
               "mast.tilt_joint", "mast.tilt_origin", "mast.tilt_axis", "mast.tilt_limits",
               "mast.head_to_left_camera")


class MastError(ValueError):
    """The mast's parameters or joint states are unusable; the message names the field."""


def pose_matrix(pose: Sequence[float], name: str) -> np.ndarray:
    """4x4 matrix of a ``[x, y, z, qx, qy, qz, qw]`` pose; ``name`` is named in errors."""
    p = np.asarray(pose, dtype=float).ravel()
    if p.shape != (7,) or not np.all(np.isfinite(p)):
        raise MastError(f"rover.yaml: field '{name}' must be 7 finite numbers "
                        f"[x, y, z, qx, qy, qz, qw], got {list(np.asarray(pose).ravel())}")
    n = float(np.linalg.norm(p[3:]))
    if n < 1e-9:
        raise MastError(f"rover.yaml: field '{name}' has a zero quaternion")
    m = np.eye(4)
    m[:3, :3] = Rotation.from_quat(p[3:] / n).as_matrix()
    m[:3, 3] = p[:3]
    return m


def pose_list(m: np.ndarray) -> list[float]:
    """``[x, y, z, qx, qy, qz, qw]`` of a 4x4 pose matrix (inverse of :func:`pose_matrix`)."""
    q = Rotation.from_matrix(np.asarray(m)[:3, :3]).as_quat()
    return [float(v) for v in np.asarray(m)[:3, 3]] + [float(v) for v in q]


def _axis(v: Sequence[float], name: str) -> np.ndarray:
    a = np.asarray(v, dtype=float).ravel()
    if a.shape != (3,) or not np.all(np.isfinite(a)) or np.linalg.norm(a) < 1e-9:
        raise MastError(f"rover.yaml: field '{name}' must be a non-zero 3-vector, got "
                        f"{list(np.asarray(v).ravel())}")
    return a / np.linalg.norm(a)


def _limits(v: Sequence[float], name: str) -> tuple[float, float]:
    a = np.asarray(v, dtype=float).ravel()
    if a.shape != (2,) or not np.all(np.isfinite(a)) or a[0] > a[1]:
        raise MastError(f"rover.yaml: field '{name}' must be [lower, upper] rad with "
                        f"lower <= upper, got {list(np.asarray(v).ravel())}")
    return float(a[0]), float(a[1])


def _rot(axis: np.ndarray, angle: float) -> np.ndarray:
    m = np.eye(4)
    m[:3, :3] = Rotation.from_rotvec(axis * angle).as_matrix()
    return m


@dataclass(frozen=True)
class MastKinematics:
    """A pan-tilt mast as URDF states it: two revolute joints and the stereo head.

    Attributes:
        pan_joint: name of the pan joint in ``/joint_states``.
        pan_origin: 4x4 pose of the pan joint frame in base_link at zero angle.
        pan_axis: unit rotation axis of the pan joint, in its own frame.
        pan_limits: ``(lower, upper)`` pan angle, rad.
        tilt_joint: name of the tilt joint in ``/joint_states``.
        tilt_origin: 4x4 pose of the tilt joint frame in the pan link at zero angle.
        tilt_axis: unit rotation axis of the tilt joint, in its own frame.
        tilt_limits: ``(lower, upper)`` tilt angle, rad.
        head_to_left_camera: 4x4 pose of the left optical frame in the tilt link.
    """

    pan_joint: str
    pan_origin: np.ndarray
    pan_axis: np.ndarray
    pan_limits: tuple[float, float]
    tilt_joint: str
    tilt_origin: np.ndarray
    tilt_axis: np.ndarray
    tilt_limits: tuple[float, float]
    head_to_left_camera: np.ndarray

    @property
    def joints(self) -> tuple[str, str]:
        """The joint names, pan first."""
        return self.pan_joint, self.tilt_joint

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> MastKinematics | None:
        """The mast of flattened ``rover.yaml`` parameters (``mast.pan_joint`` ...), or
        None when the rover has no mast (``mast.pan_joint`` absent or empty).

        Raises:
            MastError: naming the first missing or malformed field.
        """
        if not params.get("mast.pan_joint"):
            return None
        missing = [k for k in MAST_PARAMS if k not in params]
        if missing:
            raise MastError(f"rover.yaml: mast.pan_joint is set but {', '.join(missing)} "
                            f"{'is' if len(missing) == 1 else 'are'} missing")
        pan, tilt = str(params["mast.pan_joint"]), str(params["mast.tilt_joint"])
        if not tilt or tilt == pan:
            raise MastError(f"rover.yaml: field 'mast.tilt_joint' must name a joint other "
                            f"than the pan joint '{pan}', got '{tilt}'")
        return cls(pan, pose_matrix(params["mast.pan_origin"], "mast.pan_origin"),
                   _axis(params["mast.pan_axis"], "mast.pan_axis"),
                   _limits(params["mast.pan_limits"], "mast.pan_limits"),
                   tilt, pose_matrix(params["mast.tilt_origin"], "mast.tilt_origin"),
                   _axis(params["mast.tilt_axis"], "mast.tilt_axis"),
                   _limits(params["mast.tilt_limits"], "mast.tilt_limits"),
                   pose_matrix(params["mast.head_to_left_camera"], "mast.head_to_left_camera"))

    def to_params(self) -> dict[str, Any]:
        """The flattened ``rover.yaml`` parameters of this mast (inverse of
        :meth:`from_params`)."""
        return {
            "mast.pan_joint": self.pan_joint,
            "mast.pan_origin": pose_list(self.pan_origin),
            "mast.pan_axis": [float(v) for v in self.pan_axis],
            "mast.pan_limits": [float(v) for v in self.pan_limits],
            "mast.tilt_joint": self.tilt_joint,
            "mast.tilt_origin": pose_list(self.tilt_origin),
            "mast.tilt_axis": [float(v) for v in self.tilt_axis],
            "mast.tilt_limits": [float(v) for v in self.tilt_limits],
            "mast.head_to_left_camera": pose_list(self.head_to_left_camera),
        }

    def within_limits(self, pan: float, tilt: float) -> bool:
        """Whether both angles lie inside their limits (with :data:`LIMIT_SLACK_RAD`)."""
        lo, hi = self.pan_limits
        tlo, thi = self.tilt_limits
        return (lo - LIMIT_SLACK_RAD <= pan <= hi + LIMIT_SLACK_RAD
                and tlo - LIMIT_SLACK_RAD <= tilt <= thi + LIMIT_SLACK_RAD)

    def base_T_left(self, pan: float, tilt: float) -> np.ndarray:  # noqa: N802 (frame name)
        """4x4 pose of the left optical frame in base_link at joint angles (rad)
        (method step 1)."""
        return (self.pan_origin @ _rot(self.pan_axis, pan) @ self.tilt_origin
                @ _rot(self.tilt_axis, tilt) @ self.head_to_left_camera)


@dataclass(frozen=True)
class CameraPose:
    """The left camera's pose in base_link at one stamp.

    Attributes:
        base_T_left: 4x4 pose of the left optical frame in base_link.
        joints: the interpolated ``(pan, tilt)`` angles, rad; None for a fixed camera.
    """

    base_T_left: np.ndarray
    joints: tuple[float, float] | None = None


#: Why :meth:`CameraPoser.pose_at` gave no pose.
NO_JOINT_STATES = "no_joint_states"  # none has come yet
STALE_JOINT_STATES = "stale_joint_states"  # the nearest is further than the tolerance


class CameraPoser:
    """The left camera's pose in base_link at an image's stamp, from ``/joint_states``.

    Feed every JointState with :meth:`add` (in any order; out-of-order samples are
    inserted), ask with :meth:`pose_at`. With no mast (``kinematics`` None) every stamp gets
    ``fixed``. Counts of refused frames by reason are in :attr:`misses`.

    Args:
        kinematics: the mast, or None for a fixed camera.
        fixed: 4x4 ``base_T_left`` of a fixed camera (``base_to_left_camera``); required
            when ``kinematics`` is None.
        tolerance_s: largest gap between an image stamp and a joint sample used for it, s.
    """

    def __init__(self, kinematics: MastKinematics | None, fixed: np.ndarray | None = None,
                 tolerance_s: float = JOINT_STATE_TOLERANCE_S) -> None:
        if kinematics is None and fixed is None:
            raise MastError("CameraPoser: a rover without a mast needs base_to_left_camera")
        if not (math.isfinite(tolerance_s) and tolerance_s > 0):
            raise MastError(f"CameraPoser: tolerance_s must be positive, got {tolerance_s}")
        self.kinematics = kinematics
        self.fixed = None if fixed is None else np.asarray(fixed, float)
        self.tolerance_s = float(tolerance_s)
        self._t: list[float] = []
        self._q: list[tuple[float, float]] = []
        self.misses: dict[str, int] = {NO_JOINT_STATES: 0, STALE_JOINT_STATES: 0}
        self.samples = 0

    @classmethod
    def from_params(cls, params: Mapping[str, Any],
                    tolerance_s: float = JOINT_STATE_TOLERANCE_S) -> CameraPoser:
        """The poser of flattened ``rover.yaml`` parameters: the mast when ``mast.pan_joint``
        is set, else the fixed ``base_to_left_camera``.

        Raises:
            MastError: naming the missing or malformed field.
        """
        kin = MastKinematics.from_params(params)
        fixed = None
        if "base_to_left_camera" in params and any(params["base_to_left_camera"][3:]):
            fixed = pose_matrix(params["base_to_left_camera"], "base_to_left_camera")
        if kin is None and fixed is None:
            raise MastError("rover.yaml: neither 'mast.pan_joint' nor 'base_to_left_camera' "
                            "is set: the camera's pose in base_link is unknown")
        return cls(kin, fixed, tolerance_s)

    @property
    def has_mast(self) -> bool:
        """Whether the camera moves on joints (needs ``/joint_states``)."""
        return self.kinematics is not None

    @property
    def last_stamp(self) -> float | None:
        """Stamp of the newest joint sample, s (None before the first)."""
        return self._t[-1] if self._t else None

    def add(self, stamp_s: float, names: Sequence[str], positions: Sequence[float]) -> None:
        """Keep one JointState (method step 2). Joints other than the mast's are ignored
        when the message also carries the mast's.

        Raises:
            MastError: the message lacks a mast joint (naming the names it has), a position
                is missing or not finite, or an angle is outside its limits.
        """
        if self.kinematics is None:
            return
        names = list(names)
        kin = self.kinematics
        absent = [j for j in kin.joints if j not in names]
        if absent:
            raise MastError(f"/joint_states: joint {' and '.join(repr(a) for a in absent)} "
                            f"of rover.yaml's mast not in the message's names "
                            f"{names} (field 'name')")
        if len(positions) < len(names):
            raise MastError(f"/joint_states: field 'position' has {len(positions)} values "
                            f"for {len(names)} names")
        pan = float(positions[names.index(kin.pan_joint)])
        tilt = float(positions[names.index(kin.tilt_joint)])
        if not (math.isfinite(pan) and math.isfinite(tilt)):
            raise MastError(f"/joint_states: field 'position' is not finite "
                            f"({kin.pan_joint}={pan}, {kin.tilt_joint}={tilt})")
        if not kin.within_limits(pan, tilt):
            raise MastError(f"/joint_states: {kin.pan_joint}={pan:.4f} rad or "
                            f"{kin.tilt_joint}={tilt:.4f} rad outside rover.yaml's limits "
                            f"{kin.pan_limits} and {kin.tilt_limits} (field 'position')")
        t = float(stamp_s)
        i = bisect.bisect_right(self._t, t)
        if i > 0 and self._t[i - 1] == t:
            self._q[i - 1] = (pan, tilt)
        else:
            self._t.insert(i, t)
            self._q.insert(i, (pan, tilt))
        if len(self._t) > HISTORY:
            del self._t[: len(self._t) - HISTORY]
            del self._q[: len(self._q) - HISTORY]
        self.samples += 1

    def joints_at(self, stamp_s: float) -> tuple[float, float] | str:
        """Interpolated ``(pan, tilt)`` at ``stamp_s``, or the reason there is none
        (:data:`NO_JOINT_STATES`, :data:`STALE_JOINT_STATES`) (method step 3)."""
        if not self._t:
            return NO_JOINT_STATES
        t = float(stamp_s)
        tol = self.tolerance_s
        i = bisect.bisect_left(self._t, t)
        before = i - 1 if i > 0 else None
        after = i if i < len(self._t) else None
        if after is not None and self._t[after] == t:
            return self._q[after]
        ok_b = before is not None and t - self._t[before] <= tol
        ok_a = after is not None and self._t[after] - t <= tol
        if ok_b and ok_a:
            t0, t1 = self._t[before], self._t[after]
            w = (t - t0) / (t1 - t0)
            (p0, q0), (p1, q1) = self._q[before], self._q[after]
            return p0 + w * (p1 - p0), q0 + w * (q1 - q0)
        if ok_b or ok_a:
            return self._q[before if ok_b else after]
        return STALE_JOINT_STATES

    def pose_at(self, stamp_s: float) -> CameraPose | str:
        """The left camera's pose in base_link at ``stamp_s``, or the reason there is none;
        a miss is counted in :attr:`misses`."""
        if self.kinematics is None:
            return CameraPose(self.fixed)
        q = self.joints_at(stamp_s)
        if isinstance(q, str):
            self.misses[q] += 1
            return q
        return CameraPose(self.kinematics.base_T_left(*q), q)


def same_pose(a: np.ndarray, b: np.ndarray, rot_tol_rad: float = 1e-3,
              trans_tol_m: float = 1e-3) -> bool:
    """Whether two 4x4 camera poses agree within the tolerances (a mast at rest)."""
    da = Rotation.from_matrix(np.asarray(a)[:3, :3].T @ np.asarray(b)[:3, :3]).magnitude()
    return bool(da <= rot_tol_rad and
                np.linalg.norm(np.asarray(a)[:3, 3] - np.asarray(b)[:3, 3]) <= trans_tol_m)
