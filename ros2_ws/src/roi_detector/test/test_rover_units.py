"""Rover-side building blocks on small synthetic inputs: geometry, tracking, LN, inputs."""


import numpy as np
import pytest
from scipy.spatial.transform import Rotation
from sensor_msgs.msg import CompressedImage

from roi_detector.inputs import (
    BadInput,
    PairSpacing,
    PoseTrack,
    decode_image,
    read_pose_covariance,
    read_tum,
    write_tum,
)
from roi_detector.local_network import LnConfig, LocalNetwork, load_or_fresh
from roi_detector.rover_candidates import measure_region
from roi_detector.rover_pipeline import (
    FAR_ROCK_ID_BASE,
    SESSION_ID_SPAN,
    observations_in_odom,
    session_id_base,
)
from roi_detector.stereo import StereoCamera, local_ground_height
from roi_detector.tracking import Observation, Tracker, TrackerConfig, tracks_to_records
from roi_network.geojson import write_geojson
from roi_network.network import MapFrame, RoiNetwork
from roi_network.records import OUTCROP, ROCK, empty_records

# The MER-like bench of the simulator: 1.54 m high, 20 deg down, 20 cm baseline.
TILT = np.radians(20.0)
R_BC = np.column_stack([[0, -1, 0], np.cross([np.cos(TILT), 0, -np.sin(TILT)], [0, -1, 0]),
                        [np.cos(TILT), 0, -np.sin(TILT)]])
EXTRINSIC = [0.4, 0.1, 1.54, *Rotation.from_matrix(R_BC).as_quat()]
K = [300.0, 0, 159.5, 0, 300.0, 119.5, 0, 0, 1]
P_RIGHT = [300.0, 0, 159.5, -300.0 * 0.2, 0, 300.0, 119.5, 0, 0, 0, 1, 0]


def _camera() -> StereoCamera:
    return StereoCamera.from_camera_info(K, P_RIGHT, 320, 240, EXTRINSIC)


def _scene_points(camera: StereoCamera, box=None) -> np.ndarray:
    """Base_link points seen by each pixel of a flat ground (z = 0) with an optional box
    ((x0, x1, y0, y1, height) in base_link) standing on it (its top face only)."""
    rays = camera.rays_base()
    o = camera.t_base_cam
    with np.errstate(divide="ignore"):
        s = -o[2] / rays[..., 2]
    pts = o + rays * s[..., None]
    pts[~(s > 0)] = np.nan
    if box is not None:
        x0, x1, y0, y1, h = box
        st = (h - o[2]) / rays[..., 2]
        top = o + rays * st[..., None]
        inside = (st > 0) & (top[..., 0] > x0) & (top[..., 0] < x1) & (top[..., 1] > y0) & \
            (top[..., 1] < y1)
        pts[inside] = top[inside]
    far = np.linalg.norm(pts - o, axis=-1) > 14
    pts[far] = np.nan
    return pts


def test_camera_model_from_camera_info_and_extrinsic():
    cam = _camera()
    assert cam.baseline_m == pytest.approx(0.2)
    # A ground point straight ahead projects on the image's vertical centre line.
    uv, z = cam.project_base(np.array([[5.0, 0.1, 0.0]]))
    assert uv[0, 0] == pytest.approx(159.5, abs=1e-6) and z[0] > 0
    with pytest.raises(ValueError, match="baseline"):
        StereoCamera.from_camera_info(K, [300.0, 0, 0, 0.0] + [0] * 8, 320, 240, EXTRINSIC)


def test_ground_height_flat_and_box():
    cam = _camera()
    flat = local_ground_height(_scene_points(cam))
    assert np.nanmax(np.abs(flat)) < 0.02
    pts = _scene_points(cam, box=(5.0, 6.0, -0.5, 0.5, 0.5))
    h = local_ground_height(pts)
    on_box = np.abs(pts[..., 2] - 0.5) < 1e-6
    assert on_box.sum() > 50
    assert np.nanmedian(h[on_box]) == pytest.approx(0.5, abs=0.05)
    assert np.nanmedian(np.abs(h[~on_box])) < 0.02


def test_measure_region_area_height_centre():
    cam = _camera()
    pts = _scene_points(cam, box=(5.0, 6.0, -0.5, 0.5, 0.5))
    h = local_ground_height(pts)
    mask = h > 0.25
    ys, xs = np.nonzero(mask)
    bbox = (xs.min(), ys.min(), xs.max() + 1, ys.max() + 1)
    c = measure_region(mask[bbox[1]:bbox[3], bbox[0]:bbox[2]], bbox, ROCK, pts, h, cam)
    assert c is not None
    assert c.area_m2 == pytest.approx(1.0, rel=0.15)
    assert c.height_m == pytest.approx(0.5, abs=0.05)
    assert np.hypot(c.center[0] - 5.5, c.center[1]) < 0.15
    # No valid depth: nothing measured.
    none = measure_region(mask[bbox[1]:bbox[3], bbox[0]:bbox[2]], bbox, ROCK,
                          np.full_like(pts, np.nan), h, cam)
    assert none is None


def _obs(xy, t, label=ROCK, score=1.0, sigma=0.1):
    return Observation(t, np.asarray(xy, float), 0.0, np.eye(2) * sigma**2,
                       np.eye(2) * 0.01, label, score, 1.0, 0.5, np.eye(2) * 0.04)


def test_tracker_confirms_and_merges_revisit():
    tracker = Tracker(TrackerConfig(min_obs=3))
    rng = np.random.default_rng(0)
    for k in range(4):  # two ROIs 3 m apart, seen 4 times each
        tracker.update([_obs([10 + rng.normal(0, 0.05), 0], k),
                        _obs([10, 3 + rng.normal(0, 0.05)], k, OUTCROP)])
    assert len(tracker.tracks) == 2 and len(tracker.confirmed()) == 2
    tracker.update([_obs([10.2, 0.1], 500.0)])  # the route passes by again much later
    assert len(tracker.tracks) == 2
    rec = tracks_to_records(tracker.tracks)
    assert sorted(rec["label"].tolist()) == [ROCK, OUTCROP]
    assert rec["n_obs"].tolist() == [5, 4]
    # Covariance: the stereo mean shrinks with observations, the odometry part does not.
    assert 0.01 < rec["cov_xx"][0] < 0.01 + 0.01 / 4


def test_tracker_keeps_one_observation_per_track_per_pair():
    tracker = Tracker(TrackerConfig(gate_m=1.0))
    tracker.update([_obs([0, 0], 0)])
    tracker.update([_obs([0.1, 0], 1), _obs([-0.1, 0.2], 1)])
    assert len(tracker.tracks) == 2


def test_observations_rotate_into_odom():
    rec = empty_records(1)
    rec["x"], rec["label"], rec["cov_xx"], rec["cov_yy"] = 5.0, ROCK, 0.09, 0.01
    rec["major_m"] = rec["minor_m"] = 1.0
    r = Rotation.from_euler("z", np.pi / 2).as_matrix()
    (o,) = observations_in_odom(rec, 1.0, r, np.array([1.0, 2.0, 0.0]), np.eye(2) * 0.5,
                                np.zeros(2))
    np.testing.assert_allclose(o.xy, [1.0, 7.0], atol=1e-9)
    # The range error (base_link x) is along odom y after a 90 deg turn.
    assert o.cov[1, 1] == pytest.approx(0.09) and o.cov[0, 0] == pytest.approx(0.01)


def _tracks(n_obs, xs):
    rec = empty_records(len(xs))
    rec["id"] = np.arange(1, len(xs) + 1)
    rec["x"] = xs
    rec["label"] = ROCK
    rec["n_obs"] = n_obs
    rec["cov_xx"] = rec["cov_yy"] = 0.04
    rec["major_m"] = 1.0
    return rec


def test_ln_takes_confirmed_tracks_and_merges_revisits(tmp_path):
    ln = LocalNetwork(LnConfig(min_obs=3))
    assert not ln.update(_tracks([1, 2], [0.0, 10.0]))
    assert ln.update(_tracks([3, 5], [0.0, 10.0])) and len(ln) == 2
    assert not ln.update(_tracks([3, 5], [0.0, 10.0]))  # nothing new
    # A second track of the first ROI (re-visit after drift): merged, not added.
    both = np.concatenate([_tracks([3, 5], [0.0, 10.0]), _tracks([4], [0.3])])
    both["id"][2] = 7
    ln.update(both)
    assert len(ln) == 2
    merged = ln.records[ln.records["x"] < 5][0]
    assert merged["n_obs"] == 7 and merged["cov_xx"] < 0.04
    path = tmp_path / "ln.geojson"
    ln.save(path)
    again = LocalNetwork.load(path)
    np.testing.assert_array_equal(again.records, ln.records)
    # The restarted LN keeps its ids: a known track updates its node.
    moved = _tracks([3, 6], [0.0, 10.5])
    assert again.update(moved) and len(again) == 2


def test_a_restarted_detector_does_not_reuse_the_ids_the_ln_holds():
    # Two starts of the detector: each counts its map ROIs from 1, the offsets differ.
    first, second = session_id_base(1_795_650_000.7), session_id_base(1_795_650_004.2)
    assert first != second
    for base in (first, second, session_id_base(3999.0)):
        top = base + FAR_ROCK_ID_BASE + (SESSION_ID_SPAN - FAR_ROCK_ID_BASE - 1)
        assert base % SESSION_ID_SPAN == 0 and top < 2**32
    ln = LocalNetwork(LnConfig(min_obs=3))
    before = _tracks([3, 3], [0.0, 10.0])
    before["id"] += np.uint32(first)
    ln.update(before)
    # After the restart, ROI 1 of the new map is another rock 3 m from the old ROI 1.
    after = _tracks([3], [3.0])
    after["id"] += np.uint32(second)
    ln.update(after)
    assert len(ln) == 3 and sorted(ln.records["x"]) == [0.0, 3.0, 10.0]


def test_corrupt_saved_ln_is_kept_aside(tmp_path):
    path = tmp_path / "ln.geojson"
    path.write_text('{"type": "FeatureCollection", "features": [')
    messages = []
    ln = load_or_fresh(path, LnConfig(), messages.append)
    assert len(ln) == 0 and not path.exists()
    assert len(messages) == 1 and str(path) in messages[0]
    aside = list(tmp_path.glob("ln.geojson.corrupt-*"))
    assert len(aside) == 1
    # A valid GeoJSON that is not an odom LN (a map-frame GN) is refused the same way.
    write_geojson(RoiNetwork(empty_records(0), "map", MapFrame("EPSG:32719")), path)
    assert len(load_or_fresh(path, LnConfig(), messages.append)) == 0
    assert len(messages) == 2 and "odom" in messages[1]


def test_bad_input_logged_once_per_kind():
    lines = []
    bad = BadInput(lines.append)
    for _ in range(3):
        bad("undecodable image", "x")
    bad("missing pair half", "y")
    assert bad.counts == {"undecodable image": 3, "missing pair half": 1}
    assert len(lines) == 2
    assert decode_image(CompressedImage(format="jpeg", data=list(b"not a jpeg"))) is None
    assert decode_image(CompressedImage(format="jpeg")) is None


def test_pair_spacing_thins_a_dense_stream_and_keeps_a_sparse_one():
    """A 10 Hz camera at 0.15 m/s gives a pair each 1.5 cm: one in ~27 is read, 0.4-0.42 m
    apart; the simulator's pairs (0.45 m apart moving, 10 s stopped, 4.3 deg in its
    tightest turn) are all read; a turn on the spot is read every 10 deg."""
    def pose(x, yaw_deg=0.0):
        return Rotation.from_euler("z", yaw_deg, degrees=True).as_matrix(), \
            np.array([x, 0.0, 0.0]), None

    dense = PairSpacing()
    kept = [k for k in range(400) if dense.keep(0.1 * k, pose(0.015 * k))]
    gaps = np.diff(np.asarray(kept) * 0.015)
    assert len(kept) == 15 and dense.skipped == 385
    assert np.all((gaps >= 0.4) & (gaps < 0.42))
    sim = PairSpacing()
    stamps = [3.0 * k for k in range(20)] + [67.0 + 10 * k for k in range(6)]
    places = [0.45 * k for k in range(20)] + [0.45 * 19] * 6
    turns = [4.3 * k for k in range(20)] + [4.3 * 19] * 6
    assert all(sim.keep(t, pose(x, a)) for t, x, a in zip(stamps, places, turns, strict=True))
    spin = PairSpacing()
    turned = [k for k in range(91) if spin.keep(0.1 * k, pose(0.0, 1.0 * k))]
    assert set(np.diff(turned)) <= {10, 11} and len(turned) >= 9
    every = PairSpacing(min_travel_m=0.0)
    assert all(every.keep(0.1 * k, pose(0.0)) for k in range(10))
    with pytest.raises(ValueError, match="min_travel_m"):
        PairSpacing(min_travel_m=-1.0)


def test_pose_track_interpolates_and_reports_gaps(tmp_path):
    q = Rotation.from_euler("z", [[0.0], [0.2], [0.4], [0.6]]).as_quat()
    t = [0.0, 0.5, 1.0, 5.0]
    p = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]], float)
    path = tmp_path / "vo.tum"
    write_tum(path, t, p, q)
    track = read_tum(path, max_gap_s=1.0)
    r, pos, _ = track.at(0.25)
    assert pos[0] == pytest.approx(0.5)
    assert Rotation.from_matrix(r).as_euler("xyz")[2] == pytest.approx(0.1)
    assert track.at(3.0) is None  # inside a 4 s gap
    assert track.at(6.0) is None  # after the end
    assert isinstance(track, PoseTrack)
    bad = tmp_path / "bad.tum"
    bad.write_text("0 1 2 3\n")
    with pytest.raises(ValueError, match=r"bad\.tum:1"):
        read_tum(bad)


def test_pose_covariance_file_gives_the_xy_block_at_each_odometry_stamp(tmp_path):
    """rover_vo's vo_covariance.txt: t and a 6x6 covariance per pose; the LN takes its
    x-y block at each odometry stamp, and a file that does not cover the odometry, or a
    malformed one, is refused naming the file."""
    stamps = np.array([0.0, 0.5, 1.0])
    rows = []
    for k, t in enumerate(stamps):
        c = np.diag([1.0 + k, 2.0 + k, 3.0, 4.0, 5.0, 6.0])
        c[0, 1] = c[1, 0] = 0.1 * k
        rows.append(f"{t:.9f} " + " ".join(f"{v:.6e}" for v in c.ravel()))
    path = tmp_path / "vo_covariance.txt"
    path.write_text("# t, pose covariance 6x6\n" + "\n".join(rows[::-1]) + "\n")
    cov = read_pose_covariance(path, [0.5, 1.0 + 2e-7, 0.0])
    np.testing.assert_allclose(cov, [[[2.0, 0.1], [0.1, 3.0]], [[3.0, 0.2], [0.2, 4.0]],
                                     [[1.0, 0.0], [0.0, 2.0]]])
    with pytest.raises(ValueError, match=r"vo_covariance\.txt: no covariance at odometry "
                       r"stamp 0\.750000000 \(1 of 2"):
        read_pose_covariance(path, [0.0, 0.75])
    bad = tmp_path / "short.txt"
    bad.write_text("0.0 1 2 3\n")
    with pytest.raises(ValueError, match=r"short\.txt:1: expected 37 finite numbers"):
        read_pose_covariance(bad, [0.0])
    neg = tmp_path / "neg.txt"
    neg.write_text("0.0 " + " ".join(["-1.0"] + ["0.0"] * 35) + "\n")
    with pytest.raises(ValueError, match=r"neg\.txt:1: negative"):
        read_pose_covariance(neg, [0.0])


def test_rover_classifier_round_trip(tmp_path):
    """Rock Rover / Outcrop Rover trained on separable synthetic candidates, saved,
    loaded, and applied: dark tall blobs are rocks, pale flat patches outcrops."""
    from roi_detector.classifier import ModelFileError
    from roi_detector.rover_candidates import Candidate, metric_images
    from roi_detector.rover_classifier import (
        RoverClassifier,
        features_of,
        save_rover_model,
        train_classifiers,
    )

    rng = np.random.default_rng(1)
    left = rng.normal(120, 8, (480, 640, 3)).clip(0, 255).astype(np.uint8)
    cands, labels = [], []
    for k in range(24):
        y0, x0 = 20 + (k // 6) * 50, 20 + (k % 6) * 50
        kind = k % 3  # 0 background, 1 rock (dark, tall), 2 outcrop (pale, flat)
        if kind == 1:
            left[2 * y0:2 * y0 + 40, 2 * x0:2 * x0 + 40] = 40
        elif kind == 2:
            left[2 * y0:2 * y0 + 40, 2 * x0:2 * x0 + 40] = 230
        mask = np.ones((20, 20), bool)
        height = {0: 0.3, 1: 0.8, 2: 0.1}[kind] + rng.normal(0, 0.02)
        area = {0: 1.0, 1: 1.5, 2: 9.0}[kind] * (1 + rng.normal(0, 0.05))
        cands.append(Candidate(1, mask, (x0, y0, x0 + 20, y0 + 20), np.zeros(3), area, height,
                               1.2, 1.0, 0.0, 6.0, 0.1, np.array([1.0, 0.0])))
        labels.append(kind)
    gray = left.mean(axis=2).astype(np.uint8)
    metrics = metric_images(gray)
    x = features_of(left, cands, metrics, "stereo")
    clfs = train_classifiers(x, np.array(labels), "stereo", k=3)
    path = tmp_path / "rover.npz"
    save_rover_model(path, clfs, {"feature_set": "stereo", "threshold": 0.5, "test": True})
    model = RoverClassifier.load(path)
    kept = model.classify(left, cands, metrics)
    got = {id(c): c.label for c in kept}
    for c, kind in zip(cands, labels, strict=True):
        if kind == 0:
            assert id(c) not in got
        else:
            assert got.get(id(c)) == kind
    (tmp_path / "bad.npz").write_bytes(b"junk")
    with pytest.raises(ModelFileError, match=r"bad\.npz"):
        RoverClassifier.load(tmp_path / "bad.npz")


def test_a_far_rock_model_serves_the_elevation_map_and_only_it(tmp_path):
    """A model holding the far rocks' Rock Rover alone: loaded, applied to far-rock
    features, given to the far rocks; refused by name for the elevation_map method (which
    needs the map's rovers too) and the per_pair method."""
    from roi_detector.classifier import BinaryClassifier, ClassifierConfig, ModelFileError
    from roi_detector.far_rocks import far_feature_names
    from roi_detector.rover_classifier import (
        FAR_ROCK_CLASSIFIER,
        RoverClassifier,
        save_rover_model,
    )
    from roi_detector.rover_pipeline import (
        DriveMapper,
        RoverConfig,
        RoverDetector,
        check_model,
        load_classifier,
    )

    names = far_feature_names()
    rng = np.random.default_rng(3)
    f = rng.normal(0, 1, 40)  # one factor carries the class, through every feature
    x = (f[:, None] + rng.normal(0, 0.1, (40, len(names)))).astype(np.float32)
    y = (f > 0).astype(np.uint8)
    clf = BinaryClassifier(FAR_ROCK_CLASSIFIER, names, ClassifierConfig(k=3)).fit(x, y)
    path = tmp_path / "far.npz"
    save_rover_model(path, {FAR_ROCK_CLASSIFIER: clf}, {"method": "elevation_map"})
    model = RoverClassifier.load(path)
    assert model.far_rocks and not model.per_pair
    probe = np.array([[3.0], [-3.0]], np.float32) * np.ones(len(names), np.float32)
    assert model.far_rock_proba(probe).tolist() == [1.0, 0.0]
    mapper = DriveMapper(RoverConfig(), classifier=model)
    assert mapper.far.classifier is not None and mapper.map.rock_classifier is None
    # The elevation_map method classifies the map's rocks too: a model without their Rock
    # Rover is refused by name.
    with pytest.raises(ValueError, match=r"far\.npz.*map-rock"):
        load_classifier(str(path), RoverConfig())
    # Without a model the detector does not describe the far blobs.
    assert not RoverDetector([0.0] * 6 + [1.0], None, RoverConfig()).describe_blobs
    per_pair = RoverConfig(method="per_pair")
    with pytest.raises(ValueError, match=r"far\.npz.*per_pair"):
        check_model(model, per_pair)
    with pytest.raises(ValueError, match=r"far\.npz.*per_pair"):
        load_classifier(str(path), per_pair)
    # A per_pair model cannot classify far rocks: said by name.
    pp = tmp_path / "pp.npz"
    save_rover_model(pp, {n: BinaryClassifier(n, names, ClassifierConfig(k=3)).fit(x, y)
                          for n in ("rock_rover", "outcrop_rover")}, {})
    with pytest.raises(ValueError, match=r"pp\.npz.*far-rock"):
        load_classifier(str(pp), RoverConfig())
    assert load_classifier(str(pp), per_pair).per_pair
    # Not a rover model at all: named, with what it holds.
    other = tmp_path / "other.npz"
    save_rover_model(other, {"rock_orbital": BinaryClassifier(
        "rock_orbital", names, ClassifierConfig(k=3)).fit(x, y)}, {})
    with pytest.raises(ModelFileError, match=r"other\.npz.*rock_orbital"):
        RoverClassifier.load(other)


def _two_rock_rovers(rng: np.random.Generator, outcrops: bool = True) -> dict:
    """Both Rock Rovers (far and map rocks, boosted trees) fitted on random features whose
    common factor says rock (> 0) or not, as ``roi_detector train`` writes them; and with
    ``outcrops`` the map outcrops' Outcrop Rover the same way."""
    from roi_detector.classifier import BinaryClassifier, ClassifierConfig
    from roi_detector.elevation_map import MAP_OUTCROP_FEATURES, MAP_ROCK_FEATURES
    from roi_detector.far_rocks import far_feature_names
    from roi_detector.rover_classifier import (
        FAR_ROCK_CLASSIFIER,
        MAP_OUTCROP_CLASSIFIER,
        MAP_ROCK_CLASSIFIER,
    )

    clfs = {}
    parts = [(FAR_ROCK_CLASSIFIER, far_feature_names()), (MAP_ROCK_CLASSIFIER, MAP_ROCK_FEATURES)]
    if outcrops:
        parts.append((MAP_OUTCROP_CLASSIFIER, MAP_OUTCROP_FEATURES))
    for name, names in parts:
        f = rng.normal(0, 1, 60)
        x = (f[:, None] + rng.normal(0, 0.1, (60, len(names)))).astype(np.float32)
        clfs[name] = BinaryClassifier(name, names, ClassifierConfig(kind="gradient_boosting")
                                      ).fit(x, (f > 0).astype(np.uint8))
    return clfs


def test_the_map_rocks_rock_rover_is_loaded_and_given_to_the_map(tmp_path):
    """A model holding both Rock Rovers and the Outcrop Rover (what ``roi_detector
    train`` writes): the map gets the map rocks' and scores its rock regions' features
    with it, and the detector describes the far blobs for the far rocks'."""
    from roi_detector.elevation_map import MAP_ROCK_FEATURES
    from roi_detector.rover_classifier import RoverClassifier, save_rover_model
    from roi_detector.rover_pipeline import DriveMapper, RoverConfig, RoverDetector, load_classifier

    clfs = _two_rock_rovers(np.random.default_rng(5))
    path = tmp_path / "both.npz"
    save_rover_model(path, clfs, {"method": "elevation_map"})
    model = load_classifier(str(path), RoverConfig())
    assert isinstance(model, RoverClassifier) and model.map_rocks and model.far_rocks
    probe = np.array([[3.0], [-3.0]], np.float32) * np.ones(len(MAP_ROCK_FEATURES), np.float32)
    p = model.map_rock_proba(probe)
    assert p[0] > 0.9 and p[1] < 0.1
    mapper = DriveMapper(RoverConfig(), classifier=model)
    assert mapper.map.rock_classifier is not None
    assert RoverDetector([0.0] * 6 + [1.0], model, RoverConfig()).describe_blobs


def test_records_in_view_rotates_into_base_link():
    from roi_detector.rover_pipeline import records_in_view
    from roi_network.records import empty_records

    cam = _camera()
    rec = empty_records(3)
    # odom: rover at (10, 5) facing +y (yaw 90 deg); ROIs 8 m ahead, 8 m behind, 30 m ahead.
    for r, (x, y) in zip(rec, [(10.0, 13.0), (10.0, -3.0), (10.0, 35.0)], strict=True):
        r["x"], r["y"], r["z"] = x, y, 0.0
        r["cov_xx"], r["cov_yy"], r["angle_rad"] = 0.04, 0.01, 0.0
    yaw = np.pi / 2
    r_ob = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1]])
    out = records_in_view(rec, (r_ob, np.array([10.0, 5.0, 0.0]), None), cam, 20.0)
    assert len(out) == 1
    assert abs(out["x"][0] - 8.0) < 1e-9 and abs(out["y"][0]) < 1e-9
    # Covariance long along odom x = across the rover's view (base_link y).
    assert abs(out["cov_yy"][0] - 0.04) < 1e-9 and abs(out["cov_xx"][0] - 0.01) < 1e-9
    assert abs(out["angle_rad"][0] + yaw) < 1e-9


def test_the_committed_rover_model_is_the_far_rocks_rock_rover_of_training_seeds():
    """The committed model loads as the default, holds the far rocks' Rock Rover (and not
    the per_pair classifiers), was trained on training seeds only (never an evaluation
    bag's), and says how to re-train it."""
    from roi_detector.far_rocks import far_feature_names
    from roi_detector.rover_classifier import FAR_ROCK_CLASSIFIER
    from roi_detector.rover_pipeline import RoverConfig, installed_model, load_classifier

    path = installed_model()
    assert path is not None and path.stat().st_size < 1_000_000
    model = load_classifier(None, RoverConfig())
    assert model.far_rocks and not model.per_pair
    assert model.classifiers[FAR_ROCK_CLASSIFIER].feature_names == far_feature_names()
    prov = model.meta["provenance"]
    assert prov["seeds"] and all(s >= 100 for s in prov["seeds"])
    assert prov["command"].startswith("roi_detector train") and prov["rocks"] > 20
    # Boosted trees, trained on every measured far track, as the command says.
    assert model.classifiers[FAR_ROCK_CLASSIFIER].config.kind == prov["kind"] == \
        "gradient_boosting"
    assert prov["population"] == "measured"
    # The map outcrops' Outcrop Rover: the paper's PCA + kNN, on the outcrop rule's
    # candidates, which the model records.
    from roi_detector.elevation_map import MAP_OUTCROP_RULE
    from roi_detector.rover_classifier import MAP_OUTCROP_CLASSIFIER

    assert model.map_outcrops and prov["map_outcrop_kind"] == "knn"
    assert model.classifiers[MAP_OUTCROP_CLASSIFIER].config.kind == "knn"
    assert prov["map_outcrop_rule"] == MAP_OUTCROP_RULE
    assert prov["map_outcrops"] > 20
    # per_pair: the committed model holds none of its rovers, every candidate is kept.
    assert load_classifier(None, RoverConfig(method="per_pair")) is None


def test_both_rock_rovers_are_fitted_on_their_samples_and_refuse_one_class():
    from roi_detector.elevation_map import MAP_ROCK_FEATURES
    from roi_detector.far_rocks import far_feature_names
    from roi_detector.rover_classifier import FAR_ROCK_CLASSIFIER
    from roi_detector.training import fit_rock_rovers

    rng = np.random.default_rng(3)
    nf, nm = len(far_feature_names()), len(MAP_ROCK_FEATURES)
    far_y = np.r_[np.ones(20), np.zeros(40)].astype(np.uint8)
    far_x = rng.normal(size=(60, nf)) + far_y[:, None] * 3.0
    far_x[0, 2] = np.nan  # a degenerate track is left out of training
    map_y = np.r_[np.ones(30), np.zeros(10)].astype(np.uint8)
    map_x = rng.normal(size=(40, nm)) + map_y[:, None] * 3.0
    far, rocks, n = fit_rock_rovers(far_x, far_y, map_x, map_y)
    assert n == {"far_samples": 59, "far_rocks": 19, "map_samples": 40, "map_rocks": 30}
    assert far.name == FAR_ROCK_CLASSIFIER and rocks.feature_names == MAP_ROCK_FEATURES
    # Separable samples: each classifier tells its own training classes apart.
    assert (rocks.predict_proba(map_x) > 0.5).tolist() == (map_y == 1).tolist()
    assert (far.predict_proba(far_x[1:]) > 0.5).tolist() == (far_y[1:] == 1).tolist()
    with pytest.raises(ValueError, match="map rock regions of s9: 10 samples, not both"):
        fit_rock_rovers(far_x, far_y, map_x[:10], np.ones(10, np.uint8), where="s9")
    with pytest.raises(ValueError, match="far-rock candidates of s9"):
        fit_rock_rovers(far_x[20:], far_y[20:], map_x, map_y, where="s9")


def test_the_elevation_map_without_a_model_is_an_error(monkeypatch):
    """The elevation_map method asks for its classifiers: no model is a clear error, not
    ROIs silently left to the rules; 'none' runs the rules alone; per_pair without a
    model keeps every candidate."""
    import roi_detector.rover_pipeline as pipeline
    from roi_detector.rover_pipeline import RoverConfig

    monkeypatch.setattr(pipeline, "installed_model", lambda: None)
    with pytest.raises(ValueError, match="no rover model"):
        pipeline.load_classifier(None, RoverConfig())
    assert pipeline.load_classifier("none", RoverConfig()) is None
    assert pipeline.load_classifier(None, RoverConfig(method="per_pair")) is None


def test_near_rock_distance_measures_to_rocks_only():
    """The distance that decides the don't-care zone is to the nearest truth rock, not to
    an outcrop."""
    from types import SimpleNamespace

    from roi_detector.training import near_rock_distance

    rois = empty_records(2)
    rois["x"], rois["y"], rois["label"] = [0.0, 10.0], [0.0, 0.0], [ROCK, OUTCROP]
    d = near_rock_distance(np.array([[9.0, 0.0], [3.0, 4.0]]), SimpleNamespace(rois=rois))
    assert np.allclose(d, [9.0, 5.0])
    none = SimpleNamespace(rois=rois[rois["label"] == OUTCROP])
    assert np.isinf(near_rock_distance(np.array([[0.0, 0.0]]), none)).all()


def test_a_finer_camera_is_resampled_to_the_working_resolution_and_stays_calibrated():
    """A pair whose focal length is finer than ``working_fx_px`` is resampled to it, its
    K and P scaled so that a point of the scene projects where it lands in the resampled
    image and the baseline is kept; one at or under it comes back as it is."""
    from roi_detector.inputs import StereoFrame
    from roi_detector.rover_pipeline import at_working_resolution

    w, h, fx = 1024, 768, 887.0
    k = [fx, 0, 511.5, 0, fx, 383.5, 0, 0, 1]
    p = [fx, 0, 511.5, -fx * 0.3, 0, fx, 383.5, 0, 0, 0, 1, 0]
    left = np.zeros((h, w, 3), np.uint8)
    cam = StereoCamera.from_camera_info(k, p, w, h, EXTRINSIC)
    ground = np.array([[6.0, 0.8, 0.0]])
    (u, v), = cam.project_base(ground)[0]
    left[int(v) - 8:int(v) + 8, int(u) - 8:int(u) + 8] = 255  # a bright square there
    frame = StereoFrame(1, left, left.copy(), np.array(k), np.array(p))

    out = at_working_resolution(frame, 457.0)
    assert out.left.shape[1] == round(w * 457.0 / fx) and out.right.shape == out.left.shape
    small = StereoCamera.from_camera_info(out.left_k, out.right_p, out.left.shape[1],
                                          out.left.shape[0], EXTRINSIC)
    assert small.fx == pytest.approx(457.0, rel=2e-3)
    assert small.baseline_m == pytest.approx(0.3)
    # The point projects where the scaled image puts its pixel ...
    sx, sy = out.left.shape[1] / w, out.left.shape[0] / h
    (us, vs), = small.project_base(ground)[0]
    assert us == pytest.approx((u + 0.5) * sx - 0.5, abs=1e-6)
    assert vs == pytest.approx((v + 0.5) * sy - 0.5, abs=1e-6)
    # ... and where the square drawn around it lands (intensity centroid).
    wgt = out.left[..., 0].astype(float)
    ys, xs = np.mgrid[:wgt.shape[0], :wgt.shape[1]]
    cx, cy = (wgt * xs).sum() / wgt.sum(), (wgt * ys).sum() / wgt.sum()
    assert cx == pytest.approx((int(u) - 0.5 + 0.5) * sx - 0.5, abs=0.05)
    assert cy == pytest.approx((int(v) - 0.5 + 0.5) * sy - 0.5, abs=0.05)
    # The simulator's own camera (457 px) and a switched-off working resolution: untouched.
    assert at_working_resolution(frame, 0.0) is frame
    assert at_working_resolution(frame, 900.0) is frame


def test_a_model_trained_at_another_working_resolution_is_refused(tmp_path):
    """The rover model records the working resolution its features were taken at; a
    detector at another one refuses it, naming both, and one that records none (models
    before the field) is taken as trained at the default."""
    from roi_detector.rover_classifier import RoverClassifier, save_rover_model
    from roi_detector.rover_pipeline import RoverConfig, RoverDetector

    clfs = _two_rock_rovers(np.random.default_rng(3))
    for fx, ok in ((None, True), (460.0, True), (887.0, False)):
        path = tmp_path / f"m{fx}.npz"
        save_rover_model(path, clfs, {"method": "elevation_map"} |
                         ({} if fx is None else {"working_fx_px": fx}))
        model = RoverClassifier.load(path)
        if ok:
            RoverDetector(EXTRINSIC, model, RoverConfig())
        else:
            with pytest.raises(ValueError, match=r"m887\.0\.npz: trained at a working "
                               r"resolution of 887 px .* works at 460 px"):
                RoverDetector(EXTRINSIC, model, RoverConfig())
            RoverDetector(EXTRINSIC, model, RoverConfig(working_fx_px=887.0))


def test_the_map_outcrops_outcrop_rover_is_fitted_loaded_and_checked_against_the_rule(
        tmp_path):
    """``roi_detector train`` fits the Outcrop Rover on the map's outcrop regions (none
    when they are one class) and records the outcrop rule of its candidates; the map gets
    it, a model without one is refused by name, and a model trained on another rule's
    candidates is refused, naming the rule."""
    from roi_detector.elevation_map import MAP_OUTCROP_FEATURES, MAP_OUTCROP_RULE
    from roi_detector.rover_classifier import (
        MAP_OUTCROP_CLASSIFIER,
        RoverClassifier,
        save_rover_model,
    )
    from roi_detector.rover_pipeline import DriveMapper, RoverConfig, check_model
    from roi_detector.training import fit_outcrop_rover

    rng = np.random.default_rng(4)
    y = np.r_[np.ones(15), np.zeros(25)].astype(np.uint8)
    x = rng.normal(size=(40, len(MAP_OUTCROP_FEATURES))) + y[:, None] * 3.0
    assert fit_outcrop_rover(x[15:], y[15:]) is None  # no outcrop among them
    rover = fit_outcrop_rover(x, y)
    assert rover.name == MAP_OUTCROP_CLASSIFIER
    assert (rover.predict_proba(x) > 0.5).tolist() == (y == 1).tolist()
    clfs = _two_rock_rovers(rng, outcrops=False)
    cfg = RoverConfig()
    # Without it: refused by name.
    rocks_only = tmp_path / "rocks.npz"
    save_rover_model(rocks_only, clfs, {"method": "elevation_map"})
    with pytest.raises(ValueError, match=r"rocks\.npz: no map outcrops' Outcrop Rover"):
        check_model(RoverClassifier.load(rocks_only), cfg)
    path = tmp_path / "all.npz"
    save_rover_model(path, {**clfs, MAP_OUTCROP_CLASSIFIER: rover}, {
        "method": "elevation_map", "map_outcrop_rule": MAP_OUTCROP_RULE})
    model = RoverClassifier.load(path)
    assert model.map_outcrops
    check_model(model, cfg)
    assert DriveMapper(cfg, classifier=model).map.outcrop_classifier is not None
    for other in ({**MAP_OUTCROP_RULE, "outcrop_max_saturation": 0.5},
                  {**MAP_OUTCROP_RULE, "outcrop_soil_ratio": 0.75}):
        odd = tmp_path / "odd.npz"
        save_rover_model(odd, {**clfs, MAP_OUTCROP_CLASSIFIER: rover}, {
            "method": "elevation_map", "map_outcrop_rule": other})
        with pytest.raises(ValueError, match=r"odd\.npz: its Outcrop Rover was trained on "
                           r"the candidates of another outcrop rule"):
            check_model(RoverClassifier.load(odd), cfg)


def test_drive_samples_are_kept_per_bag_and_retaken_under_other_settings(tmp_path,
                                                                         monkeypatch):
    """``roi_detector train --cache``: a drive's samples are taken once per settings and
    read back as they were written; other settings (or a damaged file) take them again."""
    import roi_detector.training as training

    calls = []

    def fake(bag, log, working_fx_px):
        calls.append((bag, working_fx_px))
        return {"x": np.full((2, 3), len(calls), np.float32), "y": np.array([1, 0], np.uint8),
                "outcrop_y": np.zeros(0, np.uint8)}

    monkeypatch.setattr(training, "far_rock_samples", fake)
    cache = tmp_path / "cache"
    first = training.drive_samples("bags/s1", cache=cache)
    again = training.drive_samples("bags/s1", cache=cache)
    assert len(calls) == 1 and (again["x"] == first["x"]).all() and set(again) == set(first)
    other = training.drive_samples("bags/s1", working_fx_px=887.0, cache=cache)
    assert len(calls) == 2 and other["x"][0, 0] == 2.0
    (cache / "s1.npz").write_bytes(b"not a cache")
    logged = []
    training.drive_samples("bags/s1", cache=cache, log=logged.append)
    assert len(calls) == 3 and "s1.npz: not a samples cache" in logged[0]
    training.drive_samples("bags/s1")  # no cache: always taken
    assert len(calls) == 4


def test_frame_maker_rectifies_by_camera_info_and_takes_p():
    import cv2
    from sensor_msgs.msg import CameraInfo

    from roi_detector.inputs import FrameMaker

    rng = np.random.default_rng(2)
    img = cv2.GaussianBlur(rng.integers(0, 256, (60, 80, 3), dtype=np.uint8), (0, 0), 1.5)
    msg = CompressedImage(format="png", data=cv2.imencode(".png", img)[1].tobytes())

    def info(d=(), model="plumb_bob", tx=0.0):
        return CameraInfo(width=80, height=60, distortion_model=model, d=list(d),
                          k=[70.0, 0, 40, 0, 70, 30, 0, 0, 1], r=list(np.eye(3).ravel()),
                          p=[72.0, 0, 41, tx, 0, 72, 31, 0, 0, 0, 1, 0])

    lines, logs = [], []
    maker = FrameMaker(BadInput(lines.append), log=logs.append)
    assert not maker.ready
    maker.info = {"left": info(), "right": info(tx=-14.4)}
    frame = maker.frame(1, msg, msg)
    # K and P differ: the images are remapped to P's geometry, and P gives the intrinsics.
    np.testing.assert_array_equal(frame.left_k, [72.0, 0, 41, 0, 72, 31, 0, 0, 1])
    assert frame.right_p[3] == -14.4 and not np.array_equal(frame.left, img)
    assert len(logs) == 2
    # DESIGN.md's CameraInfo (K = P, no D): the decoded pixels as they are.
    same = {"left": info(), "right": info(tx=-14.4)}
    for side in same:
        same[side].k = [72.0, 0, 41, 0, 72, 31, 0, 0, 1]
    maker = FrameMaker(BadInput(lines.append), log=logs.append)
    maker.info = same
    np.testing.assert_array_equal(maker.frame(2, msg, msg).left, img)
    assert len(logs) == 2
    # rectify=False reads any image as rectified; a model OpenCV lacks is counted, skipped.
    maker = FrameMaker(BadInput(lines.append), rectify=False)
    maker.info = {"left": info(d=(0.1,), model="kannala"), "right": info(tx=-14.4)}
    np.testing.assert_array_equal(maker.frame(3, msg, msg).left, img)
    bad = BadInput(lines.append)
    maker = FrameMaker(bad)
    maker.info = {"left": info(d=(0.1,), model="kannala"), "right": info(tx=-14.4)}
    assert maker.frame(4, msg, msg) is None and bad.counts == {"bad camera_info": 1}
    assert "distortion model 'kannala'" in lines[-1]


def test_a_monochrome_pair_gives_the_map_no_outcrop_colour():
    """A grey pair (a monochrome navigation camera's) has no colour to tell an outcrop
    by: the map gets its heights and values, a soil's saturation, and the skip is
    counted; a colour pair keeps its appearance."""
    from roi_detector.elevation_map import is_monochrome
    from roi_detector.inputs import StereoFrame
    from roi_detector.rover_pipeline import RoverConfig, RoverDetector

    w, h, fx = 640, 480, 457.0
    k = [fx, 0, 319.5, 0, fx, 239.5, 0, 0, 1]
    p = [fx, 0, 319.5, -fx * 0.2, 0, fx, 239.5, 0, 0, 0, 1, 0]
    rng = np.random.default_rng(4)
    grey = rng.integers(0, 256, (h, w), dtype=np.uint8)
    mono = np.repeat(grey[:, :, None], 3, axis=2)
    colour = mono.copy()
    colour[..., 2] = np.clip(colour[..., 2].astype(int) + 30, 0, 255)
    assert is_monochrome(mono) and not is_monochrome(colour)
    seen = []
    detector = RoverDetector(EXTRINSIC, None, RoverConfig(),
                             lambda kind, detail: seen.append(kind))
    obs = detector.observe(StereoFrame(1, mono, mono.copy(), np.array(k), np.array(p)))
    # The value is kept (the rocks' dark seeds), the saturation is the soil's: no cell
    # passes the outcrop colour test.
    assert np.all(obs.appearance[..., 0] == 1.0) and np.ptp(obs.appearance[..., 1]) > 0
    assert seen == ["monochrome images"]
    obs = detector.observe(StereoFrame(2, colour, colour.copy(), np.array(k), np.array(p)))
    assert np.ptp(obs.appearance[..., 0]) > 0 and seen == ["monochrome images"]
