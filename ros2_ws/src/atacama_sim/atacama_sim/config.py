"""Typed configuration of the synthetic world, its sensors and the traverse.

Every generation parameter has its default here and nowhere else; ``world.yaml`` is this
object written out (``asdict``), so a bag records exactly what made it. Presets only
override fields of these defaults.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class SiteConfig:
    """Where the world sits on the planet.

    The map frame is the projected CRS shifted by ``origin`` (easting, northing, metres),
    which is the projection of ``site_lonlat`` rounded to the metre (DESIGN.md, Frames).
    The world square spans map coordinates [-extent/2, extent/2] in x and y.
    """

    crs: str = "EPSG:32719"  # WGS 84 / UTM zone 19S; "IAU_2015:49910" for Mars
    site_lonlat: tuple[float, float] = (-69.95, -24.10)  # Atacama, near Yungay (deg)
    extent_m: float = 1500.0  # side of the square world = orbital image footprint


@dataclass
class TerrainConfig:
    """Height field: spectral (FFT) synthesis of three bands plus a fine roughness tile."""

    res_m: float = 0.5  # base height-grid spacing
    large_rms_m: float = 5.0  # relief band rms, wavelengths large_wavelengths_m
    large_wavelengths_m: tuple[float, float] = (150.0, 1500.0)
    medium_rms_m: float = 0.30  # undulation band
    medium_wavelengths_m: tuple[float, float] = (4.0, 40.0)
    rough_rms_m: float = 0.012  # small roughness, a periodic tile
    rough_res_m: float = 0.025
    rough_tile_px: int = 1024  # tile period = rough_tile_px * rough_res_m


@dataclass
class AlbedoConfig:
    """Multi-scale albedo: three surface materials mixed by smooth random fields, each with
    its own cm-scale detail texture (grains, pebbles, varnished clasts)."""

    res_m: float = 0.5  # material-map spacing (same grid as the height field)
    soil_rgb: tuple[float, float, float] = (0.56, 0.45, 0.35)
    gravel_rgb: tuple[float, float, float] = (0.46, 0.41, 0.36)
    pavement_rgb: tuple[float, float, float] = (0.30, 0.23, 0.18)
    gravel_cover: float = 0.30  # fraction of the area
    pavement_cover: float = 0.25
    patch_wavelength_m: float = 25.0  # typical size of material patches
    detail_res_m: float = 0.01  # detail texture texel (pebbles)
    detail_tile_px: int = 2048  # 20 m period
    pebbles_per_m2: float = 220.0  # sub-cm..5 cm clasts in the detail texture


@dataclass
class RockConfig:
    """Major ROIs (rocks, outcrops) and sub-threshold clutter.

    Major ROIs are a Thomas cluster process: cluster centres uniform, members Gaussian
    around them, plus a uniform background fraction. Sizes follow a power law
    (size-frequency of rocks) truncated to the issue's ranges.
    """

    major_per_km2: float = 85.0  # rocks + outcrops
    outcrop_fraction: float = 0.22
    clusters_per_km2: float = 7.0
    cluster_sigma_m: float = 22.0
    background_fraction: float = 0.15  # unclustered share
    rock_area_m2: tuple[float, float] = (0.6, 6.0)
    rock_height_m: tuple[float, float] = (0.25, 2.0)
    outcrop_area_m2: tuple[float, float] = (8.0, 100.0)
    outcrop_height_m: tuple[float, float] = (0.08, 0.30)
    size_power: float = 1.8  # dN/dA ~ A^-size_power
    min_separation_m: float = 2.0  # between major ROI footprints
    clutter_per_m2: float = 0.12  # sub-threshold rocks, uniform
    clutter_apron_per_rock: int = 12  # extra debris around each major rock
    clutter_diameter_m: tuple[float, float] = (0.08, 0.75)
    n_templates: int = 16  # distinct irregular rock shapes


@dataclass
class SunConfig:
    """Sun direction (azimuth clockwise from north) and light levels (linear units)."""

    elevation_deg: float = 42.0
    azimuth_deg: float = 35.0  # NNE: southern-hemisphere morning
    irradiance: float = 1.0
    sky_ambient: float = 0.16


@dataclass
class CameraConfig:
    """Rectified stereo pair on a mast: the MER Navcam bench with a wider lens.

    Source: Maki et al. (2003), "Mars Exploration Rover engineering cameras",
    J. Geophys. Res. 108(E12), 8071: Navcams with a 20 cm stereo baseline on the mast,
    about 1.54 m above the ground, tilted down. MER's 45 deg field of view never saw half
    of the ROIs within 15 m of a 1 km route (a fixed camera sees an ROI 4 m beside the
    route only while it is 10-20 m ahead: 9-15 of 19-26 per route, docs/roi_detector.md);
    newer navigation cameras are wider (ExoMars Rosalind Franklin NavCam 65 deg,
    Perseverance Navcam 96 x 73 deg), and at 70 deg it sees 18-24 of them. We keep the
    640x480 sensor (fx = 320 / tan 35 deg = 457 px): the same rendering and stereo cost,
    depth error 1.7x MER's at equal range.
    """

    width: int = 640
    height: int = 480
    hfov_deg: float = 70.0
    baseline_m: float = 0.20
    mast_height_m: float = 1.54  # left camera centre above base_link (ground plane)
    mast_x_m: float = 0.40  # forward of the rover centre
    tilt_deg: float = 20.0  # optical axis below the horizon
    jpeg_quality: int = 93
    full_well_e: float = 12000.0  # shot noise
    read_noise_e: float = 12.0
    exposure_target: float = 0.42  # mean image level after auto-exposure
    exposure_smoothing: float = 0.3  # per-frame EMA weight of the new exposure
    gamma: float = 1 / 2.2
    near_m: float = 0.2
    far_m: float = 2000.0
    haze_m: float = 3000.0  # aerial-perspective e-folding distance


@dataclass
class ImuConfig:
    """MEMS-class IMU (numbers of an ADIS16448-like unit), at base_link."""

    rate_hz: float = 50.0
    gyro_noise_density: float = 1.7e-4  # rad/s/sqrt(Hz)
    gyro_bias_rw: float = 2.0e-5  # rad/s^2/sqrt(Hz)
    gyro_bias_init: float = 2.0e-3  # rad/s, 1-sigma turn-on bias
    accel_noise_density: float = 2.0e-3  # m/s^2/sqrt(Hz)
    accel_bias_rw: float = 3.0e-4  # m/s^3/sqrt(Hz)
    accel_bias_init: float = 0.02  # m/s^2
    gravity: float = 9.81  # Earth; 3.721 for Mars


@dataclass
class RouteConfig:
    """Traverse statistics (paper Sec. 7.2) and rover motion."""

    length_m: float = 1000.0  # path length target
    net_fraction: float = 0.6  # net displacement / path length target
    rois_target: tuple[int, int] = (20, 30)  # major ROIs passed within roi_range_m
    roi_range_m: float = 15.0
    edge_margin_m: float = 120.0  # route stays this far inside the world square
    speed_mps: float = 0.15
    accel_mps2: float = 0.05
    stop_every_m: tuple[float, float] = (40.0, 90.0)
    stop_s: tuple[float, float] = (20.0, 90.0)
    frame_spacing_m: float = 0.45  # a stereo pair every this much travel
    stop_frame_period_s: float = 10.0  # and every this long while stopped
    min_turn_radius_m: float = 6.0
    wheelbase_m: float = 1.2  # for pitch/roll from the terrain under the wheels
    track_m: float = 1.0
    body_smoothing_s: float = 0.4  # suspension low-pass of pitch, roll and height
    candidates: int = 800  # random route candidates scored by the planner
    gt_rate_hz: float = 10.0


@dataclass
class OrbitalConfig:
    """HiRISE-like orthoimage rendered from the same world."""

    gsd_m: float = 0.25
    supersample: int = 2  # rendered at gsd/supersample, then area-averaged
    mtf_sigma_px: float = 0.6  # Gaussian PSF after downsampling
    noise_dn: float = 1.5  # 8-bit read noise
    shot_noise: float = 0.006  # relative, at full scale
    tile_m: float = 256.0
    sun: SunConfig = field(default_factory=lambda: SunConfig(elevation_deg=42.0,
                                                             azimuth_deg=35.0))


@dataclass
class WorldConfig:
    """Everything that makes a bag: world, sensors, traverse, seed."""

    preset: str = "atacama_1km"
    seed: int = 1
    site: SiteConfig = field(default_factory=SiteConfig)
    terrain: TerrainConfig = field(default_factory=TerrainConfig)
    albedo: AlbedoConfig = field(default_factory=AlbedoConfig)
    rocks: RockConfig = field(default_factory=RockConfig)
    sun: SunConfig = field(default_factory=SunConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    imu: ImuConfig = field(default_factory=ImuConfig)
    route: RouteConfig = field(default_factory=RouteConfig)
    orbital: OrbitalConfig = field(default_factory=OrbitalConfig)
    start_time_ns: int = 1_700_000_000_000_000_000  # bag epoch (fixed: deterministic)

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict (tuples as lists) for world.yaml."""
        def plain(v: Any) -> Any:
            if isinstance(v, dict):
                return {k: plain(x) for k, x in v.items()}
            if isinstance(v, list | tuple):
                return [plain(x) for x in v]
            return v
        return plain(dataclasses.asdict(self))


PRESETS: dict[str, dict[str, Any]] = {
    # The paper's scenario: 1.5 x 1.5 km, ~1 km route, ~600 m net, 20-30 ROIs passed.
    "atacama_1km": {},
    # The demo: a shorter cut of the paper's scenario that still passes about as many
    # ROIs (400 m, 18-28 ROIs within 15 m) on a denser site; at the paper's density a
    # 300 m route passes 4-12, too few for any LN to be placed.
    "quick": {
        "site": {"extent_m": 700.0},
        "route": {"length_m": 400.0, "rois_target": (18, 28), "edge_margin_m": 100.0},
        "rocks": {"major_per_km2": 200.0, "clusters_per_km2": 15.0},
    },
    # Seconds: unit tests. A small square, a 12 m route through a rock cluster.
    "tiny": {
        "site": {"extent_m": 128.0},
        "terrain": {"large_rms_m": 1.0, "large_wavelengths_m": (40.0, 128.0)},
        "route": {"length_m": 12.0, "rois_target": (3, 8), "edge_margin_m": 40.0,
                  "roi_range_m": 10.0, "stop_every_m": (1000.0, 1000.0),
                  "candidates": 300},
        "rocks": {"major_per_km2": 2500.0, "clusters_per_km2": 250.0,
                  "cluster_sigma_m": 8.0},
        "orbital": {"tile_m": 128.0},
    },
}


def _override(obj: Any, values: dict[str, Any]) -> None:
    for key, value in values.items():
        if not hasattr(obj, key):
            raise KeyError(f"unknown config field '{key}' in {type(obj).__name__}")
        current = getattr(obj, key)
        if dataclasses.is_dataclass(current):
            if not isinstance(value, dict):
                raise TypeError(f"{type(obj).__name__}.{key} is a section: give its fields")
            _override(current, value)
            continue
        number = (int, float)
        if isinstance(current, number) and not isinstance(current, bool) and \
                (not isinstance(value, number) or isinstance(value, bool)
                 or (isinstance(current, int) and not float(value).is_integer())):
            raise TypeError(f"{type(obj).__name__}.{key}: expected "
                            f"{type(current).__name__}, got {value!r}")
        if isinstance(current, tuple) and not isinstance(value, list | tuple):
            raise TypeError(f"{type(obj).__name__}.{key}: expected a list, got {value!r}")
        if isinstance(current, tuple | int | float) and not isinstance(current, bool):
            value = type(current)(value)
        setattr(obj, key, value)


def make_config(preset: str = "atacama_1km", seed: int = 1,
                overrides: dict[str, Any] | None = None) -> WorldConfig:
    """The configuration of ``preset`` with ``seed`` and optional nested ``overrides``."""
    if preset not in PRESETS:
        raise KeyError(f"unknown preset '{preset}' (known: {', '.join(PRESETS)})")
    cfg = WorldConfig(preset=preset, seed=int(seed))
    _override(cfg, PRESETS[preset])
    if overrides:
        _override(cfg, overrides)
    return cfg


def rng_for(seed: int, stream: str) -> np.random.Generator:
    """An independent generator per (seed, named stream): adding a stream or drawing more
    numbers in one part never changes another part's world."""
    key = [ord(c) for c in stream]
    return np.random.default_rng(np.random.SeedSequence([int(seed), *key]))
