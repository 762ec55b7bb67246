"""The GN a run will use, checked against the bag before anything starts. No rclpy.

The GN defines the ``map`` frame the graph publishes ``/global_pose`` in (its projected CRS
and origin, DESIGN.md Frames). A GN that cannot be read, or that is in another CRS than the
bag's orbital image (prepared from another image), would only fail inside gn_server and
darces_matcher, or worse, run and publish poses in another frame. ``globloc run`` refuses
both with one line naming the file. A GN whose ROIs lie mostly outside the bag's orbital
image (a GN of another area) is allowed (the rover may not be where the GN is) with a
warning: the matcher then stays unlocalized and says so on ``/matcher/status``.
"""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np

from rover_bringup.errors import GloblocError


def check_gn(bag_root: Path, warn: Callable[[str], None]) -> None:
    """Check ``<bag>/gn.geojson`` against ``<bag>/orbital.tif`` (either may be absent).

    Raises:
        GloblocError: an unreadable GN, or a GN in another CRS than the orbital image.
    """
    from roi_network.geojson import GeoJsonFormatError, read_geojson
    from roi_network.records import xy

    gn_path, tif = bag_root / 'gn.geojson', bag_root / 'orbital.tif'
    if not gn_path.is_file():
        return
    try:
        gn = read_geojson(gn_path)
    except (GeoJsonFormatError, OSError) as exc:
        raise GloblocError(f'GN {gn_path} cannot be used: {exc}') from None
    if gn.map_frame is None:
        raise GloblocError(f'GN {gn_path} has no CRS and map origin: not a GN')
    if not tif.is_file():
        return
    import rasterio
    from pyproj import CRS
    from rasterio.errors import RasterioIOError

    try:
        with rasterio.open(tif) as ds:
            image_crs, bounds = ds.crs, ds.bounds
    except RasterioIOError as exc:
        warn(f'orbital image {tif} cannot be read ({exc}): the GN is not checked against it')
        return
    if image_crs is None:
        return
    if CRS.from_user_input(gn.map_frame.crs) != CRS.from_wkt(image_crs.to_wkt()):
        raise GloblocError(
            f"GN {gn_path} is in {gn.map_frame.crs}, the bag's orbital image {tif} in "
            f"{image_crs.to_string()}: the GN was prepared from another image and its map "
            f"frame is not this bag's; prepare it from this one: orbital_gn prepare {tif} "
            f"--out {gn_path}")
    pts = xy(gn.records) + np.asarray(gn.map_frame.origin, float)
    if len(pts):
        inside = ((pts[:, 0] >= bounds.left) & (pts[:, 0] <= bounds.right)
                  & (pts[:, 1] >= bounds.bottom) & (pts[:, 1] <= bounds.top))
        if inside.mean() < 0.5:
            warn(f"GN {gn_path}: {int((~inside).sum())} of {len(pts)} ROIs lie outside the "
                 f"bag's orbital image {tif}: a GN of another area? Where the rover is not "
                 "in the GN, the matcher stays unlocalized (/matcher/status)")


def check_truth_frame(bag_root: Path) -> None:
    """``globloc eval``: the GN's map frame (CRS and origin), in which the run published its
    poses, must be the truth's (``truth/rois.geojson``), or the two cannot be compared.

    Raises:
        GloblocError: the frames differ (both files named).
    """
    from pyproj import CRS

    from roi_network.geojson import GeoJsonFormatError, read_geojson

    gn_path, truth_path = bag_root / 'gn.geojson', bag_root / 'truth' / 'rois.geojson'
    if not (gn_path.is_file() and truth_path.is_file()):
        return
    try:
        gn, truth = read_geojson(gn_path).map_frame, read_geojson(truth_path).map_frame
    except (GeoJsonFormatError, OSError) as exc:
        raise GloblocError(f'cannot compare the map frames: {exc}') from None
    if gn is None or truth is None:
        return
    same_crs = CRS.from_user_input(gn.crs) == CRS.from_user_input(truth.crs)
    if not same_crs or not np.allclose(gn.origin, truth.origin, atol=1e-3):
        raise GloblocError(
            f'the GN {gn_path} (map frame {gn.crs}, origin {tuple(gn.origin)}) and the truth '
            f'{truth_path} ({truth.crs}, origin {tuple(truth.origin)}) are in different '
            'map frames: the run\'s /global_pose cannot be judged against this truth')
