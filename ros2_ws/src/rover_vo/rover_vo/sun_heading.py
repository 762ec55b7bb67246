"""Absolute heading from a sun sensor and gravity (no rclpy).

A sun sensor on the body measures the unit sun vector in its frame; with the body's roll
and pitch (the filter's attitude, held to the accelerometer's gravity) that vector gives
the sun's azimuth in the level body frame, and the ephemeris (:mod:`roi_network.sun`)
gives the same sun's azimuth in the map's grid at the sample's stamp: the difference is
the body's heading from grid north, whatever the odometry did before.

The odom frame is not turned (DESIGN.md: it starts at the rover's first pose and
``odom -> base_link`` never jumps). The filter carries five more error states:

- ``psi0`` (index 8): the grid azimuth of the odom frame's x axis (the yaw of
  ``map_R_odom``). The first usable sample sets it (``psi0 = sun's grid azimuth - sun's
  azimuth in odom``, its error correlated with the odometry's yaw and with the bias
  states below); every later sample is a measurement of ``yaw + psi0``.
- Four *bias* states (:attr:`SunHeading.bias`): errors that are the same from one sample
  to the next and so do not average out. The sensor's two angle biases (9, 10; rover.yaml
  ``sun_sensor.bias_deg``, constant for a sensor, and any tilt of its mount) and the tilt
  error of gravity at rest about the body's x and y axes (11, 12; the accelerometer's
  bias, ``AT_REST_TILT_BIAS_RAD`` at turn-on, then a random walk of rover.yaml's
  ``accel_bias_random_walk`` over g). Each is a small turn of the sun's direction in the
  body frame, so its share of an azimuth follows the body's heading against the sun: at
  one heading it is a constant offset, indistinguishable from ``psi0``, and stops at
  other headings separate the two. They are estimated: each sample's azimuth is taken at
  the estimated biases, and the update corrects them. Treating them as white noise makes
  the heading's variance shrink with every sample to far below the truth; leaving them
  uncorrected (consider states) keeps their full share, about 0.5 deg at 40 deg elevation
  with 0.1 deg of sensor bias and 2 mg of accelerometer bias. What no sun sample can
  separate from ``psi0`` is a turn of the mount about the boresight: the mount's yaw must
  be calibrated.

The update corrects the yaw, ``psi0`` and the bias states (position, roll and pitch, scale
and heading-rate bias keep their values, so the pose moves by a small turn about the rover
and nothing else), and the Joseph form keeps the covariance right for that gain.

Per sample (:meth:`SunHeading.measure`), at rest only (see below):

1. the vector into base_link by the mount (rover.yaml ``sun_sensor.base_to_sensor``),
   then to the body at the pair's stamp by the gyro between the two stamps, then into
   odom by the attitude (roll and pitch from the mean specific force, the estimate's
   yaw): its elevation and its azimuth in odom;
2. the ephemeris at the stamp (POSIX UTC, rover.yaml ``site.*``): the sun below the
   horizon, or a measured elevation more than ``ELEVATION_GATE_SIGMA`` sigma from the
   ephemeris', is a vector that is not the sun (counted, skipped);
3. the azimuth's sensitivity to each sensor angle and each tilt axis (numerical
   derivatives of step 1, at the estimated biases): the white part of its variance (the
   sensor's noise, the accelerometer's noise over the averaging window) and the rows of
   the bias states;
   samples whose total azimuth sigma exceeds ``MAX_AZIMUTH_SIGMA_DEG`` are not used (the
   sun near the zenith);
4. the innovation against ``yaw + psi0``, a chi-square gate (1 degree of freedom,
   ``GATE_CHI2``) on its full variance (state, bias states, white noise): a sample
   that contradicts the heading beyond its uncertainty is rejected and counted.

Only samples taken at rest are used. In motion the filter's roll and pitch err by tenths
of a degree, slowly, and an error ``e`` about the sun's horizontal direction turns the
azimuth by ``e tan(elevation)``: about 0.45 deg at 42 deg elevation, more than the gyro
drifts between two stops; the drive/stop schedule of a traverse gives the stops.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

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
#: Index of ``psi0`` in the augmented error state (after the odometry's 8) ...
PSI0 = 8
#: ... of the bias states: the sensor's two angle biases, the tilt bias about body x, y.
BIASES = slice(9, 13)
#: ... of the tilt bias states among them (they drift with the accelerometer's bias).
TILT = [11, 12]
#: State indices an update corrects: the yaw, ``psi0`` and the bias states.
CORRECTED = [5, PSI0, *range(BIASES.start, BIASES.stop)]
#: 1-sigma tilt error of gravity at rest per body axis from the accelerometer's turn-on
#: bias: 2 mg (a tactical-grade MEMS unit's; atan(0.002) = 0.115 deg), rad.
AT_REST_TILT_BIAS_RAD = math.radians(0.115)
#: The accelerometer's bias random walk when rover.yaml states none, m/s^2/sqrt(s).
ACCEL_BIAS_RANDOM_WALK = 3.0e-4
#: 1-sigma white tilt error of the 0.5 s mean specific force (noise density 0.002 m/s^2
#: per sqrt(Hz) over 0.5 s: 0.0028 m/s^2), rad.
AT_REST_TILT_NOISE_RAD = math.radians(0.016)
#: Step of the numerical derivatives of the azimuth (rad).
DERIVATIVE_STEP_RAD = 1e-6
#: The heading counts as bounded (``sun.heading_bounded`` in /vo/status) while the last
#: update is at most this old (s): a few drive segments between stops (the odometry's own
#: yaw variance grows from the last update, and says so); a longer outage is drift.
BOUNDED_FOR_S = 300.0


class SunSetupError(ValueError):
    """rover.yaml's sun sensor is malformed; the message names the field."""


@dataclass(frozen=True)
class SunSensorModel:
    """The sun sensor as rover.yaml states it.

    Attributes:
        frame: the frame of its ``/sun_sensor`` messages.
        base_R_sensor: 3x3 rotation sensor -> base_link.
        noise_rad: 1-sigma white noise of each measured angle (rad).
        bias_rad: 1-sigma of each angle's constant bias (rad).
        rate_hz: its sample rate (0: not stated).
        fov_half_angle_deg: its field of view's half-angle (nan: not stated).
    """

    frame: str
    base_R_sensor: np.ndarray
    noise_rad: float
    bias_rad: float
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
        return cls(frame, mount[:3, :3], math.radians(values["noise_deg"]),
                   math.radians(values["bias_deg"]), values["rate_hz"],
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
        variance: the azimuth's total variance (rad^2): white and bias parts (the biases'
            prior, before any update).
        white_variance: its white part (the sensor's and the accelerometer's noise).
        bias_row: the azimuth's sensitivity to the bias states (4,): the sensor's two
            angle biases, the tilt bias about body x and y.
        problem: None, or ``below_horizon``, ``elevation_mismatch``, ``near_zenith``.
        detail: what the problem was, in words.
    """

    alpha_odom: float
    alpha_map: float
    elevation: float
    elevation_measured: float
    variance: float
    white_variance: float = 0.0
    bias_row: np.ndarray = field(default_factory=lambda: np.zeros(4))
    problem: str | None = None
    detail: str = ""


def bias_prior(sensor: SunSensorModel) -> np.ndarray:
    """Prior variances of the bias states: the sensor's angle biases, the tilt biases."""
    return np.array([sensor.bias_rad**2] * 2 + [AT_REST_TILT_BIAS_RAD**2] * 2)


def augment(P: np.ndarray, m: Measurement, prior: np.ndarray) -> np.ndarray:
    """The odometry's ``P`` (8x8) with the sun's states: the bias states from their
    ``prior`` (uncorrelated with the rest), then ``psi0`` set by the first sample ``m``:
    ``e_psi0 = -e_yaw - bias_row . b - n`` (``n`` its white noise)."""
    n = P.shape[0]
    k = len(prior)
    ext = np.zeros((n + k, n + k))
    ext[:n, :n] = P
    ext[n:, n:] = np.diag(prior)
    T = np.zeros((n + 1 + k, n + k))
    T[:n, :n] = np.eye(n)
    T[n, 5] = -1.0
    T[n, n:] = -np.asarray(m.bias_row, float)
    T[n + 1:, n:] = np.eye(k)
    A = T @ ext @ T.T
    A[n, n] += m.white_variance
    return 0.5 * (A + A.T)


def measurement_row(P: np.ndarray, m: Measurement) -> np.ndarray:
    """``H`` of a sample: 1 at the yaw and at ``psi0``, its bias row."""
    H = np.zeros(P.shape[0])
    H[5] = H[PSI0] = 1.0
    H[BIASES] = m.bias_row
    return H


def heading_update(P: np.ndarray, y: float, H: np.ndarray, r: float,
                   gain_from: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Update by innovation ``y`` of row ``H`` (white variance ``r``), only the yaw (5),
    ``psi0`` (8) and the bias states (9-12) corrected; returns the correction and the new
    covariance (Joseph form, right for this gain). ``gain_from``: the covariance the gain
    is computed from (default ``P``)."""
    G = P if gain_from is None else gain_from
    S = float(H @ G @ H) + r
    K = np.zeros(P.shape[0])
    K[CORRECTED] = (G @ H)[CORRECTED] / S
    A = np.eye(P.shape[0]) - np.outer(K, H)
    P2 = A @ P @ A.T + r * np.outer(K, K)
    return K * y, 0.5 * (P2 + P2.T)


def sensor_angles(v: np.ndarray) -> np.ndarray:
    """The two angles a two-axis sun sensor reads of a sensor-frame vector (rad)."""
    return np.array([math.atan2(v[0], v[2]), math.atan2(v[1], v[2])])


def angles_vector(ang: np.ndarray) -> np.ndarray:
    """The unit vector of two sensor angles."""
    w = np.array([math.tan(ang[0]), math.tan(ang[1]), 1.0])
    return w / np.linalg.norm(w)


def small_rotation(x: float, y: float) -> np.ndarray:
    """``Exp([x, y, 0])``: the tilt perturbation about body x and y."""
    return Rotation.from_rotvec([x, y, 0.0]).as_matrix()


class SunHeading:
    """The sun heading filter's side of the estimator: the setup, ``psi0`` and counts.

    Args:
        sensor: the sensor (rover.yaml), or None.
        site: the site (rover.yaml), or None.
        accel_bias_random_walk: the accelerometer's bias random walk (m/s^2/sqrt(s)):
            how fast the tilt bias states drift.
        gravity: m/s^2.
    """

    def __init__(self, sensor: SunSensorModel | None, site: Site | None,
                 accel_bias_random_walk: float = ACCEL_BIAS_RANDOM_WALK,
                 gravity: float = 9.81) -> None:
        self.sensor = sensor
        self.site = site
        self.psi0: float | None = None
        #: Estimated bias states (rad): the sensor's two angles, the tilt about body x, y.
        self.bias = np.zeros(4)
        #: Variance rate of the tilt bias states (rad^2/s).
        self.tilt_rate = (accel_bias_random_walk / gravity) ** 2
        self._bias_t: float | None = None  # when the tilt states' drift was last added
        self.samples = 0
        self.updates = 0
        self.rejected = 0
        self.last_update_t: float | None = None
        self.last_elevation_deg = math.nan
        self.last_innovation_deg = math.nan
        self.near_zenith = 0
        self.in_motion = 0  # samples by pairs in motion: not used
        self.outages = 0  # spans without a sample, the sun out of sight or set
        self.in_outage = False

    @property
    def usable(self) -> bool:
        return self.sensor is not None and self.site is not None

    def measure(self, utc_s: float, v_sensor: np.ndarray, base_R_then_now: np.ndarray,
                odom_R_base: np.ndarray) -> Measurement:
        """The heading measurement of one sample taken at rest (module steps 1-3).

        Args:
            utc_s: the sample's stamp (POSIX UTC s).
            v_sensor: the unit sun vector in the sensor frame.
            base_R_then_now: body at the pair's stamp into body at the sample's (gyro).
            odom_R_base: the attitude at the pair's stamp: roll and pitch from the mean
                specific force, the estimate's yaw.
        """
        mount = self.sensor.base_R_sensor
        ang = sensor_angles(np.asarray(v_sensor, float))

        def sun_odom(d: np.ndarray) -> np.ndarray:
            # d: the sensor's two angle errors, the tilt error about body x and y
            s_b = base_R_then_now.T @ (mount @ angles_vector(ang - d[:2]))
            s_o = odom_R_base @ (small_rotation(d[2], d[3]) @ s_b)
            return s_o / np.linalg.norm(s_o)

        s_o = sun_odom(self.bias)
        alpha_odom = math.atan2(s_o[1], s_o[0])
        el_meas = math.asin(max(-1.0, min(1.0, float(s_o[2]))))
        row = np.zeros(4)
        h = DERIVATIVE_STEP_RAD
        for i in range(4):
            d = np.zeros(4)
            d[i] = h
            up, down = sun_odom(self.bias + d), sun_odom(self.bias - d)
            row[i] = wrap(math.atan2(up[1], up[0]) - math.atan2(down[1], down[0])) / (2 * h)
        sensor = self.sensor
        white = (float(row[:2] @ row[:2]) * sensor.noise_rad**2
                 + float(row[2:] @ row[2:]) * AT_REST_TILT_NOISE_RAD**2)
        var = white + float(row**2 @ bias_prior(sensor))
        alpha_map, el = self.site.sun_grid(utc_s)
        m = Measurement(alpha_odom, alpha_map, el, el_meas, var, white, row)
        if el <= 0.0:
            m.problem, m.detail = "below_horizon", (
                f"the ephemeris puts the sun {math.degrees(-el):.1f} deg below the horizon")
            return m
        sigma_el = math.hypot(sensor.noise_rad, sensor.bias_rad, AT_REST_TILT_BIAS_RAD,
                              AT_REST_TILT_NOISE_RAD)
        gate = max(ELEVATION_GATE_SIGMA * sigma_el, math.radians(ELEVATION_GATE_FLOOR_DEG))
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
            prior = bias_prior(self.sensor)
            state.P = augment(state.P, m, prior)
            if reference is not None and reference.P.shape[0] <= PSI0:
                reference.P = augment(reference.P, m, prior)
            self.last_update_t = self._bias_t = t
            self.in_outage = False
            return "initialized"
        # the tilt bias states drift with the accelerometer's bias since the last sample
        grow = self.tilt_rate * max(0.0, t - self._bias_t) if self._bias_t is not None else 0.0
        self._bias_t = t
        others = [] if reference is None or reference.P is state.P else [reference.P]
        for P_ in (state.P, *others):
            if P_.shape[0] >= BIASES.stop:
                P_[TILT, TILT] += grow
        y = wrap(m.alpha_map - m.alpha_odom - self.psi0)
        self.last_innovation_deg = math.degrees(y)
        P = state.P
        H = measurement_row(P, m)
        S = float(H @ P @ H) + m.white_variance
        if y * y / S > GATE_CHI2:
            self.rejected += 1
            return "rejected"
        dx, state.P = heading_update(P, y, H, m.white_variance)
        turn = rotz(float(dx[5]))
        state.R = turn @ state.R
        if reference is not None:
            if reference.P.shape == P.shape:
                _, reference.P = heading_update(reference.P, y, H, m.white_variance,
                                                gain_from=P)
            reference.R = turn @ reference.R
            reference.p = state.p + turn @ (reference.p - state.p)
        self.psi0 = wrap(self.psi0 + float(dx[PSI0]))
        self.bias = self.bias + dx[BIASES]
        self.updates += 1
        self.last_update_t = t
        self.in_outage = False
        return "updated"
