"""Probabilistic refit of a fix: EM over soft LN -> GN associations with an outlier class.

The hard refit (:func:`~darces_matcher.vote.refine`) gives every LN node at most one GN
partner inside a gate and fits on those pairs with equal trust. Under false detections
and VO drift that is brittle: a drifted far node, or a false detection, that lands inside
its wide gate near the wrong GN node pulls the rotation with full weight, and a precise
node the fit has already misplaced by a few metres drops out of its gate and cannot pull
it back. This step treats the association as unknown and maximises the likelihood of the
whole LN under a mixture model instead:

    p(x_i | T) = (1 - w) sum_j pi_ij N(T x_i; g_j, s_i^2 I) / M  +  w / A

with s_i^2 the node's per-axis variance (LN drift + GN error), pi_ij the class prior
(1 - label_confusion when the classes agree, label_confusion otherwise), M / A the GN's
density and w the share of LN nodes with no GN counterpart (false detections, orbital
misses). Expectation-maximisation alternates responsibilities (E) and a weighted closed
form rigid fit (M), the same 2D Kabsch as everywhere else, so the result is always a
proper rotation. Deterministic annealing (s_i^2 + tau^2 with tau decreasing to 0) lets
a precise node that starts metres off still pull the fit. (Also running the plain EM
from the fix and keeping the run of higher likelihood changed no outcome on 4,500
benchmark LNs and cost 0.4 ms per fix: not done.)

The transform returned is the EM's own, the maximum of the mixture likelihood: where a
far node's drift exceeds the spacing of a GN rock cluster, its responsibility is split
between the rocks rather than committed to one. (A final least-squares fit on the hard
pairs instead, exact on a noiseless LN, let one-to-one assignments permuted inside such
clusters pull the fit 2-3 m: 9 vs 4 wrong matches on the 12,737 paper-protocol LNs, 41
vs 36 under 30 % outliers and 10 % label flips.) On a noiseless LN the soft fit is within
a fraction of a millimetre of the truth, not exact: nearby GN nodes of the wide-sigma far
nodes keep a little weight.

Written by hand: no library does EM registration with per-point variances, class priors
and an outlier density (probreg / pycpd use one isotropic variance and no labels).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from darces_matcher.vote import alignment_jacobian, transform_points

#: GN candidates per LN node in the E-step.
_K = 6
#: Candidate radius, in standard deviations of the (annealed) node error.
_REACH = 3.5
#: An EM level has converged when the fit moves less than this: metres of translation
#: plus milliradians of rotation (1 cm, or 10 urad: 1 cm at 1 km).
_CONVERGED = 1e-2
#: The same at an annealing level (tau > 0), where the fit need only reach the basin of
#: the next, narrower level (a looser test changed no benchmark outcome; 1 cm 15 % slower).
_ANNEAL_CONVERGED = 0.1
#: Reach margin (m): the fit moves within an annealing level.
_MARGIN_M = 1.0


class _Candidates:
    """Candidate pairs, flat, with the per-pair moments the E- and M-steps need.

    Positions are centred: LN nodes on their centroid ``src0``, GN candidates on the
    fix's image of it ``dst0`` (the same for every query of one EM run). A transform
    (yaw, t) in the original frames is (yaw, t') here, t' = t + R src0 - dst0, and every
    step is a few dot products over the pairs:

    * E-step: the log of each pair's weighted Gaussian is linear in
      coef(yaw, t') = (|t'|^2, 2(c tx + s ty), 2(c ty - s tx), -2 tx, -2 ty, -2c, -2s)
      over the columns (1, sx, sy, dx, dy, s.d, s x d) (|R s + t' - d|^2 = |s|^2 + |d|^2
      + that product), scaled per pair by -1/(2 var): one matrix-vector product;
    * M-step: the weighted 2D Kabsch needs sum(w), sum(w s), sum(w d), sum(w s.d),
      sum(w s x d): one product of the weights with the same columns.
    """

    def __init__(self, rows: np.ndarray, gn: np.ndarray, src: np.ndarray,
                 dst: np.ndarray, prior: np.ndarray, var: np.ndarray,
                 src0: np.ndarray, dst0: np.ndarray) -> None:
        self.rows, self.gn, self.prior, self.var0 = rows, gn, prior, var
        self.src0, self.dst0 = src0, dst0
        s, d = src - src0, dst - dst0
        sx, sy, dx, dy = s[:, 0], s[:, 1], d[:, 0], d[:, 1]
        self.moments = m = np.empty((len(rows), 7))
        m[:, 0] = 1.0
        m[:, 1:3], m[:, 3:5] = s, d
        m[:, 5] = sx * dx + sy * dy
        m[:, 6] = sx * dy - sy * dx
        self.norms = sx * sx + sy * sy + dx * dx + dy * dy
        self.tau: float | None = None

    def set_tau(self, tau: float) -> None:
        """Annealing width (m): every pair's variance is its own plus tau^2."""
        if tau == self.tau:
            return
        self.tau = tau
        self.var = self.var0 + tau**2
        self.inv_var = 1.0 / self.var
        neg_half = -0.5 * self.inv_var
        # log(prior / (2 pi var)) - (|s|^2 + |d|^2) / (2 var), and the scaled columns.
        self.log_base = np.log(self.prior * self.inv_var / (2.0 * math.pi)) + neg_half * self.norms
        self.exponent = self.moments * neg_half[:, None]

    def centred(self, yaw: float, t: np.ndarray) -> tuple[float, float]:
        """(yaw, t) in the original frames -> translation t' in the centred ones."""
        c, s = math.cos(yaw), math.sin(yaw)
        x, y = self.src0
        return (t[0] + c * x - s * y - self.dst0[0], t[1] + s * x + c * y - self.dst0[1])

    def uncentred(self, yaw: float, tx: float, ty: float) -> np.ndarray:
        """The inverse of :meth:`centred`: the translation in the original frames."""
        c, s = math.cos(yaw), math.sin(yaw)
        x, y = self.src0
        return np.array([tx - c * x + s * y + self.dst0[0], ty - s * x - c * y + self.dst0[1]])

    def log_lik(self, yaw: float, tx: float, ty: float) -> np.ndarray:
        """log of each pair's class prior times its Gaussian under (yaw, t') (centred
        frames)."""
        c, s = math.cos(yaw), math.sin(yaw)
        coef = np.array([tx * tx + ty * ty, 2.0 * (c * tx + s * ty), 2.0 * (c * ty - s * tx),
                         -2.0 * tx, -2.0 * ty, -2.0 * c, -2.0 * s])
        # Rounding can make the squared distance of an exact pair -1e-12: harmless.
        return self.exponent @ coef + self.log_base

    def fit(self, weights: np.ndarray) -> tuple[float, float, float]:
        """Weighted closed-form rigid fit of the pairs (centred frames): yaw, t'."""
        w, sx, sy, dx, dy, dot, crs = weights @ self.moments
        w = max(w, 1e-300)
        sx, sy, dx, dy = sx / w, sy / w, dx / w, dy / w
        yaw = math.atan2(crs / w - (sx * dy - sy * dx), dot / w - (sx * dx + sy * dy))
        c, s = math.cos(yaw), math.sin(yaw)
        return yaw, dx - (c * sx - s * sy), dy - (s * sx + c * sy)


def gn_density(pts: np.ndarray) -> float:
    """ROIs per square metre of a GN: node count over its convex hull area.

    Falls back to the bounding box for a degenerate (collinear) GN.
    """
    try:
        area = float(ConvexHull(pts).volume)
    except (QhullError, ValueError):
        span = np.ptp(pts, axis=0)
        area = float(max(span[0], 1.0) * max(span[1], 1.0))
    return len(pts) / max(area, 1.0)


def anneal_schedule(start_m: float) -> list[float]:
    """Annealing widths tau (m): start, halved while >= 0.5 m, then 0."""
    taus = []
    tau = float(start_m)
    while tau >= 0.5:
        taus.append(tau)
        tau /= 2.0
    return [*taus, 0.0]


@dataclass
class EmFit:
    """Result of :func:`em_refit`.

    Attributes:
        yaw: rotation of ``map_T_odom``, radians.
        t: (2,) translation of ``map_T_odom``, metres.
        ln: LN indices of the hard pairs (responsibility >= 0.5, one-to-one): the
            inliers reported.
        gn: GN indices of those pairs.
        log_likelihood: log-likelihood of the LN under the mixture at the fit.
        matched: (N,) probability that each LN node has a GN counterpart (the sum of
            its responsibilities): its share of the fit's information.
    """

    yaw: float
    t: np.ndarray
    ln: np.ndarray
    gn: np.ndarray
    log_likelihood: float
    matched: np.ndarray


@dataclass
class _Query:
    """Candidates and the fit (yaw, centred t') and width tau they were queried at."""

    cand: _Candidates
    yaw: float
    tx: float
    ty: float
    tau: float


class EmModel:
    """The mixture model of one LN against one GN (see the module docstring).

    Args:
        gn_tree: KD-tree of the GN positions (``map``, metres); ``gn_tree.data`` are them.
        gn_labels: (M,) GN class labels.
        ln_pts: (N, 2) LN positions, ``odom``, metres.
        ln_labels: (N,) LN class labels.
        ln_var: (N,) per-axis variance of each node's position error, LN drift plus GN
            error, m^2.
        outlier_density: w / (1 - w) x M / A, 1/m^2: the likelihood of a node with no
            GN counterpart, relative to one with a counterpart.
        label_confusion: prior probability that an LN node's class differs from its
            GN counterpart's.
    """

    def __init__(self, gn_tree, gn_labels: np.ndarray, ln_pts: np.ndarray,
                 ln_labels: np.ndarray, ln_var: np.ndarray, outlier_density: float,
                 label_confusion: float) -> None:
        self.tree = gn_tree
        self.gn_pts = np.asarray(gn_tree.data)
        self.gn_labels = gn_labels
        self.pts = ln_pts
        self.labels = ln_labels
        self.var = ln_var
        self.outlier = outlier_density
        self.confusion = label_confusion
        self.centroid = ln_pts.mean(axis=0)
        self.var_max = float(ln_var.max())
        # Where the GN side is centred: set by :meth:`run` (the fix's image of the LN
        # centroid), else by the first query.
        self.dst0: np.ndarray | None = None
        self.radius = float(np.sqrt(np.max(np.sum((ln_pts - self.centroid) ** 2, axis=1))))

    def candidates(self, yaw: float, t: np.ndarray, tau: float) -> _Candidates:
        """GN candidates of every node near the mapped LN (within the reach of width
        tau), as a flat list of pairs."""
        mapped = transform_points(yaw, t, self.pts)
        # A margin over the reach: the fit moves within an annealing level.
        reach = _REACH * np.sqrt(self.var + tau**2) + _MARGIN_M
        dist, idx = self.tree.query(mapped, k=_K, distance_upper_bound=float(reach.max()))
        rows, cols = np.nonzero(dist <= reach[:, None])
        gn = idx[rows, cols]
        prior = np.where(self.gn_labels[gn] == self.labels[rows],
                         1.0 - self.confusion, self.confusion)
        dst = self.gn_pts[gn]
        if self.dst0 is None:
            self.dst0 = mapped.mean(axis=0)
        return _Candidates(rows, gn, self.pts[rows], dst, prior, self.var[rows],
                           self.centroid, self.dst0)

    def responsibilities(self, yaw: float, tx: float, ty: float, cand: _Candidates
                         ) -> tuple[np.ndarray, np.ndarray]:
        """E-step under (yaw, t') (centred frames): the posterior of each candidate
        pair, and each node's total likelihood (outlier term included)."""
        lik = np.exp(cand.log_lik(yaw, tx, ty))
        total = np.bincount(cand.rows, lik, minlength=len(self.pts)) + self.outlier
        return lik / total[cand.rows], total

    def run(self, yaw: float, t: np.ndarray, taus: list[float], iterations: int
            ) -> tuple[float, np.ndarray, _Candidates | None]:
        """EM from (yaw, t) through the annealing levels ``taus``.

        The candidates are queried once, at the widest level: they hold every pair
        within a narrower level's reach as long as the fit has not moved further than
        the difference of the two reaches, else they are queried again. Returns the fit
        and candidates valid at tau = 0 there (None if EM stopped early).
        """
        # Centred frames: the LN on its centroid, the GN on where the fix maps it.
        self.dst0 = transform_points(yaw, t, self.centroid[None, :])[0]
        cand = self.candidates(yaw, t, taus[0])
        a, (tx, ty) = yaw, cand.centred(yaw, t)
        state = _Query(cand, a, tx, ty, taus[0])
        for tau in taus:
            state = self._covering(state, a, tx, ty, tau)
            cand = state.cand
            cand.set_tau(tau)
            converged = _ANNEAL_CONVERGED if tau else _CONVERGED
            for _ in range(iterations):
                resp, _ = self.responsibilities(a, tx, ty, cand)
                # M-step: weighted rigid fit of every candidate pair, weight =
                # responsibility over variance; stop if fewer than 3 nodes are matched.
                if np.count_nonzero(resp > 0.5) < 3:
                    return a, cand.uncentred(a, tx, ty), None
                b, ux, uy = cand.fit(resp * cand.inv_var)
                moved = abs(b - a) * 1e3 + max(abs(ux - tx), abs(uy - ty))
                a, tx, ty = b, ux, uy
                if moved < converged:
                    break
        # The final hard pairs are read at tau = 0.
        cand = self._covering(state, a, tx, ty, 0.0).cand
        return a, cand.uncentred(a, tx, ty), cand

    def _covering(self, state: _Query, yaw: float, tx: float, ty: float, tau: float
                  ) -> _Query:
        """The candidates of ``state`` if they still cover the reach of width ``tau``
        (plus the margin) at the fit (yaw, t') (centred frames), else queried there."""
        moved = math.hypot(tx - state.tx, ty - state.ty) + abs(yaw - state.yaw) * self.radius
        # The reach grows slower with tau for larger variances: the least precise node
        # leaves the least slack.
        if tau <= state.tau and moved <= _REACH * (
                math.sqrt(self.var_max + state.tau**2) - math.sqrt(self.var_max + tau**2)):
            return state
        cand = self.candidates(yaw, state.cand.uncentred(yaw, tx, ty), tau)
        return _Query(cand, yaw, tx, ty, tau)

    def hard_pairs(self, yaw: float, t: np.ndarray, cand: _Candidates | None = None
                   ) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
        """One-to-one pairs of responsibility >= 0.5 (a GN node keeps its most
        responsible LN node), the log-likelihood at (yaw, t), and each node's
        probability of having a counterpart.

        ``cand``: candidates at tau = 0 queried near (yaw, t), if any.
        """
        if cand is None:
            cand = self.candidates(yaw, t, 0.0)
        cand.set_tau(0.0)
        resp, total = self.responsibilities(yaw, *cand.centred(yaw, t), cand)
        loglik = float(np.log(total).sum())
        matched = np.bincount(cand.rows, resp, minlength=len(self.pts))
        # At most one pair per node has responsibility >= 0.5 (they sum to < 1).
        keep = np.flatnonzero(resp >= 0.5)
        gn = cand.gn[keep]
        if len(set(gn.tolist())) < len(gn):
            order = keep[np.argsort(-resp[keep], kind="stable")]
            _, first = np.unique(cand.gn[order], return_index=True)
            keep = np.sort(order[first])
        return cand.rows[keep], cand.gn[keep], loglik, matched

    def association_covariance(self, yaw: float, t: np.ndarray) -> np.ndarray:
        """(x, y, yaw) covariance of ``map_T_odom`` at a fit (yaw rad, t m), with the
        uncertainty of which GN node each LN node pairs with (Louis 1982: the observed
        information is the complete-data information less the missing information).

        The complete information is sum_i m_i J_i^T J_i / s_i^2 (each node by its
        probability of a counterpart m_i, as :func:`~darces_matcher.refit.em_covariance`
        weighs it); the missing information, per node, the variance over its possible
        partners (its responsibilities, the outlier's score 0) of the complete-data score
        J_i^T (g_k - T x_i) / s_i^2. A node whose sigma spans two rocks of a cluster pulls
        the fit two ways at once: its information is discounted by how far apart they
        pull. ``inf`` on the diagonal when the rest is not positive definite (the pairs
        leave a direction undetermined).
        """
        cand = self.candidates(yaw, t, 0.0)
        cand.set_tau(0.0)
        resp, _ = self.responsibilities(yaw, *cand.centred(yaw, t), cand)
        jac = alignment_jacobian(self.pts, yaw)
        matched = np.bincount(cand.rows, resp, minlength=len(self.pts))
        complete = np.einsum("n,nai,naj->ij", matched / self.var, jac, jac)
        residual = self.gn_pts[cand.gn] - transform_points(yaw, t, self.pts[cand.rows])
        score = np.einsum("kai,ka->ki", jac[cand.rows], residual) / self.var[cand.rows, None]
        mean = np.zeros((len(self.pts), 3))
        np.add.at(mean, cand.rows, resp[:, None] * score)
        missing = np.einsum("k,ki,kj->ij", resp, score, score) - mean.T @ mean
        observed = 0.5 * (complete - missing + (complete - missing).T)
        ev = np.linalg.eigvalsh(observed)
        if not (np.all(np.isfinite(ev)) and ev[0] > 1e-12 * max(ev[-1], 0.0) and ev[0] > 0):
            return np.diag([np.inf, np.inf, np.inf])
        return np.linalg.inv(observed)


def em_refit(model: EmModel, yaw: float, t: np.ndarray, *, anneal_start_m: float,
             iterations: int) -> EmFit:
    """Maximum-likelihood refit of a fix under the mixture model.

    Runs the annealed EM (``anneal_schedule(anneal_start_m)``, ``iterations`` per level)
    from the fix (yaw rad, t m); its hard pairs are the inliers.
    """
    y, tt, cand = model.run(float(yaw), np.asarray(t, dtype=float),
                            anneal_schedule(anneal_start_m), iterations)
    return EmFit(y, tt, *model.hard_pairs(y, tt, cand))
