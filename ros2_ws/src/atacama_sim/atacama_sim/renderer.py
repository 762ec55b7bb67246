"""Rasteriser of the 3D world (OpenGL 4.3 core through moderngl, headless EGL).

What is drawn, per view:
- the terrain as world-fixed grid patches from a quadtree level of detail (5 cm cells near
  the camera, 12.8 m far away); the vertex shader evaluates the terrain height function
  of :mod:`atacama_sim.terrain` exactly (texel fetches, same bilinear arithmetic), so the
  geometry does not depend on the view and left/right see the same surface; patch skirts
  hide the cracks between levels;
- rocks as instanced irregular meshes (indexed: vertices shaded once, facet normals from
  screen-space derivatives), outcrops as draped slab meshes;
- per-pixel shading: albedo (material map x two-scale detail textures), bump normals from
  the detail height maps and the roughness tile, Lambert sun + sky ambient, cast shadows
  from a sun shadow map (3x3 PCF), aerial perspective, sky.
Outputs are linear radiance (float), optical depth Z (metres) and a label image (truth id
of the major ROI drawn at each pixel, 0 elsewhere).
"""

from __future__ import annotations

from collections import OrderedDict

import numpy as np

from atacama_sim.camera import StereoRig
from atacama_sim.config import SunConfig
from atacama_sim.rocks import INST, RockField
from atacama_sim.terrain import Terrain
from atacama_sim.texture import GroundTextures

PATCH = 16  # cells per patch side
MAX_PATCHES_PER_DRAW = 2048
PATCH_CACHE = 8000  # patches kept (about 55 MB)
LEVEL_CELLS = tuple(0.05 * 2**k for k in range(9))  # cell size per level: 5 cm .. 12.8 m
SPLIT_FACTOR = 3.0  # split a patch when the camera is closer than factor x its size
# (cells then subtend at most fx / (SPLIT_FACTOR * PATCH) ~ 16 px)
SUN_IRRADIANCE = 1.0  # direct sunlight on a surface facing the sun (linear radiance units)
SKY_AMBIENT = 0.16  # diffuse sky light (same units)
CAMERA_NEAR_M = 0.2  # near clipping plane of the rover cameras, m
CAMERA_FAR_M = 2000.0  # far clipping plane of the rover cameras, m
HAZE_M = 3000.0  # aerial-perspective e-folding distance of the rover views, m

_COMMON = """
#version 430
uniform sampler2D u_hmap;
uniform sampler2D u_rough;
uniform vec2 u_horigin;
uniform float u_hres;
uniform float u_rres;
float base_h(vec2 p) {
    ivec2 n = textureSize(u_hmap, 0);
    vec2 f = clamp((p - u_horigin) / u_hres, vec2(0.0), vec2(n - 1));
    ivec2 i0 = min(ivec2(floor(f)), n - 2);
    vec2 t = f - vec2(i0);
    float a = texelFetch(u_hmap, i0, 0).r * (1.0 - t.x)
            + texelFetch(u_hmap, i0 + ivec2(1, 0), 0).r * t.x;
    float b = texelFetch(u_hmap, i0 + ivec2(0, 1), 0).r * (1.0 - t.x)
            + texelFetch(u_hmap, i0 + ivec2(1, 1), 0).r * t.x;
    return a * (1.0 - t.y) + b * t.y;
}
vec3 rough_hg(vec2 p) {  // roughness height and its gradient
    ivec2 n = textureSize(u_rough, 0);
    vec2 f = p / u_rres;
    vec2 fl = floor(f);
    vec2 t = f - fl;
    ivec2 i0 = ivec2(fl);
    i0 = ((i0 % n) + n) % n;
    ivec2 i1 = (i0 + 1) % n;
    float h00 = texelFetch(u_rough, i0, 0).r, h10 = texelFetch(u_rough, ivec2(i1.x, i0.y), 0).r;
    float h01 = texelFetch(u_rough, ivec2(i0.x, i1.y), 0).r, h11 = texelFetch(u_rough, i1, 0).r;
    float a = h00 * (1.0 - t.x) + h10 * t.x;
    float b = h01 * (1.0 - t.x) + h11 * t.x;
    float gx = ((h10 - h00) * (1.0 - t.y) + (h11 - h01) * t.y) / u_rres;
    float gy = (b - a) / u_rres;
    return vec3(a * (1.0 - t.y) + b * t.y, gx, gy);
}
"""

_TERRAIN_VS = _COMMON + """
uniform mat4 u_vp;
uniform mat4 u_view;
in vec3 a_pos;   // map frame, the terrain height function evaluated on the CPU
in vec2 a_grad;  // gradient of the base grid (shading normal)
out vec3 v_world;
out vec3 v_nbase;
out float v_z;
void main() {
    v_nbase = normalize(vec3(-a_grad, 1.0));
    v_world = a_pos;
    v_z = (u_view * vec4(v_world, 1.0)).z;
    gl_Position = u_vp * vec4(v_world, 1.0);
}
"""

_LIGHTING = """
uniform sampler2DShadow u_shadow;
uniform mat4 u_light_vp;
uniform float u_sbias;
uniform vec3 u_sun;
uniform float u_irr;
uniform float u_amb;
uniform vec3 u_cam;
uniform float u_haze;
uniform vec3 u_sky_h;
uniform sampler2D u_detail_a;
uniform sampler2D u_detail_b;
uniform float u_dperiod;
float shadow_at(vec3 p, vec3 n) {
    vec4 s = u_light_vp * vec4(p + n * 0.02, 1.0);
    vec3 c = s.xyz / s.w * 0.5 + 0.5;
    if (c.x <= 0.0 || c.x >= 1.0 || c.y <= 0.0 || c.y >= 1.0 || c.z >= 1.0) return 1.0;
    // one tap: linear filtering of the depth comparison is a 2x2 PCF
    return texture(u_shadow, vec3(c.xy, c.z - u_sbias));
}
vec3 shade(vec3 albedo, vec3 p, vec3 n) {
    float lit = max(dot(n, u_sun), 0.0);
    float sh = lit > 0.0 ? shadow_at(p, n) : 1.0;
    vec3 radiance = albedo * (u_irr * lit * sh + u_amb * (0.55 + 0.45 * n.z));
    if (u_haze > 0.0) {
        float f = 1.0 - exp(-distance(p, u_cam) / u_haze);
        radiance = mix(radiance, u_sky_h, f);
    }
    return radiance;
}
// the detail tile, rotated against the map axes so that its period does not line up
// with the terrain grid
vec4 detail2(sampler2D t, vec2 p) {
    return texture(t, mat2(0.8, 0.6, -0.6, 0.8) * p / u_dperiod);
}
"""

_TERRAIN_FS = _COMMON + _LIGHTING + """
uniform sampler2D u_material;
uniform vec3 u_soil;
uniform vec3 u_gravel;
uniform vec3 u_pav;
in vec3 v_world;
in vec3 v_nbase;
in float v_z;
layout(location = 0) out vec4 o_rad;
layout(location = 1) out float o_z;
layout(location = 2) out float o_label;
vec4 ground(vec2 p, vec4 m, out vec3 alb) {
    vec4 a = detail2(u_detail_a, p);
    vec4 b = detail2(u_detail_b, p);
    float k = 255.0 / 128.0;
    // soil carries a sparse share of the gravel clasts too (desert soils are never bare)
    vec3 c = mix(u_soil * b.r * k * (0.55 + 0.45 * a.r * k), u_gravel * a.r * k, m.r);
    c = mix(c, u_pav * a.b * k, m.g);
    alb = c * m.b * k;
    float h = mix(mix(b.g + 0.5 * a.g, a.g, m.r), a.a, m.g) * 0.04;
    return vec4(h);
}
void main() {
    vec2 p = v_world.xy;
    ivec2 n = textureSize(u_material, 0);
    vec4 m = texture(u_material, ((p - u_horigin) / u_hres + 0.5) / vec2(n));
    vec3 alb;
    float h0 = ground(p, m, alb).x;
    // bump gradient in the ground plane from screen-space derivatives (2x2 solve)
    vec2 px = dFdx(p), py = dFdy(p);
    float det = px.x * py.y - px.y * py.x;
    vec2 gb = abs(det) > 1e-12
        ? vec2(py.y * dFdx(h0) - px.y * dFdy(h0), -py.x * dFdx(h0) + px.x * dFdy(h0)) / det
        : vec2(0.0);
    vec3 nrm = normalize(v_nbase + vec3(-gb.x, -gb.y, 0.0));
    o_rad = vec4(shade(alb, v_world, nrm), 0.0);
    o_z = v_z;
    o_label = 0.0;
}
"""

_ROCK_VS = """
#version 430
uniform mat4 u_vp;
uniform mat4 u_view;
in vec3 a_pos;
in vec3 i_pos;
in vec3 i_scale;
in float i_yaw;
in vec3 i_col;
in float i_label;
out vec3 v_world;
out vec3 v_rel;
out vec3 v_obj;
out vec3 v_col;
out float v_label;
out float v_z;
void main() {
    float c = cos(i_yaw), s = sin(i_yaw);
    mat3 rz = mat3(c, s, 0.0, -s, c, 0.0, 0.0, 0.0, 1.0);
    v_rel = rz * (a_pos * i_scale);
    vec3 w = i_pos + v_rel;
    v_obj = a_pos * i_scale + vec3(i_pos.xy * 0.37, 0.0);
    v_world = w;
    v_col = i_col;
    v_label = i_label;
    v_z = (u_view * vec4(w, 1.0)).z;
    gl_Position = u_vp * vec4(w, 1.0);
}
"""

_ROCK_FS = "#version 430\n" + _LIGHTING + """
in vec3 v_world;
in vec3 v_rel;
in vec3 v_obj;
in vec3 v_col;
in float v_label;
in float v_z;
layout(location = 0) out vec4 o_rad;
layout(location = 1) out float o_z;
layout(location = 2) out float o_label;
void main() {
    // flat shading: the facet normal from screen-space derivatives of the position
    // (relative to the instance, for precision), turned towards the viewer
    vec3 n = normalize(cross(dFdx(v_rel), dFdy(v_rel)));
    if (dot(n, u_cam - v_world) < 0.0) n = -n;
    vec3 w = abs(n) / (abs(n.x) + abs(n.y) + abs(n.z));
    float k = 255.0 / 128.0;
    // triplanar rock texture in object coordinates
    float t = w.x * detail2(u_detail_b, v_obj.yz * 1.3).b
            + w.y * detail2(u_detail_b, v_obj.xz * 1.3).b
            + w.z * detail2(u_detail_b, v_obj.xy * 1.3).b;
    o_rad = vec4(shade(pow(v_col, vec3(2.2)) * t * k, v_world, n), v_label);
    o_z = v_z;
    o_label = v_label;
}
"""

_SKY_VS = """
#version 430
in vec2 a_xy;
void main() { gl_Position = vec4(a_xy, 1.0, 1.0); }  // on the far plane
"""

_SKY_FS = """
#version 430
uniform mat3 u_rwc;
uniform vec4 u_k;  // fx fy cx cy
uniform float u_h;
uniform vec3 u_sky_h;
uniform vec3 u_sky_z;
layout(location = 0) out vec4 o_rad;
layout(location = 1) out float o_z;
layout(location = 2) out float o_label;
void main() {
    float u = gl_FragCoord.x - 0.5, v = u_h - gl_FragCoord.y - 0.5;
    vec3 d = normalize(u_rwc * vec3((u - u_k.z) / u_k.x, (v - u_k.w) / u_k.y, 1.0));
    float e = clamp(d.z, 0.0, 1.0);
    o_rad = vec4(mix(u_sky_h, u_sky_z, pow(e, 0.6)), 0.0);
    o_z = 0.0;
    o_label = 0.0;
}
"""

_DEPTH_FS = """
#version 430
void main() { }
"""


def look_at_light(sun: np.ndarray, centre: np.ndarray, half: float,
                  depth: float = 2000.0) -> np.ndarray:
    """Orthographic view-projection of the sun looking at ``centre`` (box +-half)."""
    f = -sun / np.linalg.norm(sun)
    up = np.array([0.0, 0.0, 1.0]) if abs(f[2]) < 0.99 else np.array([0.0, 1.0, 0.0])
    r = np.cross(f, up)
    r /= np.linalg.norm(r)
    u = np.cross(r, f)
    eye = centre - f * depth / 2
    view = np.eye(4)
    view[0, :3], view[1, :3], view[2, :3] = r, u, -f
    view[:3, 3] = -view[:3, :3] @ eye
    proj = np.diag([1 / half, 1 / half, -2 / depth, 1.0])
    proj[2, 3] = -1.0
    return proj @ view


def sun_vector(sun: SunConfig | np.ndarray) -> np.ndarray:
    """Unit vector towards the sun, map frame: a fixed :class:`SunConfig` (azimuth
    clockwise from grid north) or a direction (3,) as given (normalised)."""
    if not isinstance(sun, SunConfig):
        v = np.asarray(sun, float).reshape(3)
        return v / np.linalg.norm(v)
    el, az = np.radians(sun.elevation_deg), np.radians(sun.azimuth_deg)
    return np.array([np.sin(az) * np.cos(el), np.cos(az) * np.cos(el), np.sin(el)])


def select_patches(cam_xy: np.ndarray, fwd_xy: np.ndarray | None, half_angle: float,
                   limit: float, radius_all: float = 3.0, min_level: int = 0,
                   cam_height: float = 0.0) -> np.ndarray:
    """Quadtree level-of-detail patches around a camera: (N, 3) rows (x0, y0, cell).

    Patches lie on a world-fixed grid per level, so geometry never depends on the view.
    ``fwd_xy`` None selects every patch within ``limit`` (shadow or top-down use).
    Patches come sorted near to far, so early depth rejection saves shading.
    The quadtree is walked one level at a time over arrays of patches.
    """
    cam_xy = np.asarray(cam_xy, np.float64)
    top = len(LEVEL_CELLS) - 1
    size_top = LEVEL_CELLS[top] * PATCH
    lo = np.floor((cam_xy - limit) / size_top) * size_top
    hi = cam_xy + limit
    gx, gy = np.meshgrid(np.arange(lo[0], hi[0], size_top), np.arange(lo[1], hi[1], size_top),
                         indexing="ij")
    cur = np.column_stack([gx.ravel(), gy.ravel()])
    cos_lim = np.cos(half_angle)
    # corners and centre of a unit patch: the view-wedge test
    probe = np.array([[0, 0], [1, 0], [0, 1], [1, 1], [0.5, 0.5]])
    out = []
    for lev in range(top, -1, -1):
        if len(cur) == 0:
            break
        size = LEVEL_CELLS[lev] * PATCH
        # distance from the camera to each patch rectangle
        d = np.maximum(np.maximum(cur - cam_xy, cam_xy - (cur + size)), 0.0)
        dist = np.hypot(d[:, 0], d[:, 1])
        keep = dist <= limit
        if fwd_xy is not None:
            pts = cur[:, None, :] + probe[None] * size - cam_xy
            nrm = np.linalg.norm(pts, axis=2) + 1e-9
            inside = ((pts @ fwd_xy) / nrm > cos_lim).any(axis=1)
            # a big patch may straddle the wedge with all corners outside it
            keep &= (dist <= radius_all) | inside | (size >= dist)
        cur, dist = cur[keep], dist[keep]
        split = (np.hypot(dist, cam_height) < SPLIT_FACTOR * size) if lev > min_level \
            else np.zeros(len(cur), bool)
        leaves = cur[~split]
        out.append(np.column_stack([leaves, np.full(len(leaves), LEVEL_CELLS[lev])]))
        s2 = LEVEL_CELLS[lev - 1] * PATCH if lev > 0 else 0.0
        kids = np.array([[0, 0], [0, 1], [1, 0], [1, 1]]) * s2
        cur = (cur[split][:, None, :] + kids[None]).reshape(-1, 2)
    arr = np.concatenate(out).astype(np.float32).reshape(-1, 3)
    centre = arr[:, :2] + arr[:, 2:3] * (PATCH / 2)
    return arr[np.argsort(np.hypot(*(centre - cam_xy).T), kind="stable")]


def _patch_template() -> tuple[np.ndarray, np.ndarray]:
    """One patch as an indexed mesh: vertices (V, 3) float32 (i, j, skirt) and triangle
    indices (3T,) int32; a skirt (vertical strip) hangs below each patch edge."""
    n = PATCH + 1
    g = np.arange(n, dtype=np.float32)
    jj, ii = np.meshgrid(g, g)
    top = np.column_stack([jj.ravel(), ii.ravel(), np.zeros(n * n, np.float32)])
    k = np.arange(n * n).reshape(n, n)
    a, b, c, d = k[:-1, :-1], k[:-1, 1:], k[1:, 1:], k[1:, :-1]
    idx = [np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)]
    ring = np.concatenate([k[0, :-1], k[:-1, -1], k[-1, :0:-1], k[:0:-1, 0]])
    bottom = top[ring].copy()
    bottom[:, 2] = 1.0
    rb = n * n + np.arange(len(ring))
    r1, rb1 = np.roll(ring, -1), np.roll(rb, -1)
    idx += [np.stack([ring, r1, rb1], -1), np.stack([ring, rb1, rb], -1)]
    verts = np.vstack([top, bottom]).astype(np.float32)
    return verts, np.concatenate(idx).astype(np.int32).ravel()


class SceneRenderer:
    """One GL context holding the world; renders rover views and top-down tiles."""

    SHADOW_HALF = 40.0  # half side of the rover-view shadow map, metres
    SHADOW_DEPTH = 300.0  # depth range of the sun's orthographic view, metres
    #: The shadow map is rendered again when the sun has moved this much since (deg): a
    #: 2 m rock's shadow tip then moves 8 mm at 42 deg elevation, under a pixel at 3 m.
    SHADOW_SUN_STEP_DEG = 0.1

    def __init__(self, terrain: Terrain, textures: GroundTextures, rocks: RockField,
                 albedo_rgb: tuple[tuple[float, ...], ...], size: tuple[int, int],
                 shadow_px: int = 3072) -> None:
        import moderngl  # deferred: only the renderer needs a GL context

        if len(rocks.catalogue) > 2048:
            raise ValueError("label ids are stored in a half float: at most 2048 ROIs")
        self.ctx = moderngl.create_standalone_context(backend="egl", require=430)
        ctx = self.ctx
        self.terrain, self.rocks = terrain, rocks
        self.size = size
        # -- textures
        self.t_h = ctx.texture(terrain.base.shape[::-1], 1, terrain.base.tobytes(), dtype="f4")
        self.t_r = ctx.texture(terrain.rough.shape[::-1], 1, terrain.rough.tobytes(), dtype="f4")
        for t in (self.t_h, self.t_r):
            t.filter = (moderngl.NEAREST, moderngl.NEAREST)
        self.t_m = ctx.texture(textures.material.shape[1::-1], 4, textures.material.tobytes())
        self.t_m.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self.t_m.repeat_x = self.t_m.repeat_y = False
        self.t_da = ctx.texture(textures.detail_a.shape[1::-1], 4, textures.detail_a.tobytes())
        self.t_db = ctx.texture(textures.detail_b.shape[1::-1], 4, textures.detail_b.tobytes())
        for t in (self.t_da, self.t_db):
            t.build_mipmaps()
            t.filter = (moderngl.LINEAR_MIPMAP_LINEAR, moderngl.LINEAR)
        self.dperiod = textures.detail_a.shape[0] * textures.detail_res
        # -- programs
        self.p_ter = ctx.program(vertex_shader=_TERRAIN_VS, fragment_shader=_TERRAIN_FS)
        self.p_ter_d = ctx.program(vertex_shader=_TERRAIN_VS, fragment_shader=_DEPTH_FS)
        self.p_rock = ctx.program(vertex_shader=_ROCK_VS, fragment_shader=_ROCK_FS)
        self.p_rock_d = ctx.program(vertex_shader=_ROCK_VS, fragment_shader=_DEPTH_FS)
        self.p_sky = ctx.program(vertex_shader=_SKY_VS, fragment_shader=_SKY_FS)
        # configured colours are sRGB-like; shading happens in linear units
        soil, gravel, pav = (tuple(float(v) ** 2.2 for v in c) for c in albedo_rgb)
        for p in (self.p_ter, self.p_ter_d):
            self._set(p, u_hmap=0, u_rough=1,
                      u_horigin=(terrain.origin, terrain.origin),
                      u_hres=terrain.res, u_rres=terrain.rough_res)
        self._set(self.p_ter, u_material=2, u_detail_a=3, u_detail_b=4, u_shadow=5,
                  u_soil=soil, u_gravel=gravel, u_pav=pav, u_dperiod=self.dperiod)
        self._set(self.p_rock, u_detail_a=3, u_detail_b=4, u_shadow=5, u_dperiod=self.dperiod)
        # -- geometry
        # Patch vertices are evaluated on the CPU with Terrain.height (the truth function)
        # and cached: patches are world-fixed, so a moving rover reuses most of them.
        self.pv, pi = _patch_template()
        self.patch_cache: OrderedDict[tuple[float, float, float], np.ndarray] = OrderedDict()
        gy, gx = np.gradient(terrain.base.astype(np.float64), terrain.res)
        self.grad = (gx, gy)
        idx = pi[None, :] + (np.arange(MAX_PATCHES_PER_DRAW) * len(self.pv))[:, None]
        self.patch_ibo = ctx.buffer(idx.astype("u4").tobytes())
        self.patch_n = len(pi)
        self.patch_vbo = ctx.buffer(reserve=len(self.pv) * 20 * 512, dynamic=True)
        self.vao_ter = {}
        for key, prog in (("c", self.p_ter), ("d", self.p_ter_d)):
            fmt = ("3f 2f", "a_pos", "a_grad") if key == "c" else ("3f 8x", "a_pos")
            self.vao_ter[key] = ctx.vertex_array(prog, [(self.patch_vbo, *fmt)],
                                                 index_buffer=self.patch_ibo,
                                                 index_element_size=4)
        # rock templates: one VBO each, with a per-template instance buffer
        # (major rocks: 1280-triangle shapes; clutter: the same shapes at 320 triangles)
        self.rock_vaos: dict[bool, list] = {}
        for major, templates in ((True, rocks.templates), (False, rocks.templates_low)):
            self.rock_vaos[major] = []
            for t in templates:
                # the triangle soup as an indexed mesh (shared corners shaded once)
                verts, index = np.unique(t.positions, axis=0, return_inverse=True)
                vbo = ctx.buffer(verts.astype("f4").tobytes())
                ibo = ctx.buffer(index.astype("u4").ravel().tobytes())
                inst = ctx.buffer(reserve=44 * 1024, dynamic=True)
                self.rock_vaos[major].append((vbo, inst, self._rock_vaos(vbo, inst, ibo),
                                              len(index.ravel())))
        # outcrops: one static mesh drawn through the rock program as a single instance
        # per outcrop (identity transform, own colour and label)
        self.outcrop_vaos = []
        orng = np.random.default_rng(0)  # colours only; positions come from the world
        for oc, oid in zip(rocks.outcrops, rocks.outcrop_ids, strict=True):
            vbo = ctx.buffer(oc.positions.astype("f4").tobytes())
            v = orng.uniform(0.45, 0.62)
            inst = np.array([0, 0, 0, 1, 1, 1, 0, v * 1.04, v, v * 0.9, oid], "f4")
            ib = ctx.buffer(inst.tobytes())
            self.outcrop_vaos.append((self._rock_vaos(vbo, ib), len(oc.positions),
                                      oc.outline.mean(axis=0),
                                      float(np.ptp(oc.outline, axis=0).max())))
        self.sky_vbo = ctx.buffer(np.array([-1, -1, 3, -1, -1, 3], "f4").tobytes())
        self.vao_sky = ctx.vertex_array(self.p_sky, [(self.sky_vbo, "2f", "a_xy")])
        # instance buckets for fast range queries
        allinst = np.vstack([rocks.majors, rocks.clutter]) if len(rocks.clutter) else \
            rocks.majors
        self.inst = allinst.astype("f4")
        # square buckets of minor instances (row-major over x then y) for range queries;
        # the few major ROIs are always candidates
        self.bucket_m = 10.0
        is_major = self.inst[:, INST["label"]] > 0
        self.major_rows = np.flatnonzero(is_major)
        minor = np.flatnonzero(~is_major)
        cell = np.floor(self.inst[minor, :2] / self.bucket_m).astype(np.int64)
        self.bucket_lo = cell.min(axis=0) if len(cell) else np.zeros(2, np.int64)
        self.bucket_n = (cell.max(axis=0) - self.bucket_lo + 1) if len(cell) else \
            np.ones(2, np.int64)
        key = (cell[:, 0] - self.bucket_lo[0]) * self.bucket_n[1] + (cell[:, 1] -
                                                                      self.bucket_lo[1])
        order = np.argsort(key, kind="stable")
        self.bucket_rows = minor[order]
        self.bucket_start = np.searchsorted(key[order],
                                            np.arange(int(np.prod(self.bucket_n)) + 1))
        # -- framebuffers
        self._make_fbo(size)
        self.shadow_px = shadow_px
        self.t_shadow = ctx.depth_texture((shadow_px, shadow_px))
        self.t_shadow.compare_func = "<="
        self.t_shadow.filter = (moderngl.LINEAR, moderngl.LINEAR)
        self.fbo_shadow = ctx.framebuffer(depth_attachment=self.t_shadow)
        self._shadow_key: np.ndarray | None = None
        self._shadow_sun = np.zeros(3)
        self._light_vp = np.eye(4)

    def _rock_vaos(self, vbo, inst, ibo=None) -> dict:
        """Colour and depth-only vertex arrays of a rock mesh (positions, indexed if
        ``ibo``) + its instance buffer (the depth-only program has no colour/label
        inputs: those bytes are skipped)."""
        return {
            "c": self.ctx.vertex_array(
                self.p_rock, [(vbo, "3f", "a_pos"),
                              (inst, "3f 3f 1f 3f 1f/i", "i_pos", "i_scale", "i_yaw",
                               "i_col", "i_label")], index_buffer=ibo, index_element_size=4),
            "d": self.ctx.vertex_array(
                self.p_rock_d, [(vbo, "3f", "a_pos"),
                                (inst, "3f 3f 1f 16x/i", "i_pos", "i_scale", "i_yaw")],
                index_buffer=ibo, index_element_size=4),
        }

    @staticmethod
    def _set(prog, **uniforms) -> None:
        for k, v in uniforms.items():
            if k in prog:
                prog[k].value = v

    def _make_fbo(self, size: tuple[int, int]) -> None:
        ctx = self.ctx
        self.size = size
        self.c_rad = ctx.texture(size, 4, dtype="f2")
        self.c_z = ctx.texture(size, 1, dtype="f4")
        self.c_depth = ctx.depth_renderbuffer(size)
        # the label id travels in the alpha of c_rad; optical depth only when asked for
        # (every extra float target costs llvmpipe time per fragment)
        self.fbo = ctx.framebuffer([self.c_rad], self.c_depth)
        # with the optical depth, every target the shaders write (tests, diagnostics)
        self.c_lab = ctx.texture(size, 1, dtype="f4")
        self.fbo_z = ctx.framebuffer([self.c_rad, self.c_z, self.c_lab], self.c_depth)

    def _bind_textures(self) -> None:
        for unit, t in enumerate((self.t_h, self.t_r, self.t_m, self.t_da, self.t_db,
                                  self.t_shadow)):
            t.use(unit)

    def _instances_near(self, xy: np.ndarray, radius: float, major_radius: float,
                        fwd: np.ndarray | None, half_angle: float) -> np.ndarray:
        """Instances within ``radius`` (majors: ``major_radius``) of ``xy``, those off
        the view wedge around ``fwd`` dropped; rows in catalogue order."""
        c = self.bucket_m
        lo = np.floor((np.asarray(xy) - radius) / c).astype(np.int64) - self.bucket_lo
        hi = np.floor((np.asarray(xy) + radius) / c).astype(np.int64) - self.bucket_lo
        lo, hi = np.maximum(lo, 0), np.minimum(hi, self.bucket_n - 1)
        parts = [self.major_rows]
        for bx in range(lo[0], hi[0] + 1):
            a = self.bucket_start[bx * self.bucket_n[1] + lo[1]]
            b = self.bucket_start[bx * self.bucket_n[1] + hi[1] + 1] if hi[1] >= lo[1] else a
            parts.append(self.bucket_rows[a:b])
        rows = np.unique(np.concatenate(parts))
        inst = self.inst[rows]
        d = inst[:, :2] - xy
        dist = np.hypot(d[:, 0], d[:, 1])
        major = inst[:, INST["label"]] > 0
        keep = (dist < radius) | (major & (dist < major_radius))
        if fwd is not None:
            cosang = (d @ fwd) / np.maximum(dist, 1e-6)
            reach = np.maximum(inst[:, INST["sx"]], inst[:, INST["sy"]]) * 2
            keep &= (cosang > np.cos(half_angle)) | (dist < 4.0 + reach)
        return inst[keep]

    def _patch_vertices(self, patches: np.ndarray) -> np.ndarray:
        """(N * V, 5) float32 vertices (x, y, z, dz/dx, dz/dy) of patches (x0, y0, cell)."""
        keys = [tuple(p) for p in patches.tolist()]
        missing = [k for k in keys if k not in self.patch_cache]
        if missing:
            m = np.array(missing, np.float64)
            pv = self.pv.astype(np.float64)
            x = m[:, None, 0] + pv[None, :, 0] * m[:, None, 2]
            y = m[:, None, 1] + pv[None, :, 1] * m[:, None, 2]
            z = self.terrain.height(x, y) - pv[None, :, 2] * (0.05 + 0.5 * m[:, None, 2])
            u = (x - self.terrain.origin) / self.terrain.res
            v = (y - self.terrain.origin) / self.terrain.res
            gx = Terrain._bilinear(self.grad[0], u, v, wrap=False)
            gy = Terrain._bilinear(self.grad[1], u, v, wrap=False)
            arr = np.stack([x, y, z, gx, gy], -1).astype(np.float32)
            for k, a in zip(missing, arr, strict=True):
                self.patch_cache[k] = a
        for k in keys:
            self.patch_cache.move_to_end(k)
        while len(self.patch_cache) > PATCH_CACHE:
            self.patch_cache.popitem(last=False)
        return np.concatenate([self.patch_cache[k] for k in keys])

    def _draw(self, key: str, patches: np.ndarray, inst: np.ndarray,
              centre_xy: np.ndarray, outcrop_radius: float) -> None:
        for i in range(0, len(patches), MAX_PATCHES_PER_DRAW):
            chunk = patches[i:i + MAX_PATCHES_PER_DRAW]
            verts = self._patch_vertices(chunk)
            self.patch_vbo.orphan(verts.nbytes)
            self.patch_vbo.write(verts.tobytes())
            self.vao_ter[key].render(vertices=self.patch_n * len(chunk))
        tpl = inst[:, INST["template"]].astype(int)
        is_major = inst[:, INST["label"]] > 0
        cols = [INST[c] for c in ("x", "y", "z", "sx", "sy", "sz", "yaw", "r", "g", "b",
                                  "label")]
        for major, vao_list in self.rock_vaos.items():
            for k, (_vbo, ib, vaos, n) in enumerate(vao_list):
                sel = inst[(tpl == k) & (is_major == major)][:, cols]
                if len(sel) == 0:
                    continue
                ib.orphan(sel.nbytes)
                ib.write(np.ascontiguousarray(sel, "f4").tobytes())
                vaos[key].render(vertices=n, instances=len(sel))
        for vaos, n, c, ext in self.outcrop_vaos:
            if np.hypot(*(c - centre_xy)) < outcrop_radius + ext:
                vaos[key].render(vertices=n, instances=1)

    def _shadow_pass(self, light_vp: np.ndarray, patches: np.ndarray, inst: np.ndarray,
                     centre_xy: np.ndarray, radius: float) -> None:
        import moderngl

        self.fbo_shadow.use()
        self.ctx.viewport = (0, 0, self.shadow_px, self.shadow_px)
        self.fbo_shadow.clear(depth=1.0)
        self.ctx.enable(moderngl.DEPTH_TEST)
        self.ctx.disable(moderngl.CULL_FACE)
        m = tuple(light_vp.T.astype("f4").ravel())
        self._set(self.p_ter_d, u_vp=m, u_view=tuple(np.eye(4, dtype="f4").ravel()))
        self._set(self.p_rock_d, u_vp=m, u_view=tuple(np.eye(4, dtype="f4").ravel()))
        self._bind_textures()
        self._draw("d", patches, inst, centre_xy, radius)

    def _light_uniforms(self, sun: np.ndarray, light_vp: np.ndarray, cam: np.ndarray,
                        haze: float, sky_h: np.ndarray, light_depth: float) -> None:
        for p in (self.p_ter, self.p_rock):
            self._set(p, u_light_vp=tuple(light_vp.T.astype("f4").ravel()),
                      u_sbias=0.03 / light_depth,
                      u_sun=tuple(sun), u_irr=SUN_IRRADIANCE, u_amb=SKY_AMBIENT,
                      u_cam=tuple(cam), u_haze=haze, u_sky_h=tuple(sky_h))

    def render_views(self, rig: StereoRig, poses: list[tuple[np.ndarray, np.ndarray]],
                     sun_cfg: SunConfig | np.ndarray, want_label: bool = False,
                     want_depth: bool = False, half: bool = False,
                     ) -> list[dict[str, np.ndarray]]:
        """Render camera views sharing one shadow map (e.g. a stereo pair).

        Args:
            poses: (R_wc, centre_w) per view, optical frame in the map frame.
            sun_cfg: the sun now: a fixed :class:`SunConfig` or a map-frame direction
                (:func:`sun_vector`); the shading follows it exactly, the shadow map
                within :attr:`SHADOW_SUN_STEP_DEG`.
        Returns:
            per view: ``rad`` (H, W, 3) linear radiance, float32 (float16 as rendered
            if ``half``); the first view also
            has, if asked, ``label`` (H, W) int32 (truth id of the major ROI drawn, else 0)
            and ``z`` (H, W) float32 optical depth in metres (0 = sky).
        """
        import moderngl

        if self.size != (rig.width, rig.height):
            self._make_fbo((rig.width, rig.height))
        sun = sun_vector(sun_cfg)
        r0, c0 = poses[0]
        fwd = r0[:2, 2]
        fwd = fwd / (np.linalg.norm(fwd) + 1e-9)
        cam_xy = np.mean([c[:2] for _, c in poses], axis=0)
        cam_h = float(c0[2] - self.terrain.base_height(*cam_xy))
        half_angle = np.radians(40.0)
        patches = select_patches(cam_xy, fwd, half_angle, limit=700.0, cam_height=cam_h)
        inst = self._instances_near(cam_xy, 70.0, 450.0, fwd, half_angle)
        # The shadow map of a world-fixed square is view-independent: render it again only
        # when the near field (18 m ahead, +-26 m) leaves it or the sun has moved.
        need = cam_xy + fwd * 18.0
        moved = np.degrees(np.arccos(np.clip(sun @ self._shadow_sun, -1.0, 1.0)))
        if self._shadow_key is None or moved > self.SHADOW_SUN_STEP_DEG or \
                np.max(np.abs(need - self._shadow_key)) > self.SHADOW_HALF - 26.0:
            self._shadow_key = need
            self._shadow_sun = sun
            centre = np.array([*need, float(self.terrain.base_height(*need))])
            self._light_vp = look_at_light(sun, centre, self.SHADOW_HALF,
                                           self.SHADOW_DEPTH)
            sp = select_patches(need, None, 0, limit=self.SHADOW_HALF * 1.45, min_level=3)
            sinst = self._instances_near(need, self.SHADOW_HALF * 1.5, self.SHADOW_HALF * 1.5,
                                         None, 0)
            self._shadow_pass(self._light_vp, sp, sinst, need, self.SHADOW_HALF * 1.5)
        light_vp = self._light_vp
        sky_h = np.array([0.62, 0.70, 0.82]) * (SUN_IRRADIANCE * 0.55)
        sky_z = np.array([0.22, 0.36, 0.70]) * (SUN_IRRADIANCE * 0.45)
        proj = rig.gl_projection(CAMERA_NEAR_M, CAMERA_FAR_M)
        out = []
        for r_wc, c_w in poses:
            view = np.eye(4)
            view[:3, :3] = r_wc.T
            view[:3, 3] = -r_wc.T @ c_w
            vp = proj @ view
            fbo = self.fbo_z if want_depth and not out else self.fbo
            fbo.use()
            self.ctx.viewport = (0, 0, *self.size)
            fbo.clear(0, 0, 0, 0, depth=1.0)
            self._bind_textures()
            self.ctx.enable(moderngl.DEPTH_TEST)
            self.ctx.depth_func = "<"
            self._light_uniforms(sun, light_vp, c_w, HAZE_M, sky_h, self.SHADOW_DEPTH)
            for p in (self.p_ter, self.p_rock):
                self._set(p, u_vp=tuple(vp.T.astype("f4").ravel()),
                          u_view=tuple(view.T.astype("f4").ravel()))
            self._draw("c", patches, inst, cam_xy, 450.0)
            # the sky last, on the far plane: shaded only where no geometry was drawn
            self.ctx.depth_func = "<="
            self._set(self.p_sky, u_rwc=tuple(r_wc.T.astype("f4").ravel()),
                      u_k=(rig.fx, rig.fy, rig.cx, rig.cy), u_h=float(self.size[1]),
                      u_sky_h=tuple(sky_h), u_sky_z=tuple(sky_z))
            self.vao_sky.render(vertices=3)
            self.ctx.depth_func = "<"
            first = not out
            out.append(self._read(want_label and first, want_depth and first, half))
        return out

    def _read(self, want_label: bool, want_depth: bool = False,
              half: bool = False) -> dict[str, np.ndarray]:
        w, h = self.size
        # RGBA16F: linear radiance + the label id in alpha (exact up to 2048)
        rgba = np.frombuffer(self.c_rad.read(), "f2").reshape(h, w, 4)[::-1]
        res = {"rad": rgba[:, :, :3].astype(np.float16 if half else np.float32)}
        if want_label:
            res["label"] = np.rint(rgba[:, :, 3].astype(np.float32)).astype(np.int32)
        if want_depth:
            res["z"] = np.frombuffer(self.c_z.read(), "f4").reshape(h, w)[::-1].copy()
        return res

    def render_topdown(self, x0: float, y1: float, px: float, size: tuple[int, int],
                       sun_cfg: SunConfig) -> dict[str, np.ndarray]:
        """Orthographic top-down tile: pixel (row, col) centre at
        (x0 + (col + 0.5) px, y1 - (row + 0.5) px). Returns ``rad`` and ``label``."""
        import moderngl

        if size != self.size:
            self._make_fbo(size)
        w, h = size
        sun = sun_vector(sun_cfg)
        cx, cy = x0 + w * px / 2, y1 - h * px / 2
        half_w, half_h = w * px / 2, h * px / 2
        ext = max(half_w, half_h)
        zc = float(self.terrain.base_height(cx, cy))
        margin = 20.0
        light_vp = look_at_light(sun, np.array([cx, cy, zc]), ext + margin, depth=600.0)
        self._shadow_key = None  # the shadow map is overwritten
        # Top-down: every patch at the 0.4 m level (finer than the 0.5 m height grid).
        size_p = LEVEL_CELLS[3] * PATCH
        xs = np.arange(np.floor((cx - ext - margin) / size_p) * size_p, cx + ext + margin,
                       size_p)
        ys = np.arange(np.floor((cy - ext - margin) / size_p) * size_p, cy + ext + margin,
                       size_p)
        gx, gy = np.meshgrid(xs, ys)
        patches = np.column_stack([gx.ravel(), gy.ravel(),
                                   np.full(gx.size, LEVEL_CELLS[3])]).astype("f4")
        d = np.abs(self.inst[:, :2] - (cx, cy))
        inst = self.inst[(d[:, 0] < ext + margin) & (d[:, 1] < ext + margin)]
        self._shadow_pass(light_vp, patches, inst, np.array([cx, cy]), ext * 1.5 + margin)
        view = np.eye(4)
        view[2, 2] = -1.0  # z of the "view" = depth below 0: unused for top-down
        proj = np.eye(4)
        proj[0, 0], proj[0, 3] = 1 / half_w, -cx / half_w
        proj[1, 1], proj[1, 3] = 1 / half_h, -cy / half_h
        proj[2, 2], proj[2, 3] = -1 / 3000.0, 0.0
        self.fbo.use()
        self.ctx.viewport = (0, 0, w, h)
        self.fbo.clear(0, 0, 0, 0, depth=1.0)
        self._bind_textures()
        self.ctx.enable(moderngl.DEPTH_TEST)
        # the viewer is overhead (facing test of the rock normals; no haze)
        self._light_uniforms(sun, light_vp, np.array([cx, cy, 1e5]), 0.0, np.zeros(3), 600.0)
        for p in (self.p_ter, self.p_rock):
            self._set(p, u_vp=tuple(proj.T.astype("f4").ravel()),
                      u_view=tuple(view.T.astype("f4").ravel()))
        self._draw("c", patches, inst, np.array([cx, cy]), ext * 1.5 + margin)
        return self._read(want_label=True)

    def release(self) -> None:
        self.ctx.release()
