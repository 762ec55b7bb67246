"""The reference frame ("keyframe") a frame's motion is measured from.

The last frame becomes the next reference once the rover moved or turned far enough from
the current one (``window`` options): a camera that streams measures its frames against
one a few frames back, so the pose error grows per reference, not per frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rover_vo.features import detect_corners, stereo_match
from rover_vo.reconstruction import ground_disparity, triangulate_disparity
from rover_vo.rig import StereoRig
from rover_vo.state import OdomState


@dataclass
class Keyframe:
    """A stereo frame with triangulated corners and where they are tracked now.

    Attributes:
        state: odometry state of the frame (pose, covariance).
        points: (N, 3) corners triangulated in the keyframe's left optical frame (m).
        corners: (N, 2) their pixels in the keyframe's left image.
        tracked: (N, 2) their pixels in the last processed image.
        alive: (N,) bool, still tracked.
        image: the keyframe's left image.
        frames: frames measured against this keyframe so far.
        base_T_left: 4x4 pose of the left camera in base_link when the keyframe was taken
            (a mast moves it; a frame is measured against the keyframe only at this pose).
    """

    state: OdomState
    image: np.ndarray
    points: np.ndarray
    corners: np.ndarray
    tracked: np.ndarray
    alive: np.ndarray
    frames: int = 0
    base_T_left: np.ndarray | None = None

    @property
    def n_alive(self) -> int:
        return int(self.alive.sum())


def tilt_of(rig: StereoRig) -> tuple[float, float]:
    """Camera height above base_link (m) and optical-axis tilt below its x-y plane (rad)."""
    z_axis = rig.base_T_left[:3, 2]
    return float(rig.base_T_left[2, 3]), float(np.arcsin(-z_axis[2]))


def make_keyframe(state: OdomState, left: np.ndarray, right: np.ndarray,
                  rig: StereoRig, max_corners: int, max_depth_m: float
                  ) -> tuple[Keyframe, int, int]:
    """Detect, stereo-match and triangulate the corners of a new keyframe.

    Args:
        state: the keyframe's odometry state.
        left, right: the pair's images.
        rig: the stereo rig, with the camera's pose at this frame (``base_T_left``).
        max_corners: corners detected at most.
        max_depth_m: points farther than this (m) are not kept.

    Returns:
        ``(keyframe, corners detected, stereo matches kept)``.
    """
    corners = detect_corners(left, max_corners)
    h_cam, tilt = tilt_of(rig)
    # Start each stereo search at flat ground's disparity for its row: most corners are
    # on the ground, and LK converges from a few pixels away.
    guess = ground_disparity(corners[:, 1], rig.fy, rig.cy, h_cam, tilt, rig.fx,
                             rig.baseline_m) if len(corners) else np.zeros(0)
    disparity, ok = stereo_match(left, right, corners, rig.fx, rig.baseline_m, guess)
    pts = triangulate_disparity(corners[ok], disparity[ok], rig.fx, rig.fy, rig.cx, rig.cy,
                                rig.baseline_m)
    near = pts[:, 2] < max_depth_m
    kept = corners[ok][near]
    kf = Keyframe(state.copy(), left, pts[near], kept, kept.copy(), np.ones(len(kept), bool),
                  base_T_left=rig.base_T_left)
    return kf, len(corners), int(near.sum())
