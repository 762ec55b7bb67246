"""The mast's motion over the traverse: the drive pose, and a stereo panorama at each stop.

While the rover drives, and at its first and last standstill, the mast holds the drive
pose (pan 0, ``CameraConfig.tilt_deg``). At every stop between two drive segments, once
the body is still (:data:`STILL_S` after the wheels stop), the mast slews through the pan
positions of :func:`pan_angles` at ``MastConfig.tilt_deg``, taking a stereo pair at each
after ``settle_s``, and returns to the drive pose; the rover drives on :data:`STILL_S`
after that (:func:`panorama_stop_s` is the shortest such stop). Both joints move together
at constant speed (at most ``slew_deg_s``) between grid samples, so every event falls on
the trajectory's time grid: the joint angles of any sample are exact, not interpolated.

Method (docs/simulator.md, step 2):
  1. the pan positions spread evenly over the span, right to left (:func:`pan_angles`);
  2. the moves and settles of one panorama in grid samples (:func:`panorama_knots`);
  3. a panorama at each stop between drive segments, the joint angles and rates on the
     grid, the samples where the mast is away from the drive pose (:func:`mast_motion`).
"""

from __future__ import annotations

import itertools
import math
from dataclasses import dataclass, field

import numpy as np

from atacama_sim.camera import drive_angles, mast_kinematics
from atacama_sim.config import CameraConfig, MastConfig
from atacama_sim.route import Trajectory

#: Wait after the wheels stop before the mast moves, and after it is back before the
#: wheels turn, s (the body's suspension low-pass settles in 3 sigma = 1.2 s).
STILL_S = 2.0


def pan_angles(mast: MastConfig, cam: CameraConfig) -> np.ndarray:
    """Pan angles of a panorama's pairs in the order taken, rad (method step 1): the
    centres of as few equal sectors of the span as keep ``overlap_deg`` between
    neighbouring views, symmetric about straight ahead, from right (negative) to left; a
    360 deg span stays clear of the +-180 deg stops.

    Raises:
        ValueError: naming ``mast.overlap_deg`` or ``mast.span_deg`` when the overlap is
            not less than the field of view or the span is not within (0, 360] deg.
    """
    if not 0 < mast.span_deg <= 360:
        raise ValueError(f"mast.span_deg must be in (0, 360], got {mast.span_deg}")
    if not 0 <= mast.overlap_deg < cam.hfov_deg:
        raise ValueError(f"mast.overlap_deg must be at least 0 and less than the "
                         f"{cam.hfov_deg} deg field of view, got {mast.overlap_deg}")
    n = max(1, math.ceil(mast.span_deg / (cam.hfov_deg - mast.overlap_deg) - 1e-9))
    step = mast.span_deg / n
    return np.radians(-mast.span_deg / 2 + step / 2 + step * np.arange(n))


def _samples(seconds: float, rate: float) -> int:
    return math.ceil(seconds * rate - 1e-9)


def panorama_knots(mast: MastConfig, cam: CameraConfig, rate: float,
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One panorama from the drive pose back to it, in samples from its start (method
    step 2): knot sample offsets (the joints move linearly between knots), pan and tilt at
    the knots (rad), and the sample offset of each pair."""
    drive = drive_angles(cam)
    tilt = float(np.radians(mast.tilt_deg))
    slew = float(np.radians(mast.slew_deg_s))
    if not slew > 0:
        raise ValueError(f"mast.slew_deg_s must be positive, got {mast.slew_deg_s}")
    settle = max(1, _samples(mast.settle_s, rate))
    k, (pan0, tilt0) = 0, drive
    ks, pans, tilts, pairs = [0], [pan0], [tilt0], []
    targets = [(float(a), tilt) for a in pan_angles(mast, cam)] + [drive]
    for i, (p, t) in enumerate(targets):
        k += max(1, _samples(max(abs(p - pan0), abs(t - tilt0)) / slew, rate))
        ks.append(k)
        pans.append(p)
        tilts.append(t)
        k += settle
        ks.append(k)
        pans.append(p)
        tilts.append(t)
        if i < len(targets) - 1:
            pairs.append(k)
        pan0, tilt0 = p, t
    return np.array(ks), np.array(pans), np.array(tilts), np.array(pairs)


def panorama_s(mast: MastConfig, cam: CameraConfig, rate: float) -> float:
    """Duration of one panorama, from the mast leaving the drive pose to it settled back
    there, s."""
    return float(panorama_knots(mast, cam, rate)[0][-1] / rate)


def panorama_stop_s(mast: MastConfig, cam: CameraConfig, rate: float) -> float:
    """The shortest stop that holds a panorama (0 without panoramas), s: the panorama,
    :data:`STILL_S` before and after, one sample of slack."""
    if not mast.panoramas:
        return 0.0
    return panorama_s(mast, cam, rate) + 2 * STILL_S + 2.0 / rate


@dataclass
class Panorama:
    """One panorama on the grid.

    Attributes:
        start: sample where the mast leaves the drive pose.
        end: sample where it has settled back at the drive pose.
        frames: samples of the stereo pairs, in the order taken.
        pan: pan angle of each pair, rad.
    """

    start: int
    end: int
    frames: np.ndarray
    pan: np.ndarray


@dataclass
class MastMotion:
    """The joints over the traverse, on the trajectory's grid.

    Attributes:
        pan: (K,) pan angle, rad.
        tilt: (K,) tilt angle, rad.
        pan_rate: (K,) pan rate over the step ending at each sample, rad/s.
        tilt_rate: (K,) tilt rate, rad/s.
        busy: (K,) the mast is away from the drive pose (no ordinary frames).
        panoramas: every panorama, in time order.
    """

    pan: np.ndarray
    tilt: np.ndarray
    pan_rate: np.ndarray
    tilt_rate: np.ndarray
    busy: np.ndarray
    panoramas: list[Panorama] = field(default_factory=list)

    @property
    def frames(self) -> np.ndarray:
        """Samples of every panorama pair, in time order."""
        if not self.panoramas:
            return np.zeros(0, int)
        return np.concatenate([p.frames for p in self.panoramas]).astype(int)


def stops(traj: Trajectory) -> list[tuple[int, int]]:
    """``(first, last)`` sample of every standstill between two drive segments."""
    mov = np.asarray(traj.moving, bool)
    edges = np.flatnonzero(np.diff(mov.astype(np.int8)))
    out = []
    for a, b in itertools.pairwise(edges):
        if mov[a] and not mov[a + 1]:  # moving -> stopped at a + 1, drives again at b + 1
            out.append((int(a + 1), int(b)))
    return out


def mast_motion(traj: Trajectory, mast: MastConfig, cam: CameraConfig,
                rate: float) -> MastMotion:
    """The joints over ``traj`` with a panorama at each stop between drive segments, or
    none when ``mast.panoramas`` is off (method step 3).

    Raises:
        ValueError: a stop shorter than :func:`panorama_stop_s` (the trajectory was driven
            without it as ``min_stop_s``).
    """
    n = len(traj.t)
    drive = drive_angles(cam)
    kin = mast_kinematics(cam)
    knots_k, knots_p, knots_t = [0], [drive[0]], [drive[1]]
    pans: list[Panorama] = []
    if mast.panoramas:
        ks, kp, kt, pairs = panorama_knots(mast, cam, rate)
        if not (kin.within_limits(float(kp.min()), float(kt.min()))
                and kin.within_limits(float(kp.max()), float(kt.max()))):
            raise ValueError(f"mast.tilt_deg {mast.tilt_deg} or the pan span is outside "
                             f"the mast's limits (pan {kin.pan_limits}, tilt "
                             f"{kin.tilt_limits} rad)")
        still = _samples(STILL_S, rate)
        for first, last in stops(traj):
            k0 = first + still
            if k0 + ks[-1] + still > last:
                raise ValueError(f"the stop at t={traj.t[first]:.1f} s lasts "
                                 f"{(last - first + 1) / rate:.1f} s, shorter than a "
                                 f"panorama's {panorama_stop_s(mast, cam, rate):.1f} s")
            knots_k += list(k0 + ks)
            knots_p += list(kp)
            knots_t += list(kt)
            pans.append(Panorama(int(k0), int(k0 + ks[-1]), k0 + pairs,
                                 np.asarray(kp[2:-2:2], float)))
    knots_k.append(n - 1)
    knots_p.append(drive[0])
    knots_t.append(drive[1])
    kk = np.asarray(knots_k, float)
    grid = np.arange(n)
    pan = np.interp(grid, kk, knots_p)
    tilt = np.interp(grid, kk, knots_t)
    pan_rate, tilt_rate = np.zeros(n), np.zeros(n)
    pan_rate[1:] = np.diff(pan) * rate
    tilt_rate[1:] = np.diff(tilt) * rate
    busy = np.zeros(n, bool)
    for p in pans:
        busy[p.start:p.end + 1] = True
    return MastMotion(pan, tilt, pan_rate, tilt_rate, busy, pans)
