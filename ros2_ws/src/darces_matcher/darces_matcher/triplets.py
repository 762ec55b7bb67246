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

    Returns:
        (K, 3) int64 LN indices, K <= n_triplets, each row counter-clockwise; empty when
        the LN holds no acceptable triangle (fewer than 3 nodes, collinear nodes, ...).
    """
    n = len(pts)
    if n < 3 or n_triplets <= 0:
        return np.zeros((0, 3), dtype=np.int64)
    candidates = np.sort(np.argsort(tol, kind="stable")[:max_nodes])
    combos = candidates[_combinations3(len(candidates))]
    a, b, c = pts[combos[:, 0]], pts[combos[:, 1]], pts[combos[:, 2]]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    sides = np.stack(
        [np.linalg.norm(b - a, axis=1), np.linalg.norm(c - b, axis=1),
         np.linalg.norm(a - c, axis=1)], axis=1)
    tol_sum = tol[combos].sum(axis=1)
    min_height = np.abs(cross) / np.maximum(sides.max(axis=1), 1e-9)
    ok = (
        (sides.min(axis=1) >= min_side_m)
        # A GN counterpart may be up to the edge tolerance (~1.4 node tolerances) longer.
        & (sides.max(axis=1) + 1.5 * tol[combos].max(axis=1) <= max_side_m)
        & (min_height >= min_height_ratio * tol_sum)
    )
    combos, cross, min_height, tol_sum = combos[ok], cross[ok], min_height[ok], tol_sum[ok]
    # Counter-clockwise vertex order.
    cw = cross < 0
    combos[cw, 1], combos[cw, 2] = combos[cw, 2], combos[cw, 1].copy()
    # Selectivity: the number of random GN triangles within tolerance grows with the
    # product of the three tolerances, so precise triplets come first; ties (equal
    # precision) go to the better conditioned one.
    tol_prod = np.prod(tol[combos], axis=1)
    order = np.lexsort((-min_height / np.maximum(tol_sum, 1e-6), np.round(tol_prod, 6)))
    # Greedy spread: plain Python lists, the loop is short and numpy calls would dominate.
    # With a cost, pick a few spares: some will be dropped.
    limit = n_triplets if cost is None else spare_factor * n_triplets
    uses = np.zeros(n, dtype=np.int64)
    chosen: list[int] = []
    ordered = combos[order]
    # In blocks: rows holding an already saturated node are dropped with one numpy test
    # per block, the short greedy loop sees only the others.
    for start in range(0, len(order), 128):
        if len(chosen) >= limit:
            break
        block = ordered[start : start + 128]
        live = np.flatnonzero((uses[block] < max_uses_per_node).all(axis=1))
        for r in live.tolist():
            if len(chosen) >= limit:
                break
            row = block[r]
            if (uses[row] >= max_uses_per_node).any():
                continue
            chosen.append(int(order[start + r]))
            uses[row] += 1
    if cost is not None and chosen:
        # The GN index tells the actual number of candidates: none at all means a vertex
        # has no counterpart (outlier, wrong class, GN miss), too many is too costly to
        # verify. The order stays by precision: ranking by fewest candidates would
        # favour triplets holding an outlier.
        count = cost(combos[chosen])
        chosen = [c for c, k in zip(chosen, count, strict=True) if 0 < k <= max_cost]
        chosen = chosen[:n_triplets]
    out = combos[chosen]
    return out
