"""Where the sun is during the traverse: the site, the bag's epoch and the sun's direction.

The bag starts at the local true solar time ``SolarTimeConfig.local_solar_time_h`` of the
local date ``SolarTimeConfig.date`` at the map-frame origin (``SiteConfig.site_lonlat``);
its header stamps are that instant plus the traverse time, in POSIX UTC seconds, so the
sun at any stamp follows from the site and the stamp alone. The body (Earth or Mars) is
the one the map CRS lies on (its ellipsoid). The sun's direction comes from
:mod:`roi_network.sun` (NOAA on Earth, apparent: with refraction; Mars24 on Mars) at the
longitude and latitude of the point asked for (the map position's, through the CRS), and
turns into the map's axes with :func:`roi_network.sun.grid_north` at that point (the map
frame is grid-aligned: x grid east, y grid north, z up).
"""

from __future__ import annotations

import datetime as dt
import functools
import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from pyproj import CRS, Transformer

from atacama_sim.config import WorldConfig
from roi_network import sun as ephemeris

#: Semi-major axes (m) of the bodies the sun model knows, and the tolerance (relative)
#: within which a CRS's ellipsoid counts as that body's.
BODY_RADII_M = {ephemeris.EARTH: 6378137.0, ephemeris.MARS: 3396190.0}
BODY_RADIUS_TOLERANCE = 0.01


def site_body(crs: str) -> str:
    """``"earth"`` or ``"mars"``: the body whose ellipsoid the CRS ``crs`` uses.

    Raises:
        ValueError: naming ``site.crs`` when its ellipsoid is neither Earth's nor Mars'.
    """
    a = float(CRS.from_user_input(crs).ellipsoid.semi_major_metre)
    for body, radius in BODY_RADII_M.items():
        if abs(a - radius) <= BODY_RADIUS_TOLERANCE * radius:
            return body
    raise ValueError(f"site.crs: '{crs}' has an ellipsoid of semi-major axis {a:.0f} m, "
                     "neither Earth's nor Mars': the sun cannot be placed")


def parse_date(text: str) -> dt.date:
    """``sun.date`` as a date.

    Raises:
        ValueError: naming ``sun.date`` when it is not ``YYYY-MM-DD``.
    """
    try:
        return dt.date.fromisoformat(str(text))
    except ValueError:
        raise ValueError(f"sun.date: expected a date YYYY-MM-DD, got {text!r}") from None


@dataclass(frozen=True)
class Sky:
    """The site and the bag's epoch; the sun's direction at a bag time and map point.

    Attributes:
        body: ``"earth"`` or ``"mars"``.
        crs: the map CRS.
        origin: map-frame origin in the CRS (easting, northing), m.
        lon_deg: east longitude of the map-frame origin, degrees.
        lat_deg: latitude of the map-frame origin, degrees.
        start_ns: the bag's first stamp, ns since the POSIX epoch (UTC).
    """

    body: str
    crs: str
    origin: tuple[float, float]
    lon_deg: float
    lat_deg: float
    start_ns: int

    @classmethod
    def from_config(cls, cfg: WorldConfig, origin: tuple[float, float]) -> Sky:
        """The sky of ``cfg`` (site and ``sun`` section) over a world with map ``origin``.

        Raises:
            ValueError: naming the field (``site.crs``, ``sun.date``,
                ``sun.local_solar_time_h``) the sun cannot be placed from.
        """
        body = site_body(cfg.site.crs)
        lon, lat = (float(v) for v in cfg.site.site_lonlat)
        hours = float(cfg.sun.local_solar_time_h)
        if not (math.isfinite(hours) and 0.0 <= hours < 24.0):
            raise ValueError(f"sun.local_solar_time_h: {hours} is outside [0, 24) h")
        start = ephemeris.utc_on_date_at_solar_time(body, lon, parse_date(cfg.sun.date),
                                                    hours)
        start_ns = round(start.timestamp()) * 1_000_000_000  # whole seconds
        return cls(body, cfg.site.crs, (float(origin[0]), float(origin[1])), lon, lat,
                   start_ns)

    @property
    def start_utc(self) -> dt.datetime:
        """The bag's first stamp as a UTC datetime."""
        return dt.datetime.fromtimestamp(self.start_ns // 1_000_000_000, dt.UTC)

    def utc_s(self, t: float) -> float:
        """POSIX UTC seconds of bag time ``t`` (s after the start)."""
        return self.start_ns * 1e-9 + float(t)

    def lonlat(self, xy: np.ndarray) -> np.ndarray:
        """East longitude and latitude (degrees) of map points ``xy`` (N, 2)."""
        xy = np.atleast_2d(np.asarray(xy, float))
        lon, lat = _to_lonlat(self.crs)(xy[:, 0] + self.origin[0], xy[:, 1] + self.origin[1])
        return np.column_stack([lon, lat])

    def sun_map(self, t: float, xy: np.ndarray | None = None) -> tuple[np.ndarray, float]:
        """Unit vector toward the sun in the map frame and its apparent elevation (deg),
        at bag time ``t`` seen from map point ``xy`` (the origin when None)."""
        if xy is None:
            lon, lat = self.lon_deg, self.lat_deg
        else:
            lon, lat = self.lonlat(np.asarray(xy, float)[:2])[0]
        return sun_map_at(self.body, self.crs, float(lon), float(lat), self.utc_s(t))

    def sun_map_many(self, t: np.ndarray, xy: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`sun_map` of each bag time ``t`` (N,) at map point ``xy`` (N, 2):
        vectors (N, 3), apparent elevations (N,)."""
        t = np.asarray(t, float)
        ll = self.lonlat(xy) if len(t) else np.zeros((0, 2))
        vec = np.zeros((len(t), 3))
        el = np.zeros(len(t))
        for i in range(len(t)):
            vec[i], el[i] = sun_map_at(self.body, self.crs, float(ll[i, 0]), float(ll[i, 1]),
                                       self.utc_s(t[i]))
        return vec, el

    def metadata(self) -> dict[str, Any]:
        """The site and epoch as the bag records them (rover.yaml's ``site:``, world.yaml,
        the rosbag2 metadata's ``custom_data`` as ``site.<key>`` strings)."""
        return {"body": self.body, "crs": self.crs,
                "latitude_deg": self.lat_deg, "longitude_deg": self.lon_deg,
                "epoch_utc": self.start_utc.isoformat().replace("+00:00", "Z"),
                "epoch_ns": int(self.start_ns)}


def sun_map_at(body: str, crs: str, lon_deg: float, lat_deg: float, utc_s: float
               ) -> tuple[np.ndarray, float]:
    """Unit vector toward the (apparent) sun in the map axes of ``crs`` at a point and
    POSIX time, and its apparent elevation, degrees."""
    pos = ephemeris.sun_position(body, lat_deg, lon_deg, utc_s)
    grid = _grid_north(crs, round(lon_deg, 4), round(lat_deg, 4))
    return grid.enu_to_grid(pos.enu(refracted=True)), float(pos.apparent_elevation_deg)


@functools.lru_cache(maxsize=4096)
def _grid_north(crs: str, lon_deg: float, lat_deg: float) -> ephemeris.GridNorth:
    """Grid north at a point rounded to 1e-4 deg (11 m; the convergence changes by
    less than 1e-4 deg over it)."""
    return ephemeris.grid_north(crs, lon_deg, lat_deg)


@functools.lru_cache(maxsize=8)
def _to_lonlat(crs: str):
    target = CRS.from_user_input(crs)
    return Transformer.from_crs(target, target.geodetic_crs, always_xy=True).transform
