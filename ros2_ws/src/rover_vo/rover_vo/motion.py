"""Outlier rejection and motion estimation (paper Sec. 3): PnP RANSAC, then a robust
stereo reprojection refinement with an optional rotation prior (the gyro's), whose
Gauss-Newton information gives the motion's covariance.

``cur_T_ref`` maps points from the reference left optical frame into the current one:
``x_cur = R @ x_ref + t``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from scipy.spatial.transform import Rotation

from rover_vo.config import MotionOptions

#: PnP RANSAC hypotheses tried.
RANSAC_ITERATIONS = 200
#: Robust (Huber) loss scale of the refinement (px).
HUBER_PX = 1.0


@dataclass
class MotionEstimate:
    """Result of :func:`estimate_motion`.

    Attributes:
        R, t: ``cur_T_ref`` rotation (3x3) and translation (m).
        cov: 6x6 covariance of ``[rotvec (rad), t (m)]`` (rotation perturbation on the left).
        inliers: (N,) bool mask of the correspondences used.
        rms_px: RMS reprojection error of the inliers (px).
    """

    R: np.ndarray
    t: np.ndarray
    cov: np.ndarray
    inliers: np.ndarray
    rms_px: float


def pnp_ransac(points_ref: np.ndarray, uv_cur: np.ndarray, K: np.ndarray,
               opts: MotionOptions, R0: np.ndarray | None = None,
               t0: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """OpenCV PnP RANSAC (P3P hypotheses); ``(R, t, inlier mask)`` or None when it fails."""
    if len(points_ref) < 6:
        return None
    rvec = tvec = None
    use_guess = R0 is not None and t0 is not None
    if use_guess:
        rvec = cv2.Rodrigues(R0)[0]
        tvec = t0.reshape(3, 1).astype(float)
    ok, rvec, tvec, idx = cv2.solvePnPRansac(
        points_ref.astype(np.float64), uv_cur.astype(np.float64), K, None, rvec, tvec,
        useExtrinsicGuess=use_guess, iterationsCount=RANSAC_ITERATIONS,
        reprojectionError=opts.ransac_reprojection_px, confidence=0.999,
        flags=cv2.SOLVEPNP_AP3P)
    if not ok or idx is None or len(idx) < 6:
        return None
    mask = np.zeros(len(points_ref), bool)
    mask[idx.ravel()] = True
    return cv2.Rodrigues(rvec)[0], tvec.ravel(), mask


def _project(K: np.ndarray, X: np.ndarray) -> np.ndarray:
    z = X[:, 2]
    return np.column_stack([K[0, 0] * X[:, 0] / z + K[0, 2], K[1, 1] * X[:, 1] / z + K[1, 2]])


def _projection_jacobian(K: np.ndarray, X: np.ndarray, RX: np.ndarray) -> np.ndarray:
    """(N, 2, 6) d(pixel)/d[rotvec, t] of a point X_c = Exp(w) R x + t at w = 0.

    ``RX`` is R x (the rotated point before translation); d X_c / d w = -[R x]_x.
    """
    n = len(X)
    x, y, z = X[:, 0], X[:, 1], X[:, 2]
    dpi = np.zeros((n, 2, 3))
    dpi[:, 0, 0] = K[0, 0] / z
    dpi[:, 0, 2] = -K[0, 0] * x / z**2
    dpi[:, 1, 1] = K[1, 1] / z
    dpi[:, 1, 2] = -K[1, 1] * y / z**2
    a, b, c = RX[:, 0], RX[:, 1], RX[:, 2]
    neg_skew = np.zeros((n, 3, 3))  # -[RX]_x
    neg_skew[:, 0, 1], neg_skew[:, 0, 2] = c, -b
    neg_skew[:, 1, 0], neg_skew[:, 1, 2] = -c, a
    neg_skew[:, 2, 0], neg_skew[:, 2, 1] = b, -a
    J = np.empty((n, 2, 6))
    J[:, :, :3] = dpi @ neg_skew
    J[:, :, 3:] = dpi
    return J


def refine_motion(points_ref: np.ndarray, uv_left: np.ndarray, uv_right: np.ndarray | None,
                  K: np.ndarray, baseline_m: float, R0: np.ndarray, t0: np.ndarray,
                  opts: MotionOptions, R_prior: np.ndarray | None = None,
                  prior_cov: np.ndarray | None = None, iterations: int = 8) -> MotionEstimate:
    """Robust (Huber, by reweighting) Gauss-Newton on left and right reprojections with an
    optional rotation prior; the information matrix gives the covariance.

    Written here rather than with ``cv2.solvePnPRefineLM`` because that refines on one image
    only and takes no prior; an analytic Jacobian keeps it under a millisecond.

    Args:
        points_ref: (N, 3) reference-frame points (m).
        uv_left: (N, 2) their corners in the current left image (px).
        uv_right: (N, 2) their corners in the current right image (NaN where unmatched), or
            None.
        K, baseline_m: rectified intrinsics; the right camera sits at +baseline on x.
        R0, t0: starting ``cur_T_ref``.
        opts: motion options (pixel sigma, inlier bound).
        R_prior, prior_cov: a prior on R (the gyro's) and its 3x3 covariance (rad^2).
        iterations: Gauss-Newton steps.
    """
    sigma = opts.pixel_sigma_px
    has_r = np.zeros(len(points_ref), bool)
    if uv_right is not None:
        has_r = np.all(np.isfinite(uv_right), axis=1)
    info_prior = None
    if R_prior is not None and prior_cov is not None:
        info_prior = np.linalg.inv(prior_cov)
    offset = np.array([baseline_m, 0.0, 0.0])
    R, t = R0.copy(), np.asarray(t0, float).copy()
    H = np.eye(6)
    for _ in range(iterations):
        RX = points_ref @ R.T
        Xc = RX + t
        if np.any(Xc[:, 2] <= 1e-3):
            break
        r = [(_project(K, Xc) - uv_left)]
        J = [_projection_jacobian(K, Xc, RX)]
        if has_r.any():
            Xr = Xc[has_r] - offset
            r.append(_project(K, Xr) - uv_right[has_r])
            J.append(_projection_jacobian(K, Xr, RX[has_r]))
        res = np.concatenate(r)  # (M, 2) px
        Jm = np.concatenate(J)  # (M, 2, 6)
        # Huber weights per corner (on its 2D error), then the normal equations.
        e = np.linalg.norm(res, axis=1)
        w = np.where(e <= HUBER_PX, 1.0, HUBER_PX / np.maximum(e, 1e-12))
        w = w / sigma**2
        H = np.einsum("n,nij,nik->jk", w, Jm, Jm)
        g = np.einsum("n,nij,ni->j", w, Jm, res)
        if info_prior is not None:
            e_r = Rotation.from_matrix(R @ R_prior.T).as_rotvec()
            H[:3, :3] += info_prior
            g[:3] += info_prior @ e_r
        try:
            dx = -np.linalg.solve(H, g)
        except np.linalg.LinAlgError:
            break
        R = Rotation.from_rotvec(dx[:3]).as_matrix() @ R
        t = t + dx[3:]
        if np.linalg.norm(dx) < 1e-10:
            break
    try:
        cov = np.linalg.inv(H)
    except np.linalg.LinAlgError:
        cov = np.full((6, 6), np.inf)
    Xc = points_ref @ R.T + t
    err = np.linalg.norm(_project(K, Xc) - uv_left, axis=1)
    inl = err < opts.ransac_reprojection_px * 2
    rms = float(np.sqrt(np.mean(err[inl] ** 2))) if inl.any() else float("inf")
    return MotionEstimate(R, t, cov, inl, rms)


def estimate_motion(points_ref: np.ndarray, uv_left: np.ndarray, uv_right: np.ndarray | None,
                    K: np.ndarray, baseline_m: float, opts: MotionOptions,
                    R_guess: np.ndarray | None = None, t_guess: np.ndarray | None = None,
                    R_prior: np.ndarray | None = None,
                    prior_cov: np.ndarray | None = None) -> MotionEstimate | None:
    """Outlier rejection (PnP RANSAC) then refinement; None when too few inliers remain."""
    ransac = pnp_ransac(points_ref, uv_left, K, opts, R_guess, t_guess)
    if ransac is None or ransac[2].sum() < opts.min_inliers:
        return None
    R0, t0, inl = ransac
    ur = uv_right[inl] if uv_right is not None else None
    est = refine_motion(points_ref[inl], uv_left[inl], ur, K, baseline_m, R0, t0, opts,
                        R_prior, prior_cov)
    mask = np.zeros(len(points_ref), bool)
    mask[np.flatnonzero(inl)[est.inliers]] = True
    est.inliers = mask
    if mask.sum() < opts.min_inliers:
        return None
    return est
