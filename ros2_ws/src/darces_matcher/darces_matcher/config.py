"""The matcher's settings, :class:`MatchConfig` (docs/matcher.md, "Parameters").

Every tunable of :class:`~darces_matcher.matcher.Matcher`, with its default and the
measurement that set it; ``MatchConfig.counts()`` and ``MatchConfig.original()`` give the
baselines (the fixed-count decision before issue 13, and the paper's original DARCES).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal


@dataclass(frozen=True)
class MatchConfig:
    """Every tunable of the matcher, with its default (see docs/matcher.md).

    Attributes:
        use_orientation: triangles must have the same orientation (cw/ccw); False is the
            original DARCES. Halves the hypotheses and rejects mirrored LNs.
        use_labels: triangles and verification must agree on class labels; False is the
            original DARCES. Divides the hypotheses by the label combinations.
        n_sigma: tolerance of a node in standard deviations of its position error.
            Larger: more robust to drift, more random hypotheses and votes.
        gn_sigma_m: 1-sigma position error of a GN node per axis (orbital), metres.
        ln_sigma_floor_m: smallest 1-sigma LN position error per axis, metres.
        ln_sigma_relative: take the records' covariance relative to the LN's least
            uncertain node. An LN placed by odometry carries, at every node, the error
            the odometry had accumulated before the LN began (the covariance since the
            start of the drive): an offset and a turn common to all its nodes, which the
            alignment absorbs. Only the growth beyond the smallest node variance (less
            ``ln_sigma_floor_m``^2, kept as that node's own detection error) tells the
            nodes apart. No effect on an LN whose first node is precise, nor on an
            explicit ``ln_sigma``.
        first_fix_judged_at_newest: judge the global search's fit precise
            (``max_position_sigma_m``) at the LN's newest node, where the rover is and
            where the fix places it, as tracking does, instead of at every node: a long
            LN's fit may be uncertain at its far end and still place the rover well
            (atacama_1km seed 2 with far rocks: 1.1 m off at the rover, refused as
            ``imprecise`` at the far end; docs/e2e.md). False: every node (before
            2026-11-26; the baselines ``counts()`` and ``original()``).
        localized_anchor_newest: once the rover is localized (:meth:`match_or_track`
            given a prior), take the covariance relative to the LN's most uncertain node
            instead: the newest, the odometry's error growing as the rover drives. Each
            node's sigma is then its drift relative to where the rover is now, and the
            alignment fitted is the one that places the rover, not the LN's start: with
            a heading drift one rigid alignment of a 1 km LN cannot hold at both ends
            (atacama_1km seed 3: a refit of the whole LN 9 nodes strong put the rover
            20 m off after 900 m, 2 deg of drift over a 600 m lever arm), and the old
            nodes weigh less. The first fix keeps the least uncertain node as anchor (its
            odds need the whole LN).
        localized_keep_likelier: once the rover is localized, :meth:`match_or_track`
            tracks near the estimate even when the global search fixes, and keeps the
            fix less likely to be a chance alignment (the smaller ``p_false``, each
            judged with its own count of alignments examined). False: the global
            search's fix whenever it has one (before 2026-11-26, evening). On
            atacama_1km seed 3 a lone node at 881 m, after 620 m with none, tilted the
            global fit 2 deg about the early cluster (19 m off at the rover, p_false
            0.008), where tracking near the estimate fitted it right; replayed on the
            31 runs kept (bench/replay_matcher.py), nothing else changed by more than
            0.01 m (docs/e2e.md).
        jackknife_covariance: once localized (:meth:`match_or_track` given a prior), a
            fix's covariance, which the filter weighs it by, is widened to cover the
            jackknife's of its inlier pairs
            (:func:`~darces_matcher.vote.jackknife_covariance`). The node sigmas are
            then relative to the newest node, which weighs most (0.2 m against metres for
            the older ones): a fit whose position at the rover rests on that one pair is
            as uncertain as the pair's pull. The decision (odds, ``imprecise``) stays on
            the analytic covariance. False: the analytic covariance alone, which trusts
            the weights (before 2026-11-26, night 2). On the held-out train_1km_s113, a
            newest node with no GN counterpart paired with a GN rock 14.6 m off and
            pulled the tracked fit there, claiming 0.3 m at the rover; the filter took
            it and the run ended 16.6 m off.
        association_covariance: the covariance reported with an EM fit (the global
            search's fix, and the tracked fits without the drift refit) is widened to
            cover the observed information's (Louis 1982,
            :meth:`~darces_matcher.em_refit.EmModel.association_covariance`): the
            complete-data information less what is missing for not knowing which rock
            each node pairs with. The decision (odds, ``imprecise``) stays on the
            complete-data covariance. In a clustered GN the maximum likelihood may sit
            2-5 m from the truth with its pairs shifted by a rock each; on five
            clustered GNs under stress (``bench/darces_why.py GN --misfits``) the
            complete-data covariance held 96.7-99.2 % of the fixes within 3 sigma at the
            newest node and 59-91 % of those misfits, this one 99.5-99.7 % and 75-100 %
            (docs/matcher.md, fourteenth session).
            False: the complete-data covariance (before 2026-11-28, fourteenth session).
        drift_fit: once localized, a fix's inlier pairs are fitted again under the LN's
            correlated drift (:mod:`~darces_matcher.drift_fit`: generalized least
            squares with the odometry chain's joint covariance relative to the newest
            node, :func:`~darces_matcher.ln_drift.chain_covariance`), the pairs the
            drift cannot explain dropped one by one (``drift_outlier_p``); the fix's
            alignment, pairs and covariance become that fit's (its covariance widened
            to cover its jackknife with ``jackknife_covariance``). The decision stands.
            Only with the odometry covariance of each node (``odom_cov``, the
            darces_matcher node's :class:`~darces_matcher.ln_drift.NodeOdometry`): the
            records' covariance does not say whether the nodes' errors are a chain (the
            paper protocol's LNs drift independently, node by node), and never with an
            explicit ``ln_sigma``. False: the fix as the search or the EM gave it.
        drift_fit_mode: ``"gls"``: the fix becomes the drift fit's, as above;
            ``"screen"``: the drift fit only drops pairs, and a fix that lost some is
            fitted again on the rest as the search fits (each node weighed by its own
            sigma, :func:`~darces_matcher.vote.fit_rigid`).
        drift_fit_first: the same refit for the first fix (no prior), its alignment then
            that valid at the newest node.
        drift_outlier_p: per pair, the probability under the drift model of a deletion
            statistic above the gate (chi-square 2: the gate is ``-2 ln p``).
        min_tol_m: smallest node tolerance in the edge tolerance d_D, metres.
        min_gate_m: smallest verification gate, metres: a node within this of a GN node
            of its class under a hypothesis votes for it. Too tight and the precise
            nodes drop out when the far ones move the fit; too loose, random votes.
        max_tol_m: largest node tolerance, metres (caps far, drifted nodes).
        n_triplets: control triplets tried per LN at most. More: robustness to outliers
            and misclassified nodes, at linear cost.
        triplet_batch: triplets per round; matching stops after the first round that
            gives a fix, so clean LNs cost one round.
        min_side_m: shortest side of a control triangle, metres.
        min_height_ratio: smallest control-triangle height over the sum of its vertex
            tolerances (orientation must survive the noise).
        max_uses_per_node: control triplets that may share one LN node.
        max_hypotheses: hypotheses kept per control triplet, those whose sides agree best
            (bounds the cost on huge GNs; at 10^6 ROIs 4000 cut the true triangle of some
            LNs: fix rate 58 % vs 65 % with 16000, median time 136 vs 280 ms; on a 174-ROI
            GN a triplet has at most a few hundred).
        max_candidates: on a local (large-GN) index, control triplets whose lookup
            returns more candidate triangles than this, or none, are not used (cost cap;
            no candidate means a vertex has no counterpart). None: 3,000 with the
            automatic 40-neighbour index (up to 20,000 ROIs), else max(30000, 0.3 x GN
            size), i.e. the cap grows with the random candidates a precise triplet has.
        dense_candidates_factor: control triplets dropped by ``max_candidates`` but
            with at most this many times as many candidates are tried after the others,
            fewest candidates first, when those gave no fix (their hypotheses thinned
            out by the precise nodes' confirmation, ``prefilter_above``): in a dense
            rock field under 30 % false detections the only triangles of three true
            nodes may have 4,000-60,000 candidates (``matern_1000``); 0: never.
        prefilter_above: with more hypotheses than this in a round, only those confirmed
            by a precise LN node other than their own vertices are fully verified.
        prefilter_nodes: how many of the most precise LN nodes may confirm.
        n_refine: distinct transforms refined (the best and its alternatives).
        min_refine_support: alternatives with less raw support are not refined (their
            raw support is taken as is); 3 is a triangle's own vertices.
        refine_iterations: association/refit rounds of the final least squares.
        distinct_ratio: after refining a candidate, hypotheses that map every LN node
            within this many tolerances of it are suppressed before refining the next.
            The runner-up is a refined candidate sharing less than half of the
            winner's correspondences.
        min_inliers: least support for a fix (LN nodes matched).
        min_inlier_fraction: least support for a fix as a fraction of the LN.
        max_position_sigma_m: largest predicted 1-sigma error (per axis, from the fit's
            covariance) of any mapped LN node for a fix, metres.
        min_votes: least control triplets whose hypothesis agrees with the refined fix.
        min_margin: least lead of the winner's support over the best distinct
            alternative; below it the matcher abstains (ambiguity) rather than guesses.
        index_max_side_m: longest indexed GN triangle side, metres; None: automatic
            (every triangle for small GNs, local triangles for large ones).
        index_exhaustive_max_nodes: GN size up to which every triangle is indexed.
        index_neighbours: with automatic side limit, about this many neighbours per node
            (index memory ~ neighbours^2 per node); None: 40 up to 20,000 ROIs (sides
            ~155 m at 400 ROIs/km^2: consecutive route nodes ~50 m apart still make an
            indexed triangle; with 14, ~105 m, under 30 % outliers the LN kept 4-10
            usable triplets and 18 of 100 stressed LNs on a Poisson GN got no fix, none
            with 40), 14 above (memory: 631 MB at 10^6 ROIs with 14). 14 in ``counts()``.
            fall inside it (index memory ~ neighbours^2 per node).
        index_mean_density_side: the automatic side limit is at least the radius
            holding ``index_neighbours`` ROIs at the GN's mean density (clustered GNs);
            False in ``counts()``: the median k-th neighbour distance alone, as before.
        index_quant_m: side-length quantisation of the triangle keys, metres; None:
            4 m for an exhaustive index, 1 m for a local one.
        label_fallback: with ``use_labels``, when the labelled search gives no fix, search
            again blind to classes (triangles and votes), and accept that fix only if
            its inliers mostly agree on class. Misclassified nodes then still count as
            geometry, while a class-swapped LN is still rejected. Costs a second index
            (built at the first fallback) and a second search on the LNs that need it;
            only for a GN of at most ``label_fallback_max_nodes`` ROIs. Also enables
            the polish.
        label_fallback_max_nodes: largest GN (ROIs) given a label-blind fallback (its
            index doubles the index memory); 0 in ``counts()``: exhaustive index only,
            as before.
        min_label_agreement: least share of a label-blind fix's (or refit's) inlier
            pairs whose LN and GN classes agree.
        polish_label_blind: refit a labelled fix with label-blind association when a
            non-inlier LN node lands on a GN node of another class; the refit is kept
            if it has more inliers and passes ``min_label_agreement``. Only without
            ``probabilistic_refit``, whose class prior (``label_confusion``) lets the
            misclassified nodes join the fix softly (with the EM, the polish changed no
            benchmark outcome and cost 0.7 ms per LN under label flips).
        decide_on_ml: when a search ends without a fix because its best alignment's odds
            fall short on its hard refit (``insufficient_support``), decide once more on
            the EM's maximum-likelihood alignment from it (``probabilistic_refit``, odds
            decision): the alignment a fix would get, whose odds the hard pairs
            understate where far nodes stand among clustered GN ROIs. Same search size,
            alternatives and threshold (docs/matcher.md, 2026-11-26).
        fallback_after_withheld: with ``probabilistic_refit`` and ``label_fallback``, a
            labelled fix whose EM alignment the decision withholds falls back to the
            label-blind search as a labelled no-fix does. False: it stays withheld
            (before 2026-11-27).
        probabilistic_refit: refit every fix by EM over soft associations with an
            outlier class (:mod:`~darces_matcher.em_refit`): false detections and
            ambiguous far nodes pull the fit by how likely they are, not fully. The
            fix's transform becomes the mixture's maximum-likelihood one, its inliers
            the EM's hard pairs, which must pass the support test again.
        outlier_prior: share of LN nodes expected to have no GN counterpart (false
            detections, orbital misses), in the EM's mixture.
        marginal_outliers: the odds decision integrates the LN's outlier share out
            under a uniform prior instead of fixing it at ``outlier_prior``
            (:mod:`~darces_matcher.decision`).
        label_confusion: prior probability that an LN node's class differs from its
            GN counterpart's, in the EM's mixture (0.5: classes ignored).
        anneal_start_m: widest annealing width of the EM, metres (halved down to
            0.5 m, then 0); 0: no annealing.
        em_iterations: EM iterations per annealing level.
        decision: ``"odds"``: a fix when the probability that the winning alignment is
            a chance (or a distinct alternative's) is at most ``false_match_rate``
            (:mod:`~darces_matcher.decision`); ``"counts"``: the fixed tests of
            ``min_inliers``, ``min_inlier_fraction`` and ``min_margin`` (the matcher
            before issue 13, kept as the baseline ``darces_counts``).
        false_match_rate: the accepted share of wrong fixes, the one threshold of the
            odds decision.
        chance_scale_sigmas: the odds weigh a node against the GN's density around where
            it lands at its own scale, radius max(r_8, this many node sigmas)
            (:mod:`~darces_matcher.decision`): a drifted node on its rock in a boulder
            field is then evidence against the field's surroundings, not against the
            field's core; 0: the 8-nearest-neighbour density alone (before 2026-11-27).
        spent_by_triangle: the global search's odds of an alignment are the best of
            its triangle hypotheses' own, each at its own transform with its own
            triangle's terms left out, and at least the three-largest rule's
            (:mod:`~darces_matcher.decision`, "spent triangles"); False: the three
            largest terms at the refined alignment (before 2026-11-28, twelfth session).
        min_chance_count: the least count of chance alignments as good as the winner
            that Chernoff's bound may claim (:mod:`~darces_matcher.decision`, "the
            floor"): 1, a fix needs odds of at least 1 / ``false_match_rate`` against a
            chance alignment whatever the bound says; 0: no floor (before 2026-11-28,
            twelfth session).
        track_spent_nodes: in :meth:`track`, the largest node terms left out of the
            odds. 0: the EM moves the alignment continuously inside the prior, it is not
            fitted to three nodes as a control triangle's is, and the count of
            alignments examined (``track_cell_fraction``) already charges that freedom;
            3 (the global search's) charged it twice: on atacama_1km seed 3's late LNs
            it took 12 nats and withheld three right refinements (docs/e2e.md).
        track_cell_fraction: in :meth:`track`, the side of a distinct alignment's cell
            in node sigmas (:meth:`prior_search_size`): 0.25 counts 64x the alignments
            of 1 sigma cells, so that the EM's optimisation inside a cell gains little.
            With 0 spent nodes, the track-mode null test (chance LNs of another GN,
            priors of 5 and 15 m on a random GN ROI) gave no fix and no p_false below
            0.01 inside the prior (``bench/darces_bench.py tracknull``).
        chernoff_orders: the odds decision bounds the count of chance alignments as good
            as the winner by Chernoff's inequality at these orders s (E[LR^s] from the
            GN's densities) beside Markov's (s = 1), the smallest of them
            (:mod:`~darces_matcher.decision`; a grid over which the bound is minimised,
            not a union of tests: more orders only tighten it, at one cached moment per
            order, GN class and variance bin); (): Markov's alone (the odds decision's
            first pass, ``darces_markov``). Until 2026-11-28 (0.5, 0.75), times 3.
        min_side_floor_m: when no control triangle has sides of ``min_side_m``, the
            triplets are chosen again with this shortest side (a rock cluster's close
            nodes; their orientation is still checked against their tolerances by
            ``min_height_ratio``); None: no second try.
    """

    use_orientation: bool = True
    use_labels: bool = True
    n_sigma: float = 3.0
    gn_sigma_m: float = 0.3
    ln_sigma_floor_m: float = 0.2
    ln_sigma_relative: bool = True
    localized_anchor_newest: bool = True
    localized_keep_likelier: bool = True
    jackknife_covariance: bool = True
    association_covariance: bool = True
    drift_fit: bool = True
    drift_fit_mode: str = "gls"
    drift_fit_first: bool = False
    drift_outlier_p: float = 1e-3
    first_fix_judged_at_newest: bool = True
    min_tol_m: float = 1.0
    min_gate_m: float = 2.5
    max_tol_m: float = 30.0
    n_triplets: int = 12
    triplet_batch: int = 2
    min_side_m: float = 10.0
    min_height_ratio: float = 0.5
    max_uses_per_node: int = 3
    max_hypotheses: int = 16000
    max_candidates: int | None = None
    dense_candidates_factor: float = 30.0
    prefilter_above: int = 200
    prefilter_nodes: int = 8
    n_refine: int = 4
    min_refine_support: int = 5
    refine_iterations: int = 6
    distinct_ratio: float = 2.0
    min_inliers: int = 9
    min_inlier_fraction: float = 0.5
    min_margin: int = 4
    min_votes: int = 1
    max_position_sigma_m: float = 2.0
    index_max_side_m: float | None = None
    index_exhaustive_max_nodes: int = 300
    index_neighbours: int | None = None
    index_quant_m: float | None = None
    index_mean_density_side: bool = True
    label_fallback: bool = True
    label_fallback_max_nodes: int = 50000
    min_label_agreement: float = 0.75
    polish_label_blind: bool = True
    probabilistic_refit: bool = True
    fallback_after_withheld: bool = True
    decide_on_ml: bool = True
    outlier_prior: float = 0.3
    marginal_outliers: bool = False
    label_confusion: float = 0.1
    anneal_start_m: float = 4.0
    em_iterations: int = 4
    decision: Literal["odds", "counts"] = "odds"
    false_match_rate: float = 1e-2
    chance_scale_sigmas: float = 3.0
    chernoff_orders: tuple[float, ...] = (0.2, 0.3, 0.4, 0.5, 0.6, 0.75, 0.9)
    spent_by_triangle: bool = True
    min_chance_count: float = 1.0
    track_spent_nodes: int = 0
    track_cell_fraction: float = 0.25
    min_side_floor_m: float | None = 3.0

    @classmethod
    def counts(cls, **overrides: object) -> MatchConfig:
        """The matcher as it was before issue 13: fixed support and margin counts,
        control triangles of 10 m sides only, the label-blind fallback on an exhaustive
        index only, the local index's side limit from the median neighbour distance
        (the generality baseline)."""
        return replace(cls(decision="counts", min_side_floor_m=None,
                           label_fallback_max_nodes=0, index_mean_density_side=False,
                           index_neighbours=14, first_fix_judged_at_newest=False),
                       **overrides)

    def __post_init__(self) -> None:
        if self.drift_fit_mode not in ("gls", "screen"):
            raise ValueError("MatchConfig.drift_fit_mode must be 'gls' or 'screen', got "
                             f"{self.drift_fit_mode!r}")
        if not 0.0 < self.drift_outlier_p < 1.0:
            raise ValueError("MatchConfig.drift_outlier_p must be in (0, 1), got "
                             f"{self.drift_outlier_p!r}")

    @classmethod
    def original(cls, **overrides: object) -> MatchConfig:
        """The original DARCES: no orientation, no semantic constraint, and none of
        this project's additions beyond the paper's hypothesise-verify-vote-refit
        (no probabilistic refit)."""
        return replace(cls(use_orientation=False, use_labels=False,
                           probabilistic_refit=False, decision="counts",
                           min_side_floor_m=None, first_fix_judged_at_newest=False),
                       **overrides)
