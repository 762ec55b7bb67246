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

Written by hand: no library does EM registration with per-point variances, class priors
and an outlier density (probreg / pycpd use one isotropic variance and no labels).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, QhullError

from darces_matcher.vote import fit_rigid, transform_points

#: GN candidates per LN node in the E-step.
_K = 6
#: Candidate radius, in standard deviations of the (annealed) node error.
_REACH = 3.5
#: An EM level has converged when the fit moves less than this: metres of translation
#: plus milliradians of rotation (1 cm, or 10 urad: 1 cm at 1 km).
_CONVERGED = 1e-2


@dataclass
class _Candidates:
    """Candidate pairs of one annealing level, flat: LN row, GN index, LN and GN
    positions, class prior over the Gaussian's normaliser, variance (m^2)."""

    rows: np.ndarray
    gn: np.ndarray
    src: np.ndarray
    dst: np.ndarray
    scale: np.ndarray
    var: np.ndarray


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
        ln: LN indices of the hard pairs (responsibility >= 0.5, one-to-one).
        gn: GN indices of those pairs.
        log_likelihood: log-likelihood of the LN under the mixture where EM converged
            (before the final fit on the hard pairs).
    """

    yaw: float
    t: np.ndarray
    ln: np.ndarray
    gn: np.ndarray
    log_likelihood: float


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

    def candidates(self, yaw: float, t: np.ndarray, tau: float) -> _Candidates:
        """GN candidates of every node near the mapped LN, as a flat list of pairs."""
        mapped = transform_points(yaw, t, self.pts)
        # A margin over the reach: the fit moves within an annealing level.
        reach = _REACH * np.sqrt(self.var + tau**2) + 1.0
        dist, idx = self.tree.query(mapped, k=_K, distance_upper_bound=float(reach.max()))
        rows, cols = np.nonzero(dist <= reach[:, None])
        gn = idx[rows, cols]
        prior = np.where(self.gn_labels[gn] == self.labels[rows],
                         1.0 - self.confusion, self.confusion)
        var = self.var[rows] + tau**2
        return _Candidates(rows, gn, self.pts[rows], self.gn_pts[gn],
                           prior / (2.0 * math.pi * var), var)

    def responsibilities(self, yaw: float, t: np.ndarray, cand: _Candidates
                         ) -> tuple[np.ndarray, float]:
        """E-step: posterior of each candidate pair, and the log-likelihood of the LN."""
        d2 = np.sum((transform_points(yaw, t, cand.src) - cand.dst) ** 2, axis=1)
        lik = cand.scale * np.exp(-0.5 * d2 / cand.var)
        total = np.bincount(cand.rows, lik, minlength=len(self.pts)) + self.outlier
        return lik / total[cand.rows], float(np.log(total).sum())

    def run(self, yaw: float, t: np.ndarray, taus: list[float], iterations: int
            ) -> tuple[float, np.ndarray]:
        """EM from (yaw, t) through the annealing levels ``taus``."""
        for tau in taus:
            cand = self.candidates(yaw, t, tau)
            for _ in range(iterations):
                resp, _ = self.responsibilities(yaw, t, cand)
                # M-step: weighted rigid fit of every candidate pair, weight =
                # responsibility over variance; stop if fewer than 3 nodes are matched.
                if np.count_nonzero(resp > 0.5) < 3:
                    return yaw, t
                step = fit_rigid(cand.src, cand.dst, resp / cand.var)
                moved = abs(step[0] - yaw) * 1e3 + float(np.abs(step[1] - t).max())
                yaw, t = step
                if moved < _CONVERGED:
                    break
        return yaw, t

    def hard_pairs(self, yaw: float, t: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        """One-to-one pairs of responsibility >= 0.5 (a GN node keeps its most
        responsible LN node), and the log-likelihood at (yaw, t)."""
        cand = self.candidates(yaw, t, 0.0)
        resp, loglik = self.responsibilities(yaw, t, cand)
        # At most one pair per node has responsibility >= 0.5 (they sum to < 1).
        sel = np.flatnonzero(resp >= 0.5)
        order = sel[np.argsort(-resp[sel], kind="stable")]
        _, first = np.unique(cand.gn[order], return_index=True)
        keep = np.sort(order[first])
        return cand.rows[keep], cand.gn[keep], loglik


def em_refit(model: EmModel, yaw: float, t: np.ndarray, *, anneal_start_m: float,
             iterations: int) -> EmFit:
    """Maximum-likelihood refit of a fix under the mixture model.

    Runs the annealed EM (``anneal_schedule(anneal_start_m)``, ``iterations`` per level)
    from the fix (yaw rad, t m), then refits on its hard pairs.
    """
    y, tt = model.run(float(yaw), np.asarray(t, dtype=float),
                      anneal_schedule(anneal_start_m), iterations)
    best = EmFit(y, tt, *model.hard_pairs(y, tt))
    if len(best.ln) >= 3:
        # Final fit on the hard pairs: the transform and its inliers agree, and a
        # noiseless LN is recovered exactly (soft tails of far candidates are dropped).
        best.yaw, best.t = fit_rigid(model.pts[best.ln], model.gn_pts[best.gn],
                                     1.0 / model.var[best.ln])
    return best
