"""The LN's own error: each node's drift relative to an anchor node, once an alignment
has absorbed the anchor's odometry error, heading included.

An LN placed by odometry carries, at each node, the odometry's error at the moment the
node was observed: the position covariance and heading variance of ``/vo/odometry``
there (plus the stereo error of the node itself). A rigid alignment of the LN onto the GN
absorbs one position error and one heading error: those of the anchor node ``a``. The
records' covariance (cov_xx, cov_yy) tells the first apart (the matcher subtracts the
anchor's: ``MatchConfig.ln_sigma_relative``), not the second.

For a chain (each pose the previous one composed with a noisy step), the error of a
later node ``l`` given an earlier one ``e`` is

    e_l = e_e + theta_e * perp(p_l - p_e) + w,    Cov(w) = Q = P_l - J P_e J^T,

with ``J = [I | perp(p_l - p_e)]`` over (x, y, yaw): the heading error at ``e`` turns
everything after it about ``e``, which the alignment's rotation absorbs, and ``w`` is the
drift between the two. The same ``Q`` holds with the roles swapped for a node observed
before the anchor. :func:`turn_variance` is the part of ``P_l`` that the heading error
at ``e`` explains. Lever arms are taken between the nodes (not the rover's poses): the
heading error also turns the node's offset from the rover, so the lever is node to node
up to the heading drift times the stereo range, which ``Q`` keeps.

Without it, the anchor's heading error times the LN's length stays in every node's
sigma: on atacama_1km seed 2 an LN starting 514 m into the drive and 470 m long got node
sigmas of 2.7-3.8 m for fit residuals of 0.2-1.3 m, and no fix.

The odometry covariance a node was observed with is not in the ROI record (DESIGN.md);
:class:`NodeOdometry` keeps it on the matcher's side, from the /vo/odometry and
/local_network streams.
"""

from __future__ import annotations

import bisect

import numpy as np

#: (x, y, yaw) rows/columns of a ROS 6x6 pose covariance (x, y, z, roll, pitch, yaw).
PLANAR = [0, 1, 5]


def planar_covariance(cov6: np.ndarray) -> np.ndarray:
    """The (3, 3) (x, y, yaw) block of a ROS pose covariance (36 values, row-major)."""
    c = np.asarray(cov6, dtype=float).reshape(6, 6)
    return c[np.ix_(PLANAR, PLANAR)]


def turn_variance(pts: np.ndarray, odom_cov: np.ndarray, anchor: int) -> np.ndarray:
    """Per-axis position variance of each LN node that the anchor's heading error
    explains, m^2: what an alignment's rotation absorbs.

    For a node ``l`` observed after the node ``e`` (``e`` the anchor, or the node when
    the anchor came later), half the trace of ``J P_e J^T - P_e[:2, :2]`` (module doc):
    the heading variance at ``e`` times the squared lever arm, plus the position-heading
    cross terms. Which of two nodes came first is read from their odometry position
    variance, which grows along the drive. 0 for the anchor.

    Args:
        pts: (K, 2) node positions, odom, m.
        odom_cov: (K, 3, 3) (x, y, yaw) odometry covariance at each node's observations.
        anchor: index of the node whose odometry error the alignment absorbs.
    """
    pts = np.asarray(pts, dtype=float)
    P = np.asarray(odom_cov, dtype=float)
    odom_var = P[:, 0, 0] + P[:, 1, 1]
    e = np.where(odom_var >= odom_var[anchor], anchor, np.arange(len(pts)))
    lt = np.where(odom_var >= odom_var[anchor], np.arange(len(pts)), anchor)
    r = pts[lt] - pts[e]
    lever = np.stack([-r[:, 1], r[:, 0]], axis=1)  # perp(p_l - p_e)
    Pe = P[e]
    # trace(c r^T + r c^T + s r r^T) / 2 with c the position-heading covariance
    cross = np.einsum("ki,ki->k", Pe[:, :2, 2], lever)
    return np.clip(cross + 0.5 * Pe[:, 2, 2] * np.einsum("ki,ki->k", lever, lever), 0.0, None)


class NodeOdometry:
    """The odometry covariance each LN node was observed with, from the two streams.

    Feed it every /vo/odometry message (:meth:`add_odometry`) and every /local_network
    message (:meth:`add_ln`); :meth:`covariances` gives the (K, 3, 3) (x, y, yaw)
    covariance per node of an LN, or None when a node's is unknown.

    A node's covariance is the mean of the odometry's over the LN messages in which the
    node appeared or moved (its track took a new observation), as the record's own
    odometry part is the mean over its observations (:mod:`roi_detector.tracking`). A
    node appearing in the first LN message seen, when that message already holds more
    than one node (this process started after the LN did: a restarted matcher), is
    unknown, as is one whose stamp precedes the odometry kept; the matcher then falls
    back to the records' covariance alone.
    """

    #: a node that moved less than this between two LN messages took no observation, m
    MOVED_M = 1e-3

    def __init__(self, max_poses: int = 200_000) -> None:
        self.max_poses = max_poses
        self._stamps: list[float] = []
        self._covs: list[np.ndarray] = []
        #: id -> [sum of covariances, count, last xy], or None when unknown
        self._node: dict[int, list | None] = {}
        self._seen_ln = False

    def add_odometry(self, stamp: float, cov6: np.ndarray) -> None:
        """One /vo/odometry message: its stamp (s) and 36-value pose covariance."""
        cov = planar_covariance(cov6)
        if (self._stamps and stamp < self._stamps[-1]) or not np.all(np.isfinite(cov)):
            return  # out of order (the history stays sorted) or unusable
        self._stamps.append(float(stamp))
        self._covs.append(cov)
        if len(self._stamps) > self.max_poses:
            drop = len(self._stamps) - self.max_poses
            del self._stamps[:drop], self._covs[:drop]

    def _at(self, stamp: float) -> np.ndarray | None:
        """The covariance of the last odometry at or before ``stamp`` (None before the
        history)."""
        k = bisect.bisect_right(self._stamps, stamp) - 1
        return self._covs[k] if k >= 0 else None

    def add_ln(self, stamp: float, ids: np.ndarray, pts: np.ndarray) -> None:
        """One /local_network message: its stamp (s), node ids and (K, 2) positions."""
        late_start = not self._seen_ln and len(ids) > 1
        self._seen_ln = True
        cov = self._at(stamp)
        for i, p in zip((int(i) for i in ids), np.asarray(pts, dtype=float), strict=True):
            if i not in self._node:
                self._node[i] = None if (late_start or cov is None) else [cov.copy(), 1, p]
                continue
            state = self._node[i]
            if state is not None and np.hypot(*(p - state[2])) > self.MOVED_M:
                state[0] = state[0] + cov
                state[1] += 1
                state[2] = p

    def covariances(self, ids: np.ndarray) -> np.ndarray | None:
        """(K, 3, 3) per node of ``ids``, or None if any is unknown."""
        out = [self._node.get(int(i)) for i in ids]
        if not out or any(c is None for c in out):
            return None
        return np.array([c[0] / c[1] for c in out])


def _step(d: np.ndarray) -> np.ndarray:
    """(3, 3) Jacobian of a pose error carried over a displacement ``d`` (x, y): the
    heading error turns the displacement (``[I | perp(d)]``), the heading carries on."""
    return np.array([[1.0, 0.0, -d[1]], [0.0, 1.0, d[0]], [0.0, 0.0, 1.0]])


def chain_covariance(pts: np.ndarray, odom_cov: np.ndarray, own_var: np.ndarray,
                     anchor: int) -> np.ndarray:
    """Joint (2K, 2K) covariance of the LN nodes' position errors relative to an anchor
    node, the odometry a chain.

    The nodes are put in the order they were observed (their odometry position variance
    grows along the drive). Between two consecutive nodes ``k``, ``k + 1`` the odometry
    pose error (x, y, yaw) is carried over and grows by an independent step::

        e_{k+1} = F_k e_k + w_k,   Cov(w_k) = P_{k+1} - F_k P_k F_k^T   (clipped >= 0),

    ``F_k`` turning the displacement between the nodes by the heading error (module
    doc). The anchor's pose error is what a rigid alignment absorbs, so it is set to
    zero; a node observed before it is carried back (``e_k = F_k^-1 (e_{k+1} - w_k)``).
    Two nodes then share the steps between the anchor and the nearer of them: the drift
    of two old nodes relative to the rover is largely common, and their geometry
    between them is as good as the odometry between them, however far back they lie.
    An independent per-node model (:meth:`Matcher.node_sigma`) gives each old node its
    whole drift on its own, which lets a fit turn the old nodes as a group.

    Args:
        pts: (K, 2) node positions, odom, m (the lever arms).
        odom_cov: (K, 3, 3) (x, y, yaw) odometry covariance at each node's observations
            (:class:`NodeOdometry`); with the yaw row and column zero, a chain of
            position steps alone (an LN known by its records' covariance only).
        own_var: (K,) per-axis variance of each node's own error (its detection, not the
            odometry's), m^2, added on the diagonal.
        anchor: index of the node the errors are relative to.

    Returns:
        (2K, 2K) covariance, rows (x_0, y_0, x_1, y_1, ...) in the input order.
    """
    pts = np.asarray(pts, dtype=float)
    k = len(pts)
    P = np.asarray(odom_cov, dtype=float).reshape(k, 3, 3)
    order = np.argsort(P[:, 0, 0] + P[:, 1, 1], kind="stable")
    a = int(np.flatnonzero(order == anchor)[0])
    # Step noises between consecutive nodes in observation order.
    steps = []
    for j in range(k - 1):
        lo, hi = order[j], order[j + 1]
        F = _step(pts[hi] - pts[lo])
        Q = P[hi] - F @ P[lo] @ F.T
        w, v = np.linalg.eigh(0.5 * (Q + Q.T))
        steps.append((F, (v * np.clip(w, 0.0, None)) @ v.T))
    # Each node's pose error as a linear map of the steps' noises: G[j] (3, 3 (K - 1)).
    m = 3 * max(k - 1, 1)
    G = np.zeros((k, 3, m))
    for j in range(a + 1, k):
        F, _ = steps[j - 1]
        G[j] = F @ G[j - 1]
        G[j][:, 3 * (j - 1):3 * j] += np.eye(3)
    for j in range(a - 1, -1, -1):
        Finv = np.linalg.inv(steps[j][0])
        G[j] = Finv @ G[j + 1]
        G[j][:, 3 * j:3 * (j + 1)] -= Finv
    noise = np.zeros((m, m))
    for j, (_, Q) in enumerate(steps):
        noise[3 * j:3 * (j + 1), 3 * j:3 * (j + 1)] = Q
    pos = G[:, :2, :].reshape(2 * k, m)  # rows in observation order
    cov_sorted = pos @ noise @ pos.T
    # Back to the input order.
    idx = np.empty(2 * k, dtype=np.int64)
    idx[0::2], idx[1::2] = 2 * order, 2 * order + 1
    cov = np.empty_like(cov_sorted)
    cov[np.ix_(idx, idx)] = cov_sorted
    cov[np.diag_indices(2 * k)] += np.repeat(np.asarray(own_var, dtype=float), 2)
    return 0.5 * (cov + cov.T)
