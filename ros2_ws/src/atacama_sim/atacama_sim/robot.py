"""The rover's frame tree as a robot publishes it: ``/tf_static`` and ``/robot_description``.

The URDF holds base_link, the IMU, the pan and tilt joints of the mast
(:func:`atacama_sim.camera.mast_kinematics`: origin, axis, limits) and the stereo head;
``/tf_static`` holds its fixed joints, what robot_state_publisher latches from it:
base_link -> imu_link, base_link -> mast_pan_base (the pan joint's origin),
mast_tilt_link -> left_camera_optical (the head), left_camera_optical ->
right_camera_optical (the baseline along x), and base_link -> sun_sensor (the sun sensor's
mount). The moving links follow ``/joint_states``.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from roi_network.mast import MastKinematics

FRAME_BASE = "base_link"
FRAME_IMU = "imu_link"
FRAME_LEFT = "left_camera_optical"
FRAME_RIGHT = "right_camera_optical"
FRAME_SUN_SENSOR = "sun_sensor"
#: The pan joint's origin, fixed to base_link (robot_state_publisher's static frame).
FRAME_PAN_BASE = "mast_pan_base"
FRAME_PAN_LINK = "mast_pan_link"
FRAME_TILT_LINK = "mast_tilt_link"
ROBOT_NAME = "atacama_sim_rover"


def _translation(x: float, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    m = np.eye(4)
    m[:3, 3] = [x, y, z]
    return m


def static_transforms(kin: MastKinematics, baseline_m: float,
                      base_T_sun: np.ndarray | None = None,
                      ) -> list[tuple[str, str, np.ndarray]]:
    """``(parent, child, 4x4 child pose in parent)`` of every fixed joint (the sun
    sensor's when ``base_T_sun`` gives its mount)."""
    pan_base = np.eye(4)
    pan_base[:3, 3] = kin.pan_origin[:3, 3]
    out = [(FRAME_BASE, FRAME_IMU, np.eye(4)),
           (FRAME_BASE, FRAME_PAN_BASE, pan_base),
           (FRAME_TILT_LINK, FRAME_LEFT, kin.head_to_left_camera),
           (FRAME_LEFT, FRAME_RIGHT, _translation(baseline_m))]
    if base_T_sun is not None:
        out.append((FRAME_BASE, FRAME_SUN_SENSOR, np.asarray(base_T_sun, float)))
    return out


def _origin(m: np.ndarray) -> str:
    rpy = Rotation.from_matrix(m[:3, :3]).as_euler("xyz")  # URDF: R = Rz(y) Ry(p) Rx(r)
    xyz = " ".join(f"{v:.9g}" for v in (0.0 + np.round(m[:3, 3], 12)))
    return f'<origin xyz="{xyz}" rpy="{" ".join(f"{v:.12g}" for v in 0.0 + rpy)}"/>'


def _vec(v: np.ndarray) -> str:
    return " ".join(f"{x:.9g}" for x in 0.0 + np.asarray(v, float))


def urdf(kin: MastKinematics, baseline_m: float,
         base_T_sun: np.ndarray | None = None) -> str:
    """The URDF text of the rover's frames and mast joints (and the sun sensor's)."""
    fixed_joints = static_transforms(kin, baseline_m, base_T_sun)
    pan_in_base = np.linalg.inv(fixed_joints[1][2]) @ kin.pan_origin
    links = [FRAME_BASE, FRAME_IMU, FRAME_PAN_BASE, FRAME_PAN_LINK, FRAME_TILT_LINK,
             FRAME_LEFT, FRAME_RIGHT] + ([FRAME_SUN_SENSOR] if base_T_sun is not None else [])
    lines = ['<?xml version="1.0"?>', f'<robot name="{ROBOT_NAME}">']
    lines += [f'  <link name="{name}"/>' for name in links]

    def fixed(name: str, parent: str, child: str, m: np.ndarray) -> None:
        lines.extend([f'  <joint name="{name}" type="fixed">',
                      f'    <parent link="{parent}"/>', f'    <child link="{child}"/>',
                      f"    {_origin(m)}", "  </joint>"])

    def revolute(name: str, parent: str, child: str, m: np.ndarray, axis: np.ndarray,
                 limits: tuple[float, float]) -> None:
        lines.extend([f'  <joint name="{name}" type="revolute">',
                      f'    <parent link="{parent}"/>', f'    <child link="{child}"/>',
                      f"    {_origin(m)}", f'    <axis xyz="{_vec(axis)}"/>',
                      f'    <limit lower="{limits[0]:.12g}" upper="{limits[1]:.12g}" '
                      f'effort="10" velocity="1"/>', "  </joint>"])

    for parent, child, m in fixed_joints:
        if child == FRAME_LEFT:
            revolute(kin.pan_joint, FRAME_PAN_BASE, FRAME_PAN_LINK, pan_in_base,
                     kin.pan_axis, kin.pan_limits)
            revolute(kin.tilt_joint, FRAME_PAN_LINK, FRAME_TILT_LINK, kin.tilt_origin,
                     kin.tilt_axis, kin.tilt_limits)
        fixed(f"{child}_joint", parent, child, m)
    lines.append("</robot>")
    return "\n".join(lines) + "\n"
