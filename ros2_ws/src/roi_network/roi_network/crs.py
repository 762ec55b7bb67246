"""The map frame's CRS: one check that a CRS can carry ``map`` coordinates (no rclpy).

The ``map`` frame is metres east, north of an origin (DESIGN.md, Frames), so its CRS must
be a projected one whose first two axes point east and north. The GN codec
(:mod:`roi_network.geojson`) and the ephemeris' grid north (:mod:`roi_network.sun`) check
with :func:`projected_crs` and word a refusal alike.
"""

from __future__ import annotations

from typing import Any


class CrsError(ValueError):
    """A CRS the map frame cannot use; the message names where it came from."""


def projected_crs(crs: Any, where: str):
    """``crs`` as a ``pyproj.CRS``, checked: known, projected, axes east then north.

    Args:
        crs: an authority string (``"EPSG:32719"``, ``"IAU_2015:49910"``), WKT or PROJ.
        where: what the message names (a file's field, a parameter).

    Raises:
        CrsError: naming ``where`` and the CRS.
    """
    from pyproj import CRS
    from pyproj.exceptions import CRSError

    if not isinstance(crs, str) or not crs:
        raise CrsError(f"{where}: must be a CRS string such as 'EPSG:32719'")
    try:
        parsed = CRS.from_user_input(crs)
    except CRSError as exc:
        raise CrsError(f"{where}: unknown CRS '{crs}' ({exc})") from None
    if not parsed.is_projected:
        raise CrsError(f"{where}: '{crs}' is not a projected CRS (the map frame is metres "
                       "east, north)")
    axes = tuple(a.direction.lower() for a in parsed.axis_info[:2])
    if axes != ("east", "north"):
        raise CrsError(f"{where}: '{crs}' has axes {', '.join(axes)}; the map frame needs "
                       "east, north")
    return parsed
