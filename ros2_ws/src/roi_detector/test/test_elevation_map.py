"""The drive's elevation map and the ROIs found in it (pure library, synthetic scenes)."""

import functools
from dataclasses import replace

import numpy as np
import pytest

from roi_detector.elevation_map import (
    MAP_OUTCROP_FEATURES,
    MAP_ROCK_FEATURES,
    ElevationMap,
    ElevationMapConfig,
    ground_surface,
)
from roi_network.records import OUTCROP, ROCK

CAMERA = np.array([0.4, 0.1, 1.54])
FXB = 772.5 * 0.2
RNG = np.random.default_rng(3)


def _terrain(x, y, swell=True):
    """A gentle slope, a smooth swell 0.3 m high and 5 m wide at (10, -5)."""
    z = 0.03 * x
    if swell:
        z = z + 0.3 * np.exp(-((x - 10) ** 2 + (y + 5) ** 2) / (2 * 1.25**2))
    return z


def _scene(rock=True, swell=True, spacing=0.05, noise=0.01, rock_h=0.5):
    """Points of the ground in front of the rover, and of a 1 x 1.2 m rock ``rock_h`` tall
    at (9, 2) (top and the flank facing the rover; its far side hidden)."""
    x, y = np.meshgrid(np.arange(2.0, 16.0, spacing), np.arange(-8.0, 8.0, spacing))
    x, y = x.ravel(), y.ravel()
    z = _terrain(x, y, swell)
    if rock:
        inside = (np.abs(x - 9.0) < 0.5) & (np.abs(y - 2.0) < 0.6)
        behind = (x > 9.5) & (x < 10.3) & (np.abs(y - 2.0) < 0.6)  # occluded by the rock
        z = np.where(inside, _terrain(9.0, 2.0, swell) + rock_h, z)
        keep = ~behind
        x, y, z = x[keep], y[keep], z[keep]
        fy, fz = np.meshgrid(np.arange(1.4, 2.6, spacing), np.arange(0.0, rock_h, spacing))
        x = np.r_[x, np.full(fy.size, 8.5)]
        y = np.r_[y, fy.ravel()]
        z = np.r_[z, _terrain(8.5, 2.0, swell) + fz.ravel()]
    pts = np.column_stack([x, y, z + RNG.normal(0, noise, len(x))])
    return pts[:, None, :]


def _drive(emap, pts, n=8, appearance=None):
    for _ in range(n):
        emap.integrate(pts, appearance, np.eye(3), np.zeros(3), CAMERA, FXB)
        if emap.due():
            emap.detect(0.0, np.eye(2) * 0.01)
    emap.detect(0.0, np.eye(2) * 0.01)


def test_rock_found_swell_and_slope_ignored():
    emap = ElevationMap(ElevationMapConfig(detect_every=2))
    _drive(emap, _scene())
    rec = emap.to_records()
    rocks = rec[rec["label"] == ROCK]
    assert len(rocks) == 1, rec
    r = rocks[0]
    # The hull of the seen top and flank spans the rock: centre within 0.3 m, area and
    # height of a 1 x 1.2 x 0.5 m block.
    assert np.hypot(r["x"] - 9.0, r["y"] - 2.0) < 0.3
    assert 0.8 < r["area_m2"] < 1.8 and 0.4 < r["height_m"] < 0.6
    assert r["n_obs"] >= 3 and r["cov_xx"] > 0.01 and r["cov_yy"] > 0.01
    assert not np.any(rec["label"] == OUTCROP)


def test_no_rock_on_bare_terrain():
    emap = ElevationMap(ElevationMapConfig(detect_every=2))
    _drive(emap, _scene(rock=False))
    assert len(emap.to_records()) == 0


def test_a_mismatch_of_one_view_is_no_rock():
    """A patch 0.6 m too high in one view of six (a stereo mismatch) is no rock."""
    emap = ElevationMap(ElevationMapConfig(detect_every=100))
    clean = _scene(rock=False, swell=False)
    bad = clean.copy()
    patch = (np.abs(bad[:, 0, 0] - 7.0) < 0.6) & (np.abs(bad[:, 0, 1]) < 0.6)
    bad[patch, 0, 2] += 0.6
    for pts in (bad, clean, clean, clean, clean, clean):
        emap.integrate(pts, None, np.eye(3), np.zeros(3), CAMERA, FXB)
    emap.detect(0.0)
    assert len(emap.rois) == 0


def _slab(stripes=False, scatter=0.0, seed=5):
    """Points and colours of a 3 x 3 m grey slab 0.1 m thick at (10, -3), saturation 0.4
    of the soil's. ``stripes``: seen in sparse stripes (every other 0.1 m band of cells
    gets no point, as from afar); ``scatter``: each point's saturation scattered by this
    much (1 sigma)."""
    rng = np.random.default_rng(seed)
    pts = _scene(rock=False, swell=False)
    x, y = pts[:, 0, 0], pts[:, 0, 1]
    slab = (np.abs(x - 10.0) < 1.5) & (np.abs(y + 3.0) < 1.5)
    pts[slab, 0, 2] += 0.1
    app = np.ones((len(pts), 1, 2), np.float32)
    app[slab, 0, 0] = 0.4 + rng.normal(0.0, scatter, slab.sum())
    keep = ~(slab & (np.floor(x / 0.1).astype(int) % 2 == 1)) if stripes else slice(None)
    return pts[keep], app[keep]


def _the_slab(emap, pts, app):
    """Drive past the slab; its one outcrop record."""
    _drive(emap, pts, appearance=app)
    rec = emap.to_records()
    assert len(rec) == 1 and rec["label"][0] == OUTCROP
    assert np.hypot(rec["x"][0] - 10.0, rec["y"][0] + 3.0) < 0.3
    return rec[0]


def test_outcrop_from_pale_cells():
    """A 3 x 3 m slab 0.1 m thick whose colour is far less saturated than the soil."""
    pts, app = _slab()
    # On the averaged colour, which crosses the threshold about 0.2 m inside the slab's
    # edge: 2.6 m of its 3 m.
    rec = _the_slab(ElevationMap(ElevationMapConfig(detect_every=2)), pts, app)
    assert 6.0 < rec["area_m2"] < 11.0
    # The same slab with the soil's colour: nothing (the paper's 5.5 m^2 is the size).
    emap = ElevationMap(ElevationMapConfig(detect_every=2))
    _drive(emap, pts, appearance=np.ones_like(app))
    assert len(emap.to_records()) == 0


def test_outcrop_seen_in_sparse_stripes_is_found_on_its_smoothed_colour():
    """The slab seen in sparse stripes, its points' saturation scattered across the
    threshold (0.4 +- 0.25)."""
    pts, app = _slab(stripes=True, scatter=0.25)
    rec = _the_slab(ElevationMap(ElevationMapConfig(detect_every=2)), pts, app)
    assert 5.5 < rec["area_m2"] < 11.0
    # Its observations are the 8 pairs that saw it, not a median over its unseen stripes.
    assert rec["n_obs"] == 8


def test_an_outcrop_keeps_its_largest_footprint_a_rock_its_latest():
    from roi_detector.elevation_map import MapRoi

    emap = ElevationMap(ElevationMapConfig())
    def roi(label, x, area):
        return MapRoi(0, label, np.array([x, 0.0]), 0.0, area, 0.2, 6.0, 3.0, 0.0)
    emap._associate(roi(OUTCROP, 0.0, 30.0))
    emap._associate(roi(OUTCROP, 2.0, 8.0))  # the slab cut at the examined cells' border
    assert len(emap.rois) == 1 and emap.rois[0].rounds == 2
    assert emap.rois[0].area_m2 == 30.0 and emap.rois[0].xy[0] == 0.0
    emap._associate(roi(OUTCROP, 0.5, 35.0))
    assert emap.rois[0].area_m2 == 35.0 and emap.rois[0].rounds == 3
    emap._associate(roi(ROCK, 20.0, 1.5))
    emap._associate(roi(ROCK, 20.3, 1.0))
    assert emap.rois[1].area_m2 == 1.0 and emap.rois[1].rounds == 2


def test_window_follows_the_rover_and_keeps_odom_positions(monkeypatch):
    from roi_detector import elevation_map
    from roi_detector.elevation_map import CELL_M

    monkeypatch.setattr(elevation_map, "WINDOW_M", 20.0)
    emap = ElevationMap(ElevationMapConfig(detect_every=100))
    pts = _scene(swell=False)
    for _ in range(3):  # a cell is observed once three pairs saw it
        emap.integrate(pts, None, np.eye(3), np.zeros(3), CAMERA, FXB)
    z0, _ = emap.heights()
    at = np.floor((np.array([9.0, 2.0]) - emap.origin) / CELL_M).astype(int)
    top = z0[at[0], at[1]]
    assert np.isfinite(top)
    # The rover moves 6 m: the window shifts, the rock's cell keeps its height.
    emap.integrate(pts[:0], None, np.eye(3), np.array([6.0, 0.0, 0.0]), CAMERA, FXB)
    z1, _ = emap.heights()
    at1 = np.floor((np.array([9.0, 2.0]) - emap.origin) / CELL_M).astype(int)
    assert z1[at1[0], at1[1]] == top


def test_ground_surface_under_a_block():
    z = np.zeros((80, 80))
    z[30:40, 30:40] = 0.5
    g = ground_surface(z, np.ones_like(z, bool), window_cells=32)
    assert np.abs(g).max() < 0.05


def test_depth_edges_are_dropped_and_smooth_ground_kept():
    """A rock (disparity 11.4 px, 8 m) in front of flat ground, whose disparity grows
    linearly with the row below the horizon (20 rows above the image here): 6 px at the
    top, 42 px at the bottom. The pixels along the rock's outline, where block matching
    mixes the two, are dropped; the ground and the rock's inside are kept."""
    from roi_detector.stereo import mask_depth_edges

    rows = (0.3 * (np.arange(120) + 20)).astype(np.float32)
    disp = np.repeat(rows[:, None], 160, axis=1)
    disp[40:60, 70:90] = 11.4
    disp[0, :5] = np.nan
    out = mask_depth_edges(disp, 3, 0.15)
    edge = np.zeros_like(disp, bool)
    edge[39:61, 69:91] = True
    edge[41:59, 71:89] = False
    assert np.isnan(out[edge]).mean() > 0.7
    assert np.isfinite(out[42:58, 72:88]).all()
    ground = np.ones_like(disp, bool)
    ground[37:63, 67:93] = False
    ground[0, :5] = False
    assert np.isfinite(out[ground]).all()
    assert mask_depth_edges(disp, 3, 0.0) is disp


def test_a_far_view_misplaced_along_its_ray_weighs_less(monkeypatch):
    """A cell seen from 4 m at ground height and from 18 m at 0.3 m (a rock face whose
    points the far view's range error of ~1 m put in this cell): the horizontal part of the
    range error, times the terrain gradient, makes the far view count for little."""
    from roi_detector import elevation_map

    monkeypatch.setattr(elevation_map, "MIN_PAIRS", 1)
    monkeypatch.setattr(elevation_map, "MIN_CELL_WEIGHT", 1.0)

    def cell_height(gradient):
        monkeypatch.setattr(elevation_map, "PLACEMENT_GRADIENT", gradient)
        emap = ElevationMap(ElevationMapConfig())
        near = np.tile([4.02, 0.02, 0.0], (20, 1))[:, None, :]  # base_link at (0, 0)
        far = np.tile([18.02, 0.02, 0.3], (20, 1))[:, None, :]  # base_link at (-14, 0)
        emap.integrate(near, None, np.eye(3), np.zeros(3), CAMERA, FXB)
        emap.integrate(far, None, np.eye(3), np.array([-14.0, 0.0, 0.0]), CAMERA, FXB)
        z, seen = emap.heights()
        ij = np.floor((np.array([4.02, 0.02]) - emap.origin) / elevation_map.CELL_M).astype(int)
        assert seen[ij[0], ij[1]]
        return z[ij[0], ij[1]]

    assert cell_height(0.0) > 0.1  # both views capped at one pair's weight: the mean
    assert cell_height(0.5) < 0.03


def _dark_where_raised(pts, swell=True, value=0.35):
    """Appearance (relative saturation, value) of the points: soil 1, 1; the points
    standing above the terrain at ``value``."""
    app = np.ones((len(pts), 1, 2), np.float32)
    raised = pts[:, 0, 2] - _terrain(pts[:, 0, 0], pts[:, 0, 1], swell) > 0.05
    app[raised, 0, 1] = value
    return app


def _found(pts, value=0.35, **cfg):
    """The map ROIs of a drive past ``pts``, the raised points at brightness ``value``."""
    emap = ElevationMap(ElevationMapConfig(detect_every=2, **cfg))
    _drive(emap, pts, appearance=_dark_where_raised(pts, value=value))
    return emap.to_records()


def test_a_rock_is_darker_than_the_soil():
    rec = _found(_scene())
    assert len(rec) == 1 and rec["label"][0] == ROCK
    assert np.hypot(rec["x"][0] - 9.0, rec["y"][0] - 2.0) < 0.3
    # A block 0.35 m tall with the soil's brightness is a bump of soil (below the pale
    # height, ``ROCK_PALE_SEED_HEIGHT_M``).
    assert len(_found(_scene(rock_h=0.35), 1.0)) == 0


def _ridge(length, width=1.0, height=0.8):
    """Ground points with a dark ridge ``length`` m long (across the view, along y),
    ``width`` m wide and ``height`` m tall, centred at (9, 0), its far side hidden."""
    x, y = np.meshgrid(np.arange(2.0, 16.0, 0.05), np.arange(-8.0, 8.0, 0.05))
    x, y = x.ravel(), y.ravel()
    z = _terrain(x, y, swell=False)
    along = np.abs(y) < 0.5 * length
    inside = (np.abs(x - 9.0) < 0.5 * width) & along
    behind = (x >= 9.0 + 0.5 * width) & (x < 9.8 + 0.5 * width) & along
    z = np.where(inside, z + height, z)
    keep = ~behind
    pts = np.column_stack([x[keep], y[keep], z[keep] + RNG.normal(0, 0.01, keep.sum())])
    return pts[:, None, :]


def test_a_ridge_longer_than_the_ground_window_is_no_rock():
    """A dark ridge 0.8 m tall, 1 m wide: 2.5 m long it is a rock; 6 m long (area 6 m^2,
    under the largest rock's, and steep enough for the relief test) it is terrain,
    longer than 1.5 ground windows (4.8 m)."""
    short = _found(_ridge(2.5))
    assert len(short) == 1 and short["label"][0] == ROCK, short
    assert short["major_m"][0] < 4.8
    assert len(_found(_ridge(6.0))) == 0


def test_a_pale_rock_stands_on_its_height_alone():
    """A block as bright as the soil (or brighter: a sunlit pale rock) is a rock when its
    cells stand ROCK_PALE_SEED_HEIGHT_M (0.45 m) above the ground and the region measures
    as much; a 0.35 m one is not (test_a_rock_is_darker_than_the_soil)."""
    rec = _found(_scene(rock_h=0.7), 1.3)
    assert len(rec) == 1 and rec["label"][0] == ROCK, rec
    assert np.hypot(rec["x"][0] - 9.0, rec["y"][0] - 2.0) < 0.3
    assert rec["height_m"][0] > 0.6
    assert len(_found(_scene(rock_h=0.5), 1.0)) == 1


def test_two_rocks_joined_by_low_cells_are_two_regions():
    """Two 1 x 1 m blocks 0.5 m tall, 1.6 m apart, joined by a 0.15 m ridge of debris."""
    x, y = np.meshgrid(np.arange(2.0, 16.0, 0.05), np.arange(-8.0, 8.0, 0.05))
    x, y = x.ravel(), y.ravel()
    z = _terrain(x, y, swell=False)
    a = (np.abs(x - 9.0) < 0.5) & (np.abs(y - 1.3) < 0.5)
    b = (np.abs(x - 9.0) < 0.5) & (np.abs(y + 1.3) < 0.5)
    ridge = (np.abs(x - 9.0) < 0.3) & (np.abs(y) < 0.9)
    z = z + np.where(a | b, 0.5, np.where(ridge, 0.15, 0.0))
    pts = np.column_stack([x, y, z + RNG.normal(0, 0.01, len(x))])[:, None, :]
    app = _dark_where_raised(pts, swell=False)
    emap = ElevationMap(ElevationMapConfig(detect_every=2))
    _drive(emap, pts, appearance=app)
    two = emap.to_records()
    assert len(two) == 2 and np.all(two["label"] == ROCK), two
    assert np.allclose(np.sort(two["y"]), [-1.3, 1.3], atol=0.3)
    assert np.all(two["area_m2"] < 1.8)


def _dome_with_smear(height=0.8, radius=0.6, smear=0.45):
    """Ground points with a dark dome ``height`` m tall, ``radius`` m around (9, 2), and
    behind it (away from the camera) the streak of stereo smear a tall rock leaves: a
    wedge from ``smear`` m at the dome's edge down to the ground 1.2 m further."""
    x, y = np.meshgrid(np.arange(2.0, 16.0, 0.05), np.arange(-8.0, 8.0, 0.05))
    x, y = x.ravel(), y.ravel()
    z = _terrain(x, y, swell=False)
    d = np.hypot(x - 9.0, y - 2.0)
    dome = height * np.sqrt(np.clip(1 - (d / radius) ** 2, 0, None))
    behind = (x > 9.0) & (x < 9.0 + radius + 1.2) & (np.abs(y - 2.0) < 0.5 * radius) & \
        (d >= radius)
    wedge = np.where(behind, smear * (1 - (x - 9.0 - radius) / 1.2), 0.0)
    z = z + np.maximum(dome, wedge)
    pts = np.column_stack([x, y, z + RNG.normal(0, 0.01, len(x))])
    return pts[:, None, :]


def test_a_rock_is_placed_on_its_upper_part_not_on_its_smear():
    """The rock's centre is that of its cells above half its height: the smear behind a
    tall rock, lower than the rock, widens its footprint away from the camera and would
    move the footprint's hull centroid off the rock."""
    upper = _found(_dome_with_smear())
    assert len(upper) == 1 and upper["label"][0] == ROCK, upper
    assert np.hypot(upper["x"][0] - 9.0, upper["y"][0] - 2.0) < 0.08


def test_trace_reports_each_rock_region_and_the_test_that_rejected_it():
    events = []
    emap = ElevationMap(ElevationMapConfig(detect_every=2))
    emap.trace = lambda verdict, xy, measured: events.append((verdict, xy, measured))
    pts = _scene()
    _drive(emap, pts, appearance=_dark_where_raised(pts))
    rocks = [(xy, m) for v, xy, m in events if v == "rock"]
    assert rocks and all(np.hypot(*(xy - [9.0, 2.0])) < 0.4 for xy, _ in rocks)
    assert all(0.4 < m["height_m"] < 0.6 and m["area_m2"] > 0.6 for _, m in rocks)
    # A block 0.2 m tall is a region too low to be a rock.
    events.clear()
    emap = ElevationMap(ElevationMapConfig(detect_every=2, rock_seed_height_m=0.15))
    emap.trace = lambda verdict, xy, measured: events.append((verdict, xy, measured))
    low = pts.copy()
    raised = low[:, 0, 2] - _terrain(low[:, 0, 0], low[:, 0, 1]) > 0.05
    low[raised, 0, 2] -= 0.3 * (low[raised, 0, 2] - _terrain(9.0, 2.0)) / 0.5
    _drive(emap, low, appearance=_dark_where_raised(pts))
    assert events and {v for v, _, _ in events} == {"low"}, events
    assert len(emap.to_records()) == 0
    # A dark block 0.3 x 0.3 m is a region too small to measure.
    events.clear()
    tiny = pts.copy()
    x, y = tiny[:, 0, 0], tiny[:, 0, 1]
    tiny[:, 0, 2] = np.where((np.abs(x - 9.0) < 0.15) & (np.abs(y - 2.0) < 0.15),
                             _terrain(x, y) + 0.5, _terrain(x, y))
    emap = ElevationMap(ElevationMapConfig(detect_every=2))
    emap.trace = lambda verdict, xy, measured: events.append((verdict, xy, measured))
    _drive(emap, tiny, appearance=_dark_where_raised(tiny))
    assert events and {v for v, _, _ in events} == {"small"}, events
    assert all(m["n_cells"] < 15 for _, _, m in events)


def _fixed_score(seen: list, score: float):
    """A classifier that gives every region ``score`` and appends its features to
    ``seen``."""
    def proba(x):
        seen.append(x)
        return np.full(len(x), score)
    return proba


def test_the_map_rock_rover_decides_which_rock_regions_are_reported():
    pts = _scene()
    app = _dark_where_raised(pts)
    seen = []
    rover = functools.partial(_fixed_score, seen)

    emap = ElevationMap(ElevationMapConfig(detect_every=2), rock_classifier=rover(0.9))
    _drive(emap, pts, appearance=app)
    rec = emap.to_records()
    assert len(rec) == 1 and rec["label"][0] == ROCK and rec["score"][0] == pytest.approx(0.9)
    # Every rock region measured is scored on its finite features, the ones named.
    x = np.concatenate(seen)
    assert x.shape[1] == len(MAP_ROCK_FEATURES) and np.isfinite(x).all()
    f = dict(zip(MAP_ROCK_FEATURES, emap.rois[0].features, strict=True))
    assert f["height_m"] == pytest.approx(rec["height_m"][0])
    assert f["dark_share"] > 0.5 and f["value"] < 0.55 and f["ring_contrast"] > 0.3
    # Refused (at or below map_rock_min_score), the region stays in the map, unreported.
    emap = ElevationMap(ElevationMapConfig(detect_every=2), rock_classifier=rover(0.5))
    _drive(emap, pts, appearance=app)
    assert len(emap.rois) == 1 and len(emap.to_records()) == 0
    # Without a classifier the rules alone decide, score 1.
    assert _found(pts)["score"].tolist() == [1.0]


def test_the_map_outcrop_rover_decides_which_outcrop_regions_are_reported():
    """Each outcrop region measured is scored on its MAP_OUTCROP_FEATURES; an outcrop is
    reported while its kept measurement's score is above map_outcrop_min_score, and a
    rock's score is judged against the rocks' floor, not the outcrops'."""
    pts, app = _slab()
    seen = []
    rover = functools.partial(_fixed_score, seen)

    cfg = ElevationMapConfig(detect_every=2, map_outcrop_min_score=0.6)
    emap = ElevationMap(cfg, outcrop_classifier=rover(0.7))
    rec = _the_slab(emap, pts, app)
    assert rec["score"] == pytest.approx(0.7)
    x = np.concatenate(seen)
    assert x.shape[1] == len(MAP_OUTCROP_FEATURES) and np.isfinite(x).all()
    f = dict(zip(MAP_OUTCROP_FEATURES, emap.rois[0].features, strict=True))
    # The slab is 0.4 of the soil's saturation, the ring around it the soil's; 0.1 m thick.
    assert f["saturation"] == pytest.approx(0.4, abs=0.05)
    assert f["ring_saturation_contrast"] == pytest.approx(0.6, abs=0.1)
    assert f["log_area_m2"] == pytest.approx(np.log(rec["area_m2"]), abs=1e-5)
    assert 0.05 < f["height_m"] < 0.2 and f["rock_share"] == 0.0 and f["seen_share"] > 0.9
    # Refused (at or below the floor), it stays in the map, unreported.
    emap = ElevationMap(cfg, outcrop_classifier=rover(0.55))
    _drive(emap, pts, appearance=app)
    assert len(emap.rois) == 1 and len(emap.to_records()) == 0
    # The rocks' floor does not apply to it.
    emap = ElevationMap(replace(cfg, map_rock_min_score=0.9), outcrop_classifier=rover(0.7))
    _drive(emap, pts, appearance=app)
    assert len(emap.to_records()) == 1
