"""MapOdomFilter: consistency of its covariance on simulated drift and matches, gating,
confirmation of contradicting fixes, covariance intersection."""

from __future__ import annotations

import numpy as np
import pytest

from darces_matcher import localization
from darces_matcher.localization import (
    FilterConfig,
    MapOdomFilter,
    covariance_intersection,
    fit_with_covariance,
    global_pose,
    yaw_quaternion,
)
from darces_matcher.matcher import MatchResult
from roi_network.transform import Rigid2D, wrap_angle


def _simulate(seed: int, length_m: float = 1000.0, match_every_m: float = 25.0):
    """A drive with drifting VO, ROIs seen along it, and a least-squares fix of the whole
    LN every ``match_every_m``.

    VO drift: heading random walk (0.6 deg one-sigma per 100 m), a scale error of 0.5 %
    and 1 cm/m of position noise. ROIs: one every ~7 m, within 12 m of the route, seen
    once when the rover passes nearest, with 0.3 m of detection noise (in base_link).

    Yields ('odom', true pose (x, y, yaw) in map, odom pose (x, y, yaw)) per 0.5 m step
    and ('match', MatchResult, (LN (N, 2) in odom, GN (N, 2) in map)) every
    ``match_every_m``; the fix is the least-squares fit of the whole LN (the paper's).
    """
    rng = np.random.default_rng(seed)
    step = 0.5
    n = int(length_m / step)
    curvature = np.convolve(rng.normal(0, 0.02, n), np.ones(40) / 40, mode="same")
    yaw_true = np.cumsum(curvature * step) + rng.uniform(-np.pi, np.pi)
    xy_true = np.cumsum(step * np.c_[np.cos(yaw_true), np.sin(yaw_true)], axis=0)
    xy_true += rng.uniform(-500, 500, 2)
    scale = 1.0 + rng.choice([-1, 1]) * 0.005
    yaw_err = np.cumsum(rng.normal(0, np.radians(0.6) * np.sqrt(step / 100.0), n))
    yaw_odom = yaw_true - yaw_true[0] + yaw_err
    steps = scale * step * np.c_[np.cos(yaw_odom), np.sin(yaw_odom)]
    steps += rng.normal(0, 0.01 * np.sqrt(step), (n, 2))
    xy_odom = np.cumsum(steps, axis=0) - steps[0]
    rois_seen = []  # (step index, odom xy, true map xy)
    for i in range(0, n, 14):
        side = rng.uniform(-12, 12)
        lateral = np.array([-np.sin(yaw_true[i]), np.cos(yaw_true[i])])
        roi_map = xy_true[i] + side * lateral
        rel = Rigid2D(yaw_true[i], *xy_true[i]).inverse().apply(roi_map)
        rel = rel + rng.normal(0, 0.3, 2)
        roi_odom = Rigid2D(yaw_odom[i], *xy_odom[i]).apply(rel)
        rois_seen.append((i, roi_odom, roi_map))
    next_match = match_every_m
    for i in range(n):
        yield ("odom", (*xy_true[i], yaw_true[i]), (*xy_odom[i], yaw_odom[i]))
        if i * step >= next_match:
            next_match += match_every_m
            seen = [r for r in rois_seen if r[0] <= i]
            if len(seen) < 5:
                continue
            src = np.array([r[1] for r in seen])
            dst = np.array([r[2] for r in seen])
            t, cov = fit_with_covariance(src, dst)
            pairs = np.c_[np.arange(len(src)), np.arange(len(src))]
            yield ("match", MatchResult("fix", "ok", map_T_odom=t, covariance=cov,
                                        inliers=pairs, support=len(seen)), (src, dst))


def _run(seed: int, config: FilterConfig, local: bool = True):
    """Run the filter on one simulated drive; per step after the first fix: horizontal
    error (m) and squared Mahalanobis distance of the truth under the published covariance.
    """
    f = MapOdomFilter(config)
    errors, mahal2, events = [], [], []
    for kind, a, b in _simulate(seed):
        if kind == "match":
            ln, gn = b
            events.append(f.update(a, ln, gn if local else None))
            continue
        truth, odom = a, b
        f.predict(np.array(odom[:2]))
        if not f.localized:
            continue
        pos, _, cov = global_pose(f.alignment, np.array([odom[0], odom[1], 0.0]),
                                  yaw_quaternion(odom[2]), np.eye(6) * 0.01)
        d = pos[:2] - np.array(truth[:2])
        errors.append(float(np.hypot(*d)))
        mahal2.append(float(d @ np.linalg.solve(cov[:2, :2], d)))
    return np.array(errors), np.array(mahal2), events


@pytest.mark.parametrize("local", [True, False])
def test_truth_within_three_sigma_on_simulated_drives(local):
    """>= 99 % of the published poses have the truth inside their 3-sigma ellipse, over
    four simulated 1 km drives (the filter's drift parameters are its defaults, not fitted
    to the simulator), with and without the local refit."""
    inside, total, rmse = 0, 0, []
    for seed in range(4):
        errors, mahal2, events = _run(seed, FilterConfig(), local)
        assert events.count("switched") == 0 and events.count("held") == 0, events
        assert "refined" in events
        inside += int((mahal2 <= 9.0).sum())
        total += len(mahal2)
        rmse.append(float(np.sqrt(np.mean(errors**2))))
    assert inside / total >= 0.99, f"3-sigma consistency {inside / total:.4f}"
    if local:
        # The recent pairs say where the rover is now; a whole-LN fit spreads the drift.
        assert max(rmse) < 1.0, rmse
    else:
        assert min(rmse) > 1.0, rmse


def test_overconfident_filter_fails_consistency(monkeypatch):
    """The check above can fail: a filter that ignores drift is inconsistent."""
    monkeypatch.setattr(localization, "MIN_MATCH_SIGMA_M", 0.0)
    monkeypatch.setattr(localization, "MIN_MATCH_SIGMA_YAW_RAD", 0.0)
    cfg = FilterConfig(drift_xy_m2_per_m=0.0, drift_yaw_rad2_per_m=0.0)
    inside, total = 0, 0
    for seed in range(3):
        _, mahal2, _ = _run(seed, cfg)
        inside += int((mahal2 <= 9.0).sum())
        total += len(mahal2)
    assert inside / total < 0.95


def test_covariance_grows_with_distance_and_about_the_rover():
    f = MapOdomFilter(FilterConfig(drift_xy_m2_per_m=0.01, drift_yaw_rad2_per_m=1e-6))
    f.predict(np.zeros(2))
    fix = MatchResult("fix", "ok", map_T_odom=Rigid2D(0.0, 100.0, 50.0),
                      covariance=np.diag([0.04, 0.04, 1e-6]), support=10)
    assert f.update(fix, np.zeros((5, 2))) == "first_fix"
    p0 = f.p.copy()
    for x in np.arange(1.0, 101.0):
        f.predict(np.array([x, 0.0]))
    assert f.distance_m == pytest.approx(100.0)
    # Position variance grew by ~0.01 m^2/m * 100 m (+ the heading's lever arm).
    assert f.p[0, 0] - p0[0, 0] >= 1.0 - 1e-9
    # The heading part rotates the alignment about the rover, away from the odom origin:
    # map y of the alignment is correlated with its yaw.
    assert abs(f.p[1, 2]) > 1e-5
    pos, _, cov = global_pose(f.alignment, np.array([100.0, 0.0, 0.0]),
                              yaw_quaternion(0.0), np.zeros(36))
    # Across-track variance at the rover: the fix's (plus its heading through the 100 m
    # lever arm), the position drift (1 m^2) and the heading drift met at each point x of
    # the route, through the lever arm 100 - x: 1e-6 * 100^3 / 3.
    expected = p0[1, 1] + p0[2, 2] * 100**2 + 1.0 + 1e-6 * 100**3 / 3
    assert cov[1, 1] == pytest.approx(expected, rel=0.02)
    # Along-track: no heading term.
    assert cov[0, 0] == pytest.approx(p0[0, 0] + 1.0, rel=0.02)
    assert np.allclose(pos[:2], [200.0, 50.0])


def test_a_bounded_odometry_heading_bounds_the_alignments_heading_drift():
    """With the odometry's heading bounded (sun updates), the alignment's heading variance
    stops growing at its value at the fix plus the bound; without, it keeps walking."""
    bound = np.radians(0.15) ** 2 * 2

    def drive(bounded):
        f = MapOdomFilter(FilterConfig(drift_xy_m2_per_m=0.01, drift_yaw_rad2_per_m=3e-6))
        f.predict(np.zeros(2))
        fix = MatchResult("fix", "ok", map_T_odom=Rigid2D(0.3, 100.0, 50.0),
                          covariance=np.diag([0.04, 0.04, 1e-6]), support=10)
        assert f.update(fix, np.zeros((5, 2))) == "first_fix"
        for x in np.arange(1.0, 501.0):
            f.predict(np.array([x, 0.0]), bound if bounded else None)
        return f

    free, sun = drive(False), drive(True)
    at_fix = sun._yaw_var_fix  # the fix's, with the filter's floor
    assert at_fix == pytest.approx(2e-6)
    assert free.p[2, 2] == pytest.approx(at_fix + 3e-6 * 500, rel=1e-6)
    assert sun.p[2, 2] == pytest.approx(at_fix + bound, rel=1e-9)
    # still a covariance, and the position's drift is the same random walk
    assert np.all(np.linalg.eigvalsh(sun.p) > 0)
    assert sun.p[0, 0] == pytest.approx(free.p[0, 0], rel=1e-9)
    # a fix's lag drift in heading is capped the same way
    assert sun.drift_noise(sun.x, np.zeros(2), 400.0)[2, 2] == pytest.approx(bound)
    # the bound lifted (no sun for a while): the walk resumes from there
    sun.predict(np.array([600.0, 0.0]))
    assert sun.p[2, 2] == pytest.approx(at_fix + bound + 3e-6 * 100, rel=1e-6)


def _fix(t: Rigid2D, sigma: float = 0.5, support: int = 10) -> MatchResult:
    return MatchResult("fix", "ok", map_T_odom=t,
                       covariance=np.diag([sigma**2, sigma**2, (sigma / 100) ** 2]),
                       support=support)


def test_contradicting_fix_is_held_until_confirmed():
    ln = np.array([[0.0, 0.0], [50.0, 0.0], [25.0, 30.0]])
    f = MapOdomFilter(FilterConfig(confirm_matches=3))
    f.predict(np.zeros(2))
    assert f.update(MatchResult("no_fix", "ambiguous"), ln) == "none"
    assert f.update(_fix(Rigid2D(0.1, 10, 0)), ln) == "first_fix"
    assert f.update(_fix(Rigid2D(0.1, 10.3, 0.2)), ln) == "refined"
    assert f.update(MatchResult("no_fix", "ambiguous"), ln) == "kept"
    wrong = Rigid2D(2.0, 500, 0)
    assert f.update(_fix(wrong), ln) == "held"
    assert f.alignment.map_T_odom.tx == pytest.approx(10.15, abs=0.2)
    # A consistent fix in between discards the held one.
    assert f.update(_fix(Rigid2D(0.1, 10.1, 0)), ln) == "refined"
    assert f.held == []
    # Two contradicting fixes that disagree with each other do not confirm each other.
    assert f.update(_fix(wrong), ln) == "held"
    assert f.update(_fix(Rigid2D(-1.0, -300, 40)), ln) == "held"
    assert len(f.held) == 1
    # Three consecutive, mutually consistent contradicting fixes: switch.
    assert f.update(_fix(Rigid2D(-1.0, -300.5, 40)), ln) == "held"
    assert f.update(_fix(Rigid2D(-1.0, -300.2, 40.3)), ln) == "switched"
    assert f.switches == 1
    assert f.alignment.map_T_odom.tx == pytest.approx(-300.2)


def test_refinement_follows_a_tighter_fix_and_never_overshoots():
    ln = np.zeros((4, 2))
    f = MapOdomFilter()
    f.predict(np.zeros(2))
    f.update(_fix(Rigid2D(0.0, 0.0, 0.0), sigma=2.0), ln)
    f.update(_fix(Rigid2D(0.0, 1.0, 0.0), sigma=0.2), ln)
    assert 0.9 < f.x[0] <= 1.0
    assert f.p[0, 0] <= 0.2**2 + 0.1**2 + 1e-9


def test_covariance_intersection_is_consistent_and_idempotent():
    x = np.array([1.0, 2.0, 3.1])
    p = np.diag([1.0, 2.0, 0.01])
    xf, pf = covariance_intersection(x, p, x.copy(), p.copy())
    np.testing.assert_allclose(xf, x, atol=1e-12)
    np.testing.assert_allclose(pf, p, rtol=1e-9)
    # Across the yaw wrap: fused around the first estimate, the result is wrapped.
    xa, xb = np.array([0.0, 0.0, np.pi - 0.01]), np.array([0.0, 0.0, -np.pi + 0.01])
    xf, _ = covariance_intersection(xa, np.eye(3), xb, np.eye(3))
    assert abs(wrap_angle(xf[2] - np.pi)) < 0.011


def test_bad_config_and_bad_covariance_are_errors():
    with pytest.raises(ValueError, match="confirm_matches"):
        FilterConfig(confirm_matches=0)
    with pytest.raises(ValueError, match="drift_xy_m2_per_m"):
        FilterConfig(drift_xy_m2_per_m=-1.0)
    f = MapOdomFilter()
    bad = MatchResult("fix", "ok", map_T_odom=Rigid2D(), covariance=None)
    with pytest.raises(ValueError, match="covariance"):
        f.update(bad, np.zeros((3, 2)))


def _plane_dtm(sigma: float = 0.3):
    """A DTM of the plane z = 0.2 x - 0.1 y - 5 over map [-100, 300]^2 at 1 m posts."""
    from roi_network.dtm import ElevationModel

    x = np.arange(-100.0, 300.5)
    y = np.arange(300.0, -100.5, -1.0)
    xx, yy = np.meshgrid(x, y)
    return ElevationModel(0.2 * xx - 0.1 * yy - 5.0, x0=-100.0, y0=300.0, posting=1.0,
                          vertical_sigma_m=sigma)


def _drifted_alignment():
    f = MapOdomFilter()
    f.update(_fix(Rigid2D(0.5, 100.0, 50.0), sigma=0.5), np.zeros((5, 2)))
    for x in np.arange(1.0, 61.0):
        f.predict(np.array([x, 0.0]))
    return f.alignment


def test_without_a_dtm_z_is_marked_not_estimated():
    """No elevation model: z keeps the odometry's value but its variance is 1e6 m^2 and it
    is correlated with nothing, whatever the odometry claimed (0.1 m^2 here)."""
    from roi_network.dtm import UNKNOWN_VARIANCE_M2, z_is_estimated

    odom_cov = np.diag([0.1, 0.1, 0.1, 0.01, 0.01, 0.02])
    odom_cov[2, 3] = odom_cov[3, 2] = 0.01
    pos, _, cov = global_pose(_drifted_alignment(), np.array([60.0, 0.0, 4.83]),
                              yaw_quaternion(0.0), odom_cov)
    assert pos[2] == 4.83
    assert cov[2, 2] == UNKNOWN_VARIANCE_M2 and not z_is_estimated(cov[2, 2])
    assert np.count_nonzero(cov[2]) == 1 and np.count_nonzero(cov[:, 2]) == 1
    assert cov[3, 3] == pytest.approx(0.01)  # roll, pitch: still the odometry's


def test_with_a_dtm_z_is_the_ground_under_the_rover_with_the_slope_in_its_variance():
    """z = the DTM's height at the published x, y (base_link on the ground), variance =
    sigma_v^2 + g^T C_xy g, correlated with x, y and yaw through the slope; the 6x6
    covariance stays symmetric positive semi-definite. Off the DTM: not estimated."""
    from roi_network.dtm import UNKNOWN_VARIANCE_M2

    dtm = _plane_dtm(sigma=0.3)
    alignment = _drifted_alignment()
    odom_cov = np.diag([0.1, 0.1, 0.1, 0.01, 0.01, 0.02])
    pos, _, cov = global_pose(alignment, np.array([60.0, 0.0, 4.83]), yaw_quaternion(0.0),
                              odom_cov, dtm)
    assert pos[2] == pytest.approx(0.2 * pos[0] - 0.1 * pos[1] - 5.0, abs=1e-9)
    g = np.array([0.2, -0.1])
    c_xy = cov[:2, :2]
    assert cov[2, 2] == pytest.approx(0.09 + g @ c_xy @ g, rel=1e-9)
    assert cov[2, 2] > 0.09 + 1e-3  # the slope term is there
    np.testing.assert_allclose(cov[2, [0, 1, 5]], g @ cov[:2][:, [0, 1, 5]], rtol=1e-9)
    np.testing.assert_allclose(cov, cov.T)
    assert np.linalg.eigvalsh(cov).min() > -1e-9
    # The same pose without the DTM has the same horizontal block.
    _, _, bare = global_pose(alignment, np.array([60.0, 0.0, 4.83]), yaw_quaternion(0.0),
                             odom_cov)
    np.testing.assert_allclose(bare[:2, :2], c_xy)
    # Driven off the model (map x beyond 300 m): z not estimated.
    far, _, cov_far = global_pose(alignment, np.array([600.0, 0.0, 4.83]),
                                  yaw_quaternion(0.0), odom_cov, dtm)
    assert far[0] > 300.0 and cov_far[2, 2] == UNKNOWN_VARIANCE_M2
