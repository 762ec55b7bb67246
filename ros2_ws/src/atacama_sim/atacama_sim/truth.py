"""Files beside the bag: truth catalogue (GeoJSON), trajectory (TUM), rover.yaml,
world.yaml. The GeoJSON goes through the shared codec in ``roi_network``."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import yaml

from atacama_sim.camera import StereoRig, mast_kinematics, quat_xyzw
from atacama_sim.config import WorldConfig
from atacama_sim.robot import FRAME_SUN_SENSOR
from atacama_sim.sky import Sky
from atacama_sim.sunsensor import base_T_sensor
from atacama_sim.world import map_origin
from roi_network.geojson import write_geojson
from roi_network.network import MapFrame, RoiNetwork
from roi_network.records import ROI_DTYPE
from roi_network.trajectory import write_tum as write_tum_file


def catalogue_records(catalogue: np.ndarray) -> np.ndarray:
    """The truth catalogue as roi_network ROI records (map frame, score 1)."""
    rec = np.zeros(len(catalogue), dtype=ROI_DTYPE)
    for name in catalogue.dtype.names:
        rec[name] = catalogue[name]
    rec["score"] = 1.0
    return rec


def write_truth_rois(catalogue: np.ndarray, cfg: WorldConfig, origin: tuple[float, float],
                     path: Path) -> None:
    """truth/rois.geojson: every major ROI (class, centre, footprint ellipse, height)."""
    net = RoiNetwork(catalogue_records(catalogue), "map", MapFrame(cfg.site.crs, origin),
                     metadata={"source": "atacama_sim truth catalogue",
                               "preset": cfg.preset, "seed": cfg.seed,
                               "gsd_m": cfg.orbital.gsd_m,
                               "ellipse": "major_m/minor_m: full axis lengths; angle_rad: "
                                          "major axis from map +x (east), counter-clockwise"})
    write_geojson(net, path)


def write_tum(path: Path, t: np.ndarray, p: np.ndarray, q: np.ndarray) -> None:
    """TUM trajectory: ``t x y z qx qy qz qw`` per line (t: bag time = header stamp, s)."""
    write_tum_file(path, t, p, q, header="t x y z qx qy qz qw (map frame, base_link)")


def rover_params(rig: StereoRig, cfg: WorldConfig, sky: Sky | None = None) -> dict[str, Any]:
    """Extrinsics and sensor constants as ROS 2 node parameters (params-file layout); the
    site and epoch of ``sky`` (default: that of ``cfg``'s site and start time)."""
    def pose(t: np.ndarray, r: np.ndarray) -> list[float]:
        # 12 decimals: the mast's chain of products leaves 1e-17 residues
        return [round(float(v), 12) + 0.0 for v in (*t, *quat_xyzw(r))]
    ic = cfg.imu
    params = {
        "base_frame": "base_link",
        "left_camera_frame": "left_camera_optical",
        "right_camera_frame": "right_camera_optical",
        "imu_frame": "imu_link",
        "base_to_left_camera": pose(rig.t_base_left, rig.R_base_cam),
        "base_to_right_camera": pose(rig.t_base_right, rig.R_base_cam),
        "base_to_imu": [0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 1.0],
        "baseline_m": float(rig.baseline),
        "camera_height_m": float(rig.t_base_left[2]),
        "camera_tilt_deg": float(cfg.camera.tilt_deg),
        "image_width": int(rig.width),
        "image_height": int(rig.height),
        "fx": float(rig.fx), "fy": float(rig.fy), "cx": float(rig.cx), "cy": float(rig.cy),
        "imu_rate_hz": float(ic.rate_hz),
        "gyro_noise_density": float(ic.gyro_noise_density),
        "gyro_bias_random_walk": float(ic.gyro_bias_rw),
        "accel_noise_density": float(ic.accel_noise_density),
        "accel_bias_random_walk": float(ic.accel_bias_rw),
        "gravity": float(ic.gravity),
        "mast": mast_params(cfg),
        "sun_sensor": sun_sensor_params(cfg),
        "site": (sky or Sky.from_config(cfg, map_origin(cfg.site.crs, cfg.site.site_lonlat))
                 ).metadata(),
    }
    return {"/**": {"ros__parameters": params}}


def sun_sensor_params(cfg: WorldConfig) -> dict[str, Any]:
    """The sun sensor's ``sun_sensor.*`` parameters, nested as a params file holds them."""
    from roi_network.mast import pose_list

    sc = cfg.sun_sensor
    return {"frame": FRAME_SUN_SENSOR,
            "base_to_sensor": [round(v, 12) + 0.0 for v in pose_list(base_T_sensor(sc))],
            "rate_hz": float(sc.rate_hz), "noise_deg": float(sc.noise_deg),
            "bias_deg": float(sc.bias_deg),
            "fov_half_angle_deg": float(sc.fov_half_angle_deg)}


def mast_params(cfg: WorldConfig) -> dict[str, Any]:
    """The mast's ``mast.*`` parameters, nested as a params file holds them (ROS flattens
    ``mast: {pan_joint: ...}`` to ``mast.pan_joint``)."""
    flat = mast_kinematics(cfg.camera).to_params()
    return {k.split(".", 1)[1]: v for k, v in flat.items()}


ROVER_YAML_HEADER = """\
# Rover extrinsics and sensor constants for this bag, as ROS 2 node parameters
# (use with --ros-args --params-file rover.yaml). Written by atacama_sim.
# base_to_*: pose of a sensor frame in base_link as [x, y, z, qx, qy, qz, qw]
#   (metres; quaternion rotates sensor-frame vectors into base_link).
#   base_link: x forward, y left, z up, origin on the ground under the rover centre.
#   camera frames are optical: z forward, x right, y down. Rectified pair: the right
#   camera is the left one moved baseline_m along the left camera's +x.
#   base_to_left_camera and base_to_right_camera are the cameras at the mast's drive
#   pose (pan 0, tilt camera_tilt_deg), where they are while the rover drives.
# baseline_m: stereo baseline; camera_height_m: left optical centre above base_link;
# camera_tilt_deg: optical axis below the base_link x-y plane (the drive pose).
# mast.*: the pan-tilt mast the stereo head rides on, as URDF states its joints (the
#   bag's /robot_description): pan_joint / tilt_joint name the joints of /joint_states;
#   pan_origin: the pan joint frame in base_link at zero angle; tilt_origin: the tilt
#   joint frame in the pan link; head_to_left_camera: the left optical frame in the tilt
#   link (poses [x, y, z, qx, qy, qz, qw]); *_axis: rotation axis in the joint frame
#   (tilt about +y: positive looks down); *_limits: [lower, upper] rad. The camera at
#   joint angles (pan, tilt) is roi_network.mast.MastKinematics.base_T_left(pan, tilt).
# image_width/height, fx, fy, cx, cy: rectified pinhole intrinsics (pixels), as in
#   CameraInfo K (no distortion).
# imu_*: IMU rate, white-noise densities (rad/s/sqrt(Hz), m/s^2/sqrt(Hz)) and bias
#   random walks (rad/s^2/sqrt(Hz), m/s^3/sqrt(Hz)); gravity in m/s^2.
# sun_sensor.*: the two-axis sun sensor of /sun_sensor (Vector3Stamped: the unit sun
#   vector in frame sun_sensor.frame, z = boresight): base_to_sensor its pose in
#   base_link; rate_hz; noise_deg and bias_deg the 1-sigma white noise and constant bias
#   of each of its two angles atan2(x, z), atan2(y, z); fov_half_angle_deg the half-angle
#   of its field of view about z (no output outside it, at night or in the mast's shadow).
# site.*: where and when: body (earth | mars), crs (the map's), latitude_deg and
#   longitude_deg of the map-frame origin (east positive; Mars planetocentric), epoch_utc
#   and epoch_ns the bag's first stamp. Header stamps are POSIX UTC: the sun at a stamp
#   is roi_network.sun.sun_position(body, latitude_deg, longitude_deg, stamp).
"""


def write_rover_yaml(path: Path, rig: StereoRig, cfg: WorldConfig,
                     sky: Sky | None = None) -> None:
    with path.open("w") as f:
        f.write(ROVER_YAML_HEADER)
        yaml.safe_dump(rover_params(rig, cfg, sky), f, sort_keys=False,
                       default_flow_style=None)


def write_world_yaml(path: Path, cfg: WorldConfig, derived: dict[str, Any]) -> None:
    doc = {"config": cfg.to_dict(), "derived": derived}
    with path.open("w") as f:
        f.write("# Every parameter that generated this bag (atacama_sim), and derived facts.\n"
                "# Camera geometry: MER Navcam stereo bench, Maki et al. (2003), J. Geophys."
                " Res. 108(E12), 8071.\n")
        yaml.safe_dump(doc, f, sort_keys=False)
