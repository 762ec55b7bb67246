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


def _outcrop_map(sat_inside: float, observed_cols: int | None = None):
    """An 8 m elevation map, flat and observed, reddish soil with a grey 3 x 2 m slab
    at (4, 4) (colour samples only in the first ``observed_cols`` columns, if given)."""
    import numpy as np

    from roi_detector.elevation_map import ElevationMap, ElevationMapConfig

    emap = ElevationMap(ElevationMapConfig(window_m=8.0, outcrop_colour_sigma_m=0.2))
    emap.origin = np.zeros(2)
    n = emap.n
    emap.w[:] = emap.npairs[:] = 10.0
    emap.wz[:] = emap.wzz[:] = 0.0
    x = (np.arange(n) + 0.5) * 0.1
    xx, yy = np.meshgrid(x, x, indexing="ij")
    slab = ((xx - 4) / 1.5) ** 2 + ((yy - 4) / 1.0) ** 2 <= 1
    emap.nb[:] = 1.0
    if observed_cols is not None:
        emap.nb[:, observed_cols:] = 0.0
    emap.bs[:] = np.where(slab, sat_inside, 1.2) * emap.nb
    emap.bv[:] = 1.0 * emap.nb
    return emap


class _IdentityTruth:
    @staticmethod
    def odom_to_map(p):
        return p


def _slab_record():
    import numpy as np

    from roi_network.records import OUTCROP, empty_records

    r = empty_records(1)
    r["x"], r["y"], r["label"] = 4.0, 4.0, OUTCROP
    r["major_m"], r["minor_m"], r["angle_rad"], r["area_m2"] = 3.0, 2.0, 0.0, np.pi * 1.5
    return r


def test_footprint_stats_say_what_the_map_holds_in_a_truth_outcrop(diag):
    (grey,) = diag.footprint_stats(_outcrop_map(0.3), _IdentityTruth, _slab_record())
    assert grey["observed"] == 1.0 and grey["colour_ok"] > 0.8 and grey["high"] == 0.0
    assert grey["sat"] < 0.45 and grey["ring_sat"] > 1.1
    (soil,) = diag.footprint_stats(_outcrop_map(1.0), _IdentityTruth, _slab_record())
    assert soil["colour_ok"] == 0.0 and soil["sat"] > 0.9
    # Colour samples only west of x = 4 m: half the slab observed.
    (half,) = diag.footprint_stats(_outcrop_map(0.3, observed_cols=40), _IdentityTruth,
                                   _slab_record())
    assert 0.4 < half["observed"] < 0.6
    far = _slab_record()
    far["x"] = 40.0
    assert diag.footprint_stats(_outcrop_map(0.3), _IdentityTruth, far) == [None]


def test_markdown_outcrops_counts_the_stages(diag):
    rows = [{"id": 5, "area_m2": 9.0, "major_m": 4.0, "minor_m": 3.0,
             "route_distance_m": 6.0, "views": 11, "in_ln": False, "stage": "colour",
             "footprint": {"observed": 0.3, "sat": 0.9}, "roi": {}},
            {"id": 2, "area_m2": 12.0, "major_m": 5.0, "minor_m": 3.0,
             "route_distance_m": 3.0, "views": 30, "in_ln": True, "stage": "reported",
             "footprint": {"observed": 1.0}, "roi": {"score": 1.0}}]
    md = diag.markdown_outcrops("bags/x", rows)
    assert "In the LN: 1 of 2; stage: colour 1, reported 1" in md
    assert md.index("| 2 |") < md.index("| 5 |")


def test_the_outcrop_rule_and_model_options_go_with_outcrops(diag, capsys):
    with pytest.raises(SystemExit):
        diag.main(["bags/x", "--outcrop-rule", "soil_relative"])
    assert "go with --outcrops" in capsys.readouterr().err


def test_a_mapper_with_another_outcrop_rule_refuses_the_committed_model(diag):
    """The committed Outcrop Rover was trained on the default rule's candidates: a map
    with another rule refuses it, naming the rule (no diagnosis on the wrong model)."""
    with pytest.raises(ValueError, match="another outcrop rule"):
        diag.default_mapper("soil_relative")
    assert diag.default_mapper().cfg.elevation_map.outcrop_soil_ratio == 0.0
