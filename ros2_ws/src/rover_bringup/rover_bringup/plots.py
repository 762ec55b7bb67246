"""Plots of ``globloc eval`` (matplotlib, Agg backend: no display needed). No rclpy.

- ``route.png``: the route on the orbital image (``map`` frame), the GN when the bag has
  one, the last LN as aligned by the last /global_alignment, truth and estimate, and the
  place of each fix.
- ``error.png``: horizontal error against distance driven, the published 3-sigma bound,
  the 10 m false-fix line and the moment of each fix.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from rover_bringup.errors import GloblocError
from rover_bringup.evaluation import FALSE_FIX_M, Evaluation, RunData
from rover_bringup.run_outputs import LOCAL_NETWORK

#: Largest side of the orbital image as drawn, pixels (the full image can be 10k+).
MAX_IMAGE_PX = 1600
#: Margin around the route, metres.
MARGIN_M = 40.0


def _pyplot():
    import matplotlib

    matplotlib.use('Agg')
    import matplotlib.pyplot as plt

    return plt


def _save(fig, path: Path) -> None:
    # Atomic: a reader (or a crash mid-write) never sees half a PNG.
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=f'.{path.name}.', suffix='.png')
    os.close(fd)
    try:
        fig.savefig(tmp, dpi=110, bbox_inches='tight')
        os.replace(tmp, path)
    finally:
        Path(tmp).unlink(missing_ok=True)


def _orbital(bag_dir: Path, window: tuple[float, float, float, float], origin):
    """The orbital image's window (map frame) as (RGB array, extent), or None."""
    path = bag_dir / 'orbital.tif'
    if not path.is_file() or origin is None:
        return None
    try:
        import rasterio
        from rasterio.windows import from_bounds

        x0, x1, y0, y1 = window
        with rasterio.open(path) as src:
            win = from_bounds(x0 + origin[0], y0 + origin[1], x1 + origin[0], y1 + origin[1],
                              transform=src.transform)
            win = win.intersection(rasterio.windows.Window(0, 0, src.width, src.height))
            scale = max(win.width, win.height) / MAX_IMAGE_PX
            shape = (min(src.count, 3), max(int(win.height / max(scale, 1.0)), 1),
                     max(int(win.width / max(scale, 1.0)), 1))
            img = src.read(list(range(1, shape[0] + 1)), window=win, out_shape=shape)
            left, bottom, right, top = rasterio.windows.bounds(win, src.transform)
    except Exception:  # no image is not worth failing the evaluation for
        return None
    img = np.moveaxis(img, 0, -1)
    if img.dtype != np.uint8:
        img = np.clip(img / max(float(img.max()), 1e-9), 0, 1)
    if img.shape[-1] == 1:
        img = img[..., 0]
    return img, (left - origin[0], right - origin[0], bottom - origin[1], top - origin[1])


def _map_origin(bag_dir: Path):
    """The map frame's origin in the CRS: from the GN, else from the truth catalogue."""
    from roi_network.geojson import read_geojson

    for path in (bag_dir / 'gn.geojson', bag_dir / 'truth' / 'rois.geojson'):
        if path.is_file():
            try:
                net = read_geojson(path)
            except (OSError, ValueError):
                continue
            if net.map_frame is not None:
                return net.map_frame.origin
    return None


def plot_route(ev: Evaluation, data: RunData, path: Path) -> None:
    """Write ``route.png`` (module docstring)."""
    plt = _pyplot()
    route = ev.truth_route
    pts = np.vstack([route, ev.estimate_xy]) if len(ev.estimate_xy) else route
    lo, hi = pts.min(axis=0) - MARGIN_M, pts.max(axis=0) + MARGIN_M
    window = (lo[0], hi[0], lo[1], hi[1])
    fig, ax = plt.subplots(figsize=(8, 8))
    image = _orbital(data.bag_dir, window, _map_origin(data.bag_dir))
    if image is not None:
        ax.imshow(image[0], extent=image[1], origin='upper', interpolation='bilinear')
    gn_path = data.bag_dir / 'gn.geojson'
    if gn_path.is_file():
        from roi_network.geojson import read_geojson

        try:
            gn = read_geojson(gn_path).records
            inside = ((gn['x'] >= lo[0]) & (gn['x'] <= hi[0]) & (gn['y'] >= lo[1])
                      & (gn['y'] <= hi[1]))
            ax.scatter(gn['x'][inside], gn['y'][inside], s=6, c='gold', marker='o',
                       linewidths=0, label='GN', alpha=0.8)
        except (OSError, ValueError):
            pass
    ln_path = data.run_dir / LOCAL_NETWORK
    if ln_path.is_file() and len(data.alignment):
        from roi_network.transform import Rigid2D
        from rover_bringup.run_outputs import read_records_csv

        try:
            ln = read_records_csv(ln_path)
            _, tx, ty, yaw = data.alignment[-1]
            xy = Rigid2D(yaw, tx, ty).apply(np.c_[ln['x'], ln['y']])
            ax.scatter(xy[:, 0], xy[:, 1], s=16, facecolors='none', edgecolors='cyan',
                       label='LN as aligned (last alignment)')
        except (GloblocError, ValueError):
            pass
    ax.plot(route[:, 0], route[:, 1], 'w-', lw=2.5, alpha=0.6)
    ax.plot(route[:, 0], route[:, 1], 'k-', lw=1.2, label='truth')
    ax.plot(route[0, 0], route[0, 1], 'k^', ms=8, label='start')
    if len(ev.estimate_xy):
        ax.plot(ev.estimate_xy[:, 0], ev.estimate_xy[:, 1], 'r-', lw=1.2,
                label='/global_pose')
        fix_t = [f[0] for f in ev.fixes]
        if fix_t:
            k = np.clip(np.searchsorted(ev.t, fix_t), 0, len(ev.t) - 1)
            ax.plot(ev.estimate_xy[k, 0], ev.estimate_xy[k, 1], 'r+', ms=9, label='fixes')
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect('equal')
    ax.set_xlabel('map x (east), m')
    ax.set_ylabel('map y (north), m')
    s = ev.summary
    ax.set_title(f"{Path(s['bag_dir']).name}: {s['message']}")
    ax.legend(loc='best', fontsize=8)
    _save(fig, path)
    plt.close(fig)


def plot_error(ev: Evaluation, path: Path) -> None:
    """Write ``error.png`` (module docstring)."""
    plt = _pyplot()
    fig, ax = plt.subplots(figsize=(9, 4.5))
    if len(ev.t):
        ax.plot(ev.distance_m, ev.error_m, 'r-', lw=1.2, label='horizontal error')
        if np.isfinite(ev.sigma3_m).any():
            ax.plot(ev.distance_m, ev.sigma3_m, 'b--', lw=1.0, label='published 3-sigma')
        ax.axhline(FALSE_FIX_M, color='k', lw=0.8, ls=':', label='false fix (10 m)')
        for i, (_, d, event) in enumerate(ev.fixes):
            ax.axvline(d, color='green' if event != 'switched' else 'orange', lw=0.5,
                       alpha=0.6, label='fix' if i == 0 else None)
        ax.set_yscale('symlog', linthresh=1.0)
    else:
        ax.text(0.5, 0.5, ev.summary['message'], ha='center', va='center',
                transform=ax.transAxes)
    ax.set_xlim(0, max(ev.summary['route_length_m'], 1.0))
    ax.set_xlabel('distance driven, m')
    ax.set_ylabel('error, m')
    ax.grid(True, alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc='upper right', fontsize=8)
    _save(fig, path)
    plt.close(fig)
