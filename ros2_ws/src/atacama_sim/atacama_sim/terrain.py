"""The terrain: a height field in the map frame (metres, x east, y north, z up).

Height = bilinear interpolation of a base grid (large relief + medium undulation, spectral
synthesis) + bilinear interpolation of a periodic fine-roughness tile. The renderer's
vertex shader evaluates exactly this function (same texels, same bilinear weights), so
the height the truth uses is the height the cameras see.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from atacama_sim.config import TerrainConfig, rng_for

#: Base height-grid spacing (also the material map's), m.
TERRAIN_RES_M = 0.5
#: Rms height of the undulation band, m.
MEDIUM_RMS_M = 0.30
#: Shortest and longest wavelength of the undulation band, m.
MEDIUM_WAVELENGTHS_M = (4.0, 40.0)
#: Rms height of the fine roughness (a periodic tile), m.
ROUGH_RMS_M = 0.012
#: Roughness tile spacing, m.
ROUGH_RES_M = 0.025
#: Roughness tile side, texels (period ROUGH_TILE_PX * ROUGH_RES_M = 25.6 m).
ROUGH_TILE_PX = 1024


def spectral_field(rng: np.random.Generator, shape: tuple[int, int], res_m: float,
                   wavelengths_m: tuple[float, float], slope: float = 3.0) -> np.ndarray:
    """Zero-mean, unit-rms periodic random field whose power lies between two wavelengths.

    Power falls as k^-slope inside the band (slope 3 = fractal terrain, Hurst 0.5).
    Written by hand: no library synthesises band-limited fractal noise on a grid.
    """
    ny, nx = shape
    ky = np.fft.fftfreq(ny, d=res_m)[:, None]
    kx = np.fft.rfftfreq(nx, d=res_m)[None, :]
    k = np.hypot(kx, ky)
    kmin, kmax = 1.0 / wavelengths_m[1], 1.0 / wavelengths_m[0]
    with np.errstate(divide="ignore"):
        amp = np.where((k >= kmin) & (k <= kmax), k ** (-slope / 2.0), 0.0)
    # Soft band edges avoid ringing.
    amp *= np.exp(-((k / kmax) ** 4)) * (1.0 - np.exp(-((k / kmin) ** 4)))
    spec = amp * (rng.standard_normal(amp.shape) + 1j * rng.standard_normal(amp.shape))
    f = np.fft.irfft2(spec, s=shape)
    f -= f.mean()
    rms = f.std()
    return (f / rms if rms > 0 else f).astype(np.float32)


@dataclass
class Terrain:
    """Height field of the world square.

    Attributes:
        base: (N, N) float32 heights, row i at y = origin + i*res, column j at x = origin + j*res.
        origin: map x (= y) of texel [0, 0], metres.
        res: base grid spacing, metres.
        rough: (M, M) float32 periodic roughness tile, texel (i, j) at y = i*rough_res,
            x = j*rough_res (wraps).
        rough_res: roughness tile spacing, metres.
    """

    base: np.ndarray
    origin: float
    res: float
    rough: np.ndarray
    rough_res: float

    @classmethod
    def generate(cls, cfg: TerrainConfig, extent_m: float, seed: int) -> Terrain:
        """Synthesise the terrain of a square of side ``extent_m`` centred on the origin."""
        n = round(extent_m / TERRAIN_RES_M) + 1
        rng = rng_for(seed, "terrain")
        base = cfg.large_rms_m * spectral_field(rng, (n, n), TERRAIN_RES_M,
                                                cfg.large_wavelengths_m)
        base += MEDIUM_RMS_M * spectral_field(rng, (n, n), TERRAIN_RES_M,
                                              MEDIUM_WAVELENGTHS_M, slope=2.5)
        m = ROUGH_TILE_PX
        rough = ROUGH_RMS_M * spectral_field(rng, (m, m), ROUGH_RES_M,
                                             (3 * ROUGH_RES_M, 1.5), slope=2.0)
        base -= base[n // 2, n // 2]  # map origin at height 0
        return cls(base.astype(np.float32), -extent_m / 2.0, TERRAIN_RES_M,
                   rough.astype(np.float32), ROUGH_RES_M)

    @property
    def extent(self) -> float:
        """Side of the square, metres."""
        return (self.base.shape[0] - 1) * self.res

    @staticmethod
    def _bilinear(grid: np.ndarray, u: np.ndarray, v: np.ndarray, wrap: bool) -> np.ndarray:
        """Bilinear sample at fractional texel coordinates (u along columns, v along rows).

        Clamps at the border (or wraps for periodic tiles); same arithmetic as the shader.
        """
        ny, nx = grid.shape
        if wrap:
            j0 = np.floor(u)
            i0 = np.floor(v)
            tu, tv = u - j0, v - i0
            j0 = j0.astype(np.int64) % nx
            i0 = i0.astype(np.int64) % ny
            j1, i1 = (j0 + 1) % nx, (i0 + 1) % ny
        else:
            u = np.clip(u, 0.0, nx - 1.0)
            v = np.clip(v, 0.0, ny - 1.0)
            j0 = np.minimum(np.floor(u), nx - 2).astype(np.int64)
            i0 = np.minimum(np.floor(v), ny - 2).astype(np.int64)
            tu, tv = u - j0, v - i0
            j1, i1 = j0 + 1, i0 + 1
        a = grid[i0, j0] * (1 - tu) + grid[i0, j1] * tu
        b = grid[i1, j0] * (1 - tu) + grid[i1, j1] * tu
        return a * (1 - tv) + b * tv

    def base_height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Height of the base grid only (no roughness): what the rover body rides on."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        return self._bilinear(self.base, (x - self.origin) / self.res,
                              (y - self.origin) / self.res, wrap=False)

    def height(self, x: np.ndarray, y: np.ndarray) -> np.ndarray:
        """Surface height z(x, y), metres, map frame (what the cameras see)."""
        x = np.asarray(x, dtype=np.float64)
        y = np.asarray(y, dtype=np.float64)
        return self.base_height(x, y) + self._bilinear(
            self.rough, x / self.rough_res, y / self.rough_res, wrap=True)

    def slope_deg(self) -> np.ndarray:
        """Slope of the base grid, degrees (for statistics and docs)."""
        gy, gx = np.gradient(self.base.astype(np.float64), self.res)
        return np.degrees(np.arctan(np.hypot(gx, gy)))
