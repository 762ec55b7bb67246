"""Small synthetic orthoimages for the orbital_gn tests: reddish textured soil, dark rocks
with shadows, pale outcrops; written as GeoTIFF with a truth catalogue and world.yaml, the
layout of a bag directory."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import rasterio
from rasterio.transform import from_origin

from roi_network import OUTCROP, ROCK, MapFrame, RoiNetwork, empty_records
from roi_network.geojson import write_geojson

GSD = 0.25
CRS = "EPSG:32719"
ORIGIN_UL = (403000.0, 7334000.0)
#: The scene's shadows fall down-right (south-east) of each rock: the sun is in the
#: north-west, azimuth 315 deg; shadows about as long as the rock is wide: elevation 45 deg.
SUN_TAGS = {"SUN_AZIMUTH_DEG": "315.0", "SUN_ELEVATION_DEG": "45.0"}


def scene(seed: int, size: int = 320, n_rocks: int = 40, n_outcrops: int = 4):
    """(H, W, 3) uint8 RGB and the truth records (map frame, origin = raster centre)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[:size, :size].astype(np.float32)
    soil = np.array([0.56, 0.45, 0.35], np.float32)
    base = 0.85 + 0.15 * np.sin(xx / 37.0 + seed) * np.cos(yy / 29.0)
    img = base[..., None] * soil[None, None, :] + rng.normal(0, 0.015, (size, size, 1))
    truth = []
    placed: list[tuple[float, float, float]] = []

    def free(r, c, rad):
        return all((r - pr) ** 2 + (c - pc) ** 2 > (rad + prad + 4) ** 2 for pr, pc, prad in placed)

    for _ in range(n_outcrops):
        for _try in range(50):
            a, b = rng.uniform(6, 12), rng.uniform(4, 8)
            r, c = rng.uniform(20, size - 20), rng.uniform(20, size - 20)
            if free(r, c, a):
                break
        th = rng.uniform(0, np.pi)
        u = (xx - c) * np.cos(th) + (yy - r) * np.sin(th)
        v = -(xx - c) * np.sin(th) + (yy - r) * np.cos(th)
        inside = (u / a) ** 2 + (v / b) ** 2 <= 1
        img[inside] = np.array([0.72, 0.70, 0.66]) + rng.normal(0, 0.02, (inside.sum(), 3))
        placed.append((r, c, a))
        truth.append((OUTCROP, r, c, inside.sum() * GSD**2, 2 * a * GSD, 2 * b * GSD))
    # Decoys: soft pale sand patches and soft dark soil patches (not ROIs), so that the
    # classifiers see negatives.
    for _ in range(n_outcrops + n_rocks // 4):
        r, c = rng.uniform(10, size - 10), rng.uniform(10, size - 10)
        pale = rng.random() < 0.4
        s = rng.uniform(4, 7) if pale else rng.uniform(1.5, 3)
        blob = np.exp(-((xx - c) ** 2 + (yy - r) ** 2) / (2 * s * s))[..., None]
        target = np.array([0.70, 0.66, 0.60]) if pale else soil * 0.55
        img = img * (1 - 0.8 * blob) + target * 0.8 * blob
    for _ in range(n_rocks):
        for _try in range(50):
            rad = rng.uniform(1.8, 4.5)
            r, c = rng.uniform(8, size - 8), rng.uniform(8, size - 8)
            if free(r, c, rad):
                break
        else:
            continue
        d2 = (xx - c) ** 2 + (yy - r) ** 2
        shadow = ((xx - c - 0.8 * rad) ** 2 + (yy - r - 0.8 * rad) ** 2 <= rad**2) & (d2 > rad**2)
        img[shadow] *= 0.55
        inside = d2 <= rad**2
        tone = rng.uniform(0.22, 0.4)
        img[inside] = np.array([tone, tone * 0.95, tone * 0.9]) + rng.normal(0, 0.02,
                                                                             (inside.sum(), 3))
        placed.append((r, c, rad))
        truth.append((ROCK, r, c, inside.sum() * GSD**2, 2 * rad * GSD, 2 * rad * GSD))
    rgb = (np.clip(img, 0, 1) * 255).astype(np.uint8)
    rec = empty_records(len(truth))
    cx, cy = ORIGIN_UL[0] + size * GSD / 2, ORIGIN_UL[1] - size * GSD / 2
    for i, (label, r, c, area, major, minor) in enumerate(truth):
        rec[i]["id"] = i + 1
        rec[i]["label"] = label
        rec[i]["x"] = ORIGIN_UL[0] + (c + 0.5) * GSD - cx
        rec[i]["y"] = ORIGIN_UL[1] - (r + 0.5) * GSD - cy
        rec[i]["area_m2"], rec[i]["major_m"], rec[i]["minor_m"] = area, major, minor
        rec[i]["score"] = 1.0
    return rgb, RoiNetwork(rec, "map", MapFrame(CRS, (cx, cy)))


def write_tif(path: Path, data: np.ndarray, crs: str | None = CRS, transform=None,
              nodata=None, tags: dict[str, str] | None = None) -> Path:
    """Write (H, W, B) or (H, W) data as a GeoTIFF (with metadata ``tags``)."""
    arr = data if data.ndim == 3 else data[..., None]
    transform = transform if transform is not None else from_origin(*ORIGIN_UL, GSD, GSD)
    profile = {"driver": "GTiff", "width": arr.shape[1], "height": arr.shape[0],
               "count": arr.shape[2], "dtype": arr.dtype.name}
    if crs is not None:
        profile |= {"crs": crs, "transform": transform}
    if nodata is not None:
        profile["nodata"] = nodata
    with rasterio.open(path, "w", **profile) as ds:
        ds.write(np.moveaxis(arr, -1, 0))
        if tags:
            ds.update_tags(**tags)
    return path


def make_bag(root: Path, seed: int, size: int = 320) -> Path:
    """A bag directory with orbital.tif, truth/rois.geojson and world.yaml (no rosbag)."""
    rgb, truth = scene(seed, size)
    bag = root / f"scene_s{seed}"
    (bag / "truth").mkdir(parents=True)
    write_tif(bag / "orbital.tif", rgb, tags=SUN_TAGS)
    write_geojson(truth, bag / "truth" / "rois.geojson")
    (bag / "world.yaml").write_text(f"config:\n  preset: test\n  seed: {seed}\n")
    return bag


def label_features(truth: RoiNetwork, crs: str = "OGC:CRS84", polygons: bool = True,
                   n_vertices: int = 16) -> list[dict]:
    """The truth as a person's labels: footprint ellipses (or points) in ``crs``, with
    a ``class`` property."""
    from pyproj import Transformer

    tr = Transformer.from_crs(truth.map_frame.crs, crs, always_xy=True)
    ox, oy = truth.map_frame.origin
    t = np.linspace(0, 2 * np.pi, n_vertices, endpoint=False)
    feats = []
    for r in truth.records:
        x, y = float(r["x"]) + ox, float(r["y"]) + oy
        cls = {ROCK: "rock", OUTCROP: "outcrop"}[int(r["label"])]
        if polygons:
            a, b, th = r["major_m"] / 2, r["minor_m"] / 2, float(r["angle_rad"])
            ex = x + a * np.cos(t) * np.cos(th) - b * np.sin(t) * np.sin(th)
            ey = y + a * np.cos(t) * np.sin(th) + b * np.sin(t) * np.cos(th)
            u, v = tr.transform(ex, ey)
            ring = [[float(p), float(q)] for p, q in zip(u, v, strict=True)]
            geom = {"type": "Polygon", "coordinates": [ring + ring[:1]]}
        else:
            u, v = tr.transform(x, y)
            geom = {"type": "Point", "coordinates": [float(u), float(v)]}
        feats.append({"type": "Feature", "geometry": geom, "properties": {"class": cls}})
    return feats


def write_labels(path: Path, features: list[dict], crs: str | None = None) -> Path:
    """A label GeoJSON as QGIS saves it (``crs`` member only for a non-default CRS)."""
    import json

    doc: dict = {"type": "FeatureCollection", "features": features}
    if crs is not None:
        doc["crs"] = {"type": "name", "properties": {"name": crs}}
    path.write_text(json.dumps(doc))
    return path


def make_labelled_image(root: Path, seed: int, size: int = 320,
                        crs: str = "OGC:CRS84") -> tuple[Path, Path]:
    """An orthoimage and its labels (polygons, lon/lat), no truth/ nor world.yaml."""
    rgb, truth = scene(seed, size)
    root.mkdir(parents=True, exist_ok=True)
    image = write_tif(root / f"site_{seed}.tif", rgb, tags=SUN_TAGS)
    labels = write_labels(root / f"site_{seed}_labels.geojson",
                          label_features(truth, crs), None if crs == "OGC:CRS84" else crs)
    return image, labels
