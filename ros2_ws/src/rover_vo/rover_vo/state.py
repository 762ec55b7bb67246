"""The odometry state: pose of base_link in odom, its covariance, distance driven.

Error state ``[dp (odom, m), dtheta (odom, rad), ds, db]`` with ``R = Exp(dtheta) R_hat``.
A motion step ``b0_T_b1 = (dR, dp)`` composes as ``p' = p + R dp``, ``R' = R dR``; its
noise is given in the body frame and rotated into odom, and the heading uncertainty
couples into position through ``-[R dp]_x``: the covariance grows with the distance driven,
faster than linearly once the heading is uncertain, as odometry error does.

Two of the errors are systematic, not random walks, and are carried as constant states
with a prior: ``ds``, the relative scale error of the stereo odometry (calibration and
disparity bias make every step a little long or short, so the along-track error grows
linearly with distance), entering position as ``R dp ds``; and ``db``, a heading-rate bias
(rad per metre driven, about the body's up axis), entering the attitude as
``R e_z |dp| db``. Only the 6x6 pose block (``cov``) is published; the full 8x8 ``P`` keeps
the correlations that make these errors grow as they do. With a sun sensor ``P`` gains
five states: ``psi0``, the odom frame's grid azimuth, and four bias states of the sun
sensor and the gravity tilt (:mod:`rover_vo.sun_heading`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np


def skew(v: np.ndarray) -> np.ndarray:
    """Cross-product matrix of a 3-vector."""
    return np.array([[0, -v[2], v[1]], [v[2], 0, -v[0]], [-v[1], v[0], 0]])


N_ERR = 8  #: error-state size: dp (3), dtheta (3), scale, heading rate


def systematic_prior(scale_sigma: float, heading_rate_sigma_deg_per_100m: float) -> np.ndarray:
    """8x8 initial ``P``: the pose known exactly, the systematic errors from their priors."""
    P = np.zeros((N_ERR, N_ERR))
    P[6, 6] = scale_sigma**2
    P[7, 7] = np.radians(heading_rate_sigma_deg_per_100m / 100.0) ** 2
    return P


@dataclass
class OdomState:
    """Pose ``odom_T_base`` at time ``t``, its error covariance ``P`` (8x8, see the module)
    and the distance driven."""

    t: float
    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    p: np.ndarray = field(default_factory=lambda: np.zeros(3))
    P: np.ndarray = field(default_factory=lambda: np.zeros((N_ERR, N_ERR)))
    distance_m: float = 0.0

    @property
    def cov(self) -> np.ndarray:
        """6x6 pose covariance ``[dp, dtheta]`` (odom), the marginal of ``P``."""
        return self.P[:6, :6]

    def matrix(self) -> np.ndarray:
        """4x4 ``odom_T_base``."""
        T = np.eye(4)
        T[:3, :3], T[:3, 3] = self.R, self.p
        return T

    def copy(self) -> OdomState:
        return OdomState(self.t, self.R.copy(), self.p.copy(), self.P.copy(), self.distance_m)

    def compose(self, t: float, dR: np.ndarray, dp: np.ndarray, Q_body: np.ndarray) -> OdomState:
        """The state after the body moved by ``b0_T_b1 = (dR, dp)``, with noise ``Q_body``.

        Args:
            t: stamp of the new state (s).
            dR, dp: the motion in the old body frame.
            Q_body: 6x6 covariance of ``[dp, dtheta]`` in the old body frame.
        """
        step = self.R @ dp
        n = self.P.shape[0]  # N_ERR, or N_ERR + 5 with the sun heading's states
        F = np.eye(n)
        F[:3, 3:6] = -skew(step)
        F[:3, 6] = step  # scale error: the step was (1 + ds) times longer
        F[3:6, 7] = self.R[:, 2] * float(np.linalg.norm(dp))  # heading-rate bias
        G = np.zeros((n, 6))
        G[:3, :3] = self.R
        G[3:6, 3:] = self.R
        P = F @ self.P @ F.T + G @ Q_body @ G.T
        return OdomState(t, self.R @ dR, self.p + step, 0.5 * (P + P.T),
                         self.distance_m + float(np.linalg.norm(dp)))

    def ros_covariance(self) -> np.ndarray:
        """6x6 covariance in ROS order ``[x y z rx ry rz]`` (odom frame), as Odometry wants."""
        return self.cov.copy()


def step_noise(step_m: float, translation_sigma_per_m: float,
               rotation_sigma_deg_per_sqrt_m: float, measured: np.ndarray | None = None
               ) -> np.ndarray:
    """6x6 body-frame noise ``[dp, dtheta]`` of a motion step of ``step_m`` metres.

    A model that grows with the distance (sigma proportional to the step for translation,
    to its square root for rotation, i.e. random walks along the path), never below the
    estimate's own information-based covariance ``measured`` (``[rotvec, t]`` order).
    """
    st = translation_sigma_per_m * step_m
    sr = np.radians(rotation_sigma_deg_per_sqrt_m) * np.sqrt(step_m)
    Q = np.diag([st**2] * 3 + [sr**2] * 3)
    if measured is not None and np.all(np.isfinite(measured)):
        M = np.zeros((6, 6))
        M[:3, :3], M[3:, 3:] = measured[3:, 3:], measured[:3, :3]
        M[:3, 3:], M[3:, :3] = measured[3:, :3], measured[:3, 3:]
        # Keep the model unless the measurement is worse in some direction.
        w, V = np.linalg.eigh(np.linalg.solve(np.linalg.cholesky(Q), np.eye(6)) @ M
                              @ np.linalg.solve(np.linalg.cholesky(Q), np.eye(6)).T)
        if w.max() > 1:
            L = np.linalg.cholesky(Q)
            Q = L @ (V @ np.diag(np.maximum(w, 1)) @ V.T) @ L.T
    return Q
