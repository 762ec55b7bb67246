"""atacama_sim: the bag's geometry is right (tiny preset with one stop and its panorama,
generated once per module)."""

from __future__ import annotations

import json
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
import rasterio
import yaml
from scipy.spatial.transform import Rotation

from atacama_sim.camera import StereoRig
from atacama_sim.config import CONSTANT_FIELDS, constant_value, make_config
from atacama_sim.generate import generate
from atacama_sim.panorama import panorama_stop_s
from atacama_sim.renderer import SceneRenderer
from atacama_sim.rocks import INST, generate_rocks
from atacama_sim.route import drive, plan_route
from atacama_sim.sky import Sky
from atacama_sim.terrain import Terrain
from atacama_sim.texture import MATERIAL_RGB
from atacama_sim.truth import write_truth_rois
from atacama_sim.world import World, map_origin

SEED = 3
#: The test bag's lens: MER's 45 deg Navcam (fx B = 154.5 px m), the bench these image
#: formation tests were written on. At the default 70 deg lens (fx B = 91.4 px m) the
#: raw SGBM of tiny's rocks reads the ground around a rock 0.11-0.16 m low and a rock's
#: top 0.29 m low at 8 m: the rock's outline mixes with the ground behind it over more
#: of its fewer pixels (the elevation map drops those points, docs/roi_detector.md). The
#: other packages' tests run the default lens.
LENS = {"camera": {"hfov_deg": 45.0}}
#: The test bag: the lens, and one stop half way, so the rover takes one panorama (at the
#: 45 deg lens with 5 deg overlap, 9 positions over 360 deg, 12 deg down: its 35 deg tall
#: view sees the ground from 2.7 m to the horizon).
TINY = {**LENS, "route": {"stop_every_m": (6.0, 6.0)},
        "mast": {"overlap_deg": 5.0, "tilt_deg": 12.0}}


def _start_ns(cfg) -> int:
    """The bag's first stamp: the site's local solar time of ``cfg.sun`` (atacama_sim.sky)."""
    return Sky.from_config(cfg, map_origin(cfg.site.crs, cfg.site.site_lonlat)).start_ns


#: The test bag's first stamp, ns (POSIX UTC).
START_NS = _start_ns(make_config("tiny", SEED, TINY))


@pytest.fixture(scope="module")
def bag(tmp_path_factory: pytest.TempPathFactory) -> dict:
    out = tmp_path_factory.mktemp("bags") / "tiny"
    cfg = make_config("tiny", SEED, TINY)
    stats = generate(cfg, out, progress=False, keep_aux=True)
    return {"dir": out, "cfg": cfg, "stats": stats}


@pytest.fixture(scope="module")
def messages(bag: dict) -> dict:
    """Every message of the bag, decoded with rosbags, by topic: [(t_ns, msg)]."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    out: dict[str, list] = {}
    with AnyReader([bag["dir"] / "rosbag"],
                   default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, t, raw in reader.messages():
            out.setdefault(conn.topic, []).append((t, reader.deserialize(raw, conn.msgtype)))
    return out


def _rig_from_bag(bag_dir: Path, info) -> tuple[StereoRig, np.ndarray, np.ndarray]:
    """Camera model built only from the bag's CameraInfo and rover.yaml."""
    params = yaml.safe_load((bag_dir / "rover.yaml").read_text())["/**"]["ros__parameters"]
    pose = np.array(params["base_to_left_camera"])
    r_bc = Rotation.from_quat(pose[3:]).as_matrix()
    k = np.array(info.k).reshape(3, 3)
    rig = StereoRig(int(info.width), int(info.height), k[0, 0], k[1, 1], k[0, 2], k[1, 2],
                    params["baseline_m"], r_bc, pose[:3])
    return rig, r_bc, pose[:3]


class _Poser:
    """The left camera in base_link at an image stamp, from the bag alone: rover.yaml's
    mast at the ``/joint_states`` sample of that stamp."""

    def __init__(self, bag_dir: Path, messages: dict) -> None:
        from roi_network.mast import MastKinematics
        from roi_network.params import node_parameters

        self.kin = MastKinematics.from_params(
            node_parameters(yaml.safe_load((bag_dir / "rover.yaml").read_text()), "any"))
        self.angles = {t: tuple(m.position) for t, m in messages["/joint_states"]}

    def joints(self, t: float) -> tuple[float, float]:
        return self.angles[START_NS + round(t * 1e9)]

    def base_T_left(self, t: float) -> np.ndarray:  # noqa: N802
        return self.kin.base_T_left(*self.joints(t))


def _poser(bag_dir: Path, messages: dict) -> _Poser:
    return _Poser(bag_dir, messages)


def _b_t_l(poser: _Poser, t: float) -> np.ndarray:
    """The left camera in base_link at ``t`` seconds after the bag start, from the bag."""
    return poser.base_T_left(t)


def _pano_stamps(messages: dict) -> list[int]:
    """Image stamps of the panorama: between the first and last joint sample away from
    pan 0 (one of its views may look straight ahead)."""
    away = [t for t, m in messages["/joint_states"] if abs(m.position[0]) > 1e-9]
    return [t for t, _ in messages["/stereo/left/image_raw/compressed"]
            if away and away[0] <= t <= away[-1]]


def _tum(bag_dir: Path) -> np.ndarray:
    return np.loadtxt(bag_dir / "truth/trajectory.tum")


def _pose_at(tum: np.ndarray, t: float) -> tuple[np.ndarray, np.ndarray]:
    """Truth pose at ``t`` seconds after the bag start (TUM stamps are bag time)."""
    t = START_NS * 1e-9 + t
    i = int(np.argmin(np.abs(tum[:, 0] - t)))
    assert abs(tum[i, 0] - t) < 1e-4, "camera stamps are ground-truth stamps"
    return Rotation.from_quat(tum[i, 4:8]).as_matrix(), tum[i, 1:4]


def _decode(msg) -> np.ndarray:
    return cv2.imdecode(np.asarray(msg.data, np.uint8), cv2.IMREAD_COLOR)


# -- bag contents -------------------------------------------------------------------------
def test_bag_layout_and_topics(bag: dict, messages: dict) -> None:
    d = bag["dir"]
    for name in ("rosbag/metadata.yaml", "orbital.tif", "dtm.tif", "rover.yaml", "world.yaml",
                 "truth/rois.geojson", "truth/trajectory.tum", "contact_sheet.png"):
        assert (d / name).exists(), name
    n = bag["stats"]["route"]["stereo_frames"]
    assert n >= 20
    for topic in ("/stereo/left/image_raw/compressed", "/stereo/right/image_raw/compressed",
                  "/stereo/left/camera_info", "/stereo/right/camera_info"):
        assert len(messages[topic]) == n
    imu = messages["/imu/data"]
    dt = np.diff([t for t, _ in imu]) / 1e9
    assert np.allclose(dt, 1 / bag["cfg"].imu.rate_hz, atol=1e-6)
    for topic, msgs in messages.items():
        for t, m in msgs[:50]:
            if topic == "/tf_static":
                m = m.transforms[0]
            if topic == "/robot_description":
                continue  # a String: no header
            assert m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == t, topic
    assert messages["/ground_truth/pose"][0][1].header.frame_id == "map"
    left = messages["/stereo/left/camera_info"][0][1]
    right = messages["/stereo/right/camera_info"][0][1]
    assert right.p[3] == pytest.approx(-left.p[0] * bag["cfg"].camera.baseline_m)
    assert left.header.frame_id == "left_camera_optical"
    img = _decode(messages["/stereo/left/image_raw/compressed"][0][1])
    assert img.shape == (480, 640, 3)


def test_qos_recorded(bag: dict) -> None:
    meta = yaml.safe_load((bag["dir"] / "rosbag/metadata.yaml").read_text())
    topics = {t["topic_metadata"]["name"]: t["topic_metadata"]
              for t in meta["rosbag2_bagfile_information"]["topics_with_message_count"]}
    qos = topics["/imu/data"]["offered_qos_profiles"]
    text = qos if isinstance(qos, str) else json.dumps(qos)
    assert "reliability: 2" in text or "best_effort" in text or '"reliability": 2' in text
    gt = topics["/ground_truth/pose"]["offered_qos_profiles"]
    text = gt if isinstance(gt, str) else json.dumps(gt)
    assert "reliability: 1" in text or "reliable" in text or '"reliability": 1' in text


def test_bag_reads_with_mcap_ros2_decoder(bag: dict) -> None:
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    files = list((bag["dir"] / "rosbag").glob("*.mcap"))
    assert len(files) == 1
    counts: dict[str, int] = {}
    with files[0].open("rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        for _schema, channel, _message, decoded in reader.iter_decoded_messages():
            counts[channel.topic] = counts.get(channel.topic, 0) + 1
            if channel.topic == "/stereo/right/camera_info":
                assert decoded.p[3] < 0
    assert counts["/stereo/left/image_raw/compressed"] == bag["stats"]["route"]["stereo_frames"]
    assert counts["/imu/data"] > 1000


# -- camera geometry ----------------------------------------------------------------------
def _rock_vertices(world: World, inst: np.ndarray) -> np.ndarray:
    t = world.rocks.templates[int(inst[INST["template"]])]
    p = t.positions.astype(np.float64) * inst[[INST["sx"], INST["sy"], INST["sz"]]]
    c, s = np.cos(inst[INST["yaw"]]), np.sin(inst[INST["yaw"]])
    rz = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return p @ rz.T + inst[[INST["x"], INST["y"], INST["z"]]]


def _drawn_dist(mask: np.ndarray, uv: np.ndarray) -> float:
    """Distance (px) from ``uv`` to the nearest pixel centre the renderer drew in ``mask``."""
    rows, cols = np.nonzero(mask)
    return float(np.min(np.hypot(cols - uv[0], rows - uv[1])))


def test_truth_points_project_onto_rendered_pixels(bag: dict, messages: dict) -> None:
    """Extreme points of the truth rock meshes (top, leftmost, rightmost vertex; CPU
    geometry), projected with the bag's CameraInfo, rover.yaml (the mast at the joint
    states' angles) and truth pose, land on the rock's rendered pixels within 1 px (unless
    something nearer hides them), in the drive frames and the panorama's."""
    world = bag["stats"]["_world"]
    tum = _tum(bag["dir"])
    rig, _, _ = _rig_from_bag(bag["dir"], messages["/stereo/left/camera_info"][0][1])
    poser = _poser(bag["dir"], messages)
    dists = []
    for a in bag["stats"]["_aux"]:
        r_wb, p_wb = _pose_at(tum, a["t"])
        r_wc, c_w = rig.camera_pose(r_wb, p_wb, base_T_left=_b_t_l(poser, a["t"]))
        for inst in world.rocks.majors:
            mask = a["label"] == int(inst[INST["label"]])
            if mask.sum() < 100:
                continue
            verts = _rock_vertices(world, inst)
            # vertices at ground level are as often hidden by the ground as not
            verts = verts[verts[:, 2] > world.terrain.height(verts[:, 0], verts[:, 1]) + 0.05]
            uv, z = rig.project(r_wc, c_w, verts)
            if len(verts) == 0 or np.any(z <= 0.3):
                continue
            for k in (np.argmin(uv[:, 1]), np.argmin(uv[:, 0]), np.argmax(uv[:, 0])):
                u, v = np.rint(uv[k]).astype(int)
                if not (1 <= u < rig.width - 1 and 1 <= v < rig.height - 1):
                    continue
                if a["z"][v, u] < z[k] - 0.05:
                    continue  # hidden by nearer terrain or another rock
                dists.append(_drawn_dist(mask, uv[k]))
    dists = np.array(dists)
    assert len(dists) >= 10, "too few rock extremes in view"
    # Rasterisation samples pixel centres: even exact geometry leaves an extreme point
    # 0-1 px from the nearest drawn centre (median ~0.6), a thin tip up to ~1.1 px; a 1 px
    # error would double that.
    assert np.median(dists) < 0.75, np.round(dists, 2)
    assert np.mean(dists <= 1.25) >= 0.95, np.round(dists, 2)


def test_rendered_depth_lies_on_terrain(bag: dict, messages: dict) -> None:
    """Ground pixels back-projected with the bag's camera model (rover.yaml's mast at the
    joint states' angles) and truth pose at the rendered depth lie on the truth terrain
    surface, in a drive frame and in every panorama view."""
    world = bag["stats"]["_world"]
    tum = _tum(bag["dir"])
    rig, _, _ = _rig_from_bag(bag["dir"], messages["/stereo/left/camera_info"][0][1])
    poser = _poser(bag["dir"], messages)
    aux = bag["stats"]["_aux"]
    pano = set(_pano_stamps(messages))
    views = [a for a in aux if START_NS + round(a["t"] * 1e9) in pano]
    assert len(views) == 9
    for a in [aux[len(aux) // 4], *views]:
        r_wb, p_wb = _pose_at(tum, a["t"])
        r_wc, c_w = rig.camera_pose(r_wb, p_wb, base_T_left=_b_t_l(poser, a["t"]))
        vv, uu = np.mgrid[240:480:8, 0:640:8]
        z = a["z"][vv, uu]
        ok = (a["label"][vv, uu] == 0) & (z > 0) & (z < 12)
        ray = np.stack([(uu - rig.cx) / rig.fx, (vv - rig.cy) / rig.fy, np.ones_like(z)], -1)
        pts = (ray * z[..., None])[ok] @ r_wc.T + c_w
        dz = pts[:, 2] - world.terrain.height(pts[:, 0], pts[:, 1])
        # clutter rocks are label 0 too: they stick up; the ground itself is within 3 cm
        assert np.median(np.abs(dz)) < 0.01, a["t"]
        assert np.mean(np.abs(dz) < 0.03) > 0.85, a["t"]


def _sgbm(left: np.ndarray, right: np.ndarray) -> np.ndarray:
    sgbm = cv2.StereoSGBM_create(minDisparity=0, numDisparities=96, blockSize=5,
                                 P1=8 * 3 * 25, P2=32 * 3 * 25, uniquenessRatio=5,
                                 mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)
    gl, gr = (cv2.cvtColor(x, cv2.COLOR_BGR2GRAY) for x in (left, right))
    return sgbm.compute(gl, gr).astype(np.float32) / 16.0


def _frames_with_rocks(bag: dict, messages: dict, min_px: int = 1500) -> list:
    out = []
    lefts = messages["/stereo/left/image_raw/compressed"]
    rights = messages["/stereo/right/image_raw/compressed"]
    for i, a in enumerate(bag["stats"]["_aux"]):
        ids, cnt = np.unique(a["label"][a["label"] > 0], return_counts=True)
        for rid, c in zip(ids, cnt, strict=True):
            if c >= min_px:
                out.append((i, int(rid), a, lefts[i][1], rights[i][1]))
    return out


def test_stereo_disparity_agrees_with_depth(bag: dict, messages: dict) -> None:
    fx, b = None, bag["cfg"].camera.baseline_m
    info = messages["/stereo/left/camera_info"][0][1]
    fx = info.k[0]
    checked = 0
    for _i, rid, a, lm, rm in _frames_with_rocks(bag, messages)[::3][:8]:
        disp = _sgbm(_decode(lm), _decode(rm))
        mask = cv2.erode((a["label"] == rid).astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
        mask &= disp > 0
        if mask.sum() < 300:
            continue
        expected = fx * b / a["z"][mask]
        err = disp[mask] - expected
        assert np.median(np.abs(err)) < 0.5, f"rock {rid}: median |d - fB/Z| too large"
        checked += 1
    assert checked >= 2


def _stereo_points(m: np.ndarray, disp: np.ndarray, fxb: float, rig: StereoRig,
                   r_wc: np.ndarray, c_w: np.ndarray) -> np.ndarray:
    """Map-frame points (N, 3) of the pixels ``m`` triangulated from disparity alone."""
    vv, uu = np.mgrid[0:rig.height, 0:rig.width]
    m = m & (disp > 1)
    z = fxb / disp[m]
    ray = np.stack([(uu[m] - rig.cx) / rig.fx, (vv[m] - rig.cy) / rig.fy,
                    np.ones(m.sum())], -1)
    return (ray * z[:, None]) @ r_wc.T + c_w


def test_rock_is_raised_in_stereo(bag: dict, messages: dict) -> None:
    """Stereo-only heights (SGBM + CameraInfo + truth pose): a rock stands above the
    ground around it by a good part of its truth height."""
    world = bag["stats"]["_world"]
    cat = world.rocks.catalogue
    tum = _tum(bag["dir"])
    info = messages["/stereo/left/camera_info"][0][1]
    rig, _, _ = _rig_from_bag(bag["dir"], info)
    fxb = -messages["/stereo/right/camera_info"][0][1].p[3]
    # Drive views only: a panorama view (12 deg down) sees the far horizon behind a rock's
    # top, where SGBM's blocks give the rim the far disparity and lift it up to 0.2 m (a
    # stereo edge effect; the projection and depth tests cover those views' geometry).
    pano = set(_pano_stamps(messages))
    checked = 0
    for _i, rid, a, lm, rm in _frames_with_rocks(bag, messages, 1200):
        row = cat[cat["id"] == rid][0]
        if row["label"] != 1 or checked >= 4 or np.median(a["z"][a["label"] == rid]) > 15:
            continue
        if START_NS + round(a["t"] * 1e9) in pano:
            continue
        disp = _sgbm(_decode(lm), _decode(rm))
        rock = (a["label"] == rid)
        ring = cv2.dilate(rock.astype(np.uint8), np.ones((31, 31), np.uint8)) > 0
        ring &= ~(cv2.dilate(rock.astype(np.uint8), np.ones((9, 9), np.uint8)) > 0)
        ring &= a["label"] == 0
        r_wb, p_wb = _pose_at(tum, a["t"])
        r_wc, c_w = rig.camera_pose(r_wb, p_wb, base_T_left=a["base_T_left"])
        pr = _stereo_points(rock, disp, fxb, rig, r_wc, c_w)
        pg = _stereo_points(ring, disp, fxb, rig, r_wc, c_w)
        if len(pr) < 200 or len(pg) < 200:
            continue
        hr = pr[:, 2]
        # height above the truth ground surface under each stereo point
        above_rock = pr[:, 2] - world.terrain.height(pr[:, 0], pr[:, 1])
        above_ground = pg[:, 2] - world.terrain.height(pg[:, 0], pg[:, 1])
        raised = np.percentile(above_rock, 95) - np.median(above_ground)
        assert abs(np.median(above_ground)) < 0.1, "stereo ground off the terrain"
        assert raised > 0.5 * row["height_m"], f"rock {rid}: raised {raised:.2f} m"
        # stereo top vs the rendered (truth) top of the visible part
        vv, uu = np.nonzero(rock)
        zr = a["z"][rock]
        ray = np.stack([(uu - rig.cx) / rig.fx, (vv - rig.cy) / rig.fy, np.ones(len(zr))], -1)
        top = np.percentile(((ray * zr[:, None]) @ r_wc.T + c_w)[:, 2], 99)
        assert abs(np.percentile(hr, 99) - top) < 0.05 + 0.01 * np.median(zr)
        checked += 1
    assert checked >= 1


def test_images_carry_texture(messages: dict) -> None:
    orb = cv2.ORB_create(nfeatures=3000)
    counts = []
    for _t, m in messages["/stereo/left/image_raw/compressed"][::5]:
        gray = cv2.cvtColor(_decode(m), cv2.COLOR_BGR2GRAY)
        counts.append(len(orb.detect(gray, None)))
    assert min(counts) >= 300, counts


# -- orbital ------------------------------------------------------------------------------
def test_dtm_lies_under_the_orthoimage_and_the_truth_route(bag: dict) -> None:
    """dtm.tif: the orthoimage's CRS and footprint at 1 m posts, its datum and sigma in the
    tags; read in map coordinates (roi_network.dtm) it gives the truth's z under the route
    within the error it states (and within 5 cm without its stereo error field)."""
    from atacama_sim.orbital import DTM_VERTICAL_SIGMA_M, dtm_heights
    from roi_network.dtm import read_dtm
    from roi_network.geojson import read_geojson

    d = bag["dir"]
    with rasterio.open(d / "orbital.tif") as ortho, rasterio.open(d / "dtm.tif") as dtm:
        assert dtm.crs == ortho.crs and dtm.count == 1 and dtm.dtypes == ("float32",)
        assert dtm.bounds == ortho.bounds
        assert dtm.res == (1.0, 1.0)
        tags = dtm.tags()
        assert "map-frame origin" in tags["VERTICAL_DATUM"]
        assert float(tags["VERTICAL_SIGMA_M"]) == DTM_VERTICAL_SIGMA_M
        assert tags["VERTICAL_UNITS"] == "metre"
    model = read_dtm(d / "dtm.tif", read_geojson(d / "truth/rois.geojson").map_frame)
    tum = _tum(d)
    z, _ = model.height(tum[:, 1], tum[:, 2])
    err = z - tum[:, 3]
    assert np.isfinite(err).all()
    assert 0.05 < np.sqrt(np.mean(err**2)) < 1.5 * DTM_VERTICAL_SIGMA_M
    assert np.abs(err).max() < 4 * DTM_VERTICAL_SIGMA_M
    exact, _ = dtm_heights(bag["stats"]["_world"], error=False)
    post = model.heights.shape[0]
    assert exact.shape == (post, post)
    clean = type(model)(exact.astype(float), model.x0, model.y0, model.posting, 0.0)
    z_clean, _ = clean.height(tum[:, 1], tum[:, 2])
    assert np.abs(z_clean - tum[:, 3]).max() < 0.05


def test_orbital_georeference_matches_truth(bag: dict) -> None:
    d = bag["dir"]
    doc = json.loads((d / "truth/rois.geojson").read_text())
    assert doc["metadata"]["crs"] == "EPSG:32719"
    with rasterio.open(d / "orbital.tif") as src:
        assert src.crs.to_epsg() == 32719
        assert src.transform.a == pytest.approx(0.25)
        transform = src.transform
        img = src.read().mean(axis=0)
    with rasterio.open(d / "truth/orbital_labels.tif") as src:
        labels = src.read(1)
    errs, contrast = [], []
    for feat in doc["features"]:
        rid = feat["properties"]["id"]
        e, n = feat["geometry"]["coordinates"][:2]
        rows, cols = np.nonzero(labels == rid)
        assert len(rows) > 0, f"ROI {rid} not in the orbital image"
        # centroid of the ROI's pixels (pixel centres at +0.5) in CRS coordinates
        x, y = transform @ (cols.mean() + 0.5, rows.mean() + 0.5)
        errs.append(np.hypot(x - e, y - n) / 0.25)
        ring = cv2.dilate((labels == rid).astype(np.uint8), np.ones((7, 7), np.uint8)) > 0
        ring &= labels == 0
        contrast.append(abs(img[labels == rid].mean() - img[ring].mean()))
    errs = np.array(errs)
    assert np.all(errs < 1.0), errs.max()
    assert np.median(contrast) > 8, "ROIs barely visible in the orthoimage"


def test_truth_geojson_contract(bag: dict) -> None:
    from roi_network.geojson import read_geojson

    net = read_geojson(bag["dir"] / "truth/rois.geojson")
    rec = net.records
    assert len(rec) == bag["stats"]["rois"]["total"] > 10
    rocks, outcrops = rec[rec["label"] == 1], rec[rec["label"] == 2]
    assert len(rocks) and np.all((rocks["area_m2"] >= 0.55) & (rocks["area_m2"] <= 6.5))
    assert np.all((rocks["height_m"] >= 0.25) & (rocks["height_m"] <= 2.0))
    if len(outcrops):
        assert np.all((outcrops["area_m2"] >= 7.5) & (outcrops["height_m"] <= 0.3))
    assert np.all(rec["major_m"] >= rec["minor_m"])


# -- IMU, determinism ---------------------------------------------------------------------
def test_imu_consistent_with_motion(bag: dict, messages: dict) -> None:
    imu = messages["/imu/data"]
    acc = np.array([[m.linear_acceleration.x, m.linear_acceleration.y,
                     m.linear_acceleration.z] for _, m in imu])
    gyro = np.array([[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z]
                     for _, m in imu])
    g = bag["cfg"].imu.gravity
    assert np.linalg.norm(acc[:100].mean(axis=0)) == pytest.approx(g, abs=0.1)
    traj = bag["stats"]["_traj"]
    rot = traj.rotations()
    # gravity direction in the body follows pitch and roll
    g_body = rot[:100].inv().apply([0, 0, g]).mean(axis=0)
    assert np.allclose(acc[:100].mean(axis=0), g_body, atol=0.1)
    # integrated gyro yaw follows the truth heading change (bias: <0.01 rad/s * T)
    dt = 1 / bag["cfg"].imu.rate_hz
    r = Rotation.identity()
    for w in gyro:
        r = r * Rotation.from_rotvec(w * dt)
    truth = rot[0].inv() * rot[-1]
    err = (truth.inv() * r).magnitude()
    assert err < 0.01 * traj.t[-1] + 0.05


def test_same_seed_same_truth_and_trajectory(bag: dict, messages: dict,
                                             tmp_path: Path) -> None:
    cfg = make_config("tiny", SEED, TINY)
    world = World.build(cfg)
    route = plan_route(cfg.route, world.rocks.catalogue, world.terrain.extent, cfg.seed)
    traj = drive(route, cfg.route, world.terrain, cfg.imu.rate_hz, cfg.seed,
                 panorama_stop_s(cfg.mast, cfg.camera, cfg.imu.rate_hz))
    write_truth_rois(world.rocks.catalogue, cfg, world.origin, tmp_path / "rois.geojson")
    assert (tmp_path / "rois.geojson").read_bytes() == \
        (bag["dir"] / "truth/rois.geojson").read_bytes()
    tum = _tum(bag["dir"])
    first = bag["stats"]["_traj"]
    assert np.array_equal(traj.p, first.p) and np.array_equal(traj.q, first.q)
    t_rel = tum[:, 0] - START_NS * 1e-9
    i = np.searchsorted(traj.t, t_rel - 1e-4)
    assert np.allclose(traj.t[i], t_rel, atol=1e-4)
    assert np.allclose(traj.p[i], tum[:, 1:4], atol=1e-6)
    gt = messages["/ground_truth/pose"]
    assert len(gt) == len(tum)
    assert gt[5][0] * 1e-9 == pytest.approx(tum[5, 0], abs=1e-4)
    other = make_config("tiny", SEED + 1, LENS)
    rocks = generate_rocks(other.rocks, Terrain.generate(other.terrain, other.site.extent_m,
                                                         other.seed), other.seed)
    assert not np.array_equal(rocks.catalogue["x"], world.rocks.catalogue["x"])


def test_renderer_is_deterministic(bag: dict) -> None:
    world = bag["stats"]["_world"]
    cfg = bag["cfg"]
    rig = StereoRig.from_config(cfg.camera)
    traj = bag["stats"]["_traj"]
    k = int(bag["stats"]["_cam_idx"][3])
    r = SceneRenderer(world.terrain, world.textures, world.rocks, MATERIAL_RGB,
                      (cfg.camera.width, cfg.camera.height))
    try:
        poses = [rig.camera_pose(traj.rotations()[k].as_matrix(), traj.p[k],
                                 base_T_left=bag["stats"]["_aux"][3]["base_T_left"])]
        sun = bag["stats"]["_aux"][3]["sun"]
        a, b = (r.render_views(rig, poses, sun, want_label=True, want_depth=True)[0]
                for _ in range(2))
    finally:
        r.release()
    assert np.array_equal(a["rad"], b["rad"])
    assert np.array_equal(a["z"], bag["stats"]["_aux"][3]["z"])


def test_same_seed_same_bag(bag: dict, tmp_path: Path) -> None:
    """A second, independent run with the seed (production path: no auxiliary outputs)
    writes the same messages, byte for byte, and the same truth and orbital files."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    again = tmp_path / "tiny"
    generate(make_config("tiny", SEED, TINY), again, progress=False)

    def raw(d: Path) -> list[tuple[str, int, bytes]]:
        with AnyReader([d / "rosbag"],
                       default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
            return [(c.topic, t, bytes(r)) for c, t, r in reader.messages()]

    first, second = raw(bag["dir"]), raw(again)
    assert len(first) == len(second) > 0
    diff = [a[:2] for a, b in zip(first, second, strict=True) if a != b]
    assert not diff, f"{len(diff)} messages differ, first: {diff[:3]}"
    for name in ("truth/rois.geojson", "truth/trajectory.tum", "truth/orbital_labels.tif",
                 "orbital.tif", "dtm.tif", "rover.yaml"):
        assert (again / name).read_bytes() == (bag["dir"] / name).read_bytes(), name


def test_orbital_only_writes_the_same_orbital_products_and_no_traverse(
        bag: dict, tmp_path: Path) -> None:
    """``--orbital-only`` (training data for the orbital classifiers) writes the orbital
    image, its labels, the truth and world.yaml of the full run byte for byte, and no
    rosbag or rover.yaml (a stale one from a full run is removed)."""
    out = tmp_path / "tiny_orbital"
    (out / "rosbag").mkdir(parents=True)
    (out / "rover.yaml").write_text("stale")
    cfg = make_config("tiny", SEED, TINY)
    stats = generate(cfg, out, progress=False, orbital_only=True)
    assert not (out / "rosbag").exists() and not (out / "rover.yaml").exists()
    for name in ("truth/rois.geojson", "truth/trajectory.tum", "truth/orbital_labels.tif",
                 "orbital.tif", "dtm.tif"):
        assert (out / name).read_bytes() == (bag["dir"] / name).read_bytes(), name
    assert stats["orbital_only"] is True and stats["messages"] == {}
    derived = yaml.safe_load((out / "world.yaml").read_text())["derived"]
    assert derived["orbital_only"] is True
    assert derived["rois"]["seen_by_left_camera_200px"] is None


def test_set_overrides_a_preset_field_and_refuses_bad_ones(tmp_path: Path, capsys) -> None:
    """``--set SECTION.FIELD=VALUE`` changes that field of the preset (world.yaml records
    it) and ``--orbital-only`` reaches the generator; a malformed item, an unknown field,
    a value of the wrong type or a constant set to another value stops the command with a
    message naming it, before anything is written."""
    from atacama_sim.cli import main, parse_overrides

    assert parse_overrides(["camera.width=1024", "route.rois_target=[3, 8]"]) == \
        {"camera": {"width": 1024}, "route": {"rois_target": [3, 8]}}
    out = tmp_path / "set"
    assert main(["generate", "--preset", "tiny", "--seed", str(SEED), "--orbital-only",
                 "--no-progress", "--out", str(out), "--set", "camera.baseline_m=0.3",
                 "--set", "orbital.gsd_m=0.5"]) == 0
    config = yaml.safe_load((out / "world.yaml").read_text())["config"]
    assert config["camera"]["baseline_m"] == 0.3 and config["orbital"]["gsd_m"] == 0.5
    assert (out / "orbital.tif").is_file() and not (out / "rosbag").exists()
    for item, message in (("camerawidth=5", "expected SECTION.FIELD=VALUE"),
                          ("camera.nope=1", "unknown config field 'nope' in CameraConfig"),
                          ("camera.width=abc", "CameraConfig.width: expected int"),
                          ("camera.jpeg_quality=80",
                           "CameraConfig.jpeg_quality is a constant of the simulator"),
                          ("camera=5", "expected SECTION.FIELD=VALUE")):
        bad = tmp_path / "bad"
        with pytest.raises(SystemExit):
            main(["generate", "--preset", "tiny", "--orbital-only", "--no-progress",
                  "--out", str(bad), "--set", item])
        assert message in capsys.readouterr().err
        assert not bad.exists()


def test_world_yaml_with_constant_keys_loads() -> None:
    """A world.yaml that records the parameters that are now code constants loads when they
    hold the constants' values (the same configuration), and names the key otherwise."""
    cfg = make_config("tiny", SEED, LENS)
    recorded = cfg.to_dict()
    sections = {"TerrainConfig": [recorded["terrain"]], "RockConfig": [recorded["rocks"]],
                "SunConfig": [recorded["orbital"]["sun"]],
                "CameraConfig": [recorded["camera"]], "RouteConfig": [recorded["route"]],
                "OrbitalConfig": [recorded["orbital"]], "WorldConfig": [recorded]}
    assert set(CONSTANT_FIELDS) == set(sections)
    for name, keys in CONSTANT_FIELDS.items():
        for section in sections[name]:
            section.update({k: constant_value(ref) for k, ref in keys.items()})
    assert recorded["camera"]["jpeg_quality"] == 93
    assert recorded["albedo"]["soil_rgb"] == [0.56, 0.45, 0.35]
    overrides = {k: v for k, v in recorded.items() if k not in ("preset", "seed")}
    assert make_config("tiny", SEED, overrides) == cfg
    for section, key, value, named in (
            ("camera", "gamma", 0.5, "CameraConfig.gamma"),
            ("albedo", "soil_rgb", [0.5, 0.4, 0.3], "WorldConfig.albedo.soil_rgb")):
        with pytest.raises(ValueError, match=re.escape(named)):
            make_config("tiny", SEED, {section: {key: value}})
    with pytest.raises(KeyError, match=re.escape("'nope' in WorldConfig.albedo")):
        make_config("tiny", SEED, {"albedo": {"nope": 1}})


# -- the mast: drive pose, joint states, panoramas, frame tree ----------------------------
def _fixed_camera(cfg) -> tuple[np.ndarray, np.ndarray]:
    """The camera before the mast: 20 deg down, image right = rover right, at
    (mast_x_m, baseline / 2, mast_height_m)."""
    th = np.radians(cfg.camera.tilt_deg)
    z = np.array([np.cos(th), 0.0, -np.sin(th)])
    x = np.array([0.0, -1.0, 0.0])
    r = np.column_stack([x, np.cross(z, x), z])
    return r, np.array([cfg.camera.mast_x_m, cfg.camera.baseline_m / 2,
                        cfg.camera.mast_height_m])


def _rover_params(bag_dir: Path) -> dict:
    from roi_network.params import node_parameters

    return node_parameters(yaml.safe_load((bag_dir / "rover.yaml").read_text()), "vo")


def test_drive_pose_is_the_fixed_camera(bag: dict, messages: dict) -> None:
    """At the drive angles the mast puts the camera exactly where the fixed camera was;
    rover.yaml's base_to_*_camera are that pose, and every frame at the drive angles was
    rendered from it."""
    from atacama_sim.camera import drive_angles, mast_kinematics
    from roi_network.mast import pose_matrix

    cfg = bag["cfg"]
    r, t = _fixed_camera(cfg)
    m = mast_kinematics(cfg.camera).base_T_left(*drive_angles(cfg.camera))
    np.testing.assert_allclose(m[:3, :3], r, atol=1e-12)
    np.testing.assert_allclose(m[:3, 3], t, atol=1e-12)
    params = _rover_params(bag["dir"])
    left = pose_matrix(params["base_to_left_camera"], "left")
    right = pose_matrix(params["base_to_right_camera"], "right")
    np.testing.assert_allclose(left[:3, :3], r, atol=1e-9)
    np.testing.assert_allclose(left[:3, 3], t, atol=1e-9)
    np.testing.assert_allclose(right[:3, 3], t - [0, cfg.camera.baseline_m, 0], atol=1e-9)
    poser = _poser(bag["dir"], messages)
    at_drive = 0
    for a in bag["stats"]["_aux"]:
        if np.allclose(poser.joints(a["t"]), drive_angles(cfg.camera), atol=1e-12):
            np.testing.assert_allclose(a["base_T_left"], m, atol=1e-12)
            at_drive += 1
    assert at_drive >= len(bag["stats"]["_aux"]) - 9 > 20


def test_joint_states_at_every_image_and_the_panorama_spans_the_circle(
        bag: dict, messages: dict) -> None:
    """``/joint_states``: 10 Hz, and a sample at every stereo stamp written before its
    images, with the mast settled there; the panorama's pans cover 360 deg with overlap;
    no drive-pose frame is taken while the mast is away."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    cfg = bag["cfg"]
    js = messages["/joint_states"]
    assert all(list(m.name) == ["mast_pan", "mast_tilt"] and m.header.frame_id == ""
               for _, m in js)
    stamps = np.array([t for t, _ in js])
    assert np.all(np.diff(stamps) > 0) and np.max(np.diff(stamps)) <= 100_000_000
    by_t = {t: m for t, m in js}
    order: dict[int, list[str]] = {}
    with AnyReader([bag["dir"] / "rosbag"],
                   default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        for conn, t, _raw in reader.messages():
            order.setdefault(t, []).append(conn.topic)
    pans, drive = [], (0.0, np.radians(cfg.camera.tilt_deg))
    pano = set(_pano_stamps(messages))
    for t, _ in messages["/stereo/left/image_raw/compressed"]:
        m = by_t[t]  # a sample at exactly the image stamp ...
        topics = order[t]  # ... written before the images
        assert topics.index("/joint_states") < topics.index(
            "/stereo/left/image_raw/compressed")
        assert np.allclose(m.velocity, 0.0), "a pair taken while the mast moves"
        if t in pano:
            assert m.position[1] == pytest.approx(np.radians(cfg.mast.tilt_deg))
            pans.append(float(m.position[0]))
        else:
            assert np.allclose(m.position, drive, atol=1e-12)
    assert len(pans) == 9
    step = np.diff(np.degrees(pans))
    assert np.allclose(step, 40.0) and np.all(step < cfg.camera.hfov_deg)
    covered = np.degrees(pans[-1] - pans[0]) + cfg.camera.hfov_deg
    assert covered >= 360.0
    assert bag["stats"]["panoramas"]["count"] == 1
    derived = yaml.safe_load((bag["dir"] / "world.yaml").read_text())["derived"]
    assert derived["panoramas"]["positions_per_panorama"] == 9
    assert derived["panoramas"]["mast_busy_s"] > 0


def test_truth_rock_beside_the_route_is_in_a_panorama_view(bag: dict, messages: dict) -> None:
    """Truth rocks beside the stop, out of the forward view, project with the bag's camera
    model (rover.yaml's mast at the joint states' angles) onto their rendered pixels in a
    panorama view."""
    world = bag["stats"]["_world"]
    cat = world.rocks.catalogue
    tum = _tum(bag["dir"])
    rig, _, _ = _rig_from_bag(bag["dir"], messages["/stereo/left/camera_info"][0][1])
    poser = _poser(bag["dir"], messages)
    pano = set(_pano_stamps(messages))
    views = [a for a in bag["stats"]["_aux"] if START_NS + round(a["t"] * 1e9) in pano]
    assert len(views) == 9
    r_wb, p_wb = _pose_at(tum, views[0]["t"])
    heading = r_wb[:2, 0]
    checked = 0
    for row in cat[cat["label"] == 1]:
        d = np.array([row["x"], row["y"]]) - p_wb[:2]
        bearing = np.degrees(np.arccos(np.dot(d, heading) / np.linalg.norm(d)))
        if not (2.0 < np.linalg.norm(d) < 15.0 and bearing > 45.0):
            continue  # beside or behind the stop, out of the forward camera's view
        centre = np.array([[row["x"], row["y"], row["z"] + row["height_m"] / 2]])
        for a in views:
            r_wc, c_w = rig.camera_pose(r_wb, p_wb, base_T_left=_b_t_l(poser, a["t"]))
            uv, z = rig.project(r_wc, c_w, centre)
            u, v = uv[0]
            if z[0] > 0 and 40 <= u < rig.width - 40 and 40 <= v < rig.height - 40:
                mask = a["label"] == int(row["id"])
                if mask.sum() < 50:
                    continue  # hidden behind another rock
                assert _drawn_dist(mask, uv[0]) < 3.0, int(row["id"])
                checked += 1
    assert checked >= 2


def test_rover_yaml_mast_round_trips(bag: dict) -> None:
    """rover.yaml's ``mast:`` section, read as a node gets it (``mast.*``), is the
    simulator's mast at every angle."""
    from atacama_sim.camera import mast_kinematics
    from roi_network.mast import MAST_PARAMS, MastKinematics, same_pose

    params = _rover_params(bag["dir"])
    assert set(MAST_PARAMS) <= set(params)
    kin = MastKinematics.from_params(params)
    ref = mast_kinematics(bag["cfg"].camera)
    assert kin.joints == ("mast_pan", "mast_tilt")
    np.testing.assert_allclose(kin.pan_origin[:3, 3], [0.4, 0.0, 1.30])
    for pan, tilt in ((0.0, 0.35), (2.6, 0.1), (-2.6, 1.1), (1.0, -0.4)):
        assert same_pose(kin.base_T_left(pan, tilt), ref.base_T_left(pan, tilt), 1e-9, 1e-9)


def _urdf_chain(text: str, frame: str, angles: dict[str, float]) -> np.ndarray:
    """``base_link -> frame`` of a URDF at joint angles (origin xyz rpy, axis)."""
    import xml.etree.ElementTree as ET

    joints = {j.find("child").get("link"): j for j in ET.fromstring(text).iter("joint")}
    m = np.eye(4)
    while frame != "base_link":
        j = joints[frame]
        o = j.find("origin")
        t = np.eye(4)
        t[:3, :3] = Rotation.from_euler("xyz", [float(v) for v in o.get("rpy").split()]
                                        ).as_matrix()
        t[:3, 3] = [float(v) for v in o.get("xyz").split()]
        if j.get("type") == "revolute":
            axis = np.array([float(v) for v in j.find("axis").get("xyz").split()])
            rot = np.eye(4)
            rot[:3, :3] = Rotation.from_rotvec(axis * angles[j.get("name")]).as_matrix()
            t = t @ rot
        m = t @ m
        frame = j.find("parent").get("link")
    return m


def test_tf_static_and_robot_description(bag: dict, messages: dict) -> None:
    """One latched ``/tf_static`` with the fixed joints and one latched
    ``/robot_description`` whose joints put the cameras where the mast does."""
    from atacama_sim.camera import mast_kinematics

    cfg = bag["cfg"]
    (t0, tf), = messages["/tf_static"]
    (t1, desc), = messages["/robot_description"]
    assert t0 == t1 == messages["/imu/data"][0][0]
    pairs = {(x.header.frame_id, x.child_frame_id): x.transform for x in tf.transforms}
    assert set(pairs) == {("base_link", "imu_link"), ("base_link", "mast_pan_base"),
                          ("mast_tilt_link", "left_camera_optical"),
                          ("left_camera_optical", "right_camera_optical"),
                          ("base_link", "sun_sensor")}
    sun = pairs[("base_link", "sun_sensor")]
    assert (sun.translation.x, sun.translation.y, sun.translation.z) == \
        pytest.approx(bag["cfg"].sun_sensor.position_m)
    assert sun.rotation.w == pytest.approx(1.0)
    assert '<link name="sun_sensor"/>' in desc.data
    pan_base = pairs[("base_link", "mast_pan_base")]
    assert (pan_base.translation.x, pan_base.translation.z) == pytest.approx((0.4, 1.30))
    assert pairs[("left_camera_optical", "right_camera_optical")].translation.x == \
        pytest.approx(cfg.camera.baseline_m)
    text = desc.data
    assert 'name="mast_pan" type="revolute"' in text and '<axis xyz="0 1 0"/>' in text
    kin = mast_kinematics(cfg.camera)
    for pan, tilt in ((0.0, np.radians(20)), (1.2, 0.5), (-2.9, -0.3)):
        angles = {"mast_pan": pan, "mast_tilt": tilt}
        np.testing.assert_allclose(_urdf_chain(text, "left_camera_optical", angles),
                                   kin.base_T_left(pan, tilt), atol=1e-9)
        right = kin.base_T_left(pan, tilt)
        right[:3, 3] += right[:3, 0] * cfg.camera.baseline_m
        np.testing.assert_allclose(_urdf_chain(text, "right_camera_optical", angles), right,
                                   atol=1e-9)
    meta = yaml.safe_load((bag["dir"] / "rosbag/metadata.yaml").read_text())
    topics = {t["topic_metadata"]["name"]: t["topic_metadata"]
              for t in meta["rosbag2_bagfile_information"]["topics_with_message_count"]}
    for name in ("/tf_static", "/robot_description"):
        qos = topics[name]["offered_qos_profiles"]
        text = qos if isinstance(qos, str) else json.dumps(qos)
        assert "durability: 1" in text or "transient_local" in text or \
            '"durability": 1' in text, text


def test_no_panoramas_takes_no_pan_frames(bag: dict, tmp_path: Path) -> None:
    """``--no-panoramas``: the same stop, the mast at the drive pose throughout, no
    panorama in world.yaml, the mast still in rover.yaml."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from atacama_sim.cli import main

    out = tmp_path / "nopano"
    assert main(["generate", "--preset", "tiny", "--seed", str(SEED), "--no-progress",
                 "--out", str(out), "--no-panoramas", "--set", "camera.hfov_deg=45",
                 "--set", "route.stop_every_m=[6, 6]"]) == 0
    derived = yaml.safe_load((out / "world.yaml").read_text())["derived"]
    assert derived["panoramas"]["count"] == 0 and derived["panoramas"]["stereo_pairs"] == 0
    assert derived["route"]["stereo_frames"] < bag["stats"]["route"]["stereo_frames"]
    drive = (0.0, np.radians(20.0))
    with AnyReader([out / "rosbag"],
                   default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        conns = [c for c in reader.connections if c.topic == "/joint_states"]
        positions = [reader.deserialize(raw, c.msgtype).position
                     for c, _t, raw in reader.messages(connections=conns)]
    assert len(positions) > 100 and np.allclose(positions, drive, atol=1e-12)
    assert "mast.pan_joint" in _rover_params(out)


def test_panorama_shape_is_checked() -> None:
    """Pan positions spread evenly, symmetric, inside the stops, as few as keep the
    overlap; a shape that cannot is refused naming the field."""
    from atacama_sim.config import CameraConfig, MastConfig
    from atacama_sim.panorama import pan_angles

    cam = CameraConfig()
    np.testing.assert_allclose(np.degrees(pan_angles(MastConfig(), cam)),
                               [-150, -90, -30, 30, 90, 150])
    np.testing.assert_allclose(np.degrees(pan_angles(MastConfig(overlap_deg=15), cam)),
                               -180 + 360 / 7 * (np.arange(7) + 0.5))
    np.testing.assert_allclose(np.degrees(pan_angles(MastConfig(span_deg=120), cam)),
                               [-30, 30])
    with pytest.raises(ValueError, match=r"mast\.overlap_deg"):
        pan_angles(MastConfig(overlap_deg=70), cam)
    with pytest.raises(ValueError, match=r"mast\.span_deg"):
        pan_angles(MastConfig(span_deg=400), cam)


def test_a_stop_gets_its_end_of_drive_frame_before_the_mast_moves():
    from atacama_sim.route import STOP_FRAME_DELAY_S, Trajectory, camera_indices

    rate = 50.0
    t = np.arange(0, 60, 1 / rate)
    moving = (t > 3) & (t < 20)
    s = np.cumsum(moving) * 0.15 / rate  # 0.15 m/s while moving
    traj = Trajectory(t, np.zeros((len(t), 3)), np.tile([0, 0, 0, 1.0], (len(t), 1)), s, moving)
    busy = (t >= 22) & (t < 49)  # the panorama, 2 s after the wheels stop
    idx = camera_indices(traj, 0.45, 10.0, rate, busy)
    in_stop = t[idx][t[idx] >= 20]
    assert in_stop[0] == pytest.approx(20 + STOP_FRAME_DELAY_S, abs=2 / rate)
    assert not np.any(busy[idx])
    # Without it the first stop frame would come only after the panorama.
    assert np.sum((t[idx] > 20) & (t[idx] < 22)) == 1


# -- the sun: epoch, site, sun sensor, light ----------------------------------------------
def _sun_in_map(params: dict, origin: list[float], xy: np.ndarray, stamp_s: float
                ) -> np.ndarray:
    """The sun in the map frame from the bag's own records and roi_network.sun."""
    from pyproj import CRS, Transformer

    from roi_network import sun as ephemeris

    crs = CRS.from_user_input(params["site.crs"])
    lon, lat = Transformer.from_crs(crs, crs.geodetic_crs, always_xy=True).transform(
        xy[0] + origin[0], xy[1] + origin[1])
    pos = ephemeris.sun_position(params["site.body"], lat, lon, stamp_s)
    return ephemeris.grid_north(params["site.crs"], lon, lat).enu_to_grid(pos.enu())


def test_the_bag_records_its_site_and_epoch(bag: dict, messages: dict) -> None:
    """The rosbag2 metadata's custom_data, rover.yaml's ``site:`` and world.yaml hold the
    body, CRS, latitude, longitude and epoch; the first stamp is the epoch, at the local
    solar time of ``sun.local_solar_time_h``."""
    from roi_network import sun as ephemeris

    meta = yaml.safe_load((bag["dir"] / "rosbag/metadata.yaml").read_text())
    custom = meta["rosbag2_bagfile_information"]["custom_data"]
    params = _rover_params(bag["dir"])
    derived = yaml.safe_load((bag["dir"] / "world.yaml").read_text())["derived"]
    want = {"body": "earth", "crs": "EPSG:32719", "latitude_deg": -24.1,
            "longitude_deg": -69.95, "epoch_ns": START_NS}
    for key, value in want.items():
        assert custom[f"site.{key}"] == str(value), key
        assert params[f"site.{key}"] == value, key
        assert derived["site"][key] == value, key
    assert params["site.epoch_utc"] == custom["site.epoch_utc"] == "2023-05-05T14:18:31Z"
    first = min(t for msgs in messages.values() for t, _ in msgs)
    assert first == START_NS
    assert ephemeris.local_solar_time_h("earth", -69.95, first * 1e-9) == \
        pytest.approx(bag["cfg"].sun.local_solar_time_h, abs=1 / 3600)


def test_sun_sensor_reads_the_ephemeris_in_its_frame(bag: dict, messages: dict) -> None:
    """Each /sun_sensor vector, against the sun computed from the bag alone (rover.yaml's
    site and mount, the truth pose, roi_network.sun): its two angles are off by the
    bag's bias plus noise of rover.yaml's sigma; the samples come at its rate, minus those
    the mast shadows (world.yaml counts them)."""
    params = _rover_params(bag["dir"])
    derived = yaml.safe_load((bag["dir"] / "world.yaml").read_text())["derived"]
    tum = _tum(bag["dir"])
    mount = np.array(params["sun_sensor.base_to_sensor"])
    r_bs = Rotation.from_quat(mount[3:]).as_matrix()
    msgs = messages["/sun_sensor"]
    sensor = derived["sun"]["sensor"]
    assert len(msgs) == sensor["output"] > 0.9 * sensor["samples"]
    assert sensor["samples"] == pytest.approx(derived["route"]["duration_s"]
                                              * params["sun_sensor.rate_hz"], abs=1)
    err = []
    for t, m in msgs:
        assert m.header.frame_id == params["sun_sensor.frame"] == "sun_sensor"
        r_wb, p = _pose_at(tum, (t - START_NS) * 1e-9)
        s_map = _sun_in_map(params, derived["map_origin"], p + r_wb @ mount[:3], t * 1e-9)
        truth = r_bs.T @ r_wb.T @ s_map
        v = np.array([m.vector.x, m.vector.y, m.vector.z])
        assert np.linalg.norm(v) == pytest.approx(1.0, abs=1e-9)
        assert truth[2] > np.cos(np.radians(params["sun_sensor.fov_half_angle_deg"]))
        err.append([np.arctan2(v[0], v[2]) - np.arctan2(truth[0], truth[2]),
                    np.arctan2(v[1], v[2]) - np.arctan2(truth[1], truth[2])])
    err = np.degrees(err) - sensor["bias_deg"]
    noise = params["sun_sensor.noise_deg"]
    assert np.all(np.abs(err) < 5 * noise)
    np.testing.assert_allclose(err.std(axis=0), [noise, noise], rtol=0.2)
    np.testing.assert_allclose(err.mean(axis=0), 0.0, atol=5 * noise / np.sqrt(len(err)))
    dt = np.diff([t for t, _ in msgs]) * 1e-9
    assert np.min(dt) == pytest.approx(1 / params["sun_sensor.rate_hz"], abs=1e-6)


def test_the_light_follows_the_sun_of_each_frame(bag: dict) -> None:
    """Each pair is lit by the ephemeris' sun at its stamp and camera; over the bag it
    moves as the sun does, and a sun an hour on changes the image."""
    params = _rover_params(bag["dir"])
    derived = yaml.safe_load((bag["dir"] / "world.yaml").read_text())["derived"]
    aux = bag["stats"]["_aux"]
    traj = bag["stats"]["_traj"]
    for a in (aux[0], aux[len(aux) // 2], aux[-1]):
        want = _sun_in_map(params, derived["map_origin"], traj.p[a["k"]][:2],
                           START_NS * 1e-9 + a["t"])
        assert np.degrees(np.arccos(min(1.0, float(want @ a["sun"])))) < 0.002
    moved = np.degrees(np.arccos(float(aux[0]["sun"] @ aux[-1]["sun"])))
    span = aux[-1]["t"] - aux[0]["t"]
    assert 0.003 * span < moved < 0.006 * span  # about 15 deg/h in the sky
    sky = bag["stats"]["_sky"]
    cfg = bag["cfg"]
    world = bag["stats"]["_world"]
    rig = StereoRig.from_config(cfg.camera)
    k = aux[3]["k"]
    poses = [rig.camera_pose(traj.rotations()[k].as_matrix(), traj.p[k],
                             base_T_left=aux[3]["base_T_left"])]
    r = SceneRenderer(world.terrain, world.textures, world.rocks, MATERIAL_RGB,
                      (cfg.camera.width, cfg.camera.height))
    try:
        now = r.render_views(rig, poses, aux[3]["sun"])[0]["rad"]
        key = r._shadow_sun.copy()
        later_sun, _ = sky.sun_map(aux[3]["t"] + 3600.0, traj.p[k][:2])
        later = r.render_views(rig, poses, later_sun)[0]["rad"]
        assert not np.array_equal(r._shadow_sun, key)  # the shadow map followed
    finally:
        r.release()
    assert np.mean(np.abs(later.astype(float) - now)) > 0.01 * np.mean(now)


def test_sun_check_reports_the_sensor_against_the_ephemeris(bag: dict, tmp_path: Path,
                                                            capsys) -> None:
    """``python -m atacama_sim.sun_check BAG``: the output rate and share, the outages, and
    the error (within noise once the recorded bias is taken off); a bag without its files
    is named."""
    from atacama_sim.sun_check import main, sun_sensor_report

    report = sun_sensor_report(bag["dir"])
    sensor = bag["stats"]["sun"]["sensor"]
    assert report["messages"] == sensor["output"] and report["median_interval_s"] == 0.2
    assert report["output_rate_hz"] == pytest.approx(5.0 * sensor["output_share"], rel=0.02)
    assert sum(report["outages"].values()) == sensor["samples"] - sensor["output"]
    assert report["angle_error_deg"]["median"] < 0.05 * 2 + np.hypot(*sensor["bias_deg"])
    assert max(report["axis_error_less_bias_deg"]["std"]) < 0.07
    assert main([str(tmp_path / "nothing")]) == 1
    assert f"{tmp_path / 'nothing' / 'rover.yaml'}" in capsys.readouterr().err
