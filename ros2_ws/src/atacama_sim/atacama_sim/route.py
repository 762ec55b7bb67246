"""Traverse: route planning (paper Sec. 7.2 statistics) and the rover's motion on it.

Planning: random candidate routes of two kinds, alternating: a heading-biased random walk
whose waypoints detour to pass beside major ROIs, and a detour from a start to a goal
placed at the target net displacement, visiting ROIs on the way within the length budget
(the walk alone rarely combines a paper-like net displacement with enough ROIs). Both are
smoothed by Chaikin corner cutting and scored against the targets (path length, net
displacement / length, number of major ROIs within ``roi_range_m``); driving over a major
ROI is penalised. Motion: trapezoidal speed profiles between
stops; the body rides on the terrain (plane through the wheel contacts gives pitch and
roll), low-passed like a suspension. Everything is sampled on one time grid at the IMU
rate, so IMU, cameras and ground truth are consistent by construction.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.ndimage import gaussian_filter1d
from scipy.spatial import cKDTree
from scipy.spatial.transform import Rotation

from atacama_sim.config import RouteConfig, rng_for
from atacama_sim.terrain import Terrain

#: Acceleration and braking of the speed profile, m/s^2.
ACCEL_MPS2 = 0.05
#: Distance between the front and rear wheels, m (pitch from the terrain under them).
WHEELBASE_M = 1.2
#: Distance between the left and right wheels, m (roll from the terrain under them).
TRACK_M = 1.0
#: Suspension low-pass of pitch, roll and height (Gaussian sigma), s.
BODY_SMOOTHING_S = 0.4


def chaikin(pts: np.ndarray, iterations: int = 5) -> np.ndarray:
    """Corner-cutting smoothing of an open polyline (end points kept)."""
    for _ in range(iterations):
        q = 0.75 * pts[:-1] + 0.25 * pts[1:]
        r = 0.25 * pts[:-1] + 0.75 * pts[1:]
        mid = np.empty((2 * len(q), 2))
        mid[0::2], mid[1::2] = q, r
        pts = np.vstack([pts[:1], mid, pts[-1:]])
    return pts


def resample(path: np.ndarray, step: float) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` metres along ``path`` and their arclengths."""
    seg = np.hypot(*np.diff(path, axis=0).T)
    s = np.concatenate([[0], np.cumsum(seg)])
    si = np.arange(0, s[-1], step)
    si = np.append(si, s[-1]) if s[-1] - si[-1] > 1e-9 else si
    return np.column_stack([np.interp(si, s, path[:, 0]), np.interp(si, s, path[:, 1])]), si


@dataclass
class Route:
    path: np.ndarray  # (N, 2) map frame, dense (5 cm)
    s: np.ndarray  # (N,) arclength
    length: float
    net: float
    rois_passed: np.ndarray  # catalogue indices within roi_range of the path


def _beside(rng: np.random.Generator, xy: np.ndarray, radius: np.ndarray, j: int,
            frm: np.ndarray) -> np.ndarray:
    """A waypoint passing beside major ROI ``j`` (2.5-6 m clear of it), seen from ``frm``."""
    side = rng.choice([-1, 1])
    off = radius[j] + rng.uniform(2.5, 6.0)
    dj = xy[j] - frm
    perp = np.array([-dj[1], dj[0]]) / (np.hypot(*dj) + 1e-9) * side
    return xy[j] + perp * off


def _walk_waypoints(rng: np.random.Generator, xy: np.ndarray, radius: np.ndarray, tree,
                    density: np.ndarray, half: float, target: float) -> list[np.ndarray]:
    """Heading-biased random walk that heads for ROIs roughly ahead."""
    start = rng.uniform(-half, half, 2)
    theta = rng.uniform(-np.pi, np.pi)
    sigma = rng.uniform(0.3, 1.2)
    pts = [start]
    length = 0.0
    tries = 0
    while length < target * 1.08 and tries < 400:
        tries += 1
        step = target * rng.uniform(0.04, 0.12)
        head = theta + rng.normal(0, sigma)
        p = pts[-1] + step * np.array([np.cos(head), np.sin(head)])
        if tree is not None and rng.uniform() < 0.85:
            # Head for a major ROI roughly ahead, preferring dense rock fields (rovers
            # visit rocks), and pass beside it.
            near = np.array(tree.query_ball_point(pts[-1], 1.6 * step), dtype=int)
            if len(near):
                d = xy[near] - pts[-1]
                dist = np.hypot(d[:, 0], d[:, 1])
                ang = np.abs((np.arctan2(d[:, 1], d[:, 0]) - theta + np.pi)
                             % (2 * np.pi) - np.pi)
                ok = (dist > 0.4 * step) & (ang < np.radians(75))
                if ok.any():
                    cand = near[ok]
                    j = cand[rng.choice(len(cand), p=density[cand] / density[cand].sum())]
                    p = _beside(rng, xy, radius, j, pts[-1])
        if np.any(np.abs(p) > half):
            theta += np.pi / 2 * rng.choice([-1, 1])
            continue
        length += float(np.hypot(*(p - pts[-1])))
        pts.append(p)
    return pts


def _detour_waypoints(rng: np.random.Generator, xy: np.ndarray, radius: np.ndarray, tree,
                      density: np.ndarray, half: float, target: float,
                      net_fraction: float) -> list[np.ndarray] | None:
    """From a start to a goal ``net_fraction * target`` away, visiting ROIs (or wandering
    where there are none) while the length budget still allows reaching the goal."""
    net = net_fraction * target
    inside = np.all(np.abs(xy) <= half, axis=1) if len(xy) else np.zeros(0, bool)
    if inside.sum() >= 2 and rng.uniform() < 0.7:
        # both ends in rock fields: start at a major ROI (dense fields preferred), goal
        # at one about the net displacement away
        idx = np.flatnonzero(inside)
        i = idx[rng.choice(len(idx), p=density[idx] / density[idx].sum())]
        d = np.hypot(*(xy[idx] - xy[i]).T)
        far = idx[np.abs(d - net) < 0.05 * net]
        if len(far) == 0:
            return None
        g = far[rng.choice(len(far), p=density[far] / density[far].sum())]
        start = _beside(rng, xy, radius, i, xy[g])
        goal = _beside(rng, xy, radius, g, xy[i])
    else:
        start = rng.uniform(-half, half, 2)
        theta = rng.uniform(-np.pi, np.pi)
        goal = start + net * np.array([np.cos(theta), np.sin(theta)])
    if np.any(np.abs(start) > half) or np.any(np.abs(goal) > half):
        return None
    budget = target * 1.08  # corner cutting shortens the polyline a little
    pts, length, used = [start], 0.0, set()
    for _ in range(400):
        cur = pts[-1]
        step = target * rng.uniform(0.02, 0.07)
        cands = []
        if tree is not None:
            near = [j for j in tree.query_ball_point(cur, 2.0 * step) if j not in used]
            cands = [(j, _beside(rng, xy, radius, j, cur)) for j in near]
        if not cands:
            head = rng.uniform(-np.pi, np.pi)
            cands = [(-1, cur + step * np.array([np.cos(head), np.sin(head)]))]
        ok = [(j, p) for j, p in cands if np.all(np.abs(p) <= half) and
              length + np.hypot(*(p - cur)) + np.hypot(*(goal - p)) <= budget]
        if not ok:
            break
        # dense rock fields first, near ones first (weaving through a field is cheap)
        w = np.array([density[j] * np.exp(-np.hypot(*(p - cur)) / 30.0) if j >= 0 else 1.0
                      for j, p in ok]) + 1e-12
        j, p = ok[rng.choice(len(ok), p=w / w.sum())]
        used.add(j)
        length += float(np.hypot(*(p - cur)))
        pts.append(p)
    pts.append(goal)
    return pts


def plan_route(cfg: RouteConfig, catalogue: np.ndarray, extent: float,
               seed: int) -> Route:
    """Best of ``cfg.candidates`` random routes against the paper's statistics."""
    rng = rng_for(seed, "route")
    xy = np.column_stack([catalogue["x"], catalogue["y"]]) if len(catalogue) else \
        np.zeros((0, 2))
    radius = np.sqrt(catalogue["area_m2"] / np.pi) if len(catalogue) else np.zeros(0)
    tree = cKDTree(xy) if len(xy) else None
    # local ROI density (neighbours within 25 m): the planner prefers rock fields
    density = (np.array([len(n) for n in tree.query_ball_point(xy, 25.0)], float) ** 2
               if tree is not None else np.zeros(0))
    half = extent / 2 - cfg.edge_margin_m
    target = cfg.length_m
    lo, hi = cfg.rois_target
    best, best_score = None, np.inf
    for c in range(cfg.candidates):
        if c % 2:
            pts = _detour_waypoints(rng, xy, radius, tree, density, half, target,
                                    cfg.net_fraction)
            if pts is None:
                continue
        else:
            pts = _walk_waypoints(rng, xy, radius, tree, density, half, target)
        path = chaikin(np.array(pts))
        dense, s = resample(path, 0.05)
        if s[-1] < target * 0.9:
            continue
        dense, s = dense[s <= target], s[s <= target]
        net = float(np.hypot(*(dense[-1] - dense[0])))
        if tree is not None:
            dist, _ = cKDTree(dense).query(xy)
            passed = np.nonzero(dist < cfg.roi_range_m)[0]
            collide = int(np.sum(dist < radius + 0.8))
        else:
            passed, collide = np.zeros(0, int), 0
        n = len(passed)
        score = abs(net / s[-1] - cfg.net_fraction) * 15 + 10 * collide
        score += 5 * (1 - s[-1] / target)  # short of the length target
        score += 0 if lo <= n <= hi else min(abs(n - lo), abs(n - hi)) * 1.0
        score += 0.02 * abs(n - (lo + hi) / 2)  # prefer the middle of the range
        if score < best_score:
            best_score = score
            best = Route(dense, s, float(s[-1]), net, passed)
    if best is None:
        raise RuntimeError("route planner found no route: world too small for the route")
    return best


@dataclass
class Trajectory:
    """Rover motion on the IMU time grid (t[k] = k / rate)."""

    t: np.ndarray  # (K,) seconds from the bag start
    p: np.ndarray  # (K, 3) base_link origin, map frame
    q: np.ndarray  # (K, 4) base_link orientation (x, y, z, w), map frame
    s: np.ndarray  # (K,) arclength travelled
    moving: np.ndarray  # (K,) bool
    added_stop_s: float = 0.0  # stop time beyond the drawn durations (min_stop_s), s

    def rotations(self) -> Rotation:
        return Rotation.from_quat(self.q)


def _segment(length: float, v: float, a: float, dt: float) -> np.ndarray:
    """Arclength samples of a trapezoidal speed profile covering ``length``."""
    d_acc = v * v / (2 * a)
    if length < 2 * d_acc:  # triangle profile
        v = np.sqrt(length * a)
        d_acc = length / 2
    t_acc = v / a
    t_tot = 2 * t_acc + (length - 2 * d_acc) / v
    t = np.arange(0, t_tot + dt, dt)
    s = np.where(t < t_acc, 0.5 * a * t ** 2,
                 np.where(t < t_tot - t_acc, d_acc + v * (t - t_acc),
                          length - 0.5 * a * np.clip(t_tot - t, 0, None) ** 2))
    return np.clip(s, 0, length)


def drive(route: Route, cfg: RouteConfig, terrain: Terrain, rate: float,
          seed: int, min_stop_s: float = 0.0) -> Trajectory:
    """Time-sample the rover driving ``route`` with stops, riding on the terrain. A stop
    between drive segments lasts at least ``min_stop_s`` (a panorama's); the durations
    drawn are the same either way."""
    rng = rng_for(seed, "drive")
    added = 0.0
    dt = 1.0 / rate
    pieces, moving = [np.zeros(int(3 * rate))], [np.zeros(int(3 * rate), bool)]
    s0 = 0.0
    while s0 < route.length - 1e-6:
        seg = min(rng.uniform(*cfg.stop_every_m), route.length - s0)
        prof = s0 + _segment(seg, cfg.speed_mps, ACCEL_MPS2, dt)
        pieces.append(prof[1:])
        moving.append(np.ones(len(prof) - 1, bool))
        s0 += seg
        if s0 < route.length - 1e-6:
            drawn = rng.uniform(*cfg.stop_s)
            stop = max(drawn, min_stop_s)
            added += stop - drawn
        else:
            stop = 3.0
        n = int(stop * rate)
        pieces.append(np.full(n, s0))
        moving.append(np.zeros(n, bool))
    s = np.concatenate(pieces)
    mov = np.concatenate(moving)
    t = np.arange(len(s)) * dt
    x = np.interp(s, route.s, route.path[:, 0])
    y = np.interp(s, route.s, route.path[:, 1])
    # Heading from the path tangent (look 0.3 m ahead/behind: the rover's footprint).
    xa = np.interp(s + 0.3, route.s, route.path[:, 0])
    ya = np.interp(s + 0.3, route.s, route.path[:, 1])
    xb = np.interp(s - 0.3, route.s, route.path[:, 0])
    yb = np.interp(s - 0.3, route.s, route.path[:, 1])
    yaw = np.unwrap(np.arctan2(ya - yb, xa - xb))
    # Plane through the six wheel contacts: height, forward slope, lateral slope.
    wb, tr = WHEELBASE_M / 2, TRACK_M / 2
    offs = np.array([[dx, dy] for dx in (-wb, 0, wb) for dy in (-tr, tr)])
    c, sn = np.cos(yaw), np.sin(yaw)
    wx = x[:, None] + c[:, None] * offs[:, 0] - sn[:, None] * offs[:, 1]
    wy = y[:, None] + sn[:, None] * offs[:, 0] + c[:, None] * offs[:, 1]
    wz = terrain.height(wx, wy)
    z = wz.mean(axis=1)
    gx = (wz * offs[:, 0]).sum(axis=1) / (offs[:, 0] ** 2).sum()
    gy = (wz * offs[:, 1]).sum(axis=1) / (offs[:, 1] ** 2).sum()
    sig = BODY_SMOOTHING_S * rate
    z = gaussian_filter1d(z, sig, mode="nearest")
    pitch = gaussian_filter1d(-np.arctan(gx), sig, mode="nearest")
    roll = gaussian_filter1d(np.arctan(gy), sig, mode="nearest")
    yaw = gaussian_filter1d(yaw, sig / 2, mode="nearest")
    rot = Rotation.from_euler("ZYX", np.column_stack([yaw, pitch, roll]))
    return Trajectory(t, np.column_stack([x, y, z]), rot.as_quat(), s, mov, float(added))


#: A stop's first frame is taken this long after the wheels stop (the body settled, before
#: the mast moves: atacama_sim.panorama.STILL_S), s.
STOP_FRAME_DELAY_S = 1.0


def camera_indices(traj: Trajectory, spacing: float, stop_period: float,
                   rate: float, busy: np.ndarray | None = None) -> np.ndarray:
    """Grid indices of the stereo frames at the drive pose: every ``spacing`` metres of
    travel, once :data:`STOP_FRAME_DELAY_S` after the wheels stop (the end-of-drive view,
    before a panorama), then every ``stop_period`` seconds while stopped; none while
    ``busy`` (the mast away from the drive pose)."""
    idx = [0]
    last_s, last_t = traj.s[0], traj.t[0]
    stopped_at, stop_seen = None, True
    for k in range(1, len(traj.t)):
        if traj.moving[k]:
            stopped_at, stop_seen = None, False
        elif stopped_at is None:
            stopped_at = traj.t[k]
        if busy is not None and busy[k]:
            continue
        end_of_drive = (not stop_seen and stopped_at is not None
                        and traj.t[k] - stopped_at >= STOP_FRAME_DELAY_S)
        if end_of_drive or traj.s[k] - last_s >= spacing or (
                not traj.moving[k] and traj.t[k] - last_t >= stop_period):
            idx.append(k)
            last_s, last_t = traj.s[k], traj.t[k]
            if stopped_at is not None:
                stop_seen = True
    return np.array(idx)
