"""atacama_sim's sky and sun sensor without rendering: the epoch and the sun's path, the
sensor's outages (night, field of view, the mast's shadow), its noise and bias."""

from __future__ import annotations

import datetime as dt
from types import SimpleNamespace

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from atacama_sim.camera import mast_kinematics
from atacama_sim.config import SunSensorConfig, make_config
from atacama_sim.route import Trajectory
from atacama_sim.sky import Sky, site_body
from atacama_sim.sunsensor import (
    NIGHT,
    OK,
    OUTSIDE_FOV,
    SHADOWED,
    base_T_sensor,
    mast_shadows,
    measure,
    sample_step,
    simulate_sun_sensor,
)
from atacama_sim.world import map_origin
from roi_network import sun as ephemeris

RATE = 50.0


def _sky(overrides: dict | None = None) -> Sky:
    cfg = make_config("quick", 1, overrides)
    return Sky.from_config(cfg, map_origin(cfg.site.crs, cfg.site.site_lonlat))


def _still(rotation: Rotation, seconds: float = 4.0) -> Trajectory:
    """The rover standing at the map origin with attitude ``rotation``."""
    t = np.arange(0, seconds, 1 / RATE)
    q = np.tile(rotation.as_quat(), (len(t), 1))
    return Trajectory(t, np.zeros((len(t), 3)), q, np.zeros(len(t)), np.zeros(len(t), bool))


def _mast(traj: Trajectory, pan: float = 0.0, tilt: float = 0.35) -> SimpleNamespace:
    return SimpleNamespace(pan=np.full(len(traj.t), pan), tilt=np.full(len(traj.t), tilt))


def _run(sky: Sky, traj: Trajectory, pan: float = 0.0, cfg: SunSensorConfig | None = None,
         seed: int = 1):
    cfg = cfg or SunSensorConfig()
    return simulate_sun_sensor(cfg, sky, traj, _mast(traj, pan),
                               mast_kinematics(make_config("quick").camera), RATE, seed)


def test_the_epoch_is_the_local_solar_time_of_the_config_and_keeps_the_demo_light():
    """The bag starts at sun.local_solar_time_h of sun.date at the site; the default puts
    the sun at today's demo lighting (35 deg grid azimuth, 42 deg up) half way through
    the quick bag (3709 s)."""
    sky = _sky()
    assert sky.body == "earth" and sky.start_ns % 1_000_000_000 == 0
    assert sky.start_utc.date() == dt.date(2023, 5, 5)
    ltst = ephemeris.local_solar_time_h("earth", sky.lon_deg, sky.start_ns * 1e-9)
    assert ltst == pytest.approx(9.70, abs=1 / 3600)
    v, el = sky.sun_map(3709 / 2)
    assert np.degrees(np.arctan2(v[0], v[1])) == pytest.approx(35.0, abs=0.5)
    assert el == pytest.approx(42.0, abs=0.5)
    v0, el0 = sky.sun_map(0.0)
    assert el0 < el - 3 and np.linalg.norm(v0) == pytest.approx(1.0)


def test_the_sun_in_the_map_is_the_ephemeris_in_grid_axes():
    """sun_map at a point is roi_network.sun's ENU vector at that point's lon/lat, turned
    by the CRS's grid north there (UTM 19S east of its meridian: 0.39 deg)."""
    sky = _sky()
    t, xy = 1234.5, np.array([250.0, -180.0])
    lon, lat = sky.lonlat(xy)[0]
    assert (lon, lat) != pytest.approx((sky.lon_deg, sky.lat_deg), abs=1e-4)
    pos = ephemeris.sun_position("earth", lat, lon, sky.start_ns * 1e-9 + t)
    grid = ephemeris.grid_north("EPSG:32719", lon, lat)
    v, el = sky.sun_map(t, xy)
    # grid north is taken on a 1e-4 deg lattice: 1e-5 deg of convergence at most
    np.testing.assert_allclose(v, grid.enu_to_grid(pos.enu()), atol=1e-6)
    assert el == pytest.approx(pos.apparent_elevation_deg)
    az_true = np.degrees(np.arctan2(pos.enu()[0], pos.enu()[1]))
    assert np.degrees(np.arctan2(v[0], v[1])) - az_true == pytest.approx(
        -grid.convergence_deg, abs=0.02)


def test_the_body_is_the_crs_ellipsoids_and_a_bad_one_is_named():
    assert site_body("EPSG:32719") == "earth"
    assert site_body("IAU_2015:49910") == "mars"
    mars = _sky({"site": {"crs": "IAU_2015:49910", "site_lonlat": (-24.55, 18.2)}})
    assert mars.body == "mars"
    assert ephemeris.local_solar_time_h("mars", -24.55, mars.start_ns * 1e-9) == \
        pytest.approx(9.70, abs=0.01)
    with pytest.raises(ValueError, match=r"site\.crs: 'ESRI:103881' .* neither Earth's "
                                         r"nor Mars'"):
        site_body("ESRI:103881")
    with pytest.raises(ValueError, match=r"sun\.date: expected a date YYYY-MM-DD, got "
                                         r"'5 May'"):
        _sky({"sun": {"date": "5 May"}})
    with pytest.raises(ValueError, match=r"sun\.local_solar_time_h: 24\.0 is outside"):
        _sky({"sun": {"local_solar_time_h": 24.0}})
    # --set reads a date value as YAML does: kept as its text
    assert make_config("quick", 1, {"sun": {"date": dt.date(2023, 8, 8)}}).sun.date == \
        "2023-08-08"


def test_the_rate_divides_the_motion_grid():
    assert sample_step(SunSensorConfig(rate_hz=5.0), RATE) == 10
    assert sample_step(SunSensorConfig(rate_hz=10.0), RATE) == 5
    with pytest.raises(ValueError, match=r"sun_sensor\.rate_hz: 3 Hz does not divide the "
                                         r"IMU's 50 Hz"):
        sample_step(SunSensorConfig(rate_hz=3.0), RATE)
    with pytest.raises(ValueError, match=r"sun_sensor\.rate_hz: 0\.0 Hz must be positive"):
        sample_step(SunSensorConfig(rate_hz=0.0), RATE)


def test_a_level_rover_reads_the_ephemeris_within_noise_and_bias():
    """Level rover heading 160 deg left of grid east: each angle's error is the bag's bias
    plus white noise of the datasheet's sigma; the vector is the ephemeris in the sensor
    frame."""
    sky = _sky()
    yaw = Rotation.from_euler("z", 160, degrees=True)
    traj = _still(yaw, seconds=200.0)
    data = _run(sky, traj)
    assert len(data.idx) == 1000 and np.all(data.reason == OK)
    sun_map, _ = sky.sun_map_many(traj.t[data.idx], np.zeros((len(data.idx), 2)))
    truth = yaw.inv().apply(sun_map)
    np.testing.assert_allclose(data.truth, truth, atol=2e-4)  # the sensor is 0.5 m away
    m, t = data.measured, data.truth
    err = np.degrees(np.column_stack([np.arctan2(m[:, 0], m[:, 2]) - np.arctan2(t[:, 0], t[:, 2]),
                                      np.arctan2(m[:, 1], m[:, 2]) - np.arctan2(t[:, 1], t[:, 2])]))
    bias = np.degrees(data.bias_rad)
    np.testing.assert_allclose(err.mean(axis=0), bias, atol=4 * 0.05 / np.sqrt(1000))
    np.testing.assert_allclose(err.std(axis=0), [0.05, 0.05], rtol=0.1)
    assert np.all(np.abs(bias) < 0.4) and np.any(np.abs(bias) > 1e-4)
    np.testing.assert_allclose(np.linalg.norm(m, axis=1), 1.0, atol=1e-12)
    # another seed, another bias; the same seed, the same readings
    assert not np.allclose(_run(sky, traj, seed=2).bias_rad, data.bias_rad)
    np.testing.assert_array_equal(_run(sky, traj).measured, m)


def test_no_output_at_night_or_outside_the_field_of_view():
    """At 23 h the sun is below the horizon; at 7.2 h it is 60+ deg from the boresight of
    a level rover; a rover pitched toward the sun brings it back into view."""
    night = _run(_sky({"sun": {"local_solar_time_h": 23.0}}), _still(Rotation.identity()))
    assert np.all(night.reason == NIGHT) and np.all(np.isnan(night.measured))
    assert np.all(night.elevation_deg < 0)
    early = _sky({"sun": {"local_solar_time_h": 7.2}})
    v, el = early.sun_map(0.0)
    assert 0 < el < 30
    low = _run(early, _still(Rotation.identity()))
    assert np.all(low.reason == OUTSIDE_FOV) and low.counts()["outside_fov"] == len(low.idx)
    # tilt the deck 25 deg toward the sun: the sun is then within 60 deg of the boresight
    axis = np.cross([0, 0, 1.0], v)
    tilted = _run(early, _still(Rotation.from_rotvec(axis / np.linalg.norm(axis)
                                                     * np.radians(25))))
    assert np.all(tilted.reason == OK)


def test_the_mast_shadows_the_sensor_at_the_pan_of_the_moment():
    """Turn the rover so that the sun stands behind a point of the stereo head 15 cm off
    the pan axis: shadowed at pan 0, in the sun with the head panned 90 deg; behind the
    post it is shadowed at any pan."""
    kin = mast_kinematics(make_config("quick").camera)
    sensor = base_T_sensor(SunSensorConfig())[:3, 3]
    head_side = np.array([0.40, 0.15, 1.54]) - sensor
    head_side /= np.linalg.norm(head_side)
    assert mast_shadows(kin, sensor, head_side, 0.0, 0.35)
    assert not mast_shadows(kin, sensor, head_side, np.pi / 2, 0.35)
    post = np.array([0.40, 0.0, 1.0]) - sensor
    post /= np.linalg.norm(post)
    assert all(mast_shadows(kin, sensor, post, pan, 0.35) for pan in (0.0, 1.5, -2.5))
    assert not mast_shadows(kin, sensor, np.array([0.0, 0.0, 1.0]), 0.0, 0.35)
    assert not mast_shadows(kin, sensor, -head_side, 0.0, 0.35)  # behind the sensor

    sky = _sky({"sun": {"local_solar_time_h": 10.3}})
    sun_map, _ = sky.sun_map(2.0)
    # the attitude that puts the sun's direction on head_side (roughly a yaw and a tilt)
    rot, _ = Rotation.align_vectors([sun_map], [head_side])
    traj = _still(rot)
    shadowed = _run(sky, traj)
    assert np.mean(shadowed.reason == SHADOWED) > 0.9
    assert np.all(np.isnan(shadowed.measured[shadowed.reason == SHADOWED]))
    panned = _run(sky, traj, pan=np.pi / 2)
    assert np.all(panned.reason == OK)


def test_measure_recovers_the_vector_without_noise():
    rng = np.random.default_rng(0)
    v = np.array([[0.3, -0.2, 0.9], [0.0, 0.0, 1.0]])
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    np.testing.assert_allclose(measure(v, np.zeros(2), 0.0, rng), v, atol=1e-12)
    biased = measure(np.array([[0.0, 0.0, 1.0]]), np.radians([0.1, -0.2]), 0.0, rng)[0]
    assert np.degrees(np.arctan2(biased[0], biased[2])) == pytest.approx(0.1)
    assert np.degrees(np.arctan2(biased[1], biased[2])) == pytest.approx(-0.2)
