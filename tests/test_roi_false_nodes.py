"""bench/roi_false_nodes.py's pure part: what a false rock node stands on."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def false_nodes(bench_script):
    return bench_script("roi_false_nodes")


def test_categories_in_order(false_nodes):
    cat = false_nodes.categorise
    clutter_m = np.array([0.3, 8.5, 20.0])  # the node's distance to each clutter rock
    heights = np.array([0.4, 0.1, 0.1])
    assert cat(True, 10.0, clutter_m, heights) == "class"
    assert cat(False, 10.0, clutter_m, heights) == "clutter rock"
    # The same clutter rock under the height threshold: nothing tall here.
    assert cat(False, 10.0, clutter_m, np.array([0.2, 0.1, 0.1])) == "low clutter"
    # A catalogued rock 1.6 m off wins over low clutter beside the node.
    assert cat(False, 1.6, np.array([0.1, 8.5]), np.array([0.1, 0.1])) == \
        "catalogued rock off-centre"
    assert cat(False, 40.0, np.array([31.6, 40.0]), heights[:2]) == "none"
    assert cat(False, np.inf, np.zeros(0), np.zeros(0)) == "none"


def test_markdown_counts_the_categories(false_nodes):
    row = {"bag": "b", "node": 3, "height_m": 0.3, "area_m2": 0.9, "score": 0.95,
           "nearest_catalogued_m": 40.0, "nearest_clutter_m": 0.1, "nearest_clutter_h_m": 0.4}
    rows = [{**row, "category": "clutter rock"}, {**row, "category": "none"},
            {**row, "category": "clutter rock"}]
    md = false_nodes.markdown("x", "python bench/roi_false_nodes.py ...", rows)
    assert "3 false rock nodes: clutter rock 2, none 1" in md
    assert "| b | 3 | clutter rock | 0.30 | 0.90 | 0.95 | 40.0 | 0.10 (0.40) |" in md
