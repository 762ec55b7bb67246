"""The Global Network index, built once per GN: KD-trees and a triangle index.

Two structures serve the matcher (paper Sec. 6):

* KD-trees over the GN positions (one for all nodes, one per class label) answer the
  radius queries of verification: "is there a GN node of this class within d of this
  transformed LN node?".
* A triangle index replaces the paper's "every GN node is a primary candidate, look for
  secondaries on a circle, then auxiliaries" search. Every GN triangle whose sides are all
  at most ``max_side_m`` is stored once, its vertices ordered counter-clockwise and
  rotated so that the longest side comes first. Rows are sorted by an integer key made of
  the class labels of the three vertices and the three quantised side lengths, so that
  all GN triangles congruent to an LN control triangle (within the edge tolerance d_D)
  are found by a few binary searches: the star-tracker approach. For a
  small GN ``max_side_m`` is infinite, and the index holds every triangle, which is
  exactly the paper's exhaustive search; for a large GN it is limited to local triangles,
  so that the per-LN cost grows with the number of congruent triangles, not with the GN.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree

from roi_network.network import RoiNetwork
from roi_network.records import LABEL_NAMES, xy

#: Quantisation of the label code: labels are 1 or 2, a triangle's code is base-3.
_LABEL_BASE = 3
#: Room for each quantised side length in the key (2**16 cells of quant_m metres).
_SIDE_RANGE = 1 << 16


@dataclass(frozen=True)
class IndexStats:
    """Cost of building a :class:`GnIndex`.

    Attributes:
        n_nodes: GN nodes indexed.
        n_triangles: triangles stored in the triangle index.
        max_side_m: longest triangle side stored, metres (``inf``: every triangle).
        build_s: wall time to build, seconds.
        memory_bytes: bytes held by the index arrays (KD-trees approximated).
    """

    n_nodes: int
    n_triangles: int
    max_side_m: float
    build_s: float
    memory_bytes: int


def label_code(labels: np.ndarray, use_labels: bool) -> np.ndarray:
    """Integer code of the ordered class labels of triangles.

    Args:
        labels: (M, 3) class labels of the vertices, in triangle order.
        use_labels: when False every triangle gets code 0 (original DARCES).

    Returns:
        (M,) int64 codes.
    """
    labels = np.asarray(labels, dtype=np.int64)
    if not use_labels:
        return np.zeros(len(labels), dtype=np.int64)
    return (labels[:, 0] * _LABEL_BASE + labels[:, 1]) * _LABEL_BASE + labels[:, 2]


def triangle_key(
    code: np.ndarray, q0: np.ndarray, q1: np.ndarray, q2: np.ndarray
) -> np.ndarray:
    """Sort key of (label code, quantised sides 0, 1 and 2), int64."""
    key = np.asarray(code, dtype=np.int64)
    for q in (q0, q1, q2):
        key = key * _SIDE_RANGE + np.clip(q, 0, _SIDE_RANGE - 1)
    return key


def ccw_longest_first(tri: np.ndarray, pts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Order triangle vertices counter-clockwise with the longest side first.

    Args:
        tri: (M, 3) vertex indices into ``pts``.
        pts: (N, 2) positions, metres.

    Returns:
        The reordered (M, 3) indices and their (M, 3) sides: side k joins vertex k and
        vertex k+1 (mod 3).
    """
    tri = tri.copy()
    a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
    cross = (b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1]) - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0])
    cw = cross < 0
    tri[cw, 1], tri[cw, 2] = tri[cw, 2], tri[cw, 1].copy()
    sides = triangle_sides(tri, pts)
    # Rotate the vertex order (which keeps the orientation) so that side 0 is the longest.
    shift = np.argmax(sides, axis=1)
    rows = np.arange(len(tri))[:, None]
    order = (shift[:, None] + np.arange(3)[None, :]) % 3
    return tri[rows, order], sides[rows, order]


def triangle_sides(tri: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """(M, 3) side lengths |v0 v1|, |v1 v2|, |v2 v0| of triangles, metres."""
    p = pts[tri]
    return np.linalg.norm(p - np.roll(p, -1, axis=1), axis=2)


def _edges_upper_csr(tree: cKDTree, n: int, max_side_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Pairs (i < j) closer than ``max_side_m`` as CSR (row pointer, sorted columns)."""
    if np.isfinite(max_side_m):
        pairs = tree.query_pairs(max_side_m, output_type="ndarray").astype(np.int64)
    else:
        i, j = np.triu_indices(n, k=1)
        pairs = np.column_stack([i, j]).astype(np.int64)
    pairs = pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
    indptr = np.zeros(n + 1, dtype=np.int64)
    np.add.at(indptr, pairs[:, 0] + 1, 1)
    return np.cumsum(indptr), pairs[:, 1]


def enumerate_triangles(
    pts: np.ndarray, tree: cKDTree, max_side_m: float, min_height_m: float
) -> np.ndarray:
    """All triangles (i < j < k) whose three sides are at most ``max_side_m``.

    Wedges (i; j, k) with j < k both upper neighbours of i are generated in bulk and kept
    when (j, k) is an edge too. Hand-written because neither scipy nor networkx enumerate
    geometric triangles in vectorised form.

    Args:
        pts: (N, 2) positions, metres.
        tree: KD-tree over ``pts``.
        max_side_m: longest allowed side, metres (``inf``: all triangles).
        min_height_m: triangles whose smallest height is below this are dropped: their
            orientation is not stable under position noise.

    Returns:
        (M, 3) int64 vertex indices.
    """
    n = len(pts)
    indptr, cols = _edges_upper_csr(tree, n, max_side_m)
    deg = np.diff(indptr)
    # Wedge (p, q): two positions p < q in the same CSR row.
    row_of = np.repeat(np.arange(n), deg)
    after = indptr[row_of + 1] - np.arange(len(cols)) - 1
    first = np.repeat(np.arange(len(cols)), after)
    start = np.repeat(np.cumsum(after) - after, after)
    second = first + 1 + (np.arange(len(first)) - start)
    i, j, k = row_of[first], cols[first], cols[second]
    # Closure test: is (j, k) an edge? Edge keys are sorted because CSR is row-major.
    edge_keys = row_of * n + cols
    want = j * n + k
    pos = np.searchsorted(edge_keys, want)
    pos = np.minimum(pos, len(edge_keys) - 1)
    closed = edge_keys[pos] == want if len(edge_keys) else np.zeros(len(want), bool)
    tri = np.column_stack([i[closed], j[closed], k[closed]])
    if len(tri) and min_height_m > 0:
        sides = triangle_sides(tri, pts)
        a, b, c = pts[tri[:, 0]], pts[tri[:, 1]], pts[tri[:, 2]]
        area2 = np.abs((b[:, 0] - a[:, 0]) * (c[:, 1] - a[:, 1])
                       - (b[:, 1] - a[:, 1]) * (c[:, 0] - a[:, 0]))
        min_height = area2 / np.maximum(sides.max(axis=1), 1e-9)
        tri = tri[min_height >= min_height_m]
    return tri


def auto_max_side(pts: np.ndarray, tree: cKDTree, neighbours: int) -> float:
    """Triangle side limit for a large GN: the radius holding k neighbours on average.

    The larger of the median distance to the k-th neighbour and the radius of a disc
    holding k ROIs at the GN's mean density (ROIs over its convex hull). On a Poisson GN
    the two agree, and it keeps about ``neighbours**2 / 6`` triangles per node whatever
    the density. On a clustered GN the median is the spacing inside a cluster (a few
    metres in a dense boulder field), which would index only triangles smaller than any
    route's, so the mean-density radius holds: the LN's triangles span the gaps between
    clusters.
    """
    k = min(neighbours + 1, len(pts))
    sample = pts[:: max(1, len(pts) // 20000)]
    dist, _ = tree.query(sample, k=k)
    median = float(np.median(dist[:, -1]))
    try:
        area = float(ConvexHull(pts).volume)
    except (QhullError, ValueError):
        return median
    return max(median, float(np.sqrt(neighbours * area / (np.pi * len(pts)))))


#: Class separation of the class-lifted KD-tree, metres: far beyond any query radius.
_CLASS_SEPARATION_M = 1.0e7


def _lift(labels: np.ndarray) -> np.ndarray:
    """Lifted z of nodes of the given classes (see :attr:`GnIndex.lifted_tree`)."""
    return np.asarray(labels, dtype=float) * _CLASS_SEPARATION_M


class GnIndex:
    """KD-trees and the triangle index of one Global Network (``map`` frame).

    Args:
        gn: the Global Network; positions in metres, ``map`` frame.
        use_labels: key triangles by class labels (False for original DARCES).
        max_side_m: longest triangle side to index, metres; ``None`` picks infinity for a
            GN of at most ``exhaustive_max_nodes`` nodes, else :func:`auto_max_side`.
        exhaustive_max_nodes: GN size up to which every triangle is indexed.
        neighbours: k of :func:`auto_max_side`.
        quant_m: quantisation of side lengths in the key, metres; trades the number of
            binary searches per query (small cells) against candidates to filter (large);
            None: 4 m for an exhaustive index, 1 m for a local one.
        min_height_m: drop GN triangles flatter than this, metres.

    Raises:
        ValueError: if the GN has fewer than 3 nodes.
    """

    def __init__(
        self,
        gn: RoiNetwork,
        *,
        use_labels: bool = True,
        max_side_m: float | None = None,
        exhaustive_max_nodes: int = 300,
        neighbours: int = 14,
        quant_m: float | None = None,
        min_height_m: float = 1.0,
    ) -> None:
        t0 = time.perf_counter()
        if len(gn) < 3:
            raise ValueError(f"GnIndex: the GN needs at least 3 ROIs, got {len(gn)}")
        self.gn = gn
        self.pts = xy(gn.records)
        if not np.isfinite(self.pts).all():
            raise ValueError("GnIndex: the GN holds non-finite positions")
        self.labels = gn.records["label"].astype(np.int64)
        self.use_labels = use_labels
        if max_side_m is None:
            exhaustive = len(gn) <= exhaustive_max_nodes
            max_side_m = np.inf if exhaustive else None
        # Coarse cells for the long sides and loose tolerances of an exhaustive index,
        # fine ones for the short local triangles of a large GN.
        self.quant_m = float(quant_m or (4.0 if max_side_m == np.inf else 1.0))
        self.tree = cKDTree(self.pts)
        #: Per-label KD-trees and the GN indices of their points.
        self.label_trees: dict[int, tuple[cKDTree, np.ndarray]] = {}
        for label in LABEL_NAMES:
            members = np.flatnonzero(self.labels == label)
            if len(members):
                self.label_trees[label] = (cKDTree(self.pts[members]), members)
        self._all_ext = np.append(np.arange(len(self.pts)), -1)
        # One KD-tree for every class at once: each node lifted to z = class x
        # _CLASS_SEPARATION_M, so that a query within a smaller radius only ever reaches
        # nodes of its own class (one query per LN instead of one per class present).
        self.lifted_tree = cKDTree(np.column_stack([self.pts, _lift(self.labels)]))
        if max_side_m is None:
            max_side_m = auto_max_side(self.pts, self.tree, neighbours)
        self.max_side_m = float(max_side_m)
        #: Whether every triangle is indexed (small GN) rather than local ones only.
        self.exhaustive = not np.isfinite(self.max_side_m)
        tri = enumerate_triangles(self.pts, self.tree, self.max_side_m, min_height_m)
        tri, sides = ccw_longest_first(tri, self.pts)
        codes = label_code(self.labels[tri], use_labels)
        keys = triangle_key(codes, *(self._q(sides[:, k]) for k in range(3)))
        order = np.argsort(keys, kind="stable")
        self.keys = keys[order]
        # Sides are not stored (memory): candidates recompute theirs from positions.
        self.tri = tri[order].astype(np.int32)
        memory = self.keys.nbytes + self.tri.nbytes + self.pts.nbytes
        # cKDTree keeps a copy of the data plus ~2 index arrays: approximate it.
        memory += 2 * (self.pts.nbytes + 8 * len(self.pts))
        # The class-lifted tree: (x, y, z) copy plus its index arrays.
        memory += 2 * (24 * len(self.pts) + 8 * len(self.pts))
        self.stats = IndexStats(
            n_nodes=len(gn),
            n_triangles=len(self.tri),
            max_side_m=self.max_side_m,
            build_s=time.perf_counter() - t0,
            memory_bytes=int(memory),
        )

    def _q(self, length: np.ndarray) -> np.ndarray:
        return np.floor(np.asarray(length) / self.quant_m).astype(np.int64)

    def _cells(
        self, sides: np.ndarray, tol: np.ndarray, codes: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Key ranges of query triangles: one per (query, side-0 cell, side-1 cell).

        Returns:
            The query of each range and the start and count of its rows in :attr:`keys`.
        """
        lo_q = self._q(sides - tol)
        hi_q = self._q(sides + tol)
        n0, n1 = hi_q[:, 0] - lo_q[:, 0] + 1, hi_q[:, 1] - lo_q[:, 1] + 1
        cells = n0 * n1
        query = np.repeat(np.arange(len(sides)), cells)
        k = np.arange(cells.sum()) - np.repeat(np.cumsum(cells) - cells, cells)
        q0 = lo_q[query, 0] + k // n1[query]
        q1 = lo_q[query, 1] + k % n1[query]
        lo = triangle_key(codes[query], q0, q1, lo_q[query, 2])
        hi = triangle_key(codes[query], q0, q1, hi_q[query, 2] + 1)
        start = np.searchsorted(self.keys, lo)
        return query, start, np.searchsorted(self.keys, hi) - start

    def count_candidates(self, sides: np.ndarray, tol: np.ndarray, codes: np.ndarray) -> np.ndarray:
        """Upper bound on :meth:`congruent` matches per query, from binary searches only.

        Args:
            sides: (Q, 3) query sides, metres.
            tol: (Q, 3) side tolerances, metres.
            codes: (Q,) label codes.

        Returns:
            (Q,) int counts of GN triangles in the queries' key ranges.
        """
        query, _, count = self._cells(sides, tol, codes)
        return np.bincount(query, weights=count, minlength=len(sides)).astype(np.int64)

    def congruent(
        self, sides: np.ndarray, tol: np.ndarray, codes: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray]:
        """GN triangles congruent to query triangles, same vertex order and labels.

        Args:
            sides: (Q, 3) query sides |v0 v1|, |v1 v2|, |v2 v0|, metres.
            tol: (Q, 3) tolerance d_D of each side, metres.
            codes: (Q,) label codes of the queries' vertex orders (:func:`label_code`).

        Returns:
            Row indices into :attr:`tri` whose three sides all lie within tolerance, and
            for each the query it answers.
        """
        # One key range per (query, side-0 cell, side-1 cell): binary searches in bulk.
        query, start, count = self._cells(sides, tol, codes)
        total = int(count.sum())
        if total == 0:
            return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
        rows = np.repeat(start - np.cumsum(count) + count, count) + np.arange(total)
        query = np.repeat(query, count)
        diff = np.abs(triangle_sides(self.tri[rows], self.pts) - sides[query])
        ok = np.all(diff <= tol[query], axis=1)
        return rows[ok], query[ok]

    def any_label_groups(self, n: int) -> list[tuple]:
        """Query plan of N LN nodes against the whole GN, whatever their classes."""
        return [(self.tree, self._all_ext, np.arange(n), None)]

    def label_groups(self, labels: np.ndarray) -> list[tuple]:
        """Per-class query plan for LN nodes, computed once per LN.

        Args:
            labels: (N,) class labels of the LN nodes.

        Returns:
            Groups of (KD-tree, GN index of each tree point with a trailing -1 for
            "none", LN nodes of the group, lifted z of those nodes or None): one group
            of all nodes against the class-lifted tree (with ``use_labels`` False,
            against the plain tree); :meth:`nearest_same_label` falls back to the
            per-class trees for radii that the lift cannot separate.
        """
        if not self.use_labels:
            return self.any_label_groups(len(labels))
        labels = np.asarray(labels, dtype=np.int64)
        return [(self.lifted_tree, self._all_ext, np.arange(len(labels)), _lift(labels),
                 labels)]

    def _per_class_groups(self, labels: np.ndarray) -> list[tuple]:
        """One group per class present in both networks, against the per-class trees."""
        groups = []
        for label, (tree, members) in self.label_trees.items():
            sel = np.flatnonzero(labels == label)
            if len(sel):
                groups.append((tree, np.append(members, -1), sel, None))
        return groups

    def nearest_same_label(
        self,
        pts: np.ndarray,
        groups: list[tuple[cKDTree, np.ndarray, np.ndarray]],
        radius: float,
        k: int = 1,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Nearest GN node of the same class (or any class) within ``radius``.

        Args:
            pts: (..., N, 2) LN positions mapped into ``map``, metres.
            groups: :meth:`label_groups` of the N LN nodes.
            radius: largest distance searched, metres.

            k: number of nearest nodes wanted; k > 1 adds a trailing axis of size k.

        Returns:
            (..., N) distances (``inf`` when none) and GN indices (-1 when none).
        """
        shape = pts.shape[:-1] + ((k,) if k > 1 else ())
        if len(groups) == 1 and groups[0][3] is not None:
            tree, members, _, z, labels = groups[0]
            if radius < 0.5 * _CLASS_SEPARATION_M:
                # The common case: one query of the class-lifted points.
                lifted = np.empty((*pts.shape[:-1], 3))
                lifted[..., :2] = pts
                lifted[..., 2] = z
                d, i = tree.query(lifted, k=k, distance_upper_bound=radius)
                return d, members[i]
            groups = self._per_class_groups(labels)
        dist = np.full(shape, np.inf)
        idx = np.full(shape, -1, dtype=np.int64)
        for tree, members, sel, _ in groups:
            d, i = tree.query(pts[..., sel, :], k=k, distance_upper_bound=radius)
            if k > 1:
                dist[..., sel, :], idx[..., sel, :] = d, members[i]
            else:
                dist[..., sel], idx[..., sel] = d, members[i]
        return dist, idx
