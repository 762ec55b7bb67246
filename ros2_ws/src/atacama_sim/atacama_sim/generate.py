"""Make one bag directory (DESIGN.md, Files) from a configuration.

Steps (docs/simulator.md, Method): 1 build the world and place its sun (site, epoch);
2 plan the route, drive it and schedule the mast's panoramas at the stops; 3 synthesise
the IMU and the sun sensor; 4 render the orbital image and write the DTM beside it;
5 stream the traverse into the bag in time order (frame tree, IMU, sun sensor, ground
truth, joint states, stereo pairs rendered on demand under the sun of their stamp, so
memory stays bounded); 6 write truth, rover.yaml, world.yaml and the contact sheet.
"""

from __future__ import annotations

import shutil
import time
from pathlib import Path
from typing import Any

import cv2
import numpy as np
from tqdm import tqdm

from atacama_sim.bagwriter import BagWriter
from atacama_sim.camera import StereoRig, mast_kinematics
from atacama_sim.config import WorldConfig
from atacama_sim.contact import contact_sheet
from atacama_sim.imu import synthesize_imu
from atacama_sim.orbital import orbital_tiles, render_orbital, write_dtm
from atacama_sim.panorama import MastMotion, mast_motion, panorama_s, panorama_stop_s
from atacama_sim.renderer import SceneRenderer
from atacama_sim.robot import static_transforms, urdf
from atacama_sim.route import camera_indices, drive, plan_route
from atacama_sim.sensor import develop, developer_pool
from atacama_sim.sky import Sky
from atacama_sim.sunsensor import SunSensorData, base_T_sensor, simulate_sun_sensor
from atacama_sim.texture import MATERIAL_RGB
from atacama_sim.truth import write_rover_yaml, write_truth_rois, write_tum, write_world_yaml
from atacama_sim.world import World

CONTACT_FRAMES = 6  # frames shown on the contact sheet
GT_RATE_HZ = 10.0  # rate of the ground-truth poses (plus one at every stereo pair), Hz
JOINT_RATE_HZ = 10.0  # rate of /joint_states (plus one at every stereo pair), Hz


def _base_T_left(kin, motion: MastMotion, k: int) -> np.ndarray:  # noqa: N802
    """The left camera in base_link at grid sample ``k``: the mast at its joint angles."""
    return kin.base_T_left(float(motion.pan[k]), float(motion.tilt[k]))


def _contact_choice(rig: StereoRig, kin, motion: MastMotion, traj, cam_idx: np.ndarray,
                    catalogue: np.ndarray) -> set[int]:
    """Frames for the contact sheet: spread along the route, preferring frames that see
    truth ROIs (centres projected into the image within 25 m)."""
    if len(cam_idx) == 0:
        return set()
    rot = traj.rotations()
    pts = np.column_stack([catalogue["x"], catalogue["y"], catalogue["z"]])
    score = np.zeros(len(cam_idx))
    for i, k in enumerate(cam_idx):
        r_wc, c = rig.camera_pose(rot[k].as_matrix(), traj.p[k],
                                  base_T_left=_base_T_left(kin, motion, int(k)))
        uv, z = rig.project(r_wc, c, pts)
        vis = (z > 1) & (z < 25) & (uv[:, 0] >= 0) & (uv[:, 0] < rig.width) & \
              (uv[:, 1] >= 0) & (uv[:, 1] < rig.height)
        score[i] = vis.sum()
    chosen = set()
    for part in np.array_split(np.arange(len(cam_idx)), CONTACT_FRAMES):
        if len(part):
            chosen.add(int(part[np.argmax(score[part])]))
    return chosen


def _traverse(cfg: WorldConfig, rig: StereoRig, renderer, sky: Sky, traj, motion: MastMotion,
              imu, sun: SunSensorData, cam_idx: np.ndarray, gt_idx: np.ndarray,
              js_idx: np.ndarray, cat, out: Path, bar, keep_aux: bool, seen_px: np.ndarray,
              frames_contact: list, aux: list, timings: dict[str, float]) -> dict[str, int]:
    """Drive the route: write the frame tree, IMU, sun sensor, ground truth, joint states
    and stereo pairs to ``out/rosbag`` in time order (at a pair's stamp the joint state
    before the images), each pair lit by the sun of its stamp at its camera; fill
    ``seen_px`` (per ROI, most pixels in one left view), ``frames_contact``, ``aux`` and
    ``timings``; return the message counts per topic."""
    kin = mast_kinematics(cfg.camera)
    contact = _contact_choice(rig, kin, motion, traj, cam_idx, cat)
    rot = traj.rotations()
    cam_set = {int(k): i for i, k in enumerate(cam_idx)}
    gt_set = set(gt_idx.tolist())
    js_set = set(js_idx.tolist())
    sun_out = {int(sun.idx[j]): sun.measured[j] for j in np.flatnonzero(sun.reason == 0)}
    t0 = time.perf_counter()
    render_s = 0.0
    bar.set_postfix_str("traverse")
    # Pair i + 1 is rendered (GL, this process) while pair i is developed (noise, JPEG)
    # in a worker process; the bag is still written in time order.
    pending: dict[int, Any] = {}
    n_rendered = 0

    def render_next(pool) -> None:
        nonlocal n_rendered, render_s
        i = n_rendered
        k = int(cam_idx[i])
        b_t_l = _base_T_left(kin, motion, k)
        poses = [rig.camera_pose(rot[k].as_matrix(), traj.p[k], right=r, base_T_left=b_t_l)
                 for r in (False, True)]
        light, _ = sky.sun_map(float(traj.t[k]), poses[0][1][:2])
        tr = time.perf_counter()
        views = renderer.render_views(rig, poses, light, want_label=True,
                                      want_depth=keep_aux, half=True)
        render_s += time.perf_counter() - tr
        lab = views[0]["label"]
        np.maximum(seen_px, np.bincount(lab.ravel(), minlength=len(seen_px)), out=seen_px)
        pending[i] = (pool.submit(develop, i, views[0]["rad"], views[1]["rad"], i in contact),
                      lab)
        if keep_aux:
            aux.append({"k": k, "t": float(traj.t[k]), "z": views[0]["z"], "label": lab,
                        "base_T_left": b_t_l, "sun": light})
        n_rendered += 1

    with developer_pool(cfg.camera, rig.fx, cfg.seed) as pool, \
            BagWriter(out / "rosbag", sky.start_ns) as bag:
        bag.set_site(sky.metadata())
        t0_bag = float(traj.t[0])
        b_t_sun = base_T_sensor(cfg.sun_sensor)
        bag.write_tf_static(t0_bag, static_transforms(kin, cfg.camera.baseline_m, b_t_sun))
        bag.write_robot_description(t0_bag, urdf(kin, cfg.camera.baseline_m, b_t_sun))
        for k in range(len(traj.t)):
            t = float(traj.t[k])
            bag.write_imu(t, imu.gyro[k], imu.accel[k], imu.gyro_sigma, imu.accel_sigma)
            if k in sun_out:
                bag.write_sun_sensor(t, sun_out[k])
            if k in gt_set:
                bag.write_pose(t, traj.p[k], traj.q[k])
            if k in js_set:
                bag.write_joint_state(t, kin.joints, (motion.pan[k], motion.tilt[k]),
                                      (motion.pan_rate[k], motion.tilt_rate[k]))
            if k not in cam_set:
                continue
            i = cam_set[k]
            while n_rendered < min(i + 2, len(cam_idx)):
                render_next(pool)
            fut, lab = pending.pop(i)
            jpeg_l, jpeg_r, left = fut.result()
            bag.write_stereo(t, rig, jpeg_l, jpeg_r)
            if left is not None:
                frames_contact.append((left, lab, t))
            bar.update(1)
        counts = dict(bag.counts)
    timings["traverse_s"] = time.perf_counter() - t0
    timings["render_s"] = render_s
    return counts


def generate(cfg: WorldConfig, out: Path, progress: bool = True,
             keep_aux: bool = False, orbital_only: bool = False) -> dict[str, Any]:
    """Write the bag directory ``out``; return the statistics written to world.yaml.

    ``keep_aux``: also return per-frame rendered depth/labels of the left camera
    (tests only: memory grows with the number of frames).
    ``orbital_only``: write the world's orbital products and truth (``orbital.tif``,
    ``dtm.tif``, ``truth/``, ``world.yaml``, ``contact_sheet.png``) but no traverse: no
    ``rosbag/``, no ``rover.yaml`` (training data for the orbital classifiers, at a sixth
    of the time).
    """
    t_start = time.perf_counter()
    out = Path(out)
    if (out / "rosbag").exists():
        shutil.rmtree(out / "rosbag")
    if orbital_only:
        (out / "rover.yaml").unlink(missing_ok=True)  # no traverse: no rig of its own
    (out / "truth").mkdir(parents=True, exist_ok=True)
    timings: dict[str, float] = {}

    t0 = time.perf_counter()
    # 1. Build the world; place its sun (the site, the epoch).
    world = World.build(cfg)
    sky = Sky.from_config(cfg, world.origin)
    cat = world.rocks.catalogue
    # 2. Plan the route, drive it (stops long enough for a panorama), schedule the mast.
    route = plan_route(cfg.route, cat, world.terrain.extent, cfg.seed)
    rate = cfg.imu.rate_hz
    traj = drive(route, cfg.route, world.terrain, rate, cfg.seed,
                 min_stop_s=panorama_stop_s(cfg.mast, cfg.camera, rate))
    motion = mast_motion(traj, cfg.mast, cfg.camera, rate)
    # 3. Synthesise the IMU and the sun sensor.
    imu = synthesize_imu(traj, cfg.imu, cfg.seed)
    sun = simulate_sun_sensor(cfg.sun_sensor, sky, traj, motion, mast_kinematics(cfg.camera),
                              rate, cfg.seed)
    cam_idx = np.union1d(camera_indices(traj, cfg.route.frame_spacing_m,
                                        cfg.route.stop_frame_period_s, rate, motion.busy),
                         motion.frames)
    gt_step = max(1, round(rate / GT_RATE_HZ))
    gt_idx = np.union1d(np.arange(0, len(traj.t), gt_step), cam_idx)
    js_idx = np.union1d(np.arange(0, len(traj.t), max(1, round(rate / JOINT_RATE_HZ))),
                        cam_idx)
    rig = StereoRig.from_config(cfg.camera)
    timings["world_s"] = time.perf_counter() - t0

    renderer = SceneRenderer(world.terrain, world.textures, world.rocks,
                             MATERIAL_RGB, (cfg.camera.width, cfg.camera.height))
    n_traverse = 0 if orbital_only else len(cam_idx)
    bar = tqdm(total=orbital_tiles(world) + n_traverse, unit="step", disable=not progress,
               desc=f"atacama_sim {cfg.preset}")
    # 4. Render the orbital image; write the elevation model beside it.
    t0 = time.perf_counter()
    bar.set_postfix_str("orbital")
    orb = render_orbital(world, renderer, out / "orbital.tif", out / "truth/orbital_labels.tif",
                         progress=lambda: bar.update(1))
    dtm = write_dtm(world, out / "dtm.tif")
    timings["orbital_s"] = time.perf_counter() - t0

    seen_px = np.zeros(len(cat) + 1, np.int64)
    frames_contact: list = []
    aux: list = []
    counts: dict[str, int] = {}
    # 5. Stream the traverse into the bag (_traverse).
    if not orbital_only:
        counts = _traverse(cfg, rig, renderer, sky, traj, motion, imu, sun, cam_idx, gt_idx,
                           js_idx, cat, out, bar, keep_aux, seen_px, frames_contact, aux,
                           timings)
    bar.close()
    renderer.release()

    # 6. Write the files.
    write_truth_rois(cat, cfg, world.origin, out / "truth/rois.geojson")
    # TUM stamps are bag time in seconds (= header stamps), like the pipeline's outputs
    t_abs = sky.start_ns * 1e-9 + traj.t[gt_idx]
    write_tum(out / "truth/trajectory.tum", t_abs, traj.p[gt_idx], traj.q[gt_idx])
    if not orbital_only:
        write_rover_yaml(out / "rover.yaml", rig, cfg, sky)
    sheet = contact_sheet(orb["rgb"], world.terrain.extent, route.path, cat, frames_contact,
                          f"{cfg.preset} seed {cfg.seed}: {len(cat)} ROIs, "
                          f"route {route.length:.0f} m, net {route.net:.0f} m")
    cv2.imwrite(str(out / "contact_sheet.png"), sheet)

    n_frames = len(cam_idx)
    seen = np.flatnonzero(seen_px[1:] >= 200) + 1
    timings["total_s"] = time.perf_counter() - t_start
    stats = {
        "map_origin": [float(v) for v in world.origin],
        "crs": cfg.site.crs,
        "rois": {"total": len(cat), "rocks": int(np.sum(cat["label"] == 1)),
                 "outcrops": int(np.sum(cat["label"] == 2)),
                 "clutter_rocks": len(world.rocks.clutter),
                 "within_roi_range_of_route": len(route.rois_passed),
                 "seen_by_left_camera_200px": None if orbital_only else len(seen)},
        "route": {"length_m": round(route.length, 2), "net_m": round(route.net, 2),
                  "duration_s": round(float(traj.t[-1]), 2),
                  "stereo_frames": n_frames,
                  "mean_frame_spacing_m": round(route.length / max(1, n_frames - 1), 3)},
        "panoramas": _panorama_stats(cfg, traj, motion, rate),
        "site": sky.metadata(),
        "sun": _sun_stats(sky, traj, sun, cfg.sun_sensor.rate_hz),
        "terrain": {"height_range_m": [round(float(world.terrain.base.min()), 2),
                                       round(float(world.terrain.base.max()), 2)],
                    "slope_p95_deg": round(float(np.percentile(world.terrain.slope_deg(),
                                                               95)), 2)},
        "dtm": dtm,
        "orbital_only": orbital_only,
        "messages": counts,
        "timing_s": {k: round(v, 2) for k, v in timings.items()},
        "render_s_per_stereo_frame": round(timings.get("render_s", 0.0) / max(1, n_frames),
                                           4),
        "total_s_per_stereo_frame": round(timings.get("traverse_s", 0.0) / max(1, n_frames),
                                          4),
    }
    write_world_yaml(out / "world.yaml", cfg, stats)
    if keep_aux:
        stats["_aux"] = aux
        stats["_world"] = world
        stats["_traj"] = traj
        stats["_cam_idx"] = cam_idx
        stats["_motion"] = motion
        stats["_sky"] = sky
        stats["_sun_sensor"] = sun
    return stats


def _sun_stats(sky: Sky, traj, sun: SunSensorData, rate_hz: float) -> dict[str, Any]:
    """world.yaml's sun figures: its path over the bag (grid azimuth, apparent elevation at
    the start, middle and end) and the sun sensor's outcomes."""
    from roi_network.sun import local_solar_time_h

    path = {}
    for name, k in (("start", 0), ("middle", len(traj.t) // 2), ("end", len(traj.t) - 1)):
        v, el = sky.sun_map(float(traj.t[k]), traj.p[k][:2])
        path[name] = {"azimuth_deg": round(float(np.degrees(np.arctan2(v[0], v[1]))) % 360.0,
                                           3),
                      "elevation_deg": round(el, 3)}
    counts = sun.counts()
    n = max(1, len(sun.idx))
    return {"local_solar_time_h_start": round(local_solar_time_h(
                sky.body, sky.lon_deg, sky.utc_s(float(traj.t[0]))), 4),
            "path": path,
            "sensor": {"rate_hz": float(rate_hz), "samples": len(sun.idx),
                       **counts, "output_share": round(counts["output"] / n, 4),
                       "bias_deg": [round(float(b), 4) for b in np.degrees(sun.bias_rad)]}}


def _panorama_stats(cfg: WorldConfig, traj, motion: MastMotion, rate: float) -> dict[str, Any]:
    """world.yaml's panorama figures: count, shape, frames and the rover time they cost."""
    pans = motion.panoramas
    per = len(pans[0].frames) if pans else 0
    step = cfg.mast.span_deg / max(1, per)
    return {"count": len(pans), "positions_per_panorama": per,
            "pan_deg": [round(float(np.degrees(a)), 2) for a in pans[0].pan] if pans else [],
            "tilt_deg": cfg.mast.tilt_deg if pans else None,
            "overlap_deg": round(cfg.camera.hfov_deg - step, 2) if pans else None,
            "stereo_pairs": len(motion.frames),
            "seconds_each": round(panorama_s(cfg.mast, cfg.camera, rate), 2) if pans else 0.0,
            "mast_busy_s": round(float(np.sum(motion.busy)) / rate, 2),
            "added_stop_s": round(traj.added_stop_s, 2)}
