"""The fit of a fix's inlier pairs under the LN's correlated drift (generalized least
squares), and the pairs that drift cannot explain.

The search and the EM weigh each LN node by its own sigma, as if the nodes' errors were
independent (:meth:`~darces_matcher.matcher.Matcher.node_sigma`). Once the rover is
localized those sigmas are relative to the newest node, and an LN that reaches 500 m
back gives each old node its whole drift, metres, on its own: the fit may then turn the
old nodes as a group, by degrees, to follow one new pair, since twelve independent
3.4 m errors allow that much (held-out bag s113 at 822 m: a new node with no GN
counterpart, paired with a rock 14.6 m away, turned the fit 2.9 deg and its analytic
covariance claimed 0.3 m at the rover). In the odometry the old nodes' drift relative to
the rover is largely common, and their geometry among themselves is as good as the
odometry between them: :func:`~darces_matcher.ln_drift.chain_covariance` gives the
joint covariance.

Under that covariance:

- :func:`gls_fit` fits the rigid ``map_T_odom`` by Gauss-Newton on the residuals
  ``R(yaw) p_i + t - g_i`` with the LN's covariance (rotated into ``map``) plus the GN
  nodes' own; its covariance ``(J^T S^-1 J)^-1`` is that of the alignment valid at the
  anchor node;
- :func:`deletion_statistics` gives, per pair, the drop in chi-square when the pair is
  given a free shift (the mean-shift outlier test; with correlated errors the same as
  leaving the pair out): chi-square with 2 degrees of freedom for a pair that drift
  explains, whatever the others' correlation with it. It also gives each pair's
  leave-one-out alignment, for the jackknife;
- :func:`drift_consistent_fit` drops the worst pair while its statistic exceeds the
  gate, refits, and returns the fit of the pairs kept.

The statistics are scaled by a robust estimate of how far the odometry's covariance
understates the spread (the median statistic over its expectation under chi-square 2,
never below 1): a VO covariance that is too small must not cost the good pairs.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.linalg import cho_factor, cho_solve

#: median of chi-square with 2 degrees of freedom (2 ln 2)
CHI2_2_MEDIAN = 2.0 * math.log(2.0)


@dataclass
class GlsFit:
    """A generalized least-squares rigid fit of pairs."""

    yaw: float
    t: np.ndarray
    #: (3, 3) covariance of (x, y, yaw) of ``map_T_odom``
    covariance: np.ndarray
    chi2: float


@dataclass
class DriftFit:
    """:func:`drift_consistent_fit`'s outcome."""

    fit: GlsFit
    #: indices of the pairs kept (into the pairs given)
    kept: np.ndarray
    #: indices of the pairs dropped, worst first
    dropped: np.ndarray
    #: (3, 3) jackknife covariance of the kept pairs' leave-one-out alignments (inf on the
    #: diagonal for fewer than 4 pairs)
    jackknife: np.ndarray
    #: how far the odometry covariance understates the spread (>= 1)
    scale: float


def _rotate_blocks(cov: np.ndarray, yaw: float) -> np.ndarray:
    """``B cov B^T`` for ``B`` block-diagonal with the 2D rotation by ``yaw``."""
    c, s = math.cos(yaw), math.sin(yaw)
    k = cov.shape[0] // 2
    c4 = cov.reshape(k, 2, k, 2)
    r = np.array([[c, -s], [s, c]])
    return np.einsum("ab,ibjc,dc->iajd", r, c4, r).reshape(2 * k, 2 * k)


def _system(src: np.ndarray, dst: np.ndarray, cov: np.ndarray, gn_var: float,
            yaw: float, t: np.ndarray):
    """Residuals, Jacobian and the Cholesky factor of the residuals' covariance at
    (yaw, t)."""
    c, s = math.cos(yaw), math.sin(yaw)
    rx = c * src[:, 0] - s * src[:, 1]
    ry = s * src[:, 0] + c * src[:, 1]
    r = np.column_stack([rx + t[0] - dst[:, 0], ry + t[1] - dst[:, 1]]).ravel()
    k = len(src)
    J = np.zeros((2 * k, 3))
    J[0::2, 0] = 1.0
    J[1::2, 1] = 1.0
    J[0::2, 2] = -ry
    J[1::2, 2] = rx
    S = _rotate_blocks(cov, yaw)
    S[np.diag_indices(2 * k)] += gn_var
    return r, J, cho_factor(S, lower=True)


def gls_fit(src: np.ndarray, dst: np.ndarray, cov: np.ndarray, gn_var: float,
            yaw: float, t: np.ndarray, iterations: int = 4) -> GlsFit:
    """Generalized least-squares rigid ``map_T_odom`` of K pairs, by Gauss-Newton from
    (yaw, t).

    Args:
        src: (K, 2) LN positions, ``odom``, m; dst: (K, 2) GN positions, ``map``, m.
        cov: (2K, 2K) covariance of the LN positions' errors (``odom``), rows
            (x_0, y_0, x_1, ...), e.g. :func:`~darces_matcher.ln_drift.chain_covariance`.
        gn_var: per-axis variance of a GN node, m^2.
        yaw, t: the starting alignment (rad, (2,) m).
        iterations: Gauss-Newton steps.

    Returns:
        The fit; its covariance ``inf`` on the diagonal when it is undetermined.
    """
    t = np.asarray(t, dtype=float).copy()
    for _ in range(iterations):
        r, J, cho = _system(src, dst, cov, gn_var, yaw, t)
        A = J.T @ cho_solve(cho, J)
        try:
            step = -np.linalg.solve(A, J.T @ cho_solve(cho, r))
        except np.linalg.LinAlgError:
            return GlsFit(yaw, t, np.diag([np.inf] * 3), math.inf)
        t += step[:2]
        yaw += float(step[2])
        if np.abs(step[:2]).max() < 1e-6 and abs(step[2]) < 1e-9:
            break
    r, J, cho = _system(src, dst, cov, gn_var, yaw, t)
    A = J.T @ cho_solve(cho, J)
    try:
        covariance = np.linalg.inv(A)
    except np.linalg.LinAlgError:
        covariance = np.diag([np.inf] * 3)
    return GlsFit(math.atan2(math.sin(yaw), math.cos(yaw)), t, covariance,
                  float(r @ cho_solve(cho, r)))


def deletion_statistics(src: np.ndarray, dst: np.ndarray, cov: np.ndarray, gn_var: float,
                        fit: GlsFit) -> tuple[np.ndarray, np.ndarray]:
    """Per pair, the mean-shift outlier statistic and the leave-one-out alignment.

    With ``S`` the residuals' covariance, ``M = S^-1 - S^-1 J A^-1 J^T S^-1`` and ``r``
    the residuals ``R(yaw) p + t - g`` at the fit, pair i's free shift
    ``s_i = -M_ii^-1 (M r)_i`` lowers the chi-square by ``(M r)_i^T M_ii^-1 (M r)_i``
    (chi-square 2 under the model) and moves the alignment by ``-A^-1 J^T S^-1 E_i s_i``,
    ``E_i`` pair i's two columns (linearized at the fit).

    Returns:
        (K,) statistics and (K, 3) leave-one-out (x, y, yaw) of ``map_T_odom``.
    """
    k = len(src)
    r, J, cho = _system(src, dst, cov, gn_var, fit.yaw, fit.t)
    Sinv_J = cho_solve(cho, J)
    A_inv = np.linalg.inv(J.T @ Sinv_J)
    Sinv = cho_solve(cho, np.eye(2 * k))
    M = Sinv - Sinv_J @ A_inv @ Sinv_J.T
    Mr = (M @ r).reshape(k, 2)
    Mb = M.reshape(k, 2, k, 2)[np.arange(k), :, np.arange(k), :]  # (K, 2, 2)
    shift = -np.linalg.solve(Mb, Mr[..., None])[..., 0]
    stat = -np.einsum("ki,ki->k", Mr, shift)
    # Alignment without pair i: - A^-1 J^T S^-1 E_i s_i; (J^T S^-1 E_i) = Sinv_J rows.
    g = Sinv_J.reshape(k, 2, 3)
    moved = -np.einsum("ab,kcb,kc->ka", A_inv, g, shift)
    base = np.array([fit.t[0], fit.t[1], fit.yaw])
    return stat, base + moved


def drift_consistent_fit(src: np.ndarray, dst: np.ndarray, cov: np.ndarray, gn_var: float,
                         yaw: float, t: np.ndarray, gate: float,
                         min_pairs: int = 3) -> DriftFit:
    """The GLS fit of the pairs that the LN's drift explains.

    Fits all pairs (:func:`gls_fit`), then drops the pair with the largest deletion
    statistic (:func:`deletion_statistics`, over the robust scale) while it exceeds
    ``gate`` and more than ``min_pairs`` remain, refitting each time.

    Args:
        src, dst, cov, gn_var: as in :func:`gls_fit` (``cov`` over all K pairs).
        yaw, t: the starting alignment (the fix's).
        gate: a chi-square 2 value (``-2 ln p`` for a per-pair false-alarm rate p).
        min_pairs: never fewer pairs than this.

    Returns:
        The :class:`DriftFit` of the pairs kept.
    """
    kept = np.arange(len(src))
    dropped: list[int] = []
    while True:
        idx = np.column_stack([2 * kept, 2 * kept + 1]).ravel()
        sub = cov[np.ix_(idx, idx)]
        fit = gls_fit(src[kept], dst[kept], sub, gn_var, yaw, t)
        yaw, t = fit.yaw, fit.t
        if not np.all(np.isfinite(fit.covariance)):
            return DriftFit(fit, kept, np.array(dropped, dtype=np.int64),
                            np.diag([np.inf] * 3), 1.0)
        stat, loo = deletion_statistics(src[kept], dst[kept], sub, gn_var, fit)
        scale = max(1.0, float(np.median(stat)) / CHI2_2_MEDIAN)
        worst = int(np.argmax(stat))
        if stat[worst] / scale <= gate or len(kept) <= min_pairs:
            break
        dropped.append(int(kept[worst]))
        kept = np.delete(kept, worst)
    n = len(kept)
    if n < 4:
        jack = np.diag([np.inf] * 3)
    else:
        theta = loo.copy()
        theta[:, 2] = np.angle(np.exp(1j * (theta[:, 2] - fit.yaw)))
        d = theta - theta.mean(axis=0)
        jack = (n - 1) / n * (d.T @ d)
    fit.covariance = fit.covariance * scale
    return DriftFit(fit, kept, np.array(dropped, dtype=np.int64), jack, scale)
