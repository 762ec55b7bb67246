"""The odds decision (decision.py), the evaluation family of GNs, short and prefix LNs."""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from darces_matcher import decision
from darces_matcher.decision import (
    ChanceModel,
    class_frequencies,
    decide,
    false_match_probability,
    local_density,
)
from darces_matcher.eval_cli import main as darces_eval
from darces_matcher.gn_generator import FAMILY, FamilySpec, family_gn, generate_family_gn
from darces_matcher.matcher import MatchConfig, Matcher
from darces_matcher.simulate import (
    SimOptions,
    corridor_ln,
    iter_lns,
    ln_prefix,
    transform_error,
)
from roi_network.records import OUTCROP, ROCK, xy


def test_false_match_probability_follows_the_odds_the_search_and_the_alternatives() -> None:
    base = false_match_probability(20.0, 1000.0)
    assert base == pytest.approx(1000.0 / (1000.0 + math.exp(20.0)))
    assert false_match_probability(25.0, 1000.0) < base       # stronger evidence
    assert false_match_probability(20.0, 10000.0) > base      # a wider search
    assert false_match_probability(20.0, 1000.0, [19.0]) > 0.2  # a close alternative
    assert false_match_probability(-5.0, 1.0) > 0.99
    # The one threshold: the accepted false-match rate.
    assert decide(20.0, 1000.0, [], 1e-2).accept
    assert not decide(20.0, 1000.0, [], 1e-9).accept
    verdict = decide(20.0, 1000.0, [19.5], 1e-2)
    assert not verdict.accept and verdict.ambiguous


def test_local_density_and_class_frequencies() -> None:
    # A 10 m grid: 0.01 ROIs/m^2 everywhere (the k-NN estimate within its discreteness).
    g = np.arange(0.0, 400.0, 10.0)
    pts = np.stack(np.meshgrid(g, g), axis=-1).reshape(-1, 2)
    inner = np.all((pts > 100) & (pts < 300), axis=1)
    density = local_density(pts)[inner]
    assert np.all((density > 0.005) & (density < 0.02))
    freq = class_frequencies(np.array([ROCK] * 19 + [OUTCROP]))
    assert freq[ROCK] == pytest.approx(0.95) and freq[OUTCROP] == pytest.approx(0.05)


def test_odds_grow_with_sparsity_and_rarity_and_fall_for_a_wrong_alignment() -> None:
    sparse, dense = family_gn("poisson_50", seed=1), family_gn("poisson_1000", seed=1)

    def odds(gn, shift: float) -> float:
        pts, labels = xy(gn.records), gn.records["label"].astype(np.int64)
        chance = ChanceModel(cKDTree(pts), labels, use_labels=True, outlier_prior=0.3,
                             label_confusion=0.1)
        nodes = np.arange(8)
        var = np.full(8, 0.5**2)
        return chance.odds(0.0, np.array([shift, 0.0]), pts[nodes], labels[nodes],
                           var).log_odds

    # Eight precise nodes on their own ROIs: far more evidence where ROIs are sparse.
    assert odds(sparse, 0.0) > odds(dense, 0.0) > 0.0
    # The same nodes 7 m off (14 sigma): they land on nothing.
    assert odds(sparse, 7.0) < 0.0 and odds(dense, 7.0) < odds(dense, 0.0)


def test_a_drifted_node_on_its_rock_in_a_boulder_field_is_evidence(monkeypatch) -> None:
    # Boulder fields (20 ROIs within ~5 m) among sparse ROIs: a node of sigma 4 m on its
    # own rock is judged against the density around the field at its own scale (three
    # sigmas), not against the field's core, where its spread peak is worth nothing.
    rng = np.random.default_rng(2)
    centres = rng.uniform(0, 2000, (15, 2))
    fields = (centres[:, None] + rng.normal(0, 5.0, (15, 20, 2))).reshape(-1, 2)
    pts = np.vstack([fields, rng.uniform(0, 2000, (200, 2))])
    labels = np.full(len(pts), ROCK, dtype=np.int64)
    tree = cKDTree(pts)
    nodes = np.arange(0, 300, 20)  # one rock of each field
    var = np.full(len(nodes), 4.0**2)
    precise = np.full(len(nodes), 0.3**2)
    vbin = int(ChanceModel.variance_bins(np.array([4.0**2]))[0])

    def node_lr(v: np.ndarray) -> np.ndarray:
        model = ChanceModel(tree, labels, use_labels=True, outlier_prior=0.3,
                            label_confusion=0.1)
        return model.odds(0.0, np.zeros(2), pts[nodes], labels[nodes], v,
                          spent=0).node_log_lr

    scaled = ChanceModel(tree, labels, use_labels=True, outlier_prior=0.3,
                         label_confusion=0.1)
    lam, area = scaled.density_at(vbin)
    scaled_lr, scaled_precise = node_lr(var), node_lr(precise)
    # The density of the k nearest neighbours alone, the core of a field.
    monkeypatch.setattr(decision, "SCALE_SIGMAS", 0.0)
    core_lr, core_precise = node_lr(var), node_lr(precise)
    assert np.median(core_lr) < 0.1
    assert np.median(scaled_lr) > 0.3
    assert np.all(scaled_lr >= core_lr - 0.01)
    # Precise nodes keep the k-nearest-neighbour density: the same evidence either way.
    assert np.allclose(scaled_precise, core_precise)
    # Each GN node owns 1 / lambda_j of its scale's area; at the wider scale the fields'
    # ROIs own more of it.
    assert area == pytest.approx(np.sum(1.0 / lam))
    assert np.median(lam[:300]) < 0.75 * np.median(scaled.density[:300])
    assert area > scaled.area


def test_family_members_generate_as_specified() -> None:
    assert {"poisson_50", "poisson_1000", "thomas_strong", "rocks95", "hole"} <= set(FAMILY)
    rocks = family_gn("rocks95", seed=1)
    assert np.mean(rocks.records["label"] == ROCK) == pytest.approx(0.95, abs=0.03)
    hole = family_gn("hole", seed=1)
    pts = xy(hole.records)
    assert not np.any(np.all(np.abs(pts - [1000.0, 500.0]) < [299.0, 249.0], axis=1))
    strong = generate_family_gn(FamilySpec("thomas", 400.0, 20.0, 5.0), seed=3)
    poisson = generate_family_gn(FamilySpec("poisson", 400.0), seed=3)
    # Clustered: the median nearest-neighbour distance collapses (Poisson ~25 m).
    for gn in (strong, poisson):
        assert len(gn) == pytest.approx(800, rel=0.1)
    nn = [np.median(cKDTree(xy(g.records)).query(xy(g.records), k=2)[0][:, 1])
          for g in (strong, poisson)]
    assert nn[0] < 0.3 * nn[1]
    assert np.array_equal(xy(family_gn("poisson_50", seed=4).records),
                          xy(family_gn("poisson_50", seed=4).records))
    with pytest.raises(ValueError, match="poisson_50"):
        family_gn("no_such_gn")


@pytest.fixture(scope="module")
def sparse_gn():
    """The family's sparsest GN (100 ROIs: a small exhaustive index)."""
    return family_gn("poisson_50", seed=1)


def test_a_short_perfect_ln_localizes_where_fixed_counts_could_not(sparse_gn) -> None:
    # As on bags/quick: the ROIs within 15 m of a short route (here 6-8 of them), 1 %
    # drift, random odom frame. The paper's counts (9 inliers at least) can never fix it;
    # the odds of a few precise nodes on a sparse GN can.
    gn = sparse_gn
    pts, labels = xy(gn.records), gn.records["label"]
    odds, counts = Matcher(gn), Matcher(gn, MatchConfig.original())
    fixes = tried = 0
    for k, sim in enumerate(iter_lns(gn, SimOptions(min_nodes=7, max_nodes=9), seed=5,
                                     max_lns=4)):
        # The route through the trajectory's first 6 nodes, densified.
        stops = pts[sim.trajectory[:6]]
        route = np.concatenate([a + np.linspace(0.0, 1.0, 20)[:, None] * (b - a)
                                for a, b in itertools.pairwise(stops)])
        ln = corridor_ln(pts, labels, route, 15.0, 0.01, np.random.default_rng(k))
        assert ln is not None and 6 <= len(ln.records) <= 8
        tried += 1
        assert not counts.match(ln.records).is_fix
        result = odds.match(ln.records)
        if result.is_fix:
            fixes += 1
            assert transform_error(result.map_T_odom, ln, pts) < 2.0
            assert result.false_match_probability <= MatchConfig().false_match_rate
    assert tried == 4 and fixes >= 3


def test_lns_of_another_gn_give_no_fix(sparse_gn) -> None:
    # The null hypothesis itself: LNs from one GN against another of the same
    # statistics. Every fix would be a chance alignment.
    matcher = Matcher(family_gn("poisson_50", seed=2))
    options = SimOptions(min_nodes=7, max_nodes=10, walks_per_pair=1)
    for sim in iter_lns(sparse_gn, options, seed=3, max_lns=5):
        result = matcher.match(sim.records)
        assert not result.is_fix
        # The best chance alignment is about as good as the chance alignments the
        # search expects (p_false near 1/2, here 0.49-1), far from the accepted rate.
        assert np.isnan(result.false_match_probability) or \
            result.false_match_probability > 0.4 > 10 * MatchConfig().false_match_rate


def test_prefix_keeps_the_least_travelled_nodes(sparse_gn) -> None:
    sim = next(iter_lns(sparse_gn, SimOptions(min_nodes=7, max_nodes=10), seed=0, max_lns=1))
    prefix = ln_prefix(sim, 5)
    assert len(prefix.records) == 5
    assert prefix.sigma.max() <= np.sort(sim.sigma)[4]
    assert set(prefix.truth_gn) <= set(sim.truth_gn)


def test_darces_eval_generates_a_family_gn_by_name(tmp_path: Path) -> None:
    out = tmp_path / "out.json"
    code = darces_eval(["--synthetic", "poisson_50", "--gn-seed", "1", "--max-lns", "3",
                        "--min-nodes", "7", "--max-nodes", "10",
                        "--methods", "darces,darces_original", "--json", str(out)])
    assert code == 0
    report = json.loads(out.read_text())
    assert report["options"]["gn"] == "synthetic:poisson_50:seed1"
    for name in ("darces", "darces_original"):
        r = report["methods"][name]
        assert r["lns"] == 3
        assert sum(r["no_fix_reasons"].values()) == r["no_fix"]
        assert 0.0 <= r["no_fix_oracle_fit_rate"] <= 1.0
    assert darces_eval(["--synthetic", "no_such_gn", "--json", str(out)]) == 1


def test_peak_integral_has_the_closed_forms() -> None:
    from darces_matcher.decision import _peak_integral

    # From a GN node far below the outlier floor to one ~1e30 above it: inside the
    # tabulated range and beyond it at both ends.
    w, b = 0.3, np.geomspace(1e-8, 1e30, 77)
    sw, sb = math.sqrt(w), np.sqrt(w + b)
    half = 2 * (sb - sw) - 2 * sw * np.log((sb + sw) / (2 * sw))
    for s, exact in ((0.5, half), (1.0, b)):  # s = 1: E[LR_i] = 1, J = b
        got = _peak_integral(b, w, s)
        assert got == pytest.approx(exact, rel=1e-4)
        # The Chernoff bound stays conservative: the integral errs high, never low.
        assert np.all(got >= exact * (1 - 1e-9))


def test_chernoff_moment_bounds_a_chance_nodes_lr_and_shrinks_the_chance_count() -> None:
    rng = np.random.default_rng(3)
    gn = rng.uniform(0, 1000, (200, 2))
    labels = np.where(rng.random(200) < 0.8, ROCK, OUTCROP)
    model = ChanceModel(cKDTree(gn), labels, use_labels=True, outlier_prior=0.3,
                        label_confusion=0.1)
    # Monte Carlo: one node of variance v dropped uniformly inside the GN (away from its
    # edge), its LR^s averaged; the model's moment (4 spent nodes' worth of copies, so
    # that one is kept) bounds it.
    x = rng.uniform(150, 850, (20000, 2))
    for v, s in ((1.0, 0.5), (25.0, 0.5), (4.0, 0.75)):
        var = np.full(4, v)
        lab = np.full(4, ROCK)
        bound = math.exp(model.log_moment(lab, var, s))
        lr = [math.exp(model.odds(0.0, p, np.zeros((1, 2)), np.array([ROCK]),
                                  np.array([v])).node_log_lr[0]) for p in x[:4000]]
        assert np.mean(np.power(lr, s)) <= bound * 1.05
        assert bound < 1.0
    # Precise nodes are worth more than drifted ones: their moment is smaller.
    lab = np.full(12, ROCK)
    assert model.log_moment(lab, np.full(12, 1.0), 0.5) < model.log_moment(
        lab, np.full(12, 25.0), 0.5) < 0.0
    # The count of chance alignments shrinks where the moments are small and the odds
    # weak; where they are not, Markov's bound stands.
    log_m = {0.5: model.log_moment(lab, np.full(12, 1.0), 0.5)}
    n_eff = 1000.0 * min(1.0, math.exp(log_m[0.5] + 0.5 * 6.0))
    assert n_eff < 250.0
    assert false_match_probability(6.0, 1000.0, (), log_m) == pytest.approx(
        n_eff / (n_eff + math.exp(6.0)))
    assert false_match_probability(40.0, 1000.0, (), log_m) == pytest.approx(
        false_match_probability(40.0, 1000.0))
    assert false_match_probability(10.0, 1000.0, (), {0.5: 0.0}) == pytest.approx(
        false_match_probability(10.0, 1000.0))
    # The orders are a grid over which one bound is minimised, not tests of the data:
    # several give the smallest of their single bounds, with no union factor.
    both = {0.5: log_m[0.5], 0.75: model.log_moment(lab, np.full(12, 1.0), 0.75)}
    single = [false_match_probability(6.0, 1000.0, (), {s: m}) for s, m in both.items()]
    assert false_match_probability(6.0, 1000.0, (), both) == pytest.approx(min(single))


def test_decision_on_the_ml_alignment_rescues_right_fixes_only() -> None:
    # A clustered GN under stress (30 % false nodes, 10 % flipped classes), the family
    # protocol: where the hard refit's odds fall short, the EM's maximum-likelihood
    # alignment from it is decided on again (refit.decide_on_ml). The fixes it makes are
    # right, within the accepted false-match rate.
    from darces_matcher.eval_cli import oracle_error

    gn = family_gn("thomas_few", seed=1)
    pts, labels = xy(gn.records), gn.records["label"]
    options = SimOptions(min_nodes=9, max_nodes=13, outliers=0.3, label_flips=0.1)
    matcher = Matcher(gn)
    rescued = 0
    for sim in iter_lns(gn, options, seed=7, max_lns=25):
        result = matcher.match(sim.records)
        if not (result.is_fix and result.reason == "ok"
                and "ml_decision" in result.timings_ms):
            continue
        rescued += 1
        assert result.false_match_probability <= MatchConfig().false_match_rate
        assert transform_error(result.map_T_odom, sim, pts) <= \
            oracle_error(sim, pts, labels) + 2.0
    assert rescued >= 1


def test_a_hypothesis_odds_leave_out_its_own_triangle() -> None:
    # The odds of a triangle hypothesis sum the LN's node terms less its own triangle's
    # (module docstring, "spent triangles"): its three largest terms are one such
    # triangle; a triangle of weaker nodes leaves more evidence.
    from darces_matcher.search import Hypotheses
    from darces_matcher.vote import transform_points

    gn = family_gn("poisson_85", seed=1)
    pts, labels = xy(gn.records), gn.records["label"]
    chance = ChanceModel(cKDTree(pts), labels, use_labels=True, outlier_prior=0.3,
                         label_confusion=0.1)
    rng = np.random.default_rng(3)
    idx = rng.choice(len(pts), 12, replace=False)
    truth_yaw, truth_t = 0.7, np.array([120.0, -40.0])
    # LN in odom: the GN nodes moved by the inverse of (yaw, t), plus noise.
    c, s = math.cos(truth_yaw), math.sin(truth_yaw)
    ln = (pts[idx] - truth_t) @ np.array([[c, -s], [s, c]]) + rng.normal(0, 0.3, (12, 2))
    var = np.full(12, 0.5**2)
    mapped = transform_points(truth_yaw, truth_t, ln)
    top3 = chance.odds(truth_yaw, truth_t, ln, labels[idx], var)
    order = np.argsort(top3.node_log_lr)
    strong, weak = order[-3:], order[:3]
    both = chance.triangle_odds(np.stack([mapped, mapped]), np.stack([strong, weak]),
                                labels[idx], var)
    assert both[0] == pytest.approx(top3.log_odds)
    assert both[1] > both[0] + 1.0
    # The alignment's odds: the best of the hypotheses that are it; none is: -inf.
    gate = np.full(12, 1.5)
    tested = Hypotheses(np.stack([strong, weak]), np.stack([idx[strong], idx[weak]]),
                        np.stack([mapped, mapped + 50.0]), np.array([12, 0]), gate)
    fits = [(truth_yaw, truth_t, np.arange(12), idx),
            (truth_yaw + 1.0, truth_t, np.arange(12), idx[::-1])]
    got = tested.log_odds(chance, fits, ln, labels[idx], var)
    assert got[0] == pytest.approx(both[0])  # the weak triangle's hypothesis is elsewhere
    assert got[1] == -np.inf


def test_odds_of_the_finding_triangle_fix_right_lns_only() -> None:
    # A clustered GN under stress, where a right alignment may be found by a triangle of
    # weak nodes (a boulder field): with the odds of the hypothesis that found it, every
    # fix is right; LNs of another GN of the same statistics still get none.
    from darces_matcher.eval_cli import oracle_error

    gn = family_gn("thomas_few", seed=1)
    pts, labels = xy(gn.records), gn.records["label"]
    # The family protocol's LNs (bench/darces_bench.py family_options at 85 ROIs/km^2).
    options = SimOptions(min_nodes=9, max_nodes=13, walks_per_pair=16, outliers=0.3,
                         label_flips=0.1)
    matcher = Matcher(gn)
    fixes = 0
    for sim in iter_lns(gn, options, seed=7, max_lns=30):
        result = matcher.match(sim.records)
        if result.is_fix:
            fixes += 1
            assert transform_error(result.map_T_odom, sim, pts) <= \
                oracle_error(sim, pts, labels) + 2.0
    assert fixes >= 15
    other = Matcher(family_gn("thomas_few", seed=2))
    for sim in iter_lns(gn, options, seed=3, max_lns=8):
        result = other.match(sim.records)
        assert not result.is_fix


def test_the_floor_keeps_a_fix_to_odds_of_one_over_the_rate() -> None:
    # Chernoff's moments of a long LN can call odds of ~1 an e^-11 event; the floor
    # (decision.MIN_CHANCE_COUNT) lets the bound lower the chance count to 1 only.
    moments = {0.5: -20.0, 0.75: -15.0}
    loose = false_match_probability(0.1, 300.0, (), moments)
    floored = false_match_probability(0.1, 300.0, (), moments, min_count=1.0)
    assert loose < 0.01 and floored == pytest.approx(1.0 / (1.0 + math.exp(0.1)))
    # Where the bound leaves more than one chance alignment, the floor does not bind.
    mild = {0.9: -6.0}  # 300 e^(-6 + 0.1 * 12) = 2.5 alignments
    assert false_match_probability(12.0, 300.0, (), mild, min_count=1.0) == \
        pytest.approx(false_match_probability(12.0, 300.0, (), mild))
    assert false_match_probability(12.0, 300.0, (), mild) < \
        false_match_probability(12.0, 300.0)
    assert not decide(0.1, 300.0, [], 1e-2, moments, min_count=1.0).accept
    assert decide(0.1, 300.0, [], 1e-2, moments).accept


def test_a_clustered_chance_alignment_is_no_fix() -> None:
    # The null test's closest chance alignment: the 95th stressed LN of the family's
    # thomas_strong (GN seed 1, LN seed 7) on the GN of seed 2, which the label-blind
    # search places at odds e^0.1 on a boulder field; without the floor under the
    # Chernoff bound (decision.MIN_CHANCE_COUNT) it would be a fix.
    # The family protocol at 400 ROIs/km^2 (bench/darces_bench.py family_options).
    options = SimOptions(walks_per_pair=2, outliers=0.3, label_flips=0.1)
    lns = list(iter_lns(family_gn("thomas_strong", seed=1), options, seed=7, max_lns=95))
    ln = lns[94].records
    result = Matcher(family_gn("thomas_strong", seed=2)).match(ln)
    assert not result.is_fix and result.false_match_probability > 0.1
