"""Verification and voting over the whole Local Network, and the least-squares refit.

Paper Sec. 6: not "winner takes all" on a triangle: every hypothesis is verified against
the whole LN (minor and major ROIs), and the support of a transform is the number of LN
nodes that land within their tolerance of a GN node of the same class.
"""

from __future__ import annotations

import math

import numpy as np
from scipy.optimize import linear_sum_assignment

from darces_matcher.gn_index import GnIndex

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


def displacement(mapped: np.ndarray, ref: np.ndarray, node_tol: np.ndarray) -> np.ndarray:
    """Largest displacement of LN nodes between transforms, in node tolerances.

    Args:
        mapped: (H, N, 2) or (N, 2) LN nodes mapped by the hypotheses, metres.
        ref: (N, 2) LN nodes mapped by the reference transform, metres.
        node_tol: (N,) node tolerances, metres.
    """
    return np.max(np.linalg.norm(mapped - ref, axis=-1) / node_tol, axis=-1)


def triplet_votes(
    ln_idx: np.ndarray,
    gn_idx: np.ndarray,
    source: np.ndarray,
    mapped: np.ndarray,
    fix_ln: np.ndarray,
    fix_gn: np.ndarray,
    fix_mapped: np.ndarray,
    gate: np.ndarray,
    same_ratio: float,
) -> int:
    """Control triplets that vote for a refined fix.

    A triplet votes when one of its triangle hypotheses is made of three of the fix's
    inlier pairs, or is the same alignment: every LN node within ``same_ratio`` gates of
    where the fix maps it. In a rock cluster a right hypothesis may hold a vertex on the
    neighbouring rock, which the refit exchanges for the right one: the alignment is the
    triangle's, its pairs are not.

    Args:
        ln_idx, gn_idx: (H, 3) LN and GN vertices of each hypothesis.
        source: (H,) control triplet of each hypothesis.
        mapped: (H, N, 2) the LN mapped by each hypothesis, metres.
        fix_ln, fix_gn: the fix's inlier pairs (LN, GN indices).
        fix_mapped: (N, 2) the LN mapped by the fix, metres.
        gate: (N,) verification gate of each LN node, metres.
        same_ratio: largest displacement of a node, in gates, of the same alignment.
    """
    if not len(source):
        return 0
    agree = agreeing(ln_idx, gn_idx, mapped, fix_ln, fix_gn, fix_mapped, gate, same_ratio)
    return len(np.unique(source[agree]))


def agreeing(
    ln_idx: np.ndarray,
    gn_idx: np.ndarray,
    mapped: np.ndarray,
    fix_ln: np.ndarray,
    fix_gn: np.ndarray,
    fix_mapped: np.ndarray,
    gate: np.ndarray,
    same_ratio: float,
) -> np.ndarray:
    """(H,) mask of the triangle hypotheses that are a fix: made of three of its inlier
    pairs, or the same alignment (every LN node within ``same_ratio`` gates of where the
    fix maps it). Arguments as :func:`triplet_votes`'."""
    if not len(ln_idx):
        return np.zeros(0, dtype=bool)
    partner = np.full(len(fix_mapped), -1, dtype=np.int64)
    partner[fix_ln] = fix_gn
    agree = (partner[ln_idx] == gn_idx).all(axis=1)
    agree |= displacement(mapped, fix_mapped, gate) <= same_ratio
    return agree


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
    if len(set(first.tolist())) == len(first):
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
    readmit: bool = True,
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
        readmit: try left-out nodes back in the end (:func:`_readmit`).

    Returns:
        Refined yaw (rad), translation (m), and the LN and GN indices of the inliers.
    """
    yaw, t = float(yaw), np.asarray(t, dtype=float)
    ln_in = gn_in = np.zeros(0, dtype=np.int64)
    excluded = np.zeros(len(ln_pts), dtype=bool)
    ln_var = 1.0 / weights
    gn_pts = index.pts
    for _ in range(1 + max_drops):
        base = np.where(excluded, 0.0, gate)
        # At most twice the base gate: wider would let false associations in.
        widest = np.minimum(2 * base, max_gate)
        node_gate = base
        ln_in = gn_in = np.zeros(0, dtype=np.int64)
        for _ in range(iterations):
            mapped = transform_points(yaw, t, ln_pts)
            new_ln, new_gn, _ = associate(index, mapped, groups, node_gate)
            if np.array_equal(new_ln, ln_in) and np.array_equal(new_gn, gn_in):
                # Converged: the inliers of the current fit are the ones it was fitted on.
                break
            if len(new_ln) < 3:
                break
            ln_in, gn_in = new_ln, new_gn
            yaw, t = fit_rigid(ln_pts[ln_in], gn_pts[gn_in], weights[ln_in])
            cov = pose_covariance(ln_pts[ln_in], yaw, weights[ln_in])
            fit_var = predicted_variance(ln_pts, yaw, cov)
            node_gate = np.clip(n_sigma * np.sqrt(ln_var + fit_var), base, widest)
        if len(ln_in) < 5:
            break
        # Leverage check: a wrong association on a precise node can hold the whole fit.
        # Refit without each inlier in turn; the one the others place furthest outside
        # its gate is excluded, and the fit redone.
        miss = leave_one_out_residual(ln_pts[ln_in], gn_pts[gn_in], weights[ln_in])
        ratio = miss / gate[ln_in]
        worst = int(np.argmax(ratio))
        if ratio[worst] <= 1.0:
            break
        excluded[ln_in[worst]] = True
    # Support is counted with the base gate, the same for every hypothesis.
    mapped = transform_points(yaw, t, ln_pts)
    ln_in, gn_in, _ = associate(index, mapped, groups, np.where(excluded, 0.0, gate))
    if readmit and 3 <= len(ln_in) < len(ln_pts):
        yaw, t, ln_in, gn_in = _readmit(index, ln_pts, groups, gate, weights, max_gate,
                                        yaw, t, ln_in, gn_in, mapped)
    return yaw, t, ln_in, gn_in


def _readmit(
    index: GnIndex,
    ln_pts: np.ndarray,
    groups: list,
    gate: np.ndarray,
    weights: np.ndarray,
    max_gate: float,
    yaw: float,
    t: np.ndarray,
    ln_in: np.ndarray,
    gn_in: np.ndarray,
    mapped: np.ndarray,
    max_tries: int = 2,
) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """Try left-out nodes back into a refined fit; keep a refit with more inliers.

    The refit path can leave out a right pair, typically the first, precise node when
    the fit rests on far, drifted nodes (or a wrong pair among them pulled it away):
    it then lies just outside its small gate. Only when at most ``max_tries`` nodes are
    left out and every one of them has a GN node of its class within twice its gate (an
    LN with a node near no GN node holds outliers, and a near one may be an outlier too:
    its readmission would pull a right fit away): each (most precise first) is added to
    the inliers, the fit redone and the whole LN re-associated with the base gates; that
    fit replaces the current one when it has more inliers (the criterion that ranks
    candidates).
    """
    out = np.ones(len(ln_pts), dtype=bool)
    out[ln_in] = False
    nodes = np.flatnonzero(out)
    if len(nodes) > max_tries:
        return yaw, t, ln_in, gn_in
    wide = np.minimum(2 * gate[nodes], max_gate)
    dist, gn = index.nearest_same_label(mapped[nodes], _subset(groups, nodes),
                                        float(wide.max()))
    near = dist <= wide
    if not near.all():
        # A left-out node with no GN node near it is an outlier (false detection, GN
        # miss): this LN has some, and a near node may then be one too. Readmit only
        # into fits that explain every other node.
        return yaw, t, ln_in, gn_in
    taken = set(gn_in.tolist())
    tries = [(nodes[i], gn[i]) for i in np.argsort(gate[nodes], kind="stable")
             if near[i] and int(gn[i]) not in taken][:max_tries]
    for node, partner in tries:
        src = np.append(ln_in, node)
        dst = np.append(gn_in, partner)
        y2, t2 = fit_rigid(ln_pts[src], index.pts[dst], weights[src])
        for _ in range(2):
            ln2, gn2, _ = associate(index, transform_points(y2, t2, ln_pts), groups, gate)
            if len(ln2) < 3:
                break
            y2, t2 = fit_rigid(ln_pts[ln2], index.pts[gn2], weights[ln2])
        ln2, gn2, _ = associate(index, transform_points(y2, t2, ln_pts), groups, gate)
        if len(ln2) > len(ln_in):
            yaw, t, ln_in, gn_in = y2, t2, ln2, gn2
            break
    return yaw, t, ln_in, gn_in


def _subset(groups: list, nodes: np.ndarray) -> list:
    """:meth:`GnIndex.label_groups` of a subset of the LN nodes (in ``nodes`` order)."""
    out = []
    for group in groups:
        tree, members, sel, z = group[:4]
        if z is None:
            out.append((tree, members, np.arange(len(nodes)), None))
        else:
            pos = np.full(int(sel.max(initial=-1)) + 1, -1)
            pos[sel] = np.arange(len(sel))
            keep = pos[nodes]
            out.append((tree, members, np.arange(len(nodes)), z[keep], group[4][keep]))
    return out


def transform_points(yaw: float, t: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(N, 2) points mapped by one rigid transform (yaw rad, translation t m)."""
    c, s = math.cos(yaw), math.sin(yaw)
    return pts @ np.array([[c, s], [-s, c]]) + t


def fit_rigid(src: np.ndarray, dst: np.ndarray, weights: np.ndarray) -> tuple[float, np.ndarray]:
    """Weighted least-squares proper rigid transform of one correspondence set.

    The single-set form of :func:`~darces_matcher.hypotheses.fit_rigid_batch` (same
    closed-form 2D Kabsch, never a reflection), without the batch overhead.

    Args:
        src: (K, 2) ``odom`` points; dst: (K, 2) ``map`` points, metres;
        weights: (K,) non-negative weights.

    Returns:
        yaw (rad) and (2,) translation (m) of ``map_T_odom``.
    """
    w = weights / max(float(weights.sum()), 1e-300)
    ca, cb = w @ src, w @ dst
    a0, b0 = src - ca, dst - cb
    cos = float(w @ (a0[:, 0] * b0[:, 0] + a0[:, 1] * b0[:, 1]))
    sin = float(w @ (a0[:, 0] * b0[:, 1] - a0[:, 1] * b0[:, 0]))
    yaw = math.atan2(sin, cos)
    c, s = math.cos(yaw), math.sin(yaw)
    return yaw, cb - np.array([c * ca[0] - s * ca[1], s * ca[0] + c * ca[1]])


def leave_one_out_fits(src: np.ndarray, dst: np.ndarray,
                       weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The weighted rigid fit of all the pairs but one, for each pair left out.

    Args:
        src: (K, 2) ``odom`` points; dst: (K, 2) ``map`` points; weights: (K,).

    Returns:
        (K,) yaw (rad) and (K, 2) translation (m) of ``map_T_odom`` without pair i.
    """
    # Closed form: the weighted sums of the full fit minus each pair's own terms (the
    # same 2D Kabsch as :func:`fit_rigid` on the other K - 1 pairs), on centred points.
    mean_src, mean_dst = src.mean(axis=0), dst.mean(axis=0)
    src = src - mean_src
    dst = dst - mean_dst
    w = weights
    wa, wb = w[:, None] * src, w[:, None] * dst
    rest_w = w.sum() - w
    rest_a = wa.sum(axis=0) - wa
    rest_b = wb.sum(axis=0) - wb
    dot = src[:, 0] * dst[:, 0] + src[:, 1] * dst[:, 1]
    crs = src[:, 0] * dst[:, 1] - src[:, 1] * dst[:, 0]
    safe_w = np.maximum(rest_w, 1e-300)
    ca, cb = rest_a / safe_w[:, None], rest_b / safe_w[:, None]
    cos = (w @ dot - w * dot) - rest_w * (ca[:, 0] * cb[:, 0] + ca[:, 1] * cb[:, 1])
    sin = (w @ crs - w * crs) - rest_w * (ca[:, 0] * cb[:, 1] - ca[:, 1] * cb[:, 0])
    yaw = np.arctan2(sin, cos)
    c, s = np.cos(yaw), np.sin(yaw)
    # t = (cb + mean_dst) - R (ca + mean_src): the fit maps the left-in centroid.
    ax, ay = ca[:, 0] + mean_src[0], ca[:, 1] + mean_src[1]
    t = np.column_stack([cb[:, 0] + mean_dst[0] - (c * ax - s * ay),
                         cb[:, 1] + mean_dst[1] - (s * ax + c * ay)])
    return yaw, t


def leave_one_out_residual(src: np.ndarray, dst: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Distance (m) between each destination point and its source point mapped by the
    weighted fit of all the other pairs (:func:`leave_one_out_fits`).

    Args:
        src: (K, 2) ``odom`` points; dst: (K, 2) ``map`` points; weights: (K,).
    """
    yaw, t = leave_one_out_fits(src, dst, weights)
    c, s = np.cos(yaw), np.sin(yaw)
    px = c * src[:, 0] - s * src[:, 1] + t[:, 0]
    py = s * src[:, 0] + c * src[:, 1] + t[:, 1]
    return np.hypot(px - dst[:, 0], py - dst[:, 1])


def jackknife_covariance(src: np.ndarray, dst: np.ndarray, weights: np.ndarray) -> np.ndarray:
    """Jackknife (x, y, yaw) covariance of the weighted rigid fit of K pairs.

    ``(K - 1) / K * sum_i (theta_i - mean)(theta_i - mean)^T`` over the fits that leave
    one pair out (:func:`leave_one_out_fits`; Efron and Stein 1981). Where the analytic
    covariance (:func:`pose_covariance`) trusts the weights, this one sees what each pair
    does to the fit: an alignment that rests on one pair (a single precise node far
    from the others, which alone sets the translation there) moves by that pair's whole
    pull when it is left out, however good the weights say the pair is.

    Args:
        src: (K, 2) ``odom`` points; dst: (K, 2) ``map`` points; weights: (K,).

    Returns:
        (3, 3) covariance; ``inf`` on the diagonal for fewer than 4 pairs (a fit of 2
        pairs is no fit).
    """
    k = len(src)
    if k < 4:
        return np.diag([np.inf, np.inf, np.inf])
    yaw, t = leave_one_out_fits(src, dst, weights)
    theta = np.column_stack([t, yaw])
    # Yaw about the first fit's, so that a fit near +-pi never averages across the cut.
    theta[:, 2] = np.angle(np.exp(1j * (yaw - yaw[0])))
    d = theta - theta.mean(axis=0)
    return (k - 1) / k * (d.T @ d)


def covering_covariance(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The covariance that covers both ``a`` and ``b``: ``a`` widened along each
    direction (in ``a``'s whitened space) where ``b`` is wider, unchanged elsewhere.

    Args:
        a: (3, 3) positive definite covariance (e.g. the analytic one).
        b: (3, 3) positive semi-definite covariance (e.g. the jackknife's).

    Returns:
        (3, 3) covariance ``C >= a`` and ``C >= b``; ``a`` when either is not finite or
        ``a`` is not positive definite.
    """
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return a
    try:
        root = np.linalg.cholesky(0.5 * (a + a.T))
    except np.linalg.LinAlgError:
        return a
    inv = np.linalg.inv(root)
    w, v = np.linalg.eigh(inv @ (0.5 * (b + b.T)) @ inv.T)
    c = root @ (v * np.maximum(w, 1.0)) @ v.T @ root.T
    return 0.5 * (c + c.T)


def alignment_jacobian(ln_pts: np.ndarray, yaw: float) -> np.ndarray:
    """(N, 2, 3) derivative of each mapped LN node R(yaw) p + t with respect to the
    alignment's (x, y, yaw): ``[[1, 0, -ry], [0, 1, rx]]`` with (rx, ry) = R(yaw) p."""
    c, s = math.cos(yaw), math.sin(yaw)
    x, y = ln_pts[:, 0], ln_pts[:, 1]
    jac = np.zeros((len(ln_pts), 2, 3))
    jac[:, 0, 0] = jac[:, 1, 1] = 1.0
    jac[:, 0, 2], jac[:, 1, 2] = -(s * x + c * y), c * x - s * y
    return jac


def predicted_variance(ln_pts: np.ndarray, yaw: float, cov: np.ndarray) -> np.ndarray:
    """Per-axis variance (m^2) of LN nodes mapped by a fit with (x, y, yaw) covariance."""
    c, s = math.cos(yaw), math.sin(yaw)
    rx = c * ln_pts[:, 0] - s * ln_pts[:, 1]
    ry = s * ln_pts[:, 0] + c * ln_pts[:, 1]
    var_x = cov[0, 0] - 2 * cov[0, 2] * ry + cov[2, 2] * ry**2
    var_y = cov[1, 1] + 2 * cov[1, 2] * rx + cov[2, 2] * rx**2
    var = 0.5 * (var_x + var_y)
    # A singular or numerically broken fit (NaN, negative variance) is infinitely loose.
    var[~(var >= 0.0)] = np.inf
    return var


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
    c, s = math.cos(yaw), math.sin(yaw)
    x, y = ln_pts[:, 0], ln_pts[:, 1]
    rx, ry = c * x - s * y, s * x + c * y
    # d(residual)/d(x, y, yaw) for one point: [[1, 0, -ry], [0, 1, rx]].
    sw, swx, swy = float(weights.sum()), float(weights @ rx), float(weights @ ry)
    sww = float(weights @ (rx * rx + ry * ry))
    # The inverse of [[sw, 0, -swy], [0, sw, swx], [-swy, swx, sww]] in closed form
    # (cofactors over the determinant sw (sw sww - swx^2 - swy^2)).
    schur = sw * sww - swx * swx - swy * swy
    det = sw * schur
    if not (sw > 0.0 and schur > 1e-12 * sw * sww and math.isfinite(det)):
        return np.diag([np.inf, np.inf, np.inf])
    return np.array([
        [(sw * sww - swx * swx) / det, -swx * swy / det, swy / schur],
        [-swx * swy / det, (sw * sww - swy * swy) / det, -swx / schur],
        [swy / schur, -swx / schur, sw * sw / det]])
