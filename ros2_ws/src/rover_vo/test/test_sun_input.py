"""The estimator with a sun sensor on the flat world (2 pairs driving, 3 standing, 1 s
apart, the rover level at yaw 0 in odom): the updates fix the odom frame's grid yaw; each
bad input is counted and named, and the odometry goes on."""

from __future__ import annotations

import copy
import logging
import math

import numpy as np
import pytest
import vo_flatworld as fw

from rover_vo import messages as m
from rover_vo.config import ImuOptions, VoConfig
from rover_vo.sun_heading import Site, rotz
from rover_vo.testing import run

#: Sun heading updates on (imu.sun_heading, the default) and off.
ON = VoConfig(imu=ImuOptions(sun_heading=True))
OFF = VoConfig(imu=ImuOptions(sun_heading=False))
SHORT = fw.Schedule(period_s=1.0).drive(2).stand(3, period_s=1.0)
PSI0_TRUE_DEG = 40.0
SENSOR = {"sun_sensor.frame": "sun_sensor",
          "sun_sensor.base_to_sensor": [0.0, 0.0, 0.8, 0.0, 0.0, 0.0, 1.0],
          "sun_sensor.noise_deg": 0.05, "sun_sensor.bias_deg": 0.1, "sun_sensor.rate_hz": 5.0}
#: fw.START_NS is 2023-11-14 22:13 UTC: about 10 h local solar time at 176.7 E (day)...
DAY = {"site.body": "earth", "site.crs": "EPSG:32760", "site.latitude_deg": -17.0,
       "site.longitude_deg": 176.7, "site.epoch_ns": fw.START_NS - 10**9}
#: ... and 22 h at 0 E (night).
NIGHT = dict(DAY, **{"site.crs": "EPSG:32631", "site.latitude_deg": 45.0,
                     "site.longitude_deg": 0.0})


def sun_messages(site_params: dict, rate_hz: float = 5.0) -> list[tuple[str, object]]:
    """/sun_sensor as the level rover at grid yaw 40 deg sees the sun, at ``rate_hz``."""
    site, _ = Site.from_params(site_params)
    msgs = fw.Messages()
    T = msgs.T
    out = []
    for k in range(int((SHORT.t + 1.5) * rate_hz)):
        t_ns = fw.START_NS + round((-1.0 + k / rate_hz) * 1e9)
        alpha, el = site.sun_grid(t_ns * 1e-9)
        v = rotz(-math.radians(PSI0_TRUE_DEG)) @ np.array(
            [math.cos(el) * math.cos(alpha), math.cos(el) * math.sin(alpha), math.sin(el)])
        out.append((m.TOPIC_SUN, T["geometry_msgs/msg/Vector3Stamped"](
            header=msgs.header(t_ns, "sun_sensor"),
            vector=T["geometry_msgs/msg/Vector3"](x=float(v[0]), y=float(v[1]),
                                                  z=float(v[2])))))
    return out


def merged(a, b):
    """Two streams in stamp order (a stable sort: ``a`` first at equal stamps)."""
    return sorted(a + b, key=lambda e: m.stamp_ns(e[1]))


@pytest.fixture(scope="module")
def base():
    return fw.stream(SHORT)


@pytest.fixture(scope="module")
def day(base):
    return merged(base, sun_messages(DAY))


@pytest.fixture(scope="module")
def no_sun(base):
    _, outputs, _ = run(base, fw.rover_params())
    assert len(outputs) == len(SHORT.frames)
    return outputs


def params(*extra):
    p = fw.rover_params()
    for e in extra:
        p.update(e)
    return p


def warnings(logs):
    return [text for level, text in logs if level >= logging.WARNING]


def test_sun_updates_fix_the_odom_frames_grid_yaw(day, no_sun):
    est, outputs, logs = run(day, params(SENSOR, DAY), ON)
    assert len(outputs) == len(no_sun)
    status = est.status()
    assert status["sun.state"] == "updating" and status["sun.heading_bounded"] is True
    # only pairs at rest use a sample (in motion the tilt is not known well enough): the
    # first sets psi0, the next two update
    assert [o.source for o in outputs][2:] == ["zero_velocity"] * 3
    assert est.sun.updates == 2 and status["sun.in_motion"] == 2
    assert status["sun.odom_grid_yaw_deg"] == pytest.approx(PSI0_TRUE_DEG, abs=0.3)
    assert status["sun.heading_sigma_deg"] < 1.0
    assert not [k for k, v in status.items() if k.startswith("bad_input.sun") and v]
    # the odometry's positions are those without the sun (a few mm: only the heading moves)
    for a, b in zip(outputs, no_sun, strict=True):
        assert np.allclose(a.state.p, b.state.p, atol=5e-3)
    assert any("sun heading on" in text for _, text in logs)


def test_bad_sun_vectors_are_skipped_and_counted(base, no_sun):
    sun = sun_messages(DAY)
    bad = {3: "nan", 6: "long", 9: "frame", 12: "repeat"}
    for k, what in bad.items():
        msg = copy.deepcopy(sun[k][1])
        if what == "nan":
            msg.vector.y = math.nan
        elif what == "long":
            msg.vector.x, msg.vector.y, msg.vector.z = 0.0, 0.0, 1.2
        elif what == "frame":
            msg.header.frame_id = "sun_link"
        else:
            msg = copy.deepcopy(sun[k - 1][1])
        sun[k] = (m.TOPIC_SUN, msg)
    est, outputs, logs = run(merged(base, sun), params(SENSOR, DAY), ON)
    assert len(outputs) == len(no_sun)
    for kind in ("sun_nan", "sun_not_unit", "sun_wrong_frame", "sun_out_of_order"):
        assert est.counts.bad[kind] == 1, kind
    said = "\n".join(warnings(logs))
    assert "/sun_sensor at" in said and "not finite" in said
    assert "of norm 1.2000, not a unit vector" in said
    assert "frame 'sun_link' is not rover.yaml's sun_sensor.frame 'sun_sensor'" in said
    assert est.sun.updates >= 2


def test_a_sun_sensor_rover_yaml_lacks_is_named(day, no_sun):
    est, outputs, logs = run(day, params(), ON)
    assert len(outputs) == len(no_sun)
    assert est.counts.bad["sun_no_mount"] > 0 and est.sun.updates == 0
    said = [t for t in warnings(logs) if "sun_no_mount" in t]
    assert len(said) == 1
    assert "frame 'sun_sensor' has no mount in rover.yaml" in said[0]
    assert est.status()["sun.state"] == "off"


def test_a_bag_without_site_and_epoch_refuses_sun_updates_in_one_line(day, no_sun):
    site = {k: v for k, v in DAY.items() if k not in ("site.latitude_deg", "site.epoch_ns")}
    est, outputs, logs = run(day, params(SENSOR, site), ON)
    assert len(outputs) == len(no_sun) and est.sun.updates == 0
    said = [t for t in warnings(logs) if "refused" in t]
    assert len(said) == 1 and "site.latitude_deg, site.epoch_ns" in said[0]
    assert est.status()["sun.state"] == "refused"
    assert not est.counts.bad  # the samples are not bad input: the site is missing


def test_no_sun_at_night_is_said_once_and_the_odometry_goes_on(base, no_sun):
    est, outputs, logs = run(base, params(SENSOR, NIGHT), ON)
    assert len(outputs) == len(no_sun)
    said = [t for t in warnings(logs) if "no sun" in t]
    assert len(said) == 1 and "below the horizon" in said[0]
    assert est.status()["sun.state"] == "waiting" and est.sun.updates == 0
    for a, b in zip(outputs, no_sun, strict=True):
        assert np.array_equal(a.state.p, b.state.p)
        assert np.array_equal(a.state.cov, b.state.cov)


def test_a_vector_the_ephemeris_says_is_impossible_is_skipped(base, no_sun):
    # the day's vectors, fed to the night's site: the sun is below the horizon there
    est, outputs, logs = run(merged(base, sun_messages(DAY)), params(SENSOR, NIGHT), ON)
    assert len(outputs) == len(no_sun) and est.sun.updates == 0
    at_rest = [o for o in outputs if o.source == "zero_velocity"]
    assert est.counts.bad["sun_not_sun"] == len(at_rest) == 3
    said = [t for t in warnings(logs) if "sun_not_sun" in t]
    assert len(said) == 1 and "below the horizon" in said[0]


def test_the_sun_updates_switched_off_read_no_sample(day, no_sun):
    """With rover.yaml's sun sensor but imu.sun_heading false, /sun_sensor is not read: the
    odometry is the gyro's, no sample is counted bad, and the log says so once. On is the
    default."""
    assert VoConfig().imu.sun_heading is True
    est, outputs, logs = run(day, params(SENSOR, DAY), OFF)
    assert len(outputs) == len(no_sun)
    for a, b in zip(outputs, no_sun, strict=True):
        assert np.array_equal(a.state.p, b.state.p)
        assert np.array_equal(a.state.cov, b.state.cov)
    assert not any(n for kind, n in est.counts.bad.items() if kind.startswith("sun"))
    assert sum("heading updates off" in text for _, text in logs) == 1
