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
from dataclasses import asdict, dataclass, field

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
    rec = _roi_records(pts, rng.random(n) < spec.outcrop_fraction, rng)
    return RoiNetwork(
        rec, "map", map_frame=MapFrame(spec.crs, (350000.0, 7400000.0)),
        metadata={"source_image": "synthetic", "generator": "darces_matcher.gn_generator",
                  "seed": seed, **asdict(spec)},
    )


@dataclass(frozen=True)
class FamilySpec:
    """One member of the evaluation family of GNs (point process, density, classes).

    Attributes:
        process: ``"poisson"`` (complete spatial randomness), ``"thomas"`` (Neyman-Scott:
            Poisson parents, Poisson children displaced by an isotropic Gaussian of
            ``cluster_sigma_m``) or ``"matern"`` (children uniform in a disc of radius
            ``cluster_sigma_m``).
        density_per_km2: mean ROI density, ROIs per square kilometre.
        clusters_per_km2: parent intensity of a cluster process.
        cluster_sigma_m: Thomas: Gaussian sigma; Matern: disc radius, metres.
        background: share of ROIs of a cluster process drawn uniformly instead (the
            isolated rocks between boulder fields; without any, clusters more than a
            route step apart cannot be driven between).
        rock_fraction: share of rocks (the rest outcrops).
        hole_m: (width, height) of a rectangle with no ROI (a dune field) in the
            middle of the area, metres; (0, 0): none.
        extent_m: (x, y) size of the area, metres.
        description: one line for tables.
    """

    process: str = "poisson"
    density_per_km2: float = 400.0
    clusters_per_km2: float = 10.0
    cluster_sigma_m: float = 20.0
    background: float = 0.0
    rock_fraction: float = 0.8
    hole_m: tuple[float, float] = (0.0, 0.0)
    extent_m: tuple[float, float] = (2000.0, 1000.0)
    description: str = field(default="", compare=False)


#: The evaluation family: what orbital catalogues look like, from complete
#: spatial randomness to strongly clustered boulder fields, sparse to dense, one class
#: dominant, and a dune field with no ROI. ``darces_eval --synthetic NAME`` generates
#: each (areas 2 km x 1 km: 100..2,000 ROIs).
FAMILY: dict[str, FamilySpec] = {
    "poisson_50": FamilySpec("poisson", 50.0, description="Poisson, 50 ROIs/km^2"),
    "poisson_85": FamilySpec("poisson", 85.0, description="Poisson, 85 ROIs/km^2 (paper)"),
    "poisson_400": FamilySpec("poisson", 400.0, description="Poisson, 400 ROIs/km^2"),
    "poisson_1000": FamilySpec("poisson", 1000.0, description="Poisson, 1,000 ROIs/km^2"),
    "thomas_weak": FamilySpec("thomas", 400.0, 20.0, 50.0,
                              description="Thomas, sigma 50 m, 20 clusters/km^2"),
    "thomas_mid": FamilySpec("thomas", 400.0, 10.0, 20.0, background=0.3,
                             description="Thomas, sigma 20 m, 10 clusters/km^2 (30 % "
                                         "background)"),
    "thomas_strong": FamilySpec("thomas", 400.0, 20.0, 5.0, background=0.3,
                                description="Thomas, sigma 5 m, 20 clusters/km^2 "
                                            "(30 % background)"),
    "thomas_few": FamilySpec("thomas", 85.0, 2.0, 50.0, background=0.3,
                             description="Thomas, sigma 50 m, 2 clusters/km^2 (30 % "
                                         "background), 85 ROIs/km^2"),
    "matern_400": FamilySpec("matern", 400.0, 10.0, 30.0, background=0.3,
                             description="Matern, radius 30 m, 10 clusters/km^2 (30 % "
                                         "background)"),
    "matern_1000": FamilySpec("matern", 1000.0, 20.0, 40.0,
                              description="Matern, radius 40 m, 20 clusters/km^2, "
                                          "1,000 ROIs/km^2"),
    "rocks95": FamilySpec("thomas", 400.0, 10.0, 20.0, background=0.3, rock_fraction=0.95,
                          description="Thomas, sigma 20 m, 10 clusters/km^2 (30 % "
                                      "background), 95 % rocks"),
    "hole": FamilySpec("thomas", 400.0, 10.0, 20.0, background=0.3, hole_m=(600.0, 500.0),
                       description="Thomas, sigma 20 m, 10 clusters/km^2 (30 % background),"
                                   " 600 x 500 m dune field with no ROI"),
}


def family_gn(name: str, seed: int = 0) -> RoiNetwork:
    """Generate the family member ``name`` (a key of :data:`FAMILY`).

    Raises:
        ValueError: on an unknown name (the message lists the known ones).
    """
    if name not in FAMILY:
        raise ValueError(f"unknown synthetic GN '{name}' (known: {', '.join(FAMILY)})")
    return generate_family_gn(FAMILY[name], seed=seed, name=name)


def generate_family_gn(spec: FamilySpec, seed: int = 0, name: str = "") -> RoiNetwork:
    """A GN drawn from a point process (see :class:`FamilySpec`), ``map`` frame.

    Cluster processes are drawn on a torus (wrapped at the borders, so the density is
    uniform); the hole is cut afterwards, so the ROIs outside it keep their process.
    Sizes as in :func:`generate_gn`.
    """
    rng = np.random.default_rng(seed)
    side = np.array(spec.extent_m, dtype=float)
    area_km2 = side[0] * side[1] / 1e6
    n = int(rng.poisson(spec.density_per_km2 * area_km2))
    if spec.process == "poisson":
        pts = rng.uniform(0.0, side, size=(n, 2))
    elif spec.process in ("thomas", "matern"):
        n_parents = max(1, int(rng.poisson(spec.clusters_per_km2 * area_km2)))
        parents = rng.uniform(0.0, side, size=(n_parents, 2))
        members = rng.integers(0, n_parents, size=n)
        if spec.process == "thomas":
            offset = rng.normal(0.0, spec.cluster_sigma_m, size=(n, 2))
        else:
            radius = spec.cluster_sigma_m * np.sqrt(rng.random(n))
            angle = rng.uniform(-np.pi, np.pi, n)
            offset = radius[:, None] * np.column_stack([np.cos(angle), np.sin(angle)])
        pts = (parents[members] + offset) % side
        loose = rng.random(n) < spec.background
        pts[loose] = rng.uniform(0.0, side, size=(int(loose.sum()), 2))
    else:
        raise ValueError(f"FamilySpec.process must be poisson, thomas or matern, "
                         f"got '{spec.process}'")
    if spec.hole_m[0] > 0 and spec.hole_m[1] > 0:
        lo = side / 2 - np.array(spec.hole_m) / 2
        inside = np.all((pts >= lo) & (pts <= lo + np.array(spec.hole_m)), axis=1)
        pts = pts[~inside]
    rec = _roi_records(pts, rng.random(len(pts)) >= spec.rock_fraction, rng)
    meta = {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(spec).items()}
    return RoiNetwork(
        rec, "map", map_frame=MapFrame("EPSG:32719", (350000.0, 7400000.0)),
        metadata={"source_image": "synthetic", "generator": "darces_matcher.gn_generator",
                  "family": name, "seed": seed, **meta},
    )


def _roi_records(pts: np.ndarray, outcrop: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """ROI records at ``pts`` (metres), outcrops where ``outcrop``, ids 0..n-1.

    Sizes above the paper's orbital detection limits (Sec. 4.2: rocks > 0.6 m^2,
    outcrops > 8 m^2), log-normal like boulder size distributions.
    """
    n = len(pts)
    rec = empty_records(n)
    rec["x"], rec["y"] = pts[:, 0], pts[:, 1]
    rec["id"] = np.arange(n)
    rec["label"] = np.where(outcrop, OUTCROP, ROCK)
    area = np.where(outcrop, 8.0 + rng.lognormal(2.5, 0.8, n), 0.6 + rng.lognormal(0.0, 0.7, n))
    aspect = rng.uniform(1.0, 2.0, n)
    rec["area_m2"] = area
    rec["major_m"] = np.sqrt(4.0 * area * aspect / np.pi)
    rec["minor_m"] = np.sqrt(4.0 * area / (aspect * np.pi))
    rec["angle_rad"] = rng.uniform(-np.pi / 2, np.pi / 2, n)
    rec["score"] = 1.0
    rec["n_obs"] = 1
    return rec


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
