"""bench/roi_false_nodes.py's pure part: what a false rock node stands on."""

from __future__ import annotations

import numpy as np
import pytest


@pytest.fixture(scope="module")
def false_nodes(bench_script):
    return bench_script("roi_false_nodes")


def test_categories_in_order(false_nodes):
    cat = false_nodes.categorise
    rocks = np.array([[10.0, 0.0]])
    clutter = np.array([[0.3, 0.0], [8.5, 0.0], [20.0, 0.0]])
    heights = np.array([0.4, 0.1, 0.1])
    node = np.zeros(2)
    assert cat(node, True, rocks, clutter, heights) == "class"
    assert cat(node, False, rocks, clutter, heights) == "clutter rock"
    # The same clutter rock under the height threshold: nothing tall here.
    assert cat(node, False, rocks, clutter, np.array([0.2, 0.1, 0.1])) == "low clutter"
    # A catalogued rock 1.6 m off wins over low clutter beside the node.
    assert cat(np.array([8.4, 0.0]), False, rocks, clutter, heights) == \
        "catalogued rock off-centre"
    assert cat(np.array([40.0, 0.0]), False, rocks, clutter, heights) == "none"
    assert cat(node, False, rocks, np.zeros((0, 2)), np.zeros(0)) == "none"


def test_markdown_counts_the_categories(false_nodes):
    row = {"bag": "b", "node": 3, "height_m": 0.3, "area_m2": 0.9, "score": 0.95,
           "nearest_catalogued_m": 40.0, "nearest_clutter_m": 0.1, "nearest_clutter_h_m": 0.4}
    rows = [{**row, "category": "clutter rock"}, {**row, "category": "none"},
            {**row, "category": "clutter rock"}]
    md = false_nodes.markdown("x", "python bench/roi_false_nodes.py ...", rows)
    assert "3 false rock nodes: clutter rock 2, none 1" in md
    assert "| b | 3 | clutter rock | 0.30 | 0.90 | 0.95 | 40.0 | 0.10 (0.40) |" in md
