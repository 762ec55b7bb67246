"""Unit tests of the imagery-agnostic detection library: metrics, candidates, features,
classifiers. Fixtures are synthetic images built here."""

from __future__ import annotations

import math

import numpy as np
import pytest

from roi_detector.candidates import (
    ORBITAL_PAPER,
    ROVER_PAPER,
    ClassRule,
    MetricMoments,
    ThresholdTerm,
    candidate_mask,
    candidate_regions,
    ellipse_from_cov,
    metric_moments,
    metric_stats,
    shadow_shift_px,
    sun_direction_px,
    threshold_excess,
)
from roi_detector.classifier import (
    BinaryClassifier,
    ClassifierConfig,
    ModelFileError,
    load_classifiers,
    save_classifiers,
)
from roi_detector.features import (
    GROUPS,
    PAPER_GROUPS,
    SUN_GROUPS,
    candidate_features,
    entropy_pixels,
    feature_names,
)
from roi_detector.metrics import (
    hessian_eigenvalues,
    hessian_halo_px,
    local_contrast,
    sigma_px_from_gsd,
    to_gray_u8,
    weighted_entropy,
    weighted_entropy_at,
)
from roi_network import OUTCROP, ROCK


def _scene(seed: int = 0, shape=(120, 160)):
    """Textured soil with dark disc 'rocks' and a pale square 'outcrop'."""
    rng = np.random.default_rng(seed)
    g = 140 + rng.normal(0, 4, shape)
    yy, xx = np.mgrid[: shape[0], : shape[1]]
    rocks = [(30, 30, 2.6), (80, 50, 2.5), (40, 120, 2.9)]
    for r, c, rad in rocks:
        g[(yy - r) ** 2 + (xx - c) ** 2 <= rad**2] = 40 + rng.normal(0, 10)
    g[70:90, 100:125] = 215
    return np.clip(g, 0, 255).astype(np.uint8), rocks


def _entropy_bruteforce(g, r, c, size, sigma_e2=8.0):
    half = size // 2
    gp = np.pad(g, half, mode="reflect")
    nb = gp[r:r + size, c:c + size].astype(int).ravel()
    mu = round(nb.mean())
    total = 0.0
    for i in np.unique(nb):
        p = (nb == i).mean()
        total -= (1 - math.exp(-((i - mu) ** 2) / (2 * sigma_e2))) * p * math.log2(p)
    return total


def test_weighted_entropy_matches_equation_2():
    g, _ = _scene()
    e = weighted_entropy(g, 5)
    assert e.shape == g.shape and e.dtype == np.float32
    for r, c in [(0, 0), (30, 30), (75, 99), (119, 159), (60, 3)]:
        assert e[r, c] == pytest.approx(_entropy_bruteforce(g, r, c, 5), abs=1e-4)
    # A flat neighbourhood has zero entropy; weights zero the mean's own grey level.
    assert weighted_entropy(np.full((9, 9), 77, np.uint8), 3).max() == 0.0


def test_weighted_entropy_rejects_bad_input():
    with pytest.raises(ValueError, match="uint8"):
        weighted_entropy(np.zeros((5, 5), np.float32), 3)
    with pytest.raises(ValueError, match="odd"):
        weighted_entropy(np.zeros((5, 5), np.uint8), 4)


def test_hessian_sign_of_dark_and_bright_blobs():
    g, rocks = _scene()
    lmax, lmin = hessian_eigenvalues(g, 2.0)
    assert np.all(lmax >= lmin)
    for r, c, _ in rocks:
        assert lmin[r, c] > 20  # dark blob: both eigenvalues large positive
    lmax8, _ = hessian_eigenvalues(g, 8.0)
    assert lmax8[80, 112] < -15  # bright plateau at its scale: both negative
    assert sigma_px_from_gsd(0.5, 0.25) == 2.0
    with pytest.raises(ValueError):
        sigma_px_from_gsd(1.0, 0.0)


def test_hessian_window_with_halo_equals_whole_image():
    g, _ = _scene()
    sigma = 1.5
    halo = hessian_halo_px(sigma)
    whole = hessian_eigenvalues(g, sigma)[1]
    win = hessian_eigenvalues(g[20 - halo:70 + halo, 40 - halo:100 + halo], sigma)[1]
    np.testing.assert_allclose(win[halo:-halo, halo:-halo], whole[20:70, 40:100], atol=1e-3)


def test_to_gray_u8():
    rgb = np.zeros((2, 2, 3), np.uint16)
    rgb[0, 0] = 1000
    out = to_gray_u8(rgb, 0, 1000)
    assert out.dtype == np.uint8 and out[0, 0] == 255 and out[1, 1] == 0
    with pytest.raises(ValueError, match="lo and hi"):
        to_gray_u8(rgb)


def _metrics(g):
    lmax, lmin = hessian_eigenvalues(g, 1.5)
    return {"entropy": weighted_entropy(g, 9), "hessian_max": lmax, "hessian_min": lmin}


def test_orbital_paper_rules_find_rocks_and_outcrop():
    g, rocks = _scene()
    m = _metrics(g)
    lmax_big, lmin_big = hessian_eigenvalues(g, 6.0)
    stats = metric_stats(m)
    rock_rule = ORBITAL_PAPER.rule(ROCK)
    mask = candidate_mask(rock_rule, m, stats)
    regions = candidate_regions(mask, rock_rule, 0.0625, threshold_excess(rock_rule, m, stats))
    found = {(round(r.row), round(r.col)) for r in regions}
    for r, c, _ in rocks:
        assert any(abs(r - fr) <= 2 and abs(c - fc) <= 2 for fr, fc in found), found
    assert all(reg.label == ROCK and reg.area_m2 > 0.6 and reg.score >= 0 for reg in regions)
    big = {"hessian_max": lmax_big, "hessian_min": lmin_big}
    out_rule = ORBITAL_PAPER.rule(OUTCROP)
    omask = candidate_mask(out_rule, big, metric_stats(big))
    oregions = candidate_regions(omask, out_rule, 0.0625)
    assert len(oregions) == 1
    assert oregions[0].row == pytest.approx(79.5, abs=1.5)
    assert oregions[0].col == pytest.approx(112, abs=1.5)


def test_rover_rules_are_expressible():
    rock = ROVER_PAPER.rule(ROCK)
    assert rock.combine == "or" and rock.min_height_m == 0.25 and rock.min_area_m2 == 0.6
    assert {t.direction for t in rock.terms} == {"above", "below"}
    outcrop = ROVER_PAPER.rule(OUTCROP)
    assert outcrop.min_area_m2 == 5.5 and {t.metric for t in outcrop.terms} == {"hessian",
                                                                                "entropy"}
    with pytest.raises(ValueError, match="metric"):
        ThresholdTerm("brightness", "above")
    with pytest.raises(KeyError):
        ORBITAL_PAPER.__class__("x", ()).rule(ROCK)


def test_region_geometry_area_threshold_and_extent():
    mask = np.zeros((60, 60), bool)
    mask[10:14, 10:30] = True  # 4 x 20 px bar: 80 px
    mask[40, 40] = True  # 1 px: below area threshold
    rule = ClassRule(ROCK, 0.5, (ThresholdTerm("entropy", "above"),), max_extent_m=6.0)
    regions = candidate_regions(mask, rule, 0.0625)
    assert len(regions) == 1
    reg = regions[0]
    assert reg.area_m2 == pytest.approx(5.0) and reg.n_px == 80
    assert (reg.row, reg.col) == pytest.approx((11.5, 19.5))
    assert reg.footprint.shape == (4, 20) and reg.footprint.all()
    major, minor, angle = ellipse_from_cov(reg.cov_px)
    # A uniform ellipse with the bar's second moments: full axes 4 sqrt(L^2 / 12).
    assert major == pytest.approx(4 * math.sqrt(400 / 12)) and minor == pytest.approx(
        4 * math.sqrt(16 / 12))
    assert abs(angle) < 1e-9  # along +x (columns)
    # Wider than max_extent_m (20 px * 0.25 m = 5 m > 4 m): rejected.
    small_rule = ClassRule(ROCK, 0.5, rule.terms, max_extent_m=4.0)
    assert candidate_regions(mask, small_rule, 0.0625) == []
    # Per-pixel area map: the area is the sum.
    areas = np.full(mask.shape, 0.01)
    (reg_map,) = candidate_regions(mask, rule, areas)  # 80 px * 0.01 m^2 > 0.5 m^2
    assert reg_map.area_m2 == pytest.approx(0.8)
    assert candidate_regions(mask, ClassRule(ROCK, 0.9, rule.terms), areas) == []


def test_ellipse_angle_convention():
    a = 0.6
    rot = np.array([[math.cos(a), -math.sin(a)], [math.sin(a), math.cos(a)]])
    cov = rot @ np.diag([4.0, 1.0]) @ rot.T
    major, minor, angle = ellipse_from_cov(cov)
    assert (major, minor, angle) == pytest.approx((8.0, 4.0, 0.6))


def test_moments_combine_exactly_over_windows():
    rng = np.random.default_rng(3)
    m = {"entropy": rng.random((40, 30)).astype(np.float32),
         "hessian_max": rng.random((40, 30)).astype(np.float32),
         "hessian_min": rng.random((40, 30)).astype(np.float32)}
    whole = metric_moments(m)
    top = metric_moments({k: v[:17] for k, v in m.items()})
    bottom = metric_moments({k: v[17:] for k, v in m.items()})
    for k in whole:
        s1, s2 = whole[k].stats(), (top[k] + bottom[k]).stats()
        assert s1.mean == pytest.approx(s2.mean, rel=1e-12)
        assert s1.std == pytest.approx(s2.std, rel=1e-12)
    assert whole["hessian"].count == 2 * 40 * 30
    assert MetricMoments().stats().std == 0.0


def _features_of_scene(seed, groups=GROUPS):
    g, _ = _scene(seed)
    m = _metrics(g)
    stats = metric_stats(m)
    rule = ClassRule(ROCK, 0.1, (ThresholdTerm("hessian", "above", 1.0),), max_extent_m=8)
    regions = candidate_regions(candidate_mask(rule, m, stats), rule, 0.0625)
    rgb = np.repeat(g[..., None], 3, axis=2).astype(np.float32) / 255.0
    return regions, candidate_features(regions, rgb, g, m["entropy"], groups)


def test_features_fixed_length_and_named():
    regions, f = _features_of_scene(1)
    assert f.shape == (len(regions), len(feature_names()))
    assert np.isfinite(f).all()
    names = feature_names()
    assert len(set(names)) == len(names)
    assert feature_names(PAPER_GROUPS) == names[: len(feature_names(PAPER_GROUPS))]
    _, fp = _features_of_scene(1, PAPER_GROUPS)
    assert fp.shape[1] == len(feature_names(PAPER_GROUPS))
    # The dark rocks are darker than their ring.
    i = names.index("gray_contrast")
    assert (f[:, i] < 0).sum() >= 3
    with pytest.raises(ValueError, match="unknown feature group"):
        feature_names(("colour",))


def _toy_data(seed, n=120, f=6):
    rng = np.random.default_rng(seed)
    y = rng.integers(0, 2, n)
    x = rng.normal(0, 1, (n, f)) + y[:, None] * 2.5
    return x.astype(np.float32), y


def test_classifier_learns_and_round_trips_without_pickle(tmp_path):
    x, y = _toy_data(0)
    names = tuple(f"f{i}" for i in range(6))
    clf = BinaryClassifier("rock_orbital", names, ClassifierConfig(n_components=3, k=5)).fit(x, y)
    xt, yt = _toy_data(1)
    acc = (clf.predict(xt) == yt.astype(bool)).mean()
    assert acc > 0.9
    path = tmp_path / "m.npz"
    save_classifiers(path, {"rock_orbital": clf}, {"training_seeds": [101, 102]})
    loaded, meta = load_classifiers(path)
    np.testing.assert_array_equal(loaded["rock_orbital"].predict_proba(xt),
                                  clf.predict_proba(xt))
    assert meta["provenance"]["training_seeds"] == [101, 102]
    assert "scikit-learn" in meta["library_versions"]
    assert meta["classifiers"]["rock_orbital"]["feature_names"] == list(names)
    # No object arrays: the file loads with pickle disabled.
    with np.load(path, allow_pickle=False) as z:
        assert all(z[k].dtype != object for k in z.files)
    # Non-finite features vote "no".
    bad = xt[:2].copy()
    bad[0, 0] = np.nan
    assert clf.predict_proba(bad)[0] == 0.0


def test_classifier_bad_input(tmp_path):
    names = ("a", "b")
    with pytest.raises(ValueError, match="both classes"):
        BinaryClassifier("x", names).fit(np.zeros((4, 2)), np.zeros(4))
    with pytest.raises(ValueError, match=r"\(N, 2\)"):
        BinaryClassifier("x", names).fit(np.zeros((4, 3)), np.array([0, 1, 0, 1]))
    with pytest.raises(ModelFileError, match="not found"):
        load_classifiers(tmp_path / "missing.npz")
    junk = tmp_path / "junk.npz"
    junk.write_bytes(b"not a zip")
    with pytest.raises(ModelFileError, match=r"junk\.npz"):
        load_classifiers(junk)
    np.savez(tmp_path / "nometa.npz", a=np.zeros(2))
    with pytest.raises(ModelFileError, match="meta_json"):
        load_classifiers(tmp_path / "nometa.npz")


def test_local_contrast_and_contrast_rule():
    g, rocks = _scene()
    c = local_contrast(g, 6.0)
    for r, cc, _ in rocks:
        assert c[r, cc] < -50
    assert c[72, 102] > 30  # inside the pale square, near its corner
    m = {"contrast": c}
    rule = ClassRule(ROCK, 0.6, (ThresholdTerm("contrast", "below", 3.0),), max_extent_m=4)
    regions = candidate_regions(candidate_mask(rule, m, metric_stats(m)), rule, 0.0625)
    for r, cc, _ in rocks:
        assert any(abs(reg.row - r) < 1 and abs(reg.col - cc) < 1 for reg in regions)
    with pytest.raises(ValueError):
        local_contrast(g, 0)


def test_weighted_entropy_at_equals_the_map():
    g, _ = _scene(2)
    rng = np.random.default_rng(0)
    rows, cols = rng.integers(0, g.shape[0], 400), rng.integers(0, g.shape[1], 400)
    rows[:2], cols[:2] = (0, g.shape[0] - 1), (0, g.shape[1] - 1)  # borders reflect alike
    for size in (3, 5, 9):
        np.testing.assert_allclose(weighted_entropy_at(g, rows, cols, size),
                                   weighted_entropy(g, size)[rows, cols], atol=1e-5)
    assert weighted_entropy_at(g, np.zeros(0, int), np.zeros(0, int), 5).shape == (0,)


def test_entropy_pixels_cover_region_and_ring():
    regions, _ = _features_of_scene(1)
    reg = regions[0]
    rows, cols = entropy_pixels(reg, (120, 160))
    r0, c0, _, _ = reg.bbox
    fr, fc = np.nonzero(reg.footprint)
    got = set(zip(rows.tolist(), cols.tolist(), strict=True))
    assert {(r + r0, c + c0) for r, c in zip(fr, fc, strict=True)} <= got
    assert len(got) > reg.n_px


def test_gradient_boosting_classifier_round_trips(tmp_path):
    x, y = _toy_data(4, n=200)
    names = tuple(f"f{i}" for i in range(6))
    cfg = ClassifierConfig(kind="gradient_boosting")
    clf = BinaryClassifier("outcrop_orbital", names, cfg).fit(x, y)
    xt, yt = _toy_data(5, n=200)
    assert (clf.predict(xt) == yt.astype(bool)).mean() > 0.9
    save_classifiers(tmp_path / "g.npz", {"outcrop_orbital": clf}, {})
    loaded, meta = load_classifiers(tmp_path / "g.npz")
    assert meta["classifiers"]["outcrop_orbital"]["config"]["kind"] == "gradient_boosting"
    np.testing.assert_array_equal(loaded["outcrop_orbital"].predict_proba(xt),
                                  clf.predict_proba(xt))
    # Stored as trees: the file does not hold the training set.
    with np.load(tmp_path / "g.npz", allow_pickle=False) as z:
        assert "outcrop_orbital__x" not in z.files and "outcrop_orbital__trees_value" in z.files
    assert meta["classifiers"]["outcrop_orbital"]["stored"] == "trees"
    assert meta["classifiers"]["outcrop_orbital"]["n_samples"] == 200
    with pytest.raises(ValueError, match="kind"):
        ClassifierConfig(kind="svm")


def test_tree_ensemble_evaluates_as_scikit_learn_does():
    """The stored trees give scikit-learn's probabilities exactly, NaN routing included,
    and the model file does not grow with the training set."""
    from sklearn.ensemble import HistGradientBoostingClassifier
    from sklearn.pipeline import Pipeline
    from sklearn.preprocessing import StandardScaler

    from roi_detector.classifier import TreeEnsemble

    rng = np.random.default_rng(7)
    x = rng.normal(0, 3, (1000, 5)).astype(np.float32)
    x[rng.random(x.shape) < 0.05] = np.nan
    y = ((np.nan_to_num(x[:, 0]) + x[:, 1] ** 2 / 4 + rng.normal(0, 1, 1000)) > 1).astype(int)
    pipe = Pipeline([("scale", StandardScaler()),
                     ("gbt", HistGradientBoostingClassifier(
                         max_iter=30, class_weight="balanced", early_stopping=False,
                         random_state=0))]).fit(x, y)
    trees = TreeEnsemble.from_pipeline(pipe)
    xt = rng.normal(0, 3, (2000, 5)).astype(np.float32)
    xt[rng.random(xt.shape) < 0.05] = np.nan
    np.testing.assert_array_equal(trees.predict_proba(xt), pipe.predict_proba(xt)[:, 1])
    again = TreeEnsemble.from_arrays(trees.to_arrays("p_"), "p_")
    np.testing.assert_array_equal(again.predict_proba(xt), pipe.predict_proba(xt)[:, 1])
    broken = trees.to_arrays("p_")
    broken["p_left"] = broken["p_left"] + 10**6
    with pytest.raises(ValueError, match="out of range"):
        TreeEnsemble.from_arrays(broken, "p_")


def test_boosted_model_file_size_does_not_grow_with_training_set(tmp_path):
    """The stored trees are bounded by the tree count and leaves, not by the samples."""
    names = tuple(f"f{i}" for i in range(6))
    cfg = ClassifierConfig(kind="gradient_boosting")
    sizes = []
    for n in (4000, 40000):
        x, y = _toy_data(9, n=n)
        clf = BinaryClassifier("rock_orbital", names, cfg).fit(x, y)
        save_classifiers(tmp_path / f"m{n}.npz", {"rock_orbital": clf}, {})
        sizes.append((tmp_path / f"m{n}.npz").stat().st_size)
        loaded, _ = load_classifiers(tmp_path / f"m{n}.npz")
        np.testing.assert_array_equal(loaded["rock_orbital"].predict_proba(x[:50]),
                                      clf.predict_proba(x[:50]))
        # 200 trees of at most 31 leaves (61 nodes) whatever the training set's size.
        assert loaded["rock_orbital"]._trees.value.size <= 200 * 61
    # A training set of 40000 x 6 float16 alone is 480 kB.
    assert sizes[1] < 480_000 / 2


def test_first_format_model_files_still_load(tmp_path):
    """A file of format /1 (boosted trees stored as their training set) is re-fitted."""
    import json

    x, y = _toy_data(4, n=200)
    names = tuple(f"f{i}" for i in range(6))
    meta = {"format": "globloc-roi-classifiers/1", "provenance": {}, "library_versions": {},
            "classifiers": {"rock_orbital": {
                "feature_names": list(names), "n_samples": 200, "n_positive": int(y.sum()),
                "config": {"n_components": 8, "k": 5, "weights": "uniform",
                           "kind": "gradient_boosting"}}}}
    np.savez(tmp_path / "old.npz", rock_orbital__x=x.astype(np.float16),
             rock_orbital__y=y.astype(np.uint8),
             meta_json=np.frombuffer(json.dumps(meta).encode(), np.uint8))
    loaded, _ = load_classifiers(tmp_path / "old.npz")
    fresh = BinaryClassifier("rock_orbital", names,
                             ClassifierConfig(kind="gradient_boosting")).fit(x, y)
    np.testing.assert_array_equal(loaded["rock_orbital"].predict_proba(x),
                                  fresh.predict_proba(x))


def test_sun_direction_px_on_a_north_up_image():
    jac = np.array([[0.25, 0.0], [0.0, -0.25]])  # north-up, 0.25 m/px
    assert sun_direction_px(90.0, jac) == pytest.approx((1.0, 0.0), abs=1e-12)  # east: +col
    assert sun_direction_px(0.0, jac) == pytest.approx((0.0, -1.0), abs=1e-12)  # north: -row
    dc, dr = sun_direction_px(315.0, jac)
    assert dc == pytest.approx(-math.sqrt(0.5)) and dr == pytest.approx(-math.sqrt(0.5))


def _rock_with_shadow(sun_dir, radius=6.0, shadow_len=8.0, size=80):
    """A dark rock disc centred at (40, 40) whose cast shadow (a disc swept ``shadow_len``
    px down-sun) darkens the soil: the dark region's centroid lies down-sun of the rock."""
    yy, xx = np.mgrid[:size, :size].astype(np.float64)
    dark = np.zeros((size, size), bool)
    for t in np.linspace(0.0, shadow_len, 17):
        dark |= (xx - 40 + t * sun_dir[0]) ** 2 + (yy - 40 + t * sun_dir[1]) ** 2 <= radius**2
    return dark


@pytest.mark.parametrize("azimuth", [35.0, 200.0, 315.0])
def test_shadow_shift_moves_the_centroid_back_to_the_rock(azimuth):
    jac = np.array([[0.25, 0.0], [0.0, -0.25]])
    sun = sun_direction_px(azimuth, jac)
    mask = _rock_with_shadow(sun)
    rule = ClassRule(ROCK, 0.1, (ThresholdTerm("contrast", "below"),), max_extent_m=8)
    (reg,) = candidate_regions(mask, rule, 0.0625)
    raw = math.hypot(reg.col - 40, reg.row - 40)
    assert raw > 3.0  # the shadow pulls the centroid about half its length down-sun
    # kappa from the geometry of this image: shift = half the shadow, s = the disc's
    # spread across the sun axis (radius / 2), at 45 deg elevation (tan = 1).
    dc, dr = shadow_shift_px(reg.cov_px, sun, 45.0, kappa=4.0 / 3.0)
    fixed = math.hypot(reg.col + dc - 40, reg.row + dr - 40)
    assert fixed < 0.25 * raw
    # Towards the sun, not away from it; a wrong azimuth makes it worse.
    assert dc * sun[0] + dr * sun[1] > 0
    wc, wr = shadow_shift_px(reg.cov_px, (-sun[0], -sun[1]), 45.0, kappa=4.0 / 3.0)
    assert math.hypot(reg.col + wc - 40, reg.row + wr - 40) > raw
    # A lower sun means longer shadows: a larger shift for the same region.
    lc, lr = shadow_shift_px(reg.cov_px, sun, 20.0, kappa=4.0 / 3.0)
    assert math.hypot(lc, lr) > math.hypot(dc, dr)
    for bad in (0.0, -5.0, 91.0):
        with pytest.raises(ValueError, match="elevation"):
            shadow_shift_px(reg.cov_px, sun, bad, kappa=1.0)


def test_sun_features_see_the_lit_side():
    # A dark region (shaded face + shadow) with a bright lit face on its +col side.
    yy, xx = np.mgrid[:60, :60].astype(np.float64)
    g = np.full((60, 60), 128, np.uint8)
    dark = (xx - 28) ** 2 + (yy - 30) ** 2 <= 25
    g[dark] = 60
    g[((xx - 34) ** 2 + (yy - 30) ** 2 <= 9) & ~dark] = 210
    rule = ClassRule(ROCK, 0.1, (ThresholdTerm("contrast", "below"),), max_extent_m=8)
    regions = candidate_regions(dark, rule, 0.0625)
    rgb = np.repeat(g[..., None], 3, axis=2).astype(np.float32) / 255.0
    ent = np.zeros(g.shape, np.float32)
    names = feature_names(SUN_GROUPS)
    assert names[: len(feature_names())] == feature_names()
    f_lit = candidate_features(regions, rgb, g, ent, SUN_GROUPS, (1.0, 0.0))[0]
    f_wrong = candidate_features(regions, rgb, g, ent, SUN_GROUPS, (-1.0, 0.0))[0]
    assert f_lit.shape == (len(names),) and np.isfinite(f_lit).all()
    i = names.index("sun_ring_contrast")
    assert f_lit[i] > 0.03 > -0.03 > f_wrong[i]
    j = names.index("sun_lit_max")
    assert f_lit[j] > f_wrong[j]
    with pytest.raises(ValueError, match="sun direction"):
        candidate_features(regions, rgb, g, ent, SUN_GROUPS)
