"""Verification and voting over the whole Local Network, and the least-squares refit.

Paper Sec. 6: not "winner takes all" on a triangle: every hypothesis is verified against
the whole LN (minor and major ROIs), and the support of a transform is the number of LN
nodes that land within their tolerance of a GN node of the same class.
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import linear_sum_assignment

from darces_matcher.gn_index import GnIndex
from darces_matcher.hypotheses import apply_batch, fit_rigid_batch

#: Candidates per LN node in the one-to-one assignment.
_K = 3


def vote(
    index: GnIndex,
    groups: list,
    node_tol: np.ndarray,
    mapped: np.ndarray,
) -> np.ndarray:
    """Support of each hypothesis: LN nodes with a same-class GN node within tolerance.

    Args:
        index: the GN index.
        groups: :meth:`GnIndex.label_groups` of the LN nodes.
        node_tol: (N,) position tolerance of each LN node, metres.
        mapped: (H, N, 2) LN positions mapped into ``map`` by each hypothesis, metres.

    Returns:
        (H,) int support counts.
    """
    if mapped.shape[0] == 0:
        return np.zeros(0, dtype=np.int64)
    dist, _ = index.nearest_same_label(mapped, groups, float(node_tol.max()))
    return (dist <= node_tol[None, :]).sum(axis=1)


def associate(
    index: GnIndex,
    mapped: np.ndarray,
    groups: list,
    node_tol: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One-to-one LN -> GN inliers of one transform.

    Args:
        index: the GN index.
        mapped: (N, 2) LN positions mapped into ``map``, metres.
        groups: :meth:`GnIndex.label_groups` of the LN nodes.
        node_tol: (N,) tolerances, metres.

    Returns:
        LN indices, GN indices and distances (metres) of the inliers. When LN nodes
        compete for a GN node, an optimal assignment over each node's nearest
        candidates (most pairs, then least sum of squared normalised distances) decides,
        so that the loser can still take its second-nearest GN node.
    """
    dist, gn = index.nearest_same_label(mapped, groups, float(node_tol.max()), k=_K)
    valid = dist <= node_tol[:, None]
    ln = np.flatnonzero(valid[:, 0])
    first = gn[ln, 0]
    if len(np.unique(first)) == len(first):
        # No competition (the common case): every node keeps its nearest GN node.
        return ln, first, dist[ln, 0]
    rows = np.flatnonzero(valid.any(axis=1))
    cols, col_of = np.unique(gn[rows][valid[rows]], return_inverse=True)
    cost = np.full((len(rows), len(cols)), 1e6)
    r_idx = np.repeat(np.arange(len(rows)), valid[rows].sum(axis=1))
    cost[r_idx, col_of] = (dist[rows][valid[rows]] / node_tol[rows][r_idx]) ** 2
    # Hand-written cost matrix, scipy's Hungarian solver: tiny (LN nodes x candidates).
    r, c = linear_sum_assignment(cost)
    ok = cost[r, c] < 1e6
    ln, gn_out = rows[r[ok]], cols[c[ok]]
    order = np.argsort(ln)
    ln, gn_out = ln[order], gn_out[order]
    return ln, gn_out, np.linalg.norm(mapped[ln] - index.pts[gn_out], axis=1)


def refine(
    index: GnIndex,
    ln_pts: np.ndarray,
    groups: list,
    gate: np.ndarray,
    weights: np.ndarray,
    yaw: float,
    t: np.ndarray,
    *,
    iterations: int,
    n_sigma: float,
    max_gate: float,
    max_drops: int = 3,
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Iterate association and weighted least-squares refit on all inliers.

    After each fit the gate of every node widens by the fit's own predicted uncertainty
    at that node (propagated from the (x, y, yaw) covariance): when a fit rests on far,
    drifted nodes, the precise nodes it misplaces by more than their node tolerance can
    still join, and then anchor it.

    Args:
        index: the GN index.
        ln_pts: (N, 2) LN positions, ``odom``, metres.
        groups: :meth:`GnIndex.label_groups` of the LN nodes.
        gate: (N,) base association gate of each node, metres.
        weights: (N,) least-squares weights, inverse per-axis variance, 1/m^2.
        yaw: initial rotation of ``map_T_odom``, radians.
        t: (2,) initial translation of ``map_T_odom``, metres.
        iterations: maximum number of association/refit rounds.
        n_sigma: gate width in standard deviations.
        max_gate: widest gate, metres.
        max_drops: most inliers excluded by the leave-one-out leverage check.

    Returns:
        Refined yaw (rad), translation (m), and the LN and GN indices of the inliers.
    """
    yaw_arr, t_arr = np.array([yaw]), np.asarray(t, dtype=float)[None, :]
    ln_in = gn_in = np.zeros(0, dtype=np.int64)
    excluded = np.zeros(len(ln_pts), dtype=bool)
    for _ in range(1 + max_drops):
        base = np.where(excluded, 0.0, gate)
        node_gate = base
        ln_in = gn_in = np.zeros(0, dtype=np.int64)
        for _ in range(iterations):
            mapped = apply_batch(yaw_arr, t_arr, ln_pts)[0]
            new_ln, new_gn, _ = associate(index, mapped, groups, node_gate)
            if np.array_equal(new_ln, ln_in) and np.array_equal(new_gn, gn_in):
                # Converged: the inliers of the current fit are the ones it was fitted on.
                break
            if len(new_ln) < 3:
                break
            ln_in, gn_in = new_ln, new_gn
            yaw_arr, t_arr = fit_rigid_batch(
                ln_pts[ln_in][None], index.pts[gn_in][None], weights[ln_in][None]
            )
            cov = pose_covariance(ln_pts[ln_in], float(yaw_arr[0]), weights[ln_in])
            fit_var = predicted_variance(ln_pts, float(yaw_arr[0]), cov)
            # At most twice the base gate: wider would let false associations in.
            widest = np.minimum(2 * base, max_gate)
            node_gate = np.clip(n_sigma * np.sqrt(1.0 / weights + fit_var), base, widest)
        if len(ln_in) < 5:
            break
        # Leverage check: a wrong association on a precise node can hold the whole fit.
        # Refit without each inlier in turn; the one the others place furthest outside
        # its gate is excluded, and the fit redone.
        miss = leave_one_out_residual(ln_pts[ln_in], index.pts[gn_in], weights[ln_in])
        worst = int(np.argmax(miss / gate[ln_in]))
        if miss[worst] <= gate[ln_in[worst]]:
            break
        excluded[ln_in[worst]] = True
    # Support is counted with the base gate, the same for every hypothesis.
    mapped = apply_batch(yaw_arr, t_arr, ln_pts)[0]
    ln_in, gn_in, _ = associate(index, mapped, groups, np.where(excluded, 0.0, gate))
    return float(yaw_arr[0]), t_arr[0], ln_in, gn_in


def leave_one_out_residual(src: np.ndarray, dst: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Distance (m) between each destination point and its source point mapped by the
    weighted fit of all the other pairs.

    Args:
        src: (K, 2) ``odom`` points; dst: (K, 2) ``map`` points; weights: (K,).
    """
    k = len(src)
    w = np.broadcast_to(weights, (k, k)).copy()
    np.fill_diagonal(w, 0.0)
    yaw, t = fit_rigid_batch(np.broadcast_to(src, (k, k, 2)), np.broadcast_to(dst, (k, k, 2)), w)
    c, s = np.cos(yaw), np.sin(yaw)
    pred = np.column_stack([c * src[:, 0] - s * src[:, 1], s * src[:, 0] + c * src[:, 1]]) + t
    return np.linalg.norm(pred - dst, axis=1)


def predicted_variance(ln_pts: np.ndarray, yaw: float, cov: np.ndarray) -> np.ndarray:
    """Per-axis variance (m^2) of LN nodes mapped by a fit with (x, y, yaw) covariance."""
    c, s = np.cos(yaw), np.sin(yaw)
    rx = c * ln_pts[:, 0] - s * ln_pts[:, 1]
    ry = s * ln_pts[:, 0] + c * ln_pts[:, 1]
    var_x = cov[0, 0] - 2 * cov[0, 2] * ry + cov[2, 2] * ry**2
    var_y = cov[1, 1] + 2 * cov[1, 2] * rx + cov[2, 2] * rx**2
    return np.nan_to_num(0.5 * (var_x + var_y), nan=np.inf, posinf=np.inf)


def pose_covariance(ln_pts: np.ndarray, yaw: float, weights: np.ndarray) -> np.ndarray:
    """(x, y, yaw) covariance of the weighted least-squares ``map_T_odom``.

    Gauss-Newton information J^T W J of the residuals R(yaw) p_i + t - g_i with
    isotropic weights w_i (1/m^2); x, y are the translation of ``map_T_odom`` (m) and
    yaw its rotation (rad).

    Args:
        ln_pts: (K, 2) inlier LN positions, ``odom``, metres.
        yaw: fitted rotation, radians.
        weights: (K,) inverse variances, 1/m^2.

    Returns:
        (3, 3) covariance; ``inf`` on the diagonal if the fit is undetermined.
    """
    c, s = np.cos(yaw), np.sin(yaw)
    rp = ln_pts @ np.array([[c, -s], [s, c]]).T
    # d(residual)/d(x, y, yaw) for one point: [[1, 0, -rp_y], [0, 1, rp_x]].
    info = np.zeros((3, 3))
    info[0, 0] = info[1, 1] = weights.sum()
    info[0, 2] = info[2, 0] = -(weights * rp[:, 1]).sum()
    info[1, 2] = info[2, 1] = (weights * rp[:, 0]).sum()
    info[2, 2] = (weights * (rp**2).sum(axis=1)).sum()
    try:
        cov = np.linalg.inv(info)
    except np.linalg.LinAlgError:
        return np.diag([np.inf, np.inf, np.inf])
    return 0.5 * (cov + cov.T)
