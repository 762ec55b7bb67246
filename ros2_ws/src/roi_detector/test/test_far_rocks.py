"""Far rocks: dark blobs tracked across pairs and triangulated from the rover's motion, on
a ray-cast scene (flat soil, upright dark cylinders) seen by the bags' camera."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from roi_detector.far_rocks import FarRockConfig, FarRockTracker, dark_blobs
from roi_detector.rover_pipeline import FAR_ROCK_ID_BASE, far_rock_records
from roi_detector.stereo import StereoCamera
from roi_network.records import OUTCROP, ROCK

# The bags' navigation camera: 640 x 480, 70 deg, 1.54 m high, 20 deg down, 0.2 m baseline.
TILT = np.radians(20.0)
R_BC = np.column_stack([[0, -1, 0], np.cross([np.cos(TILT), 0, -np.sin(TILT)], [0, -1, 0]),
                        [np.cos(TILT), 0, -np.sin(TILT)]])
EXTRINSIC = [0.4, 0.1, 1.54, *Rotation.from_matrix(R_BC).as_quat()]
FX = 457.0
K = [FX, 0, 319.5, 0, FX, 239.5, 0, 0, 1]
P_RIGHT = [FX, 0, 319.5, -FX * 0.2, 0, FX, 239.5, 0, 0, 0, 1, 0]
SOIL = (89, 106, 124)  # BGR of the bags' soil
ROCK_BGR = (40, 43, 47)  # varnished rock: darker and greyer
SHADOW = (45, 54, 64)  # the soil in shadow: darker, as saturated


def _camera() -> StereoCamera:
    return StereoCamera.from_camera_info(K, P_RIGHT, 640, 480, EXTRINSIC)


def _render(camera: StereoCamera, x_rover: float, rocks=(), shadows=(), spot=None):
    """Left image and disparity of flat soil (z = 0) with upright cylinders ``rocks``
    ``(x, y, radius, height)``, flat shadow discs ``shadows`` ``(x, y, radius)`` and a dark
    ``spot`` ``(u, v, radius_px, depth_m)`` fixed in the image, for the rover at
    ``(x_rover, 0)`` heading +x."""
    rays = camera.rays_base()  # unit depth: the ray parameter is the depth
    o = camera.t_base_cam + np.array([x_rover, 0.0, 0.0])
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.where(rays[..., 2] < 0, -o[2] / rays[..., 2], np.inf)
    img = np.empty((*rays.shape[:2], 3), np.uint8)
    img[:] = SOIL
    hit = o + rays * np.where(np.isfinite(depth), depth, 0)[..., None]
    for x, y, r in shadows:
        img[np.isfinite(depth) & (np.hypot(hit[..., 0] - x, hit[..., 1] - y) < r)] = SHADOW
    for x, y, r, h in rocks:
        dx, dy = o[0] - x, o[1] - y
        a = rays[..., 0] ** 2 + rays[..., 1] ** 2
        b = 2 * (dx * rays[..., 0] + dy * rays[..., 1])
        c = dx * dx + dy * dy - r * r
        disc = b * b - 4 * a * c
        with np.errstate(invalid="ignore"):
            s = (-b - np.sqrt(disc)) / (2 * a)
        z = o[2] + s * rays[..., 2]
        side = (disc > 0) & (s > 0) & (z >= 0) & (z <= h) & (s < depth)
        with np.errstate(divide="ignore", invalid="ignore"):
            st = (h - o[2]) / rays[..., 2]
        top = o + rays * st[..., None]
        cap = (st > 0) & (np.hypot(top[..., 0] - x, top[..., 1] - y) < r) & (st < depth)
        depth = np.where(side, s, depth)
        depth = np.where(cap & ~side, st, depth)
        img[side | cap] = ROCK_BGR
    if spot is not None:
        u, v, rad, d = spot
        vv, uu = np.mgrid[0:img.shape[0], 0:img.shape[1]]
        inside = np.hypot(uu - u, vv - v) < rad
        img[inside] = ROCK_BGR
        depth[inside] = d
    with np.errstate(divide="ignore"):
        disp = (camera.fxb / depth).astype(np.float32)
    disp[~np.isfinite(depth)] = np.nan
    return img, disp[::2, ::2]


def _drive(camera, tracker, cfg, steps, **scene):
    r = np.eye(3)
    for k, x in enumerate(steps):
        img, disp = _render(camera, x, **scene)
        tracker.add(dark_blobs(img, disp, camera, cfg), float(k), r, np.array([x, 0, 0.0]),
                    camera)
    tracker.close_all()


def test_a_rock_beside_the_route_is_triangulated_and_measured():
    camera = _camera()
    cfg = FarRockConfig()
    tracker = FarRockTracker(cfg)
    # 11 m beside the route, seen from 33 m down to 16 m (it leaves the 70 deg view),
    # always beyond the elevation map's 20 m... and 12 m blob limit.
    rock = (32.0, 11.0, 0.6, 0.6)  # 1.2 m wide (1.13 m^2), 0.6 m high
    _drive(camera, tracker, cfg, np.arange(0.0, 20.0, 0.45), rocks=[rock])
    rocks = tracker.rocks()
    assert len(rocks) == 1
    r = rocks[0]
    # The noise-free disparities of this scene are those of the rock's near face, 0.6 m
    # short of its centre and all alike: the estimated range error is then small and the
    # fit leans on them, within the half width that the covariance allows for where the
    # blob sits on the rock.
    assert np.hypot(r.xy[0] - 32.0, r.xy[1] - 11.0) < 0.6
    assert r.width_m == pytest.approx(1.2, rel=0.2)
    assert r.height_m == pytest.approx(0.6, rel=0.25)
    assert r.parallax_deg > 8 and r.residual_px < 1.0
    # The position covariance is honest about the error: within 3 sigma.
    err = r.xy - [32.0, 11.0]
    assert err @ np.linalg.solve(r.cov, err) < 9.0
    rec = far_rock_records(rocks)
    assert rec["id"][0] > FAR_ROCK_ID_BASE and rec["label"][0] == ROCK
    assert rec["n_obs"][0] == r.n_views and rec["area_m2"][0] > 0.6


def test_small_rock_is_measured_below_the_thresholds():
    camera, cfg = _camera(), FarRockConfig()
    tracker = FarRockTracker(cfg)
    _drive(camera, tracker, cfg, np.arange(0.0, 20.0, 0.45), rocks=[(30.0, -10.0, 0.3, 0.3)])
    assert tracker.rocks() == []
    measured = [m for m in tracker.measured if np.hypot(m.xy[0] - 30, m.xy[1] + 10) < 1.0]
    assert measured and all(m.area_m2 < 0.6 and not m.passed for m in measured)


def test_shadows_are_not_blobs_and_a_spot_on_the_lens_is_no_rock():
    camera, cfg = _camera(), FarRockConfig()
    img, disp = _render(camera, 0.0, shadows=[(25.0, 3.0, 1.5)])
    assert dark_blobs(img, disp, camera, cfg) == []
    # The same patch as dark and grey as a rock is a blob: the test is the colour.
    assert len(dark_blobs(*_render(camera, 0.0, rocks=[(25.0, 3.0, 1.5, 0.02)]), camera,
                          cfg)) == 1
    # A dark spot that moves with the camera: its rays never meet.
    tracker = FarRockTracker(cfg)
    _drive(camera, tracker, cfg, np.arange(0.0, 20.0, 0.45), spot=(500, 300, 8, 25.0))
    assert tracker.rocks() == []
    assert tracker.measured and not tracker.measured[0].passed


def test_near_blobs_are_left_to_the_elevation_map():
    camera, cfg = _camera(), FarRockConfig()
    img, disp = _render(camera, 0.0, rocks=[(8.0, 1.0, 0.6, 0.6)])
    assert dark_blobs(img, disp, camera, cfg) == []
    far = FarRockConfig(min_depth_m=5.0)
    blobs = dark_blobs(img, disp, camera, far)
    assert len(blobs) == 1 and 6.0 < blobs[0].depth_m < 9.0


def test_the_ln_gets_the_far_rocks_no_map_roi_stands_near():
    from roi_detector.elevation_map import MapRoi
    from roi_detector.far_rocks import FarRock
    from roi_detector.rover_pipeline import DriveMapper, RoverConfig

    def far(i, x, y):
        return FarRock(i, np.array([x, y]), 0.3, np.eye(2) * 0.04, 1.2, 0.5, 1.13, 20, 10.0,
                       0.5, 15.0, True, True)

    mapper = DriveMapper(RoverConfig())
    mapper.map.rois = [MapRoi(7, ROCK, np.array([10.0, 5.0]), 0.2, 1.5, 0.6, 1.6, 1.2, 0.0,
                              rounds=3, examined=3, n_pairs=12),
                       MapRoi(8, OUTCROP, np.array([40.0, 0.0]), 0.1, 30.0, 0.2, 8.0, 5.0,
                              0.0, rounds=3, examined=3, n_pairs=12)]
    # Far rock 1 is the map's rock 7 seen from afar; rock 3 stands beside outcrop 8, 2 m
    # from its centre (within half its major axis): a rock, not the outcrop.
    mapper.far.measured = [far(1, 10.8, 5.3), far(2, 30.0, -8.0), far(3, 42.0, 0.0)]
    rec = mapper._map_and_far_records()
    assert sorted(rec["id"]) == [7, 8, FAR_ROCK_ID_BASE + 2, FAR_ROCK_ID_BASE + 3]


def test_a_map_rock_the_map_does_not_report_does_not_hide_a_far_rock():
    """A map rock found in too few of its rounds is not in the LN: the far rock seen at its
    place is (else the rock would be lost between the two)."""
    from roi_detector.elevation_map import MapRoi
    from roi_detector.far_rocks import FarRock
    from roi_detector.rover_pipeline import DriveMapper, RoverConfig

    far = FarRock(1, np.array([10.5, 5.2]), 0.3, np.eye(2) * 0.04, 1.2, 0.5, 1.13, 20,
                  10.0, 0.5, 15.0, True, True)
    mapper = DriveMapper(RoverConfig())
    flicker = MapRoi(7, ROCK, np.array([10.0, 5.0]), 0.2, 1.5, 0.6, 1.6, 1.2, 0.0,
                     rounds=1, examined=4, n_pairs=12)
    mapper.map.rois = [flicker]
    mapper.far.measured = [far]
    assert mapper.map.consistent() == []
    assert sorted(mapper._map_and_far_records()["id"]) == [FAR_ROCK_ID_BASE + 1]
    # Once the map reports its rock, the rock is the map's alone.
    flicker.rounds = 3
    assert sorted(mapper._map_and_far_records()["id"]) == [7]


def test_dark_blob_reads_the_disparity_of_its_own_rows():
    """A thin blob starting on an odd image row (off the half-resolution disparity grid)
    takes its depth from the grid rows inside it, not from the row above."""
    camera = _camera()
    img = np.empty((480, 640, 3), np.uint8)
    img[:] = SOIL
    img[201:204, 300:340] = ROCK_BGR  # image rows 201-203: grid row 101 (image row 202)
    disp = np.full((240, 320), camera.fxb / 8.0, np.float32)  # the soil: 8 m
    disp[100] = camera.fxb / 60.0  # image row 200, above the blob: out of range
    disp[101] = camera.fxb / 20.0  # image row 202, inside the blob
    disp[102] = camera.fxb / 60.0  # image row 204, below it
    blobs = dark_blobs(img, disp, camera)
    assert len(blobs) == 1
    assert blobs[0].depth_m == pytest.approx(20.0, rel=1e-3)



def test_the_cli_builds_the_library_default_configuration(monkeypatch):
    """One default (RoverConfig) for the library, the offline CLI and the node: ``roi_detector
    ln`` with no flag runs it; --method and --min-obs set what they name; the flags of
    removed variants are refused."""
    from roi_detector import cli
    from roi_detector.local_network import LnConfig
    from roi_detector.rover_pipeline import RoverConfig
    from roi_detector.tracking import TrackerConfig

    seen = []

    def build_ln(bag, odometry, model, cfg, *args, **kwargs):
        seen.append(cfg)
        raise ValueError("stop here")  # the CLI reports it and exits 1

    monkeypatch.setattr(cli, "build_ln", build_ln)
    ln = ["ln", "BAG", "--odometry", "o.tum", "--out", "ln.geojson"]
    assert cli.main(ln) == 1 and seen[-1] == RoverConfig()
    assert cli.main([*ln, "--method", "per_pair", "--min-obs", "2"]) == 1
    assert seen[-1] == RoverConfig(method="per_pair", tracker=TrackerConfig(min_obs=2),
                                   ln=LnConfig(min_obs=2))
    for gone in ("--no-far-rocks", "--no-classify-map-outcrops"):
        with pytest.raises(SystemExit):
            cli.main([*ln, gone])


def _drive_described(camera, tracker, cfg, steps, **scene):
    r = np.eye(3)
    for k, x in enumerate(steps):
        img, disp = _render(camera, x, **scene)
        tracker.add(dark_blobs(img, disp, camera, cfg, describe=True), float(k), r,
                    np.array([x, 0, 0.0]), camera)
    tracker.close_all()


def test_blobs_described_by_the_papers_features_and_their_darkness():
    from roi_detector.far_rocks import far_feature_names

    camera, cfg = _camera(), FarRockConfig()
    img, disp = _render(camera, 0.0, rocks=[(25.0, 3.0, 0.6, 0.6)])
    assert dark_blobs(img, disp, camera, cfg)[0].appearance is None  # not asked for
    (blob,) = dark_blobs(img, disp, camera, cfg, describe=True)
    names = far_feature_names()
    # The appearance: the paper's groups, then value and saturation relative to the soil.
    assert blob.appearance.shape == (len(names) - 7,) and np.isfinite(blob.appearance).all()
    soil_v, rock_v = max(SOIL) / 255, max(ROCK_BGR) / 255
    assert blob.appearance[-2] == pytest.approx(rock_v / soil_v, rel=0.05)
    gray_contrast = blob.appearance[names.index("gray_contrast")]
    assert gray_contrast < -0.2  # darker than the ring of soil around it


def _says(answer, seen):
    from roi_detector.far_rocks import far_feature_names

    def proba(x):
        assert x.shape == (1, len(far_feature_names())) and np.isfinite(x).all()
        seen.append(x[0])
        return np.array([answer])
    return proba


def test_the_classifier_stands_in_for_the_size_thresholds_on_every_measured_track(
        monkeypatch):
    """The Rock Rover decides every track that passed the geometric tests, whatever its
    measured size: the small rock, refused by the area threshold, is a rock when the
    classifier says so, and the candidate is not when it says no. A track that fails the
    geometry never reaches it; a classifier needs the blobs' appearance."""
    from roi_detector import far_rocks

    camera, cfg = _camera(), FarRockConfig()
    rock, small = (32.0, 11.0, 0.6, 0.6), (30.0, -10.0, 0.3, 0.3)
    steps = np.arange(0.0, 20.0, 0.45)
    seen = []
    yes = FarRockTracker(cfg, _says(0.8, seen))
    _drive_described(camera, yes, cfg, steps, rocks=[rock, small])
    got = sorted(yes.rocks(), key=lambda r: r.xy[1])
    assert len(got) == 2 and np.hypot(*(got[0].xy - [30.0, -10.0])) < 1.0
    assert not got[0].candidate and got[0].passed and got[0].area_m2 < far_rocks.MIN_AREA_M2
    assert len(yes.rocks(classified=False)) == 1  # the rules alone: the big rock
    decided = [m for m in yes.measured if np.isfinite(m.score)]
    assert len(seen) == len(decided) >= 2
    assert all(m.parallax_deg >= far_rocks.CLASSIFIED_MIN_PARALLAX_DEG
               and m.residual_px <= far_rocks.MAX_RESIDUAL_PX for m in decided)
    no = FarRockTracker(cfg, _says(0.2, []))
    _drive_described(camera, no, cfg, steps, rocks=[rock, small])
    assert no.rocks() == [] and len(no.rocks(classified=False)) == 1
    # Geometry still gates: with a 90 deg bearing-spread demand on the tracks it decides,
    # no track is decided.
    # The rules' bearing-spread test is the candidates' alone: the classifier still decides
    # both tracks.
    rules_strict = FarRockConfig(min_parallax_deg=90.0)
    both = FarRockTracker(rules_strict, _says(0.8, []))
    _drive_described(camera, both, rules_strict, steps, rocks=[rock, small])
    assert len(both.rocks()) == 2 and both.rocks(classified=False) == []
    # A classifier needs the blobs' appearance.
    blind = FarRockTracker(cfg, _says(0.8, []))
    with pytest.raises(ValueError, match="appearance"):
        _drive(camera, blind, cfg, steps, rocks=[rock])
    # Geometry still gates: with a 90 deg bearing-spread demand on the tracks it decides,
    # no track is decided.
    monkeypatch.setattr(far_rocks, "CLASSIFIED_MIN_PARALLAX_DEG", 90.0)
    seen = []
    none = FarRockTracker(cfg, _says(0.8, seen))
    _drive_described(camera, none, cfg, steps, rocks=[rock, small])
    assert none.rocks() == [] and seen == []


def _noisy_track(rng, bearing_px, range_share, n=30):
    """A track of ``n`` views of a rock at (30, 12) from a straight drive along x, its
    bearings off by ``bearing_px`` (1 sigma) and its stereo ranges by ``range_share`` of
    their nominal sigma (0.5 px of disparity)."""
    from roi_detector.far_rocks import FarTrack, _View

    rock = np.array([30.0, 12.0])
    views = []
    for x in np.linspace(0.0, 14.0, n):
        c = np.array([x, 0.0, 1.5])
        true = rock - c[:2]
        r = float(np.linalg.norm(true))
        a = np.arctan2(true[1], true[0]) + rng.normal(0, bearing_px / FX)
        sigma = r * r / (FX * 0.2) * 0.5
        ray = np.array([np.cos(a), np.sin(a), -0.05])
        views.append(_View(0.0, c, ray / np.linalg.norm(ray), 0.04, 0.0, -0.02, x,
                           r + rng.normal(0, range_share * sigma), sigma))
    tr = FarTrack(1, views, np.r_[views[0].centre[:2] + views[0].ray[:2] * 20.0, 0.0])
    for k in range(1, n + 1):  # as the tracker does, view by view
        sub = FarTrack(1, views[:k], tr.point)
        sub.triangulate(1.0 / FX)
        tr.point = sub.point
    return tr, rock


def test_variance_components_estimate_the_tracks_own_errors_and_place_it_better():
    rng = np.random.default_rng(3)
    prior, fitted, scales = [], [], []
    for _ in range(40):
        # Bearings worse than the 1 px prior, stereo ranges better than theirs.
        tr, rock = _noisy_track(rng, bearing_px=1.5, range_share=0.3)
        prior.append(np.linalg.norm(tr.point[:2] - rock))
        sb, info = tr.refine(1.0 / FX, 0.5)
        fitted.append(np.linalg.norm(tr.point[:2] - rock))
        scales.append(sb * FX)
        assert info.shape == (2, 2) and np.all(np.linalg.eigvalsh(info) > 0)
    assert np.median(scales) == pytest.approx(1.5, rel=0.2)
    assert np.median(fitted) < 0.7 * np.median(prior)
    # Noise as the priors say: the scales stay near them and the fit does not degrade.
    tr, rock = _noisy_track(np.random.default_rng(4), bearing_px=1.0, range_share=1.0)
    before = np.linalg.norm(tr.point[:2] - rock)
    sb, _ = tr.refine(1.0 / FX, 0.5)
    assert 0.6 < sb * FX < 1.5
    assert np.linalg.norm(tr.point[:2] - rock) < before + 0.3
