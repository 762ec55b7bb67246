"""bench/rock_rover_bench.py's pure parts: what the classifiers keep of a held-out bag."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def bench(bench_script):
    return bench_script("rock_rover_bench")


class _Fixed:
    """A classifier whose scores are given per sample."""

    def __init__(self, scores) -> None:
        self.scores = np.asarray(scores, float)

    def predict_proba(self, x):
        assert len(x) == len(self.scores)
        return self.scores


def test_judge_counts_what_each_classifier_keeps_at_the_pipelines_thresholds(bench):
    held_out = {
        "map_x": np.zeros((4, 3)), "map_y": np.array([1, 1, 0, 0], np.uint8),
        "x": np.zeros((5, 3)), "y": np.array([1, 1, 0, 0, 1], np.uint8),
        # The last track fails the geometric tests: the classifier never decides it.
        "decidable": np.array([True, True, True, True, False]),
        "counted_j": np.array([7, 7, -1, -1, 9]), "n_counted": 3,
    }
    # Map: one rock refused, one false region kept; a score at the threshold is refused.
    rocks = _Fixed([0.9, 0.5, 0.8, 0.1])
    far = _Fixed([0.9, 0.7, 0.6, 0.2, 0.99])
    row = bench.judge(far, rocks, held_out)
    assert (row["map_true_kept"], row["map_true"]) == (1, 2)
    assert (row["map_false_kept"], row["map_false"]) == (1, 2)
    assert (row["far_true_kept"], row["far_true"]) == (2, 2)
    assert (row["far_false_kept"], row["far_false"]) == (1, 2)
    # Two kept true tracks on the same rock find one counted rock; the undecided one none.
    assert row["far_counted_found"] == 1 and row["counted_rocks"] == 3


def test_a_held_out_bag_in_the_training_set_is_refused(bench, tmp_path):
    with pytest.raises(SystemExit):
        bench.main(["--train", "bags/a", "bags/b", "--eval", "bags/b",
                    "--cache", str(tmp_path)])
