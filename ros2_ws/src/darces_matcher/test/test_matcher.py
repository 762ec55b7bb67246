"""Matcher behaviour: recovery, orientation and semantic constraints, abstention, bad input."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from darces_matcher import matcher as matcher_module
from darces_matcher import search
from darces_matcher.gn_generator import GnSpec, generate_gn, repeated_pattern_gn
from darces_matcher.matcher import MatchConfig, Matcher
from darces_matcher.refit import refit_fix
from darces_matcher.simulate import SimOptions, iter_lns, transform_error
from darces_matcher.tolerances import ln_nodes
from roi_network.network import RoiNetwork
from roi_network.records import OUTCROP, ROCK, empty_records, xy
from roi_network.transform import Rigid2D

#: Exact recovery of a noiseless LN: by the hard least-squares refit (the original
#: DARCES), to rounding; by the default EM refit (the mixture's maximum likelihood,
#: where nearby GN nodes of the wide-sigma far nodes keep a little weight), to a
#: fraction of a millimetre.
_EXACT_M = 1e-6
_EXACT_EM_M = 1e-3


def _lns(gn: RoiNetwork, n: int, **options: float) -> list:
    return list(iter_lns(gn, SimOptions(**options), seed=7, max_lns=n))


@pytest.mark.parametrize("em", [True, False])
def test_exact_recovery_on_noiseless_lns(gn: RoiNetwork, em: bool) -> None:
    matcher = Matcher(gn, MatchConfig() if em else MatchConfig.original())
    gn_pts = xy(gn.records)
    lns = _lns(gn, 12, noise_fraction=0.0)
    assert len(lns) == 12
    for sim in lns:
        result = matcher.match(sim.records)
        assert result.status == "fix", result.reason
        assert transform_error(result.map_T_odom, sim, gn_pts) < (_EXACT_EM_M if em else _EXACT_M)
        # Every LN node is an inlier, paired with its own GN node.
        assert result.support == len(sim.records)
        assert np.array_equal(sim.truth_gn[result.inliers[:, 0]], result.inliers[:, 1])
        assert result.covariance.shape == (3, 3)
        assert np.all(np.linalg.eigvalsh(result.covariance) > 0)


def test_paper_protocol_noise_gives_right_matches(gn: RoiNetwork, matcher: Matcher) -> None:
    gn_pts = xy(gn.records)
    for sim in _lns(gn, 20):
        result = matcher.match(sim.records)
        assert result.status == "fix", result.reason
        # Drift limits the fit (see eval_cli): the right place, within a few metres.
        assert transform_error(result.map_T_odom, sim, gn_pts) < 6.0


def test_mirrored_ln_is_rejected(gn: RoiNetwork, matcher: Matcher) -> None:
    for sim in _lns(gn, 6, noise_fraction=0.0):
        mirrored = sim.records.copy()
        mirrored["x"] = -mirrored["x"]
        result = matcher.match(mirrored)
        assert result.status == "no_fix"


def test_original_darces_ignores_orientation_and_labels(gn: RoiNetwork) -> None:
    original = Matcher(gn, MatchConfig.original())
    assert not original.model.use_orientation and not original.model.use_labels
    assert original.blind_model is None
    sim = _lns(gn, 1, noise_fraction=0.0)[0]
    result = original.match(sim.records)
    assert result.status == "fix"
    assert transform_error(result.map_T_odom, sim, xy(gn.records)) < _EXACT_M


def test_class_swapped_ln_is_rejected(gn: RoiNetwork, matcher: Matcher) -> None:
    for sim in _lns(gn, 6, noise_fraction=0.0):
        swapped = sim.records.copy()
        swapped["label"] = np.where(swapped["label"] == ROCK, OUTCROP, ROCK)
        assert matcher.match(swapped).status == "no_fix"


def _flip_fifth(records: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A copy with the class of every fifth node swapped (rock <-> outcrop)."""
    flipped = records.copy()
    nodes = np.arange(0, len(flipped), 5)
    flipped["label"][nodes] = np.where(flipped["label"][nodes] == ROCK, OUTCROP, ROCK)
    return flipped, nodes


def test_misclassified_nodes_join_the_fix(gn: RoiNetwork, matcher: Matcher) -> None:
    # The EM refit's class prior lets the misclassified nodes join the labelled fix.
    for sim in _lns(gn, 6, noise_fraction=0.0):
        flipped, nodes = _flip_fifth(sim.records)
        result = matcher.match(flipped)
        assert result.status == "fix", result.reason
        assert result.support == len(flipped) - len(nodes)
        assert len(result.inliers) == len(flipped)
        assert np.array_equal(sim.truth_gn[result.inliers[:, 0]], result.inliers[:, 1])


def test_repeated_pattern_gives_no_fix() -> None:
    gn = repeated_pattern_gn(n_copies=2, seed=1)
    matcher = Matcher(gn)
    rng = np.random.default_rng(0)
    copy0 = np.flatnonzero(gn.records["x"] < 1000.0)
    nodes = rng.choice(copy0, 15, replace=False)
    truth = Rigid2D(0.7, 123.0, -456.0)
    ln = empty_records(len(nodes))
    odom = truth.inverse().apply(xy(gn.records[nodes]))
    ln["x"], ln["y"], ln["label"] = odom[:, 0], odom[:, 1], gn.records["label"][nodes]
    result = matcher.match(ln)
    assert result.status == "no_fix"
    assert result.reason == "ambiguous"
    assert result.support == result.runner_up == len(nodes)


def test_fewer_than_three_nodes(matcher: Matcher) -> None:
    for n in (0, 1, 2):
        ln = empty_records(n)
        ln["label"] = ROCK
        result = matcher.match(ln)
        assert (result.status, result.reason) == ("no_fix", "too_few_nodes")


def test_collinear_nodes(matcher: Matcher) -> None:
    ln = empty_records(10)
    ln["x"] = np.arange(10) * 30.0
    ln["label"] = ROCK
    result = matcher.match(ln)
    assert (result.status, result.reason) == ("no_fix", "no_control_triplet")


def test_non_finite_nodes_are_ignored(gn: RoiNetwork, matcher: Matcher) -> None:
    sim = _lns(gn, 1, noise_fraction=0.0)[0]
    records = sim.records.copy()
    records["x"][0] = np.nan
    result = matcher.match(records)
    assert result.status == "fix"
    assert 0 not in result.inliers[:, 0]
    assert np.array_equal(sim.truth_gn[result.inliers[:, 0]], result.inliers[:, 1])


def test_invalid_records_raise_clearly(matcher: Matcher) -> None:
    with pytest.raises(ValueError, match="label"):
        matcher.match(empty_records(5))  # class 0 is no class


def test_empty_or_tiny_gn_raises_clearly() -> None:
    with pytest.raises(ValueError, match="at least 3"):
        Matcher(RoiNetwork.empty("map"))
    tiny = empty_records(2)
    tiny["label"] = ROCK
    with pytest.raises(ValueError, match="at least 3"):
        Matcher(RoiNetwork(tiny, "map"))


def test_ln_error_model_argument(gn: RoiNetwork, matcher: Matcher) -> None:
    sim = _lns(gn, 1)[0]
    records = sim.records.copy()
    records["cov_xx"] = records["cov_yy"] = 0.0
    # The error model given explicitly replaces the records' covariance.
    result = matcher.match(records, ln_sigma=sim.sigma)
    assert result.status == "fix"
    assert result.timings_ms["total"] > 0


def test_relative_node_sigma_drops_the_common_odometry_error(gn: RoiNetwork) -> None:
    # An LN observed late in a drive: every node carries the odometry covariance since
    # the start (here 6 m, 1 sigma, on top of its own drift), an error common to all its
    # nodes that the alignment absorbs.
    sims = _lns(gn, 6)
    late = []
    for sim in sims:
        rec = sim.records.copy()
        rec["cov_xx"] = rec["cov_yy"] = sim.sigma**2 + 36.0
        late.append(rec)
    relative = Matcher(gn)
    for sim, rec in zip(sims, late, strict=True):
        # Relative to the least uncertain node: each node's own drift, floored.
        expected = np.maximum(np.sqrt(np.clip(sim.sigma**2 - sim.sigma.min() ** 2
                                              + 0.2**2, 0, None)), 0.2)
        assert np.allclose(relative.node_sigma(rec, None), expected, atol=1e-3)
        # The late LN is placed as well as the same LN seen from its own start.
        result = relative.match(rec)
        assert result.status == "fix", result.reason
        assert transform_error(result.map_T_odom, sim, xy(gn.records)) < 6.0
    # With the absolute covariance as the error model the late LNs' gates are too wide
    # to place them.
    absolute = [np.sqrt(rec["cov_xx"]) for rec in late]
    assert np.all(np.concatenate(absolute) >= 5.99)
    assert sum(relative.match(rec, ln_sigma=sigma).is_fix
               for rec, sigma in zip(late, absolute, strict=True)) < len(late)
    # A node without a position is ignored, also as the least uncertain node.
    rec = late[0].copy()
    rec["x"][0], rec["cov_xx"][0], rec["cov_yy"][0] = np.nan, 0.0, 0.0
    kept = np.arange(1, len(rec))
    assert np.allclose(ln_nodes(rec, None, relative.config).sigma,
                       relative.node_sigma(rec[kept], None))


def test_robust_to_outliers_and_label_flips(gn: RoiNetwork, matcher: Matcher) -> None:
    gn_pts = xy(gn.records)
    lns = _lns(gn, 20, outliers=0.3, label_flips=0.1)
    fixed = [matcher.match(sim.records) for sim in lns]
    errors = [transform_error(r.map_T_odom, s, gn_pts) for r, s in zip(fixed, lns, strict=True)
              if r.is_fix]
    assert len(errors) >= 18
    assert max(errors) < 6.0


def test_large_gn_uses_local_triangles() -> None:
    gn = generate_gn(GnSpec(n_rois=5000, aspect=1.0), seed=2)
    matcher = Matcher(gn)
    assert np.isfinite(matcher.index.max_side_m)
    # Local triangles only: ~neighbours^2 / 6 per node (40 neighbours below 20,000 ROIs),
    # far below the ~2 x 10^10 of the exhaustive index.
    assert matcher.index.stats.n_triangles < 5000 * 40**2 / 6
    lns = list(iter_lns(gn, SimOptions(noise_fraction=0.0), seed=1, max_lns=3))
    for sim in lns:
        result = matcher.match(sim.records)
        assert result.status == "fix"
        assert transform_error(result.map_T_odom, sim, xy(gn.records)) < _EXACT_EM_M


def test_dense_triplets_are_tried_after_the_selective_ones(monkeypatch) -> None:
    # A local-index GN with a candidate cap so low that every control triplet is
    # "dense": only the second tier of triplets can fix.
    gn = generate_gn(GnSpec(n_rois=800), seed=4)
    sims = list(iter_lns(gn, SimOptions(), seed=2, max_lns=3))
    matcher = Matcher(gn)
    matcher.model = dataclasses.replace(matcher.model, max_candidates=1)
    assert not matcher.index.exhaustive
    for sim in sims:
        monkeypatch.setattr(search, "DENSE_CANDIDATES_FACTOR", 0.0)
        assert matcher.match(sim.records).reason == "no_control_triplet"
        monkeypatch.setattr(search, "DENSE_CANDIDATES_FACTOR", 1e9)
        result = matcher.match(sim.records)
        assert result.status == "fix"
        assert transform_error(result.map_T_odom, sim, xy(gn.records)) < 2.0


def test_a_withheld_labelled_fix_falls_back_to_the_label_blind_search(
        gn: RoiNetwork, monkeypatch) -> None:
    # The EM refit withholds every labelled fix (as the odds may withhold the EM's
    # alignment of a right labelled fix): the label-blind search places the LN, and its
    # inliers agree on class at 80 % (every fifth node flipped).
    def withhold_labelled(result, *args):
        result = refit_fix(result, *args)
        if result.reason == "ok":
            result.status, result.reason = "no_fix", "insufficient_support"
        return result

    monkeypatch.setattr(matcher_module, "refit_fix", withhold_labelled)
    matcher = Matcher(gn)
    gn_pts = xy(gn.records)
    for sim in _lns(gn, 3, noise_fraction=0.0):
        flipped, _ = _flip_fifth(sim.records)
        result = matcher.match(flipped)
        assert result.status == "fix" and result.reason == "ok_label_blind"
        assert transform_error(result.map_T_odom, sim, gn_pts) < _EXACT_EM_M
