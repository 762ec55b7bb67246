"""A person's labels of an orthoimage, as drawn in QGIS: the truth that ``train`` and
``eval`` use for an image that is not a simulator bag.

A label file is a GeoJSON FeatureCollection of Point / MultiPoint / Polygon /
MultiPolygon features with a ``class`` property (``rock`` or ``outcrop``, any case), in
any CRS pyproj reads: the legacy ``crs`` member (QGIS writes it for a projected layer),
else RFC 7946's longitude / latitude (OGC:CRS84). A polygon gives the ROI's footprint
(centroid, area, second-moment ellipse); a point gives its position, with its size when
the feature carries ``area_m2`` (and ``major_m`` / ``minor_m``) properties.

The labels cover a *region*: the polygons of a region file (``--region``), else the label
file's extent (its ``bbox`` member, else the bounding box of its features), clipped to the
image. Inside the region, ground without a label is negative; outside it nothing is used.
Labels outside the image or the region are counted and skipped.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Final

import numpy as np
from pyproj import CRS, Transformer
from pyproj.exceptions import CRSError

from orbital_gn.raster import OrthoInfo
from roi_network import LABELS, MapFrame, RoiNetwork, empty_records

#: The CRS of a GeoJSON without a ``crs`` member (RFC 7946: longitude, latitude).
DEFAULT_CRS: Final = "OGC:CRS84"
#: Margin of the region drawn around the labels when no region is given, m.
EXTENT_PAD_M: Final = 1.0


class LabelFileError(ValueError):
    """A label or region file cannot be used; the message names the file and feature."""


@dataclass
class Region:
    """The labelled region in the image's CRS: polygons (each a list of rings, the first
    the exterior, (N, 2) arrays) whose union is the region."""

    polygons: list[list[np.ndarray]]
    source: str

    def contains(self, xy: np.ndarray) -> np.ndarray:
        """(N,) bool: points (N, 2) inside the region (even-odd rule per polygon)."""
        xy = np.asarray(xy, float).reshape(-1, 2)
        inside = np.zeros(len(xy), bool)
        for rings in self.polygons:
            inside |= _in_polygon(xy, rings)
        return inside

    def area_m2(self) -> float:
        """The region's area (polygons assumed not to overlap)."""
        return float(sum(abs(_ring_area(rings[0])) - sum(abs(_ring_area(r)) for r in rings[1:])
                         for rings in self.polygons))


@dataclass
class LabelSet:
    """Labels of one image: ROI records in the image's ``map`` frame, and their region.

    Attributes:
        truth: the labels as ROI records (``map`` frame, image CRS and origin).
        region: where the labels are complete.
        source: the label file.
        counts: labels read, kept per class, skipped outside the image / region.
    """

    truth: RoiNetwork
    region: Region
    source: str
    counts: dict[str, Any] = field(default_factory=dict)

    def notes(self) -> list[str]:
        """User-facing lines about skipped labels (none when every label was used)."""
        out = []
        for key, where in (("outside_image", "outside the image"),
                           ("outside_region", "outside the labelled region")):
            if self.counts.get(key):
                out.append(f"{self.source}: {self.counts[key]} of {self.counts['read']} "
                           f"labels lie {where} and are skipped")
        return out


def _ring_area(ring: np.ndarray) -> float:
    x, y = ring[:, 0], ring[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def _in_polygon(xy: np.ndarray, rings: list[np.ndarray]) -> np.ndarray:
    inside = np.zeros(len(xy), bool)
    px, py = xy[:, 0:1], xy[:, 1:2]
    for ring in rings:
        x0, y0 = ring[:, 0], ring[:, 1]
        x1, y1 = np.roll(x0, -1), np.roll(y0, -1)
        cross = (y0 > py) != (y1 > py)
        with np.errstate(divide="ignore", invalid="ignore"):
            xint = x0 + (py - y0) * (x1 - x0) / (y1 - y0)
        inside ^= (cross & (px < xint)).sum(axis=1) % 2 == 1
    return inside


def polygon_footprint(rings: list[np.ndarray]) -> tuple[float, float, float, np.ndarray]:
    """(area, centroid x, centroid y, 2x2 second-moment covariance) of a polygon with
    holes, by Green's theorem (about the first vertex: projected coordinates are large)."""
    ref = rings[0][0]
    a = cx = cy = sxx = syy = sxy = 0.0
    for k, ring in enumerate(rings):
        x, y = ring[:, 0] - ref[0], ring[:, 1] - ref[1]
        xn, yn = np.roll(x, -1), np.roll(y, -1)
        c = x * yn - xn * y
        sign = 1.0 if k == 0 else -1.0
        ar = 0.5 * c.sum()
        orient = math.copysign(1.0, ar) if ar else 1.0
        s = sign * orient  # exterior counted positive, holes negative, any winding
        a += s * ar
        cx += s * ((x + xn) * c).sum() / 6.0
        cy += s * ((y + yn) * c).sum() / 6.0
        sxx += s * ((y * y + y * yn + yn * yn) * c).sum() / 12.0
        syy += s * ((x * x + x * xn + xn * xn) * c).sum() / 12.0
        sxy += s * ((x * yn + 2 * x * y + 2 * xn * yn + xn * y) * c).sum() / 24.0
    if a <= 0:
        raise ValueError("polygon of zero area")
    mx, my = cx / a, cy / a
    cov = np.array([[syy / a - mx * mx, sxy / a - mx * my],
                    [sxy / a - mx * my, sxx / a - my * my]])
    return a, mx + ref[0], my + ref[1], cov


def _ellipse(cov: np.ndarray) -> tuple[float, float, float]:
    # Full axes 4 sqrt(eigenvalue): the detector's convention (a filled ellipse's moments).
    w, v = np.linalg.eigh(cov)
    w = np.maximum(w, 0.0)
    major, minor = 4.0 * math.sqrt(w[1]), 4.0 * math.sqrt(w[0])
    return major, minor, math.atan2(v[1, 1], v[0, 1])


def _file_crs(doc: dict, source: str) -> CRS:
    member = doc.get("crs")
    if member is None:
        return CRS.from_user_input(DEFAULT_CRS)
    name = member.get("properties", {}).get("name") if isinstance(member, dict) else None
    try:
        return CRS.from_user_input(name)
    except (CRSError, TypeError) as exc:
        raise LabelFileError(f"{source}: field 'crs' names no CRS pyproj reads "
                             f"({member!r})") from exc


def _load(path: str | os.PathLike[str], what: str) -> tuple[dict, str]:
    p = Path(path)
    if not p.is_file():
        raise LabelFileError(f"{p}: {what} file not found")
    try:
        doc = json.loads(p.read_text(encoding="utf-8"))
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise LabelFileError(f"{p}: not valid JSON ({exc})") from exc
    if not isinstance(doc, dict) or doc.get("type") != "FeatureCollection":
        raise LabelFileError(f"{p}: field 'type' must be 'FeatureCollection' (a GeoJSON "
                             "layer saved from QGIS)")
    if not isinstance(doc.get("features"), list):
        raise LabelFileError(f"{p}: field 'features' must be a list")
    return doc, str(p)


def _polygons(geom: dict, where: str) -> list[list[np.ndarray]]:
    kind, coords = geom.get("type"), geom.get("coordinates")
    try:
        polys = [coords] if kind == "Polygon" else coords
        out = []
        for poly in polys:
            rings = [np.asarray(r, float)[:, :2] for r in poly]
            if not rings or any(len(r) < 3 or not np.isfinite(r).all() for r in rings):
                raise ValueError
            out.append(rings)
        return out
    except (TypeError, ValueError, IndexError) as exc:
        raise LabelFileError(f"{where}: field 'geometry.coordinates' is not a valid "
                             f"{kind}") from exc


def _points(geom: dict, where: str) -> list[np.ndarray]:
    kind, coords = geom.get("type"), geom.get("coordinates")
    try:
        pts = [coords] if kind == "Point" else coords
        out = [np.asarray(p, float)[:2] for p in pts]
        if any(p.shape != (2,) or not np.isfinite(p).all() for p in out):
            raise ValueError
        return out
    except (TypeError, ValueError, IndexError) as exc:
        raise LabelFileError(f"{where}: field 'geometry.coordinates' is not a valid "
                             f"{kind}") from exc


def _transformer(src: CRS, info: OrthoInfo) -> Transformer:
    return Transformer.from_crs(src, CRS.from_user_input(info.crs), always_xy=True)


def _to_image(tr: Transformer, xy: np.ndarray) -> np.ndarray:
    x, y = tr.transform(xy[:, 0], xy[:, 1])
    return np.column_stack([x, y])


def image_footprint(info: OrthoInfo) -> list[np.ndarray]:
    """The raster's outline (one ring, CRS coordinates)."""
    t = info.transform
    corners = [(0, 0), (info.width, 0), (info.width, info.height), (0, info.height)]
    return [np.array([t * c for c in corners], float)]


def read_region(path: str | os.PathLike[str], info: OrthoInfo) -> Region:
    """The polygons of a region file, in the image's CRS.

    Raises:
        LabelFileError: unreadable file, unknown CRS, or no polygon (names the file).
    """
    doc, source = _load(path, "region")
    tr = _transformer(_file_crs(doc, source), info)
    polys = []
    for i, feat in enumerate(doc["features"]):
        geom = (feat or {}).get("geometry") or {}
        if geom.get("type") in ("Polygon", "MultiPolygon"):
            for rings in _polygons(geom, f"{source}: feature {i}"):
                polys.append([_to_image(tr, r) for r in rings])
    if not polys:
        raise LabelFileError(f"{source}: no Polygon feature: a region file is a polygon "
                             "layer drawn around the labelled ground")
    return Region(polys, source)


def read_labels(path: str | os.PathLike[str], info: OrthoInfo, origin: tuple[float, float],
                region: str | os.PathLike[str] | None = None) -> LabelSet:
    """Read a label file against an image: ROI records in the image's ``map`` frame.

    Args:
        path: the label GeoJSON.
        info: the image (:func:`orbital_gn.raster.open_ortho`).
        origin: the ``map``-frame origin (easting, northing) in the image's CRS.
        region: a region file; default: the label file's extent.

    Raises:
        LabelFileError: unreadable file, unknown CRS, a feature without a ``class`` or
            with a class other than rock / outcrop (all such classes named), a geometry
            that is not a point or polygon, or no label left inside the image.
    """
    doc, source = _load(path, "label")
    tr = _transformer(_file_crs(doc, source), info)
    rows: list[tuple[int, float, float, float, float, float, float]] = []
    bad: dict[str, list[int]] = {}
    xy_all = []
    for i, feat in enumerate(doc["features"]):
        where = f"{source}: feature {i}"
        if not isinstance(feat, dict):
            raise LabelFileError(f"{where}: must be an object")
        props = feat.get("properties") or {}
        cls = props.get("class")
        name = cls.strip().lower() if isinstance(cls, str) else None
        if name not in LABELS:
            bad.setdefault(repr(cls), []).append(i)
            continue
        geom = feat.get("geometry") or {}
        kind = geom.get("type")
        if kind in ("Polygon", "MultiPolygon"):
            for rings in _polygons(geom, where):
                rings = [_to_image(tr, r) for r in rings]
                try:
                    area, x, y, cov = polygon_footprint(rings)
                except ValueError as exc:
                    raise LabelFileError(f"{where}: polygon of zero area") from exc
                major, minor, angle = _ellipse(cov)
                rows.append((LABELS[name], x, y, area, major, minor, angle))
                xy_all.append(np.vstack(rings))
        elif kind in ("Point", "MultiPoint"):
            for p in _points(geom, where):
                x, y = _to_image(tr, p[None, :])[0]
                area = _size(props, "area_m2", where)
                major = _size(props, "major_m", where) or 2.0 * math.sqrt(area / math.pi)
                minor = _size(props, "minor_m", where) or major
                rows.append((LABELS[name], x, y, area, major, minor, 0.0))
                xy_all.append(np.array([[x, y]]))
        else:
            raise LabelFileError(f"{where}: geometry type {kind!r}; a label is a Point or a "
                                 "Polygon (or their Multi- forms)")
    if bad:
        listed = ", ".join(f"{c} (features {_few(ix)})" for c, ix in sorted(bad.items()))
        raise LabelFileError(f"{source}: property 'class' must be 'rock' or 'outcrop'; "
                             f"found {listed}: rename or delete those features")
    if region is not None:
        reg = read_region(region, info)
    else:
        reg = _extent_region(doc, tr, xy_all, source)
    lab = np.array([r[0] for r in rows], int)
    xy = np.array([[r[1], r[2]] for r in rows], float).reshape(-1, 2)
    in_image = Region([image_footprint(info)], info.path).contains(xy)
    in_region = reg.contains(xy)
    keep = in_image & in_region
    if rows and not keep.any():
        raise LabelFileError(f"{source}: none of its {len(rows)} labels lies inside "
                             f"{info.path} (after reprojection to {info.crs}) and the "
                             "labelled region: is it the labels of another image?")
    rec = empty_records(int(keep.sum()))
    kept = [r for r, k in zip(rows, keep, strict=True) if k]
    for j, (label, x, y, area, major, minor, angle) in enumerate(kept):
        rec[j]["id"] = j + 1
        rec[j]["label"] = label
        rec[j]["x"], rec[j]["y"] = x - origin[0], y - origin[1]
        rec[j]["area_m2"], rec[j]["major_m"], rec[j]["minor_m"] = area, major, minor
        rec[j]["angle_rad"], rec[j]["score"] = angle, 1.0
    counts = {"read": len(rows), "rock": int((lab[keep] == LABELS["rock"]).sum()),
              "outcrop": int((lab[keep] == LABELS["outcrop"]).sum()),
              "outside_image": int((~in_image).sum()),
              "outside_region": int((in_image & ~in_region).sum())}
    truth = RoiNetwork(rec, "map", MapFrame(info.crs, origin),
                       {"source": source, "labels": counts})
    return LabelSet(truth, reg, source, counts)


def _size(props: dict, name: str, where: str) -> float:
    v = props.get(name)
    if v is None:
        return 0.0
    if isinstance(v, bool) or not isinstance(v, int | float) or not math.isfinite(v) or v < 0:
        raise LabelFileError(f"{where}: property '{name}' must be a number >= 0, got {v!r}")
    return float(v)


def _few(ix: list[int]) -> str:
    return ", ".join(map(str, ix[:5])) + (f", ... {len(ix)} in all" if len(ix) > 5 else "")


def _extent_region(doc: dict, tr: Transformer, xy_all: list[np.ndarray],
                   source: str) -> Region:
    bbox = doc.get("bbox")
    if isinstance(bbox, list) and len(bbox) in (4, 6):
        x0, y0 = bbox[0], bbox[1]
        x1, y1 = bbox[len(bbox) // 2], bbox[len(bbox) // 2 + 1]
        ring = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float)
        # Densify so that a box in degrees stays the same box once projected.
        t = np.linspace(0, 1, 16, endpoint=False)[:, None]
        ring = np.vstack([a + t * (b - a) for a, b in zip(ring, np.roll(ring, -1, 0),
                                                           strict=True)])
        return Region([[_to_image(tr, ring)]], f"{source} (bbox)")
    if not xy_all:
        raise LabelFileError(f"{source}: no label and no 'bbox': give the labelled region "
                             "with --region REGION.geojson")
    pts = np.vstack(xy_all)
    # Padded by EXTENT_PAD_M, so that a point label on the box's edge lies inside it.
    (x0, y0), (x1, y1) = pts.min(axis=0) - EXTENT_PAD_M, pts.max(axis=0) + EXTENT_PAD_M
    ring = np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]], float)
    return Region([[ring]], f"{source} (extent of its labels)")
