"""bench/outcrop_rover_bench.py's pure parts: each drive scored by a rover fitted on the
others, and the features' separation."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def bench(bench_script):
    return bench_script("outcrop_rover_bench")


def _drive(rng, n_out, n_other, nf):
    y = np.r_[np.ones(n_out), np.zeros(n_other)].astype(np.uint8)
    return 0.3 * rng.normal(size=(len(y), nf)) + 3.0 * y[:, None], y


def test_each_drive_is_scored_by_a_rover_that_never_saw_it(bench):
    from roi_detector.elevation_map import MAP_OUTCROP_FEATURES

    rng = np.random.default_rng(2)
    nf = len(MAP_OUTCROP_FEATURES)
    drives = [_drive(rng, 20, 30, nf), _drive(rng, 25, 25, nf), _drive(rng, 0, 0, nf)]
    xs, ys = [d[0] for d in drives], [d[1] for d in drives]
    scores = bench.left_one_out(xs, ys, "gradient_boosting", 5)
    assert [len(s) for s in scores] == [50, 50, 0]
    # Separable drives: each held-out drive's outcrops score above its other regions.
    for s, y in zip(scores[:2], ys[:2], strict=True):
        assert s[y == 1].min() > 0.5 > s[y == 0].max()
    # A drive whose others hold no outcrop cannot be scored: NaN, not a guess.
    ys_one = [np.zeros_like(ys[0]), ys[1]]
    assert np.isnan(bench.left_one_out(xs[:2], ys_one, "knn", 3)[1]).all()


def test_feature_auc_says_which_way_and_how_well_each_feature_separates(bench):
    x = np.array([[1.0, 0.0, 5.0], [2.0, 1.0, 5.0], [3.0, 0.0, 5.0], [4.0, 1.0, 5.0]])
    y = np.array([0, 0, 1, 1], np.uint8)
    assert bench.feature_auc(x, y) == pytest.approx([1.0, 0.5, 0.5])
    assert np.isnan(bench.feature_auc(x, np.zeros(4, np.uint8))).all()
