"""Where the sun is, on Earth and on Mars, and which way grid north points.

The sun's direction at a place and time, for a sun sensor model and an absolute heading
update: azimuth (degrees from true north, clockwise) and elevation (degrees above the
horizon), the unit sun vector in the local ENU frame (x east, y north, z up), the local
mean and true solar time, and the inverse (the UTC instant of a local solar time on a
given day). Closed-form published algorithms, no ephemeris files:

- **Earth**: NOAA's solar calculator (its spreadsheet and web page), which is Meeus,
  *Astronomical Algorithms* (1991), ch. 25 (low accuracy sun, ~0.01 deg) with his
  equation of time (eq. 28.3) and NOAA's refraction fit for a standard atmosphere.
  Latitude geodetic (WGS 84), longitude east positive. UT is taken equal to UTC and TT
  to UT, as NOAA does (both below 0.001 deg of sun direction).
- **Mars**: Allison & McEwen (2000) as NASA GISS's Mars24 clock computes it (its
  "Algorithm and Worked Examples" page, steps A-1 to D-6): Mars Sol Date, areocentric
  solar longitude Ls, equation of time, Coordinated Mars Time, local mean and true solar
  time, subsolar point. Longitude is planetocentric **east positive** (IAU 2015, the
  convention of the project's Mars CRSs, e.g. ``IAU_2015:49910``); the Mars24 worked
  examples quote west longitudes, 360 - east. UTC -> TT uses the leap-second table below.

The local horizon is the plane normal to the site's vertical, given by ``lat_deg``: on the
IAU 2015 Mars sphere (the project's Mars CRSs) that is the planetocentric latitude; on an
ellipsoid pass the geodetic (planetographic) latitude, whose normal is the vertical. The
sun's declination is the direction's (``asin(sin(obliquity) sin(Ls))`` on Mars); Mars24's
step D-1 adds ``0.25 deg sin(Ls)`` to give the planetographic latitude of the point under
the ray from the planet's centre (``MarsSun.subsolar_latitude_ographic_deg``), which is
not the declination of the direction.

Grid north (:func:`grid_north`): the map frame is a projected CRS shifted (DESIGN.md,
Frames), so a heading in the map is measured from grid north, not true north. PROJ's
projection factors at the site (``pyproj.Proj.get_factors``) give the meridian
convergence (grid azimuth of true north = ``-convergence_deg``), the angle between
meridian and parallel and the scales along both; together they map a true azimuth to its
grid azimuth in any projection (a rotation by the convergence in a conformal one such as
UTM or transverse Mercator; a stretch in an equirectangular one such as
``IAU_2015:49910``, whose convergence is 0).

Method (docs/roi_network.md, Sun):
  1. time: UTC -> Julian day (UT) -> TT (Mars: TT - UTC = leap seconds + 32.184 s);
  2. the sun in the body's sky: declination and equation of time (Earth: NOAA / Meeus;
     Mars: Mars24), hence the local true solar time and hour angle at the longitude;
  3. azimuth and elevation from declination, latitude and hour angle
     (:func:`horizontal`); Earth's apparent elevation adds NOAA's refraction;
  4. grid azimuth = the direction's image under the projection's local linear map.
"""

from __future__ import annotations

import bisect
import datetime as dt
import functools
import math
from dataclasses import dataclass

import numpy as np

EARTH = "earth"
MARS = "mars"
BODIES = (EARTH, MARS)

#: Julian day of the POSIX epoch (1970-01-01 00:00 UTC) and of J2000.0 (2000-01-01 12:00 TT).
JD_POSIX_EPOCH = 2440587.5
JD_J2000 = 2451545.0
#: TT - TAI, s.
TT_MINUS_TAI_S = 32.184
#: TAI - UTC from each leap second on (UTC date, seconds), IERS Bulletin C; 37 s holds
#: until the next one is announced (a new leap second needs a new line here).
LEAP_SECONDS = (
    ("1972-01-01", 10), ("1972-07-01", 11), ("1973-01-01", 12), ("1974-01-01", 13),
    ("1975-01-01", 14), ("1976-01-01", 15), ("1977-01-01", 16), ("1978-01-01", 17),
    ("1979-01-01", 18), ("1980-01-01", 19), ("1981-07-01", 20), ("1982-07-01", 21),
    ("1983-07-01", 22), ("1985-07-01", 23), ("1988-01-01", 24), ("1990-01-01", 25),
    ("1991-01-01", 26), ("1992-07-01", 27), ("1993-07-01", 28), ("1994-07-01", 29),
    ("1996-01-01", 30), ("1997-07-01", 31), ("1999-01-01", 32), ("2006-01-01", 33),
    ("2009-01-01", 34), ("2012-07-01", 35), ("2015-07-01", 36), ("2017-01-01", 37),
)
_LEAP_POSIX = [dt.datetime.fromisoformat(d).replace(tzinfo=dt.UTC).timestamp()
               for d, _ in LEAP_SECONDS]

#: Mars: Earth days per sol (mean solar day), and Mars24's MSD offset at the J2000 epoch.
MARS_SOL_DAYS = 1.0274912517
_MSD_AT_J2000_PLUS_4_5 = 44796.0 - 0.0009626
#: Mars' obliquity as Allison & McEwen's declination formula uses it: sin(25.19 deg).
MARS_SIN_OBLIQUITY = 0.42565
#: Mars semi-major axis (AU), Mars24 step D-2.
MARS_SEMI_MAJOR_AU = 1.52367934
#: Allison & McEwen (2000) Table 5 (Mars24 B-3): planetary perturbations of the fictitious
#: mean sun, amplitude (deg), period (Julian years), phase (deg).
_MARS_PERTURBERS = (
    (0.0071, 2.2353, 49.409), (0.0057, 2.7543, 168.173), (0.0039, 1.1177, 191.837),
    (0.0037, 15.7866, 21.736), (0.0021, 2.1354, 15.704), (0.0020, 2.4694, 95.528),
    (0.0018, 32.8493, 49.095),
)

_sin = lambda deg: math.sin(math.radians(deg))  # noqa: E731
_cos = lambda deg: math.cos(math.radians(deg))  # noqa: E731


class SunError(ValueError):
    """An input the ephemeris cannot use; the message names it."""


# ----------------------------------------------------------------------------- time


def posix_seconds(utc: dt.datetime | float) -> float:
    """Seconds since 1970-01-01 00:00 UTC (POSIX, no leap seconds) of ``utc``.

    Args:
        utc: a timezone-aware datetime, or POSIX seconds (a ROS stamp's ``sec +
            nanosec * 1e-9`` is one).

    Raises:
        SunError: a naive datetime (its zone is unknown), or a time that is not finite.
    """
    if isinstance(utc, dt.datetime):
        if utc.tzinfo is None or utc.utcoffset() is None:
            raise SunError(f"utc: naive datetime {utc.isoformat()}; give a timezone-aware "
                           "datetime (e.g. tzinfo=datetime.timezone.utc) or POSIX seconds")
        return utc.timestamp()
    if isinstance(utc, bool) or not isinstance(utc, (int, float, np.integer, np.floating)):
        raise SunError(f"utc: expected a datetime or POSIX seconds, got {type(utc).__name__}")
    t = float(utc)
    if not math.isfinite(t):
        raise SunError(f"utc: POSIX seconds must be finite, got {t}")
    return t


def julian_day_ut(utc: dt.datetime | float) -> float:
    """Julian day (UT, taken equal to UTC) of ``utc``."""
    return JD_POSIX_EPOCH + posix_seconds(utc) / 86400.0


def tt_minus_utc_s(utc: dt.datetime | float) -> float:
    """TT - UTC at ``utc``, s (leap seconds + 32.184 s).

    Raises:
        SunError: before 1972-01-01, where UTC had no whole-second offset from TAI.
    """
    t = posix_seconds(utc)
    i = bisect.bisect_right(_LEAP_POSIX, t)
    if i == 0:
        raise SunError(f"utc: {_iso(t)} is before 1972-01-01, where the leap-second table "
                       "(roi_network.sun.LEAP_SECONDS) starts")
    return LEAP_SECONDS[i - 1][1] + TT_MINUS_TAI_S


def _iso(t: float) -> str:
    return dt.datetime.fromtimestamp(t, dt.UTC).isoformat()


def _utc(t: float) -> dt.datetime:
    return dt.datetime.fromtimestamp(t, dt.UTC)


def _body(body: str) -> str:
    b = str(body).strip().lower()
    if b not in BODIES:
        raise SunError(f"body: '{body}' is not one of {', '.join(BODIES)}")
    return b


def _finite(value: float, name: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise SunError(f"{name}: expected a number, got {value!r}") from None
    if not math.isfinite(v):
        raise SunError(f"{name}: must be finite, got {v}")
    return v


def _latitude(lat_deg: float) -> float:
    lat = _finite(lat_deg, "lat_deg")
    if not -90.0 <= lat <= 90.0:
        raise SunError(f"lat_deg: {lat} is outside [-90, 90] degrees")
    return lat


# ----------------------------------------------------------------------------- Earth


@dataclass(frozen=True)
class EarthSun:
    """The sun seen from Earth's centre at one instant (NOAA / Meeus ch. 25, 28).

    Attributes:
        jd: Julian day (UT = TT, as NOAA takes it).
        julian_century: Julian centuries since J2000.0.
        mean_longitude_deg: geometric mean longitude L0, [0, 360).
        mean_anomaly_deg: mean anomaly M (not wrapped, as NOAA's spreadsheet gives it).
        eccentricity: eccentricity of Earth's orbit.
        equation_of_center_deg: C.
        true_longitude_deg: L0 + C.
        distance_au: sun distance R.
        apparent_longitude_deg: true longitude corrected for nutation and aberration.
        obliquity_deg: obliquity of the ecliptic, corrected (NOAA's "obliq corr").
        right_ascension_deg: apparent right ascension, (-180, 180].
        declination_deg: apparent declination.
        equation_of_time_min: true minus mean solar time, minutes.
        subsolar_longitude_deg: east longitude where the sun culminates now, (-180, 180].
    """

    jd: float
    julian_century: float
    mean_longitude_deg: float
    mean_anomaly_deg: float
    eccentricity: float
    equation_of_center_deg: float
    true_longitude_deg: float
    distance_au: float
    apparent_longitude_deg: float
    obliquity_deg: float
    right_ascension_deg: float
    declination_deg: float
    equation_of_time_min: float
    subsolar_longitude_deg: float

    @property
    def subsolar_latitude_deg(self) -> float:
        """Latitude under the sun: the declination."""
        return self.declination_deg


def earth_sun_at_jd(jd: float) -> EarthSun:
    """:class:`EarthSun` at Julian day ``jd`` (UT = TT). NOAA spreadsheet columns G-V."""
    jd = _finite(jd, "jd")
    t = (jd - JD_J2000) / 36525.0
    l0 = (280.46646 + t * (36000.76983 + t * 0.0003032)) % 360.0
    m = 357.52911 + t * (35999.05029 - 0.0001537 * t)
    e = 0.016708634 - t * (0.000042037 + 0.0000001267 * t)
    c = (_sin(m) * (1.914602 - t * (0.004817 + 0.000014 * t))
         + _sin(2 * m) * (0.019993 - 0.000101 * t) + _sin(3 * m) * 0.000289)
    true_long = l0 + c
    r = 1.000001018 * (1 - e * e) / (1 + e * _cos(m + c))
    omega = 125.04 - 1934.136 * t
    lam = true_long - 0.00569 - 0.00478 * _sin(omega)
    eps0 = 23 + (26 + (21.448 - t * (46.815 + t * (0.00059 - t * 0.001813))) / 60) / 60
    eps = eps0 + 0.00256 * _cos(omega)
    ra = math.degrees(math.atan2(_cos(eps) * _sin(lam), _cos(lam)))
    dec = math.degrees(math.asin(_sin(eps) * _sin(lam)))
    y = math.tan(math.radians(eps / 2)) ** 2
    eot = 4 * math.degrees(y * _sin(2 * l0) - 2 * e * _sin(m) + 4 * e * y * _sin(m) * _cos(2 * l0)
                           - 0.5 * y * y * _sin(4 * l0) - 1.25 * e * e * _sin(2 * m))
    minutes = ((jd + 0.5) % 1.0) * 1440.0
    sub_lon = _wrap180((720.0 - minutes - eot) / 4.0)
    return EarthSun(jd, t, l0, m, e, c, true_long, r, lam, eps, ra, dec, eot, sub_lon)


def earth_sun(utc: dt.datetime | float) -> EarthSun:
    """:class:`EarthSun` at ``utc`` (datetime or POSIX seconds)."""
    return earth_sun_at_jd(julian_day_ut(utc))


def noaa_refraction_deg(elevation_deg: float) -> float:
    """Atmospheric refraction (deg) at a geometric elevation, NOAA's fit for a standard
    atmosphere (Bennett's formula above 5 deg, a polynomial down to -0.575 deg, a decaying
    term below, zero above 85 deg): what is added to give the apparent elevation."""
    e = _finite(elevation_deg, "elevation_deg")
    if e > 85.0:
        return 0.0
    te = math.tan(math.radians(e))
    if e > 5.0:
        arcsec = 58.1 / te - 0.07 / te ** 3 + 0.000086 / te ** 5
    elif e > -0.575:
        arcsec = 1735 + e * (-518.2 + e * (103.4 + e * (-12.79 + e * 0.711)))
    else:
        arcsec = -20.772 / te
    return arcsec / 3600.0


# ----------------------------------------------------------------------------- Mars


@dataclass(frozen=True)
class MarsSun:
    """Mars time and the sun seen from Mars at one instant (Mars24 steps A to D).

    Attributes:
        jd_tt: Julian day, TT (A-5).
        dt_j2000_days: days since J2000.0, TT (A-6).
        mean_anomaly_deg: Mars' mean anomaly M, [0, 360) (B-1).
        fms_deg: right ascension of the fictitious mean sun, [0, 360) (B-2).
        perturbation_deg: planetary perturbations PBS (B-3).
        equation_of_center_deg: true minus mean anomaly (B-4).
        ls_deg: areocentric solar longitude Ls, [0, 360) (B-5).
        equation_of_time_deg: true minus mean solar time, degrees (C-1; /15 for hours).
        msd: Mars Sol Date (C-2).
        mtc_h: Coordinated Mars Time, the mean solar time at 0 deg longitude, h (C-2).
        declination_deg: the sun direction's declination, asin(0.42565 sin Ls).
        subsolar_latitude_ographic_deg: Mars24's subsolar latitude, planetographic (D-1).
        subsolar_longitude_deg: east longitude under the sun, [0, 360) (C-5, as east).
        distance_au: heliocentric distance (D-2).
    """

    jd_tt: float
    dt_j2000_days: float
    mean_anomaly_deg: float
    fms_deg: float
    perturbation_deg: float
    equation_of_center_deg: float
    ls_deg: float
    equation_of_time_deg: float
    msd: float
    mtc_h: float
    declination_deg: float
    subsolar_latitude_ographic_deg: float
    subsolar_longitude_deg: float
    distance_au: float

    def lmst_h(self, lon_deg: float) -> float:
        """Local mean solar time at east longitude ``lon_deg``, h in [0, 24) (C-3)."""
        return (self.mtc_h + _finite(lon_deg, "lon_deg") / 15.0) % 24.0

    def ltst_h(self, lon_deg: float) -> float:
        """Local true solar time at east longitude ``lon_deg``, h in [0, 24) (C-4)."""
        return (self.lmst_h(lon_deg) + self.equation_of_time_deg / 15.0) % 24.0


def mars_sun_at_tt(dt_j2000_days: float) -> MarsSun:
    """:class:`MarsSun` at ``dt_j2000_days`` days (TT) after J2000.0 (Mars24 B to D)."""
    d = _finite(dt_j2000_days, "dt_j2000_days")
    m = (19.3871 + 0.52402073 * d) % 360.0
    fms = (270.3871 + 0.524038496 * d) % 360.0
    pbs = sum(a * _cos(0.985626 * d / tau + phi) for a, tau, phi in _MARS_PERTURBERS)
    nu_m = ((10.691 + 3.0e-7 * d) * _sin(m) + 0.623 * _sin(2 * m) + 0.050 * _sin(3 * m)
            + 0.005 * _sin(4 * m) + 0.0005 * _sin(5 * m) + pbs)
    ls = (fms + nu_m) % 360.0
    eot = 2.861 * _sin(2 * ls) - 0.071 * _sin(4 * ls) + 0.002 * _sin(6 * ls) - nu_m
    msd = (d - 4.5) / MARS_SOL_DAYS + _MSD_AT_J2000_PLUS_4_5
    mtc = (24.0 * msd) % 24.0
    dec = math.degrees(math.asin(MARS_SIN_OBLIQUITY * _sin(ls)))
    sub_west = (mtc * 15.0 + eot + 180.0) % 360.0
    r = MARS_SEMI_MAJOR_AU * (1.00436 - 0.09309 * _cos(m) - 0.004336 * _cos(2 * m)
                              - 0.00031 * _cos(3 * m) - 0.00003 * _cos(4 * m))
    return MarsSun(d + JD_J2000, d, m, fms, pbs, nu_m, ls, eot, msd, mtc, dec,
                   dec + 0.25 * _sin(ls), (-sub_west) % 360.0, r)


def mars_sun(utc: dt.datetime | float) -> MarsSun:
    """:class:`MarsSun` at ``utc`` (datetime or POSIX seconds; from 1972 on)."""
    t = posix_seconds(utc)
    jd_tt = JD_POSIX_EPOCH + (t + tt_minus_utc_s(t)) / 86400.0
    return mars_sun_at_tt(jd_tt - JD_J2000)


# ----------------------------------------------------------------------------- the local sky


def horizontal(declination_deg: float, lat_deg: float, hour_angle_deg: float
               ) -> tuple[float, float]:
    """Azimuth (deg from north, clockwise, [0, 360)) and elevation (deg) of a direction of
    declination ``declination_deg`` at hour angle ``hour_angle_deg`` (positive west of the
    meridian: afternoon) seen from latitude ``lat_deg``. Mars24 D-5, D-6; NOAA's columns
    AD-AH, in atan2 form (no singularity but the poles' azimuth)."""
    dec, lat, h = (math.radians(v) for v in (declination_deg, lat_deg, hour_angle_deg))
    sin_el = math.sin(lat) * math.sin(dec) + math.cos(lat) * math.cos(dec) * math.cos(h)
    el = math.degrees(math.asin(max(-1.0, min(1.0, sin_el))))
    east = -math.cos(dec) * math.sin(h)
    north = math.sin(dec) * math.cos(lat) - math.cos(dec) * math.sin(lat) * math.cos(h)
    az = math.degrees(math.atan2(east, north)) % 360.0
    return az, el


@dataclass(frozen=True)
class SunPosition:
    """The sun in a site's sky at one instant.

    Attributes:
        body: ``"earth"`` or ``"mars"``.
        azimuth_deg: from true north, clockwise (east = 90), [0, 360).
        elevation_deg: geometric elevation above the horizon (no refraction).
        apparent_elevation_deg: with refraction (Earth: NOAA's; Mars: none, equal to
            ``elevation_deg``).
        declination_deg: the sun direction's declination.
        hour_angle_deg: local hour angle, positive in the afternoon, (-180, 180].
        local_mean_solar_time_h: h in [0, 24).
        local_true_solar_time_h: h in [0, 24) (12 = the sun on the meridian).
    """

    body: str
    azimuth_deg: float
    elevation_deg: float
    apparent_elevation_deg: float
    declination_deg: float
    hour_angle_deg: float
    local_mean_solar_time_h: float
    local_true_solar_time_h: float

    def enu(self, refracted: bool = True) -> np.ndarray:
        """Unit vector toward the sun in the local ENU frame (x east, y north, z up); the
        apparent direction unless ``refracted`` is False."""
        el = math.radians(self.apparent_elevation_deg if refracted else self.elevation_deg)
        az = math.radians(self.azimuth_deg)
        return np.array([math.cos(el) * math.sin(az), math.cos(el) * math.cos(az),
                         math.sin(el)])

    @property
    def above_horizon(self) -> bool:
        """The sun's apparent centre is above the astronomical horizon."""
        return self.apparent_elevation_deg > 0.0


def _wrap180(deg: float) -> float:
    w = (deg + 180.0) % 360.0 - 180.0
    return 180.0 if w == -180.0 else w


def sun_position(body: str, lat_deg: float, lon_deg: float, utc: dt.datetime | float
                 ) -> SunPosition:
    """The sun in the sky of a site at ``utc``.

    Args:
        body: ``"earth"`` or ``"mars"``.
        lat_deg: latitude of the site's vertical, degrees (Earth: geodetic; Mars:
            planetocentric on the IAU 2015 sphere).
        lon_deg: longitude, degrees east positive (any value; wrapped).
        utc: timezone-aware datetime or POSIX seconds.

    Raises:
        SunError: an unknown body, a latitude outside [-90, 90], a value that is not
            finite, a naive datetime, a Mars time before 1972.
    """
    b = _body(body)
    lat = _latitude(lat_deg)
    lon = _finite(lon_deg, "lon_deg")
    if b == EARTH:
        sun = earth_sun(utc)
        lmst = (((sun.jd + 0.5) % 1.0) * 24.0 + lon / 15.0) % 24.0
        ltst = (lmst + sun.equation_of_time_min / 60.0) % 24.0
        dec = sun.declination_deg
    else:
        msun = mars_sun(utc)
        lmst, ltst = msun.lmst_h(lon), msun.ltst_h(lon)
        dec = msun.declination_deg
    hour = _wrap180(15.0 * (ltst - 12.0))
    az, el = horizontal(dec, lat, hour)
    apparent = el + noaa_refraction_deg(el) if b == EARTH else el
    return SunPosition(b, az, el, apparent, dec, hour, lmst, ltst)


def sun_enu(body: str, lat_deg: float, lon_deg: float, utc: dt.datetime | float,
            refracted: bool = True) -> np.ndarray:
    """Unit sun vector in the site's ENU frame (see :func:`sun_position`)."""
    return sun_position(body, lat_deg, lon_deg, utc).enu(refracted)


# ----------------------------------------------------------------------------- solar time


def local_solar_time_h(body: str, lon_deg: float, utc: dt.datetime | float,
                       true_solar: bool = True) -> float:
    """Local true (or, with ``true_solar`` False, mean) solar time at east longitude
    ``lon_deg``, h in [0, 24)."""
    b = _body(body)
    lon = _finite(lon_deg, "lon_deg")
    if b == EARTH:
        sun = earth_sun(utc)
        lmst = (((sun.jd + 0.5) % 1.0) * 24.0 + lon / 15.0) % 24.0
        return (lmst + sun.equation_of_time_min / 60.0) % 24.0 if true_solar else lmst
    msun = mars_sun(utc)
    return msun.ltst_h(lon) if true_solar else msun.lmst_h(lon)


def solar_day(body: str, lon_deg: float, utc: dt.datetime | float) -> int:
    """The local mean solar day in progress at the site at ``utc``: on Earth the Julian
    day number of the local mean solar date, on Mars the sol number ``floor(MSD + lon/360)``
    (Mars24's local sol count)."""
    b = _body(body)
    lon = _finite(lon_deg, "lon_deg")
    if b == EARTH:
        return math.floor(julian_day_ut(utc) + 0.5 + lon / 360.0)
    return math.floor(mars_sun(utc).msd + lon / 360.0)


def utc_at_solar_time(body: str, lon_deg: float, day: int, hours: float,
                      true_solar: bool = True) -> dt.datetime:
    """The UTC instant at which the local (true or mean) solar time at east longitude
    ``lon_deg`` is ``hours`` on local mean solar day ``day`` (as :func:`solar_day` counts).

    With ``true_solar`` the instant is the one nearest to the mean-time instant of the
    same reading (the equation of time moves it by at most ~17 min on Earth, ~51 min on
    Mars, possibly into the neighbouring mean day near midnight).

    Raises:
        SunError: ``hours`` outside [0, 24), an unknown body, a value not finite.
    """
    b = _body(body)
    lon = _finite(lon_deg, "lon_deg")
    h = _finite(hours, "hours")
    if not 0.0 <= h < 24.0:
        raise SunError(f"hours: {h} is outside [0, 24)")
    if isinstance(day, bool) or not isinstance(day, (int, np.integer)):
        raise SunError(f"day: expected an integer day number (solar_day's), got {day!r}")
    n = int(day)
    offset_h = 0.0  # equation of time, hours
    t = 0.0
    for _ in range(6):
        mean_h = h - offset_h
        if b == EARTH:
            jd = n - 0.5 - lon / 360.0 + mean_h / 24.0
            t = (jd - JD_POSIX_EPOCH) * 86400.0
            new = earth_sun_at_jd(jd).equation_of_time_min / 60.0 if true_solar else 0.0
        else:
            msd = n - lon / 360.0 + mean_h / 24.0
            d_tt = (msd - _MSD_AT_J2000_PLUS_4_5) * MARS_SOL_DAYS + 4.5
            t_tt = (d_tt + JD_J2000 - JD_POSIX_EPOCH) * 86400.0
            t = t_tt - tt_minus_utc_s(t_tt - 69.184)
            t = t_tt - tt_minus_utc_s(t)
            new = mars_sun_at_tt(d_tt).equation_of_time_deg / 15.0 if true_solar else 0.0
        if abs(new - offset_h) < 1e-10:
            break
        offset_h = new
    return _utc(t)


def utc_on_date_at_solar_time(body: str, lon_deg: float, date: dt.date, hours: float,
                              true_solar: bool = True) -> dt.datetime:
    """:func:`utc_at_solar_time` on the local solar day in progress at the site at 12:00
    UTC of ``date``: on Earth the local calendar date ``date`` itself (any longitude in
    (-180, 180)); on Mars the sol under way at that instant (a sol is 1.0275 days, so one
    date in ~37 shares its sol with the next)."""
    if not isinstance(date, dt.date):
        raise SunError(f"date: expected a datetime.date, got {type(date).__name__}")
    noon = dt.datetime(date.year, date.month, date.day, 12, tzinfo=dt.UTC)
    return utc_at_solar_time(body, lon_deg, solar_day(body, lon_deg, noon), hours,
                             true_solar)


# ----------------------------------------------------------------------------- grid north


@dataclass(frozen=True)
class GridNorth:
    """How true directions at one point look in a projected CRS's grid (PROJ factors).

    Attributes:
        crs: the projected CRS, as given.
        convergence_deg: PROJ's meridian convergence: true north has grid azimuth
            ``-convergence_deg`` (positive east of a UTM central meridian in the northern
            hemisphere, negative in the southern).
        meridian_parallel_angle_deg: grid angle from the meridian to the parallel (90 in a
            conformal projection).
        meridional_scale: scale along the meridian (h).
        parallel_scale: scale along the parallel (k).
    """

    crs: str
    convergence_deg: float
    meridian_parallel_angle_deg: float
    meridional_scale: float
    parallel_scale: float

    def _matrix(self) -> np.ndarray:
        """Maps (east, north) components of a true direction to (grid x, grid y)."""
        north = math.radians(-self.convergence_deg)
        east = north + math.radians(self.meridian_parallel_angle_deg)
        return np.array([[self.parallel_scale * math.sin(east),
                          self.meridional_scale * math.sin(north)],
                         [self.parallel_scale * math.cos(east),
                          self.meridional_scale * math.cos(north)]])

    def grid_azimuth_deg(self, true_azimuth_deg: float) -> float:
        """Grid azimuth (deg from grid north, clockwise, [0, 360)) of a true azimuth."""
        a = math.radians(_finite(true_azimuth_deg, "true_azimuth_deg"))
        gx, gy = self._matrix() @ np.array([math.sin(a), math.cos(a)])
        return math.degrees(math.atan2(gx, gy)) % 360.0

    def true_azimuth_deg(self, grid_azimuth_deg: float) -> float:
        """True azimuth of a grid azimuth (the inverse of :meth:`grid_azimuth_deg`)."""
        g = math.radians(_finite(grid_azimuth_deg, "grid_azimuth_deg"))
        e, n = np.linalg.solve(self._matrix(), np.array([math.sin(g), math.cos(g)]))
        return math.degrees(math.atan2(e, n)) % 360.0

    def enu_to_grid(self, vector_enu: np.ndarray) -> np.ndarray:
        """A direction in the local ENU frame as seen in the map's axes (x grid east,
        y grid north, z up): the horizontal part turned to its grid azimuth, its length
        and the vertical part kept (a unit vector stays one, its elevation unchanged)."""
        v = np.asarray(vector_enu, dtype=float).reshape(3)
        if not np.all(np.isfinite(v)):
            raise SunError(f"vector_enu: not finite: {v.tolist()}")
        horiz = math.hypot(v[0], v[1])
        if horiz == 0.0:
            return v.copy()
        g = self._matrix() @ v[:2]
        g *= horiz / float(np.hypot(g[0], g[1]))
        return np.array([g[0], g[1], v[2]])


@functools.lru_cache(maxsize=16)
def _proj(crs: str):
    from pyproj import Proj

    from roi_network.crs import CrsError, projected_crs

    try:
        return Proj(projected_crs(crs, "crs"))
    except CrsError as exc:
        raise SunError(str(exc)) from None


def grid_north(crs: str, lon_deg: float, lat_deg: float) -> GridNorth:
    """PROJ's projection factors of ``crs`` at a point, as a :class:`GridNorth`.

    Args:
        crs: a projected CRS with east, north axes (``"EPSG:32719"``,
            ``"IAU_2015:49910"``, a PROJ string).
        lon_deg, lat_deg: the point, degrees, east longitude, in the CRS's own geographic
            coordinates (as the map origin's ``site_lonlat`` is given).

    Raises:
        SunError: an unknown or unprojected CRS, other axes, a point PROJ cannot project.
    """
    lon = _finite(lon_deg, "lon_deg")
    lat = _latitude(lat_deg)
    from pyproj.exceptions import ProjError

    try:
        f = _proj(str(crs)).get_factors(lon, lat, errcheck=True)
    except ProjError as exc:
        raise SunError(f"crs: '{crs}' cannot project lon {lon}, lat {lat} ({exc})") from exc
    values = (f.meridian_convergence, f.meridian_parallel_angle, f.meridional_scale,
              f.parallel_scale)
    if not all(math.isfinite(v) for v in values):
        raise SunError(f"crs: '{crs}' has no projection factors at lon {lon}, lat {lat}")
    return GridNorth(str(crs), *(float(v) for v in values))


def meridian_convergence_deg(crs: str, lon_deg: float, lat_deg: float) -> float:
    """PROJ's meridian convergence of ``crs`` at a point, deg (see :class:`GridNorth`)."""
    return grid_north(crs, lon_deg, lat_deg).convergence_deg


def grid_azimuth_deg(true_azimuth_deg: float, crs: str, lon_deg: float, lat_deg: float
                     ) -> float:
    """The grid azimuth in ``crs`` of a true azimuth at a point (see :func:`grid_north`)."""
    return grid_north(crs, lon_deg, lat_deg).grid_azimuth_deg(true_azimuth_deg)
