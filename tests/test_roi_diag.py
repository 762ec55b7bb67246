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
