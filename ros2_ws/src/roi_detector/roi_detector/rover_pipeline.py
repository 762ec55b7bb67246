"""The rover half of Sec. 4-5, one stereo pair at a time: detect, classify, track, LN.

Two methods (``RoverConfig.method``):

- ``"elevation_map"`` (default): ``RoverDetector.observe`` turns a stereo pair into its
  3D points and colour; ``DriveMapper.add_pair`` fuses them into the drive's elevation
  map in odom with the pair's odometry pose, where rocks and outcrops are found and kept
  (:mod:`roi_detector.elevation_map`). The pair's dark blobs are also tracked and
  triangulated from the rover's motion, for the rocks beyond the map's reach
  (:mod:`roi_detector.far_rocks`). The rover model's Rock Rovers and Outcrop Rover
  decide which of the map's regions and far rocks are ROIs.
- ``"per_pair"`` (the paper's baseline): ``observe`` detects and classifies ROIs in the
  pair (base_link; PCA + kNN); ``add_pair`` places them in odom and tracks them across
  pairs.

Either way ``DriveMapper`` keeps the Local Network up to date. The offline build
(:mod:`roi_detector.local_network_build`) and the two nodes call exactly these (the nodes
split them: roi_detector runs observe + add_pair, ln_builder the LN). The rover model
they run is loaded and checked against the configuration here (:func:`load_classifier`).

Steps (docs/roi_detector.md, Method): 1 pair spacing (inputs.PairSpacing, before
``observe``), 2 stereo points, 3 integration, 4-9 ground, rock regions, map rocks' Rock
Rover, outcrop regions, map outcrops' Outcrop Rover, persistence (ElevationMap.detect),
10 dark blobs, 11-14 tracks, triangulation, measurement and geometry, far rocks' Rock
Rover (FarRocks.add, FarRocks.rocks), 15 LN nodes.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import cv2
import numpy as np

from roi_detector.elevation_map import (
    MAP_OUTCROP_RULE,
    ElevationMap,
    ElevationMapConfig,
    appearance,
    is_monochrome,
)
from roi_detector.far_rocks import MERGE_M as FAR_MERGE_M
from roi_detector.far_rocks import (
    Blob,
    FarRock,
    FarRockConfig,
    FarRockTracker,
    dark_blobs,
)
from roi_detector.inputs import StereoFrame
from roi_detector.local_network import LnConfig, LocalNetwork
from roi_detector.rover_candidates import (
    Candidate,
    RoverThresholds,
    metric_images,
    rover_candidates,
)
from roi_detector.rover_classifier import RoverClassifier
from roi_detector.stereo import (
    StereoCamera,
    StereoConfig,
    disparity,
    mask_depth_edges,
    points_base,
)
from roi_detector.tracking import (
    Observation,
    Tracker,
    TrackerConfig,
    observation_covariance,
    tracks_to_records,
)
from roi_network.records import ROCK, empty_records


@dataclass(frozen=True)
class RoverConfig:
    """Every parameter of the rover pipeline a user tunes, defaults in one place.

    Attributes:
        method: ``"elevation_map"`` (ROIs found in the drive's fused height map, with the
            far rocks triangulated beyond it; the rover model's Rock Rovers and Outcrop
            Rover decide them) or ``"per_pair"`` (the paper's: ROIs detected and
            classified per stereo pair, PCA + kNN, then tracked).
        working_fx_px: the angular resolution the detector works at, as a focal length
            (pixels per radian at the image centre): a rectified pair whose left focal
            length is finer is resampled to it (:func:`at_working_resolution`), one
            coarser is used as it is; 0 keeps every pair as it comes. The pixel
            parameters and the committed Rock Rovers are set at the simulator's 640 x
            480, 70 deg camera (fx 457 px); a rover model records the value it was
            trained at.
        elevation_map: the elevation map's parameters (elevation_map method).
        far: the far rocks' parameters (elevation_map method).
        stereo: the stereo matcher's parameters.
        thresholds: the rover candidate thresholds (per_pair method).
        tracker: the tracker's parameters (per_pair method).
        ln: the Local Network's parameters.
    """

    method: str = "elevation_map"
    working_fx_px: float = 460.0
    elevation_map: ElevationMapConfig = field(default_factory=ElevationMapConfig)
    far: FarRockConfig = field(default_factory=FarRockConfig)
    stereo: StereoConfig = field(default_factory=StereoConfig)
    thresholds: RoverThresholds = field(default_factory=RoverThresholds)
    tracker: TrackerConfig = field(default_factory=TrackerConfig)
    ln: LnConfig = field(default_factory=LnConfig)


METHODS = ("elevation_map", "per_pair")
#: A pair is resampled only when its focal length exceeds the working one by more than
#: this factor (the simulator's 457 px camera stays as it is under the default 460).
RESAMPLE_ABOVE = 1.02
#: The depth-edge test on the grid the elevation map integrates (half resolution,
#: :func:`~roi_detector.stereo.mask_depth_edges`): a point is dropped where the
#: disparities in a window this wide (pixels) span more than EDGE_MAX_RELATIVE_RANGE of
#: its own (an occlusion edge). Not applied by the per-pair method.
EDGE_WINDOW_PX = 3
EDGE_MAX_RELATIVE_RANGE = 0.15


def at_working_resolution(frame: StereoFrame, working_fx_px: float) -> StereoFrame:
    """``frame`` resampled (area averaging) so that its left focal length is
    ``working_fx_px``, with its calibration scaled to match (``K`` and ``P`` by the
    pixel-centre convention of ``cv2.resize``: x' = (x + 0.5) s - 0.5); the frame itself
    when it is no finer than that (or ``working_fx_px`` is 0). The pair stays rectified:
    both images are scaled alike, and the right projection's ``fx * baseline`` with them.
    """
    fx = float(frame.left_k[0])
    if working_fx_px <= 0 or fx <= RESAMPLE_ABOVE * working_fx_px:
        return frame
    h, w = frame.left.shape[:2]
    size = (max(1, round(w * working_fx_px / fx)), max(1, round(h * working_fx_px / fx)))
    sx, sy = size[0] / w, size[1] / h
    scale = np.array([[sx, 0.0, 0.5 * sx - 0.5], [0.0, sy, 0.5 * sy - 0.5], [0.0, 0.0, 1.0]])
    k = scale @ np.asarray(frame.left_k, float).reshape(3, 3)
    p = scale @ np.asarray(frame.right_p, float).reshape(3, 4)
    return StereoFrame(frame.stamp_ns,
                       cv2.resize(frame.left, size, interpolation=cv2.INTER_AREA),
                       cv2.resize(frame.right, size, interpolation=cv2.INTER_AREA),
                       k.ravel(), p.ravel())


@dataclass
class PairObservation:
    """What one stereo pair contributes (base_link).

    Attributes:
        records: per_pair method: the pair's classified detections (ROI records).
        points: elevation_map method: (H/2, W/2, 3) stereo points, NaN where invalid.
        appearance: elevation_map method: (H/2, W/2, 2) relative saturation and value.
        blobs: elevation_map method: the pair's dark blobs.
    """

    records: np.ndarray | None = None
    points: np.ndarray | None = None
    appearance: np.ndarray | None = None
    blobs: list[Blob] | None = None


#: Camera poses whose rays in base_link the detector keeps (a mast's drive pose and a
#: panorama's positions; a fixed camera has one).
POSE_CACHE = 12


class RoverDetector:
    """Stereo pair -> classified candidates (base_link).

    Each pair is read at its left camera's pose in base_link: the fixed
    ``base_to_left_camera``, or the ``base_t_left`` its caller gives (a mast's pose at the
    pair's stamp, :class:`~roi_detector.camera_poses.PairPoses`). The camera model and its
    rays in base_link are kept per pose (:data:`POSE_CACHE` of them) and computed when a
    pose comes that is not kept.

    Args:
        base_to_left_camera: rover.yaml extrinsic ``[x, y, z, qx, qy, qz, qw]`` (the pose
            of the pairs given none).
        classifier: the rover model (per_pair: Rock Rover / Outcrop Rover; elevation_map:
            the far rocks' Rock Rover, which needs the blobs' appearance); None keeps
            every candidate with its proposed class (score 1).
        cfg: pipeline configuration.
        on_bad: bad-input counter, called as ``on_bad(kind, detail)``.

    Raises:
        ValueError: unknown method, or a model without the method's classifiers.
    """

    def __init__(self, base_to_left_camera, classifier: RoverClassifier | None,
                 cfg: RoverConfig = RoverConfig(), on_bad=None) -> None:
        if cfg.method not in METHODS:
            raise ValueError(f"method: unknown '{cfg.method}' (expected one of {METHODS})")
        check_model(classifier, cfg)
        self.extrinsic = list(base_to_left_camera)
        self.classifier = classifier
        #: Compute the far blobs' appearance (the far rocks' classifier reads it;
        #: training sets it without a classifier).
        self.describe_blobs = far_classifier(classifier, cfg) is not None
        self.cfg = cfg
        self.on_bad = on_bad or (lambda kind, detail: None)
        #: The camera of the latest pair (its pose in base_link, the working resolution).
        self.camera: StereoCamera | None = None
        self._rays = None
        # (intrinsics, pose) -> (camera, half-resolution rays in base_link), oldest first.
        self._cache: OrderedDict = OrderedDict()

    def _camera(self, frame: StereoFrame, base_t_left=None) -> StereoCamera:
        """The pair's camera at its pose (default: the fixed extrinsic), from the cache
        when that pose was seen; sets :attr:`camera` and the rays."""
        h, w = frame.left.shape[:2]
        pose = self.extrinsic if base_t_left is None else base_t_left
        key = (tuple(np.round(frame.left_k, 6)), tuple(np.round(frame.right_p, 6)), w, h,
               tuple(np.round(np.asarray(pose, float).ravel(), 9)))
        hit = self._cache.get(key)
        if hit is None:
            camera = StereoCamera.from_camera_info(frame.left_k, frame.right_p, w, h, pose)
            hit = (camera, camera.rays_base()[::2, ::2].copy())
            self._cache[key] = hit
            if len(self._cache) > POSE_CACHE:
                self._cache.popitem(last=False)
        else:
            self._cache.move_to_end(key)
        self.camera, self._rays = hit
        return self.camera

    def observe(self, frame: StereoFrame, base_t_left=None) -> PairObservation:
        """The pair's contribution under the configured method (see the module), at the
        working resolution (``RoverConfig.working_fx_px``; :attr:`camera` is then the
        working camera) and at the left camera's pose ``base_t_left`` (4x4 in base_link;
        None: the fixed extrinsic)."""
        frame = at_working_resolution(frame, self.cfg.working_fx_px)
        if self.cfg.method == "per_pair":
            return PairObservation(records=detections_to_records(
                self.detect(frame, base_t_left)))
        camera = self._camera(frame, base_t_left)
        left = cv2.cvtColor(frame.left, cv2.COLOR_BGR2GRAY)
        right = cv2.cvtColor(frame.right, cv2.COLOR_BGR2GRAY)
        st = self.cfg.stereo
        # 2. Stereo points.
        raw = self._disparity(left, right)
        disp = mask_depth_edges(raw, EDGE_WINDOW_PX, EDGE_MAX_RELATIVE_RANGE)
        points = points_base(disp, camera, self._rays, st.max_range_m)
        h, w = points.shape[:2]
        small = cv2.resize(frame.left, (w, h), interpolation=cv2.INTER_AREA)
        # 10. Dark blobs (tracked in add_pair).
        blobs = dark_blobs(frame.left, raw, camera, self.cfg.far, describe=self.describe_blobs)
        colour = appearance(small, np.isfinite(points[..., 2]))
        if is_monochrome(small):
            # A monochrome camera's pair (or grey JPEGs): no colour to tell an outcrop's
            # grey slab from the soil by. Its saturation, 0 everywhere, would make every
            # cell an outcrop candidate (quick's mono8 copy: 16 outcrop nodes, none
            # true); with none at all the rocks would lose their dark seeds too (33 rock
            # nodes, 10 true). So the pair keeps its value and reads as saturated as the
            # soil: its rocks are found as by day, its outcrops not looked for.
            colour[..., 0] = 1.0
            self.on_bad("monochrome images", "the stereo pair carries no colour: its "
                        "outcrops are not looked for (rocks are)")
        return PairObservation(points=points, appearance=colour, blobs=blobs)

    def _disparity(self, left: np.ndarray, right: np.ndarray) -> np.ndarray:
        """Disparity of the full-resolution pair on the half-resolution grid, in
        full-resolution pixels."""
        return disparity(left, right, self.cfg.stereo)[::2, ::2]

    def candidates(self, frame: StereoFrame, base_t_left=None
                   ) -> tuple[list[Candidate], dict | None]:
        """Candidates above the rover thresholds (unclassified) and the metric images, at
        the working resolution and the camera pose ``base_t_left`` (None: the fixed one)."""
        frame = at_working_resolution(frame, self.cfg.working_fx_px)
        camera = self._camera(frame, base_t_left)
        left = cv2.cvtColor(frame.left, cv2.COLOR_BGR2GRAY)
        right = cv2.cvtColor(frame.right, cv2.COLOR_BGR2GRAY)
        metrics = metric_images(left, 0.5)
        # Candidates are found and measured on a half-resolution grid of the stereo
        # points, the grid of the metric images: 4x fewer pixels, and a rover ROI still
        # covers tens to thousands.
        st = self.cfg.stereo
        disp = self._disparity(left, right)
        points = points_base(disp, camera, self._rays, st.max_range_m)
        cands = rover_candidates(
            metrics["_gray"], points, camera, self.cfg.thresholds,
            metrics, on_no_depth=lambda: self.on_bad(
                "no valid depth", f"a candidate at {frame.stamp_ns * 1e-9:.3f} s has too "
                "few stereo points"))
        return cands, metrics

    def detect(self, frame: StereoFrame, base_t_left=None) -> list[Candidate]:
        """Classified detections of one pair (candidates the classifiers accept), at the
        camera pose ``base_t_left`` (None: the fixed one)."""
        frame = at_working_resolution(frame, self.cfg.working_fx_px)
        cands, metrics = self.candidates(frame, base_t_left)
        if self.classifier is None or not cands:
            for c in cands:
                c.score = 1.0
            return cands
        return self.classifier.classify(frame.left, cands, metrics)


def detections_to_records(dets: list[Candidate]) -> np.ndarray:
    """ROI records (base_link) of detections; covariance: the stereo range error along
    the line of sight and the lateral error across it (base_link x-y)."""
    rec = empty_records(len(dets))
    for i, d in enumerate(dets):
        cov = observation_covariance(d.bearing, d.range_sigma_m, d.major_m)
        r = rec[i]
        r["x"], r["y"], r["z"] = d.center
        r["id"], r["label"] = i + 1, d.label
        r["area_m2"], r["height_m"] = d.area_m2, d.height_m
        r["major_m"], r["minor_m"], r["angle_rad"] = d.major_m, d.minor_m, d.angle_rad
        r["score"] = d.score
        r["cov_xx"], r["cov_xy"], r["cov_yy"] = cov[0, 0], cov[0, 1], cov[1, 1]
        r["n_obs"] = 1
    return rec


#: The committed rover model (package data).
DEFAULT_MODEL = Path(__file__).resolve().parent / "models" / "rover.npz"


def installed_model() -> Path | None:
    """The committed rover model: beside this module, or in the package's share
    directory; None when neither holds one."""
    if DEFAULT_MODEL.is_file():
        return DEFAULT_MODEL
    try:
        from ament_index_python.packages import get_package_share_directory

        p = Path(get_package_share_directory("roi_detector")) / "models" / "rover.npz"
        return p if p.is_file() else None
    except Exception:
        return None


def load_classifier(path: str | None, cfg: RoverConfig | None = None):
    """The rover model of ``path`` (default: the committed model; 'none': None) for
    ``cfg``'s method.

    elevation_map needs its far rocks' and map rocks' Rock Rovers and its map outcrops'
    Outcrop Rover, so a missing model is an error; per_pair uses the committed model if
    it holds the per-pair classifiers (else none: every candidate kept). A model named by
    ``path`` must hold those of ``cfg``'s method (:func:`check_model`).

    Raises:
        ValueError: an unreadable model, or none where ``cfg`` needs one.
    """
    cfg = cfg or RoverConfig()
    if path == "none":
        return None
    model = Path(path) if path else installed_model()
    if model is None:
        if cfg.method == "elevation_map":
            raise ValueError(f"no rover model (none at {DEFAULT_MODEL}; train one: make "
                             "rover-model; or run without one: model 'none')")
        return None
    clf = RoverClassifier.load(model)
    if not path and cfg.method == "per_pair" and not clf.per_pair:
        return None
    check_model(clf, cfg)
    return clf


def check_model(classifier: RoverClassifier | None, cfg: RoverConfig) -> None:
    """Raise ValueError when a rover model lacks what ``cfg``'s method runs, was trained
    at another working resolution (a model that records none was trained at the
    default), or its map outcrops' Outcrop Rover on the candidates of another outcrop
    rule than :data:`~roi_detector.elevation_map.MAP_OUTCROP_RULE`."""
    if classifier is None:
        return
    where = classifier.meta.get("path", "the rover model")
    prov = classifier.meta.get("provenance", {})
    trained_fx = prov.get("working_fx_px")
    if trained_fx is not None and \
            abs(float(trained_fx) - cfg.working_fx_px) > 0.02 * max(float(trained_fx), 1.0):
        raise ValueError(f"{where}: trained at a working resolution of {float(trained_fx):g} "
                         f"px (focal length), the detector works at {cfg.working_fx_px:g} "
                         f"px: its features would not mean the same (retrain it at this "
                         f"resolution, or set working_fx_px to {float(trained_fx):g})")
    if cfg.method == "per_pair":
        if not classifier.per_pair:
            raise ValueError(f"{where}: no Rock Rover / Outcrop Rover for the per_pair "
                             "method (train them: roi_detector train --method per_pair)")
        return
    for held, what in ((classifier.far_rocks, "far-rock Rock Rover"),
                       (classifier.map_rocks, "map-rock Rock Rover"),
                       (classifier.map_outcrops, "map outcrops' Outcrop Rover")):
        if not held:
            raise ValueError(f"{where}: no {what} for the elevation_map method (train it: "
                             "roi_detector train; or run without a model: model 'none')")
    trained = prov.get("map_outcrop_rule")
    if trained is not None and (
            trained.get("outcrop_soil_ratio", 0.0) != 0.0
            or any(not np.isclose(float(trained.get(k, np.nan)), float(v))
                   for k, v in MAP_OUTCROP_RULE.items())):
        raise ValueError(f"{where}: its Outcrop Rover was trained on the candidates of "
                         f"another outcrop rule ({trained}) than the map's "
                         f"({MAP_OUTCROP_RULE}): retrain it (roi_detector train)")


def map_outcrop_classifier(classifier: RoverClassifier | None, cfg: RoverConfig):
    """The map outcrops' Outcrop Rover (probability of features) when ``cfg`` runs the
    elevation map and the model holds one, else None."""
    if classifier is None or cfg.method != "elevation_map" or not classifier.map_outcrops:
        return None
    return classifier.map_outcrop_proba


def far_classifier(classifier: RoverClassifier | None, cfg: RoverConfig):
    """The far rocks' Rock Rover (vote share of features) when ``cfg`` runs the
    elevation map and the model holds one, else None."""
    if classifier is None or cfg.method != "elevation_map" or not classifier.far_rocks:
        return None
    return classifier.far_rock_proba


def map_rock_classifier(classifier: RoverClassifier | None, cfg: RoverConfig):
    """The map rocks' Rock Rover (probability of features) when ``cfg`` runs the
    elevation map and the model holds one, else None."""
    if classifier is None or cfg.method != "elevation_map" or not classifier.map_rocks:
        return None
    return classifier.map_rock_proba


#: Far rocks' track ids are offset by this in ROI records (the map's ROIs count from 1).
FAR_ROCK_ID_BASE = 500_000
#: The ids of one run of the detector are below this (the map's and the far rocks').
SESSION_ID_SPAN = 1_000_000


def session_id_base(unix_s: float) -> int:
    """The id offset of a detector node started at ``unix_s``: another one at each start
    (repeating every 4,000 s, so that ids stay uint32), so that a restarted detector, whose
    map counts its ROIs from 1 again, never reuses the ids of the ROIs ln_builder holds."""
    return (int(unix_s) % 4000 + 1) * SESSION_ID_SPAN


def far_rock_records(rocks: list[FarRock]) -> np.ndarray:
    """ROI records (odom) of triangulated far rocks: a round footprint of their width,
    ``n_obs`` their views."""
    rec = empty_records(len(rocks))
    for i, r in enumerate(rocks):
        rec[i]["id"], rec[i]["label"] = FAR_ROCK_ID_BASE + r.track_id, ROCK
        rec[i]["x"], rec[i]["y"], rec[i]["z"] = r.xy[0], r.xy[1], r.z
        rec[i]["area_m2"], rec[i]["height_m"] = r.area_m2, r.height_m
        rec[i]["major_m"] = rec[i]["minor_m"] = r.width_m
        rec[i]["angle_rad"], rec[i]["score"] = 0.0, 1.0
        rec[i]["cov_xx"], rec[i]["cov_xy"], rec[i]["cov_yy"] = r.cov[0, 0], r.cov[0, 1], \
            r.cov[1, 1]
        rec[i]["n_obs"] = r.n_views
    return rec


def records_in_view(records_odom: np.ndarray, pose, camera: StereoCamera,
                    max_depth_m: float) -> np.ndarray:
    """The records (odom) whose centre is in the pair's left image within
    ``max_depth_m``, re-expressed in base_link at the pair's odometry ``pose``."""
    if len(records_odom) == 0:
        return records_odom
    r_ob, t_ob = pose[0], np.asarray(pose[1], float)
    p = np.column_stack([records_odom["x"], records_odom["y"], records_odom["z"]])
    pb = (p - t_ob) @ r_ob
    uv, z = camera.project_base(pb)
    ok = (z > 0) & (z <= max_depth_m) & (uv[:, 0] >= 0) & (uv[:, 0] < camera.width) & \
        (uv[:, 1] >= 0) & (uv[:, 1] < camera.height)
    out = records_odom[ok].copy()
    out["x"], out["y"], out["z"] = pb[ok, 0], pb[ok, 1], pb[ok, 2]
    yaw = float(np.arctan2(r_ob[1, 0], r_ob[0, 0]))
    c, s = np.cos(yaw), np.sin(yaw)
    rot = np.array([[c, s], [-s, c]])  # odom -> base_link, x-y
    for r in out:  # covariance and ellipse rotated from odom into base_link
        cov = np.array([[r["cov_xx"], r["cov_xy"]], [r["cov_xy"], r["cov_yy"]]])
        cb = rot @ cov @ rot.T
        r["cov_xx"], r["cov_xy"], r["cov_yy"] = cb[0, 0], cb[0, 1], cb[1, 1]
        r["angle_rad"] = r["angle_rad"] - yaw
    return out


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
    """Tracks and Local Network of a drive, fed pair by pair (odom).

    Args:
        cfg: pipeline configuration.
        ln: the LN to extend (default: a new one).
        classifier: the rover model whose far-rock Rock Rover decides the far rocks
            (the pairs' blobs must then carry their appearance: the RoverDetector given
            the same model and config), whose map-rock Rock Rover decides the map's
            rocks and whose map outcrops' Outcrop Rover its outcrops; None: the rules
            alone.
    """

    def __init__(self, cfg: RoverConfig = RoverConfig(), ln: LocalNetwork | None = None,
                 classifier: RoverClassifier | None = None) -> None:
        self.cfg = cfg
        self.classifier = classifier
        self.tracker = Tracker(cfg.tracker)
        self.map = ElevationMap(cfg.elevation_map, map_rock_classifier(classifier, cfg),
                                map_outcrop_classifier(classifier, cfg))
        self.far = FarRockTracker(cfg.far, far_classifier(classifier, cfg))
        self.ln = ln if ln is not None else LocalNetwork(cfg.ln)
        self._tracks = empty_records(0)
        # A mast's pose the detector drives with, and whether the camera has left it.
        self._home: StereoCamera | None = None
        self._away = False

    @property
    def n_tracks(self) -> int:
        """ROIs followed so far (tracks, or elevation-map ROIs)."""
        return len(self.map.rois) if self.cfg.method == "elevation_map" else \
            len(self.tracker.tracks)

    def add_pair(self, obs: PairObservation, t: float, pose,
                 camera: StereoCamera) -> np.ndarray:
        """Add one pair's observation with its odometry pose ``(R_odom_base, t_odom_base,
        xy cov or None)``; returns the track records (odom) the detector stands behind.

        elevation_map: the ROIs of the map (``n_obs`` = detection rounds that found
        them), after a detection round when one is due: every ``detect_every`` pairs, and
        at the pair that brings a mast back to the pose it left (the end of a panorama:
        what the stop's views found is in the tracks before the rover drives on).
        """
        if obs.records is not None:
            return self.add_detections(obs.records, t, pose, camera)
        r_ob, t_ob, cov = pose
        back = self._returned(camera)
        # 3. Integration.
        self.map.integrate(obs.points, obs.appearance, r_ob, np.asarray(t_ob, float),
                           camera.t_base_cam, camera.fxb)
        # 11.-14. Tracks, triangulation, measurement, far rocks' Rock Rover (FarRocks).
        if obs.blobs is not None:
            self.far.add(obs.blobs, t, r_ob, t_ob, camera, cov)
        # 4.-9. Ground, rock and outcrop regions, their Rovers, persistence (ElevationMap.detect).
        if self.map.due() or (back and self.map.pending()):
            self.map.detect(t, cov)
            self._tracks = self._map_and_far_records()
        return self._tracks

    def _returned(self, camera: StereoCamera) -> bool:
        """Whether ``camera`` brings the mast back to the pose it had before it moved
        (a fixed camera never moves)."""
        if self._home is None:
            self._home = camera
        if camera is self._home or camera.same_mount(self._home):
            back, self._away = self._away, False
            return back
        self._away = True
        return False

    def finish(self, t: float, cov=None) -> np.ndarray:
        """A last detection round over what was integrated since the last one (and the
        far-rock tracks still open, closed)."""
        if self.cfg.method == "elevation_map":
            self.map.detect(t, cov)
            self.far.close_all()
            self._tracks = self._map_and_far_records()
        return self.current_tracks()

    def _map_and_far_records(self, far_rocks: list[FarRock] | None = None) -> np.ndarray:
        """The map's ROI records, and the far rocks (default: the tracker's) that no
        reported map rock stands near (within ``far_rocks.MERGE_M`` or half its major axis: the
        map measures what it reaches better than a far view does; a rock beside an
        outcrop is a rock). A map rock the map does not report (found in too few of its
        rounds) does not hide a far rock."""
        reported = self.map.consistent()
        rec = self.map.to_records(reported)
        near = [(r.xy, max(FAR_MERGE_M, 0.5 * r.major_m)) for r in reported
                if r.label == ROCK]
        far = [r for r in (self.far.rocks() if far_rocks is None else far_rocks)
               if all(np.linalg.norm(r.xy - xy) > d for xy, d in near)]
        return np.concatenate([rec, far_rock_records(far)]) if far else rec

    def current_tracks(self) -> np.ndarray:
        """The track records (odom) the detector stands behind now."""
        if self.cfg.method == "elevation_map":
            return self._tracks
        return tracks_to_records(self.tracker.consistent())

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
        """Feed the current tracks to the LN; True if the LN changed."""
        # 15. LN nodes.
        return self.ln.update(self.current_tracks())
