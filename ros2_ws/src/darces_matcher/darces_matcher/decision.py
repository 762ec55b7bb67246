"""The decision: how likely is it that the winning alignment is a chance coincidence?

astrometry.net's verification (Lang et al. 2010, Sec. 2.4) in 2D, with classes. Under a
candidate ``map_T_odom`` T, each LN node i either has a GN counterpart (probability
1 - w) or none (a false detection, an orbital miss: w). Against the hypothesis that T is
a chance alignment, under which an LN node's position and class say nothing about the
GN, node i's likelihood ratio is::

    LR_i = w + (1 - w) sum_j N(T x_i; g_j, s_i^2 I) P(c_i | c_j) / (lambda_j f(c_i))

with s_i^2 its position variance (LN drift + GN error), lambda_j the GN's *local*
density around GN node j (ROIs/m^2) at the node's own scale (below), f(c) the share of
class c in the GN and P(c_i | c_j) = 1 - label_confusion when the classes agree,
label_confusion otherwise. The sum N / lambda is how much denser the GN is right where
the node lands, at the node's own precision, than around there: a precise node on an
isolated rare-class ROI of a sparse GN is worth ~10 nats, a far, drifted node in a
dense rock field next to nothing, and a node that lands on nothing costs log(w).
So a few distinctive nodes suffice in a sparse GN and a dense GN demands more, with no
fixed node count.

"Around there" is measured at the node's own scale: lambda_j is the count of the other GN
nodes within R = max(r_k, c s_i) of GN node j over pi R^2, r_k the distance to its k-th
(8th) neighbour and c :data:`SCALE_SIGMAS` (3), so that it is the k-nearest-neighbour
estimate for a precise node and, for a node whose sigma exceeds the spacing inside a
rock cluster, the density of the cluster's surroundings at the node's precision. Measured
at r_k alone, a drifted node (sigma ~4 m) landing on its own rock in a 5 m boulder field
scores log LR -0.8..0 (its peak spread over the cluster against the density of the
cluster's core): a right alignment of 20 such nodes has odds of ~1 nat. The chance model
follows the same density (each GN node owns 1 / lambda_j of its variance's area), so the
bounds below hold unchanged.

The log-odds of the alignment is the sum over the LN of log LR_i, less the three
largest terms: T was fitted to the nodes, three of them (a triangle) fix it, and their
agreement is no evidence (astrometry.net leaves the quad's own stars out likewise).

Which three (spent triangles): a hypothesis of the global search is a control triangle's three LN
nodes put on a congruent GN triangle, and under chance the other nodes land where chance
puts them whatever those three did. So a hypothesis' evidence is the sum, at its own
transform, over the nodes outside its own triangle (:meth:`ChanceModel.triangle_odds`),
and the union over the ``n_tested`` hypotheses (below) bounds the best of them, whichever
it is. An alignment's odds are the best of those of the hypotheses that are it (made of
three of its pairs, or every node within its gate of where it maps them:
:func:`~darces_matcher.vote.agreeing`; the 8 best supported), and at least the sum at
the refined alignment less its three largest terms (which also covers an alignment the
refit moved away from every triangle); each alternative's likewise. Leaving out the three
largest terms alone would charge a right alignment found by a triangle of weak nodes for
the LN's three strongest (in a boulder field, the few isolated rocks). The Chernoff
moments leave out the three smallest, which bounds any three.

Under the chance hypothesis the likelihood ratio has expectation 1, so a chance alignment
reaches odds e^K with probability at most e^-K (Markov), and among the ``n_tested``
alignments a search examines, the expected number that do is at most n_tested e^-K.
With the distinct alternatives the search refined (odds e^K_a each), the probability that
the winner is not the true alignment is::

    p_false = (n_tested + sum_a e^K_a) / (n_tested + e^K + sum_a e^K_a)

and the matcher reports a fix when p_false <= ``false_match_rate``: the one threshold,
the share of wrong fixes accepted.

Markov's inequality is loose: it holds for any LR of mean 1, and a chance alignment's LR
is far from any: nearly every node lands on nothing (LR_i = w) and a rare one on a GN
node (a large LR_i). Chernoff's, at an order s in (0, 1), bounds the same tail by
P(LR >= e^K) <= E[LR^s] e^(-s K), and E[LR^s] = prod_i E[LR_i^s] is computed from the GN
(:meth:`ChanceModel.log_moment`): for a node of variance v landing uniformly over the
area A the GN covers (A = sum_j 1 / lambda_j, so that E[LR_i] = 1 exactly), each GN node
j adds its peak, isolated from the others (overlapping peaks only lower the s-th power
of their sum, s < 1: the bound stays conservative)::

    E[LR_i^s] = w^s + (2 pi v / A) sum_j J_s(b_ij),   b_ij = (1 - w) a_ij / (2 pi v)
    J_s(b) = int_0^inf ((w + b e^-u)^s - w^s) du

(a_ij = P(c_i | c_j) / (f(c_i) lambda_j), the ratio above), the three smallest moments
left out with the spent nodes. With the orders S of :data:`CHERNOFF_ORDERS` the expected
count of chance alignments as good as the winner is the smallest of the bounds::

    n_tested min(1, min_s E[LR^s] e^((1 - s) K))   in place of n_tested

No union over the orders: at a given K every order's bound holds, so their minimum
does (it is Chernoff's bound itself, inf_s, over a grid of s); the moments are the GN's
and the LN's, fixed before any alignment is seen, so the minimum is a fixed function of
K that lies above the chance tail at every K, which is all the decision needs.

It helps where many precise nodes each carry E[LR_i^s] well below 1 and the winner's
odds are weak, which is where Markov's bound withheld fixes the oracle makes
(docs/matcher.md); on short, drifted LNs Markov's stays the smaller and nothing changes.

The floor (:data:`MIN_CHANCE_COUNT`): the Chernoff bound may lower the count of chance
alignments to 1 and no further, so that a fix needs odds of at least 1 /
``false_match_rate`` against a chance alignment, whatever the bound. The moments assume
that a chance alignment drops each node independently and uniformly over the GN. On a
clustered GN it does not: a triangle put on a boulder field brings the LN's own nearby
nodes into the field too, and each of them then scores about what it would on its own
rock (the density is local). A 27-node LN of one strongly clustered GN placed so on
another scored odds of e^0.1, an alignment the moments call an e^-11 event (the null
test, docs/matcher.md). The odds themselves hold on clustered GNs, the far tail of the
moments does not: below odds of 1 / ``false_match_rate`` the bound is not trusted.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from darces_matcher.vote import transform_points

#: GN candidates per LN node in the likelihood ratio: every GN node within reach in a
#: boulder field, where a drifted node's Gaussian spans a dozen (6 summed half of them).
_K = 32
#: Candidate reach, in standard deviations of the node's position error.
_REACH = 4.0
#: Neighbours of the local density estimate lambda_j = k / (pi r_k^2): enough that the
#: estimate is not the node itself and its closest pair, few enough to stay local
#: (~80 m at 400 ROIs/km^2, ~20 m inside a rock cluster).
DENSITY_NEIGHBOURS = 8
#: Terms left out of the log-odds: the degrees of freedom of a 2D rigid fit are fixed by
#: three nodes (a control triangle).
SPENT_NODES = 3
#: Variance bins per e-fold of the chance model's caches (moments, scaled densities).
_BINS_PER_E = 8.0
#: Grid of log y of the tabulated peak integral F_s (:func:`_peak_table`): lowest,
#: highest, points.
_PEAK_LOG_Y = (-30.0, 60.0, 4001)
#: A node's density is measured within at least this many of its sigmas of where it
#: lands (module docstring): a drifted node on its rock in a boulder field is then
#: evidence against the field's surroundings, not against the field's core.
SCALE_SIGMAS = 3.0
#: Orders s of the Chernoff bounds beside Markov's (module docstring): a grid over which
#: the bound is minimised, not a union of tests (more orders only tighten it, at one
#: cached moment per order, GN class and variance bin).
CHERNOFF_ORDERS = (0.2, 0.3, 0.4, 0.5, 0.6, 0.75, 0.9)
#: The least count of chance alignments as good as the winner that Chernoff's bound may
#: claim (module docstring, "the floor"): a fix needs odds of at least
#: 1 / false_match_rate against a chance alignment whatever the bound says.
MIN_CHANCE_COUNT = 1.0


def local_density(pts: np.ndarray, tree: cKDTree | None = None,
                  k: int = DENSITY_NEIGHBOURS) -> np.ndarray:
    """Local ROI density at each GN node, ROIs per square metre.

    The k-nearest-neighbour estimate k / (pi r_k^2), r_k the distance to the k-th
    other node (a node is not its own neighbour); at most k = N - 1.

    Args:
        pts: (N, 2) GN positions, ``map``, metres.
        tree: KD-tree of ``pts`` if already built.
        k: neighbours of the estimate.
    """
    n = len(pts)
    k = max(1, min(k, n - 1))
    tree = tree if tree is not None else cKDTree(pts)
    dist, _ = tree.query(pts, k=k + 1)
    r = np.maximum(dist[:, -1], 1.0)
    return k / (math.pi * r**2)


def class_frequencies(labels: np.ndarray) -> np.ndarray:
    """Share of each class label in the GN, indexed by label (0 for absent labels)."""
    labels = np.asarray(labels, dtype=np.int64)
    counts = np.bincount(labels, minlength=int(labels.max(initial=0)) + 1).astype(float)
    return counts / max(1.0, counts.sum())


@dataclass
class Odds:
    """Evidence for one alignment.

    Attributes:
        log_odds: K, natural log of the likelihood ratio of the alignment against a
            chance one, spent nodes left out.
        node_log_lr: (N,) log LR_i of each LN node.
    """

    log_odds: float
    node_log_lr: np.ndarray


class ChanceModel:
    """How a chance alignment looks on one GN: local densities and class frequencies.

    Built once per GN (one KD-tree query). The LN side (positions, classes, variances)
    is given per call.

    Args:
        tree: KD-tree of the GN positions (``map``, metres).
        gn_labels: (M,) GN class labels.
        use_labels: whether classes carry evidence (False: the original DARCES).
        outlier_prior: w, share of LN nodes with no GN counterpart.
        label_confusion: probability that an LN node's class differs from its GN
            counterpart's.
    """

    def __init__(self, tree: cKDTree, gn_labels: np.ndarray, *, use_labels: bool,
                 outlier_prior: float, label_confusion: float) -> None:
        self.tree = tree
        self.gn_labels = np.asarray(gn_labels, dtype=np.int64)
        pts = np.asarray(tree.data)
        self.density = local_density(pts, tree)
        #: Radius of each GN node's k-nearest-neighbour density estimate, m.
        self.radius = np.sqrt(min(DENSITY_NEIGHBOURS, max(1, len(pts) - 1))
                              / (math.pi * self.density))
        self.use_labels = use_labels
        self.outlier_prior = outlier_prior
        self.label_confusion = label_confusion
        self.frequency = class_frequencies(self.gn_labels)
        #: The area the GN covers by its own density estimate, m^2 (E[LR_i] = 1 on it).
        self.area = float(np.sum(1.0 / self.density))
        self._moments: dict[tuple[int, int, float], float] = {}
        self._scaled: dict[int, tuple[np.ndarray, float]] = {}

    @staticmethod
    def variance_bins(var: np.ndarray) -> np.ndarray:
        """The bins of node variances (m^2): eight per e-fold; a bin stands for its
        largest variance (:meth:`bin_variance`)."""
        return np.ceil(_BINS_PER_E * np.log(np.maximum(var, 1e-6))).astype(np.int64)

    @staticmethod
    def bin_variance(vbin: int) -> float:
        """The variance a bin of :meth:`variance_bins` stands for, m^2."""
        return math.exp(vbin / _BINS_PER_E)

    def density_at(self, vbin: int) -> tuple[np.ndarray, float]:
        """Each GN node's density at the scale of a node of variance bin ``vbin``
        (module docstring), ROIs/m^2, and the area they cover, sum 1 / lambda_j, m^2."""
        if vbin not in self._scaled:
            sigma = math.sqrt(self.bin_variance(vbin))
            r = np.maximum(self.radius, SCALE_SIGMAS * sigma)
            if np.all(r <= self.radius):
                self._scaled[vbin] = (self.density, self.area)
            else:
                others = self.tree.query_ball_point(np.asarray(self.tree.data), r,
                                                    return_length=True) - 1
                lam = np.where(r <= self.radius, self.density,
                               np.maximum(others, 1) / (math.pi * r**2))
                self._scaled[vbin] = (lam, float(np.sum(1.0 / lam)))
        return self._scaled[vbin]

    def _ratio(self, labels: np.ndarray, j: np.ndarray, density: np.ndarray) -> np.ndarray:
        """a_ij: the class ratio over GN node j's local density, for LN labels (N,), GN
        indices j (N, k) and the density of each pair's GN node (N, k), ROIs/m^2."""
        ratio = 1.0 / density
        if self.use_labels:
            freq = np.maximum(self.frequency[np.minimum(labels, len(self.frequency) - 1)],
                              1e-3)
            agree = self.gn_labels[j] == labels[:, None]
            ratio = ratio * np.where(agree, 1.0 - self.label_confusion,
                                     self.label_confusion) / freq[:, None]
        return ratio

    def log_moment(self, labels: np.ndarray, var: np.ndarray, order: float) -> float:
        """log E[LR^s] (s = ``order`` in (0, 1)) of an LN under chance (module
        docstring), the three smallest node moments left out (the spent nodes: whichever
        three they are, the bound stays conservative). Per node, cached by class and
        variance (eight bins per e-fold, the bin's largest variance: the moment grows
        with v)."""
        w = self.outlier_prior
        logs = []
        for label, vbin in zip(np.asarray(labels, dtype=np.int64),
                               self.variance_bins(np.asarray(var, float)), strict=True):
            key = (int(label), int(vbin), order)
            if key not in self._moments:
                vb = self.bin_variance(key[1])
                density, area = self.density_at(key[1])
                a = self._ratio(np.array([label]), np.arange(len(self.gn_labels))[None],
                                density[None])[0]
                b = (1.0 - w) * a / (2.0 * math.pi * vb)
                m = w**order + 2.0 * math.pi * vb / area * float(
                    _peak_integral(b, w, order).sum())
                self._moments[key] = math.log(min(m, 1.0))
            logs.append(self._moments[key])
        logs = np.sort(np.array(logs))
        return float(logs[SPENT_NODES:].sum()) if len(logs) > SPENT_NODES else 0.0

    def log_moments(self, labels: np.ndarray, var: np.ndarray) -> dict[float, float]:
        """log E[LR^s] of an LN under chance at each order s of :data:`CHERNOFF_ORDERS`
        (:meth:`log_moment`), for the Chernoff bounds of :func:`decide`."""
        return {s: self.log_moment(labels, var, s) for s in CHERNOFF_ORDERS}

    def _evidence(self, mapped: np.ndarray, labels: np.ndarray, var: np.ndarray
                  ) -> np.ndarray:
        """E_i of (M, 2) mapped LN nodes (``map``, m) of labels (M,) and per-axis
        variances (M,), m^2: the sum over the GN nodes within reach of each node's
        Gaussian times the class ratio over the GN's density at the node's scale
        (module docstring)."""
        reach = _REACH * np.sqrt(var)
        k = min(_K, len(self.gn_labels))
        dist, idx = self.tree.query(mapped, k=k, distance_upper_bound=float(reach.max()))
        dist, idx = dist.reshape(len(mapped), k), idx.reshape(len(mapped), k)
        near = dist <= reach[:, None]
        j = np.where(near, idx, 0)
        gauss = np.exp(-0.5 * dist**2 / var[:, None]) / (2.0 * math.pi * var[:, None])
        # Each node against the GN's density at its own scale (one density per bin).
        bins = self.variance_bins(var)
        density = np.empty_like(gauss)
        for vbin in np.unique(bins):
            rows = bins == vbin
            density[rows] = self.density_at(int(vbin))[0][j[rows]]
        ratio = gauss * self._ratio(labels, j, density)
        return np.where(near, ratio, 0.0).sum(axis=1)

    def triangle_odds(self, mapped: np.ndarray, triangles: np.ndarray, labels: np.ndarray,
                      var: np.ndarray) -> np.ndarray:
        """Log-odds of H triangle hypotheses, each at its own transform ((H, N, 2) the LN
        mapped by each, ``map``, m) with its own triangle's terms left out ((H, 3) LN
        indices; module docstring, "spent triangles"); fixed outlier share. LN labels
        (N,) and per-axis variances (N,), m^2."""
        h, n = mapped.shape[:2]
        if h == 0:
            return np.zeros(0)
        evidence = self._evidence(mapped.reshape(h * n, 2), np.tile(labels, h),
                                  np.tile(var, h)).reshape(h, n)
        w = self.outlier_prior
        node = np.log(w + (1.0 - w) * evidence)
        spent = np.take_along_axis(node, np.asarray(triangles), axis=1).sum(axis=1)
        return node.sum(axis=1) - spent

    def odds(self, yaw: float, t: np.ndarray, pts: np.ndarray, labels: np.ndarray,
             var: np.ndarray, spent: int = SPENT_NODES) -> Odds:
        """Log-odds of the alignment (yaw rad, t m) of an LN against a chance one.

        Args:
            yaw: rotation of ``map_T_odom``, radians.
            t: (2,) translation of ``map_T_odom``, metres.
            pts: (N, 2) LN positions, ``odom``, metres.
            labels: (N,) LN class labels.
            var: (N,) per-axis position variance of each node (LN drift + GN), m^2.
            spent: the largest node terms left out (the nodes the alignment was fitted
                to: a control triangle's three in the global search).
        """
        mapped = transform_points(yaw, np.asarray(t, dtype=float), pts)
        evidence = self._evidence(mapped, labels, var)
        w = self.outlier_prior
        node = np.log(w + (1.0 - w) * evidence)
        left_out = (np.sort(node)[len(node) - spent:].sum() if len(node) > spent
                    else node.sum())
        return Odds(float(node.sum() - left_out), node)


def _peak_integral(b: np.ndarray, w: float, s: float) -> np.ndarray:
    """J_s(b) = int_0^inf ((w + b e^-u)^s - w^s) du for each b (a GN node's peak over the
    outlier floor).

    With x = (b / w) e^-u it is w^s F_s(b / w), F_s(y) = int_0^y ((1 + x)^s - 1) / x dx,
    a function of one variable: tabulated once per order s (:func:`_peak_table`) and
    interpolated, ~50x cheaper than integrating every GN node's peak at every cache miss
    of :meth:`ChanceModel.log_moment` (integrating costs a sixth of the matcher's time on
    a 400 ROIs/km^2 GN). Outside the table F_s is its series: s y below, and
    F_s(Y) + (y^s - Y^s) / s above (the integrand is x^(s-1) there, to 1e-15).
    """
    b = np.asarray(b, float)
    log_y, table = _peak_table(float(s))
    ly = np.log(np.maximum(b, 1e-300) / w)
    f = np.interp(ly, log_y, table)
    low, high = ly < log_y[0], ly > log_y[-1]
    f[low] = s * np.exp(ly[low])
    f[high] = table[-1] + (np.exp(s * ly[high]) - math.exp(s * log_y[-1])) / s
    return w**s * f


@functools.lru_cache(maxsize=16)
def _peak_table(s: float) -> tuple[np.ndarray, np.ndarray]:
    """F_s(y) of :func:`_peak_integral` on a grid of log y (``_PEAK_LOG_Y``), by the
    trapezoid rule in t = log x (dx / x = dt) on a grid 8x finer. The integrand is
    increasing in t, so the rule, and the linear interpolation of F_s between grid
    points, err high by ~1e-5 of F: the bound stays conservative."""
    lo, hi, n, fine = *_PEAK_LOG_Y, 8
    t = np.linspace(lo, hi, (n - 1) * fine + 1)
    g = np.expm1(s * np.log1p(np.exp(t)))
    cum = np.concatenate([[0.0], np.cumsum((g[:-1] + g[1:]) * (0.5 * (t[1] - t[0])))])
    # int_0^(e^lo) ((1 + x)^s - 1) / x dx = s e^lo to first order (e^lo ~ 1e-13).
    return t[::fine], s * math.exp(lo) + cum[::fine]


def false_match_probability(log_odds: float, n_tested: float,
                            alternatives: list[float] | tuple[float, ...] = (),
                            log_moments: dict[float, float] | None = None,
                            min_count: float = 0.0) -> float:
    """Probability that the winning alignment is not the true one.

    Args:
        log_odds: K of the winner (natural log).
        n_tested: alignments the search examined (each a chance alignment of expected
            odds at most 1).
        alternatives: K of each distinct alternative the search refined.
        log_moments: log E[LR^s] of a chance alignment of this LN, by order s in (0, 1)
            (Chernoff's bounds beside Markov's, module docstring); None or empty:
            Markov's alone.
        min_count: the least the Chernoff bound may lower the count of chance
            alignments to (module docstring, "the floor"); 0: no floor.

    Returns:
        (n + sum e^K_a) / (n + e^K + sum e^K_a), computed in log space, n the expected
        count of chance alignments as good as the winner (times e^K): ``n_tested``, or
        ``n_tested min(1, min_s E[LR^s] e^((1 - s) K))`` with ``log_moments`` (no union
        over the orders: each bounds the same tail at this K, module docstring).
    """
    log_n = math.log(max(n_tested, 1.0))
    if log_moments:
        chernoff = min(m + (1.0 - s) * log_odds for s, m in log_moments.items())
        log_n = max(log_n + min(0.0, chernoff),
                    math.log(min_count) if min_count > 0.0 else -math.inf)
    others = np.array([log_n, *alternatives], dtype=float)
    log_others = float(np.logaddexp.reduce(others))
    # p = e^lo / (e^lo + e^K) = 1 / (1 + e^(K - lo))
    return float(1.0 / (1.0 + math.exp(min(log_odds - log_others, 700.0))))


@dataclass
class Verdict:
    """The decision on one alignment.

    Attributes:
        accept: whether p_false <= the accepted false-match rate.
        log_odds: K of the winner.
        p_false: probability that the winner is a chance or wrong alignment.
        ambiguous: the rejection is due to a distinct alternative (without the
            alternatives the winner would have passed).
    """

    accept: bool
    log_odds: float
    p_false: float
    ambiguous: bool


def decide(log_odds: float, n_tested: float, alternatives: list[float],
           false_match_rate: float, log_moments: dict[float, float] | None = None,
           min_count: float = 0.0) -> Verdict:
    """Accept the winner when its false-match probability is within the accepted rate.

    Args:
        log_odds: K of the winner.
        n_tested: alignments examined by the search.
        alternatives: K of the distinct alternatives refined.
        false_match_rate: the accepted share of wrong fixes (the one threshold).
        log_moments, min_count: see :func:`false_match_probability`.
    """
    p_false = false_match_probability(log_odds, n_tested, alternatives, log_moments,
                                      min_count)
    accept = p_false <= false_match_rate
    ambiguous = (not accept) and false_match_probability(
        log_odds, n_tested, (), log_moments, min_count) <= false_match_rate
    return Verdict(accept, log_odds, p_false, ambiguous)
