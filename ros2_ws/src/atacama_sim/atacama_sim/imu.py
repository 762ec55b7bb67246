"""IMU synthesis from the trajectory: body rates and specific force, plus sensor errors.

Specific force f_b = R_wb^T (a_w + g e_z) (at rest the accelerometer reads +g up), body
rate from consecutive orientations. Errors: white noise (density * sqrt(rate)) and a
bias random walk (density * sqrt(dt) per step) started at a random turn-on bias.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from atacama_sim.config import ImuConfig, rng_for
from atacama_sim.route import Trajectory


@dataclass
class ImuData:
    gyro: np.ndarray  # (K, 3) rad/s, base_link (= imu_link)
    accel: np.ndarray  # (K, 3) m/s^2
    gyro_true: np.ndarray
    accel_true: np.ndarray
    gyro_sigma: float  # per-sample white-noise sigma
    accel_sigma: float


def synthesize_imu(traj: Trajectory, cfg: ImuConfig, seed: int) -> ImuData:
    rng = rng_for(seed, "imu")
    dt = 1.0 / cfg.rate_hz
    rot = traj.rotations()
    vel = np.gradient(traj.p, dt, axis=0)
    acc = np.gradient(vel, dt, axis=0)
    f_true = rot.inv().apply(acc + np.array([0, 0, cfg.gravity]))
    # body rate: central difference of orientation, expressed in the body frame
    k = len(traj.t)
    w_true = np.zeros((k, 3))
    if k > 2:
        d = (rot[:-2].inv() * rot[2:]).as_rotvec() / (2 * dt)
        w_true[1:-1] = d
        w_true[0], w_true[-1] = d[0], d[-1]
    gs = cfg.gyro_noise_density * np.sqrt(cfg.rate_hz)
    as_ = cfg.accel_noise_density * np.sqrt(cfg.rate_hz)
    gb = cfg.gyro_bias_init * rng.standard_normal(3) + np.cumsum(
        cfg.gyro_bias_rw * np.sqrt(dt) * rng.standard_normal((k, 3)), axis=0)
    ab = cfg.accel_bias_init * rng.standard_normal(3) + np.cumsum(
        cfg.accel_bias_rw * np.sqrt(dt) * rng.standard_normal((k, 3)), axis=0)
    gyro = w_true + gb + gs * rng.standard_normal((k, 3))
    accel = f_true + ab + as_ * rng.standard_normal((k, 3))
    return ImuData(gyro, accel, w_true, f_true, gs, as_)
