"""The sun heading filter on its own (no images): a straight drive whose gyro has a bias,
sun vectors synthesised from the ephemeris, the rover.yaml setup and its errors."""

from __future__ import annotations

import math

import numpy as np
import pytest

from rover_vo import sun_heading as sh
from rover_vo.state import OdomState, step_noise, systematic_prior

#: The simulator's Atacama site and a morning epoch (sun ~37 deg up, rover.yaml's keys).
SITE = {"site.body": "earth", "site.crs": "EPSG:32719", "site.latitude_deg": -24.1,
        "site.longitude_deg": -69.95, "site.epoch_ns": 1683296311000000000}
SENSOR = {"sun_sensor.frame": "sun_sensor",
          "sun_sensor.base_to_sensor": [-0.4, 0.3, 0.75, 0.0, 0.0, 0.0, 1.0],
          "sun_sensor.noise_deg": 0.05, "sun_sensor.bias_deg": 0.1, "sun_sensor.rate_hz": 5.0,
          "sun_sensor.fov_half_angle_deg": 60.0}
PSI0_TRUE = math.radians(40.0)  # the true grid yaw of the odom frame's x axis


def site() -> sh.Site:
    s, why = sh.Site.from_params(SITE)
    assert why is None
    return s


def sun_in_body(s: sh.Site, utc: float, body_grid_yaw: float, rng, noise_deg: float
                ) -> np.ndarray:
    """The unit sun vector a level body at ``body_grid_yaw`` sees, with angle noise."""
    alpha, el = s.sun_grid(utc)
    v = np.array([math.cos(el) * math.cos(alpha), math.cos(el) * math.sin(alpha),
                  math.sin(el)])
    v = sh.rotz(-body_grid_yaw) @ v
    ang = np.array([math.atan2(v[0], v[2]), math.atan2(v[1], v[2])])
    ang += np.radians(noise_deg) * rng.standard_normal(2)
    w = np.array([math.tan(ang[0]), math.tan(ang[1]), 1.0])
    return w / np.linalg.norm(w)


def drive(with_sun: bool, metres: int = 1000, seed: int = 3):
    """1 m/s straight ahead (truth: yaw 0 in odom) for ``metres`` s; the odometry turns
    by a gyro bias of 1e-5 rad/s. Returns (heading errors deg, their 1-sigmas, final
    state, filter)."""
    rng = np.random.default_rng(seed)
    s = site()
    sensor = sh.SunSensorModel.from_params(SENSOR)
    f = sh.SunHeading(sensor, s)
    state = OdomState(0.0, P=systematic_prior(0.003, 0.05))
    errors, sigmas = [], []
    bias = 1e-5
    for k in range(1, metres + 1):
        Q = step_noise(1.0, 0.01, 0.02)
        state = state.compose(float(k), sh.rotz(bias), np.array([1.0, 0.0, 0.0]), Q)
        if with_sun:
            v = sun_in_body(s, s.epoch_s + k, PSI0_TRUE, rng, 0.05)
            m = f.measure(s.epoch_s + k, v, np.eye(3), state.R)
            assert m.problem is None
            f.apply(m, state)
        yaw = math.atan2(state.R[1, 0], state.R[0, 0])
        psi0 = f.psi0 if f.psi0 is not None else PSI0_TRUE
        errors.append(math.degrees(sh.wrap(yaw + psi0 - PSI0_TRUE)))
        sigmas.append(f.heading_sigma_deg(state.P) if with_sun
                      else math.degrees(math.sqrt(state.P[5, 5])))
    return np.array(errors), np.array(sigmas), state, f


def test_sun_bounds_the_heading_of_a_drive_with_a_gyro_bias():
    free, _, free_state, _ = drive(with_sun=False)
    sun, sigma, sun_state, f = drive(with_sun=True)
    # without the sun the bias turns the heading by 1e-5 rad/s * 1000 s = 0.57 deg
    assert abs(free[-1]) > 0.5
    assert abs(free[-1]) > abs(free[len(free) // 2]) + 0.2  # and it keeps growing
    # with the sun the heading error stays small all along, inside its 3 sigma (at one
    # heading the bias states cannot be told from psi0 and take a little of the drift)
    assert np.max(np.abs(sun[10:])) < 0.3
    assert np.all(np.abs(sun) <= 3 * sigma + 1e-9)
    assert f.updates == 999 and f.rejected == 0
    # the odometry's own yaw variance says so: bounded, below the free drive's
    assert sun_state.P[5, 5] < free_state.P[5, 5]
    half = drive(with_sun=True, metres=500)[2]
    # (the consider states' share changes with the sun's path: a little growth, no drift)
    assert sun_state.P[5, 5] <= half.P[5, 5] * 1.5 < free_state.P[5, 5] / 50
    # only the heading moved: the position follows the same straight line
    assert abs(sun_state.p[0] - free_state.p[0]) < 0.1


def test_a_contradicting_sample_is_rejected_and_counted():
    rng = np.random.default_rng(1)
    s = site()
    f = sh.SunHeading(sh.SunSensorModel.from_params(SENSOR), s)
    state = OdomState(0.0, P=systematic_prior(0.003, 0.05))
    for k in range(5):
        m = f.measure(s.epoch_s + k, sun_in_body(s, s.epoch_s + k, PSI0_TRUE, rng, 0.05),
                      np.eye(3), state.R)
        assert f.apply(m, state) in ("initialized", "updated")
    R_before = state.R.copy()
    m = f.measure(s.epoch_s + 6, sun_in_body(s, s.epoch_s + 6, PSI0_TRUE + math.radians(5),
                                             rng, 0.05), np.eye(3), state.R)
    assert f.apply(m, state) == "rejected"
    assert f.rejected == 1 and np.array_equal(state.R, R_before)


def test_the_reference_turns_with_the_state_about_the_rover():
    s = site()
    f = sh.SunHeading(sh.SunSensorModel.from_params(SENSOR), s)
    ref = OdomState(0.0, P=systematic_prior(0.003, 0.05))
    rng = np.random.default_rng(2)
    f.apply(f.measure(s.epoch_s, sun_in_body(s, s.epoch_s, PSI0_TRUE, rng, 0), np.eye(3),
                      ref.R), ref)
    # the reference to the rover: a step whose heading is 2 deg uncertain (drift)
    dR, dp = sh.rotz(0.01), np.array([0.3, 0.0, 0.0])
    Q = step_noise(0.3, 0.01, 0.02)
    Q[5, 5] = math.radians(2.0) ** 2
    cur = ref.compose(1.0, dR, dp, Q)
    # a sample that puts the rover 0.5 deg right of the estimate: the state turns toward
    # it, the reference with it (the next vision frame composes from it), the position
    # stays
    v = sun_in_body(s, s.epoch_s + 1, PSI0_TRUE + 0.01 - math.radians(0.5), rng, 0)
    p_before = cur.p.copy()
    m = f.measure(s.epoch_s + 1, v, np.eye(3), cur.R)
    assert f.apply(m, cur, ref) == "updated"
    assert np.array_equal(cur.p, p_before)
    yaw = math.atan2(cur.R[1, 0], cur.R[0, 0])
    assert 0.01 - math.radians(0.5) < yaw < 0.01 - math.radians(0.4)
    again = ref.compose(1.0, dR, dp, Q)
    assert np.allclose(again.R, cur.R) and np.allclose(again.p, cur.p)
    assert cur.P[5, 5] < math.radians(0.3) ** 2  # the yaw's variance came down


def test_the_azimuth_variance_grows_toward_the_zenith():
    s = site()
    f = sh.SunHeading(sh.SunSensorModel.from_params(SENSOR), s)
    v_low = np.array([math.cos(math.radians(20)), 0.0, math.sin(math.radians(20))])
    low = f.measure(s.epoch_s, v_low, np.eye(3), np.eye(3))
    high_el = math.radians(60)
    v_high = np.array([math.cos(high_el), 0.0, math.sin(high_el)])
    high = f.measure(s.epoch_s, v_high, np.eye(3), np.eye(3))
    # a level zenith-pointing sensor, the sun due +x: the angle about y (ay = 0) turns the
    # azimuth by tan(el), the other (ax = 90 deg - el) not at all; a tilt about the sun's
    # horizontal direction (body x) by tan(el) too, one about y only moves the elevation
    el = math.radians(20)
    row = low.bias_row
    assert abs(row[0]) < 1e-6 and abs(row[3]) < 1e-6
    assert abs(row[1]) == pytest.approx(math.tan(el), rel=1e-3)
    assert abs(row[2]) == pytest.approx(math.tan(el), rel=1e-3)
    assert abs(high.bias_row[2]) == pytest.approx(math.tan(high_el), rel=1e-3)
    # the total variance: the white part plus each consider state's share
    prior = sh.bias_prior(f.sensor)
    assert low.variance == pytest.approx(low.white_variance + float(row**2 @ prior))
    assert high.variance > low.variance
    # a site and time with the sun ~88 deg up: too high to give a heading
    near = dict(SITE, **{"site.latitude_deg": 16.3, "site.longitude_deg": -69.95,
                         "site.crs": "EPSG:32619"})
    s2, _ = sh.Site.from_params(near)
    noon = max((s.epoch_s + 60.0 * k for k in range(300)), key=lambda t: s2.sun_grid(t)[1])
    alpha, el2 = s2.sun_grid(noon)
    f2 = sh.SunHeading(f.sensor, s2)
    v = np.array([math.cos(el2) * math.cos(alpha), math.cos(el2) * math.sin(alpha),
                  math.sin(el2)])
    m = f2.measure(noon, v, np.eye(3), np.eye(3))
    assert math.degrees(el2) > 85 and m.problem == "near_zenith"


def stop_and_go(bias_deg: tuple[float, float], tilt_deg: tuple[float, float],
                headings_deg: tuple[float, ...], samples: int = 60, seed: int = 5,
                leg_error_deg: float = 0.3, rotation_sigma_deg_per_sqrt_m: float = 0.05):
    """Stops at several headings (a level body, truth yaw in odom = heading), 20 m apart:
    at each, ``samples`` sun samples through a sensor whose two angles carry a constant
    bias, the gravity tilt a constant body-frame error. The odometry turns to each heading
    with ``leg_error_deg`` of error, its model says ``rotation_sigma_deg_per_sqrt_m``.
    Returns each update's grid heading error and 1-sigma (deg), and the filter."""
    rng = np.random.default_rng(seed)
    s = site()
    f = sh.SunHeading(sh.SunSensorModel.from_params(SENSOR), s)
    state = OdomState(0.0, P=systematic_prior(0.003, 0.05))
    tilt = sh.small_rotation(*np.radians(tilt_deg))
    errors, sigmas = [], []
    t = s.epoch_s
    for heading in np.radians(headings_deg):
        # drive to the stop: the odometry turns to the heading with an error
        turn = heading - math.atan2(state.R[1, 0], state.R[0, 0]) + math.radians(leg_error_deg)
        Q = step_noise(20.0, 0.01, rotation_sigma_deg_per_sqrt_m)
        state = state.compose(state.t + 130.0, sh.rotz(turn), np.array([20.0, 0, 0]), Q)
        t += 130.0
        for _ in range(samples):
            t += 1.0
            body_yaw = PSI0_TRUE + heading
            v = sun_in_body(s, t, body_yaw, rng, 0.0)
            ang = sh.sensor_angles(v) + np.radians(bias_deg)
            ang += np.radians(0.05) * rng.standard_normal(2)
            m = f.measure(t, sh.angles_vector(ang), np.eye(3), state.R @ tilt)
            assert m.problem is None
            assert f.apply(m, state) in ("initialized", "updated")
            yaw = math.atan2(state.R[1, 0], state.R[0, 0])
            errors.append(math.degrees(sh.wrap(yaw + f.psi0 - body_yaw)))
            sigmas.append(f.heading_sigma_deg(state.P))
    return np.array(errors), np.array(sigmas), f


def test_a_biased_sensor_and_tilt_stay_inside_the_heading_sigma():
    # 1-sigma biases of the sensor (0.1 deg) and of the gravity tilt (0.115 deg) over
    # stops at four headings: the errors do not average out, and the sigma says so
    errors, sigmas, f = stop_and_go((0.1, -0.1), (0.115, 0.115), (0.0, 90.0, 180.0, 270.0))
    assert f.rejected == 0
    assert np.max(np.abs(errors)) > 0.1  # the biases show
    assert np.all(np.abs(errors) <= 3 * sigmas)
    # the sigma does not shrink with the number of samples below the biases' share
    assert sigmas[-1] > 0.08
    # without biases the same stops give a heading within 0.1 deg
    clean, _, _ = stop_and_go((0.0, 0.0), (0.0, 0.0), (0.0, 90.0, 180.0, 270.0))
    assert np.max(np.abs(clean[5:])) < 0.1


def test_stops_at_other_headings_estimate_the_biases():
    # a 0.23 deg sensor bias (the demo bag's draw) and 2 mg of accelerometer bias. Each
    # bias turns the sun in the body frame, so its share of the azimuth follows the
    # heading: at one heading it is psi0's, and stops at other headings, joined by an
    # odometry that turns as well as rover_vo's (0.03 deg per 20 m leg), tell them apart.
    headings = (0.0, 90.0, 180.0, 270.0, 45.0, 135.0, 225.0, 315.0)
    errors, sigmas, f = stop_and_go((-0.23, 0.01), (-0.1, 0.1), headings, leg_error_deg=0.03,
                                    rotation_sigma_deg_per_sqrt_m=0.01)
    per_stop = np.abs(errors).reshape(len(headings), -1).max(axis=1)
    assert f.rejected == 0 and np.all(np.abs(errors) <= 3 * sigmas)
    assert per_stop[0] > 0.12  # the first stop: the biases are psi0's
    assert np.all(per_stop[2:] < 0.1)  # from the third heading on: within 0.1 deg
    assert sigmas[-1] < 0.5 * sigmas[0]  # and the sigma says so
    assert np.abs(f.bias).max() > np.radians(0.03)  # the bias states moved


def test_impossible_vectors_are_not_the_sun():
    s = site()
    f = sh.SunHeading(sh.SunSensorModel.from_params(SENSOR), s)
    # the elevation 10 deg off the ephemeris'
    alpha, el = s.sun_grid(s.epoch_s)
    e = el + math.radians(10)
    v = np.array([math.cos(e) * math.cos(alpha), math.cos(e) * math.sin(alpha), math.sin(e)])
    m = f.measure(s.epoch_s, v, np.eye(3), np.eye(3))
    assert m.problem == "elevation_mismatch" and "ephemeris" in m.detail
    # at night (12 h later) any vector is impossible
    m = f.measure(s.epoch_s + 12 * 3600, np.array([0.0, 0.0, 1.0]), np.eye(3), np.eye(3))
    assert m.problem == "below_horizon" and "below the horizon" in m.detail


def test_vector_problems():
    assert sh.vector_problem(np.array([0.0, 0.0, 1.0])) is None
    assert sh.vector_problem(np.array([0.0, math.nan, 1.0])) == "sun_nan"
    assert sh.vector_problem(np.array([0.0, 0.0, 1.1])) == "sun_not_unit"


def test_rover_yaml_sensor_and_site_errors_are_named():
    assert sh.SunSensorModel.from_params({}) is None
    with pytest.raises(sh.SunSetupError, match=r"sun_sensor\.base_to_sensor"):
        sh.SunSensorModel.from_params({k: v for k, v in SENSOR.items()
                                       if k != "sun_sensor.base_to_sensor"})
    with pytest.raises(sh.SunSetupError, match=r"sun_sensor\.noise_deg"):
        sh.SunSensorModel.from_params(dict(SENSOR, **{"sun_sensor.noise_deg": -1.0}))
    site_, why = sh.Site.from_params({k: v for k, v in SITE.items()
                                      if k not in ("site.latitude_deg", "site.epoch_ns")})
    assert site_ is None
    assert "site.latitude_deg, site.epoch_ns" in why
    site_, why = sh.Site.from_params(dict(SITE, **{"site.body": "venus"}))
    assert site_ is None and "site.body" in why and "venus" in why


def test_grid_heading_error_adds_the_odom_frames_grid_yaw(tmp_path):
    from rover_vo.evaluation import grid_heading_error_deg

    def tum(path, rows):
        lines = []
        for t, yaw_deg in rows:
            h = math.radians(yaw_deg) / 2
            lines.append(f"{t} 0 0 0 0 0 {math.sin(h)} {math.cos(h)}")
        path.write_text("\n".join(lines) + "\n")
        return path

    truth = tum(tmp_path / "truth.tum", [(0.0, 133.0), (10.0, 10.0), (20.0, 179.9)])
    est = tum(tmp_path / "vo.tum", [(0.0, 0.0), (10.2, -123.0)])
    # the last estimate (t 10.2) meets the truth row nearest it (t 10): -123 + 133.3 - 10
    assert grid_heading_error_deg(est, truth, 133.3) == pytest.approx(0.3, abs=1e-9)
    est = tum(tmp_path / "vo2.tum", [(0.0, 0.0), (19.9, 46.7)])
    # wrapped: 46.7 + 133.0 - 179.9 = -0.2
    assert grid_heading_error_deg(est, truth, 133.0) == pytest.approx(-0.2, abs=1e-9)
