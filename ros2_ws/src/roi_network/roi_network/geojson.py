"""GeoJSON codec for georeferenced ROI networks (the GN file, and the truth catalogue).

A GN file is a FeatureCollection of Point features whose coordinates are in the projected
CRS of the orthoimage (easting, northing[, z]), so that it opens in QGIS as is. The CRS is
given both as the legacy ``crs`` member (which GDAL/QGIS honour) and in ``metadata``,
together with the map-frame origin and provenance (source image, ground sample distance).

Records are in the ``map`` frame (CRS coordinates minus the origin). Each feature also
stores its exact map-frame position as properties ``map_x``/``map_y``; a reader uses them
when they agree with the geometry to 1 mm, so that write -> read is bit-exact, and falls
back to the geometry when they do not (a point moved in QGIS, say).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Final

import numpy as np
from pyproj import CRS

from roi_network.crs import CrsError, projected_crs
from roi_network.network import MapFrame, RoiNetwork
from roi_network.records import LABEL_NAMES, LABELS, ROI_DTYPE, as_records

#: Properties every GN feature must carry (DESIGN.md, Files).
REQUIRED_PROPERTIES: Final = ("id", "class", "area_m2", "major_m", "minor_m", "angle_rad",
                              "score")
#: Record fields that may be absent from a file (defaults: 0).
OPTIONAL_PROPERTIES: Final = ("height_m", "cov_xx", "cov_xy", "cov_yy", "n_obs")
_FLOAT_PROPERTIES: Final = ("area_m2", "major_m", "minor_m", "angle_rad", "score",
                            "height_m", "cov_xx", "cov_xy", "cov_yy")
_INT_PROPERTIES: Final = ("id", "n_obs")
_MAP_XY_TOLERANCE_M: Final = 1e-3
#: Values of a GN's ``metadata.domain_check.status`` (orbital_gn's check of the orthoimage
#: against the model's training images), in increasing doubt.
DOMAIN_STATUSES: Final = ("ok", "warn", "out_of_distribution")


class GeoJsonFormatError(ValueError):
    """A GeoJSON file is not a valid ROI network; the message names the file and field."""


def validate_crs(crs: Any, where: str) -> str:
    """Check that ``crs`` can carry the map frame (:func:`roi_network.crs.projected_crs`)
    and return it as given.

    Raises:
        GeoJsonFormatError: naming ``where`` if the CRS is unknown, not projected or not
            east, north.
    """
    try:
        projected_crs(crs, where)
    except CrsError as exc:
        raise GeoJsonFormatError(str(exc)) from None
    return crs


def _crs_urn(crs: str) -> str:
    authority = CRS.from_user_input(crs).to_authority(min_confidence=90)
    if authority is None:
        return crs
    return f"urn:ogc:def:crs:{authority[0]}::{authority[1]}"


def to_geojson_dict(network: RoiNetwork) -> dict[str, Any]:
    """The FeatureCollection of a georeferenced network (``map`` frame + MapFrame)."""
    if network.map_frame is None:
        raise GeoJsonFormatError("RoiNetwork: field 'map_frame' is required to write GeoJSON")
    crs = validate_crs(network.map_frame.crs, "RoiNetwork.map_frame.crs")
    ox, oy = (float(v) for v in network.map_frame.origin)
    records = as_records(network.records)
    features = []
    for i, r in enumerate(records):
        props: dict[str, Any] = {"id": int(r["id"]), "class": LABEL_NAMES[int(r["label"])]}
        for name in _FLOAT_PROPERTIES:
            props[name] = float(r[name])
        props["n_obs"] = int(r["n_obs"])
        props["map_x"], props["map_y"] = float(r["x"]), float(r["y"])
        coords = [float(r["x"]) + ox, float(r["y"]) + oy, float(r["z"])]
        for name, value in (*props.items(), ("coordinates", coords)):
            values = value if isinstance(value, list) else [value]
            if any(isinstance(v, float) and not math.isfinite(v) for v in values):
                raise GeoJsonFormatError(f"record {i} (id {int(r['id'])}): field '{name}' "
                                         "is not finite")
        features.append({"type": "Feature", "id": int(r["id"]),
                         "geometry": {"type": "Point", "coordinates": coords},
                         "properties": props})
    metadata = {**network.metadata, "crs": crs, "map_origin": [ox, oy],
                "frame_id": network.frame_id}
    return {"type": "FeatureCollection",
            "crs": {"type": "name", "properties": {"name": _crs_urn(crs)}},
            "metadata": metadata, "features": features}


def write_geojson(network: RoiNetwork, path: str | os.PathLike[str]) -> None:
    """Write ``network`` to ``path`` atomically (a partial file never replaces a good one)."""
    doc = to_geojson_dict(network)
    path = Path(path)
    tmp = path.with_name(path.name + ".tmp")
    with tmp.open("w", encoding="utf-8") as f:
        # One feature per line: diffable, and streamable for large GNs.
        head = {k: v for k, v in doc.items() if k != "features"}
        f.write(json.dumps(head, allow_nan=False)[:-1] + ', "features": [\n')
        f.write(",\n".join(json.dumps(feat, allow_nan=False) for feat in doc["features"]))
        f.write("\n]}\n")
    tmp.replace(path)


def _number(props: dict[str, Any], name: str, where: str, integer: bool) -> float | int:
    value = props[name]
    if isinstance(value, bool) or not isinstance(value, int | float):
        raise GeoJsonFormatError(f"{where}: property '{name}' must be a number, "
                                 f"got {type(value).__name__}")
    if integer and (not float(value).is_integer() or not 0 <= value < 2**32):
        raise GeoJsonFormatError(f"{where}: property '{name}' must be an integer in "
                                 f"[0, 2^32), got {value}")
    if not math.isfinite(value):
        raise GeoJsonFormatError(f"{where}: property '{name}' is not finite")
    return int(value) if integer else float(value)


def from_geojson_dict(doc: Any, source: str = "<GeoJSON>") -> RoiNetwork:
    """Parse a FeatureCollection into a ``map``-frame :class:`RoiNetwork`.

    Raises:
        GeoJsonFormatError: naming ``source`` and the offending feature and field.
    """
    if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection":
        raise GeoJsonFormatError(f"{source}: field 'type' must be 'FeatureCollection'")
    metadata = doc.get("metadata")
    if not isinstance(metadata, dict):
        raise GeoJsonFormatError(f"{source}: field 'metadata' (CRS, map origin) is missing")
    crs = validate_crs(metadata.get("crs"), f"{source}: field 'metadata.crs'")
    origin = metadata.get("map_origin")
    if (not isinstance(origin, list) or len(origin) != 2
            or not all(isinstance(v, int | float) and not isinstance(v, bool)
                       and math.isfinite(v) for v in origin)):
        raise GeoJsonFormatError(f"{source}: field 'metadata.map_origin' must be "
                                 "[easting, northing] in metres")
    ox, oy = float(origin[0]), float(origin[1])
    features = doc.get("features")
    if not isinstance(features, list):
        raise GeoJsonFormatError(f"{source}: field 'features' must be a list")
    records = np.zeros(len(features), dtype=ROI_DTYPE)
    for i, feat in enumerate(features):
        where = f"{source}: feature {i}"
        if not isinstance(feat, dict):
            raise GeoJsonFormatError(f"{where}: must be an object")
        geom = feat.get("geometry")
        if not isinstance(geom, dict) or geom.get("type") != "Point":
            raise GeoJsonFormatError(f"{where}: field 'geometry' must be a Point")
        coords = geom.get("coordinates")
        if (not isinstance(coords, list) or len(coords) not in (2, 3)
                or not all(isinstance(v, int | float) and not isinstance(v, bool)
                           and math.isfinite(v) for v in coords)):
            raise GeoJsonFormatError(f"{where}: field 'geometry.coordinates' must be "
                                     "[easting, northing] or [easting, northing, z]")
        props = feat.get("properties")
        if not isinstance(props, dict):
            raise GeoJsonFormatError(f"{where}: field 'properties' is missing")
        for name in REQUIRED_PROPERTIES:
            if name not in props:
                raise GeoJsonFormatError(f"{where}: property '{name}' is missing")
        cls = props["class"]
        if cls not in LABELS:
            raise GeoJsonFormatError(f"{where}: property 'class' is {cls!r}, expected one "
                                     f"of {sorted(LABELS)}")
        rec = records[i]
        rec["label"] = LABELS[cls]
        for name in (*_FLOAT_PROPERTIES, *_INT_PROPERTIES):
            if name in props:
                rec[name] = _number(props, name, where, integer=name in _INT_PROPERTIES)
        x, y = coords[0] - ox, coords[1] - oy
        mx, my = props.get("map_x"), props.get("map_y")
        if (isinstance(mx, int | float) and isinstance(my, int | float)
                and abs(mx - x) <= _MAP_XY_TOLERANCE_M and abs(my - y) <= _MAP_XY_TOLERANCE_M):
            x, y = mx, my
        rec["x"], rec["y"] = x, y
        rec["z"] = coords[2] if len(coords) == 3 else 0.0
    _check_domain_field(metadata.get("domain_check"), source)
    extra = {k: v for k, v in metadata.items() if k not in ("crs", "map_origin", "frame_id")}
    return RoiNetwork(records, metadata.get("frame_id", "map"), MapFrame(crs, (ox, oy)), extra)


def _check_domain_field(check: Any, source: str) -> None:
    if check is None:
        return
    where = f"{source}: field 'metadata.domain_check"
    if not isinstance(check, dict):
        raise GeoJsonFormatError(f"{where}' must be an object")
    if check.get("status") not in DOMAIN_STATUSES:
        raise GeoJsonFormatError(f"{where}.status' is {check.get('status')!r}, expected one "
                                 f"of {list(DOMAIN_STATUSES)}")
    if not isinstance(check.get("reasons", []), list):
        raise GeoJsonFormatError(f"{where}.reasons' must be a list")


def domain_status(network: RoiNetwork) -> str:
    """A GN's ``metadata.domain_check.status``, or ``"unknown"`` when it has none (a GN
    not written by ``orbital_gn prepare``, or an older one)."""
    check = network.metadata.get("domain_check")
    return check.get("status", "unknown") if isinstance(check, dict) else "unknown"


def domain_reasons(network: RoiNetwork) -> list[str]:
    """The messages of a GN's domain-check reasons (empty when it has none)."""
    check = network.metadata.get("domain_check")
    reasons = check.get("reasons", []) if isinstance(check, dict) else []
    return [str(r.get("message", r)) if isinstance(r, dict) else str(r) for r in reasons]


def read_geojson(path: str | os.PathLike[str]) -> RoiNetwork:
    """Read a GN (or truth) GeoJSON file.

    Raises:
        FileNotFoundError: if ``path`` does not exist.
        GeoJsonFormatError: if it is not valid JSON or not a valid ROI network; the
            message names the file, the feature and the field.
    """
    path = Path(path)
    try:
        with path.open(encoding="utf-8") as f:
            doc = json.load(f)
    except FileNotFoundError:
        raise FileNotFoundError(f"GN file not found: {path}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise GeoJsonFormatError(f"{path}: not valid JSON ({exc})") from exc
    return from_geojson_dict(doc, str(path))
