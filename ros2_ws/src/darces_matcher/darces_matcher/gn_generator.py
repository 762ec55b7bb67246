"""Synthetic Global Networks of any size, for tests and benchmarks.

ROIs on a desert pavement cluster (rock fields, debris around outcrops), so positions come
from a Thomas (Neyman-Scott) cluster process: parent centres uniform over a square, a
Poisson-like number of children per parent, displaced by an isotropic Gaussian; plus a
uniform background. The defaults put 174 ROIs, the size of the paper's Atacama GN, at
400 ROIs/km^2 on a 1.32 km x 0.33 km strip (an orbital crop around a traverse), so that
routes of 600 m..1 km through 19..29 ROIs exist (paper Sec. 7.2); at that density
10^6 ROIs cover 2,500 km^2.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

import numpy as np

from roi_network.network import MapFrame, RoiNetwork
from roi_network.records import OUTCROP, ROCK, empty_records


@dataclass(frozen=True)
class GnSpec:
    """Parameters of a synthetic GN.

    Attributes:
        n_rois: number of ROIs.
        density_per_km2: mean ROI density, ROIs per square kilometre.
        aspect: x extent over y extent of the rectangular area (an orbital crop around
            a traverse is a strip).
        cluster_fraction: share of ROIs that belong to clusters (the rest is uniform).
        mean_cluster_size: mean number of ROIs per cluster.
        cluster_sigma_m: standard deviation of a cluster's spread, metres.
        outcrop_fraction: share of outcrops (the rest are rocks).
        crs: projected CRS recorded in the map frame.
    """

    n_rois: int = 174
    density_per_km2: float = 400.0
    aspect: float = 4.0
    cluster_fraction: float = 0.6
    mean_cluster_size: float = 5.0
    cluster_sigma_m: float = 30.0
    outcrop_fraction: float = 0.2
    crs: str = "EPSG:32719"

    @property
    def extent_m(self) -> tuple[float, float]:
        """(x, y) extent of the rectangular area, metres."""
        area_m2 = 1e6 * self.n_rois / self.density_per_km2
        return math.sqrt(area_m2 * self.aspect), math.sqrt(area_m2 / self.aspect)


def generate_gn(spec: GnSpec | None = None, seed: int = 0) -> RoiNetwork:
    """A clustered synthetic GN in the ``map`` frame (origin at the square's corner).

    Args:
        spec: generation parameters (defaults: 174 ROIs in a strip, as in the paper).
        seed: random seed; the same seed gives the same GN.

    Returns:
        The GN, ids 0..n-1, positions in metres within the extent.
    """
    spec = spec or GnSpec()
    rng = np.random.default_rng(seed)
    n, side = spec.n_rois, np.array(spec.extent_m)
    n_clustered = round(spec.cluster_fraction * n)
    n_parents = max(1, math.ceil(n_clustered / spec.mean_cluster_size))
    parents = rng.uniform(0.0, side, size=(n_parents, 2))
    members = rng.integers(0, n_parents, size=n_clustered)
    clustered = parents[members] + rng.normal(0.0, spec.cluster_sigma_m, size=(n_clustered, 2))
    # Wrap around (torus) so that clusters near the border keep the density uniform.
    clustered %= side
    background = rng.uniform(0.0, side, size=(n - n_clustered, 2))
    pts = np.vstack([clustered, background])
    pts = pts[rng.permutation(n)]
    rec = empty_records(n)
    rec["x"], rec["y"] = pts[:, 0], pts[:, 1]
    rec["id"] = np.arange(n)
    outcrop = rng.random(n) < spec.outcrop_fraction
    rec["label"] = np.where(outcrop, OUTCROP, ROCK)
    # Sizes above the paper's orbital detection limits (Sec. 4.2: rocks > 0.6 m^2,
    # outcrops > 8 m^2), log-normal like boulder size distributions.
    area = np.where(outcrop, 8.0 + rng.lognormal(2.5, 0.8, n), 0.6 + rng.lognormal(0.0, 0.7, n))
    aspect = rng.uniform(1.0, 2.0, n)
    rec["area_m2"] = area
    rec["major_m"] = np.sqrt(4.0 * area * aspect / np.pi)
    rec["minor_m"] = np.sqrt(4.0 * area / (aspect * np.pi))
    rec["angle_rad"] = rng.uniform(-np.pi / 2, np.pi / 2, n)
    rec["score"] = 1.0
    rec["n_obs"] = 1
    return RoiNetwork(
        rec, "map", map_frame=MapFrame(spec.crs, (350000.0, 7400000.0)),
        metadata={"source_image": "synthetic", "generator": "darces_matcher.gn_generator",
                  "seed": seed, **asdict(spec)},
    )


def repeated_pattern_gn(n_copies: int = 2, seed: int = 0, spacing_m: float = 2000.0) -> RoiNetwork:
    """A GN made of identical copies of one cluster field, for ambiguity tests.

    Args:
        n_copies: how many translated copies of a 60-ROI field.
        seed: random seed of the field.
        spacing_m: translation between copies along x, metres.
    """
    base = generate_gn(GnSpec(n_rois=60, aspect=1.0), seed=seed).records
    parts = []
    for k in range(n_copies):
        part = base.copy()
        part["x"] += k * spacing_m
        parts.append(part)
    rec = np.concatenate(parts)
    rec["id"] = np.arange(len(rec))
    return RoiNetwork(rec, "map", map_frame=MapFrame("EPSG:32719"))
