"""bench/roi_diag.py's pure parts: the furthest stage of the regions near a rock."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def diag(bench_script):
    return bench_script("roi_diag")


def test_furthest_stage_and_its_last_measurement(diag):
    assert diag.furthest([]) == ("none", {})
    verdicts = [("small", {"cells": 3}), ("low", {"height_m": 0.2}),
                ("ring_unseen", {}), ("low", {"height_m": 0.22})]
    assert diag.furthest(verdicts) == ("low", {"height_m": 0.22})
    assert diag.furthest([*verdicts, ("rock", {"area_m2": 1.0})])[0] == "rock"


def test_markdown_counts_the_stages(diag):
    rows = [{"id": 3, "area_m2": 1.0, "height_m": 0.5, "route_distance_m": 4.0,
             "views": 20, "in_ln": True, "stage": "rock", "measured": {"height_m": 0.4}},
            {"id": 7, "area_m2": 0.7, "height_m": 0.3, "route_distance_m": 12.0,
             "views": 5, "in_ln": False, "stage": "none", "measured": {}}]
    md = diag.markdown("bags/x", rows)
    assert "In the LN: 1 of 2; furthest stage: none 1, rock 1" in md
    assert md.index("| 3 |") < md.index("| 7 |")  # nearest the route first


def test_far_verdict_takes_the_furthest_track_and_says_what_it_measured(diag):
    import numpy as np

    from roi_detector.far_rocks import FarRock, FarRockConfig

    cfg = FarRockConfig()

    def track(passed: bool, residual_px: float, score: float = float("nan")) -> FarRock:
        return FarRock(1, np.zeros(2), 0.0, np.eye(2), 0.6, 0.3, 0.28, 8, 3.0,
                       residual_px, 15.0, False, passed, None, score)

    assert diag.far_verdict([], cfg, np.zeros(0)) == ("none", {})
    sloppy = track(False, cfg.max_residual_px + 1.0)
    refused = track(False, 0.5, score=0.2)
    stage, measured = diag.far_verdict([sloppy, refused], cfg, np.array([0.3, 1.2]))
    assert stage == "refused" and measured["off_m"] == 1.2 and measured["score"] == 0.2
    assert diag.far_verdict([sloppy], cfg, np.array([0.3]))[0] == "geometry"
    kept = track(True, 0.5, score=0.9)
    assert diag.far_verdict([refused, kept], cfg, np.array([0.1, 0.9]))[0] == "kept"
