"""Triangle hypotheses: GN triangles that may correspond to an LN control triplet.

Paper Sec. 6: the primary LN point may match any GN node (of its class), the secondary one
any GN node on the circle of radius |ps| +/- d_D around it, and the auxiliary one any GN
node consistent with both remaining edges; the improved DARCES also requires the same
orientation (cw/ccw) and the same class labels. The GN triangle index
(:class:`~darces_matcher.gn_index.GnIndex`) answers all of it with one lookup per vertex
rotation of the control triangle. Each hypothesis then yields a proper rigid transform.
"""

from __future__ import annotations

import numpy as np

from darces_matcher.gn_index import GnIndex, label_code, triangle_sides

#: The three cyclic rotations of a triangle's vertex order (orientation preserved).
_ROTATIONS = np.array([[0, 1, 2], [1, 2, 0], [2, 0, 1]])
#: The same for the mirrored triangle (orientation reversed), for original DARCES.
_MIRRORED = np.array([[0, 2, 1], [2, 1, 0], [1, 0, 2]])


def query_triangles(
    ln_pts: np.ndarray,
    ln_labels: np.ndarray,
    edge_tol: np.ndarray,
    triplets: np.ndarray,
    *,
    use_orientation: bool,
    use_labels: bool,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The index queries of control triplets: every admissible vertex order of each.

    Args:
        ln_pts: (N, 2) LN positions, ``odom``, metres.
        ln_labels: (N,) LN class labels.
        edge_tol: (N, N) edge tolerances d_D, metres.
        triplets: (K, 3) counter-clockwise LN index triplets.
        use_orientation: only rotations (False: mirrored orders too).
        use_labels: key by class labels.

    Returns:
        Query vertex orders (Q, 3), owning triplet (Q,), sides (Q, 3), side tolerances
        (Q, 3) and label codes (Q,).
    """
    orders = _ROTATIONS if use_orientation else np.vstack([_ROTATIONS, _MIRRORED])
    queries = triplets[:, orders].reshape(-1, 3)
    owner = np.repeat(np.arange(len(triplets)), len(orders))
    nxt = np.roll(queries, -1, axis=1)
    sides = np.linalg.norm(ln_pts[queries] - ln_pts[nxt], axis=2)
    tol = edge_tol[queries, nxt]
    # GN triangles are stored longest side first: a vertex order can only match if its
    # first side may be the longest one of the GN counterpart.
    possible = sides[:, 0] + tol[:, 0] >= np.max(sides - tol, axis=1)
    queries, owner, sides, tol = queries[possible], owner[possible], sides[possible], tol[possible]
    return queries, owner, sides, tol, label_code(ln_labels[queries], use_labels)


def triangle_hypotheses(
    index: GnIndex,
    ln_pts: np.ndarray,
    ln_labels: np.ndarray,
    edge_tol: np.ndarray,
    triplets: np.ndarray,
    *,
    use_orientation: bool,
    max_hypotheses: int,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """GN triangles congruent to control triplets, all triplets in one vectorised query.

    Args:
        index: the GN index.
        ln_pts: (N, 2) LN positions, ``odom`` frame, metres.
        ln_labels: (N,) LN class labels.
        edge_tol: (N, N) edge tolerance d_D between LN nodes, metres.
        triplets: (K, 3) LN indices (primary, secondary, auxiliary), counter-clockwise.
        use_orientation: only same-orientation triangles (False: also mirrored ones).
        max_hypotheses: keep at most this many per triplet (those whose sides agree
            best) to bound the cost on huge GNs.

    Returns:
        (H, 3) LN indices and (H, 3) GN indices of corresponding vertices, and (H,) the
        row of ``triplets`` each hypothesis comes from.
    """
    # Every admissible vertex order of every triplet is one query triangle.
    queries, owner, sides, tol, codes = query_triangles(
        ln_pts, ln_labels, edge_tol, triplets,
        use_orientation=use_orientation, use_labels=index.use_labels,
    )
    rows, query = index.congruent(sides, tol, codes)
    ln_idx, gn_idx, source = queries[query], index.tri[rows].astype(np.int64), owner[query]
    counts = np.bincount(source, minlength=len(triplets))
    if counts.max(initial=0) > max_hypotheses:
        # Keep the triangles whose sides agree best, per triplet (bounded cost).
        err = np.abs(triangle_sides(gn_idx, index.pts) - sides[query]).sum(axis=1)
        order = np.lexsort((err, source))
        rank = np.arange(len(order)) - np.repeat(np.cumsum(counts) - counts, counts)
        keep = np.sort(order[rank < max_hypotheses])
        ln_idx, gn_idx, source = ln_idx[keep], gn_idx[keep], source[keep]
    return ln_idx, gn_idx, source


def fit_rigid_batch(
    src: np.ndarray, dst: np.ndarray, weights: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares proper rigid transforms for many small correspondence sets at once.

    The batched form of :meth:`roi_network.transform.Rigid2D.fit` (same closed-form 2D
    Kabsch, never a reflection); written out because that method fits one set per call
    and the matcher fits thousands of hypotheses per LN.

    Args:
        src: (H, K, 2) source points (``odom``), metres.
        dst: (H, K, 2) destination points (``map``), metres.
        weights: optional (H, K) non-negative weights.

    Returns:
        (H,) yaw in radians and (H, 2) translation in metres of ``map_T_odom``.
    """
    if weights is None:
        weights = np.ones(src.shape[:2])
    w = weights / np.maximum(weights.sum(axis=1, keepdims=True), 1e-300)
    ca = np.einsum("hk,hkd->hd", w, src)
    cb = np.einsum("hk,hkd->hd", w, dst)
    a0 = src - ca[:, None, :]
    b0 = dst - cb[:, None, :]
    cos = np.einsum("hk,hk->h", w, a0[..., 0] * b0[..., 0] + a0[..., 1] * b0[..., 1])
    sin = np.einsum("hk,hk->h", w, a0[..., 0] * b0[..., 1] - a0[..., 1] * b0[..., 0])
    yaw = np.arctan2(sin, cos)
    c, s = np.cos(yaw), np.sin(yaw)
    t = cb - np.stack([c * ca[:, 0] - s * ca[:, 1], s * ca[:, 0] + c * ca[:, 1]], axis=1)
    return yaw, t


def apply_batch(yaw: np.ndarray, t: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply H transforms to N points: (H,), (H, 2), (N, 2) -> (H, N, 2)."""
    c, s = np.cos(yaw)[:, None], np.sin(yaw)[:, None]
    x = c * pts[None, :, 0] - s * pts[None, :, 1] + t[:, 0:1]
    y = s * pts[None, :, 0] + c * pts[None, :, 1] + t[:, 1:2]
    return np.stack([x, y], axis=2)
