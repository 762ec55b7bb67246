"""The rover's sun sensor: a digital two-axis fine sun sensor on the deck, looking up.

What it reads (:func:`simulate_sun_sensor`), at every sample of its rate:
  1. the true sun in the map frame at the sensor's position and stamp (:class:`Sky`),
     turned into base_link by the truth attitude and into the sensor frame by its mount;
  2. no output when the sun is below the horizon (night), when it is further from the
     boresight than the field of view's half-angle, or when the ray from the sensor to the
     sun meets the mast (:func:`mast_shadows`: the post, and the stereo head at that
     sample's pan and tilt, from ``roi_network.mast``);
  3. else the two angles a two-axis sensor measures, ``atan2(x, z)`` and ``atan2(y, z)``,
     each with its constant bias (drawn once per bag) and white noise, back to a unit
     vector.

The sensor frame (``sun_sensor``, :data:`atacama_sim.robot.FRAME_SUN_SENSOR`) has its
axes along base_link's (x forward, y left, z up = the boresight);
``SunSensorConfig.position_m`` places it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from atacama_sim.config import SunSensorConfig, rng_for
from atacama_sim.sky import Sky
from roi_network.mast import MastKinematics

#: The sensor's axes in base_link (columns): along base_link's, boresight up.
SENSOR_ROTATION = np.eye(3)
#: The mast post: a cylinder of this radius on the pan axis, from the deck at this height
#: above base_link up to the tilt axis (it carries the pan link), m.
MAST_POST_RADIUS_M = 0.04
MAST_POST_BOTTOM_M = 0.60
#: The stereo head: a box centred on the tilt axis, half extents along the tilt link's
#: x (forward), y (the stereo bar, both cameras' bodies) and z, m.
HEAD_HALF_EXTENTS_M = (0.06, 0.18, 0.06)

#: Why a sample has no output (:attr:`SunSensorData.reason`).
OK, NIGHT, OUTSIDE_FOV, SHADOWED = 0, 1, 2, 3
REASONS = {OK: "output", NIGHT: "below_horizon", OUTSIDE_FOV: "outside_fov",
           SHADOWED: "shadowed_by_mast"}


def base_T_sensor(cfg: SunSensorConfig) -> np.ndarray:  # noqa: N802 (frame name)
    """4x4 pose of the sensor frame in base_link."""
    m = np.eye(4)
    m[:3, :3] = SENSOR_ROTATION
    m[:3, 3] = cfg.position_m
    return m


def sample_step(cfg: SunSensorConfig, imu_rate_hz: float) -> int:
    """Samples of the motion grid (the IMU's rate) between two sun sensor samples.

    Raises:
        ValueError: naming ``sun_sensor.rate_hz`` when it is not positive or does not
            divide the IMU rate.
    """
    rate = float(cfg.rate_hz)
    if not (np.isfinite(rate) and 0 < rate <= imu_rate_hz):
        raise ValueError(f"sun_sensor.rate_hz: {rate} Hz must be positive and at most the "
                         f"IMU's {imu_rate_hz:g} Hz")
    step = round(imu_rate_hz / rate)
    if abs(imu_rate_hz / step - rate) > 1e-9 * rate:
        raise ValueError(f"sun_sensor.rate_hz: {rate:g} Hz does not divide the IMU's "
                         f"{imu_rate_hz:g} Hz (the motion's time grid); e.g. "
                         f"{imu_rate_hz / max(1, step):g} Hz")
    return step


def _ray_hits_box(origin: np.ndarray, direction: np.ndarray, half: np.ndarray) -> bool:
    """Whether the ray ``origin + s direction`` (s > 0) meets the box ``|x_i| <= half_i``."""
    lo, hi = 0.0, np.inf
    for i in range(3):
        if abs(direction[i]) < 1e-12:
            if abs(origin[i]) > half[i]:
                return False
            continue
        a = (-half[i] - origin[i]) / direction[i]
        b = (half[i] - origin[i]) / direction[i]
        lo, hi = max(lo, min(a, b)), min(hi, max(a, b))
        if lo > hi:
            return False
    return True


def _ray_hits_cylinder(origin: np.ndarray, direction: np.ndarray, base: np.ndarray,
                       axis: np.ndarray, length: float, radius: float) -> bool:
    """Whether the ray (s > 0) meets the solid cylinder from ``base`` along unit ``axis``."""
    w = origin - base
    d_perp = direction - axis * (direction @ axis)
    w_perp = w - axis * (w @ axis)
    a = d_perp @ d_perp
    b = 2.0 * (d_perp @ w_perp)
    c = w_perp @ w_perp - radius * radius
    if a < 1e-15:  # parallel to the axis
        if c > 0:
            return False
        s_range = (0.0, np.inf)
    else:
        disc = b * b - 4 * a * c
        if disc < 0:
            return False
        r = np.sqrt(disc)
        s_range = ((-b - r) / (2 * a), (-b + r) / (2 * a))
    s0, s1 = max(s_range[0], 0.0), s_range[1]
    if s0 > s1:
        return False
    # the axial coordinate along the ray is linear: the segment [s0, s1] meets [0, length]
    h0, h1 = (w @ axis) + s0 * (direction @ axis), (w @ axis) + s1 * (direction @ axis)
    if np.isinf(s1):
        h1 = np.inf if direction @ axis > 0 else (-np.inf if direction @ axis < 0 else h0)
    return max(min(h0, h1), 0.0) <= min(max(h0, h1), length)


def mast_shadows(kin: MastKinematics, sensor_base: np.ndarray, sun_base: np.ndarray,
                 pan: float, tilt: float) -> bool:
    """Whether the mast (post and head at joint angles ``pan``, ``tilt``, rad) lies on the
    ray from ``sensor_base`` toward unit ``sun_base`` (both in base_link)."""
    o = np.asarray(sensor_base, float)
    d = np.asarray(sun_base, float)
    pan_base = kin.pan_origin[:3, 3]
    axis = kin.pan_origin[:3, :3] @ kin.pan_axis
    tilt_link = kin.base_T_left(pan, tilt) @ np.linalg.inv(kin.head_to_left_camera)
    top = float((tilt_link[:3, 3] - pan_base) @ axis)
    bottom = pan_base + axis * (MAST_POST_BOTTOM_M - pan_base[2]) / max(axis[2], 1e-9)
    length = top + float((pan_base - bottom) @ axis)
    if _ray_hits_cylinder(o, d, bottom, axis, length, MAST_POST_RADIUS_M):
        return True
    r, c = tilt_link[:3, :3], tilt_link[:3, 3]
    return _ray_hits_box(r.T @ (o - c), r.T @ d, np.asarray(HEAD_HALF_EXTENTS_M))


@dataclass
class SunSensorData:
    """Every sample of the sun sensor over the traverse.

    Attributes:
        idx: motion-grid index of each sample (K,).
        reason: :data:`OK` where there is an output, else why not (K,).
        truth: true unit sun vector in the sensor frame (K, 3) (also below the horizon).
        measured: the output (K, 3), NaN where there is none.
        elevation_deg: the sun's apparent elevation at the sensor (K,).
        bias_rad: the two angles' biases of this bag, rad (2,).
    """

    idx: np.ndarray
    reason: np.ndarray
    truth: np.ndarray
    measured: np.ndarray
    elevation_deg: np.ndarray
    bias_rad: np.ndarray

    def counts(self) -> dict[str, int]:
        """Samples by outcome (:data:`REASONS`' names)."""
        return {name: int(np.sum(self.reason == code)) for code, name in REASONS.items()}


def measure(truth: np.ndarray, bias_rad: np.ndarray, noise_rad: float,
            rng: np.random.Generator) -> np.ndarray:
    """The two-axis reading of true sensor-frame unit vectors ``truth`` (N, 3), z > 0:
    each angle plus its bias and white noise, as unit vectors (N, 3)."""
    t = np.atleast_2d(truth)
    ang = np.column_stack([np.arctan2(t[:, 0], t[:, 2]), np.arctan2(t[:, 1], t[:, 2])])
    ang = ang + bias_rad + noise_rad * rng.standard_normal(ang.shape)
    v = np.column_stack([np.tan(ang[:, 0]), np.tan(ang[:, 1]), np.ones(len(t))])
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def simulate_sun_sensor(cfg: SunSensorConfig, sky: Sky, traj, motion, kin: MastKinematics,
                        imu_rate_hz: float, seed: int) -> SunSensorData:
    """The sun sensor's samples along ``traj`` (truth attitude; ``motion``: the mast's
    joint angles on the same grid) (module method)."""
    step = sample_step(cfg, imu_rate_hz)
    idx = np.arange(0, len(traj.t), step)
    rot = traj.rotations()[idx].as_matrix()  # base_link in map
    b_t_s = base_T_sensor(cfg)
    p_sensor = traj.p[idx] + rot @ b_t_s[:3, 3]
    sun_map, elevation = sky.sun_map_many(traj.t[idx], p_sensor[:, :2])
    sun_base = np.einsum("kji,kj->ki", rot, sun_map)  # R_wb^T s
    truth = sun_base @ b_t_s[:3, :3]  # R_bs^T s, row-wise
    cos_fov = np.cos(np.radians(cfg.fov_half_angle_deg))
    reason = np.full(len(idx), OK, np.int8)
    reason[truth[:, 2] < cos_fov] = OUTSIDE_FOV
    reason[elevation <= 0.0] = NIGHT
    for j in np.flatnonzero(reason == OK):
        k = int(idx[j])
        if mast_shadows(kin, b_t_s[:3, 3], sun_base[j], float(motion.pan[k]),
                        float(motion.tilt[k])):
            reason[j] = SHADOWED
    rng = rng_for(seed, "sun_sensor")
    bias = np.radians(cfg.bias_deg) * rng.standard_normal(2)
    measured = np.full((len(idx), 3), np.nan)
    ok = reason == OK
    # the noise stream draws for every sample, so an outage does not reshuffle the others
    all_meas = measure(np.where(ok[:, None], truth, [0.0, 0.0, 1.0]), bias,
                       float(np.radians(cfg.noise_deg)), rng)
    measured[ok] = all_meas[ok]
    return SunSensorData(idx, reason, truth, measured, elevation, bias)
