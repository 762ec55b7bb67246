"""Rocks and outcrops: the major ROIs (truth catalogue) and sub-threshold clutter.

- Rock shapes: :data:`N_TEMPLATES` irregular bodies made from an icosphere by low-frequency
  radial noise and random planar cuts (angular, faceted blocks), normalised so that the
  ground plane is z = 0, the top is z = 1, 35 % of the body is buried, and the silhouette
  centroid is at the origin. Each rock is an instance: template, anisotropic scale, yaw.
- Outcrops: tabular slabs draped on the terrain, with a star-shaped irregular outline,
  their own texture and albedo; one mesh each, in map coordinates.
- Clutter: rock instances below the area threshold, uniform plus debris aprons around
  the major rocks; not catalogued one by one.

Footprint ellipses: full axis lengths (major_m, minor_m) of the ellipse with the
silhouette's area and second moments, angle_rad of the major axis from map +x (CCW).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import ConvexHull, cKDTree

from atacama_sim.config import RockConfig, rng_for
from atacama_sim.terrain import Terrain

BURIED = 0.35  # fraction of a template's height below its ground plane

#: Distinct irregular rock shapes (templates).
N_TEMPLATES = 16
#: Share of the major ROIs placed uniformly rather than in clusters.
BACKGROUND_FRACTION = 0.15
#: Footprint area and height ranges of a rock, m^2 and m (the ROI definition).
ROCK_AREA_M2 = (0.6, 6.0)
ROCK_HEIGHT_M = (0.25, 2.0)
#: Footprint area and height ranges of an outcrop, m^2 and m.
OUTCROP_AREA_M2 = (8.0, 100.0)
OUTCROP_HEIGHT_M = (0.08, 0.30)
#: Exponent of the size-frequency law dN/dA ~ A^-SIZE_POWER (outcrops: SIZE_POWER - 0.3).
SIZE_POWER = 1.8
#: Least gap between major ROI footprints, m.
MIN_SEPARATION_M = 2.0
#: Debris rocks scattered around each major rock.
CLUTTER_APRON_PER_ROCK = 12
#: Diameter range of a clutter rock, m.
CLUTTER_DIAMETER_M = (0.08, 0.75)

# Instance columns (float32 rows uploaded to the GPU).
INST_FIELDS = ("x", "y", "z", "sx", "sy", "sz", "yaw", "r", "g", "b", "label", "template")
INST = {name: i for i, name in enumerate(INST_FIELDS)}


def icosphere(subdiv: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit icosphere: (vertices (V, 3), faces (F, 3)). Written by hand (tiny, no deps)."""
    t = (1 + 5 ** 0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t),
         (0, -1, -t), (0, 1, -t), (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4),
         (11, 10, 2), (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8),
         (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    verts = [np.array(p, float) / np.linalg.norm(p) for p in v]
    faces = f
    for _ in range(subdiv):
        cache: dict[tuple[int, int], int] = {}

        def mid(a: int, b: int, cache: dict = cache) -> int:
            key = (min(a, b), max(a, b))
            if key not in cache:
                m = verts[a] + verts[b]
                verts.append(m / np.linalg.norm(m))
                cache[key] = len(verts) - 1
            return cache[key]

        new = []
        for a, b, c in faces:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            new += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        faces = new
    return np.array(verts), np.array(faces, dtype=np.int64)


def polygon_moments(poly: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
    """Area, centroid (2,) and covariance (2, 2) of a simple polygon (N, 2), CCW or CW."""
    x, y = poly[:, 0], poly[:, 1]
    x1, y1 = np.roll(x, -1), np.roll(y, -1)
    cr = x * y1 - x1 * y
    a = cr.sum() / 2
    cx = ((x + x1) * cr).sum() / (6 * a)
    cy = ((y + y1) * cr).sum() / (6 * a)
    sxx = ((x * x + x * x1 + x1 * x1) * cr).sum() / (12 * a) - cx * cx
    syy = ((y * y + y * y1 + y1 * y1) * cr).sum() / (12 * a) - cy * cy
    sxy = ((x * y1 + 2 * x * y + 2 * x1 * y1 + x1 * y) * cr).sum() / (24 * a) - cx * cy
    return abs(a), np.array([cx, cy]), np.array([[sxx, sxy], [sxy, syy]])


def ellipse_of(cov: np.ndarray) -> tuple[float, float, float]:
    """(major_m, minor_m, angle_rad) full axes of the uniform ellipse with covariance cov."""
    w, v = np.linalg.eigh(cov)
    major, minor = 4 * np.sqrt(max(w[1], 0)), 4 * np.sqrt(max(w[0], 0))
    ang = float(np.arctan2(v[1, 1], v[0, 1]))
    ang = (ang + np.pi / 2) % np.pi - np.pi / 2  # an axis: angle modulo pi
    return float(major), float(minor), ang


@dataclass
class RockTemplate:
    """One unit rock shape: flat-shaded triangles and its silhouette statistics."""

    positions: np.ndarray  # (3F, 3) float32, triangle soup
    normals: np.ndarray  # (3F, 3) float32
    area: float  # silhouette area at unit scale
    cov: np.ndarray  # silhouette covariance at unit scale


def make_templates(n: int, seed: int, subdiv: int = 3) -> list[RockTemplate]:
    """``n`` irregular rock shapes."""
    rng = rng_for(seed, "rock_templates")
    sv, faces = icosphere(subdiv)
    out = []
    for _ in range(n):
        r = np.ones(len(sv))
        for _k in range(6):  # low-frequency lumps
            d = rng.normal(size=3)
            d /= np.linalg.norm(d)
            r += 0.10 * rng.uniform(0.3, 1) * np.cos(rng.uniform(1, 3.5) * sv @ d
                                                     + rng.uniform(0, 2 * np.pi))
        for _k in range(rng.integers(4, 9)):  # planar cuts: angular facets
            nrm = rng.normal(size=3)
            nrm /= np.linalg.norm(nrm)
            off = rng.uniform(0.62, 0.92)
            dot = sv @ nrm
            r = np.where(dot > 1e-6, np.minimum(r, off / np.maximum(dot, 1e-6)), r)
        p = sv * r[:, None]
        p[:, 2] *= rng.uniform(0.75, 1.0)
        z0, z1 = p[:, 2].min(), p[:, 2].max()
        p[:, 2] = -BURIED + (1 + BURIED) * (p[:, 2] - z0) / (z1 - z0)
        # Silhouette (top-down) of the part above ground: hull of vertices with z >= 0.
        above = p[p[:, 2] >= 0, :2]
        hull = above[ConvexHull(above).vertices]
        area, c, _ = polygon_moments(hull)
        p[:, :2] -= c
        s = 1.0 / np.sqrt(area)  # unit silhouette area
        p[:, :2] *= s
        area, _, cov = polygon_moments((hull - c) * s)
        tri = p[faces]  # (F, 3, 3)
        nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
        nrm /= np.linalg.norm(nrm, axis=1, keepdims=True)
        out.append(RockTemplate(tri.reshape(-1, 3).astype(np.float32),
                                np.repeat(nrm, 3, axis=0).astype(np.float32), area, cov))
    return out


def _power_law(rng: np.random.Generator, lo: float, hi: float, p: float, n: int) -> np.ndarray:
    """Samples of dN/dA ~ A^-p on [lo, hi] (inverse CDF)."""
    u = rng.uniform(size=n)
    a, b = lo ** (1 - p), hi ** (1 - p)
    return (a + u * (b - a)) ** (1 / (1 - p))


@dataclass
class Outcrop:
    """A tabular outcrop: outline (map frame) and mesh (triangle soup, map frame)."""

    outline: np.ndarray  # (K, 2)
    positions: np.ndarray  # (3F, 3) float32
    normals: np.ndarray  # (3F, 3) float32


@dataclass
class RockField:
    """All rocks of the world.

    Attributes:
        templates: rock shapes (1280 triangles; major rocks).
        templates_low: the same shapes at 320 triangles, drawn for clutter.
        majors: (N, 12) float32 instances of major rocks (label = catalogue id).
        clutter: (M, 12) float32 instances of sub-threshold rocks (label 0).
        outcrops: outcrop meshes, catalogue ids in ``outcrop_ids``.
        outcrop_ids: ids of the outcrops in the catalogue.
        catalogue: structured array (roi_network ROI_DTYPE fields), map frame.
    """

    templates: list[RockTemplate]
    templates_low: list[RockTemplate]  # the same shapes, 320 triangles (clutter)
    majors: np.ndarray
    clutter: np.ndarray
    outcrops: list[Outcrop]
    outcrop_ids: np.ndarray
    catalogue: np.ndarray


def _outcrop_mesh(rng: np.random.Generator, terrain: Terrain, cx: float, cy: float,
                  area: float, elong: float, angle: float, height: float) -> Outcrop:
    n_t, n_r = 48, 6
    th = np.linspace(0, 2 * np.pi, n_t, endpoint=False)
    rad = np.ones(n_t)
    for k in range(2, 7):  # star-shaped irregular outline
        rad += rng.uniform(0.02, 0.07) * np.cos(k * th + rng.uniform(0, 2 * np.pi))
    a = np.sqrt(area / (np.pi * elong))
    b = a * elong
    lx, ly = a * rad * np.cos(th), b * rad * np.sin(th)
    ca, sa = np.cos(angle), np.sin(angle)
    ox, oy = ca * lx - sa * ly, sa * lx + ca * ly
    outline = np.column_stack([cx + ox, cy + oy])
    # Rescale so the outline's area is exactly the requested area.
    ar, _, _ = polygon_moments(outline)
    s = np.sqrt(area / ar)
    outline = np.column_stack([cx + ox * s, cy + oy * s])
    rings = []
    for k in range(n_r + 1):
        f = k / n_r
        xy = np.column_stack([cx + (outline[:, 0] - cx) * f, cy + (outline[:, 1] - cy) * f])
        z = terrain.height(xy[:, 0], xy[:, 1]) + height * (0.72 + 0.28 * (1 - f * f))
        rings.append(np.column_stack([xy, z]))
    foot = np.column_stack([outline, terrain.height(outline[:, 0], outline[:, 1]) - 0.15])
    tris = []
    for i in range(n_t):
        j = (i + 1) % n_t
        tris.append((rings[0][i], rings[1][i], rings[1][j]))
        for k in range(1, n_r):
            tris.append((rings[k][i], rings[k + 1][i], rings[k + 1][j]))
            tris.append((rings[k][i], rings[k + 1][j], rings[k][j]))
        e = rings[n_r]
        tris.append((e[i], foot[i], foot[j]))
        tris.append((e[i], foot[j], e[j]))
    tri = np.array(tris)  # (F, 3, 3)
    nrm = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    nrm /= np.linalg.norm(nrm, axis=1, keepdims=True) + 1e-12
    flip = nrm[:, 2] < 0
    # Walls: outward normals; tops: up.
    centre = np.array([cx, cy])
    outward = ((tri[:, :, :2].mean(axis=1) - centre) * nrm[:, :2]).sum(axis=1) < 0
    wall = np.abs(nrm[:, 2]) < 0.5
    nrm[(~wall) & flip] *= -1
    nrm[wall & outward] *= -1
    return Outcrop(outline, tri.reshape(-1, 3).astype(np.float32),
                   np.repeat(nrm, 3, axis=0).astype(np.float32))


def generate_rocks(cfg: RockConfig, terrain: Terrain, seed: int,
                   focus_xy: np.ndarray | None = None) -> RockField:
    """Place major ROIs (clustered) and clutter on ``terrain``.

    ``focus_xy`` (optional, (2,)) adds one cluster centred there (used by the tiny preset so
    that its short route meets rocks).
    """
    rng = rng_for(seed, "rocks")
    templates = make_templates(N_TEMPLATES, seed)
    half = terrain.extent / 2 - 3.0
    area_km2 = (2 * half / 1000) ** 2
    n_major = rng.poisson(cfg.major_per_km2 * area_km2)
    n_clusters = max(1, rng.poisson(cfg.clusters_per_km2 * area_km2))
    centres = rng.uniform(-half, half, size=(n_clusters, 2))
    if focus_xy is not None:
        centres[0] = focus_xy
    placed: list[tuple[float, float, float]] = []  # x, y, radius
    rows = []
    attempts = 0
    while len(rows) < n_major and attempts < 50 * n_major + 100:
        attempts += 1
        if rng.uniform() < BACKGROUND_FRACTION:
            xy = rng.uniform(-half, half, size=2)
        else:
            xy = centres[rng.integers(n_clusters)] + rng.normal(0, cfg.cluster_sigma_m, 2)
        if np.any(np.abs(xy) > half - 4):
            continue
        outcrop = rng.uniform() < cfg.outcrop_fraction
        if outcrop:
            area = float(_power_law(rng, *OUTCROP_AREA_M2, SIZE_POWER - 0.3, 1)[0])
            height = float(rng.uniform(*OUTCROP_HEIGHT_M))
            elong = float(rng.uniform(0.4, 0.95))
        else:
            area = float(_power_law(rng, *ROCK_AREA_M2, SIZE_POWER, 1)[0])
            height = float(np.clip(np.sqrt(area) * rng.uniform(0.35, 0.85),
                                   *ROCK_HEIGHT_M))
            elong = float(rng.uniform(0.55, 1.0))
        radius = np.sqrt(area / (np.pi * elong))
        if any(np.hypot(xy[0] - px, xy[1] - py) < radius + pr + MIN_SEPARATION_M
               for px, py, pr in placed):
            continue
        placed.append((float(xy[0]), float(xy[1]), float(radius)))
        rows.append((xy[0], xy[1], outcrop, area, height, elong,
                     rng.uniform(-np.pi, np.pi), int(rng.integers(N_TEMPLATES))))

    cat_fields = [("x", "<f8"), ("y", "<f8"), ("z", "<f8"), ("id", "<u4"), ("label", "u1"),
                  ("area_m2", "<f4"), ("height_m", "<f4"), ("major_m", "<f4"),
                  ("minor_m", "<f4"), ("angle_rad", "<f4")]
    catalogue = np.zeros(len(rows), dtype=cat_fields)
    majors, outcrops, outcrop_ids = [], [], []
    for i, (x, y, is_out, area, height, elong, yaw, tpl) in enumerate(rows):
        rid = i + 1
        zc = float(terrain.height(x, y))
        if is_out:
            oc = _outcrop_mesh(rng, terrain, x, y, area, elong, yaw, height)
            a, c, cov = polygon_moments(oc.outline)
            outcrops.append(oc)
            outcrop_ids.append(rid)
            major, minor, ang = ellipse_of(cov)
            catalogue[i] = (c[0], c[1], zc, rid, 2, a, height, major, minor, ang)
            continue
        t = templates[tpl]
        sy = np.sqrt(area * elong / t.area)
        sx = sy / elong
        # Sit the rock so no part of its footprint floats (lowest ground under it).
        rr = np.sqrt(area / np.pi)
        ring = np.linspace(0, 2 * np.pi, 12, endpoint=False)
        zg = float(np.min(terrain.height(x + rr * np.cos(ring), y + rr * np.sin(ring))))
        zb = min(zc, zg)
        sz = height + (zc - zb)  # top at zc + height
        col = _rock_colour(rng)
        majors.append((x, y, zb, sx, sy, sz, yaw, *col, rid, tpl))
        c, s = np.cos(yaw), np.sin(yaw)
        rot = np.array([[c, -s], [s, c]]) @ np.diag([sx, sy])
        major, minor, ang = ellipse_of(rot @ t.cov @ rot.T)
        catalogue[i] = (x, y, zc, rid, 1, t.area * sx * sy, height, major, minor, ang)

    clutter = _clutter(rng, cfg, terrain, templates, np.array(majors).reshape(-1, 12),
                       catalogue, outcrops, half)
    templates_low = make_templates(N_TEMPLATES, seed, subdiv=2)
    return RockField(templates, templates_low, np.array(majors, np.float32).reshape(-1, 12),
                     clutter, outcrops, np.array(outcrop_ids, np.int64), catalogue)


def _rock_colour(rng: np.random.Generator) -> tuple[float, float, float]:
    """Varnished dark andesite to pale tuff; reddish-brown bias of the Atacama."""
    v = rng.uniform(0.16, 0.5)
    warm = rng.uniform(1.0, 1.2)
    return (v * warm, v, v / warm * rng.uniform(0.85, 1.0))


def _clutter(rng: np.random.Generator, cfg: RockConfig, terrain: Terrain,
             templates: list[RockTemplate], majors: np.ndarray, catalogue: np.ndarray,
             outcrops: list[Outcrop], half: float) -> np.ndarray:
    n_uni = rng.poisson(cfg.clutter_per_m2 * (2 * half) ** 2)
    xy = rng.uniform(-half, half, size=(n_uni, 2))
    aprons = []
    for m in majors:
        r = np.sqrt(m[INST["sx"]] * m[INST["sy"]])
        k = CLUTTER_APRON_PER_ROCK
        ang = rng.uniform(0, 2 * np.pi, k)
        dist = r * (0.9 + rng.exponential(1.2, k))
        aprons.append(np.column_stack([m[0] + dist * np.cos(ang), m[1] + dist * np.sin(ang)]))
    if aprons:
        xy = np.vstack([xy, *aprons])
    xy = xy[np.all(np.abs(xy) < half, axis=1)]
    # Keep clutter off the major ROIs' footprints.
    if len(catalogue):
        tree = cKDTree(np.column_stack([catalogue["x"], catalogue["y"]]))
        rmax = catalogue["major_m"] / 2 + 0.3
        keep = np.ones(len(xy), bool)
        for i, idx in enumerate(tree.query_ball_point(xy, r=float(rmax.max()))):
            for j in idx:
                if np.hypot(*(xy[i] - (catalogue["x"][j], catalogue["y"][j]))) < rmax[j]:
                    keep[i] = False
                    break
        xy = xy[keep]
    n = len(xy)
    d0, d1 = CLUTTER_DIAMETER_M
    u = rng.uniform(size=n)
    diam = d0 * (d1 / d0) ** (u ** 2.5)
    tpl = rng.integers(len(templates), size=n)
    elong = rng.uniform(0.55, 1.0, n)
    t_area = np.array([t.area for t in templates])[tpl]
    area = np.pi * diam ** 2 / 4
    sy = np.sqrt(area * elong / t_area)
    sx = sy / elong
    sz = diam * rng.uniform(0.25, 0.6, n) + 0.01
    z = terrain.height(xy[:, 0], xy[:, 1]) - 0.01
    v = rng.uniform(0.18, 0.55, n)
    warm = rng.uniform(1.0, 1.2, n)
    out = np.column_stack([xy, z, sx, sy, sz, rng.uniform(-np.pi, np.pi, n),
                           v * warm, v, v / warm, np.zeros(n), tpl])
    return out.astype(np.float32)
