"""Tiled, parallel detection over a raster of any size, on dask.

Two passes over overlapping windows, each task reading its own window from the file (so
memory is bounded by a window per worker, whatever the raster size):

1. statistics (docs/orbital_gn.md, Method step 3): the metric distributions' moments
   over a fixed grid of 512 x 512 blocks (at most :data:`STATS_BLOCKS` of them, spread
   evenly), combined exactly, so the sigma thresholds do not depend on the processing tile size;
2. detection (steps 4-6): candidates of every window whose centroid lies in its core, with
   features.

Local by default (dask's multiprocessing scheduler); ``scheduler="ADDRESS"`` runs the same
task graph on a dask.distributed cluster (its workers must be able to read the raster's
path). ``scheduler="sync"`` runs in-process (tests, debugging).
"""

from __future__ import annotations

import math
import multiprocessing
import os
from collections.abc import Callable, Iterator
from concurrent.futures import ProcessPoolExecutor
from contextlib import contextmanager
from dataclasses import dataclass

import dask
import numpy as np

from orbital_gn.detect import (
    Candidates,
    halo_px,
    metrics_halo_px,
    window_candidates,
    window_moments,
)
from orbital_gn.raster import OrthoInfo, Sun, read_window
from orbital_gn.recipe import Recipe
from roi_detector.candidates import MetricMoments, MetricStats
from roi_detector.features import feature_names
from roi_network import empty_records

#: Side of a statistics block, pixels (fixed: the thresholds must not depend on tiling).
STATS_BLOCK_PX = 512
#: At most this many statistics blocks, spread evenly over the raster (all when fewer).
STATS_BLOCKS = 16
#: Windows a local worker process handles before it is replaced.
WINDOWS_PER_WORKER = 2


@dataclass(frozen=True)
class Tile:
    """A window's core in raster pixels: rows [row0, row1), cols [col0, col1)."""

    row0: int
    col0: int
    row1: int
    col1: int


def tile_grid(height: int, width: int, tile_px: int) -> list[Tile]:
    """Cores of ``tile_px`` side covering the raster, in raster order."""
    if tile_px < 1:
        raise ValueError(f"tile_px must be >= 1, got {tile_px}")
    return [Tile(r, c, min(r + tile_px, height), min(c + tile_px, width))
            for r in range(0, height, tile_px) for c in range(0, width, tile_px)]


def stats_tiles(info: OrthoInfo, max_blocks: int) -> list[Tile]:
    """The statistics blocks: all of the fixed grid, or ``max_blocks`` evenly spread."""
    grid = tile_grid(info.height, info.width, STATS_BLOCK_PX)
    if len(grid) <= max_blocks:
        return grid
    idx = np.unique(np.linspace(0, len(grid) - 1, max_blocks).round().astype(int))
    return [grid[i] for i in idx]


def _read_with_halo(info: OrthoInfo, tile: Tile, halo: int):
    win = read_window(info, tile.row0 - halo, tile.col0 - halo,
                      tile.row1 - tile.row0 + 2 * halo, tile.col1 - tile.col0 + 2 * halo)
    core = (tile.row0 - win.row0, tile.col0 - win.col0,
            tile.row1 - win.row0, tile.col1 - win.col0)
    return win, core


def _moments_task(info: OrthoInfo, tile: Tile, recipe: Recipe):
    win, core = _read_with_halo(info, tile, metrics_halo_px(recipe, info.gsd_m))
    return window_moments(win, core, recipe, info.gsd_m)


def _candidates_task(info: OrthoInfo, tile: Tile, stats, recipe: Recipe,
                     origin: tuple[float, float], sun: Sun | None) -> list[Candidates]:
    win, core = _read_with_halo(info, tile, halo_px(recipe, info.gsd_m))
    if not win.valid[core[0]:core[2], core[1]:core[3]].any():
        return []
    return window_candidates(win, core, info, stats, recipe, origin, sun)


def _run(tasks: list, scheduler: str | None, workers: int,
         progress: Callable[[str, int], Iterator] | None, what: str) -> list:
    """Compute delayed tasks in order, with a progress bar when ``progress`` is given."""
    if scheduler in (None, "processes", "threads", "sync"):
        # One task gains nothing from worker processes (and would pay their start-up).
        sched = "sync" if len(tasks) <= 1 else (scheduler or "processes")
        if sched == "processes":
            with _worker_pool(workers) as pool:
                return _compute_local(tasks, sched, workers, progress, what, pool)
        return _compute_local(tasks, sched, workers, progress, what, None)
    return _compute_distributed(tasks, scheduler, progress, what)


@contextmanager
def _worker_pool(workers: int):
    """Worker processes that are replaced after a few windows: what a long-lived Python
    process keeps of its freed arrays (allocator fragmentation) would otherwise grow with
    the number of windows, i.e. with the raster."""
    os.environ.setdefault("PYTHONHASHSEED", "6640")  # as dask's own pool: stable hashing
    pool = ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn"),
                               max_tasks_per_child=WINDOWS_PER_WORKER)
    try:
        yield pool
    finally:
        pool.shutdown()


def _compute_local(tasks: list, sched: str, workers: int, progress, what: str, pool) -> list:
    kwargs = {"scheduler": sched, "num_workers": workers}
    if pool is not None:
        kwargs["pool"] = pool
    if progress is None:
        return list(dask.compute(*tasks, **kwargs))
    from dask.callbacks import Callback

    bar = progress(what, len(tasks))

    class _Bar(Callback):
        def _posttask(self, key, result, dsk, state, worker_id):
            if str(key).startswith(("_moments_task", "_candidates_task")):
                bar.update(1)

    with _Bar():
        out = list(dask.compute(*tasks, **kwargs))
    bar.close()
    return out


def _compute_distributed(tasks: list, scheduler: str, progress, what: str) -> list:
    from distributed import Client, as_completed

    with Client(scheduler) as client:
        futures = client.compute(tasks)
        index = {f.key: i for i, f in enumerate(futures)}
        out: list = [None] * len(futures)
        bar = progress(what, len(futures)) if progress else None
        for fut in as_completed(futures):
            out[index[fut.key]] = fut.result()
            if bar:
                bar.update(1)
        if bar:
            bar.close()
        return out


def raster_stats(info: OrthoInfo, recipe: Recipe, scheduler: str | None = None,
                 workers: int = 2, progress=None
                 ) -> tuple[dict[int, dict[str, MetricStats]], int]:
    """Per class, mean and sigma of each metric over the raster's valid pixels (pass 1),
    and the number of valid pixels sampled."""
    tasks = [dask.delayed(_moments_task, pure=True)(info, t, recipe)
             for t in stats_tiles(info, STATS_BLOCKS)]
    parts = _run(tasks, scheduler, workers, progress, "statistics")
    out: dict[int, dict[str, MetricStats]] = {}
    n_valid = 0
    for rule in recipe.rules.rules:
        acc: dict[str, MetricMoments] = {}
        for p in parts:  # fixed order: exact, tiling-independent sums
            for k, v in p[rule.label].items():
                acc[k] = acc.get(k, MetricMoments()) + v
        out[rule.label] = {k: v.stats() for k, v in acc.items()}
        n_valid = max([n_valid] + [v.count for k, v in acc.items() if k != "hessian"])
    return out, n_valid


def detect_candidates(info: OrthoInfo, recipe: Recipe, stats, origin: tuple[float, float],
                      tile_px: int = 1536, scheduler: str | None = None, workers: int = 2,
                      progress=None, sun: Sun | None = None) -> list[Candidates]:
    """Candidates of every class over the whole raster (pass 2), merged by class
    (``sun``: the sun direction, for a ``sun_aware`` recipe)."""
    if recipe.sun_aware and sun is None:
        raise ValueError(f"recipe {recipe.name!r} needs the sun direction")
    tiles = tile_grid(info.height, info.width, tile_px)
    tasks = [dask.delayed(_candidates_task, pure=True)(info, t, stats, recipe, origin, sun)
             for t in tiles]
    parts = _run(tasks, scheduler, workers, progress, "detection")
    merged = []
    for rule in recipe.rules.rules:
        chunks = [c for p in parts for c in p if c.label == rule.label]
        if not chunks:
            n_feat = len(feature_names(recipe.feature_groups))
            merged.append(Candidates(rule.label, empty_records(0),
                                     np.zeros((0, n_feat), np.float32), np.zeros(0),
                                     np.zeros(0)))
            continue
        merged.append(Candidates(rule.label, np.concatenate([c.records for c in chunks]),
                                 np.concatenate([c.features for c in chunks]),
                                 np.concatenate([c.row for c in chunks]),
                                 np.concatenate([c.col for c in chunks])))
    return merged


def default_tile_px(info: OrthoInfo) -> int:
    """A core size giving windows of ~4 Mpx at most (about 150 MB of maps per worker)."""
    return int(min(2048, max(256, math.isqrt(info.height * info.width) + 1)))
