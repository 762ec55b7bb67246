"""Control-point triplets of the Local Network (paper Sec. 6: primary, secondary, auxiliary).

A control triplet is a triangle of LN nodes whose GN counterparts are searched for. Good
triplets are (a) well conditioned: the smallest height is large against the position
tolerance of the vertices, so the orientation (cw/ccw) is reliable; (b) made of precise
nodes (early in the route: little VO drift), so the tolerance d_D, and with it the number
of false hypotheses, stays small; (c) spread over different nodes, so that one outlier
or misclassified node spoils few triplets. Triplets are returned most selective first.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import lru_cache
from itertools import combinations

import numpy as np


@lru_cache(maxsize=64)
def _combinations3(n: int) -> np.ndarray:
    """All index triples i < j < k < n, (C(n, 3), 3), cached per n."""
    out = np.array(list(combinations(range(n), 3)), dtype=np.int64).reshape(-1, 3)
    out.flags.writeable = False
    return out


@lru_cache(maxsize=64)
def _flat_edges(n: int) -> np.ndarray:
    """Flat (row-major n x n) indices of the edges (i, j), (j, k), (k, i) of every
    triple of :func:`_combinations3`, (3, C(n, 3)), cached per n."""
    c = _combinations3(n)
    out = np.stack([c[:, 0] * n + c[:, 1], c[:, 1] * n + c[:, 2], c[:, 2] * n + c[:, 0]])
    out.flags.writeable = False
    return out


def control_triplets(
    pts: np.ndarray,
    tol: np.ndarray,
    n_triplets: int,
    *,
    min_side_m: float,
    max_side_m: float,
    min_height_ratio: float,
    max_uses_per_node: int,
    max_nodes: int = 30,
    cost: Callable[[np.ndarray], np.ndarray] | None = None,
    spare_factor: int = 3,
    max_cost: float = np.inf,
    max_dense_cost: float = 0.0,
    dense_out: list[np.ndarray] | None = None,
) -> np.ndarray:
    """Choose control triplets (primary, secondary, auxiliary), counter-clockwise.

    Args:
        pts: (N, 2) LN positions, ``odom`` frame, metres.
        tol: (N,) position tolerance of each LN node, metres.
        n_triplets: how many triplets to return at most.
        min_side_m: shortest allowed side, metres (short sides carry no shape).
        max_side_m: longest allowed side, metres (the GN triangle index limit).
        min_height_ratio: smallest triangle height over the sum of vertex tolerances;
            below it the orientation could flip under noise.
        max_uses_per_node: how many chosen triplets may share one node.
        max_nodes: only the ``max_nodes`` most precise nodes are combined (cost is cubic).
        cost: optional function of (M, 3) counter-clockwise triplets giving the number of
            GN candidates of each (:meth:`GnIndex.count_candidates`); triplets with none
            or more than ``max_cost`` are dropped.
        spare_factor: with ``cost``, this many times ``n_triplets`` are chosen before
            the cost filter.
        max_cost: triplets with more candidates than this are dropped (too costly to
            verify, and too unselective to win a margin).
        max_dense_cost: with ``cost`` and ``dense_out``, the triplets dropped for having
            more than ``max_cost`` candidates but at most this many are kept aside.
        dense_out: if given, receives one (D, 3) array: those dense triplets, fewest
            candidates first, at most ``n_triplets`` (the matcher tries them after the
            others: in a dense rock field a triangle of three true nodes may have tens of
            thousands of congruent GN triangles).

    Returns:
        (K, 3) int64 LN indices, K <= n_triplets, each row counter-clockwise; empty when
        the LN holds no acceptable triangle (fewer than 3 nodes, collinear nodes, ...).
    """
    n = len(pts)
    if n < 3 or n_triplets <= 0:
        if dense_out is not None:
            dense_out.append(np.zeros((0, 3), dtype=np.int64))
        return np.zeros((0, 3), dtype=np.int64)
    candidates = np.sort(np.argsort(tol, kind="stable")[:max_nodes])
    m = len(candidates)
    local = _combinations3(m)
    edges = _flat_edges(m)
    p, t = pts[candidates], tol[candidates]
    # Pairwise side lengths and cross products once (m x m), then gathered per triple:
    # cross(a, b, c) = a x b + b x c + c x a, the doubled signed area.
    dist = np.sqrt(((p[:, None, :] - p[None, :, :]) ** 2).sum(axis=2)).ravel()
    wedge = (np.multiply.outer(p[:, 0], p[:, 1]) - np.multiply.outer(p[:, 1], p[:, 0])).ravel()
    # Column-wise (3 separate vectors): numpy reductions over a length-3 axis are slow.
    s0, s1, s2 = dist[edges[0]], dist[edges[1]], dist[edges[2]]
    w = wedge[edges]
    cross = w[0] + w[1] + w[2]
    t0, t1, t2 = t[local[:, 0]], t[local[:, 1]], t[local[:, 2]]
    tol_sum = t0 + t1 + t2
    longest = np.maximum(np.maximum(s0, s1), s2)
    min_height = np.abs(cross) / np.maximum(longest, 1e-9)
    ok = (
        (np.minimum(np.minimum(s0, s1), s2) >= min_side_m)
        & (min_height >= min_height_ratio * tol_sum)
    )
    if np.isfinite(max_side_m):
        # A GN counterpart may be up to the edge tolerance (~1.4 node tolerances) longer.
        ok &= longest + 1.5 * np.maximum(np.maximum(t0, t1), t2) <= max_side_m
    keep = np.flatnonzero(ok)
    combos = candidates[local[keep]]
    cross, min_height, tol_sum = cross[keep], min_height[keep], tol_sum[keep]
    tol_prod = t0[keep] * t1[keep] * t2[keep]
    # Counter-clockwise vertex order.
    cw = cross < 0
    combos[cw, 1], combos[cw, 2] = combos[cw, 2], combos[cw, 1].copy()
    # Selectivity: the number of random GN triangles within tolerance grows with the
    # product of the three tolerances, so precise triplets come first; ties (equal
    # precision) go to the better conditioned one.
    order = np.lexsort((-min_height / np.maximum(tol_sum, 1e-6), np.round(tol_prod, 6)))
    # Greedy spread in plain Python (a short loop; numpy calls per row would dominate).
    # With a cost, pick a few spares: some will be dropped.
    limit = n_triplets if cost is None else spare_factor * n_triplets
    uses = [0] * n
    chosen: list[int] = []
    # In blocks: only as many rows are converted to Python as the greedy loop reads.
    for start in range(0, len(order), 64):
        if len(chosen) >= limit:
            break
        block = order[start : start + 64]
        for r, (i, j, k) in zip(block.tolist(), combos[block].tolist(), strict=True):
            if uses[i] >= max_uses_per_node or uses[j] >= max_uses_per_node or (
                uses[k] >= max_uses_per_node
            ):
                continue
            chosen.append(r)
            uses[i] += 1
            uses[j] += 1
            uses[k] += 1
            if len(chosen) >= limit:
                break
    if cost is not None and chosen:
        # The GN index tells the actual number of candidates: none at all means a vertex
        # has no counterpart (outlier, wrong class, GN miss), too many is too costly to
        # verify. The order stays by precision: ranking by fewest candidates would
        # favour triplets holding an outlier.
        count = cost(combos[chosen])
        if dense_out is not None:
            dense = [(k, c) for c, k in zip(chosen, count, strict=True)
                     if max_cost < k <= max_dense_cost]
            rows = [c for _, c in sorted(dense)[:n_triplets]]
            dense_out.append(combos[rows].reshape(-1, 3))
        chosen = [c for c, k in zip(chosen, count, strict=True) if 0 < k <= max_cost]
        chosen = chosen[:n_triplets]
    elif dense_out is not None:
        dense_out.append(np.zeros((0, 3), dtype=np.int64))
    out = combos[chosen]
    return out
