"""The world: terrain + ground textures + rocks + georeference, built from a config."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from pyproj import CRS, Transformer

from atacama_sim.config import WorldConfig
from atacama_sim.rocks import RockField, generate_rocks
from atacama_sim.terrain import Terrain
from atacama_sim.texture import GroundTextures, generate_textures


def map_origin(crs: str, lonlat: tuple[float, float]) -> tuple[float, float]:
    """Projected coordinates of ``lonlat`` in ``crs``, rounded to the metre: the map-frame
    origin. Uses the CRS's own geographic CRS, so Mars CRSs take Mars longitudes."""
    target = CRS.from_user_input(crs)
    tr = Transformer.from_crs(target.geodetic_crs, target, always_xy=True)
    e, n = tr.transform(*lonlat)
    return float(round(e)), float(round(n))


@dataclass
class World:
    """Everything the sensors observe."""

    cfg: WorldConfig
    terrain: Terrain
    textures: GroundTextures
    rocks: RockField
    origin: tuple[float, float]  # map-frame origin in the CRS (easting, northing)

    @classmethod
    def build(cls, cfg: WorldConfig, focus_xy: np.ndarray | None = None) -> World:
        terrain = Terrain.generate(cfg.terrain, cfg.site.extent_m, cfg.seed)
        textures = generate_textures(terrain.base.shape[0], cfg.seed)
        rocks = generate_rocks(cfg.rocks, terrain, cfg.seed, focus_xy=focus_xy)
        return cls(cfg, terrain, textures, rocks, map_origin(cfg.site.crs, cfg.site.site_lonlat))
