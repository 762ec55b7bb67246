"""Albedo of the ground at three scales.

1. Material map (0.5 m): soil, gravel patches and dark desert pavement, mixed by smooth
   random fields with soft boundaries, plus a low-frequency brightness variation.
2. Detail tiles (1 cm texels, periodic 20.48 m): per material, an albedo factor and a bump
   height: rounded pebbles for gravel, packed varnished clasts for pavement, fine grain and
   wind ripples for soil, and a fractured-rock texture for rocks and outcrops.
3. The renderer samples each detail tile twice, at two rotations and scales, which hides
   the tile period; mip-mapping averages it out for far views and the orbital image.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from atacama_sim.config import rng_for
from atacama_sim.terrain import TERRAIN_RES_M, spectral_field

#: Albedo (linear RGB) of the soil, the gravel patches and the desert pavement.
SOIL_RGB = (0.56, 0.45, 0.35)
GRAVEL_RGB = (0.46, 0.41, 0.36)
PAVEMENT_RGB = (0.30, 0.23, 0.18)
#: Share of the area covered by gravel, by pavement.
GRAVEL_COVER = 0.30
PAVEMENT_COVER = 0.25
#: Typical size of the material patches, m.
PATCH_WAVELENGTH_M = 25.0
#: Detail texture texel (pebbles), m.
DETAIL_RES_M = 0.01
#: Detail tile side, texels (a 20 m period).
DETAIL_TILE_PX = 2048
#: Sub-cm to 5 cm clasts per m^2 in the gravel detail texture (1.6 times that on pavement).
PEBBLES_PER_M2 = 220.0
#: The three materials' albedos, in the renderer's order.
MATERIAL_RGB = (SOIL_RGB, GRAVEL_RGB, PAVEMENT_RGB)


@dataclass
class GroundTextures:
    """Arrays the renderer uploads.

    Attributes:
        material: (N, N, 4) uint8 on the terrain grid: gravel weight, pavement weight,
            brightness (128 = 1.0), unused.
        detail_a: (M, M, 4) uint8: gravel albedo, gravel height, pavement albedo,
            pavement height (albedo factor = value / 128).
        detail_b: (M, M, 4) uint8: soil albedo, soil height, rock albedo, rock height.
        detail_res: metres per detail texel.
    """

    material: np.ndarray
    detail_a: np.ndarray
    detail_b: np.ndarray
    detail_res: float


def _cover_weight(field: np.ndarray, cover: float, softness: float = 0.25) -> np.ndarray:
    """Soft indicator of the top ``cover`` fraction of ``field`` (logistic edge)."""
    thr = np.quantile(field, 1.0 - cover)
    return 1.0 / (1.0 + np.exp(-(field - thr) / softness))


def _clasts(rng: np.random.Generator, size: int, res: float, per_m2: float,
            diam_m: tuple[float, float], albedo: tuple[float, float],
            background: float) -> tuple[np.ndarray, np.ndarray]:
    """Rasterise random rounded clasts on a periodic tile: (albedo factor, height m).

    Clasts are drawn largest first with OpenCV into an id image (later, smaller ones on
    top), wrapped copies near the edges keep the tile periodic; each pixel's height is
    then a spherical cap of its clast.
    """
    period = size * res
    n = int(per_m2 * period * period)
    centres = rng.uniform(0, size, size=(n, 2))  # pixels
    u = rng.uniform(size=n)
    d0, d1 = diam_m
    rad = d0 * (d1 / d0) ** (u ** 2.2) / 2 / res  # pixels
    alb = rng.uniform(*albedo, size=n)
    order = np.argsort(-rad)
    pad = int(np.ceil(rad.max())) + 2
    canvas = np.full((size + 2 * pad, size + 2 * pad), -1, np.int32)
    # the clast itself and its wrapped copies that reach into the tile
    offs = [(ox, oy) for ox in (-size, 0, size) for oy in (-size, 0, size)]
    cx = np.concatenate([centres[order, 0] + ox for ox, _ in offs])
    cy = np.concatenate([centres[order, 1] + oy for _, oy in offs])
    rr = np.tile(rad[order], len(offs))
    kk = np.tile(order, len(offs))
    seq = np.tile(np.arange(n), len(offs))
    keep = (cx > -rr) & (cx < size + rr) & (cy > -rr) & (cy < size + rr)
    sel = np.argsort(seq[keep], kind="stable")  # largest first
    ix = np.round((cx[keep][sel] + pad) * 16).astype(int).tolist()
    iy = np.round((cy[keep][sel] + pad) * 16).astype(int).tolist()
    ir = np.round(rr[keep][sel] * 16).astype(int).tolist()
    for x, y, r, k in zip(ix, iy, ir, kk[keep][sel].tolist(), strict=True):
        cv2.circle(canvas, (x, y), r, k, -1, lineType=cv2.LINE_8, shift=4)
    ids = canvas[pad:pad + size, pad:pad + size]
    yy, xx = np.mgrid[0:size, 0:size].astype(np.float64)
    has = ids >= 0
    k = np.where(has, ids, 0)
    dx = (xx - centres[k, 0] + size / 2) % size - size / 2
    dy = (yy - centres[k, 1] + size / 2) % size - size / 2
    r = rad[k]
    cap = np.sqrt(np.clip(1 - (dx * dx + dy * dy) / (r * r), 0, 1)) * r * res * 0.7
    height = np.where(has, cap, 0.0)
    albedo_f = np.where(has, alb[k], background)
    return albedo_f, height


def _u8(a: np.ndarray, scale: float) -> np.ndarray:
    return np.clip(np.round(a * scale), 0, 255).astype(np.uint8)


def generate_textures(grid_n: int, seed: int) -> GroundTextures:
    """Material map on a ``grid_n`` x ``grid_n`` grid (terrain grid) and detail tiles."""
    rng = rng_for(seed, "albedo")
    shape = (grid_n, grid_n)
    lam = PATCH_WAVELENGTH_M
    g_field = spectral_field(rng, shape, TERRAIN_RES_M, (lam / 6, lam * 6), slope=3.0)
    p_field = spectral_field(rng, shape, TERRAIN_RES_M, (lam / 4, lam * 8), slope=3.2)
    w_gravel = _cover_weight(g_field, GRAVEL_COVER)
    w_pav = _cover_weight(p_field, PAVEMENT_COVER)
    bright = 1.0 + 0.08 * spectral_field(rng, shape, TERRAIN_RES_M, (2.0, 200.0), slope=2.5)
    material = np.stack([_u8(w_gravel, 255), _u8(w_pav, 255), _u8(bright, 128),
                         np.zeros(shape, np.uint8)], axis=-1)

    m, res = DETAIL_TILE_PX, DETAIL_RES_M
    grain = spectral_field(rng, (m, m), res, (2 * res, 0.3), slope=1.5)
    gravel_alb, gravel_h = _clasts(rng, m, res, PEBBLES_PER_M2, (0.006, 0.06),
                                   (0.55, 1.45), 1.0)
    gravel_alb = gravel_alb * (1 + 0.10 * grain)
    pav_alb, pav_h = _clasts(rng, m, res, PEBBLES_PER_M2 * 1.6, (0.01, 0.08),
                             (0.55, 1.1), 1.25)
    pav_alb = pav_alb * (1 + 0.08 * grain)
    # Soil: fine grain + faint wind ripples (period ~8 cm) across the tile.
    yy, xx = np.mgrid[0:m, 0:m] * res
    period = m * res
    ripple = np.sin(2 * np.pi * (xx * 120 + yy * 37) / period
                    + 1.5 * spectral_field(rng, (m, m), res, (0.2, 3.0)))
    mottle = spectral_field(rng, (m, m), res, (0.05, 2.0), slope=2.5)
    soil_alb = 1.0 + 0.22 * grain + 0.12 * mottle + 0.03 * ripple
    soil_h = 0.003 * (0.5 + 0.5 * ripple) + 0.003 * (1 + grain)
    # Rock: mottled grains + dark fracture lines (zero crossings of band-limited noise).
    crack = spectral_field(rng, (m, m), res, (0.08, 0.6), slope=2.0)
    edge = np.clip(np.abs(crack) / 0.12, 0, 1)
    mott = spectral_field(rng, (m, m), res, (0.02, 1.0), slope=2.0)
    rock_alb = (0.75 + 0.25 * edge) * (1 + 0.18 * mott + 0.08 * grain)
    rock_h = 0.01 * edge + 0.004 * mott
    detail_a = np.stack([_u8(gravel_alb, 128), _u8(gravel_h, 255 / 0.04),
                         _u8(pav_alb, 128), _u8(pav_h, 255 / 0.04)], axis=-1)
    detail_b = np.stack([_u8(soil_alb, 128), _u8(soil_h, 255 / 0.04),
                         _u8(rock_alb, 128), _u8(rock_h, 255 / 0.04)], axis=-1)
    return GroundTextures(material, detail_a, detail_b, res)
