"""IMU propagation (OpenVINS ``Propagator``): a time-ordered buffer of gyro and accelerometer
samples, integrated between two stamps with the current gyro bias, and the gyro bias
itself (a 3-state Kalman filter fed by the vision and zero-velocity updates).

Frames: samples are in ``imu_link``; results are returned in ``base_link`` through the
rig's ``base_R_imu``. ``delta_rotation(t0, t1)`` is ``b0_R_b1`` (body at t1 into body at t0).
"""

from __future__ import annotations

import bisect
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation


def ordered_product(rotations: Rotation) -> Rotation:
    """``r[0] * r[1] * ... * r[n-1]`` by pairwise halving (log2(n) vectorised products)."""
    r = rotations
    while len(r) > 1:
        if len(r) % 2:
            r = Rotation.concatenate([r, Rotation.identity()])
        r = r[0::2] * r[1::2]
    return r[0]


@dataclass
class ImuInterval:
    """What the IMU says about the body between two stamps.

    Attributes:
        R: 3x3 ``b0_R_b1`` from the bias-corrected gyro (base_link).
        cov: 3x3 covariance of that rotation (rad^2): white noise and bias uncertainty.
        mean_gyro: mean raw gyro (imu_link, rad/s), for the zero-velocity bias update.
        mean_accel: mean specific force (base_link, m/s^2).
        max_rate: largest bias-corrected body rate seen (rad/s).
        n: samples used. gap: the largest spacing between samples (s), ends included.
    """

    R: np.ndarray
    cov: np.ndarray
    mean_gyro: np.ndarray
    mean_accel: np.ndarray
    max_rate: float
    n: int
    gap: float


class Propagator:
    """IMU buffer, gyro integration and gyro bias estimate.

    Args:
        base_R_imu: 3x3 rotation imu_link -> base_link.
        gyro_noise_density: rad/s/sqrt(Hz).
        gyro_bias_random_walk: rad/s^2/sqrt(Hz).
        gyro_bias_sigma0: prior 1-sigma of the turn-on bias (rad/s).
        horizon_s: samples older than this behind the newest are dropped (memory stays flat).
    """

    def __init__(self, base_R_imu: np.ndarray, gyro_noise_density: float,
                 gyro_bias_random_walk: float, gyro_bias_sigma0: float,
                 horizon_s: float = 120.0) -> None:
        self.base_R_imu = np.asarray(base_R_imu, float)
        self.noise_density = gyro_noise_density
        self.bias_rw = gyro_bias_random_walk
        self.horizon_s = horizon_s
        self.t: list[float] = []
        self.gyro: list[np.ndarray] = []
        self.accel: list[np.ndarray] = []
        self.bias = np.zeros(3)  # imu_link, rad/s
        self.bias_cov = np.eye(3) * gyro_bias_sigma0**2
        self.bias_time: float | None = None

    # -- buffer ---------------------------------------------------------------------------
    def add(self, t: float, gyro: np.ndarray, accel: np.ndarray) -> str | None:
        """Append one sample; returns the kind of bad input it was (and drops it), or None.

        Kinds: ``imu_nan`` (non-finite value), ``imu_duplicate`` (same stamp as the last),
        ``imu_out_of_order`` (older than the last).
        """
        if not (np.all(np.isfinite(gyro)) and np.all(np.isfinite(accel)) and np.isfinite(t)):
            return "imu_nan"
        if self.t:
            if t == self.t[-1]:
                return "imu_duplicate"
            if t < self.t[-1]:
                return "imu_out_of_order"
        self.t.append(t)
        self.gyro.append(np.asarray(gyro, float))
        self.accel.append(np.asarray(accel, float))
        if t - self.t[0] > 2 * self.horizon_s:
            k = bisect.bisect_left(self.t, t - self.horizon_s)
            del self.t[:k], self.gyro[:k], self.accel[:k]
        return None

    @property
    def latest(self) -> float | None:
        """Stamp of the newest sample (s), or None."""
        return self.t[-1] if self.t else None

    # -- integration ------------------------------------------------------------------------
    def interval(self, t0: float, t1: float) -> ImuInterval | None:
        """Integrate the bias-corrected gyro over ``[t0, t1]`` (piecewise-constant rate).

        Returns None when no sample lies in the interval.
        """
        i0 = bisect.bisect_right(self.t, t0)
        i1 = bisect.bisect_right(self.t, t1)
        if i1 <= i0 or t1 <= t0:
            return None
        ts = np.array(self.t[i0:i1])
        g = np.array(self.gyro[i0:i1])
        a = np.array(self.accel[i0:i1])
        # Each sample's rate holds from the previous sample's stamp (or t0) to its own.
        edges = np.concatenate([[t0], ts])
        dts = np.diff(edges)
        tail = t1 - ts[-1]  # the last rate holds up to t1
        dts[-1] += tail
        w = g - self.bias
        R = ordered_product(Rotation.from_rotvec(w * dts[:, None]))
        dt = t1 - t0
        gap = float(max(dts.max(), tail))
        Rb = self.base_R_imu @ R.as_matrix() @ self.base_R_imu.T
        # White noise integrates to density^2 * dt; the bias uncertainty to dt^2 * P_b.
        cov_imu = np.eye(3) * self.noise_density**2 * dt + dt**2 * self._bias_cov_at(t1)
        cov = self.base_R_imu @ cov_imu @ self.base_R_imu.T
        return ImuInterval(Rb, cov, g.mean(axis=0), a.mean(axis=0) @ self.base_R_imu.T,
                           float(np.linalg.norm(w, axis=1).max()), len(ts), gap)

    # -- gyro bias --------------------------------------------------------------------------
    def _bias_cov_at(self, t: float) -> np.ndarray:
        if self.bias_time is None or t <= self.bias_time:
            return self.bias_cov
        return self.bias_cov + np.eye(3) * self.bias_rw**2 * (t - self.bias_time)

    def _bias_update(self, t: float, z: np.ndarray, H: float, R: np.ndarray) -> None:
        P = self._bias_cov_at(t)
        S = H * H * P + R
        K = H * P @ np.linalg.inv(S)
        self.bias = self.bias + K @ (z - H * self.bias)
        self.bias_cov = (np.eye(3) - H * K) @ P
        self.bias_time = t

    def update_bias_from_rotation(self, t0: float, t1: float, R_vision: np.ndarray,
                                  vision_cov: np.ndarray) -> None:
        """Gyro bias from a vision rotation ``b0_R_b1`` over ``[t0, t1]`` (base_link).

        With the bias b used, the gyro rotation misses the true one by about
        ``Exp(-(b_true - b) dt)``, so ``Log(R_gyro^T R_vision) / dt`` measures ``-(b_true - b)``.
        """
        iv = self.interval(t0, t1)
        if iv is None:
            return
        dt = t1 - t0
        e_base = Rotation.from_matrix(iv.R.T @ R_vision).as_rotvec()
        e = self.base_R_imu.T @ e_base
        z = self.bias - e / dt  # a direct measurement of b_true (H = 1)
        R = (np.eye(3) * self.noise_density**2 * dt
             + self.base_R_imu.T @ vision_cov @ self.base_R_imu) / dt**2
        self._bias_update(t1, z, 1.0, R)

    def update_bias_at_rest(self, t1: float, iv: ImuInterval, rate_hz: float) -> None:
        """Zero-velocity update: standing still, the mean gyro is the bias."""
        sigma2 = self.noise_density**2 * rate_hz / max(iv.n, 1)
        self._bias_update(t1, iv.mean_gyro, 1.0, np.eye(3) * sigma2)
