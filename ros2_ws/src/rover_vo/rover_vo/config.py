"""Typed options of the estimator, defaults in one place (OpenVINS ``VioManagerOptions``).

Every field is a ROS parameter of the ``rover_vo`` node named ``<section>.<field>``
(``features.max_corners``) and a key of the same name in the params YAML the offline CLI
reads (``rover_vo: {ros__parameters: {...}}``), so one file configures both.

Three modes are compared in ``bench/vo_bench.py``:

* ``paper`` (default): frame to frame only (the paper's rovers had no bundle adjustment),
  with VO + IMU fusion (gyro rotation prior, gyro bias, gravity for roll and pitch);
* ``vo``: frame to frame, vision alone (no IMU at all);
* ``keyframes``: each frame measured against a keyframe, tracked from the keyframe's image
  (beyond the paper), with the IMU.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from roi_network.params import node_parameters

MODES = ("paper", "vo", "keyframes")


@dataclass
class FeatureOptions:
    """Corner detection and tracking (``features.py``)."""

    max_corners: int = 600  #: corners kept per left image
    quality_level: float = 0.005  #: Shi-Tomasi quality relative to the best corner
    min_distance_px: float = 12.0  #: minimum spacing between corners (px)
    grid_cols: int = 8  #: the image is cut into grid_cols x grid_rows cells ...
    grid_rows: int = 6  #: ... and each cell gets at most max_corners / cells corners
    lk_window_px: int = 15  #: Lucas-Kanade window side (px)
    lk_levels: int = 3  #: Lucas-Kanade pyramid levels above the full image
    lk_iterations: int = 10  #: Lucas-Kanade iterations per level at most
    lk_epsilon_px: float = 0.03  #: ... or until the update is smaller than this (px)
    fb_max_px: float = 0.5  #: forward-backward consistency bound of a track (px)
    #: remap images whose CameraInfo has distortion (D) or a rectifying rotation (R) to
    #: its P, as image_proc does; false: read every image as rectified (DESIGN.md's are)
    rectify: bool = True
    #: left and right images whose header stamps differ by at most this many seconds are
    #: one pair, stamped with the left's (roi_network.images.StereoHalves); 0: exact stamps
    stereo_sync_tolerance_s: float = 0.005
    stereo_max_dy_px: float = 1.0  #: rectified pair: |row difference| allowed (px)
    min_disparity_px: float = 1.0  #: farther points (smaller disparity) are not triangulated
    max_depth_m: float = 60.0  #: farther points are not used


@dataclass
class MotionOptions:
    """Motion estimation between a reference frame and the current one (``motion.py``)."""

    ransac_reprojection_px: float = 1.5  #: PnP RANSAC inlier bound (px)
    ransac_iterations: int = 200
    min_inliers: int = 25  #: fewer inliers: the frame is not used (IMU propagation)
    pixel_sigma_px: float = 0.5  #: image measurement noise (px, 1 sigma) of a tracked corner
    huber_px: float = 1.0  #: robust loss scale of the refinement (px)


@dataclass
class WindowOptions:
    """Keyframes (``keyframes.py``)."""

    frame_to_frame: bool = False  #: the paper's mode: the reference is the last frame ...
    #: ... once the rover moved this far from the reference or turned
    #: ``frame_to_frame_min_turn_deg`` (Curiosity runs VO about each metre; a camera
    #: streaming at 10 Hz would otherwise make every 1.5 cm step a measurement of its
    #: own); 0: always the last frame
    frame_to_frame_min_travel_m: float = 0.3
    frame_to_frame_min_turn_deg: float = 5.0  #: ... or turned this far from it
    keyframe_min_tracked: float = 0.3  #: new keyframe when fewer of its points are tracked
    keyframe_max_frames: int = 4  #: new keyframe at the latest after this many frames
    track_from_keyframe: bool = True  #: track from the keyframe image (else frame to frame)


@dataclass
class ImuOptions:
    """IMU propagation and fusion (``propagator.py``, ``zero_velocity.py``)."""

    use_imu: bool = True  #: False: vision alone (gyro unused, no gravity alignment)
    gyro_noise_density: float = 1.7e-4  #: rad/s/sqrt(Hz); rover.yaml overrides
    gyro_bias_random_walk: float = 2.0e-5  #: rad/s^2/sqrt(Hz); rover.yaml overrides
    gyro_bias_sigma0: float = 5.0e-3  #: prior 1-sigma of the turn-on gyro bias (rad/s)
    accel_tilt_sigma_deg: float = 0.5  #: roll/pitch measurement noise of mean gravity (deg)
    tilt_window_s: float = 0.5  #: accelerometer samples averaged for gravity (s before a frame)
    max_gap_s: float = 0.2  #: IMU samples further apart than this are an IMU gap
    input_wait_s: float = 5.0  #: a pair waits for its partner, infos and IMU until images
    #: this much newer (stamp time) arrive; then it is processed with what it has
    gravity: float = 9.81  #: m/s^2; rover.yaml overrides
    zero_velocity_flow_px: float = 0.3  #: median corner motion below this: standing still
    zero_velocity_gyro_rad_s: float = 0.01  #: and gyro rate below this (if IMU is used)


@dataclass
class CovarianceOptions:
    """Process noise of the odometry covariance (``state.py``): grows with distance."""

    translation_sigma_per_m: float = 0.01  #: 1-sigma translation error per metre driven
    rotation_sigma_deg_per_sqrt_m: float = 0.02  #: 1-sigma heading random walk (deg/sqrt m)
    scale_sigma: float = 0.003  #: prior 1-sigma of the systematic scale error (0.3 %)
    heading_rate_sigma_deg_per_100m: float = 0.05  #: prior 1-sigma of the heading-rate bias
    propagation_translation_sigma: float = 0.5  #: per metre, when vision is unavailable
    propagation_floor_m: float = 0.05  #: per frame without vision, even with no step
    unseen_rotation_sigma_deg: float = 10.0  #: per frame with neither vision nor gyro
    #: After a restart (:meth:`VoEstimator.resume`), 1-sigma motion over the gap nobody
    #: watched, as a fraction of the fastest speed and turn rate seen before it, times the gap.
    resume_motion_fraction: float = 0.5


@dataclass
class VoConfig:
    """All options of the estimator. ``mode`` selects a preset applied on top (see module)."""

    mode: str = "paper"
    features: FeatureOptions = field(default_factory=FeatureOptions)
    motion: MotionOptions = field(default_factory=MotionOptions)
    window: WindowOptions = field(default_factory=WindowOptions)
    imu: ImuOptions = field(default_factory=ImuOptions)
    covariance: CovarianceOptions = field(default_factory=CovarianceOptions)

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode '{self.mode}': expected one of {', '.join(MODES)}")

    def resolved(self) -> VoConfig:
        """A copy with the mode's preset applied (what the estimator runs)."""
        cfg = dataclasses.replace(
            self, features=dataclasses.replace(self.features),
            motion=dataclasses.replace(self.motion), window=dataclasses.replace(self.window),
            imu=dataclasses.replace(self.imu), covariance=dataclasses.replace(self.covariance))
        if cfg.mode in ("paper", "vo"):
            cfg.window.frame_to_frame = True
        if cfg.mode == "vo":
            cfg.imu.use_imu = False
        return cfg


SECTIONS = ("features", "motion", "window", "imu", "covariance")


def flat_parameters(cfg: VoConfig) -> dict[str, Any]:
    """``{"mode": ..., "features.max_corners": 600, ...}``: the node's parameter names."""
    out: dict[str, Any] = {"mode": cfg.mode}
    for section in SECTIONS:
        for f in dataclasses.fields(getattr(cfg, section)):
            out[f"{section}.{f.name}"] = getattr(getattr(cfg, section), f.name)
    return out


def config_from_flat(values: dict[str, Any], base: VoConfig | None = None) -> VoConfig:
    """Apply ``section.field`` values (as the node's parameters or a params YAML hold them).

    Raises:
        ValueError: an unknown key or a value of the wrong type.
    """
    cfg = dataclasses.replace(base or VoConfig())
    sections = {s: dataclasses.replace(getattr(cfg, s)) for s in SECTIONS}
    mode = cfg.mode
    for key, value in values.items():
        if key == "mode":
            mode = str(value)
            continue
        section, _, name = key.partition(".")
        if section not in sections:
            continue  # rover.yaml keys (extrinsics), use_sim_time...: not ours
        fields = {f.name: f for f in dataclasses.fields(sections[section])}
        if name not in fields:
            raise ValueError(f"unknown parameter '{key}'")
        default = getattr(sections[section], name)
        if isinstance(default, bool):
            if not isinstance(value, bool):
                raise ValueError(f"parameter '{key}': expected true/false, got {value!r}")
        elif isinstance(default, int):
            if isinstance(value, bool) or not isinstance(value, int):
                raise ValueError(f"parameter '{key}': expected an integer, got {value!r}")
        elif isinstance(default, float):
            if isinstance(value, bool) or not isinstance(value, int | float):
                raise ValueError(f"parameter '{key}': expected a number, got {value!r}")
            value = float(value)
        setattr(sections[section], name, value)
    return VoConfig(mode=mode, **sections)


def read_ros_params(path: str | Path, node_name: str = "rover_vo") -> dict[str, Any]:
    """The ``ros__parameters`` a ROS params file gives ``node_name`` (``/**`` first).

    Nested mappings are flattened to dotted names, as ROS does.

    Raises:
        ValueError: the file is not a ROS params file.
    """
    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"{path}: cannot read ROS params YAML: {exc}") from exc
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: not a ROS params file (expected a mapping at the top)")
    return node_parameters(doc, node_name)
