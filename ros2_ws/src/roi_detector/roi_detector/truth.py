"""Ground truth for training and evaluation ONLY: no pipeline code path imports this.

Reads a bag directory's ``truth/rois.geojson`` (map) and ``truth/trajectory.tum``
(base_link in map), places truth ROIs in base_link at a stereo stamp, labels candidates
by DESIGN.md's matching rule, and re-expresses the truth trajectory in an odom frame that
starts at its first position and heading, gravity-aligned as rover_vo's odom is (the
"truth odometry" of the figures).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from roi_detector.inputs import PoseTrack, read_tum, write_tum
from roi_network.geojson import read_geojson
from roi_network.records import OUTCROP, ROCK, xy

#: Rover thresholds of the truth ROIs the recall counts (paper Sec. 4.2).
ROCK_MIN_AREA_M2, ROCK_MIN_HEIGHT_M, OUTCROP_MIN_AREA_M2 = 0.6, 0.25, 5.5


@dataclass
class Truth:
    """Truth ROIs (map) and the truth trajectory of one bag directory."""

    rois: np.ndarray
    trajectory: PoseTrack

    @classmethod
    def load(cls, bag_dir: str | Path) -> Truth:
        """Read ``truth/rois.geojson`` and ``truth/trajectory.tum``."""
        bag_dir = Path(bag_dir)
        return cls(read_geojson(bag_dir / "truth" / "rois.geojson").records,
                   read_tum(bag_dir / "truth" / "trajectory.tum", max_gap_s=5.0))

    def pose(self, t: float) -> tuple[np.ndarray, np.ndarray] | None:
        """(R_map_base, t_map_base) at ``t`` seconds, or None outside the trajectory."""
        p = self.trajectory.at(t)
        return None if p is None else (p[0], p[1])

    def base_to_map(self, t: float, points_base: np.ndarray) -> np.ndarray | None:
        """Map-frame points of (N, 3) base_link points at ``t``."""
        p = self.pose(t)
        return None if p is None else np.asarray(points_base) @ p[0].T + p[1]

    def above_thresholds(self) -> np.ndarray:
        """Boolean mask of truth ROIs above the rover thresholds."""
        r = self.rois
        rock = (r["label"] == ROCK) & (r["area_m2"] > ROCK_MIN_AREA_M2) & \
            (r["height_m"] > ROCK_MIN_HEIGHT_M)
        outcrop = (r["label"] == OUTCROP) & (r["area_m2"] > OUTCROP_MIN_AREA_M2)
        return rock | outcrop

    def counted(self, radius_m: float = 15.0) -> np.ndarray:
        """Boolean mask of the truth ROIs the recall counts: above the rover thresholds
        and within ``radius_m`` of the route."""
        return self.above_thresholds() & self.near_route(radius_m)

    def near_route(self, radius_m: float = 15.0) -> np.ndarray:
        """Boolean mask of truth ROIs within ``radius_m`` of the route (x-y)."""
        route = self.trajectory.p[:, :2]
        route = route[:: max(1, len(route) // 5000)]
        from scipy.spatial import cKDTree

        d, _ = cKDTree(route).query(xy(self.rois))
        return d <= radius_m

    def views(self, rover_params: dict, max_depth_m: float, step_m: float = 0.45,
              moved: list[tuple[float, np.ndarray]] = ()) -> np.ndarray:
        """Per truth ROI, the number of stereo pairs (one every ``step_m`` of the route,
        at the drive pose ``base_to_left_camera``; and each of ``moved``) whose left image
        holds its centre (0.2 m above the ground) at most ``max_depth_m`` deep: what the
        camera can see of it.

        Args:
            rover_params: the bag's rover.yaml parameters (``base_to_left_camera``,
                ``fx fy cx cy``, ``image_width``, ``image_height``).
            moved: ``(stamp s, base_T_left)`` of the pairs a mast took away from the
                drive pose (its panoramas; :func:`~roi_detector.camera_poses.moved_pair_poses`).
        """
        tr, r, p = self.trajectory, self.rois, rover_params
        e = np.asarray(p["base_to_left_camera"], float)
        r_bc, t_bc = Rotation.from_quat(e[3:]).as_matrix(), e[:3]
        travelled = np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(tr.p[:, :2], axis=0), axis=1))]
        idx = np.searchsorted(travelled, np.arange(0.0, travelled[-1], step_m))
        centres = np.column_stack([r["x"], r["y"], r["z"] + 0.2])
        count = np.zeros(len(r), int)

        def seen(r_mb, t_mb, r_bc, t_bc) -> np.ndarray:
            pc = ((centres - t_mb) @ r_mb - t_bc) @ r_bc
            z = pc[:, 2]
            with np.errstate(divide="ignore", invalid="ignore"):
                u = p["fx"] * pc[:, 0] / z + p["cx"]
                v = p["fy"] * pc[:, 1] / z + p["cy"]
            return (z > 0) & (z <= max_depth_m) & (u >= 0) & (u < p["image_width"]) & \
                (v >= 0) & (v < p["image_height"])

        for k in np.unique(np.clip(idx, 0, len(tr.p) - 1)):
            count += seen(Rotation.from_quat(tr.q[k]).as_matrix(), tr.p[k], r_bc, t_bc)
        for t, m in moved:
            pose = tr.at(t)
            if pose is not None:
                count += seen(pose[0], pose[1], m[:3, :3], m[:3, 3])
        return count

    def _odom_in_map(self) -> Rotation:
        """Rotation of odom in map: the first pose's heading only (odom is gravity-aligned,
        as rover_vo's is: z up, x along the first heading)."""
        yaw = Rotation.from_quat(self.trajectory.q[0]).as_euler("ZYX")[0]
        return Rotation.from_euler("z", yaw)

    def odom_track(self) -> PoseTrack:
        """The truth trajectory re-expressed in odom (origin at its first position)."""
        tr = self.trajectory
        r0 = self._odom_in_map()
        p = r0.inv().apply(tr.p - tr.p[0])
        q = (r0.inv() * Rotation.from_quat(tr.q)).as_quat()
        return PoseTrack(tr.t, p, q, max_gap_s=tr.max_gap_s)

    def write_odom_tum(self, path: str | Path) -> None:
        """Write :meth:`odom_track` as a TUM file (base_link in odom)."""
        o = self.odom_track()
        write_tum(path, o.t, o.p, o.q, "truth trajectory re-expressed in odom (first pose)")

    def odom_to_map(self, points_odom: np.ndarray) -> np.ndarray:
        """Map-frame (N, 3) of odom points (see :meth:`_odom_in_map`)."""
        return self._odom_in_map().apply(np.asarray(points_odom, float)) + self.trajectory.p[0]


def match_rule_radius(truth_major_m: np.ndarray) -> np.ndarray:
    """DESIGN.md: a detection matches a truth ROI within max(1 m, half its major axis)."""
    return np.maximum(1.0, 0.5 * np.asarray(truth_major_m, float))


def match_to_truth(xy_map: np.ndarray, truth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each (N, 2) map position, the index of the nearest truth ROI within the match
    radius (or -1) and the distance to it (m)."""
    if len(truth) == 0 or len(xy_map) == 0:
        return np.full(len(xy_map), -1), np.full(len(xy_map), np.inf)
    txy = xy(truth)
    d = np.linalg.norm(np.asarray(xy_map)[:, None, :2] - txy[None], axis=2)
    d_in = np.where(d <= match_rule_radius(truth["major_m"])[None], d, np.inf)
    j = np.argmin(d_in, axis=1)
    dist = d_in[np.arange(len(j)), j]
    return np.where(np.isfinite(dist), j, -1), np.where(np.isfinite(dist), dist, d.min(axis=1))
