"""bench/ellipse_replay.py: the bag's GN inside a landing-ellipse GN tiled from other GNs,
and a run replayed against both."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest


@pytest.fixture(scope="module")
def ellipse(bench_script):
    return bench_script("ellipse_replay")


def _tile_bag(root: Path, seed: int) -> Path:
    from darces_matcher.gn_generator import generate_gn
    from roi_network.geojson import write_geojson

    bag = root / f"tile_{seed}"
    bag.mkdir(parents=True)
    write_geojson(generate_gn(seed=seed), bag / "gn.geojson")
    return bag


def test_ellipse_gn_keeps_the_bag_gn_and_tiles_the_rest(ellipse) -> None:
    from darces_matcher.gn_generator import generate_gn
    from roi_network.records import xy

    own = generate_gn(seed=11)
    tiles = [generate_gn(seed=s).records for s in (12, 13)]
    gn, info = ellipse.ellipse_gn(own, tiles, 3, seed=4)
    corner, side = ellipse._square(own.records)
    assert info["area_km2"] == pytest.approx((3 * side) ** 2 / 1e6)
    assert info["rois"] == len(gn) > 3 * len(own)
    # The bag's own ROIs are there, unmoved, and its tile holds nothing else.
    pts, own_pts = xy(gn.records), xy(own.records)
    assert np.all(pts[: len(own)] == own_pts)
    inside = np.all((pts >= corner) & (pts <= corner + side), axis=1)
    assert inside.sum() == len(own)
    # The grid covers n x n tiles around it, and ids are unique.
    home = np.array(info["home_tile"])
    lo = corner - home * side
    assert np.all(pts >= lo - 1e-6) and np.all(pts <= lo + 3 * side + 1e-6)
    assert len(np.unique(gn.records["id"])) == len(gn)
    # Same seed, same GN; another seed, another.
    again, _ = ellipse.ellipse_gn(own, tiles, 3, seed=4)
    other, _ = ellipse.ellipse_gn(own, tiles, 3, seed=5)
    assert np.array_equal(again.records, gn.records)
    assert len(other) != len(gn) or not np.array_equal(other.records, gn.records)


def test_dihedral_maps_the_square_onto_itself(ellipse) -> None:
    from darces_matcher.gn_generator import generate_gn
    from roi_network.records import xy

    rec = generate_gn(seed=12).records
    side = float(xy(rec).max()) + 1.0
    d = np.linalg.norm(xy(rec)[:, None] - xy(rec)[None], axis=2)
    for seed in range(8):
        out = ellipse._dihedral(rec, side, np.random.default_rng(seed))
        p = xy(out)
        assert np.all((p >= -1e-9) & (p <= side + 1e-9))
        # Distances kept (a rigid motion or a reflection), footprint angles in range.
        assert np.allclose(np.linalg.norm(p[:, None] - p[None], axis=2), d)
        assert np.all(np.abs(out["angle_rad"]) <= np.pi / 2 + 1e-6)


def test_replay_localizes_inside_the_ellipse(tmp_path: Path, ellipse, replay_run) -> None:
    run, bag = replay_run(tmp_path)
    tiles = [_tile_bag(tmp_path, s) for s in (12, 13)]
    out = tmp_path / "results"
    assert ellipse.main([str(run), str(bag), "--tile-bags", *map(str, tiles), "--tiles", "3",
                         "--seeds", "1", "--name", "t", "--out", str(out)]) == 0
    rows = json.loads((out / "ellipse_t.json").read_text())["rows"]
    assert [r["gn"] for r in rows] == ["own", "ellipse_3x3"]
    assert rows[1]["rois"] > 5 * rows[0]["rois"]
    for r in rows:
        assert r["first_fix_after_m"] is not None and r["poses_over_10m"] == 0
        assert r["final_error_m"] < 1.0
    assert "| ellipse_3x3 | 1 |" in (out / "ellipse_t.md").read_text()


def test_ellipse_bad_input(tmp_path: Path, ellipse, replay_run) -> None:
    run, bag = replay_run(tmp_path)
    tile = _tile_bag(tmp_path, 12)
    out = ["--out", str(tmp_path / "results")]
    with pytest.raises(SystemExit):  # the bag's own GN as a tile
        ellipse.main([str(run), str(bag), "--tile-bags", str(bag), *out])
    with pytest.raises(SystemExit):  # a tile bag without a GN
        ellipse.main([str(run), str(bag), "--tile-bags", str(tmp_path / "nosuch"), *out])
    with pytest.raises(SystemExit):  # no tile per side
        ellipse.main([str(run), str(bag), "--tile-bags", str(tile), "--tiles", "0", *out])
    assert not (tmp_path / "results").exists()
