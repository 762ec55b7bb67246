"""HiRISE-like orbital products: the orthoimage (top-down render of the world, MTF, noise,
GeoTIFF) and the elevation model beside it.

Tiles are rendered orthographically at gsd / supersample with the orbital sun (shading and
cast shadows), area-averaged to the GSD (pixel integration), blurred by a Gaussian PSF
(optics MTF), given shot and read noise, and quantised with a fixed exposure. A label
raster (truth id of the major ROI covering each pixel) is written beside it for
evaluation only.

The DTM (``dtm.tif``), as landing-site DTMs are made from orbital stereo: the terrain's
height field averaged over each 1 m post (HiRISE DTMs are posted at 1 m), plus a stereo
matching error of the 1-sigma its tags state (a random field correlated over 3-30 m), in
the orthoimage's CRS and footprint, heights in ``map`` z (0 at the ground under the
map-frame origin), its vertical datum stated in the tags. Rocks are not in it: a stereo
DTM at 1 m smooths the decimetre rocks the rover drives among.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rasterio
from rasterio.transform import Affine
from scipy.ndimage import gaussian_filter

from atacama_sim.config import rng_for
from atacama_sim.renderer import SKY_AMBIENT, SUN_IRRADIANCE, SceneRenderer, sun_vector
from atacama_sim.terrain import spectral_field
from atacama_sim.texture import SOIL_RGB
from atacama_sim.world import World
from roi_network.dtm import write_dtm as write_dtm_file

#: Tiles are rendered at gsd / SUPERSAMPLE, then area-averaged to the GSD.
SUPERSAMPLE = 2
#: Sigma of the Gaussian PSF applied after the area average, pixels.
MTF_SIGMA_PX = 0.6
#: Read noise of the 8-bit product, DN rms.
NOISE_DN = 1.5
#: Shot noise at full scale, relative rms.
SHOT_NOISE = 0.006
#: Post spacing of the DTM, m (HiRISE stereo DTMs: 1 m).
DTM_POSTING_M = 1.0
#: Height samples per post side averaged into one post.
DTM_SUPERSAMPLE = 4
#: The DTM's vertical 1-sigma, m (roi_network.dtm's HiRISE figure): the rms of the error
#: added to its posts, and what its VERTICAL_SIGMA_M tag states.
DTM_VERTICAL_SIGMA_M = 0.25
#: Shortest and longest wavelength of the DTM's error field, m.
DTM_ERROR_WAVELENGTHS_M = (3.0, 30.0)
#: The DTM's vertical datum, as its tags state it.
DTM_DATUM = ("map frame z: metres above the ground at the map-frame origin (atacama_sim "
             "local datum; the truth trajectory's z)")


def orbital_transform(world: World) -> Affine:
    """Pixel -> projected CRS affine of the orthoimage (upper-left corner origin)."""
    e = world.terrain.extent
    gsd = world.cfg.orbital.gsd_m
    ox, oy = world.origin
    return Affine(gsd, 0.0, ox - e / 2, 0.0, -gsd, oy + e / 2)


def render_orbital(world: World, renderer: SceneRenderer, out_tif: Path,
                   out_labels: Path, progress=None) -> dict:
    """Render and write ``orbital.tif`` (RGB uint8) and the label raster (uint16)."""
    ocfg = world.cfg.orbital
    e = world.terrain.extent
    gsd = ocfg.gsd_m
    n = round(e / gsd)
    ss = SUPERSAMPLE
    tile_px = round(ocfg.tile_m / gsd)
    margin = 8  # px of overlap so the PSF has no tile seams
    rgb = np.zeros((n, n, 3), np.uint8)
    labels = np.zeros((n, n), np.uint16)
    # Fixed exposure: lit soil at mid-grey, as a HiRISE product is stretched.
    sun = sun_vector(ocfg.sun)
    soil = np.array(SOIL_RGB) ** 2.2  # linear
    lit = soil.mean() * (SUN_IRRADIANCE * sun[2] + SKY_AMBIENT)
    gain = 0.58 ** 2.2 / lit
    x_left, y_top = -e / 2, e / 2
    rng = rng_for(world.cfg.seed, "orbital")
    for r0 in range(0, n, tile_px):
        for c0 in range(0, n, tile_px):
            r1, c1 = min(r0 + tile_px, n), min(c0 + tile_px, n)
            h, w = r1 - r0 + 2 * margin, c1 - c0 + 2 * margin
            x0 = x_left + (c0 - margin) * gsd
            y1 = y_top - (r0 - margin) * gsd
            out = renderer.render_topdown(x0, y1, gsd / ss, (w * ss, h * ss), ocfg.sun)
            rad = out["rad"].reshape(h, ss, w, ss, 3).mean(axis=(1, 3))
            lab = out["label"].reshape(h, ss, w, ss).max(axis=(1, 3))
            img = gaussian_filter(rad * gain, sigma=(MTF_SIGMA_PX, MTF_SIGMA_PX, 0))
            img = np.clip(img, 0, 1) ** (1 / 2.2)  # stretched product, like a HiRISE browse
            img = img + rng.standard_normal(img.shape) * np.sqrt(
                (NOISE_DN / 255) ** 2 + SHOT_NOISE ** 2 * img)
            tile = (np.clip(img, 0, 1) * 255 + 0.5).astype(np.uint8)
            rgb[r0:r1, c0:c1] = tile[margin:margin + r1 - r0, margin:margin + c1 - c0]
            labels[r0:r1, c0:c1] = lab[margin:margin + r1 - r0, margin:margin + c1 - c0]
            if progress is not None:
                progress()
    transform = orbital_transform(world)
    crs = world.cfg.site.crs
    profile = {"driver": "GTiff", "width": n, "height": n, "transform": transform,
               "crs": crs, "compress": "deflate", "tiled": True, "blockxsize": 256,
               "blockysize": 256}
    with rasterio.open(out_tif, "w", count=3, dtype="uint8", photometric="RGB",
                       **profile) as dst:
        dst.write(np.moveaxis(rgb, -1, 0))
        dst.update_tags(GSD_M=str(gsd), SOURCE="atacama_sim orthographic render",
                        SUN_ELEVATION_DEG=str(ocfg.sun.elevation_deg),
                        SUN_AZIMUTH_DEG=str(ocfg.sun.azimuth_deg))
    with rasterio.open(out_labels, "w", count=1, dtype="uint16", **profile) as dst:
        dst.write(labels[None])
    return {"size_px": n, "gsd_m": gsd, "tiles": int(np.ceil(n / tile_px)) ** 2,
            "rgb": rgb, "labels": labels}


def orbital_tiles(world: World) -> int:
    n = round(world.terrain.extent / world.cfg.orbital.gsd_m)
    tile_px = round(world.cfg.orbital.tile_m / world.cfg.orbital.gsd_m)
    return int(np.ceil(n / tile_px)) ** 2


def dtm_heights(world: World, error: bool = True) -> tuple[np.ndarray, Affine]:
    """The DTM's posts: each the mean of the terrain's surface height over its cell
    (``DTM_SUPERSAMPLE``^2 samples) plus, with ``error``, the stereo error field
    (``DTM_VERTICAL_SIGMA_M`` rms), row 0 north; and its pixel -> CRS affine (the
    orthoimage's upper-left corner, ``DTM_POSTING_M`` posts)."""
    e = world.terrain.extent
    post = DTM_POSTING_M
    n = round(e / post)
    ss = DTM_SUPERSAMPLE
    offs = (np.arange(ss) + 0.5) / ss * post  # sample offsets inside a cell
    x = -e / 2 + (np.arange(n)[:, None] * post + offs).ravel()  # west to east
    heights = np.empty((n, n), np.float32)
    rows_per_block = max(1, 2_000_000 // (len(x) * ss))
    for r0 in range(0, n, rows_per_block):
        r1 = min(n, r0 + rows_per_block)
        y = e / 2 - (np.arange(r0, r1)[:, None] * post + offs).ravel()  # north to south
        z = world.terrain.height(x[None, :], y[:, None])
        heights[r0:r1] = z.reshape(r1 - r0, ss, n, ss).mean(axis=(1, 3))
    if error:
        rng = rng_for(world.cfg.seed, "dtm")
        heights += DTM_VERTICAL_SIGMA_M * spectral_field(rng, (n, n), post,
                                                         DTM_ERROR_WAVELENGTHS_M, slope=2.0)
    ox, oy = world.origin
    return heights, Affine(post, 0.0, ox - e / 2, 0.0, -post, oy + e / 2)


def write_dtm(world: World, out_tif: Path) -> dict:
    """Write ``dtm.tif`` (float32 heights, metres; roi_network.dtm's layout and tags)
    beside the orthoimage."""
    heights, transform = dtm_heights(world)
    write_dtm_file(out_tif, heights, world.cfg.site.crs, transform.c, transform.f,
                   DTM_POSTING_M, DTM_VERTICAL_SIGMA_M, DTM_DATUM,
                   source="atacama_sim terrain height field, mean over each post, plus a "
                          f"{DTM_VERTICAL_SIGMA_M} m rms stereo error field")
    return {"size_px": heights.shape[0], "posting_m": DTM_POSTING_M,
            "vertical_sigma_m": DTM_VERTICAL_SIGMA_M,
            "height_range_m": [round(float(heights.min()), 2), round(float(heights.max()), 2)]}
