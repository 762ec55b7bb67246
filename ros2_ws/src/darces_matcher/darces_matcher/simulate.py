"""Simulated Local Networks following the paper's protocol (Sec. 7.2), plus stress options.

Protocol, as implemented (docs/matcher.md states it with the LN counts it yields):

1. Start/end pairs: every ordered pair (S, E) of GN nodes with
   ``MIN_PAIR_M <= |SE| <= MAX_PAIR_M`` (600 m..1 km). Ordered, because the drift grows
   from S: (S, E) and (E, S) are different routes.
2. Trajectories: the paper's "all possible trajectories from S to E with 19..29 nodes and
   a length under 1 km" is combinatorially huge, so each pair gets ``walks_per_pair``
   seeded random walks through GN nodes. Walk k of (S, E) draws a target node count n
   uniformly in ``min_nodes..max_nodes``; from the current node it may step to any
   unvisited GN node within ``STEP_RADIUS_M`` from which E can still be reached within
   the length budget (length so far + step + straight line to E < ``MAX_LENGTH_M``),
   and it picks uniformly among the ``K_NEAREST`` admissible nodes of smallest cost
   |progress - distance left / steps left| + detour (even progress towards E, little
   detour); E is the n-th node and only the n-th. A walk that gets stuck is dropped;
   duplicates (same node sequence) are counted once. The random generator of walk k of
   (S, E) is seeded by (seed, S, E, k), so the set is the same whatever subset is asked.
3. Detectability: ``round(DROP_FRACTION * n)`` nodes of each trajectory, chosen at random,
   are removed (paper: 20 %).
4. Localisation error: each remaining node moves by a random offset uniform in the disc
   of radius f s (the VO's maximum error), with s its distance travelled from S along the
   trajectory and f = ``noise_fraction`` (paper: 1 %).
5. Unknown odom frame: ``map_T_odom`` has a uniform random yaw and a translation uniform in
   a +/-``ODOM_OFFSET_M`` (1 km) box around S; the LN is expressed in ``odom`` and its
   records shuffled.

The LN records carry the error model the rover's VO would report (per-axis variance of the
drift, cov_xx = cov_yy = (f s)^2 / 4), never the truth. The truth (GN index of each LN
node, true transform) stays in :class:`SimulatedLn` for evaluation only.

Stress options: ``outliers`` adds round(F n) false detections (each uniform in a
``OUTLIER_RADIUS_M`` (40 m) disc around a random true LN node, with that node's drift
model, as if seen from the route there; class drawn with the GN's class frequencies);
``label_flips`` swaps the class of round(F n) true nodes; ``gn_misses``
(:func:`degrade_gn`) removes a fraction of the GN given to the matcher (orbital ROIs never
detected), the LN still seeing them.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from roi_network.network import RoiNetwork
from roi_network.records import OUTCROP, ROCK, empty_records, xy
from roi_network.transform import Rigid2D

#: Shortest S-E distance of a route, metres (paper).
MIN_PAIR_M = 600.0
#: Longest S-E distance of a route, metres (paper).
MAX_PAIR_M = 1000.0
#: Trajectory length limit, metres (paper).
MAX_LENGTH_M = 1000.0
#: Longest step of a walk, metres.
STEP_RADIUS_M = 150.0
#: A walk picks among this many lowest-cost admissible nodes.
K_NEAREST = 3
#: Share of trajectory nodes the rover misses (paper: 20 %).
DROP_FRACTION = 0.2
#: A false detection lies within this of a random true node, metres.
OUTLIER_RADIUS_M = 40.0
#: Half-size of the box of the odom origin around S, metres.
ODOM_OFFSET_M = 1000.0


@dataclass(frozen=True)
class SimOptions:
    """Options of the LN simulation (defaults: the paper's protocol).

    Attributes:
        min_nodes: fewest nodes of a trajectory (24 - 20 %).
        max_nodes: most nodes of a trajectory (24 + 20 %).
        walks_per_pair: random walks tried per (S, E) pair.
        noise_fraction: VO error bound as a share of distance travelled.
        outliers: false detections added, as a share of the true LN nodes.
        label_flips: true LN nodes whose class is swapped, as a share.
    """

    min_nodes: int = 19
    max_nodes: int = 29
    walks_per_pair: int = 16
    noise_fraction: float = 0.01
    outliers: float = 0.0
    label_flips: float = 0.0


@dataclass
class SimulatedLn:
    """One simulated LN and its truth (evaluation only: the matcher never sees it).

    Attributes:
        records: LN records in ``odom`` (shuffled), covariance = the VO error model.
        sigma: (N,) 1-sigma position error per axis the rover would report, metres.
        truth_gn: (N,) GN index (of the full GN) of each LN node, -1 for false detections.
        map_T_odom: the true transform.
        trajectory: GN indices of the whole trajectory, S first.
    """

    records: np.ndarray
    sigma: np.ndarray
    truth_gn: np.ndarray
    map_T_odom: Rigid2D
    trajectory: np.ndarray


def start_end_pairs(pts: np.ndarray) -> np.ndarray:
    """Ordered (S, E) pairs with MIN_PAIR_M <= |SE| <= MAX_PAIR_M, sorted, (P, 2)."""
    tree = cKDTree(pts)
    far = tree.query_pairs(MAX_PAIR_M, output_type="ndarray")
    d = np.linalg.norm(pts[far[:, 0]] - pts[far[:, 1]], axis=1)
    far = far[d >= MIN_PAIR_M]
    pairs = np.vstack([far, far[:, ::-1]])
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


class TrajectoryEnumerator:
    """The seeded random-walk trajectories of step 2 (see the module docstring).

    Args:
        pts: (N, 2) GN positions, ``map``, metres.
        options: simulation options.
        seed: random seed.
    """

    def __init__(self, pts: np.ndarray, options: SimOptions, seed: int) -> None:
        self.pts, self.options, self.seed = pts, options, seed
        tree = cKDTree(pts)
        self.neighbours: list[np.ndarray] = []
        self.step_len: list[np.ndarray] = []
        for i, nb in enumerate(tree.query_ball_point(pts, STEP_RADIUS_M)):
            nb = np.array([j for j in nb if j != i], dtype=np.int64)
            d = np.linalg.norm(pts[nb] - pts[i], axis=1)
            order = np.argsort(d, kind="stable")
            self.neighbours.append(nb[order])
            self.step_len.append(d[order])
        self.visited = np.zeros(len(pts), dtype=bool)

    def trajectories(self, start: int, end: int) -> list[np.ndarray]:
        """The distinct trajectories of one (S, E) pair, in walk order."""
        opt = self.options
        to_end = np.linalg.norm(self.pts - self.pts[end], axis=1)
        seen: set[tuple[int, ...]] = set()
        out = []
        for k in range(opt.walks_per_pair):
            rng = np.random.default_rng([self.seed, start, end, k])
            path = self._walk(start, end, to_end, rng)
            if path is not None and tuple(path) not in seen:
                seen.add(tuple(path))
                out.append(np.array(path, dtype=np.int64))
        return out

    def _walk(
        self, start: int, end: int, to_end: np.ndarray, rng: np.random.Generator
    ) -> list[int] | None:
        opt = self.options
        n_target = int(rng.integers(opt.min_nodes, opt.max_nodes + 1))
        path, length = [start], 0.0
        self.visited[start] = True
        try:
            while len(path) < n_target:
                cur = path[-1]
                nb, step = self.neighbours[cur], self.step_len[cur]
                remaining = n_target - len(path)
                ok = ~self.visited[nb] & (length + step + to_end[nb] < MAX_LENGTH_M)
                # E closes the route, and only as its last node.
                ok &= (nb == end) if remaining == 1 else (nb != end)
                cand = np.flatnonzero(ok)
                if not len(cand):
                    return None
                # Aim at even progress towards E over the remaining steps, with little detour.
                progress = to_end[cur] - to_end[nb[cand]]
                cost = np.abs(progress - to_end[cur] / remaining) + (step[cand] - progress)
                best = cand[np.argsort(cost, kind="stable")[:K_NEAREST]]
                pick = int(best[rng.integers(len(best))])
                path.append(int(nb[pick]))
                self.visited[nb[pick]] = True
                length += float(step[pick])
            return path
        finally:
            self.visited[path] = False


def simulate_ln(
    gn_pts: np.ndarray,
    gn_labels: np.ndarray,
    trajectory: np.ndarray,
    options: SimOptions,
    rng: np.random.Generator,
) -> SimulatedLn:
    """Turn one trajectory into an LN (steps 3-5 and the stress options).

    Args:
        gn_pts: (N, 2) positions of the full GN, ``map``, metres.
        gn_labels: (N,) class labels of the full GN.
        trajectory: GN indices, S first.
        options: simulation options.
        rng: random generator.
    """
    route = gn_pts[trajectory]
    travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(route, axis=0), axis=1))])
    n = len(trajectory)
    keep = np.sort(rng.choice(n, n - round(DROP_FRACTION * n), replace=False))
    nodes, s = trajectory[keep], travelled[keep]
    half = options.noise_fraction * s
    yaw = rng.uniform(-np.pi, np.pi)
    offset = rng.uniform(-ODOM_OFFSET_M, ODOM_OFFSET_M, 2)
    map_T_odom = Rigid2D(yaw, *(route[0] + offset))
    # Uniform in the disc of radius f s: sqrt of a uniform radius fraction, uniform angle.
    radius = half * np.sqrt(rng.random(len(nodes)))
    angle = rng.uniform(-np.pi, np.pi, len(nodes))
    drift = radius[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
    odom = map_T_odom.inverse().apply(gn_pts[nodes]) + drift
    # Per-axis standard deviation of a uniform disc of radius R is R / 2.
    sigma = half / 2.0
    labels = gn_labels[nodes].copy()
    truth = nodes.copy()
    n_flip = round(options.label_flips * len(nodes))
    flip = rng.choice(len(nodes), n_flip, replace=False)
    labels[flip] = np.where(labels[flip] == ROCK, OUTCROP, ROCK)
    n_out = round(options.outliers * len(nodes))
    if n_out:
        # A false detection is seen from the route: near a true node, with its drift.
        near = rng.integers(0, len(nodes), n_out)
        radius = OUTLIER_RADIUS_M * np.sqrt(rng.random(n_out))
        angle = rng.uniform(-np.pi, np.pi, n_out)
        fake = odom[near] + radius[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
        odom = np.vstack([odom, fake])
        p_outcrop = float(np.mean(gn_labels == OUTCROP))
        labels = np.concatenate([labels, np.where(rng.random(n_out) < p_outcrop, OUTCROP, ROCK)])
        sigma = np.concatenate([sigma, sigma[near]])
        truth = np.concatenate([truth, np.full(n_out, -1)])
    order = rng.permutation(len(odom))
    rec = empty_records(len(odom))
    rec["x"], rec["y"] = odom[order, 0], odom[order, 1]
    rec["id"] = np.arange(len(odom))
    rec["label"] = labels[order]
    rec["cov_xx"] = rec["cov_yy"] = sigma[order] ** 2
    rec["score"] = 1.0
    rec["n_obs"] = 1
    return SimulatedLn(rec, sigma[order], truth[order], map_T_odom, trajectory)


def iter_lns(
    gn: RoiNetwork, options: SimOptions, seed: int = 0, max_lns: int | None = None
) -> Iterator[SimulatedLn]:
    """Simulated LNs of a GN, deterministic for a seed.

    ``max_lns`` subsamples deterministically: (S, E) pairs are visited in a seeded random
    order and all trajectories of a pair are taken before the next pair. On a GN of more
    than :data:`PAIR_ENUMERATION_LIMIT` ROIs with ``max_lns`` given, pairs are drawn
    instead (S uniform, E uniform among the nodes 600 m..1 km from it, seeded).

    Args:
        gn: the full (true) GN, ``map``.
        options: simulation options.
        seed: random seed.
        max_lns: stop after this many LNs (None: all).
    """
    pts, labels = xy(gn.records), gn.records["label"].astype(np.int64)
    enumerator = TrajectoryEnumerator(pts, options, seed)
    if len(pts) > PAIR_ENUMERATION_LIMIT and max_lns is not None:
        # Listing every pair of a huge GN (10^6 ROIs: ~10^9 pairs) is out of reach.
        pairs: Iterator[np.ndarray] | np.ndarray = _sampled_pairs(pts, seed)
    else:
        pairs = start_end_pairs(pts)
        pairs = pairs[np.random.default_rng([seed, 1]).permutation(len(pairs))]
    count = 0
    for start, end in pairs:
        for k, traj in enumerate(enumerator.trajectories(int(start), int(end))):
            if max_lns is not None and count >= max_lns:
                return
            rng = np.random.default_rng([seed, int(start), int(end), k, 2])
            yield simulate_ln(pts, labels, traj, options, rng)
            count += 1


#: GN size above which :func:`iter_lns` samples (S, E) pairs instead of listing them all.
PAIR_ENUMERATION_LIMIT = 20000


def _sampled_pairs(pts: np.ndarray, seed: int) -> Iterator[np.ndarray]:
    """Endless seeded (S, E) pairs: S uniform over the GN, E uniform among its partners."""
    tree = cKDTree(pts)
    rng = np.random.default_rng([seed, 4])
    while True:
        start = int(rng.integers(len(pts)))
        near = np.array(tree.query_ball_point(pts[start], MAX_PAIR_M), dtype=np.int64)
        d = np.linalg.norm(pts[near] - pts[start], axis=1)
        partners = near[d >= MIN_PAIR_M]
        if len(partners):
            yield np.array([start, int(partners[rng.integers(len(partners))])])


def count_trajectories(gn: RoiNetwork, options: SimOptions, seed: int = 0) -> tuple[int, int]:
    """(number of S-E pairs, number of trajectories) the protocol yields on a GN."""
    pts = xy(gn.records)
    enumerator = TrajectoryEnumerator(pts, options, seed)
    pairs = start_end_pairs(pts)
    return len(pairs), sum(len(enumerator.trajectories(int(s), int(e))) for s, e in pairs)


def degrade_gn(gn: RoiNetwork, misses: float, seed: int = 0) -> tuple[RoiNetwork, np.ndarray]:
    """The GN the matcher gets when a share of orbital ROIs was never detected.

    Args:
        gn: the full GN.
        misses: share of ROIs removed.
        seed: random seed.

    Returns:
        The degraded GN and, for each of its nodes, its index in the full GN.
    """
    rng = np.random.default_rng([seed, 3])
    n_miss = round(misses * len(gn))
    kept = np.sort(rng.choice(len(gn), len(gn) - n_miss, replace=False))
    return RoiNetwork(gn.records[kept].copy(), gn.frame_id, gn.map_frame, dict(gn.metadata)), kept


def transform_error(result_T: Rigid2D, sim: SimulatedLn, gn_pts: np.ndarray) -> float:
    """Largest distance between the estimated and true map position of the LN's true nodes.

    DESIGN.md Metrics: the recovered transform must map each LN node to within 2 m of its
    true GN node. Drift moved the LN nodes, so the test uses each node's drift-free odom
    position (true ``odom_T_map`` applied to its GN node): the error is
    max_i |T_est(T_true^-1 g_i) - g_i|, metres.
    """
    g = gn_pts[sim.truth_gn[sim.truth_gn >= 0]]
    odom_true = sim.map_T_odom.inverse().apply(g)
    return float(np.max(np.linalg.norm(result_T.apply(odom_true) - g, axis=1)))


def ln_prefix(sim: SimulatedLn, n: int) -> SimulatedLn:
    """The LN as the rover holds it after its first ``n`` nodes (least travelled first).

    Nodes are ordered by their drift sigma, which grows with the distance travelled
    (ties, e.g. a false detection and the node it was seen from, keep record order).
    """
    order = np.argsort(sim.sigma, kind="stable")[:n]
    rec = sim.records[order].copy()
    rec["id"] = np.arange(len(order))
    return SimulatedLn(rec, sim.sigma[order], sim.truth_gn[order], sim.map_T_odom,
                       sim.trajectory)


def corridor_ln(
    gn_pts: np.ndarray,
    gn_labels: np.ndarray,
    route: np.ndarray,
    radius_m: float,
    noise_fraction: float,
    rng: np.random.Generator,
) -> SimulatedLn | None:
    """A perfect LN of the GN ROIs a route passes (every ROI within ``radius_m``).

    Each ROI is seen at the route point nearest to it; its drift is uniform in the disc
    of radius ``noise_fraction`` x the distance travelled to that point (protocol step
    4); the odom frame is random (step 5). Evaluation only.

    Args:
        gn_pts: (M, 2) GN positions, ``map``, metres.
        gn_labels: (M,) GN class labels.
        route: (K, 2) route positions in ``map``, in driving order, metres.
        radius_m: corridor half-width, metres.
        noise_fraction: VO error bound as a share of distance travelled.
        rng: random generator.

    Returns:
        The LN, or None when fewer than 3 ROIs lie in the corridor.
    """
    travelled = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(route, axis=0),
                                                                axis=1))])
    dist, at = cKDTree(route).query(gn_pts)
    nodes = np.flatnonzero(dist <= radius_m)
    if len(nodes) < 3:
        return None
    nodes = nodes[np.argsort(travelled[at[nodes]], kind="stable")]
    s = travelled[at[nodes]]
    half = noise_fraction * s
    yaw = rng.uniform(-np.pi, np.pi)
    map_T_odom = Rigid2D(yaw, *(route[0] + rng.uniform(-ODOM_OFFSET_M, ODOM_OFFSET_M, 2)))
    radius = half * np.sqrt(rng.random(len(nodes)))
    angle = rng.uniform(-np.pi, np.pi, len(nodes))
    drift = radius[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
    odom = map_T_odom.inverse().apply(gn_pts[nodes]) + drift
    sigma = half / 2.0
    rec = empty_records(len(nodes))
    rec["x"], rec["y"] = odom[:, 0], odom[:, 1]
    rec["id"] = np.arange(len(nodes))
    rec["label"] = gn_labels[nodes]
    rec["cov_xx"] = rec["cov_yy"] = sigma**2
    rec["score"] = 1.0
    rec["n_obs"] = 1
    return SimulatedLn(rec, sigma, nodes, map_T_odom, nodes)
