"""Absolute heading from a sun sensor and gravity (no rclpy).

A sun sensor on the body measures the unit sun vector in its frame; with the body's roll
and pitch (the filter's attitude, held to the accelerometer's gravity) that vector gives
the sun's azimuth in the level body frame, and the ephemeris (:mod:`roi_network.sun`)
gives the same sun's azimuth in the map's grid at the sample's stamp: the difference is
the body's heading from grid north, whatever the odometry did before.

The odom frame is not turned (DESIGN.md: it starts at the rover's first pose and
``odom -> base_link`` never jumps). The filter carries one more error state, ``psi0``:
the grid azimuth of the odom frame's x axis (the yaw of ``map_R_odom``). It is set by the
first usable sample (``psi0 = sun's grid azimuth - sun's azimuth in odom``, its variance
the sample's plus the odometry's yaw variance then, its errors correlated with the
odometry's yaw), and every later sample is a measurement of ``yaw + psi0`` (H has a 1 at
the yaw error and at ``psi0``). The update is a Schmidt-Kalman one: only the yaw and
``psi0`` are corrected (position, roll and pitch, scale and heading-rate bias keep their
values, so the pose moves by a small turn about the rover and nothing else), and the
Joseph form keeps the covariance right for that gain. The odometry's yaw variance then
stays bounded: about the sample's variance plus ``psi0``'s.

Per sample (:meth:`SunHeading.measure`):

1. the vector into base_link by the mount (rover.yaml ``sun_sensor.base_to_sensor``),
   then to the body at the pair's stamp by the gyro between the two stamps, then into
   odom by the filter's attitude: its elevation and its azimuth in odom;
2. the ephemeris at the stamp (POSIX UTC, rover.yaml ``site.*``): the sun below the
   horizon, or a measured elevation more than ``ELEVATION_GATE_SIGMA`` sigma from the
   ephemeris', is a vector that is not the sun (counted, skipped);
3. the azimuth's variance: the sensor's noise and bias (rover.yaml ``noise_deg``,
   ``bias_deg``, per angle) over ``cos(elevation)^2`` (the azimuth is ill-defined near
   the zenith), plus the tilt's uncertainty times ``tan(elevation)^2`` (a roll or pitch
   error about the sun's horizontal direction turns the vector's horizontal part);
   samples whose azimuth sigma exceeds ``MAX_AZIMUTH_SIGMA_DEG`` are not used;
4. the innovation against ``yaw + psi0``, a chi-square gate (1 degree of freedom,
   ``GATE_CHI2``): a sample that contradicts the heading beyond its uncertainty is
   rejected and counted.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np

from roi_network import sun as ephemeris
from roi_network.mast import MastError, pose_matrix

#: The sun sensor's rover.yaml parameters (``sun_sensor: {...}`` flattened); the first
#: four are required once any is set.
SENSOR_PARAMS = ("sun_sensor.frame", "sun_sensor.base_to_sensor", "sun_sensor.noise_deg",
                 "sun_sensor.bias_deg", "sun_sensor.rate_hz", "sun_sensor.fov_half_angle_deg")
REQUIRED_SENSOR_PARAMS = SENSOR_PARAMS[:4]
#: The site and epoch the ephemeris needs (rover.yaml ``site: {...}``).
SITE_PARAMS = ("site.body", "site.crs", "site.latitude_deg", "site.longitude_deg",
               "site.epoch_ns")

#: Chi-square gate of the heading innovation, 1 degree of freedom (99.9 %).
GATE_CHI2 = 10.83
#: A measured elevation this many sigma from the ephemeris' is not the sun.
ELEVATION_GATE_SIGMA = 5.0
#: ... and never closer than this (deg): the refraction model, the site's extent.
ELEVATION_GATE_FLOOR_DEG = 1.0
#: Samples whose azimuth is less certain than this (1 sigma, deg) are not used: the sun
#: near the zenith.
MAX_AZIMUTH_SIGMA_DEG = 3.0
#: A sample older than this behind the pair it would update is not used (s).
MAX_SAMPLE_AGE_S = 1.0
#: A vector whose norm is further than this from 1 is not a unit vector.
UNIT_TOLERANCE = 1e-3
#: Index of ``psi0`` in the augmented error state (after the odometry's 8).
PSI0 = 8
#: 1-sigma roll and pitch of the level frame at rest, from the mean specific force over
#: 0.5 s (the accelerometer's noise averages to ~0.002 deg; its bias, not estimated, is
#: taken at 0.05 deg), rad.
AT_REST_TILT_SIGMA_RAD = math.radians(0.05)
#: In motion the filter's roll and pitch err by tenths of a degree, slowly: a sample is
#: folded in at most once per this many metres driven (the tilt error changes with the
#: ground), at rest every pair.
MOTION_SPACING_M = 10.0
#: The heading counts as bounded (``sun.heading_bounded`` in /vo/status) while the last
#: update is at most this old (s).
BOUNDED_FOR_S = 30.0


class SunSetupError(ValueError):
    """rover.yaml's sun sensor is malformed; the message names the field."""


@dataclass(frozen=True)
class SunSensorModel:
    """The sun sensor as rover.yaml states it.

    Attributes:
        frame: the frame of its ``/sun_sensor`` messages.
        base_R_sensor: 3x3 rotation sensor -> base_link.
        sigma_rad: 1-sigma error of each measured angle, noise and bias together (rad).
        rate_hz: its sample rate (0: not stated).
        fov_half_angle_deg: its field of view's half-angle (nan: not stated).
    """

    frame: str
    base_R_sensor: np.ndarray
    sigma_rad: float
    rate_hz: float
    fov_half_angle_deg: float

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> SunSensorModel | None:
        """The sensor of flat rover.yaml ``params``; None when none of ``sun_sensor.*`` is set.

        Raises:
            SunSetupError: some but not all of the required fields, or a bad value.
        """
        if not any(k in params for k in SENSOR_PARAMS):
            return None
        missing = [k for k in REQUIRED_SENSOR_PARAMS if k not in params]
        if missing:
            raise SunSetupError(f"rover.yaml: the sun sensor lacks {', '.join(missing)}")
        frame = str(params["sun_sensor.frame"]).strip()
        if not frame:
            raise SunSetupError("rover.yaml: field 'sun_sensor.frame' is empty")
        try:
            mount = pose_matrix(params["sun_sensor.base_to_sensor"], "sun_sensor.base_to_sensor")
        except MastError as exc:
            raise SunSetupError(f"rover.yaml: {exc}") from None
        values = {}
        for name in ("noise_deg", "bias_deg", "rate_hz", "fov_half_angle_deg"):
            key = f"sun_sensor.{name}"
            raw = params.get(key, 0.0 if name == "rate_hz" else math.nan)
            try:
                values[name] = float(raw)
            except (TypeError, ValueError):
                raise SunSetupError(f"rover.yaml: field '{key}' is not a number: {raw!r}") \
                    from None
        for name in ("noise_deg", "bias_deg"):
            if not (math.isfinite(values[name]) and values[name] >= 0.0):
                raise SunSetupError(f"rover.yaml: field 'sun_sensor.{name}' must be a number "
                                    f">= 0, got {values[name]}")
        sigma = math.radians(math.hypot(values["noise_deg"], values["bias_deg"]))
        return cls(frame, mount[:3, :3], sigma, values["rate_hz"],
                   values["fov_half_angle_deg"])


@dataclass(frozen=True)
class Site:
    """Where and when (rover.yaml ``site.*``): the ephemeris' inputs and the map's grid.

    Attributes:
        body: ``"earth"`` or ``"mars"``.
        lat_deg, lon_deg: the map-frame origin (east longitude).
        epoch_s: the bag's first stamp, POSIX UTC seconds (header stamps are UTC).
        grid: grid north of the map CRS at the site.
    """

    body: str
    lat_deg: float
    lon_deg: float
    epoch_s: float
    grid: ephemeris.GridNorth

    @classmethod
    def from_params(cls, params: Mapping[str, Any]) -> tuple[Site | None, str | None]:
        """The site of flat rover.yaml ``params``, or None and why it cannot be used (the
        missing fields named, or the ephemeris' complaint)."""
        missing = [k for k in SITE_PARAMS if k not in params or params[k] in ("", None)]
        if missing:
            return None, (f"rover.yaml has no {', '.join(missing)} (the site and epoch the "
                          "sun's direction needs)")
        try:
            body = str(params["site.body"]).strip().lower()
            if body not in ephemeris.BODIES:
                raise ephemeris.SunError(f"site.body: '{params['site.body']}' is not one of "
                                         f"{', '.join(ephemeris.BODIES)}")
            lat = float(params["site.latitude_deg"])
            lon = float(params["site.longitude_deg"])
            epoch = int(params["site.epoch_ns"]) * 1e-9
            grid = ephemeris.grid_north(str(params["site.crs"]), lon, lat)
            ephemeris.sun_position(body, lat, lon, epoch)
        except (ephemeris.SunError, TypeError, ValueError) as exc:
            return None, f"rover.yaml's site is unusable: {exc}"
        return cls(body, lat, lon, epoch, grid), None

    def sun_grid(self, utc_s: float) -> tuple[float, float]:
        """The sun's azimuth in the map's grid (rad, counter-clockwise from grid east, as a
        yaw) and its apparent elevation (rad) at POSIX UTC ``utc_s``."""
        pos = ephemeris.sun_position(self.body, self.lat_deg, self.lon_deg, utc_s)
        v = self.grid.enu_to_grid(pos.enu(refracted=True))
        return math.atan2(v[1], v[0]), math.radians(pos.apparent_elevation_deg)


def wrap(a: float) -> float:
    """An angle in (-pi, pi]."""
    return math.atan2(math.sin(a), math.cos(a))


def rotz(a: float) -> np.ndarray:
    c, s = math.cos(a), math.sin(a)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def vector_problem(v: np.ndarray) -> str | None:
    """Why a sun vector cannot be used (``nan``/``not_unit`` and the value), or None."""
    if not np.all(np.isfinite(v)):
        return "sun_nan"
    if abs(float(np.linalg.norm(v)) - 1.0) > UNIT_TOLERANCE:
        return "sun_not_unit"
    return None


@dataclass
class Measurement:
    """One sample made a heading measurement (or the reason it is not one).

    Attributes:
        alpha_odom: the sun's azimuth in odom from the estimate's attitude (rad, a yaw).
        alpha_map: the ephemeris' azimuth in the grid (rad, a yaw).
        elevation: the ephemeris' apparent elevation (rad).
        elevation_measured: the vector's elevation over the level plane (rad).
        variance: the azimuth's variance (rad^2).
        problem: None, or ``below_horizon``, ``elevation_mismatch``, ``near_zenith``.
        detail: what the problem was, in words.
    """

    alpha_odom: float
    alpha_map: float
    elevation: float
    elevation_measured: float
    variance: float
    problem: str | None = None
    detail: str = ""


def augment(P: np.ndarray, var_psi0: float) -> np.ndarray:
    """The 9x9 covariance with ``psi0`` set by a first sample: ``e0 = -e_yaw + n``."""
    n = P.shape[0]
    A = np.zeros((n + 1, n + 1))
    A[:n, :n] = P
    A[:n, n] = A[n, :n] = -P[:, 5]
    A[n, n] = P[5, 5] + var_psi0
    return A


def schmidt_update(P: np.ndarray, y: float, r: float, gain_from: np.ndarray | None = None
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Update of ``yaw + psi0`` by innovation ``y`` (variance ``r``), only the yaw (5)
    and ``psi0`` (8) corrected; returns the correction (9,) and the new covariance (Joseph
    form, right for this gain). ``gain_from``: the covariance the gain is computed from
    (default ``P``)."""
    H = np.zeros(P.shape[0])
    H[5] = H[PSI0] = 1.0
    G = P if gain_from is None else gain_from
    S = float(H @ G @ H) + r
    K = np.zeros(P.shape[0])
    K[[5, PSI0]] = (G @ H)[[5, PSI0]] / S
    A = np.eye(P.shape[0]) - np.outer(K, H)
    P2 = A @ P @ A.T + r * np.outer(K, K)
    return K * y, 0.5 * (P2 + P2.T)


class SunHeading:
    """The sun heading filter's side of the estimator: the setup, ``psi0`` and counts.

    Args:
        sensor: the sensor (rover.yaml), or None.
        site: the site (rover.yaml), or None.
    """

    def __init__(self, sensor: SunSensorModel | None, site: Site | None) -> None:
        self.sensor = sensor
        self.site = site
        self.psi0: float | None = None
        self.samples = 0
        self.updates = 0
        self.rejected = 0
        self.last_update_t: float | None = None
        self.last_elevation_deg = math.nan
        self.last_innovation_deg = math.nan
        self.near_zenith = 0
        self.outages = 0  # spans without a sample, the sun out of sight or set
        self.in_outage = False

    @property
    def usable(self) -> bool:
        return self.sensor is not None and self.site is not None

    def measure(self, utc_s: float, v_sensor: np.ndarray, base_R_then_now: np.ndarray,
                odom_R_base: np.ndarray, tilt_sigma_rad: float) -> Measurement:
        """The heading measurement of one sample (module steps 1-3).

        Args:
            utc_s: the sample's stamp (POSIX UTC s).
            v_sensor: the unit sun vector in the sensor frame.
            base_R_then_now: body at the pair's stamp into body at the sample's (gyro).
            odom_R_base: the attitude at the pair's stamp (at rest: roll and pitch from
                the mean specific force, the estimate's yaw).
            tilt_sigma_rad: 1-sigma of that attitude's roll and pitch.
        """
        s_b = base_R_then_now.T @ (self.sensor.base_R_sensor @ np.asarray(v_sensor, float))
        s_o = odom_R_base @ s_b
        s_o = s_o / np.linalg.norm(s_o)
        alpha_odom = math.atan2(s_o[1], s_o[0])
        el_meas = math.asin(max(-1.0, min(1.0, float(s_o[2]))))
        alpha_map, el = self.site.sun_grid(utc_s)
        tilt = tilt_sigma_rad
        sig = self.sensor.sigma_rad
        c = max(math.cos(el), 1e-6)
        var = sig**2 / c**2 + (tilt * math.tan(el)) ** 2
        m = Measurement(alpha_odom, alpha_map, el, el_meas, var)
        if el <= 0.0:
            m.problem, m.detail = "below_horizon", (
                f"the ephemeris puts the sun {math.degrees(-el):.1f} deg below the horizon")
            return m
        gate = max(ELEVATION_GATE_SIGMA * math.hypot(sig, tilt),
                   math.radians(ELEVATION_GATE_FLOOR_DEG))
        if abs(el_meas - el) > gate:
            m.problem, m.detail = "elevation_mismatch", (
                f"its elevation is {math.degrees(el_meas):.2f} deg, the ephemeris' sun "
                f"{math.degrees(el):.2f} deg (more than {math.degrees(gate):.2f} deg apart)")
            return m
        if var > math.radians(MAX_AZIMUTH_SIGMA_DEG) ** 2:
            m.problem, m.detail = "near_zenith", (
                f"sun at {math.degrees(el):.1f} deg elevation: azimuth sigma "
                f"{math.degrees(math.sqrt(var)):.1f} deg")
        return m

    def heading_sigma_deg(self, P: np.ndarray) -> float:
        """1-sigma of the body's grid heading (``yaw + psi0``), deg (nan before psi0)."""
        if P.shape[0] <= PSI0:
            return math.nan
        return math.degrees(math.sqrt(max(P[5, 5] + 2 * P[5, PSI0] + P[PSI0, PSI0], 0.0)))

    def bounded(self, t: float | None) -> bool:
        """Whether an update came within ``BOUNDED_FOR_S`` before ``t``."""
        return (self.last_update_t is not None and t is not None
                and t - self.last_update_t <= BOUNDED_FOR_S)

    def apply(self, m: Measurement, state: Any, reference: Any = None, t: float | None = None
              ) -> str:
        """Fold a usable measurement into ``state`` (an :class:`~rover_vo.state.OdomState`
        at the pair's stamp) and the reference frame's state ``reference`` (whose motion
        to ``state`` the next vision frame composes: it turns with it, about the rover's
        position, so that pose and the next ones agree); returns ``initialized``,
        ``updated`` or ``rejected`` (module step 4).
        """
        t = state.t if t is None else t
        self.last_elevation_deg = math.degrees(m.elevation)
        if self.psi0 is None:
            self.psi0 = wrap(m.alpha_map - m.alpha_odom)
            state.P = augment(state.P, m.variance)
            if reference is not None and reference.P.shape[0] <= PSI0:
                reference.P = augment(reference.P, m.variance)
            self.last_update_t = t
            self.in_outage = False
            return "initialized"
        y = wrap(m.alpha_map - m.alpha_odom - self.psi0)
        self.last_innovation_deg = math.degrees(y)
        P = state.P
        S = P[5, 5] + 2 * P[5, PSI0] + P[PSI0, PSI0] + m.variance
        if y * y / S > GATE_CHI2:
            self.rejected += 1
            return "rejected"
        dx, state.P = schmidt_update(P, y, m.variance)
        turn = rotz(float(dx[5]))
        state.R = turn @ state.R
        if reference is not None:
            if reference.P.shape == P.shape:
                _, reference.P = schmidt_update(reference.P, y, m.variance, gain_from=P)
            reference.R = turn @ reference.R
            reference.p = state.p + turn @ (reference.p - state.p)
        self.psi0 = wrap(self.psi0 + float(dx[PSI0]))
        self.updates += 1
        self.last_update_t = t
        self.in_outage = False
        return "updated"
