"""Typed configuration of the synthetic world, its sensors and the traverse.

The parameters a preset, a CLI option or a user varies have their defaults here and
nowhere else; ``world.yaml`` is this object written out (``asdict``), so with the code
version a bag records exactly what made it. Presets only override fields of these
defaults. The parameters nobody varies are named constants beside the code that uses
them (:data:`CONSTANT_FIELDS` lists them).
"""

from __future__ import annotations

import dataclasses
import datetime
import importlib
from dataclasses import dataclass, field
from typing import Any

import numpy as np


@dataclass
class SiteConfig:
    """Where the world sits on the planet.

    The map frame is the projected CRS shifted by the projection of ``site_lonlat``
    rounded to the metre (DESIGN.md, Frames). The world square spans map coordinates
    [-extent_m/2, extent_m/2] in x and y.

    Attributes:
        crs: projected CRS of the map frame ("EPSG:32719", WGS 84 / UTM zone 19S;
            "IAU_2015:49910" for Mars).
        site_lonlat: longitude and latitude of the map-frame origin, degrees (Atacama,
            near Yungay).
        extent_m: side of the square world and of the orbital image footprint, m.
    """

    crs: str = "EPSG:32719"
    site_lonlat: tuple[float, float] = (-69.95, -24.10)
    extent_m: float = 1500.0


@dataclass
class TerrainConfig:
    """Large relief of the height field (the finer bands are :mod:`atacama_sim.terrain`'s
    constants).

    Attributes:
        large_rms_m: rms height of the relief band, m.
        large_wavelengths_m: shortest and longest wavelength of the relief band, m.
    """

    large_rms_m: float = 5.0
    large_wavelengths_m: tuple[float, float] = (150.0, 1500.0)


@dataclass
class RockConfig:
    """Major ROIs (rocks, outcrops) and sub-threshold clutter.

    Major ROIs are a Thomas cluster process: cluster centres uniform, members Gaussian
    around them, plus a uniform background share. Sizes follow a power law truncated to
    the ROI ranges of :mod:`atacama_sim.rocks`.

    Attributes:
        major_per_km2: rocks and outcrops per km^2.
        outcrop_fraction: share of the major ROIs that are outcrops.
        clusters_per_km2: cluster centres per km^2.
        cluster_sigma_m: Gaussian spread of a cluster's members around its centre, m.
        clutter_per_m2: sub-threshold rocks per m^2, placed uniformly.
    """

    major_per_km2: float = 85.0
    outcrop_fraction: float = 0.22
    clusters_per_km2: float = 7.0
    cluster_sigma_m: float = 22.0
    clutter_per_m2: float = 0.12


@dataclass
class SunConfig:
    """A fixed sun direction: the orbital image's at acquisition (light levels are
    :mod:`atacama_sim.renderer`'s constants).

    Attributes:
        elevation_deg: sun elevation above the horizon, degrees.
        azimuth_deg: sun azimuth clockwise from grid north, degrees (NNE: a
            southern-hemisphere morning).
    """

    elevation_deg: float = 42.0
    azimuth_deg: float = 35.0


@dataclass
class SolarTimeConfig:
    """When the traverse starts; the sun's direction over it follows from the site, on the
    body the map CRS lies on (:mod:`atacama_sim.sky`, through ``roi_network.sun``).

    The default puts the Atacama site's sun at 35 deg grid azimuth and 42 deg elevation
    half way through the ``quick`` bag (about 31 min in), the orbital image's sun and the
    lighting the rover detector is tuned on: 42.8 / 37.4 deg at the start, 26.2 / 45.5 deg
    at its end.

    Attributes:
        date: local date of the start, YYYY-MM-DD (Earth: the site's calendar date; Mars:
            the sol under way there at 12:00 UTC of that date).
        local_solar_time_h: local true solar time at the map-frame origin when the bag
            starts, h (12: the sun on the meridian).
    """

    date: str = "2023-05-05"
    local_solar_time_h: float = 9.70


@dataclass
class SunSensorConfig:
    """Digital two-axis fine sun sensor on the deck, looking up (:mod:`atacama_sim.sunsensor`).

    Source: Solar MEMS SSOC-D60 datasheet (SSOCD60-14-MAN-119 rev 1.19): two orthogonal
    axes, field of view +-60 deg, accuracy 0.3 deg, precision 0.05 deg. The accuracy is
    taken as the 3-sigma bound of a constant bias per axis, the precision as the 1-sigma
    white noise per axis; the rate is the NewSpace NFSS-411's (same class) 5 Hz.

    Attributes:
        rate_hz: sample rate, Hz (divides the IMU's rate).
        noise_deg: 1-sigma white noise of each measured angle, degrees.
        bias_deg: 1-sigma of each angle's constant bias (drawn once per bag), degrees.
        fov_half_angle_deg: half-angle of the field of view's cone about the boresight
            (base_link z), degrees.
        position_m: the sensor in base_link (x forward, y left, z up), m.
    """

    rate_hz: float = 5.0
    noise_deg: float = 0.05
    bias_deg: float = 0.1
    fov_half_angle_deg: float = 60.0
    position_m: tuple[float, float, float] = (-0.40, 0.30, 0.75)


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
    depth error 1.7x MER's at equal range. Image formation (exposure, noise, gamma, JPEG)
    is :mod:`atacama_sim.sensor`'s constants.

    Attributes:
        width: image width, pixels.
        height: image height, pixels.
        hfov_deg: horizontal field of view, degrees.
        baseline_m: stereo baseline, m.
        mast_height_m: left camera centre above base_link (the ground plane), m.
        mast_x_m: camera centre forward of the rover centre, m.
        tilt_deg: optical axis below the horizon, degrees.
    """

    width: int = 640
    height: int = 480
    hfov_deg: float = 70.0
    baseline_m: float = 0.20
    mast_height_m: float = 1.54
    mast_x_m: float = 0.40
    tilt_deg: float = 20.0


@dataclass
class MastConfig:
    """The pan-tilt mast's motion and the stereo panoramas at drive stops (its geometry is
    :func:`atacama_sim.camera.mast_kinematics` of :class:`CameraConfig`).

    At every stop between drive segments the rover, once still, slews the mast through pan
    angles spread evenly over ``span_deg`` (as few as keep ``overlap_deg`` between
    neighbouring views) at ``tilt_deg``, takes a stereo pair at each after it settles, and
    returns the mast to the drive pose (pan 0, ``CameraConfig.tilt_deg``); the stop lasts
    at least as long. The slew rate is a conservative share of a pan-tilt unit's (FLIR
    PTU-D46-70: 60 deg/s at most).

    Attributes:
        panoramas: take a stereo panorama at every stop between drive segments (False:
            the mast stays at the drive pose; ``atacama_sim generate --no-panoramas``).
        span_deg: pan span of a panorama, degrees (360: all around).
        overlap_deg: least horizontal overlap of neighbouring views, degrees; sets the
            positions (stereo pairs) per panorama, ceil(span / (hfov - overlap)).
        tilt_deg: tilt of the panorama row below the horizon, degrees.
        slew_deg_s: slew rate of each joint, deg/s.
        settle_s: wait after a move before the pair is taken, s.
    """

    panoramas: bool = True
    span_deg: float = 360.0
    overlap_deg: float = 10.0
    tilt_deg: float = 20.0
    slew_deg_s: float = 30.0
    settle_s: float = 1.0


@dataclass
class ImuConfig:
    """MEMS-class IMU (numbers of an ADIS16448-like unit), at base_link.

    Attributes:
        rate_hz: sample rate, Hz (also the time grid of the simulated motion).
        gyro_noise_density: gyro white-noise density, rad/s/sqrt(Hz).
        gyro_bias_rw: gyro bias random walk, rad/s^2/sqrt(Hz).
        gyro_bias_init: 1-sigma gyro turn-on bias, rad/s.
        accel_noise_density: accelerometer white-noise density, m/s^2/sqrt(Hz).
        accel_bias_rw: accelerometer bias random walk, m/s^3/sqrt(Hz).
        accel_bias_init: 1-sigma accelerometer turn-on bias, m/s^2.
        gravity: gravity, m/s^2 (Earth; 3.721 for Mars).
    """

    rate_hz: float = 50.0
    gyro_noise_density: float = 1.7e-4
    gyro_bias_rw: float = 2.0e-5
    gyro_bias_init: float = 2.0e-3
    accel_noise_density: float = 2.0e-3
    accel_bias_rw: float = 3.0e-4
    accel_bias_init: float = 0.02
    gravity: float = 9.81


@dataclass
class RouteConfig:
    """Traverse statistics (paper Sec. 7.2) and the rover's stops and frames (its body
    geometry is :mod:`atacama_sim.route`'s constants).

    Attributes:
        length_m: target path length, m.
        net_fraction: target net displacement over path length.
        rois_target: wanted range of major ROIs passed within ``roi_range_m``.
        roi_range_m: distance from the route within which a major ROI counts as passed, m.
        edge_margin_m: the route stays this far inside the world square, m.
        speed_mps: cruise speed, m/s.
        stop_every_m: range of the distance driven between stops (each holds a
            panorama, :class:`MastConfig`), m.
        stop_s: range of a stop's duration, s.
        frame_spacing_m: a stereo pair every this much travel, m.
        stop_frame_period_s: and every this long while stopped, s.
        candidates: random route candidates scored by the planner.
    """

    length_m: float = 1000.0
    net_fraction: float = 0.6
    rois_target: tuple[int, int] = (20, 30)
    roi_range_m: float = 15.0
    edge_margin_m: float = 120.0
    speed_mps: float = 0.15
    stop_every_m: tuple[float, float] = (12.0, 28.0)
    stop_s: tuple[float, float] = (20.0, 90.0)
    frame_spacing_m: float = 0.45
    stop_frame_period_s: float = 10.0
    candidates: int = 800


@dataclass
class OrbitalConfig:
    """HiRISE-like orthoimage rendered from the same world (its optics and noise are
    :mod:`atacama_sim.orbital`'s constants).

    Attributes:
        gsd_m: ground sample distance, m.
        tile_m: side of a rendered tile, m.
        sun: sun direction at acquisition.
    """

    gsd_m: float = 0.25
    tile_m: float = 256.0
    sun: SunConfig = field(default_factory=lambda: SunConfig(elevation_deg=42.0,
                                                             azimuth_deg=35.0))


@dataclass
class WorldConfig:
    """Everything that makes a bag: world, sensors, traverse, seed.

    Attributes:
        preset: name of the preset the fields start from (:data:`PRESETS`).
        seed: seed of every random stream (:func:`rng_for`).
        site: georeference and size of the world.
        terrain: large relief.
        rocks: major ROIs and clutter.
        sun: when the traverse starts (the sun follows from it and the site).
        sun_sensor: the rover's sun sensor.
        camera: stereo rig.
        mast: pan-tilt motion and panoramas.
        imu: IMU noise model.
        route: traverse.
        orbital: orthoimage.
    """

    preset: str = "atacama_1km"
    seed: int = 1
    site: SiteConfig = field(default_factory=SiteConfig)
    terrain: TerrainConfig = field(default_factory=TerrainConfig)
    rocks: RockConfig = field(default_factory=RockConfig)
    sun: SolarTimeConfig = field(default_factory=SolarTimeConfig)
    sun_sensor: SunSensorConfig = field(default_factory=SunSensorConfig)
    camera: CameraConfig = field(default_factory=CameraConfig)
    mast: MastConfig = field(default_factory=MastConfig)
    imu: ImuConfig = field(default_factory=ImuConfig)
    route: RouteConfig = field(default_factory=RouteConfig)
    orbital: OrbitalConfig = field(default_factory=OrbitalConfig)

    def to_dict(self) -> dict[str, Any]:
        """Plain nested dict (tuples as lists) for world.yaml."""
        return _plain(dataclasses.asdict(self))


def _plain(v: Any) -> Any:
    if isinstance(v, dict):
        return {k: _plain(x) for k, x in v.items()}
    if isinstance(v, list | tuple):
        return [_plain(x) for x in v]
    return v


#: world.yaml keys that are code constants, per section class: key -> "module.NAME" in
#: ``atacama_sim`` (a nested dict for a section that is all constants; a number for a key
#: no code reads). A world.yaml that carries such a key loads when its value equals it.
CONSTANT_FIELDS: dict[str, dict[str, Any]] = {
    "WorldConfig": {
        "albedo": {
            "res_m": "terrain.TERRAIN_RES_M",
            "soil_rgb": "texture.SOIL_RGB",
            "gravel_rgb": "texture.GRAVEL_RGB",
            "pavement_rgb": "texture.PAVEMENT_RGB",
            "gravel_cover": "texture.GRAVEL_COVER",
            "pavement_cover": "texture.PAVEMENT_COVER",
            "patch_wavelength_m": "texture.PATCH_WAVELENGTH_M",
            "detail_res_m": "texture.DETAIL_RES_M",
            "detail_tile_px": "texture.DETAIL_TILE_PX",
            "pebbles_per_m2": "texture.PEBBLES_PER_M2",
        },
    },
    "TerrainConfig": {
        "res_m": "terrain.TERRAIN_RES_M",
        "medium_rms_m": "terrain.MEDIUM_RMS_M",
        "medium_wavelengths_m": "terrain.MEDIUM_WAVELENGTHS_M",
        "rough_rms_m": "terrain.ROUGH_RMS_M",
        "rough_res_m": "terrain.ROUGH_RES_M",
        "rough_tile_px": "terrain.ROUGH_TILE_PX",
    },
    "RockConfig": {
        "background_fraction": "rocks.BACKGROUND_FRACTION",
        "rock_area_m2": "rocks.ROCK_AREA_M2",
        "rock_height_m": "rocks.ROCK_HEIGHT_M",
        "outcrop_area_m2": "rocks.OUTCROP_AREA_M2",
        "outcrop_height_m": "rocks.OUTCROP_HEIGHT_M",
        "size_power": "rocks.SIZE_POWER",
        "min_separation_m": "rocks.MIN_SEPARATION_M",
        "clutter_apron_per_rock": "rocks.CLUTTER_APRON_PER_ROCK",
        "clutter_diameter_m": "rocks.CLUTTER_DIAMETER_M",
        "n_templates": "rocks.N_TEMPLATES",
    },
    "SunConfig": {
        "irradiance": "renderer.SUN_IRRADIANCE",
        "sky_ambient": "renderer.SKY_AMBIENT",
    },
    "CameraConfig": {
        "jpeg_quality": "sensor.JPEG_QUALITY",
        "full_well_e": "sensor.FULL_WELL_E",
        "read_noise_e": "sensor.READ_NOISE_E",
        "exposure_target": "sensor.EXPOSURE_TARGET",
        "exposure_smoothing": "sensor.EXPOSURE_SMOOTHING",
        "gamma": "sensor.GAMMA",
        "near_m": "renderer.CAMERA_NEAR_M",
        "far_m": "renderer.CAMERA_FAR_M",
        "haze_m": "renderer.HAZE_M",
    },
    "RouteConfig": {
        "accel_mps2": "route.ACCEL_MPS2",
        "wheelbase_m": "route.WHEELBASE_M",
        "track_m": "route.TRACK_M",
        "body_smoothing_s": "route.BODY_SMOOTHING_S",
        "gt_rate_hz": "generate.GT_RATE_HZ",
        "min_turn_radius_m": 6.0,  # read by no code: a value, not a constant
    },
    "OrbitalConfig": {
        "supersample": "orbital.SUPERSAMPLE",
        "mtf_sigma_px": "orbital.MTF_SIGMA_PX",
        "noise_dn": "orbital.NOISE_DN",
        "shot_noise": "orbital.SHOT_NOISE",
    },
}


def constant_value(ref: Any) -> Any:
    """The value of a :data:`CONSTANT_FIELDS` entry, as world.yaml writes it (tuples as
    lists; a section as a dict)."""
    if isinstance(ref, dict):
        return {k: constant_value(r) for k, r in ref.items()}
    if not isinstance(ref, str):
        return ref
    module, name = ref.rsplit(".", 1)
    return _plain(getattr(importlib.import_module(f"atacama_sim.{module}"), name))


def _check_constant(obj: Any, key: str, value: Any) -> None:
    ref = CONSTANT_FIELDS.get(type(obj).__name__, {}).get(key)
    if ref is None:
        raise KeyError(f"unknown config field '{key}' in {type(obj).__name__}")
    expected = constant_value(ref)
    if isinstance(expected, dict):
        if not isinstance(value, dict):
            raise TypeError(f"{type(obj).__name__}.{key} is a section: give its fields")
        for k, v in value.items():
            if k not in expected:
                raise KeyError(f"unknown config field '{k}' in {type(obj).__name__}.{key}")
            if _plain(v) != expected[k]:
                raise ValueError(f"{type(obj).__name__}.{key}.{k} is a constant of the "
                                 f"simulator ({expected[k]!r}), not {v!r}")
        return
    if _plain(value) != expected:
        raise ValueError(f"{type(obj).__name__}.{key} is a constant of the simulator "
                         f"({expected!r}), not {value!r}")


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
    # Seconds: unit tests. A small square, a 12 m route through a rock cluster, no stop
    # on the way and so no panorama (the other packages' tests drive it as a fixed camera).
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
        if key not in {f.name for f in dataclasses.fields(obj)}:
            _check_constant(obj, key, value)
            continue
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
        if isinstance(current, bool) and not isinstance(value, bool):
            raise TypeError(f"{type(obj).__name__}.{key}: expected true or false, got "
                            f"{value!r}")
        if isinstance(current, str) and isinstance(value, datetime.date):
            value = value.isoformat()  # YAML reads 2023-05-05 as a date
        if isinstance(current, tuple) and not isinstance(value, list | tuple):
            raise TypeError(f"{type(obj).__name__}.{key}: expected a list, got {value!r}")
        if isinstance(current, tuple | int | float) and not isinstance(current, bool):
            value = type(current)(value)
        setattr(obj, key, value)


#: Map-frame origin (longitude, latitude, degrees) of a Mars CRS given without one:
#: Oxia Planum.
MARS_SITE_LONLAT = (-24.55, 18.2)
#: Gravity on Mars, m/s^2.
MARS_GRAVITY = 3.721


def add_site(overrides: dict[str, Any], crs: str | None,
             site_lonlat: tuple[float, float] | None) -> dict[str, Any]:
    """Add a CRS and a site to nested ``overrides`` (in place, and returned). A Mars CRS
    (``IAU_2015:499xx``) without a site is placed at :data:`MARS_SITE_LONLAT`, with Mars'
    gravity unless the overrides set one."""
    if crs:
        overrides.setdefault("site", {})["crs"] = crs
    if site_lonlat:
        overrides.setdefault("site", {})["site_lonlat"] = tuple(site_lonlat)
    if crs and crs.upper().startswith("IAU_2015:499") and not site_lonlat:
        overrides["site"]["site_lonlat"] = MARS_SITE_LONLAT
        overrides.setdefault("imu", {}).setdefault("gravity", MARS_GRAVITY)
    return overrides


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
