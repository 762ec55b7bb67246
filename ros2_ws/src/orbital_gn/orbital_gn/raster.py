"""Reading georeferenced orthoimages (any raster GDAL reads, through rasterio) by windows.

What the detector needs from a raster: its georeference (projected CRS, affine transform,
ground sample distance), windows of it as RGB in [0, 1] plus uint8 gray, and a validity
mask (nodata, alpha or internal masks). 1-band rasters (panchromatic, e.g. HiRISE RED)
are replicated into three channels; uint8 is used as is; other dtypes are stretched with
one mapping for the whole raster (percentiles of a decimated read), so that every window
of one raster sees the same grey levels.
"""

from __future__ import annotations

import hashlib
import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path
from typing import Final

import numpy as np
import rasterio
from affine import Affine
from pyproj import CRS
from rasterio.errors import NotGeoreferencedWarning, RasterioError
from rasterio.windows import Window

from roi_detector.metrics import to_gray_u8

#: GDAL block cache per process while reading windows, MiB.
GDAL_CACHE_MB = 64


class OrthoImageError(ValueError):
    """An orthoimage cannot be used; the message names the file and says what to do."""


@dataclass(frozen=True)
class OrthoInfo:
    """Georeference and layout of an orthoimage.

    Attributes:
        path: the file.
        width, height: pixels.
        crs: projected CRS as an authority string (or WKT when it has no authority code).
        transform: affine pixel (col, row) -> CRS (x, y) of the pixel's corner.
        gsd_m: ground sample distance, sqrt of a pixel's area, metres.
        bands: indexes (1-based) read as R, G, B (one index three times for 1 band).
        dtype: the raster's data type.
        stretch: (lo, hi) mapped to 0 and 1 for non-uint8 rasters, else None.
    """

    path: str
    width: int
    height: int
    crs: str
    transform: Affine
    gsd_m: float
    bands: tuple[int, int, int]
    dtype: str
    stretch: tuple[float, float] | None

    @property
    def pixel_area_m2(self) -> float:
        return self.gsd_m**2


#: Raster metadata tags giving the sun direction at acquisition (GDAL metadata, default
#: domain), as atacama_sim's orthoimages carry them; other products give it in their label
#: (incidence angle, solar azimuth in the product's convention), to convert and pass to
#: ``prepare --sun-azimuth --sun-elevation``.
SUN_TAGS: Final = ("SUN_AZIMUTH_DEG", "SUN_ELEVATION_DEG")


@dataclass(frozen=True)
class Sun:
    """Sun direction at acquisition.

    Attributes:
        azimuth_deg: degrees clockwise from the map's (grid) north, [0, 360).
        elevation_deg: degrees above the horizon, (0, 90].
    """

    azimuth_deg: float
    elevation_deg: float

    @classmethod
    def checked(cls, azimuth_deg: float, elevation_deg: float, source: str) -> Sun:
        """A validated Sun; ``source`` (an option or a file) names where the values came from.

        Raises:
            ValueError: non-finite azimuth, or elevation outside (0, 90] degrees.
        """
        az, el = float(azimuth_deg), float(elevation_deg)
        if not math.isfinite(az):
            raise ValueError(f"{source}: sun azimuth {azimuth_deg!r} is not a finite number")
        if not (math.isfinite(el) and 0.0 < el <= 90.0):
            raise ValueError(f"{source}: sun elevation {elevation_deg!r} is not in (0, 90] "
                             "degrees (a shadow-aware recipe needs the sun above the horizon)")
        return cls(az % 360.0, el)


def sun_from_tags(path: str | os.PathLike[str]) -> Sun | None:
    """The sun direction recorded in the raster's metadata (:data:`SUN_TAGS`), or None.

    Raises:
        OrthoImageError: a tag is present but not a valid angle (names the file and tag).
    """
    with rasterio.open(path) as ds:
        tags = ds.tags()
    if not all(t in tags for t in SUN_TAGS):
        return None
    try:
        return Sun.checked(float(tags[SUN_TAGS[0]]), float(tags[SUN_TAGS[1]]),
                           f"{path}: metadata {'/'.join(SUN_TAGS)}")
    except ValueError as exc:
        raise OrthoImageError(f"{path}: metadata {'/'.join(SUN_TAGS)} = "
                              f"{tags[SUN_TAGS[0]]!r}/{tags[SUN_TAGS[1]]!r}: {exc}") from exc


def _crs_string(crs: rasterio.crs.CRS) -> str:
    auth = crs.to_authority()
    return f"{auth[0]}:{auth[1]}" if auth else crs.to_wkt()


def open_ortho(path: str | os.PathLike[str]) -> OrthoInfo:
    """Validate an orthoimage and describe it.

    Raises:
        OrthoImageError: not found, not a raster, truncated, no georeference, geographic or
            unknown CRS, rotated/sheared pixels beyond 1 %, or no usable band.
    """
    p = Path(path)
    if not p.is_file():
        raise OrthoImageError(f"{p}: file not found")
    try:
        with warnings.catch_warnings():
            # An ungeoreferenced raster is reported below as an error, not a warning.
            warnings.simplefilter("ignore", NotGeoreferencedWarning)
            ds = rasterio.open(p)
        with ds:
            crs, transform = ds.crs, ds.transform
            width, height, count = ds.width, ds.height, ds.count
            dtypes = ds.dtypes
            colorinterp = ds.colorinterp
            if crs is None or transform == Affine.identity():
                raise OrthoImageError(
                    f"{p}: the raster has no georeference (CRS and geotransform); "
                    "georeference it (e.g. gdal_translate -a_srs EPSG:... -a_ullr ...) or "
                    "give a GeoTIFF exported with its projected CRS")
            if not CRS.from_user_input(crs.to_wkt()).is_projected:
                raise OrthoImageError(
                    f"{p}: CRS '{_crs_string(crs)}' is geographic (degrees); reproject the "
                    "image to a projected CRS in metres first, e.g. "
                    f"gdalwarp -t_srs EPSG:326xx {p.name} out.tif (UTM) or an IAU Mars "
                    "equirectangular CRS")
            # Reading the last block catches most truncated files before work starts.
            ds.read(1, window=Window(width - 1, height - 1, 1, 1))
            bands = _pick_bands(count, colorinterp)
            dtype = dtypes[bands[0] - 1]
            stretch = None if dtype == "uint8" else _stretch(ds, bands, p)
    except OrthoImageError:
        raise
    except (RasterioError, OSError, ValueError) as exc:
        raise OrthoImageError(f"{p}: not a readable raster ({exc})") from exc
    a, b, d, e = transform.a, transform.b, transform.d, transform.e
    area = abs(a * e - b * d)
    if not area > 0:
        raise OrthoImageError(f"{p}: degenerate geotransform {tuple(transform)[:6]}")
    gsd = math.sqrt(area)
    if abs(math.hypot(a, d) - math.hypot(b, e)) > 0.01 * gsd:
        raise OrthoImageError(f"{p}: pixels are not square ({math.hypot(a, d):.4g} x "
                              f"{math.hypot(b, e):.4g} m); resample to square pixels first")
    return OrthoInfo(str(p), width, height, _crs_string(crs), transform, gsd, bands, dtype,
                     stretch)


def _pick_bands(count: int, colorinterp) -> tuple[int, int, int]:
    names = [c.name for c in colorinterp]
    if all(n in names for n in ("red", "green", "blue")):
        return (names.index("red") + 1, names.index("green") + 1, names.index("blue") + 1)
    if count >= 3:
        return (1, 2, 3)
    return (1, 1, 1)


def _stretch(ds, bands: tuple[int, int, int], path: Path) -> tuple[float, float]:
    # A decimated read (at most ~1 Mpx) gives the 0.1 / 99.9 percentiles of the raster.
    step = max(1, math.ceil(math.sqrt(ds.width * ds.height / 1e6)))
    shape = (max(1, ds.height // step), max(1, ds.width // step))
    data = ds.read(sorted(set(bands)), out_shape=(len(set(bands)), *shape), masked=True)
    vals = data.compressed().astype(np.float64)
    vals = vals[np.isfinite(vals)]
    if vals.size == 0:
        return (0.0, 1.0)
    lo, hi = np.percentile(vals, [0.1, 99.9])
    return (float(lo), float(hi) if hi > lo else float(lo) + 1.0)


@dataclass
class OrthoWindow:
    """One window of an orthoimage.

    Attributes:
        row0, col0: position of the window's first pixel in the raster.
        rgb01: (h, w, 3) float32 RGB in [0, 1].
        gray: (h, w) uint8 gray.
        valid: (h, w) bool, pixels with data.
    """

    row0: int
    col0: int
    rgb01: np.ndarray
    gray: np.ndarray
    valid: np.ndarray


def read_window(info: OrthoInfo, row0: int, col0: int, height: int, width: int) -> OrthoWindow:
    """Read a window (clipped to the raster) as RGB in [0, 1], gray and validity.

    Raises:
        OrthoImageError: if the file cannot be read there (truncated or corrupt data).
    """
    r0, c0 = max(row0, 0), max(col0, 0)
    r1, c1 = min(row0 + height, info.height), min(col0 + width, info.width)
    win = Window(c0, r0, c1 - c0, r1 - r0)
    try:
        # A small GDAL block cache: each window is read once, and GDAL's default cache (5 %
        # of RAM per process) would otherwise grow with the raster in every worker.
        with rasterio.Env(GDAL_CACHEMAX=GDAL_CACHE_MB), rasterio.open(info.path) as ds:
            data = ds.read(list(info.bands), window=win, masked=True)
    except (RasterioError, OSError) as exc:
        raise OrthoImageError(f"{info.path}: cannot read window rows {r0}-{r1}, cols "
                              f"{c0}-{c1} ({exc}); the file may be truncated or corrupt") from exc
    mask = np.ma.getmaskarray(data).any(axis=0)
    raw = np.ma.getdata(data).astype(np.float32)
    finite = np.isfinite(raw).all(axis=0)
    valid = ~mask & finite
    raw = np.where(np.isfinite(raw), raw, 0.0)
    if info.stretch is None:
        rgb01 = raw / 255.0
    else:
        lo, hi = info.stretch
        rgb01 = (raw - lo) / (hi - lo)
    rgb01 = np.clip(np.moveaxis(rgb01, 0, -1), 0.0, 1.0).astype(np.float32)
    gray = to_gray_u8(rgb01, 0.0, 1.0)
    # Invalid pixels take mid-grey: a constant, so that every window of a raster sees the
    # same values there (tiling changes nothing); candidates are masked to valid pixels.
    if not valid.all():
        gray[~valid] = 128
        rgb01[~valid] = 128.0 / 255.0
    return OrthoWindow(r0, c0, rgb01, gray, valid)


def sha256_of(path: str | os.PathLike[str], chunk: int = 1 << 22) -> str:
    """sha256 hex digest of a file (provenance of a GN)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while block := f.read(chunk):
            h.update(block)
    return h.hexdigest()
