"""The sun ephemeris against published values, solar time, and grid north.

References (values copied with the decimals their sources print):

- Mars24, NASA GISS, "Mars24 Sunclock -- Algorithm and Worked Examples"
  (https://www.giss.nasa.gov/tools/mars24/help/algorithm.html), after Allison & McEwen
  (2000), Planet. Space Sci. 48, 215-235: example A (2000-01-06 00:00:00 UTC, 0 deg) and
  example B (MER Spirit, 2004-01-03 13:46:31 UTC, 184.702 deg W = 175.298 deg E,
  14.640 deg S).
- Meeus, *Astronomical Algorithms* (1991), example 25.a (the sun, low accuracy, at
  1992-10-13 0h TD, JDE 2448908.5): the algorithm NOAA's calculator implements.
- NOAA ESRL/GML solar calculator spreadsheet (NOAA_Solar_Calculations_day.xls), its first
  row with the site 40 N, 105 W, time zone -7, 2010-06-21 00:06 local.
- NREL SPA, Reda & Andreas (2008), NREL/TP-560-34302, table A5.1 (2003-10-17 12:30:30
  UTC-7, 39.742476 N, 105.1786 W): a more accurate, independent algorithm, so NOAA's
  stated ~0.01 deg is the bound there, not the printed decimals.
"""

import datetime as dt
import math

import numpy as np
import pytest
from pyproj import CRS, Geod, Transformer

from roi_network import sun
from roi_network.sun import (
    EARTH,
    MARS,
    SunError,
    earth_sun,
    earth_sun_at_jd,
    grid_azimuth_deg,
    grid_north,
    horizontal,
    local_solar_time_h,
    mars_sun,
    meridian_convergence_deg,
    noaa_refraction_deg,
    solar_day,
    sun_enu,
    sun_position,
    utc_at_solar_time,
    utc_on_date_at_solar_time,
)

UTC = dt.UTC
MARS_EXAMPLE_A = dt.datetime(2000, 1, 6, 0, 0, 0, tzinfo=UTC)  # millis 947116800000
MARS_EXAMPLE_B = 1073137591.0  # POSIX s: 2004-01-03 13:46:31 UTC
SPIRIT_EAST_LON = 360.0 - 184.702
SPIRIT_LAT = -14.640


def wrapped(a: float, b: float) -> float:
    """a - b in (-180, 180], degrees."""
    return (a - b + 180.0) % 360.0 - 180.0


def unit(last_decimals: int) -> float:
    """One unit of the last printed decimal: the published value's own rounding."""
    return 10.0 ** -last_decimals


# ----------------------------------------------------------------------------- Mars24


def test_mars24_example_a_matches_the_published_steps():
    m = mars_sun(MARS_EXAMPLE_A)
    assert sun.tt_minus_utc_s(MARS_EXAMPLE_A) == pytest.approx(64.184, abs=1e-9)
    assert m.jd_tt == pytest.approx(2451549.50074, abs=unit(5))
    assert m.dt_j2000_days == pytest.approx(4.50074, abs=unit(5))
    assert m.mean_anomaly_deg == pytest.approx(21.74558, abs=unit(5))  # B-1
    assert m.fms_deg == pytest.approx(272.74566, abs=unit(5))  # B-2
    assert m.perturbation_deg == pytest.approx(0.00142, abs=unit(5))  # B-3
    assert m.equation_of_center_deg == pytest.approx(4.44193, abs=unit(5))  # B-4
    assert m.ls_deg == pytest.approx(277.18758, abs=unit(5))  # B-5
    assert m.equation_of_time_deg == pytest.approx(-5.18774, abs=unit(5))  # C-1
    assert m.equation_of_time_deg / 15 == pytest.approx(-0.34585, abs=unit(5))
    assert m.mtc_h == pytest.approx(23.99425, abs=unit(5))  # C-2
    assert m.msd == pytest.approx(44795.99976, abs=unit(5))
    assert m.lmst_h(0.0) == pytest.approx(23.99425, abs=unit(5))  # C-3
    assert m.ltst_h(0.0) == pytest.approx(23.64840, abs=unit(5))  # C-4
    assert 360.0 - m.subsolar_longitude_deg == pytest.approx(174.72600, abs=unit(5))  # C-5, W
    assert m.subsolar_latitude_ographic_deg == pytest.approx(-25.22825, abs=unit(5))  # D-1


def test_mars24_example_b_spirit_matches_the_published_steps():
    m = mars_sun(MARS_EXAMPLE_B)
    assert m.jd_tt == pytest.approx(2453008.07471, abs=unit(5))
    assert m.dt_j2000_days == pytest.approx(1463.07471, abs=unit(5))
    assert m.mean_anomaly_deg == pytest.approx(66.06858, abs=unit(5))
    assert m.fms_deg == pytest.approx(317.09457, abs=unit(5))
    assert m.perturbation_deg == pytest.approx(0.01614, abs=unit(5))
    assert m.equation_of_center_deg == pytest.approx(10.22959, abs=unit(5))
    assert m.ls_deg == pytest.approx(327.32416, abs=unit(5))
    assert m.equation_of_time_deg / 15 == pytest.approx(-0.85170, abs=unit(5))
    assert m.mtc_h == pytest.approx(13.16537, abs=unit(5))
    assert m.lmst_h(SPIRIT_EAST_LON) == pytest.approx(0.85190, abs=unit(5))
    assert 360.0 - m.subsolar_longitude_deg == pytest.approx(4.70500, abs=unit(5))
    # The page prints LTST 0.00025 h, yet its own LMST + EOT is 0.85190 - 0.85170 = 0.00020
    # h; and its D-1 (-13.42065) and D-5 differ from their inputs in the fourth decimal.
    # Those three are held to 1e-4 h and 1e-3 deg.
    assert m.ltst_h(SPIRIT_EAST_LON) == pytest.approx(0.00025, abs=1e-4)
    assert m.subsolar_latitude_ographic_deg == pytest.approx(-13.42065, abs=1e-3)
    az, el = horizontal(m.subsolar_latitude_ographic_deg, SPIRIT_LAT,
                        15.0 * (m.ltst_h(SPIRIT_EAST_LON) - 12.0))
    assert 90.0 - el == pytest.approx(151.93895, abs=1e-3)  # D-5, solar zenith angle
    assert az == pytest.approx(179.99383, abs=unit(4))  # D-6, azimuth from north, clockwise


def test_mars_declination_is_the_directions_and_mars24s_adds_the_ographic_shift():
    m = mars_sun(MARS_EXAMPLE_A)
    assert m.declination_deg == pytest.approx(
        math.degrees(math.asin(0.42565 * math.sin(math.radians(m.ls_deg)))), abs=1e-12)
    # D-1's 0.25 deg sin(Ls) is the planetocentric -> planetographic latitude shift of the
    # point under the ray from the centre on the IAU 2015 ellipsoid (3396.19 x 3376.20 km),
    # to the 0.012 deg a coefficient rounded to 0.25 leaves.
    flat = (3376.20 / 3396.19) ** 2
    ographic = math.degrees(math.atan(math.tan(math.radians(m.declination_deg)) / flat))
    assert m.subsolar_latitude_ographic_deg == pytest.approx(ographic, abs=0.015)
    assert m.subsolar_latitude_ographic_deg - m.declination_deg < -0.24


def test_mars_perihelion_is_at_its_published_distance_and_season():
    days = np.arange(0.0, 687.0, 0.25) + 8000.0
    suns = [sun.mars_sun_at_tt(d) for d in days]
    r = np.array([s.distance_au for s in suns])
    i = int(np.argmin(r))
    assert r[i] == pytest.approx(1.3814, abs=5e-4)  # perihelion 206.6 Gm
    assert r.max() == pytest.approx(1.6660, abs=5e-4)  # aphelion 249.2 Gm
    assert suns[i].ls_deg == pytest.approx(251.0, abs=1.0)


# ----------------------------------------------------------------------------- Earth


def test_earth_matches_meeus_example_25a():
    e = earth_sun_at_jd(2448908.5)
    assert e.julian_century == pytest.approx(-0.072183436, abs=unit(9))
    assert e.mean_longitude_deg == pytest.approx(201.80720, abs=unit(5))
    assert e.mean_anomaly_deg == pytest.approx(-2241.00603, abs=unit(5))
    assert e.eccentricity == pytest.approx(0.016711668, abs=unit(9))
    assert e.equation_of_center_deg == pytest.approx(-1.89732, abs=unit(5))
    assert e.true_longitude_deg == pytest.approx(199.90988, abs=unit(5))
    assert e.distance_au == pytest.approx(0.99766, abs=unit(5))
    assert e.apparent_longitude_deg == pytest.approx(199.90895, abs=unit(5))
    assert e.obliquity_deg == pytest.approx(23.43999, abs=unit(5))
    assert e.right_ascension_deg == pytest.approx(-161.61917, abs=unit(5))
    assert e.declination_deg == pytest.approx(-7.78507, abs=unit(5))


NOAA_ROW = dt.datetime(2010, 6, 21, 7, 6, 0, tzinfo=UTC)  # 00:06 at time zone -7


def test_earth_matches_the_noaa_spreadsheet_row():
    e = earth_sun(NOAA_ROW)
    assert e.jd == pytest.approx(2455368.79583333, abs=1e-8)  # F
    assert e.right_ascension_deg == pytest.approx(89.8094800844214, abs=1e-9)  # S
    assert e.declination_deg == pytest.approx(23.4383706192869, abs=1e-9)  # T
    assert e.equation_of_time_min == pytest.approx(-1.71536757846953, abs=1e-9)  # V
    p = sun_position(EARTH, 40.0, -105.0, NOAA_ROW)
    assert p.elevation_deg == pytest.approx(-26.5537621191813, abs=1e-8)  # AE
    assert noaa_refraction_deg(p.elevation_deg) == pytest.approx(0.0115456865919242,
                                                                 abs=1e-10)  # AF
    assert p.apparent_elevation_deg == pytest.approx(-26.5422164325893, abs=1e-8)  # AG
    assert p.azimuth_deg == pytest.approx(1.09867118388445, abs=1e-7)  # AH
    assert not p.above_horizon


def test_earth_is_within_noaas_accuracy_of_nrel_spa():
    t = dt.datetime(2003, 10, 17, 19, 30, 30, tzinfo=UTC)
    p = sun_position(EARTH, 39.742476, -105.1786, t)
    e = earth_sun(t)
    # Residuals measured: declination 0.0015, hour angle 0.0022, azimuth 0.0023,
    # elevation 0.00003 deg (SPA's topocentric e0 carries 0.002 deg of parallax), EOT 0.3 s.
    assert e.declination_deg == pytest.approx(-9.31434, abs=0.005)
    assert p.hour_angle_deg == pytest.approx(11.10590, abs=0.005)
    assert p.azimuth_deg == pytest.approx(194.34024, abs=0.005)
    assert p.elevation_deg == pytest.approx(39.872046, abs=0.005)
    assert e.equation_of_time_min == pytest.approx(14.641503, abs=0.01)
    # SPA's zenith 50.11162 has refraction for 820 mbar, 11 C; NOAA's is for 1010 mbar.
    assert 90.0 - p.apparent_elevation_deg == pytest.approx(50.11162, abs=0.005)


def test_refraction_is_continuous_and_vanishes_overhead():
    for edge in (-0.575, 5.0):
        assert noaa_refraction_deg(edge - 1e-9) == pytest.approx(noaa_refraction_deg(edge + 1e-9),
                                                                 abs=2e-3)
    assert noaa_refraction_deg(0.0) == pytest.approx(1735 / 3600)  # 29 arcmin at the horizon
    assert noaa_refraction_deg(89.0) == 0.0
    assert noaa_refraction_deg(45.0) == pytest.approx(0.016, abs=1e-3)


# ----------------------------------------------------------------------------- the local sky


@pytest.mark.parametrize("body", [EARTH, MARS])
def test_the_enu_vector_is_unit_and_points_east_in_the_morning(body):
    day = solar_day(body, -69.95, dt.datetime(2024, 3, 20, 12, tzinfo=UTC))
    for hours, east in ((9.0, True), (15.0, False)):
        t = utc_at_solar_time(body, -69.95, day, hours)
        p = sun_position(body, -24.1, -69.95, t)
        v = p.enu()
        assert np.linalg.norm(v) == pytest.approx(1.0, abs=1e-12)
        assert (v[0] > 0) == east and p.above_horizon
        assert math.degrees(math.atan2(v[0], v[1])) % 360 == pytest.approx(p.azimuth_deg)
        assert math.degrees(math.asin(v[2])) == pytest.approx(p.apparent_elevation_deg)
        np.testing.assert_allclose(sun_enu(body, -24.1, -69.95, t.timestamp()), v, atol=1e-12)


@pytest.mark.parametrize("body", [EARTH, MARS])
def test_at_true_solar_noon_the_sun_is_on_the_meridian_at_its_declination(body):
    t = utc_on_date_at_solar_time(body, 137.4, dt.date(2025, 7, 1), 12.0)
    for lat in (-40.0, 60.0):
        p = sun_position(body, lat, 137.4, t)
        assert p.hour_angle_deg == pytest.approx(0.0, abs=1e-7)
        assert p.elevation_deg == pytest.approx(90.0 - abs(lat - p.declination_deg), abs=1e-7)
        south = 180.0 if lat > p.declination_deg else 0.0
        assert wrapped(p.azimuth_deg, south) == pytest.approx(0.0, abs=1e-6)


def test_mars_sun_is_lower_on_the_ellipsoid_reading_by_the_ographic_shift():
    # Mars24 D-5 takes D-1's planetographic latitude for the declination; the direction's
    # own declination puts the sun 0.135 deg lower at Spirit's midnight (0.25 deg sin Ls).
    m = mars_sun(MARS_EXAMPLE_B)
    p = sun_position(MARS, SPIRIT_LAT, SPIRIT_EAST_LON, MARS_EXAMPLE_B)
    _, el_mars24 = horizontal(m.subsolar_latitude_ographic_deg, SPIRIT_LAT, p.hour_angle_deg)
    assert el_mars24 - p.elevation_deg == pytest.approx(
        -0.25 * math.sin(math.radians(m.ls_deg)), abs=2e-3)
    assert p.apparent_elevation_deg == p.elevation_deg  # no refraction on Mars


# ----------------------------------------------------------------------------- solar time


@pytest.mark.parametrize("body", [EARTH, MARS])
@pytest.mark.parametrize("lon", [-179.5, -69.95, 0.0, 137.4, 335.45])
@pytest.mark.parametrize("hours", [0.01, 6.5, 12.0, 23.99])
def test_the_utc_of_a_solar_time_reads_back_that_time(body, lon, hours):
    day = solar_day(body, lon, dt.datetime(2026, 2, 1, tzinfo=UTC)) + 3
    for true_solar in (True, False):
        t = utc_at_solar_time(body, lon, day, hours, true_solar)
        read = local_solar_time_h(body, lon, t, true_solar)
        assert (read - hours + 12) % 24 - 12 == pytest.approx(0.0, abs=1e-6)  # 4 ms
    t = utc_at_solar_time(body, lon, day, hours, true_solar=False)
    assert solar_day(body, lon, t) == day


def test_mars24_example_b_inverts_to_its_epoch():
    day = solar_day(MARS, SPIRIT_EAST_LON, MARS_EXAMPLE_B)
    t = utc_at_solar_time(MARS, SPIRIT_EAST_LON, day, 0.85190, true_solar=False)
    assert t.timestamp() == pytest.approx(MARS_EXAMPLE_B, abs=0.4)  # 1e-5 h of a sol


def test_a_date_is_the_local_date_on_earth():
    for lon in (-179.0, -69.95, 0.0, 179.0):
        t = utc_on_date_at_solar_time(EARTH, lon, dt.date(2024, 12, 31), 23.5, False)
        local = t + dt.timedelta(hours=lon / 15.0, milliseconds=1)
        assert (local.date(), local.hour, local.minute) == (dt.date(2024, 12, 31), 23, 30)


def test_a_date_is_a_sol_on_mars_and_sols_advance_with_dates():
    start = dt.date(2021, 2, 18)
    sols = [solar_day(MARS, 77.45, utc_on_date_at_solar_time(MARS, 77.45, start + dt.timedelta(d),
                                                             12.0, False))
            for d in range(80)]
    steps = np.diff(sols)
    assert set(steps.tolist()) == {0, 1} and int(np.sum(steps == 0)) == 2  # 79 / 37.5


def test_posix_seconds_and_aware_datetimes_agree():
    t = dt.datetime(2019, 5, 4, 15, 0, tzinfo=dt.timezone(dt.timedelta(hours=-4)))
    a = sun_position(MARS, 18.2, -24.55, t)
    b = sun_position(MARS, 18.2, -24.55, t.timestamp())
    assert a == b
    assert sun.julian_day_ut(t) == pytest.approx(sun.JD_POSIX_EPOCH + t.timestamp() / 86400)


@pytest.mark.parametrize("call, message", [
    (lambda: sun_position("venus", 0, 0, 0.0), "body: 'venus' is not one of earth, mars"),
    (lambda: sun_position(EARTH, 91, 0, 0.0), "lat_deg: 91.0 is outside [-90, 90]"),
    (lambda: sun_position(EARTH, 0, float("nan"), 0.0), "lon_deg: must be finite"),
    (lambda: sun_position(EARTH, 0, 0, dt.datetime(2020, 1, 1)), "utc: naive datetime"),
    (lambda: sun_position(EARTH, 0, 0, "noon"), "utc: expected a datetime or POSIX seconds"),
    (lambda: sun_position(MARS, 0, 0, 0.0), "before 1972-01-01"),
    (lambda: utc_at_solar_time(MARS, 0, 50000, 24.0), "hours: 24.0 is outside [0, 24)"),
    (lambda: utc_on_date_at_solar_time(EARTH, 0, "2020-01-01", 12), "date: expected"),
    (lambda: utc_at_solar_time(EARTH, 0, 2.5e6, 12), "day: expected an integer"),
])
def test_bad_input_is_named(call, message):
    with pytest.raises(SunError, match=None) as err:
        call()
    assert message in str(err.value)


# ----------------------------------------------------------------------------- grid north


def test_convergence_sign_east_of_a_utm_central_meridian():
    # Zone 33N (central meridian 15 E) at 17 E 45 N: grid north lies east of true north by
    # about dlon sin(lat) = 1.41 deg; PROJ reports it positive, true north at grid -1.41.
    gamma = meridian_convergence_deg("EPSG:32633", 17.0, 45.0)
    spherical = math.degrees(math.atan(math.tan(math.radians(2.0)) * math.sin(math.radians(45))))
    assert gamma > 0 and gamma == pytest.approx(spherical, abs=0.002)
    assert grid_azimuth_deg(0.0, "EPSG:32633", 17.0, 45.0) == pytest.approx(360.0 - gamma)
    # Atacama, zone 19S (central meridian 69 W), east of it at 66 W: the sign flips.
    assert meridian_convergence_deg("EPSG:32719", -66.0, -24.1) < 0
    assert meridian_convergence_deg("EPSG:32719", -69.0, -24.1) == pytest.approx(0.0, abs=1e-9)


def _grid_azimuth_by_projection(crs, lon, lat, azimuth, geod):
    """Grid azimuth of a 0.2 m step along a geodesic leaving at ``azimuth``."""
    tr = Transformer.from_crs(CRS(crs).geodetic_crs, CRS(crs), always_xy=True)
    lon1, lat1, _ = geod.fwd(lon, lat, azimuth + 180.0, 0.1)
    lon2, lat2, _ = geod.fwd(lon, lat, azimuth, 0.1)
    (x1, x2), (y1, y2) = tr.transform([lon1, lon2], [lat1, lat2])
    return math.degrees(math.atan2(x2 - x1, y2 - y1)) % 360.0


MARS_SPHERE = Geod(a=3396190.0, b=3396190.0)


@pytest.mark.parametrize("crs, lon, lat, geod", [
    ("EPSG:32719", -66.0, -24.1, Geod(ellps="WGS84")),
    ("EPSG:32633", 17.0, 45.0, Geod(ellps="WGS84")),
    ("IAU_2015:49910", -24.55, 18.2, MARS_SPHERE),  # equirectangular: no convergence, stretch
    ("IAU_2015:49960", -24.55, 18.2, MARS_SPHERE),  # transverse Mercator on the sphere
    ("+proj=tmerc +lon_0=-27 +R=3396190 +units=m +type=crs", -24.55, 18.2, MARS_SPHERE),
    ("IAU_2015:49920", -24.55, 18.2, MARS_SPHERE),  # sinusoidal: not conformal
])
def test_grid_azimuth_is_the_projected_direction(crs, lon, lat, geod):
    g = grid_north(crs, lon, lat)
    for azimuth in (0.0, 30.0, 90.0, 135.0, 200.0, 315.0):
        expected = _grid_azimuth_by_projection(crs, lon, lat, azimuth, geod)
        got = g.grid_azimuth_deg(azimuth)
        assert wrapped(got, expected) == pytest.approx(0.0, abs=1e-5), azimuth
        assert wrapped(g.true_azimuth_deg(got), azimuth) == pytest.approx(0.0, abs=1e-9)


def test_the_projects_mars_crs_has_no_convergence_but_stretches_diagonals():
    g = grid_north("IAU_2015:49910", -24.55, 18.2)
    assert g.convergence_deg == pytest.approx(0.0, abs=1e-12)
    assert g.grid_azimuth_deg(90.0) == pytest.approx(90.0)
    # x is stretched by 1 / cos(lat): 45 deg true is 46.47 deg grid at Oxia Planum.
    expected = math.degrees(math.atan(1.0 / math.cos(math.radians(18.2))))
    assert g.grid_azimuth_deg(45.0) == pytest.approx(expected, abs=1e-6)


def test_enu_to_grid_keeps_a_unit_vector_and_its_elevation():
    g = grid_north("EPSG:32719", -66.0, -24.1)
    v = sun_enu(EARTH, -24.1, -66.0, dt.datetime(2024, 1, 10, 14, tzinfo=UTC))
    w = g.enu_to_grid(v)
    assert np.linalg.norm(w) == pytest.approx(1.0, abs=1e-12) and w[2] == v[2]
    true_az = math.degrees(math.atan2(v[0], v[1]))
    assert math.degrees(math.atan2(w[0], w[1])) % 360 == pytest.approx(
        g.grid_azimuth_deg(true_az), abs=1e-9)
    assert np.array_equal(g.enu_to_grid([0.0, 0.0, 1.0]), [0.0, 0.0, 1.0])


@pytest.mark.parametrize("crs, message", [
    ("IAU_2015:49900", "is not a projected CRS"),
    ("IAU_2015:49916", "has axes west, north"),
    ("EPSG:999999", "unknown CRS 'EPSG:999999'"),
    ("EPSG:32719", "cannot project lon 100.0, lat 0.0"),  # 169 deg off its meridian
])
def test_a_crs_grid_north_cannot_use_is_named(crs, message):
    with pytest.raises(SunError) as err:
        grid_north(crs, 100.0 if "cannot" in message else 0.0, 0.0)
    assert message in str(err.value)
