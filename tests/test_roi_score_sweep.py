"""bench/roi_score_sweep.py's pure parts: which rock nodes a threshold keeps, the table."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def sweep(bench_script):
    return bench_script("roi_score_sweep")


def test_only_rocks_under_the_threshold_are_dropped(sweep):
    from roi_network.records import OUTCROP, ROCK, ROI_DTYPE

    ln = np.zeros(4, dtype=ROI_DTYPE)
    ln["id"] = [1, 2, 3, 4]
    ln["label"] = [ROCK, ROCK, OUTCROP, ROCK]
    ln["score"] = [0.4, 0.7, 0.1, np.nan]
    kept = sweep.keep_rocks_over(ln, 0.6)
    assert kept["id"].tolist() == [2, 3, 4]
    assert len(ln) == 4
    assert sweep.keep_rocks_over(ln, 0.3)["id"].tolist() == [1, 2, 3, 4]


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
