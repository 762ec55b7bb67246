"""Typed options of the estimator, defaults in one place (OpenVINS ``VioManagerOptions``).

Every field is a ROS parameter of the ``rover_vo`` node named ``<section>.<field>``
(``features.max_corners``) and a key of the same name in the params YAML the offline CLI
reads (``rover_vo: {ros__parameters: {...}}``), so one file configures both. Values a
user does not tune are named constants next to the code that uses them.

Both modes measure each frame against the last reference frame (the paper's rovers had
no bundle adjustment):

* ``paper`` (default): VO + IMU fusion (gyro rotation prior, gyro bias, gravity for roll
  and pitch);
* ``vo``: vision alone (no IMU at all), the baseline that shows what the gyro brings.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from roi_network.mast import MAST_PARAMS
from roi_network.params import node_parameters
from rover_vo.sun_heading import ACCEL_BIAS_RANDOM_WALK, SENSOR_PARAMS, SITE_PARAMS

MODES = ("paper", "vo")

#: The node's name: its entry in a params file.
NODE_NAME = "rover_vo"

#: rover.yaml parameters the estimator reads, with the values used when the bag's
#: rover.yaml lacks them (pose [x y z qx qy qz qw] in base_link; Hz; rad/s/sqrt(Hz);
#: rad/s^2/sqrt(Hz); m/s^2/sqrt(s), the sun heading's tilt drift; m/s^2).
ROVER_PARAMETERS: dict[str, Any] = {
    "base_to_left_camera": [0.0] * 7,
    "base_to_imu": [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
    "imu_rate_hz": 50.0,
    "gyro_noise_density": 1.7e-4,
    "gyro_bias_random_walk": 2.0e-5,
    "accel_bias_random_walk": ACCEL_BIAS_RANDOM_WALK,
    "gravity": 9.81,
}

#: Parameters of the node that are not estimator options (vo_node.py declares them).
NODE_ONLY_PARAMETERS = ("odom_frame", "base_frame", "image_transport", "state_path",
                        "use_sim_time")


@dataclass
class FeatureOptions:
    """Corner detection, stereo matching and tracking (``features.py``).

    Attributes:
        max_corners: Corners detected per reference image, spread over an 8 x 6 grid.
        rectify: Remap an image whose CameraInfo has a distortion (D) or a rectifying
            rotation (R) to its P, as image_proc does; false reads every image as
            rectified.
        stereo_sync_tolerance_s: Left and right images whose header stamps differ by at
            most this many seconds are one pair, stamped with the left's (s); 0 pairs
            exact stamps only.
        max_depth_m: Triangulated points farther than this are not used (m).
    """

    max_corners: int = 600
    rectify: bool = True
    stereo_sync_tolerance_s: float = 0.005
    max_depth_m: float = 60.0


@dataclass
class MotionOptions:
    """Motion estimation between the reference frame and the current one (``motion.py``).

    Attributes:
        ransac_reprojection_px: PnP RANSAC inlier bound (px).
        min_inliers: Fewer inliers and the frame is not used: the pose is IMU-propagated.
        pixel_sigma_px: Measurement noise of a tracked corner (px, 1 sigma).
    """

    ransac_reprojection_px: float = 1.5
    min_inliers: int = 25
    pixel_sigma_px: float = 0.5


@dataclass
class WindowOptions:
    """When the last frame replaces the reference frame (``estimator.py``).

    Attributes:
        frame_to_frame_min_travel_m: The last frame becomes the reference once the rover
            moved this far from it (m), as Curiosity runs VO about each metre; 0: every
            frame.
        frame_to_frame_min_turn_deg: ... or once it turned this far from it (deg).
    """

    frame_to_frame_min_travel_m: float = 0.3
    frame_to_frame_min_turn_deg: float = 5.0


@dataclass
class ImuOptions:
    """IMU fusion and zero-velocity detection (``estimator.py``, ``zero_velocity.py``).

    Attributes:
        accel_tilt_sigma_deg: Roll and pitch noise of the mean gravity measurement (deg).
        max_gap_s: IMU samples further apart than this are an IMU gap (s).
        zero_velocity_flow_px: The rover stands still when the median corner moves less
            than this (px) ...
        zero_velocity_gyro_rad_s: ... and the gyro rate stays below this (rad/s).
        sun_heading: Update the heading from /sun_sensor and gravity when rover.yaml has a
            sun sensor and a site (without them there is nothing to update from).
    """

    accel_tilt_sigma_deg: float = 0.5
    max_gap_s: float = 0.2
    zero_velocity_flow_px: float = 0.3
    zero_velocity_gyro_rad_s: float = 0.01
    sun_heading: bool = True


@dataclass
class CovarianceOptions:
    """The odometry covariance model (``state.py``): it grows with the distance driven.

    Attributes:
        translation_sigma_per_m: Translation noise per metre driven (1 sigma, m/m).
        rotation_sigma_deg_per_sqrt_m: Rotation random walk (deg/sqrt(m)).
        scale_sigma: Prior of the systematic scale error (1 sigma, fraction: 0.003 is
            0.3 %).
        heading_rate_sigma_deg_per_100m: Prior of the heading-rate bias (1 sigma,
            deg/100 m).
        propagation_translation_sigma: Translation noise per metre of a frame without
            vision (1 sigma, m/m).
    """

    translation_sigma_per_m: float = 0.01
    rotation_sigma_deg_per_sqrt_m: float = 0.02
    scale_sigma: float = 0.003
    heading_rate_sigma_deg_per_100m: float = 0.05
    propagation_translation_sigma: float = 0.5


@dataclass
class VoConfig:
    """All options of the estimator.

    Attributes:
        mode: ``paper`` (VO + IMU fusion) or ``vo`` (vision alone).
        features: Corner detection, stereo matching and tracking.
        motion: Motion estimation.
        window: Reference frame replacement.
        imu: IMU fusion and zero-velocity detection.
        covariance: Covariance model.
    """

    mode: str = "paper"
    features: FeatureOptions = field(default_factory=FeatureOptions)
    motion: MotionOptions = field(default_factory=MotionOptions)
    window: WindowOptions = field(default_factory=WindowOptions)
    imu: ImuOptions = field(default_factory=ImuOptions)
    covariance: CovarianceOptions = field(default_factory=CovarianceOptions)

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ValueError(f"mode '{self.mode}': expected one of {', '.join(MODES)}")

    @property
    def use_imu(self) -> bool:
        """The IMU is fused (``paper``); ``vo`` uses vision alone."""
        return self.mode == "paper"


SECTIONS = ("features", "motion", "window", "imu", "covariance")


def flat_parameters(cfg: VoConfig) -> dict[str, Any]:
    """``{"mode": ..., "features.max_corners": 600, ...}``: the node's parameter names."""
    out: dict[str, Any] = {"mode": cfg.mode}
    for section in SECTIONS:
        for f in dataclasses.fields(getattr(cfg, section)):
            out[f"{section}.{f.name}"] = getattr(getattr(cfg, section), f.name)
    return out


def unknown_options(names: Iterable[str]) -> list[str]:
    """The names among ``names`` under an option section (``features.``...) that are no
    option: a typo, or an option that does not exist."""
    known = set(flat_parameters(VoConfig()))
    return [n for n in names if n.partition(".")[0] in SECTIONS and n not in known]


def config_from_flat(values: dict[str, Any], base: VoConfig | None = None) -> VoConfig:
    """Apply ``section.field`` values (as the node's parameters or a params YAML hold them).

    Keys outside the option sections (rover.yaml's, ``use_sim_time``...) are not options
    and are left alone.

    Raises:
        ValueError: an unknown option or a value of the wrong type.
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
            continue
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


def _load_params_file(path: Path) -> dict[str, Any]:
    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise ValueError(f"{path}: cannot read ROS params YAML: {exc}") from exc
    if not isinstance(doc, dict):
        raise ValueError(f"{path}: not a ROS params file (expected a mapping at the top)")
    return doc


def read_ros_params(path: str | Path, node_name: str = NODE_NAME) -> dict[str, Any]:
    """The ``ros__parameters`` a ROS params file gives ``node_name`` (``/**`` first).

    Nested mappings are flattened to dotted names, as ROS does.

    Raises:
        ValueError: the file is not a ROS params file.
    """
    path = Path(path)
    return node_parameters(_load_params_file(path), node_name)


def config_from_params_file(path: str | Path) -> VoConfig:
    """The options a ROS params file gives the ``rover_vo`` node (nested or dotted keys,
    under ``/**``, ``rover_vo`` or ``/rover_vo``).

    Raises:
        ValueError: the file is not a ROS params file, or sets a parameter the node does
            not have under its own name (an option under ``/**`` too), or a bad value;
            the message names the file and the key.
    """
    path = Path(path)
    doc = _load_params_file(path)
    own = node_parameters({k: v for k, v in doc.items() if k != "/**"}, NODE_NAME)
    known = set(flat_parameters(VoConfig())) | set(ROVER_PARAMETERS) | set(
        NODE_ONLY_PARAMETERS) | set(MAST_PARAMS) | set(SENSOR_PARAMS) | set(SITE_PARAMS)
    values = node_parameters(doc, NODE_NAME)
    unknown = [k for k in own if k not in known] + unknown_options(values)
    if unknown:
        raise ValueError(f"{path}: unknown parameter '{unknown[0]}' for {NODE_NAME}")
    try:
        return config_from_flat(values)
    except ValueError as exc:
        raise ValueError(f"{path}: {exc}") from None
