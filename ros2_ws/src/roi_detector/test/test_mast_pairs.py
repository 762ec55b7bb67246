"""A pan-tilt mast: each stereo pair placed at its own camera pose (roi_network.mast), the
panorama's views fused into the map and the far rocks, and the bad joint input counted.

Synthetic inputs only: the mast of roi_network's tests (the simulator's geometry: at pan 0,
tilt 20 deg its left camera is the bags' fixed one), a ray-cast scene of flat soil and
upright dark cylinders seen by the bags' 640 x 480, 70 deg camera.
"""

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from roi_detector.camera_poses import PairPoses, rotation_of
from roi_detector.elevation_map import CELL_M, appearance
from roi_detector.far_rocks import FarRockConfig, FarRockTracker, dark_blobs
from roi_detector.inputs import BadInput, PairSpacing, StereoFrame
from roi_detector.local_network import LocalNetwork
from roi_detector.rover_pipeline import (
    DriveMapper,
    PairObservation,
    RoverConfig,
    RoverDetector,
    records_in_view,
)
from roi_detector.stereo import StereoCamera
from roi_network.mast import MastError, MastKinematics
from roi_network.records import ROCK, empty_records

OPTICAL = Rotation.from_matrix(np.array([[0, 0, 1], [-1, 0, 0], [0, -1, 0]], float)).as_quat()
DRIVE_TILT = math.radians(20.0)
#: A panorama's tilt: the ground from 2 m to the map's reach and beyond.
PAN_TILT = 0.2
FX = 457.0
K = [FX, 0, 319.5, 0, FX, 239.5, 0, 0, 1]
P_RIGHT = [FX, 0, 319.5, -FX * 0.2, 0, FX, 239.5, 0, 0, 0, 1, 0]
SOIL = (89, 106, 124)  # BGR of the bags' soil
ROCK_BGR = (40, 43, 47)  # varnished rock: darker and greyer
JOINTS = ["mast_pan", "mast_tilt"]


def mast_params(**over) -> dict:
    """rover.yaml's parameters of a rover with the simulator's mast (nested, as the file
    holds them), its drive pose as ``base_to_left_camera``."""
    mast = {"pan_joint": "mast_pan", "pan_origin": [0.4, 0.0, 1.3, 0, 0, 0, 1],
            "pan_axis": [0, 0, 1], "pan_limits": [-math.pi, math.pi],
            "tilt_joint": "mast_tilt", "tilt_origin": [0, 0, 0.24, 0, 0, 0, 1],
            "tilt_axis": [0, 1, 0], "tilt_limits": [-0.5, 1.2],
            "head_to_left_camera": [0.0, 0.1, 0.0, *OPTICAL]}
    mast.update(over)
    kin = MastKinematics.from_params({f"mast.{k}": v for k, v in mast.items()})
    drive = kin.base_T_left(0.0, DRIVE_TILT)
    q = Rotation.from_matrix(drive[:3, :3]).as_quat()
    return {"base_to_left_camera": [*drive[:3, 3], *q], "mast": mast}


def fixed_params() -> dict:
    p = mast_params()
    del p["mast"]
    return p


KIN = MastKinematics.from_params({f"mast.{k}": v for k, v in mast_params()["mast"].items()})


def _camera(pan: float = 0.0, tilt: float = DRIVE_TILT) -> StereoCamera:
    cam = StereoCamera.from_camera_info(K, P_RIGHT, 640, 480, fixed_params()["base_to_left_camera"])
    return cam.at_pose(KIN.base_T_left(pan, tilt))


def _render(camera: StereoCamera, rover_xy=(0.0, 0.0), rocks=()):
    """Left image (BGR) and depth (m, inf where no ground) of flat soil with upright dark
    cylinders ``(x, y, radius, height)`` (odom), the rover at ``rover_xy`` heading +x."""
    rays = camera.rays_base()
    o = camera.t_base_cam + np.array([rover_xy[0], rover_xy[1], 0.0])
    with np.errstate(divide="ignore", invalid="ignore"):
        depth = np.where(rays[..., 2] < 0, -o[2] / rays[..., 2], np.inf)
    img = np.empty((*rays.shape[:2], 3), np.uint8)
    img[:] = SOIL
    # A little texture, so that the pair's median is the soil's.
    img[::7, ::5] = (95, 112, 130)
    for x, y, r, h in rocks:
        dx, dy = o[0] - x, o[1] - y
        a = rays[..., 0] ** 2 + rays[..., 1] ** 2
        b = 2 * (dx * rays[..., 0] + dy * rays[..., 1])
        c = dx * dx + dy * dy - r * r
        disc = b * b - 4 * a * c
        with np.errstate(invalid="ignore", divide="ignore"):
            s = (-b - np.sqrt(disc)) / (2 * a)
            st = (h - o[2]) / rays[..., 2]
        z = o[2] + s * rays[..., 2]
        side = (disc > 0) & (s > 0) & (z >= 0) & (z <= h) & (s < depth)
        top = o + rays * st[..., None]
        cap = (st > 0) & (np.hypot(top[..., 0] - x, top[..., 1] - y) < r) & (st < depth)
        depth = np.where(side, s, depth)
        depth = np.where(cap & ~side, st, depth)
        img[side | cap] = ROCK_BGR
    return img, depth


def _observation(camera: StereoCamera, rover_xy, rocks, max_range_m=20.0) -> PairObservation:
    """What RoverDetector.observe gives for the rendered pair (noise-free stereo)."""
    img, depth = _render(camera, rover_xy, rocks)
    d = depth[::2, ::2]
    pts = camera.t_base_cam + camera.rays_base()[::2, ::2] * d[..., None]
    pts[~(d <= max_range_m)] = np.nan
    import cv2

    small = cv2.resize(img, (pts.shape[1], pts.shape[0]), interpolation=cv2.INTER_AREA)
    with np.errstate(divide="ignore"):
        disp = (camera.fxb / depth).astype(np.float32)
    disp[~np.isfinite(depth)] = np.nan
    return PairObservation(points=pts, appearance=appearance(small, np.isfinite(pts[..., 2])),
                           blobs=dark_blobs(img, disp[::2, ::2], camera, FarRockConfig()))


def _pose(x: float, y: float = 0.0):
    return np.eye(3), np.array([x, y, 0.0]), np.eye(2) * 1e-4


# -- the pose of each pair ------------------------------------------------------------------


def test_without_a_mast_every_pair_takes_the_fixed_extrinsic_as_written():
    bad = BadInput(lambda m: None)
    poses = PairPoses(fixed_params(), bad)
    assert not poses.has_mast and poses.decidable(5.0)
    assert poses.pose(5.0) == fixed_params()["base_to_left_camera"]
    assert rotation_of(poses.pose(5.0)) is None and not bad.counts


def test_with_a_mast_each_pair_takes_its_joint_angles_pose():
    poses = PairPoses(mast_params(), BadInput(lambda m: None))
    assert poses.has_mast
    poses.add(10.0, JOINTS, [0.0, DRIVE_TILT])
    poses.pair_arrived(10.05)
    assert not poses.decidable(10.05)  # the bracket's second sample may come
    poses.add(10.1, JOINTS, [math.pi / 2, PAN_TILT])
    assert poses.decidable(10.05)
    np.testing.assert_allclose(poses.pose(10.1), KIN.base_T_left(math.pi / 2, PAN_TILT))
    # At the drive angles the pose is the fixed camera's.
    drive = StereoCamera.from_camera_info(K, P_RIGHT, 640, 480,
                                          mast_params()["base_to_left_camera"])
    assert drive.same_mount(drive.at_pose(poses.pose(10.0)))
    assert not drive.same_mount(drive.at_pose(poses.pose(10.1)))


def test_images_before_any_joint_state_are_not_placed_counted_and_named_once():
    said = []
    bad = BadInput(said.append)
    poses = PairPoses(mast_params(), bad)
    for t in (1.0, 2.0):
        poses.pair_arrived(t)
        assert not poses.decidable(1.0)
    poses.pair_arrived(3.0)  # two newer pairs and still no joint state: none is coming
    assert poses.decidable(1.0) and not poses.decidable(2.0)
    assert [poses.pose(t) for t in (1.0, 2.0, 3.0)] == [None] * 3
    # The first sample comes later: the pairs before it had none.
    poses.add(3.5, JOINTS, [0.0, DRIVE_TILT])
    assert poses.pose(3.2) is None and poses.pose(3.45) is not None
    assert bad.counts["no joint states"] == 4 and not bad.counts["stale joint states"]
    assert len(said) == 1 and "/joint_states" in said[0] and "mast_pan" in said[0]


def test_unknown_joint_names_are_an_error_offline_and_no_joint_states_live():
    strict = PairPoses(mast_params(), BadInput(lambda m: None), strict=True)
    with pytest.raises(MastError, match=r"'mast_pan'.*'pan', 'tilt'"):
        strict.add(1.0, ["pan", "tilt"], [0.0, 0.3])
    said = []
    bad = BadInput(said.append)
    live = PairPoses(mast_params(), bad, strict=False)
    for t in (1.0, 1.1, 1.2):
        live.add(t, ["pan", "tilt"], [0.0, 0.3])
    assert bad.counts["bad joint states"] == 3 and len(said) == 1
    assert "'pan', 'tilt'" in said[0]
    # dropped messages do not keep pairs waiting: two newer pairs and the mast is down
    for t in (1.05, 1.15, 1.25):
        live.pair_arrived(t)
        live.add(t + 0.01, ["pan", "tilt"], [0.0, 0.3])
    assert live.decidable(1.05) and not live.decidable(1.15)
    assert live.pose(1.1) is None and bad.counts["no joint states"] == 1


def test_joint_stamps_further_than_the_tolerance_skip_the_pair():
    bad = BadInput(lambda m: None)
    poses = PairPoses(mast_params(), bad, tolerance_s=0.1)
    poses.add(10.0, JOINTS, [0.0, DRIVE_TILT])
    poses.add(11.0, JOINTS, [0.0, DRIVE_TILT])
    assert poses.pose(10.5) is None and bad.counts["stale joint states"] == 1
    assert poses.pose(10.95) is not None  # within the tolerance of the second


def test_a_pair_waits_for_joint_states_that_lag_behind_as_long_as_they_still_come():
    """A busy node reads 10 Hz joint states seconds of stamps behind its images: a pair
    waits while samples keep coming between pairs, however far behind they are."""
    poses = PairPoses(mast_params(), BadInput(lambda m: None))
    poses.add(0.0, JOINTS, [0.0, DRIVE_TILT])
    for k in range(1, 6):  # pairs at 10, 20, ... s; the joint states read reach 0.5 s
        poses.pair_arrived(10.0 * k)
        poses.add(k * 0.1, JOINTS, [0.0, DRIVE_TILT])
        assert not poses.decidable(10.0)
    # a pair that comes before its own joint state, after an outage, waits for it too
    poses.pair_arrived(60.0)
    poses.add(60.0, JOINTS, [0.0, DRIVE_TILT])
    assert poses.decidable(60.0) and poses.pose(60.0) is not None
    poses.pair_arrived(70.0)
    poses.pair_arrived(80.0)  # two pairs with no joint message after them: the mast is down
    assert poses.decidable(10.0) and not poses.decidable(70.0)


def test_a_mast_that_stops_publishing_skips_the_pairs_and_says_so_once():
    said = []
    bad = BadInput(said.append)
    poses = PairPoses(mast_params(), bad)
    for k in range(10):
        poses.add(k * 0.1, JOINTS, [0.0, DRIVE_TILT])
    assert poses.pose(0.85) is not None
    assert [poses.pose(t) for t in (2.0, 3.0, 4.0)] == [None] * 3
    assert bad.counts["joint states stopped"] == 3
    assert len(said) == 1 and "stopped publishing" in said[0] and "0.900 s" in said[0]
    poses.add(4.5, JOINTS, [0.0, DRIVE_TILT])  # it resumes
    assert poses.pose(4.5) is not None


def test_the_spacing_reads_each_pair_of_a_panorama_taken_while_the_rover_stands():
    spacing = PairSpacing()
    still = _pose(3.0)
    assert spacing.keep(0.0, still, KIN.base_T_left(0.0, DRIVE_TILT)[:3, :3])
    kept = [spacing.keep(1.0 + 2 * k, still, KIN.base_T_left(math.radians(a), PAN_TILT)[:3, :3])
            for k, a in enumerate((-150, -90, -30, 30, 90, 150))]
    back = spacing.keep(14.0, still, KIN.base_T_left(0.0, DRIVE_TILT)[:3, :3])
    assert all(kept) and back
    # The same stop with the camera left at the drive pose: one pair per 5 s.
    fixed = PairSpacing()
    assert [fixed.keep(t, still) for t in (0.0, 1.0, 3.0, 5.0)] == [True, False, False, True]


# -- the detector at each pair's pose -------------------------------------------------------


def test_the_detector_reads_each_pair_at_its_pose_and_keeps_its_rays_per_pose(monkeypatch):
    """RoverDetector.observe with a mast's pose: the stereo points of a panned view are
    those of the rock beside the rover, in base_link; the rays of a pose come from the
    cache when it comes again."""
    import roi_detector.rover_pipeline as rp

    rock = (0.5, 9.0, 0.6, 0.8)  # 9 m to the left of the rover
    left = _camera(math.pi / 2, PAN_TILT)
    img, depth = _render(left, rocks=[rock])
    with np.errstate(divide="ignore"):
        disp = (left.fxb / depth).astype(np.float32)
    disp[~np.isfinite(depth)] = np.nan
    monkeypatch.setattr(rp, "disparity", lambda a, b, cfg: disp)
    frame = StereoFrame(0, img, img, np.array(K, float), np.array(P_RIGHT, float))
    det = RoverDetector(fixed_params()["base_to_left_camera"], None, RoverConfig())
    pose = KIN.base_T_left(math.pi / 2, PAN_TILT)
    obs = det.observe(frame, pose)
    np.testing.assert_allclose(det.camera.t_base_cam, pose[:3, 3])
    dark = obs.appearance[..., 1] < 0.55
    on_rock = obs.points[dark & np.isfinite(obs.points[..., 2])]
    assert len(on_rock) > 50
    # Its near face and top, 0.6 m wide: within its radius of its centre.
    np.testing.assert_allclose(np.median(on_rock[:, :2], axis=0), rock[:2], atol=0.6)
    rays = det._rays
    det.observe(frame)  # the drive pose: other rays
    assert det._rays is not rays and det.camera.same_mount(_camera())
    det.observe(frame, pose.copy())  # the panned pose again: its rays kept
    assert det._rays is rays


def test_detections_in_view_are_those_the_panned_camera_sees():
    rec = empty_records(2)
    rec["x"], rec["y"], rec["label"] = [8.0, 0.5], [0.0, 9.0], ROCK
    rec["cov_xx"] = rec["cov_yy"] = 0.04
    ahead = records_in_view(rec, _pose(0.0), _camera(), 20.0)
    left = records_in_view(rec, _pose(0.0), _camera(math.pi / 2, PAN_TILT), 20.0)
    assert list(ahead["x"]) == [8.0] and len(left) == 1
    np.testing.assert_allclose([left["x"][0], left["y"][0]], [0.5, 9.0])


def test_a_panorama_view_puts_its_points_in_the_map_where_the_rock_is():
    rock = (3.0, 9.0, 0.6, 0.8)
    mapper = DriveMapper(RoverConfig())
    mapper.add_pair(_observation(_camera(math.pi / 2, PAN_TILT), (2.5, 0.0), [rock]), 0.0,
                    _pose(2.5), _camera(math.pi / 2, PAN_TILT))
    emap = mapper.map
    ij = np.floor((np.array(rock[:2]) - emap.origin) / CELL_M).astype(int)
    w = emap.w[ij[0] - 3:ij[0] + 4, ij[1] - 3:ij[1] + 4]
    z = emap.wz[ij[0] - 3:ij[0] + 4, ij[1] - 3:ij[1] + 4] / np.maximum(w, 1e-9)
    assert w.max() > 0 and z[w > 0].max() == pytest.approx(0.8, abs=0.05)


def test_a_far_track_stays_open_while_the_mast_looks_away_at_a_stop():
    """A rock followed while driving, then the rover stops and pans its mast away: the
    track is not closed by the views that do not show it, and goes on after the panorama;
    a fixed camera that loses it closes it (as without a mast)."""
    cfg = FarRockConfig()
    rock = (40.0, 11.0, 0.6, 0.6)
    drive = _camera()

    def view(tracker, camera, x, t):
        img, depth = _render(camera, (x, 0.0), [rock])
        with np.errstate(divide="ignore"):
            disp = (camera.fxb / depth).astype(np.float32)
        disp[~np.isfinite(depth)] = np.nan
        tracker.add(dark_blobs(img, disp[::2, ::2], camera, cfg), t, np.eye(3),
                    np.array([x, 0.0, 0.0]), camera)

    tracker = FarRockTracker(cfg)
    xs = np.arange(0.0, 9.0, 0.45)
    for k, x in enumerate(xs):
        view(tracker, drive, x, float(k))
    assert len(tracker.tracks) == 1 and not tracker.measured
    views = len(tracker.tracks[0].views)
    for k, a in enumerate((-150, -90, 90, 150)):  # the rock is in none of these views
        view(tracker, _camera(math.radians(a), PAN_TILT), xs[-1], 100.0 + k)
    assert len(tracker.tracks) == 1 and not tracker.measured
    for k, x in enumerate(xs[-1] + np.arange(1, 6) * 0.45):
        view(tracker, drive, x, 200.0 + k)
    assert len(tracker.tracks) == 1 and len(tracker.tracks[0].views) == views + 5
    # The rover moved, then the camera lost it: closed.
    view(tracker, _camera(math.radians(-90), PAN_TILT), xs[-1] + 3.0, 300.0)
    assert not tracker.tracks and len(tracker.measured) == 1



def _stop_with_panorama(round_at_return: bool) -> tuple[list[int], np.ndarray]:
    """A drive up to a stop, the stop's 6-view panorama and the mast's return to the drive
    pose, a rock 8 m ahead and 6 m to the left of the stop: the LN's size after the drive,
    after the panorama and after the return pair, and the LN."""
    rock = (20.0, 6.0, 0.7, 0.8)
    cfg = RoverConfig()
    mapper = DriveMapper(cfg)
    if not round_at_return:
        mapper._returned = lambda camera: False
    ln = LocalNetwork(cfg.ln)
    sizes, t, stop = [], 0.0, 12.0

    def pair(camera, x):
        nonlocal t
        mapper.add_pair(_observation(camera, (x, 0.0), [rock]), t, _pose(x), camera)
        ln.update(mapper.current_tracks())
        t += 3.0

    for x in np.arange(stop - 6 * 0.45, stop + 1e-9, 0.45):
        pair(_camera(), x)
    sizes.append(len(ln))
    for a in (-150, -90, -30, 30, 90, 150):
        pair(_camera(math.radians(a), PAN_TILT), stop)
    sizes.append(len(ln))
    pair(_camera(), stop)  # the mast back at the drive pose; the rover still stands
    sizes.append(len(ln))
    return sizes, ln.records


def test_a_stops_panorama_reaches_the_ln_before_the_rover_drives_on():
    """The detection round at the mast's return to the drive pose confirms what the stop's
    views found: the rock is in the LN before the rover moves. Without that round it
    would wait for the next round, 3 pairs on, with the rover driving."""
    sizes, rec = _stop_with_panorama(True)
    assert sizes == [0, 0, 1] and rec["label"][0] == ROCK
    np.testing.assert_allclose([rec["x"][0], rec["y"][0]], [20.0, 6.0], atol=0.5)
    assert _stop_with_panorama(False)[0] == [0, 0, 0]
