"""The rover half of Sec. 4-5, one stereo pair at a time: detect, classify, track, LN.

``RoverDetector.detect`` turns a stereo pair into classified detections in base_link;
``DriveMapper.add_pair`` places them in odom with the odometry pose of the pair, tracks
them and keeps the Local Network up to date. The offline CLI and the two nodes call
exactly these (the nodes split them: roi_detector runs detect + track, ln_builder the LN).
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field

import cv2
import numpy as np

from roi_detector.inputs import StereoFrame
from roi_detector.local_network import LnConfig, LocalNetwork
from roi_detector.rover_candidates import (
    Candidate,
    RoverThresholds,
    metric_images,
    rover_candidates,
)
from roi_detector.rover_classifier import RoverClassifier
from roi_detector.stereo import StereoCamera, StereoConfig, disparity, points_base
from roi_detector.tracking import (
    Observation,
    Tracker,
    TrackerConfig,
    observation_covariance,
    tracks_to_records,
)
from roi_network.records import empty_records


@dataclass(frozen=True)
class RoverConfig:
    """Every parameter of the rover pipeline, defaults in one place."""

    stereo: StereoConfig = field(default_factory=StereoConfig)
    thresholds: RoverThresholds = field(default_factory=RoverThresholds)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    ln: LnConfig = field(default_factory=LnConfig)
    outcrops: bool = True


class RoverDetector:
    """Stereo pair -> classified candidates (base_link).

    Args:
        base_to_left_camera: rover.yaml extrinsic ``[x, y, z, qx, qy, qz, qw]``.
        classifier: the Rock Rover / Outcrop Rover classifiers; None keeps every
            candidate with its proposed class (score 1).
        cfg: pipeline configuration.
        on_bad: bad-input counter, called as ``on_bad(kind, detail)``.
    """

    def __init__(self, base_to_left_camera, classifier: RoverClassifier | None,
                 cfg: RoverConfig = RoverConfig(), on_bad=None) -> None:
        self.extrinsic = list(base_to_left_camera)
        self.classifier = classifier
        self.cfg = cfg
        self.on_bad = on_bad or (lambda kind, detail: None)
        self.camera: StereoCamera | None = None
        self._rays = None
        self._key = None

    def _camera(self, frame: StereoFrame) -> StereoCamera:
        h, w = frame.left.shape[:2]
        key = (tuple(np.round(frame.left_k, 6)), tuple(np.round(frame.right_p, 6)), w, h)
        if key != self._key:
            self.camera = StereoCamera.from_camera_info(frame.left_k, frame.right_p, w, h,
                                                        self.extrinsic)
            self._rays = self.camera.rays_base()
            self._key = key
        return self.camera

    def candidates(self, frame: StereoFrame) -> tuple[list[Candidate], dict | None]:
        """Candidates above the rover thresholds (unclassified) and the metric images."""
        camera = self._camera(frame)
        left = cv2.cvtColor(frame.left, cv2.COLOR_BGR2GRAY)
        right = cv2.cvtColor(frame.right, cv2.COLOR_BGR2GRAY)
        metrics = metric_images(left, 0.5)
        # Candidates are found and measured on a half-resolution grid of the stereo
        # points, the grid of the metric images: 4x fewer pixels, and a rover ROI still
        # covers tens to thousands. The disparities come from the full-resolution pair
        # (downscale 1) or, 8x cheaper, from the half-resolution pair (downscale 2;
        # disparities doubled back to full-resolution pixels).
        st = self.cfg.stereo
        if st.downscale == 2:
            right_s = cv2.resize(right, (metrics["_gray"].shape[1], metrics["_gray"].shape[0]),
                                 interpolation=cv2.INTER_AREA)
            half = dataclasses.replace(st, num_disparities=max(16, st.num_disparities // 32 * 16))
            disp = 2.0 * disparity(metrics["_gray"], right_s, half)
        else:
            disp = disparity(left, right, st)[::2, ::2]
        points = points_base(disp, camera, self._rays[::2, ::2], st.max_range_m)
        cands = rover_candidates(
            metrics["_gray"], points, camera, self.cfg.thresholds,
            metrics if self.cfg.outcrops else None,
            on_no_depth=lambda: self.on_bad(
                "no valid depth", f"a candidate at {frame.stamp_ns * 1e-9:.3f} s has too "
                "few stereo points"), metrics_for_rocks=metrics)
        return cands, metrics

    def detect(self, frame: StereoFrame) -> list[Candidate]:
        """Classified detections of one pair (candidates the classifiers accept)."""
        cands, metrics = self.candidates(frame)
        if self.classifier is None or not cands:
            for c in cands:
                c.score = 1.0
            return cands
        return self.classifier.classify(frame.left, cands, metrics)


def detections_to_records(dets: list[Candidate]) -> np.ndarray:
    """ROI records (base_link) of detections; covariance: the stereo range error along
    the line of sight and the lateral error across it (base_link x-y)."""
    rec = empty_records(len(dets))
    tcfg = TrackerConfig()
    for i, d in enumerate(dets):
        cov = observation_covariance(d.bearing, d.range_sigma_m, d.major_m, tcfg)
        r = rec[i]
        r["x"], r["y"], r["z"] = d.center
        r["id"], r["label"] = i + 1, d.label
        r["area_m2"], r["height_m"] = d.area_m2, d.height_m
        r["major_m"], r["minor_m"], r["angle_rad"] = d.major_m, d.minor_m, d.angle_rad
        r["score"] = d.score
        r["cov_xx"], r["cov_xy"], r["cov_yy"] = cov[0, 0], cov[0, 1], cov[1, 1]
        r["n_obs"] = 1
    return rec


def observations_in_odom(records_base: np.ndarray, t: float, r_odom_base: np.ndarray,
                         t_odom_base: np.ndarray, odom_cov_xy: np.ndarray | None,
                         camera_xy_base: np.ndarray) -> list[Observation]:
    """Detection records (base_link) placed in odom with the pair's odometry pose.

    The stereo covariance is rebuilt in odom from each record's base_link covariance
    (rotated by the pose's yaw); the odometry x-y covariance at the stamp rides along.
    """
    yaw = float(np.arctan2(r_odom_base[1, 0], r_odom_base[0, 0]))
    c, s = np.cos(yaw), np.sin(yaw)
    rot2 = np.array([[c, -s], [s, c]])
    ocov = np.zeros((2, 2)) if odom_cov_xy is None else np.asarray(odom_cov_xy, float)
    out = []
    for r in records_base:
        p = r_odom_base @ np.array([r["x"], r["y"], r["z"]]) + t_odom_base
        cov_b = np.array([[r["cov_xx"], r["cov_xy"]], [r["cov_xy"], r["cov_yy"]]], float)
        a = max(float(r["major_m"]), 1e-3) / 4
        b = max(float(r["minor_m"]), 1e-3) / 4
        ca, sa = np.cos(r["angle_rad"] + yaw), np.sin(r["angle_rad"] + yaw)
        u = np.array([[ca, -sa], [sa, ca]])
        moments = u @ np.diag([a * a, b * b]) @ u.T
        out.append(Observation(t, p[:2], float(p[2]), rot2 @ cov_b @ rot2.T, ocov,
                               int(r["label"]), float(r["score"]), float(r["area_m2"]),
                               float(r["height_m"]), moments))
    return out


class DriveMapper:
    """Tracks and Local Network of a drive, fed pair by pair (odom)."""

    def __init__(self, cfg: RoverConfig = RoverConfig(), ln: LocalNetwork | None = None) -> None:
        self.cfg = cfg
        self.tracker = Tracker(cfg.tracker)
        self.ln = ln if ln is not None else LocalNetwork(cfg.ln)

    def add_detections(self, records_base: np.ndarray, t: float, pose,
                       camera: StereoCamera | None = None) -> np.ndarray:
        """Track one pair's detections; ``pose`` = (R_odom_base, t_odom_base, xy cov or
        None). With the pair's ``camera``, tracks in its view that it did not detect count
        a miss. Returns the track records (odom) the detector stands behind (consistent
        tracks, see :meth:`Tracker.consistent`)."""
        r_ob, t_ob, cov = pose
        obs = observations_in_odom(records_base, t, r_ob, t_ob, cov, np.zeros(2))
        self.tracker.update(obs)
        if not obs:
            self.tracker._pair_t = t
        if camera is not None:
            max_range = self.cfg.stereo.max_range_m

            def in_view(xy_odom: np.ndarray) -> bool:
                p = (np.array([xy_odom[0], xy_odom[1], t_ob[2]]) - t_ob) @ r_ob
                p[2] = 0.0  # on the ground plane of base_link
                uv, z = camera.project_base(p[None])
                return bool(2.5 < z[0] < 0.8 * max_range and 0 <= uv[0, 0] < camera.width
                            and 0 <= uv[0, 1] < camera.height)

            self.tracker.mark_missed(in_view)
        return tracks_to_records(self.tracker.consistent())

    def update_ln(self) -> bool:
        """Feed the consistent tracks to the LN; True if the LN changed."""
        return self.ln.update(tracks_to_records(self.tracker.consistent()))
