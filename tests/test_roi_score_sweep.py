"""bench/roi_score_sweep.py's pure parts: which rock nodes a threshold keeps, the table."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def sweep(bench_script):
    return bench_script("roi_score_sweep")


def _feature(cls: str, score: float | None) -> dict:
    props = {"class": cls} if score is None else {"class": cls, "score": score}
    return {"type": "Feature", "properties": props}


def test_only_rocks_under_the_threshold_are_dropped(sweep):
    ln = {"type": "FeatureCollection", "metadata": {"frame": "odom"},
          "features": [_feature("rock", 0.4), _feature("rock", 0.7),
                       _feature("outcrop", 0.1), _feature("rock", None)]}
    kept = sweep.keep_rocks_over(ln, 0.6)
    assert [(f["properties"]["class"], f["properties"].get("score"))
            for f in kept["features"]] == [("rock", 0.7), ("outcrop", 0.1), ("rock", None)]
    assert kept["metadata"] == ln["metadata"] and len(ln["features"]) == 4


def test_ln_specs_are_checked(sweep):
    assert sweep.parse_ln("low=bags/quick=a/ln.geojson")[:2] == ("low", "bags/quick")
    for bad in ("low=bags/quick", "=bags/quick=ln.geojson"):
        with pytest.raises(ValueError, match="VARIANT=BAG_DIR=LN"):
            sweep.parse_ln(bad)


def test_markdown_gives_recall_and_precision(sweep):
    rows = [{"variant": "base", "threshold": 0.5, "bags": 2, "found": 9, "wanted": 12,
             "true": 10, "nodes": 12}]
    md = sweep.markdown("x", "python bench/roi_score_sweep.py ...", rows)
    assert "| base | 0.5 | 2 | 9/12 | 75.0% | 10/12 | 83.3% |" in md
