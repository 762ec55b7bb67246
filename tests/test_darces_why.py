"""bench/darces_why.py's classification of an unfixed LN: search or decision."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def why(bench_script):
    return bench_script("darces_why")


def _search(pts, mapped, candidates):
    return {"labels": True, "rounds": [{"pts": pts, "gate": np.full(len(pts), 2.5),
                                        "mapped": mapped, "candidates": candidates}]}


def test_search_or_decision(why):
    from roi_network.transform import Rigid2D

    rng = np.random.default_rng(0)
    pts = rng.uniform(0, 300, (12, 2))
    truth = Rigid2D(0.4, 100.0, -50.0)
    right = truth.apply(pts)
    wrong = Rigid2D(0.9, 20.0, 10.0).apply(pts)
    right_cand = (truth.yaw, np.array([truth.tx, truth.ty]))
    wrong_cand = (0.9, np.array([20.0, 10.0]))
    best_right = _search(pts, np.stack([wrong, right + 0.5]), [right_cand, wrong_cand])
    best_wrong = _search(pts, np.stack([wrong, right + 0.5]), [wrong_cand, right_cand])
    none_right = _search(pts, np.stack([wrong]), [wrong_cand])
    empty = {"labels": False, "rounds": []}
    assert why.classify("insufficient_support", [none_right, best_right], truth) == \
        "right alignment best, odds short"
    assert why.classify("insufficient_support", [best_wrong, empty], truth) == \
        "right hypothesis, not the best"
    assert why.classify("insufficient_support", [none_right, empty], truth) == \
        "no right hypothesis"
    assert why.classify("unsupported_refit", [best_right], truth) == "unsupported_refit"


def test_a_misfit_is_weighed_against_the_maximum_next_to_the_truth(why):
    from darces_matcher.gn_generator import family_gn
    from darces_matcher.matcher import Matcher
    from darces_matcher.simulate import iter_lns
    from roi_network.records import xy
    from roi_network.transform import Rigid2D

    gn = family_gn("poisson_85", seed=1)
    options = why.family_options(85.0)
    sim = next(iter(iter_lns(gn, options, seed=7, max_lns=1)))
    matcher = Matcher(gn)
    result = matcher.match(sim.records)
    assert result.is_fix
    # The fix is the maximum next to the truth: the same alignment, the same likelihood.
    row = why.misfit(matcher, result, sim, xy(gn.records))
    assert row["category"] == "the model's maximum"
    assert abs(row["log_lik_near_truth"] - row["log_lik_fix"]) < 0.5
    assert row["error_near_truth_m"] < 2.0
    # An alignment 20 m and 2 degrees off is not a maximum of the likelihood.
    t = result.map_T_odom
    result.map_T_odom = Rigid2D(t.yaw + 0.035, t.tx + 20.0, t.ty)
    row = why.misfit(matcher, result, sim, xy(gn.records))
    assert row["category"] == "a better maximum near the truth"
    assert row["log_lik_near_truth"] > row["log_lik_fix"] + 1.0


def test_a_fix_is_judged_inside_its_covariance_at_the_newest_node(why):
    """chi-square of the alignment's error at the true nodes under the fix's (x, y, yaw)
    covariance: 0 at the truth; a 1 m shift over a 0.5 m sigma is 4 at every node; a
    yaw error weighs with the lever arm, so the newest node, the furthest, is the worst
    unless the yaw's own variance covers it."""
    from types import SimpleNamespace

    from darces_matcher.gn_generator import family_gn
    from darces_matcher.simulate import iter_lns
    from roi_network.records import xy
    from roi_network.transform import Rigid2D

    gn = family_gn("poisson_85", seed=1)
    sim = next(iter(iter_lns(gn, why.family_options(85.0), seed=7, max_lns=1)))
    pts = xy(gn.records)
    t = sim.map_T_odom
    cov = np.diag([0.25, 0.25, 0.0])
    at = lambda a: SimpleNamespace(map_T_odom=a, covariance=cov)  # noqa: E731
    assert why.alignment_chi2(at(t), sim, pts) == pytest.approx((0.0, 0.0), abs=1e-9)
    newest, worst = why.alignment_chi2(at(Rigid2D(t.yaw, t.tx + 1.0, t.ty)), sim, pts)
    assert newest == pytest.approx(4.0, rel=1e-6) and worst == pytest.approx(4.0, rel=1e-6)
    # 0.5 deg about the map origin: metres at the LN, far outside a 0.5 m sigma.
    turned = Rigid2D(t.yaw + np.radians(0.5), t.tx, t.ty)
    newest, worst = why.alignment_chi2(at(turned), sim, pts)
    assert worst > why.CHI2_2D_3SIGMA and newest <= worst
    cov = np.diag([0.25, 0.25, np.radians(0.5) ** 2])
    newest, worst = why.alignment_chi2(at(turned), sim, pts)
    assert worst <= why.CHI2_2D_3SIGMA
