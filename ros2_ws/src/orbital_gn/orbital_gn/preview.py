"""A PNG of a GN drawn over its orthoimage (decimated read: any raster size)."""

from __future__ import annotations

import math
import os
from pathlib import Path

import cv2
import numpy as np
import rasterio

from orbital_gn.raster import open_ortho
from roi_network import ROCK, RoiNetwork

#: BGR colours: rocks red, outcrops cyan (as the simulator's contact sheet).
_COLOURS = {ROCK: (40, 40, 255), 2: (255, 255, 0)}


def draw_preview(ortho: str | os.PathLike[str], gn: RoiNetwork,
                 out: str | os.PathLike[str], max_side_px: int = 2400) -> None:
    """Draw each ROI's footprint ellipse over the image and write ``out`` (PNG, atomic)."""
    info = open_ortho(ortho)
    scale = min(1.0, max_side_px / max(info.width, info.height))
    shape = (max(1, int(info.height * scale)), max(1, int(info.width * scale)))
    with rasterio.open(info.path) as ds:
        data = ds.read(list(info.bands), out_shape=(3, *shape)).astype(np.float32)
    if info.stretch is not None:
        lo, hi = info.stretch
        data = (data - lo) / (hi - lo) * 255.0
    img = np.ascontiguousarray(np.clip(np.moveaxis(data, 0, -1), 0, 255).astype(np.uint8)[
        ..., ::-1])
    inv = ~info.transform
    ox, oy = gn.map_frame.origin if gn.map_frame else (0.0, 0.0)
    px_per_m = scale / info.gsd_m
    for r in gn.records:
        col, row = inv * (float(r["x"]) + ox, float(r["y"]) + oy)
        centre = (round(col * scale), round(row * scale))
        axes = (max(1, round(r["major_m"] / 2 * px_per_m)),
                max(1, round(r["minor_m"] / 2 * px_per_m)))
        # Map angle is counter-clockwise from east; image rows go down (north-up raster).
        angle = -math.degrees(float(r["angle_rad"]))
        cv2.ellipse(img, centre, axes, angle, 0, 360, _COLOURS.get(int(r["label"]),
                                                                   (255, 255, 255)), 1,
                    cv2.LINE_AA)
    out = Path(out)
    tmp = out.with_name(out.name + ".tmp.png")
    if not cv2.imwrite(str(tmp), img):
        raise OSError(f"{out}: cannot write the preview PNG")
    tmp.replace(out)
