"""A drive's Local Network built offline: a bag's stereo pairs and an odometry file
through the same detector and mapper the nodes run (:mod:`roi_detector.rover_pipeline`).

``roi_detector ln``, the training (truth trajectory as the odometry) and the benchmarks
call :func:`build_ln`. Each LN node's covariance comes from the odometry's covariance at
its observations, as in the nodes: a pose covariance file beside the odometry file (what
``rover_vo odometry`` and ``globloc run`` write), or a drift model when there is none (a
TUM file carries no covariance).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from roi_detector.camera_poses import NOT_PLACED, PairPoses, rotation_of
from roi_detector.inputs import (
    POSE_COVARIANCE_FILE,
    BadInput,
    PairSpacing,
    load_rover_params,
    read_pose_covariance,
    read_stereo_frames,
    read_tum,
)
from roi_detector.rover_pipeline import DriveMapper, RoverConfig, RoverDetector, load_classifier
from roi_network import images

#: Odometry 1-sigma error per metre travelled of the drift model (no covariance file).
DEFAULT_DRIFT_FRAC = 0.01


def odometry_xy_covariance(track, drift_frac: float) -> np.ndarray:
    """(N, 2, 2) x-y covariance of a TUM odometry (which carries none): isotropic, with
    1-sigma ``drift_frac`` of the distance travelled (m^2)."""
    steps = np.r_[0.0, np.linalg.norm(np.diff(track.p[:, :2], axis=0), axis=1)]
    sigma = drift_frac * np.cumsum(steps) + 0.01
    return sigma[:, None, None] ** 2 * np.eye(2)[None]


def odometry_covariance_file(odometry: str | Path, covariance: str | None) -> Path | None:
    """The pose covariance file of an odometry file: ``covariance`` if given ('none':
    none), else :data:`~roi_detector.inputs.POSE_COVARIANCE_FILE` beside the odometry
    file when there is one."""
    if covariance == "none":
        return None
    if covariance:
        return Path(covariance)
    beside = Path(odometry).parent / POSE_COVARIANCE_FILE
    return beside if beside.is_file() else None


def build_ln(bag_dir: str, odometry: str, model: str | None, cfg: RoverConfig | None = None,
             every: int = 1, drift_frac: float = DEFAULT_DRIFT_FRAC, log=print, trace=None,
             mapper: DriveMapper | None = None, describe: bool = False,
             odometry_cov: str | Path | None = None, rectify: bool = True,
             sync_tolerance_s: float = images.SYNC_TOLERANCE_S,
             spacing: PairSpacing | None = None) -> tuple:
    """Run detection, tracking and the LN over a bag with an odometry file.

    Args:
        bag_dir: the bag directory (stereo images and ``rover.yaml``; never its truth).
        odometry: TUM file of base_link in odom.
        model: rover model file (None: the committed one; 'none': no classifier).
        cfg: pipeline configuration (default :class:`RoverConfig`).
        every: read one stereo pair in ``every``.
        drift_frac: without ``odometry_cov``, the odometry's 1-sigma error per metre
            travelled (:func:`odometry_xy_covariance`).
        log: called with each log line.
        trace: set as the elevation map's :attr:`ElevationMap.trace` (diagnostics).
        mapper: the DriveMapper to fill (built with ``cfg`` and its rover model, which
            the detector then uses: ``model`` is not read; default a fresh one with
            ``model``), for callers that read its map or far-rock tracks afterwards.
        describe: the far blobs carry their appearance even without a classifier
            (training).
        odometry_cov: the odometry's pose covariance file (a row per odometry stamp,
            :func:`~roi_detector.inputs.read_pose_covariance`), whose x-y block places
            each LN node's covariance as the nodes take it from /vo/odometry.
        rectify: rectify images whose CameraInfo has a distortion
            (:class:`~roi_detector.inputs.FrameMaker`); False reads them all as
            rectified.
        sync_tolerance_s: most difference between a stereo pair's two stamps, seconds.
        spacing: which pairs are read, by the odometry at their stamps (default
            :class:`~roi_detector.inputs.PairSpacing`'s, as the node's).

    Returns:
        (LocalNetwork, stats dict).
    """
    cfg = cfg or RoverConfig()
    params = load_rover_params(Path(bag_dir) / "rover.yaml")
    track = read_tum(odometry)
    track.cov = (read_pose_covariance(odometry_cov, track.t) if odometry_cov is not None
                 else odometry_xy_covariance(track, drift_frac))
    bad = BadInput(lambda m: log(f"roi_detector: {m}"))
    # Each pair's camera pose: a mast's from the bag's /joint_states (a message the mast
    # cannot read is an error naming it), else the fixed extrinsic.
    poses = PairPoses(params, bad, strict=True)
    mapper = mapper if mapper is not None else DriveMapper(
        cfg, classifier=load_classifier(model, cfg))
    detector = RoverDetector(params["base_to_left_camera"], mapper.classifier, cfg, bad)
    detector.describe_blobs |= describe
    mapper.map.trace = trace
    n_pairs = n_dets = 0
    t_detect = 0.0
    last = None
    spacing = spacing if spacing is not None else PairSpacing()
    camera_at: dict[int, object] = {}

    def keep(stamp_ns: int) -> bool:
        t = stamp_ns * 1e-9
        cam = poses.pose(t)
        if cam is None:  # the joint states cannot place it: counted by PairPoses
            return False
        pose = track.at(t)
        if pose is not None and not (spacing.keep(t, pose, rotation_of(cam))
                                     if poses.has_mast else spacing.keep(t, pose)):
            return False
        camera_at[stamp_ns] = cam  # a gap (pose None): counted below
        return True

    for frame in read_stereo_frames(bag_dir, bad, every=every, rectify=rectify,
                                    log=lambda m: log(f"roi_detector: {m}"),
                                    sync_tolerance_s=sync_tolerance_s, keep=keep,
                                    joints=poses if poses.has_mast else None):
        t0 = time.perf_counter()
        cam = camera_at.pop(frame.stamp_ns)
        try:
            obs = detector.observe(frame, None if not poses.has_mast else cam)
        except ValueError as exc:  # a calibration the camera model refuses: named field
            bad("bad camera_info", f"stereo pair at {frame.stamp_ns * 1e-9:.3f} s: {exc}")
            continue
        n_pairs += 1
        pose = track.at(frame.stamp_ns * 1e-9)
        if pose is None:
            t_detect += time.perf_counter() - t0
            bad("odometry gap", f"no odometry pose at {frame.stamp_ns * 1e-9:.3f} s")
            continue
        mapper.add_pair(obs, frame.stamp_ns * 1e-9, pose, detector.camera)
        mapper.update_ln()
        t_detect += time.perf_counter() - t0
        n_dets += 0 if obs.records is None else len(obs.records)
        last = (frame.stamp_ns * 1e-9, pose[2])
    if n_pairs and last is not None:
        mapper.finish(*last)
        mapper.update_ln()
    stats = {"pairs": n_pairs, "pairs_spaced_out": spacing.skipped, "detections": n_dets,
             "tracks": mapper.n_tracks,
             **({"mast": True, "joint_states": poses.joint_samples,
                 "pairs_not_placed": sum(bad.counts[k] for k in NOT_PLACED)}
                if poses.has_mast else {}),
             "ln_nodes": len(mapper.ln), "bad_input": dict(bad.counts),
             "not_a_rock": dict(mapper.map.rejected),
             "detect_s_per_pair": t_detect / max(n_pairs, 1)}
    return mapper.ln, stats
