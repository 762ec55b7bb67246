"""Steps 3-4 of :meth:`~darces_matcher.matcher.Matcher.match`: the hypothesise-and-vote
search of one LN on the GN.

Control triplets (:func:`select_triplets`, :func:`~darces_matcher.triplets.control_triplets`),
from close nodes when no wide triangle exists; then, per round of triplets
(:func:`search`): triangle hypotheses
(:func:`~darces_matcher.hypotheses.triangle_hypotheses`), each a rigid transform, first
confirmed by a precise node on a huge GN, then voted by the whole LN
(:func:`~darces_matcher.vote.vote`); the refit of the distinct best
(:func:`~darces_matcher.vote.refine`) and the decision on them (the odds of a chance
alignment, :func:`~darces_matcher.decision.decide`; the paper's fixed counts for the
original DARCES), until a fix.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np

from darces_matcher.config import MatchConfig
from darces_matcher.decision import MIN_CHANCE_COUNT, ChanceModel, decide
from darces_matcher.gn_model import GnModel
from darces_matcher.hypotheses import (
    apply_batch,
    fit_rigid_batch,
    query_triangles,
    triangle_hypotheses,
)
from darces_matcher.result import MatchResult, Status
from darces_matcher.timings import add_stage
from darces_matcher.tolerances import MAX_TOL_M, LnNodes, Tolerances, fit_spread
from darces_matcher.triplets import control_triplets
from darces_matcher.vote import (
    agreeing,
    displacement,
    pose_covariance,
    refine,
    transform_points,
    triplet_votes,
    vote,
)
from roi_network.transform import Rigid2D

#: Shortest side of a control triangle, metres.
MIN_SIDE_M = 10.0
#: When no control triangle has sides of ``MIN_SIDE_M``, the triplets are chosen again
#: with this shortest side (a rock cluster's close nodes; their orientation is still
#: checked against their tolerances by ``MIN_HEIGHT_RATIO``), metres.
MIN_SIDE_FLOOR_M = 3.0
#: Smallest control-triangle height over the sum of its vertex tolerances (orientation
#: must survive the noise).
MIN_HEIGHT_RATIO = 0.5
#: Control triplets that may share one LN node.
MAX_USES_PER_NODE = 3
#: Control triplets dropped by the candidate cap but with at most this many times as
#: many candidates are tried after the others, fewest candidates first, when those gave
#: no fix (in a dense rock field under 30 % false detections the only triangles of three
#: true nodes may have 4,000-60,000 candidates).
DENSE_CANDIDATES_FACTOR = 30.0
#: Control triplets per round; matching stops after the first round that gives a fix,
#: so clean LNs cost one round.
TRIPLET_BATCH = 2
#: Hypotheses kept per control triplet, those whose sides agree best (bounds the cost
#: on huge GNs; at 10^6 ROIs 4000 cut the true triangle of some LNs).
MAX_HYPOTHESES = 16000
#: With more hypotheses than this in a round, only those confirmed by a precise LN node
#: other than their own vertices are fully verified.
PREFILTER_ABOVE = 200
#: Distinct transforms refined per round (the best and its alternatives).
N_REFINE = 4
#: Alternatives with less raw support are not refined (their raw support is taken as
#: is); 3 is a triangle's own vertices.
MIN_REFINE_SUPPORT = 5
#: Association/refit rounds of the final least squares.
REFINE_ITERATIONS = 6
#: After refining a candidate, hypotheses that map every LN node within this many
#: tolerances of it are suppressed before refining the next.
DISTINCT_RATIO = 2.0
#: Least control triplets whose hypothesis agrees with the refined fix.
MIN_VOTES = 1
#: The paper's voting (the original DARCES): least support for a fix (LN nodes matched),
#: least support as a share of the LN, and least lead over the best distinct alternative.
PAPER_MIN_INLIERS = 9
#: See ``PAPER_MIN_INLIERS``.
PAPER_MIN_INLIER_FRACTION = 0.5
#: See ``PAPER_MIN_INLIERS``.
PAPER_MIN_MARGIN = 4


@dataclass(frozen=True)
class Examined:
    """What a search examined, which the decisions on its refits are charged for.

    Attributes:
        n_tested: alignments the whole search examines (the union bound of the odds).
        alternatives: log-odds of the distinct alternatives to the winner.
        hypotheses: the triangle hypotheses it verified ("spent triangles").
    """

    n_tested: float
    alternatives: list[float]
    hypotheses: Hypotheses


@dataclass(frozen=True)
class Search:
    """The outcome of steps 2-4 on one GN model.

    Attributes:
        result: the fix, or no fix and why.
        tol: the LN's tolerances on that model (None when the LN had too few nodes).
        examined: what the odds decision examined (None without a decision on odds).
    """

    result: MatchResult
    tol: Tolerances | None = None
    examined: Examined | None = None


def select_triplets(model: GnModel, nodes: LnNodes, tol: Tolerances, cfg: MatchConfig,
                    ) -> tuple[np.ndarray, int]:
    """Step 3: control triplets, precise, well conditioned, spread over nodes; the
    selective ones first, then those of a dense rock field. Returns them and the number
    of selective ones."""
    index, pts, labels = model.index, nodes.pts, nodes.labels
    sides = [MIN_SIDE_M]
    if not cfg.original_darces:
        # No wide triangle (a short LN, or one inside a rock cluster): close nodes
        # still make a triangle whose orientation survives their tolerances.
        sides.append(MIN_SIDE_FLOOR_M)
    for min_side in sides:
        dense: list[np.ndarray] = []
        triplets = control_triplets(
            pts, tol.node_tol, cfg.n_triplets,
            min_side_m=min_side, max_side_m=index.max_side_m,
            min_height_ratio=MIN_HEIGHT_RATIO,
            max_uses_per_node=MAX_USES_PER_NODE,
            # Counting candidates pays off only where random congruent triangles
            # abound.
            cost=None if index.exhaustive else (
                lambda trips: candidate_counts(model, pts, labels, tol.edge_tol, trips)),
            max_cost=model.max_candidates,
            max_dense_cost=DENSE_CANDIDATES_FACTOR * model.max_candidates,
            dense_out=dense,
        )
        # The selective triplets first; those of a dense rock field, whose many
        # congruent GN triangles only the precise nodes' confirmation thins out,
        # only after every selective round has ended without a fix.
        n_selective = len(triplets)
        triplets = np.vstack([triplets, dense[0]])
        if len(triplets):
            break
    return triplets, n_selective


def search(
    model: GnModel,
    nodes: LnNodes,
    tol: Tolerances,
    triplets: np.ndarray,
    n_selective: int,
    cfg: MatchConfig,
    timings: dict[str, float],
) -> Search:
    """Step 4: hypotheses and votes, one batch of control triplets at a time, best
    triplets first; stop as soon as the decision is a clear fix. ``timings``: the
    stages' times, added to."""
    index, pts, labels = model.index, nodes.pts, nodes.labels
    gate, groups, weights = tol.gate, tol.groups, tol.weights
    pool = _Pool()
    # Refined hypotheses by pool row: a later round refines the same best rows again.
    refined_cache: dict[int, _Refined] = {}
    result = MatchResult("no_fix", "no_hypothesis", n_triplets=len(triplets))
    examined = None
    tested = 0
    for first in range(0, len(triplets), TRIPLET_BATCH):
        batch = triplets[first : first + TRIPLET_BATCH]
        t0 = time.perf_counter()
        # Hypotheses: congruent GN triangles (edges within d_D, orientation, labels).
        ln_idx, gn_idx, source = triangle_hypotheses(
            index, pts, labels, tol.edge_tol, batch,
            use_orientation=model.use_orientation, max_hypotheses=MAX_HYPOTHESES,
        )
        source += first
        tested += len(source)
        add_stage(timings, "hypotheses", t0)
        t0 = time.perf_counter()
        # Each hypothesis gives a proper rigid transform (never a reflection).
        yaw, trans = fit_rigid_batch(pts[ln_idx], index.pts[gn_idx])
        # Cheap first look on the most precise nodes (huge GNs: many random triangles).
        if len(yaw) > PREFILTER_ABOVE:
            keep = _confirmed(model, pts, gate, tol.precise, yaw, trans, ln_idx)
            yaw, trans, source = yaw[keep], trans[keep], source[keep]
            ln_idx, gn_idx = ln_idx[keep], gn_idx[keep]
        # Verification: every hypothesis votes with the whole LN.
        mapped = apply_batch(yaw, trans, pts)
        support = vote(index, groups, gate, mapped)
        pool.add(yaw, trans, mapped, support, source, ln_idx, gn_idx)
        add_stage(timings, "vote", t0)
        if not len(pool.yaw):
            continue
        t0 = time.perf_counter()
        # Refit the best distinct transforms on all their inliers.
        candidates, leftover = _refine_distinct(model, pts, groups, gate, weights, pool,
                                                cfg, refined_cache)
        # Decision: enough support AND a clear margin over the best distinct alternative.
        done = min(first + TRIPLET_BATCH, len(triplets))
        # The alignments the whole search examines (the union bound of the odds),
        # extrapolated from the rounds so far (over the selective triplets while
        # only those have been tried).
        n_tested = tested * (n_selective if done <= n_selective else len(triplets)) / done
        result, examined = _decide(model, candidates, leftover, pool, nodes, weights,
                                   n_tested, gate, cfg)
        result.n_triplets = done
        add_stage(timings, "refine", t0)
        if result.is_fix:
            break
    result.n_hypotheses = len(pool.yaw)
    return Search(result, tol, examined)


def _confirmed(
    model: GnModel,
    pts: np.ndarray,
    gate: np.ndarray,
    precise: tuple[np.ndarray, list],
    yaw: np.ndarray,
    trans: np.ndarray,
    ln_idx: np.ndarray,
) -> np.ndarray:
    """Hypotheses confirmed by at least one precise LN node besides their own vertices.

    A random congruent GN triangle seldom also has a GN node of the right class where
    a fourth, precise LN node lands, the true one almost always does: a star
    tracker's fourth star. Only the survivors get the full vote.
    """
    nodes, groups = precise
    mapped = apply_batch(yaw, trans, pts[nodes])
    dist, _ = model.index.nearest_same_label(mapped, groups, float(gate[nodes].max()))
    hit = dist <= gate[nodes][None, :]
    own = (ln_idx[:, :, None] == nodes[None, None, :]).any(axis=1)
    return np.flatnonzero((hit & ~own).any(axis=1))


def candidate_counts(
    model: GnModel, pts: np.ndarray, labels: np.ndarray, edge_tol: np.ndarray,
    triplets: np.ndarray,
) -> np.ndarray:
    """GN candidate count of each triplet, from the triangle index (selectivity)."""
    _, owner, sides, tol, codes = query_triangles(
        pts, labels, edge_tol, triplets,
        use_orientation=model.use_orientation, use_labels=model.index.use_labels,
    )
    per_query = model.index.count_candidates(sides, tol, codes)
    return np.bincount(owner, weights=per_query, minlength=len(triplets))


def _decide(
    model: GnModel,
    candidates: list[_Refined],
    leftover: int,
    pool: _Pool,
    nodes: LnNodes,
    weights: np.ndarray,
    n_tested: float,
    gate: np.ndarray,
    cfg: MatchConfig,
) -> tuple[MatchResult, Examined | None]:
    """Fix or no fix from the refined candidates (best first); ``gate``: the nodes'
    verification gates, metres. Also returns what the odds decision examined."""
    pts, labels, kept = nodes.pts, nodes.labels, nodes.kept
    best = candidates[0]
    best_T = Rigid2D(best.yaw, best.t[0], best.t[1])
    # The runner-up is the best candidate that is a different fix: it shares less than
    # half of its correspondences with the winner.
    runner_up = max((len(c.ln) for c in candidates[1:] if not _same_fix(best, c)),
                    default=0)
    runner_up = max(runner_up, leftover)
    support = len(best.ln)
    # The triplets whose hypotheses are this fix: its pairs, or its alignment, every
    # node within its own gate of where the fix maps it (within ``DISTINCT_RATIO`` gates
    # a triplet would also vote for a refit that moved 2 gates from its triangle).
    votes = triplet_votes(pool.ln_idx, pool.gn_idx, pool.source, pool.mapped, best.ln,
                          best.gn, transform_points(best.yaw, best.t, pts), gate, 1.0)
    covariance = pose_covariance(pts[best.ln], best.yaw, weights[best.ln])
    spread = fit_spread(nodes, best.yaw, covariance)
    status: Status = "fix"
    reason = "ok"
    log_odds = p_false = float("nan")
    examined = None
    if not cfg.original_darces:
        # The odds of the winner and of every distinct alternative against chance.
        var = 1.0 / weights
        hypotheses = Hypotheses(pool.ln_idx, pool.gn_idx, pool.mapped, pool.support, gate)
        chance = model.chance
        scored = [best, *(c for c in candidates[1:] if not _same_fix(best, c))]
        odds = np.array([chance.odds(c.yaw, c.t, pts, labels, var).log_odds
                         for c in scored])
        moments = chance.log_moments(labels, var)
        verdict = decide(float(odds[0]), n_tested, odds[1:].tolist(),
                         cfg.false_match_rate, moments, MIN_CHANCE_COUNT)
        # The hypotheses' odds only raise an alignment's: a lone winner that passes
        # on the refit's odds passes on them too (the decision is the same; the odds
        # reported are then the refit's, a lower bound).
        if not (verdict.accept and len(scored) == 1):
            odds = np.maximum(odds, hypotheses.log_odds(
                chance, [(c.yaw, c.t, c.ln, c.gn) for c in scored], pts, labels, var))
            verdict = decide(float(odds[0]), n_tested, odds[1:].tolist(),
                             cfg.false_match_rate, moments, MIN_CHANCE_COUNT)
        examined = Examined(n_tested, odds[1:].tolist(), hypotheses)
        log_odds, p_false = verdict.log_odds, verdict.p_false
        unsupported = not verdict.accept and not verdict.ambiguous
        ambiguous = not verdict.accept and verdict.ambiguous
    else:
        # The paper's voting: fixed counts of support and margin.
        unsupported = support < max(PAPER_MIN_INLIERS, PAPER_MIN_INLIER_FRACTION * len(pts))
        ambiguous = support - runner_up < PAPER_MIN_MARGIN
    if unsupported:
        status, reason = "no_fix", "insufficient_support"
    elif votes < MIN_VOTES:
        # The refit drifted away from every triangle hypothesis: not trustworthy.
        status, reason = "no_fix", "unsupported_refit"
    elif spread > cfg.max_position_sigma_m:
        # Right or wrong, a fit this loose cannot place the LN within metres.
        status, reason = "no_fix", "imprecise"
    elif ambiguous:
        status, reason = "no_fix", "ambiguous"
    return MatchResult(
        status=status, reason=reason, map_T_odom=best_T,
        covariance=covariance, position_sigma_m=spread,
        inliers=np.column_stack([kept[best.ln], best.gn]).astype(np.int64),
        votes=votes, support=support,
        runner_up=runner_up, margin=support - runner_up,
        log_odds=log_odds, false_match_probability=p_false,
    ), examined


def _refine_distinct(
    model: GnModel,
    pts: np.ndarray,
    groups: list,
    node_tol: np.ndarray,
    weights: np.ndarray,
    pool: _Pool,
    cfg: MatchConfig,
    cache: dict[int, _Refined] | None = None,
) -> tuple[list[_Refined], int]:
    """Refine the ``N_REFINE`` best mutually distinct hypotheses, best first.

    Non-maximum suppression: after refining the best remaining hypothesis, every
    hypothesis within ``DISTINCT_RATIO`` tolerances of it is set aside.

    Returns:
        The refined transforms, by decreasing support, then increasing residual, and
        the best raw support of the hypotheses left unrefined.
    """
    index = model.index
    alive = np.ones(len(pool.yaw), dtype=bool)
    refined = []
    for _ in range(N_REFINE):
        if not alive.any():
            break
        pick = int(np.flatnonzero(alive)[np.argmax(pool.support[alive])])
        # An alternative supported by little more than its own triangle is not worth
        # refining: its raw support stands for it.
        if refined and pool.support[pick] < MIN_REFINE_SUPPORT:
            break
        if cache is not None and pick in cache:
            # Refined in an earlier round (the pool only grows): same input, same fit.
            refined.append(cache[pick])
        else:
            yaw, t, ln, gn = refine(
                index, pts, groups, node_tol, weights, float(pool.yaw[pick]),
                pool.t[pick], iterations=REFINE_ITERATIONS, n_sigma=cfg.n_sigma,
                max_gate=MAX_TOL_M,
            )
            residual = transform_points(yaw, t, pts[ln]) - index.pts[gn]
            cost = float(np.sum(weights[ln] * np.sum(residual**2, axis=1)))
            refined.append(_Refined(yaw, t, ln, gn, cost))
            if cache is not None:
                cache[pick] = refined[-1]
        alive &= displacement(pool.mapped, pool.mapped[pick], node_tol) > DISTINCT_RATIO
    leftover = int(pool.support[alive].max(initial=0))
    return sorted(refined, key=lambda r: (-len(r.ln), r.cost)), leftover


@dataclass
class _Refined:
    """A refined transform: yaw (rad), t (m), inlier LN/GN indices, weighted cost."""

    yaw: float
    t: np.ndarray
    ln: np.ndarray
    gn: np.ndarray
    cost: float


@dataclass
class Hypotheses:
    """The triangle hypotheses a search verified, for the odds of the hypothesis that
    found an alignment (:mod:`~darces_matcher.decision`, "spent triangles"): their
    LN and GN vertices (H, 3), the LN mapped by each (H, N, 2, metres), their support
    (H,) and the nodes' verification gates (N,), metres."""

    ln_idx: np.ndarray
    gn_idx: np.ndarray
    mapped: np.ndarray
    support: np.ndarray
    gate: np.ndarray

    #: Hypotheses of one alignment scored (the best supported): the odds are a maximum
    #: over them, so fewer only lowers it.
    MAX_SCORED = 8

    def log_odds(self, chance: ChanceModel, fits: list[tuple[float, np.ndarray, np.ndarray,
                                                            np.ndarray]],
                 pts: np.ndarray, labels: np.ndarray, var: np.ndarray) -> np.ndarray:
        """Per alignment (yaw, t, LN pair indices, GN pair indices) of ``fits``: the best
        odds, each at its own transform with its own triangle left out, of the
        hypotheses that are it (:func:`~darces_matcher.vote.agreeing`, within one gate);
        -inf when none is. LN positions ``pts``, labels, per-axis variances ``var``. One
        evaluation of the chance model for all of them."""
        groups = []
        for yaw, t, ln, gn in fits:
            fix_mapped = transform_points(yaw, np.asarray(t, dtype=float), pts)
            # Only hypotheses with half the alignment's support or more can be it (the
            # rest put half its pairs outside their gates): a cheap first cut.
            rows = np.flatnonzero(self.support >= 0.5 * len(ln))
            rows = rows[agreeing(self.ln_idx[rows], self.gn_idx[rows], self.mapped[rows], ln,
                                 gn, fix_mapped, self.gate, 1.0)]
            groups.append(rows[np.argsort(-self.support[rows], kind="stable")
                               [: self.MAX_SCORED]])
        rows = np.concatenate(groups) if groups else np.zeros(0, dtype=np.int64)
        scores = chance.triangle_odds(self.mapped[rows], self.ln_idx[rows], labels, var)
        out, at = np.full(len(fits), -np.inf), 0
        for i, g in enumerate(groups):
            if len(g):
                out[i] = scores[at : at + len(g)].max()
            at += len(g)
        return out


class _Pool:
    """Hypotheses verified so far: transforms, mapped LN, support, source triplet and
    triangle correspondences (LN and GN indices)."""

    def __init__(self) -> None:
        self.yaw = np.zeros(0)
        self.t = np.zeros((0, 2))
        self.mapped = np.zeros((0, 0, 2))
        self.support = np.zeros(0, dtype=np.int64)
        self.source = np.zeros(0, dtype=np.int64)
        self.ln_idx = np.zeros((0, 3), dtype=np.int64)
        self.gn_idx = np.zeros((0, 3), dtype=np.int64)

    def add(self, yaw: np.ndarray, t: np.ndarray, mapped: np.ndarray, support: np.ndarray,
            source: np.ndarray, ln_idx: np.ndarray, gn_idx: np.ndarray) -> None:
        """Append a batch of verified hypotheses."""
        if not len(self.yaw):
            self.mapped = mapped
        else:
            self.mapped = np.concatenate([self.mapped, mapped])
        self.yaw = np.concatenate([self.yaw, yaw])
        self.t = np.concatenate([self.t, t])
        self.support = np.concatenate([self.support, support])
        self.source = np.concatenate([self.source, source])
        self.ln_idx = np.concatenate([self.ln_idx, ln_idx])
        self.gn_idx = np.concatenate([self.gn_idx, gn_idx])


def _same_fix(a: _Refined, b: _Refined) -> bool:
    """Whether two refined transforms share at least half of the smaller inlier set."""
    pairs_a = set(zip(a.ln.tolist(), a.gn.tolist(), strict=True))
    shared = sum((p in pairs_a) for p in zip(b.ln.tolist(), b.gn.tolist(), strict=True))
    return shared >= 0.5 * max(1, min(len(a.ln), len(b.ln)))
