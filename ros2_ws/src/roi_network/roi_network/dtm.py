"""An orbital elevation model (DTM): the ground's height under a ``map`` position.

Landing-site DTMs are made from orbital stereo (HiRISE: 1 m posts). One is read from a
single-band GeoTIFF in the GN's projected CRS; its heights are ``map`` z (the DTM's
vertical datum is the map's: ``map`` shifts the CRS in x and y only, DESIGN.md Frames).
The matcher takes /global_pose z from it and ``globloc eval`` judges that z; both read it
here.

- :func:`write_dtm`: heights on a north-up grid as such a GeoTIFF, with the tags below;
- :func:`read_dtm`: the file, checked (one band, a CRS equal to the GN's, a north-up
  grid, finite heights where it has data), as an :class:`ElevationModel`;
- :meth:`ElevationModel.height`: bilinear height between post centres (NaN off the
  model or next to a nodata post) and its gradient;
- :meth:`ElevationModel.ground_z`: the rover's z on the ground and its variance: the
  model's vertical variance plus the horizontal covariance through the slope.

GeoTIFF tags this module reads (the simulator writes them; ``rio edit-info --tag
VERTICAL_SIGMA_M=0.5 dtm.tif`` adds one to a DTM of one's own): ``VERTICAL_SIGMA_M``, the
1-sigma vertical error of a post, metres (default :data:`DEFAULT_VERTICAL_SIGMA_M`);
``VERTICAL_DATUM``, text, quoted in messages.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass

import numpy as np

from roi_network.network import MapFrame

#: Variance that marks a coordinate as not estimated, m^2 (a 1 km standard deviation:
#: no consumer mistakes it for a measurement; robot_pose_ekf-era drivers flag an
#: unmeasured variable by a variance "on the order of 1e3", robot_localization's
#: preparing-your-data guide).
UNKNOWN_VARIANCE_M2 = 1e6
#: A variance at or above this marks the coordinate as not estimated, m^2.
UNKNOWN_THRESHOLD_M2 = 1e4
#: Vertical 1-sigma of a DTM post when the file states none, m: HiRISE stereo DTMs at
#: 1 m posts reach a vertical precision of a few tens of centimetres (Kirk et al. 2008,
#: J. Geophys. Res. 113, E00A24).
DEFAULT_VERTICAL_SIGMA_M = 0.25
#: GeoTIFF tag: the vertical 1-sigma of a post, metres.
SIGMA_TAG = "VERTICAL_SIGMA_M"
#: GeoTIFF tag: the vertical datum, text.
DATUM_TAG = "VERTICAL_DATUM"


class DtmFormatError(ValueError):
    """A DTM file that cannot be used; the message names the file and what is wrong."""


def z_is_estimated(variance: float) -> bool:
    """Whether a published z variance is a measurement's (finite, below the unknown mark)."""
    return bool(math.isfinite(variance) and 0.0 <= variance < UNKNOWN_THRESHOLD_M2)


@dataclass(frozen=True)
class ElevationModel:
    """Heights on a north-up grid of posts, in the ``map`` frame.

    Attributes:
        heights: (rows, cols) float64 heights, metres (map z); NaN where the model has
            no data. Row 0 is the northern edge.
        x0: map x of the centre of post (0, 0), metres.
        y0: map y of the centre of post (0, 0), metres.
        posting: post spacing, metres (x grows with the column, y falls with the row).
        vertical_sigma_m: 1-sigma vertical error of a post, metres.
        datum: the vertical datum as the file states it ("" if it does not).
        source: the file, for messages.
        sigma_stated: whether the file states ``vertical_sigma_m`` (False: the default).
    """

    heights: np.ndarray
    x0: float
    y0: float
    posting: float
    vertical_sigma_m: float
    datum: str = ""
    source: str = "<DTM>"
    sigma_stated: bool = True

    def height(self, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bilinear height between post centres and its gradient (dz/dx, dz/dy).

        Within half a post of the outer posts the edge cell is extended; further out, or
        in a cell with a nodata post, the height and gradient are NaN.

        Returns:
            (N,) heights (metres) and (N, 2) gradients (metres per metre).
        """
        x = np.atleast_1d(np.asarray(x, dtype=float))
        y = np.atleast_1d(np.asarray(y, dtype=float))
        rows, cols = self.heights.shape
        u = (x - self.x0) / self.posting          # fractional column
        v = (self.y0 - y) / self.posting          # fractional row
        inside = ((u >= -0.5) & (u <= cols - 0.5) & (v >= -0.5) & (v <= rows - 0.5)
                  & np.isfinite(u) & np.isfinite(v))
        z = np.full(x.shape, np.nan)
        grad = np.full((*x.shape, 2), np.nan)
        if rows < 2 or cols < 2 or not inside.any():
            return z, grad
        uc = np.clip(u[inside], 0.0, cols - 1.0)
        vc = np.clip(v[inside], 0.0, rows - 1.0)
        j0 = np.minimum(np.floor(uc), cols - 2).astype(np.int64)
        i0 = np.minimum(np.floor(vc), rows - 2).astype(np.int64)
        tu, tv = uc - j0, vc - i0
        h = self.heights
        a, b = h[i0, j0], h[i0, j0 + 1]
        c, d = h[i0 + 1, j0], h[i0 + 1, j0 + 1]
        top = a + (b - a) * tu
        bottom = c + (d - c) * tu
        z[inside] = top + (bottom - top) * tv
        dz_du = (b - a) * (1 - tv) + (d - c) * tv
        dz_dv = bottom - top
        grad[inside, 0] = dz_du / self.posting
        grad[inside, 1] = -dz_dv / self.posting
        return z, grad

    def ground_z(self, x: float, y: float, xy_covariance: np.ndarray,
                 height_above_ground_m: float = 0.0) -> tuple[float, np.ndarray, float]:
        """z of a frame ``height_above_ground_m`` above the ground at (x, y), and its error.

        Args:
            x, y: map position, metres.
            xy_covariance: (2, 2) covariance of (x, y), m^2.
            height_above_ground_m: the frame's height above the ground (0 for base_link,
                whose origin is on the ground under the rover).

        Returns:
            z (NaN off the model), the gradient (2,) (dz/dx, dz/dy), and the variance of
            z: the post's vertical variance plus ``g^T C g`` (the slope times the
            horizontal sigma along it), m^2.
        """
        z, grad = self.height(np.array([x]), np.array([y]))
        g = grad[0]
        cov = np.asarray(xy_covariance, dtype=float).reshape(2, 2)
        var = self.vertical_sigma_m ** 2 + float(g @ cov @ g)
        return float(z[0]) + height_above_ground_m, g, var

    def describe(self) -> str:
        """One line for a log: file, size, posting, sigma, datum."""
        rows, cols = self.heights.shape
        datum = f", datum: {self.datum}" if self.datum else ""
        assumed = "" if self.sigma_stated else f" (assumed: no {SIGMA_TAG} tag)"
        return (f"DTM {self.source}: {cols} x {rows} posts at {self.posting:g} m, "
                f"vertical sigma {self.vertical_sigma_m:g} m{assumed}{datum}")


def read_dtm(path: str | os.PathLike[str], map_frame: MapFrame) -> ElevationModel:
    """Read a DTM GeoTIFF in the GN's CRS as heights in ``map``.

    Args:
        path: single-band GeoTIFF (float heights, metres; nodata allowed).
        map_frame: the GN's CRS and map-frame origin.

    Returns:
        The model; ``vertical_sigma_m`` from the file's ``VERTICAL_SIGMA_M`` tag, else
        :data:`DEFAULT_VERTICAL_SIGMA_M`.

    Raises:
        DtmFormatError: unreadable, not one band, no CRS or another CRS than the GN's, a
            rotated or non-square grid, fewer than 2 x 2 posts, no finite height, or a
            bad ``VERTICAL_SIGMA_M`` (each named with the file).
    """
    import rasterio
    from pyproj import CRS
    from rasterio.errors import RasterioError

    where = f"DTM {path}"
    try:
        with rasterio.open(path) as ds:
            if ds.count != 1:
                raise DtmFormatError(f"{where}: {ds.count} bands, expected 1 (heights)")
            if ds.crs is None:
                raise DtmFormatError(f"{where}: no CRS (expected the GN's, {map_frame.crs})")
            crs = CRS.from_wkt(ds.crs.to_wkt())
            t = ds.transform
            tags = ds.tags()
            band = ds.read(1, masked=True)
    except RasterioError as exc:
        raise DtmFormatError(f"{where}: cannot be read ({exc})") from None
    if crs != CRS.from_user_input(map_frame.crs):
        raise DtmFormatError(f"{where} is in {crs.to_string()}, the GN in {map_frame.crs}: "
                             "its heights cannot be placed on the map")
    if t.b != 0.0 or t.d != 0.0 or t.a <= 0.0 or not math.isclose(-t.e, t.a, rel_tol=1e-9):
        raise DtmFormatError(f"{where}: its grid is not north-up with square posts "
                             f"(transform {tuple(t)[:6]})")
    heights = np.ma.filled(band.astype(np.float64), np.nan)
    heights[~np.isfinite(heights)] = np.nan
    if heights.shape[0] < 2 or heights.shape[1] < 2:
        raise DtmFormatError(f"{where}: {heights.shape[1]} x {heights.shape[0]} posts, "
                             "at least 2 x 2 needed")
    if not np.isfinite(heights).any():
        raise DtmFormatError(f"{where}: no finite height (every post is nodata)")
    sigma = DEFAULT_VERTICAL_SIGMA_M
    if SIGMA_TAG in tags:
        try:
            sigma = float(tags[SIGMA_TAG])
        except ValueError:
            sigma = math.nan
        if not (math.isfinite(sigma) and sigma >= 0.0):
            raise DtmFormatError(f"{where}: tag {SIGMA_TAG} = {tags[SIGMA_TAG]!r}, expected "
                                 "a vertical 1-sigma in metres (>= 0)")
    ox, oy = map_frame.origin
    return ElevationModel(heights, x0=t.c + 0.5 * t.a - ox, y0=t.f + 0.5 * t.e - oy,
                          posting=float(t.a), vertical_sigma_m=sigma,
                          datum=tags.get(DATUM_TAG, ""), source=str(path),
                          sigma_stated=SIGMA_TAG in tags)


def write_dtm(path: str | os.PathLike[str], heights: np.ndarray, crs: str, west: float,
              north: float, posting: float, vertical_sigma_m: float, datum: str,
              source: str = "") -> None:
    """Write heights as a DTM GeoTIFF :func:`read_dtm` reads (float32, deflate).

    Args:
        path: the file.
        heights: (rows, cols) heights, metres, row 0 north; NaN: nodata.
        crs: the projected CRS (the GN's), e.g. ``"EPSG:32719"``.
        west, north: CRS coordinates of the grid's upper-left corner, metres.
        posting: post spacing, metres.
        vertical_sigma_m: the posts' vertical 1-sigma (tag ``VERTICAL_SIGMA_M``), metres.
        datum: the vertical datum (tag ``VERTICAL_DATUM``).
        source: provenance (tag ``SOURCE``).
    """
    import rasterio
    from rasterio.transform import Affine

    h = np.asarray(heights, dtype=np.float32)
    rows, cols = h.shape
    profile = {"driver": "GTiff", "width": cols, "height": rows, "count": 1,
               "dtype": "float32", "crs": crs, "nodata": np.nan, "compress": "deflate",
               "predictor": 3,
               "transform": Affine(posting, 0.0, west, 0.0, -posting, north)}
    if rows >= 256 and cols >= 256:
        profile.update(tiled=True, blockxsize=256, blockysize=256)
    with rasterio.open(path, "w", **profile) as dst:
        dst.write(h[None])
        dst.set_band_description(1, "height")
        dst.units = ("metre",)
        dst.update_tags(**{SIGMA_TAG: repr(float(vertical_sigma_m)), DATUM_TAG: datum,
                           "VERTICAL_UNITS": "metre", "POSTING_M": repr(float(posting)),
                           "SOURCE": source})
