"""Contact sheet: what a bag holds, at a glance.

Left: the orbital overview with the route (yellow, start green, end magenta) and the truth
ROIs (rocks red, outcrops cyan, as footprint ellipses). Right: rover left frames with the
truth ROIs they show outlined (from the renderer's label image), with frame time.
"""

from __future__ import annotations

import cv2
import numpy as np

ROCK_BGR = (40, 40, 230)
OUTCROP_BGR = (230, 220, 40)


def contact_sheet(orbital_rgb: np.ndarray, extent: float, path_xy: np.ndarray,
                  catalogue: np.ndarray, frames: list[tuple[np.ndarray, np.ndarray, float]],
                  title: str, side: int = 760) -> np.ndarray:
    """BGR uint8 image. ``frames``: (rgb, label, t) of rover left images."""
    ov = cv2.resize(orbital_rgb[:, :, ::-1], (side, side), interpolation=cv2.INTER_AREA)
    scale = side / extent

    def px(xy: np.ndarray) -> np.ndarray:
        return np.column_stack([(xy[:, 0] + extent / 2) * scale,
                                (extent / 2 - xy[:, 1]) * scale])

    for r in catalogue:
        c = px(np.array([[r["x"], r["y"]]]))[0]
        axes = (max(1, int(r["major_m"] / 2 * scale + 1.5)),
                max(1, int(r["minor_m"] / 2 * scale + 1.5)))
        col = ROCK_BGR if r["label"] == 1 else OUTCROP_BGR
        cv2.ellipse(ov, (int(c[0]), int(c[1])), axes, -np.degrees(r["angle_rad"]), 0, 360,
                    col, 1, cv2.LINE_AA)
    pts = px(path_xy[:: max(1, len(path_xy) // 2000)]).astype(np.int32)
    cv2.polylines(ov, [pts.reshape(-1, 1, 2)], False, (0, 220, 255), 2, cv2.LINE_AA)
    cv2.circle(ov, tuple(int(v) for v in pts[0]), 6, (0, 200, 0), -1)
    cv2.circle(ov, tuple(int(v) for v in pts[-1]), 6, (200, 0, 200), -1)
    cv2.putText(ov, title, (8, 22), cv2.FONT_HERSHEY_SIMPLEX, 0.6, (255, 255, 255), 2)
    tiles = []
    fw, fh = 380, 285
    for rgb, label, t in frames:
        img = rgb[:, :, ::-1].copy()
        for rid in np.unique(label[label > 0]):
            mask = (label == rid).astype(np.uint8)
            if mask.sum() < 30:
                continue
            cnts, _ = cv2.findContours(mask, cv2.RETR_EXTERNAL, cv2.CHAIN_APPROX_SIMPLE)
            cls = catalogue["label"][catalogue["id"] == rid]
            col = ROCK_BGR if len(cls) and cls[0] == 1 else OUTCROP_BGR
            cv2.drawContours(img, cnts, -1, col, 2, cv2.LINE_AA)
        img = cv2.resize(img, (fw, fh), interpolation=cv2.INTER_AREA)
        cv2.putText(img, f"t={t:.0f}s", (6, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5,
                    (255, 255, 255), 1, cv2.LINE_AA)
        tiles.append(img)
    while len(tiles) < 6:
        tiles.append(np.zeros((fh, fw, 3), np.uint8))
    grid = np.vstack([np.hstack(tiles[0:2]), np.hstack(tiles[2:4]), np.hstack(tiles[4:6])])
    grid = cv2.resize(grid, (int(grid.shape[1] * side / grid.shape[0]), side),
                      interpolation=cv2.INTER_AREA)
    return np.hstack([ov, grid])
