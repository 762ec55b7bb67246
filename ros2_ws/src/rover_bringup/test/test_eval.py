"""``globloc eval``: metrics on synthetic run directories made here, with known answers."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from rover_bringup.cli import main
from rover_bringup.errors import GloblocError
from rover_bringup.evaluation import evaluate, load_run
from rover_bringup.report import EvalOptions, evaluate_run
from rover_bringup.run_outputs import export_outputs

T0 = 1_700_000_000.0
ORIGIN = (403446.0, 7334375.0)


def _tum(path: Path, t: np.ndarray, xy: np.ndarray, header: str = '# t x y z qx qy qz qw\n',
         z: np.ndarray | None = None):
    z = np.zeros(len(t)) if z is None else z
    rows = [f'{ti:.9f} {x:.6f} {y:.6f} {zi:.6f} 0 0 0 1\n'
            for ti, (x, y), zi in zip(t, xy, z, strict=True)]
    path.write_text(header + ''.join(rows))


def _bag(tmp_path: Path) -> tuple[Path, np.ndarray, np.ndarray]:
    """A bag directory with a 300 m straight truth route at 1 m/s, 10 Hz, an orbital image
    and a GN (map origin ORIGIN)."""
    bag = tmp_path / 'bags' / 'synthetic'
    (bag / 'truth').mkdir(parents=True)
    t = T0 + np.arange(0, 300.0, 0.1)
    xy = np.c_[np.arange(len(t)) * 0.1 - 150.0, np.full(len(t), 20.0)]
    _tum(bag / 'truth' / 'trajectory.tum', t, xy)
    import rasterio
    from rasterio.transform import from_origin

    img = np.random.default_rng(0).integers(0, 255, (3, 200, 200), dtype=np.uint8)
    with rasterio.open(bag / 'orbital.tif', 'w', driver='GTiff', width=200, height=200,
                       count=3, dtype='uint8', crs='EPSG:32719',
                       transform=from_origin(ORIGIN[0] - 200, ORIGIN[1] + 200, 2.0, 2.0),
                       ) as d:
        d.write(img)
    from roi_network.geojson import write_geojson
    from roi_network.network import MapFrame, RoiNetwork
    from roi_network.records import empty_records

    gn = empty_records(30)
    gn['x'], gn['y'], gn['id'], gn['label'] = np.linspace(-150, 150, 30), 25.0, range(30), 1
    write_geojson(RoiNetwork(gn, 'map', MapFrame('EPSG:32719', ORIGIN)), bag / 'gn.geojson')
    return bag, t, xy


def _run_dir(tmp_path: Path, bag: Path) -> Path:
    run = tmp_path / 'out' / 'synthetic' / 'r1'
    run.mkdir(parents=True)
    (run / 'run.yaml').write_text(yaml.safe_dump({'bag': {'dir': str(bag)}}))
    return run


def _write_estimate(run: Path, t, xy, sigma: np.ndarray, z=None, var_z=None):
    """global_pose.tum and global_pose_cov.tsv; ``var_z`` None: the file of a run exported
    before it had a cov_zz column (4 columns)."""
    _tum(run / 'global_pose.tum', t, xy, z=z)
    if var_z is None:
        rows = [f'{ti:.9f} {s**2:.9g} 0 {s**2:.9g}\n' for ti, s in zip(t, sigma, strict=True)]
        (run / 'global_pose_cov.tsv').write_text('# t cov_xx cov_xy cov_yy\n' + ''.join(rows))
        return
    var_z = np.broadcast_to(var_z, len(t))
    rows = [f'{ti:.9f} {s**2:.9g} 0 {s**2:.9g} {vz:.9g}\n'
            for ti, s, vz in zip(t, sigma, var_z, strict=True)]
    (run / 'global_pose_cov.tsv').write_text('# t cov_xx cov_xy cov_yy cov_zz\n' + ''.join(rows))


def test_metrics_of_a_run_with_known_errors(tmp_path: Path):
    bag, t, xy = _bag(tmp_path)
    run = _run_dir(tmp_path, bag)
    # First /global_pose at 50 s (50 m driven); a 0.5 m error across the track, except a
    # 15 m jump over 2 s after a (false) refinement at 200 s. Published sigma 0.3 m:
    # 0.5 m is inside 3 sigma, the jump is not.
    k = t >= T0 + 50.0
    te, est = t[k], xy[k] + [0.0, 0.5]
    jump = (te >= T0 + 200.0) & (te < T0 + 202.0)
    est[jump, 1] += 14.5
    _write_estimate(run, te, est, np.full(len(te), 0.3))
    (run / 'matcher_events.tsv').write_text(
        '# t\tevent\treason\tln_size\tinliers\n'
        f'{T0 + 50.0:.9f}\tfirst_fix\tok\t10\t8\n'
        f'{T0 + 120.0:.9f}\tkept\tambiguous\t12\t0\n'
        f'{T0 + 200.0:.9f}\trefined\tok\t15\t9\n'
        f'{T0 + 202.0:.9f}\tswitched\tok\t16\t12\n')
    _tum(run / 'vo.tum', t, xy * 1.01)

    ev = evaluate(load_run(run))
    s = ev.summary
    assert s['localized'] is True
    assert s['distance_before_first_fix_m'] == pytest.approx(50.0, abs=0.11)
    assert s['final_error_m'] == pytest.approx(0.5, abs=1e-6)
    n_jump = int(jump.sum())
    expected_rmse = np.sqrt(((len(te) - n_jump) * 0.25 + n_jump * 15.0**2) / len(te))
    assert s['rmse_after_first_fix_m'] == pytest.approx(expected_rmse, rel=1e-6)
    assert s['false_fixes'] == 1 and s['poses_over_10m'] == n_jump
    assert s['consistency_3sigma'] == pytest.approx(1 - n_jump / len(te))
    assert s['route_length_m'] == pytest.approx(299.9, abs=0.01)
    assert s['matcher_events'] == {'first_fix': 1, 'kept': 1, 'refined': 1, 'switched': 1}
    assert [f[2] for f in ev.fixes] == ['first_fix', 'refined', 'switched']
    # Fixes at 50, 200 and 202 m on a 299.9 m route: the longest stretch is 50-200 m, and
    # the pose before the fix closing it is the 0.5 m off one (the jump starts at 200 s).
    assert s['longest_stretch_without_fix_m'] == pytest.approx(150.0, abs=0.11)
    assert s['error_at_stretch_end_m'] == pytest.approx(0.5, abs=1e-6)
    assert s['heading_final_error_deg'] == 0.0 and s['heading_rmse_deg'] == 0.0
    # A straight route cannot anchor a 3D alignment: said, not a crash.
    assert 'evo could not align' in s['vo']['error']
    assert s['meets_targets'] == {'final_error_m': True, 'rmse_after_first_fix_m': False,
                                  'false_fixes': False, 'distance_before_first_fix_m': True,
                                  'consistency_3sigma': True}  # 20 of 2500 outside

    report = evaluate_run(EvalOptions(run))
    assert json.loads((run / 'report.json').read_text()) == report
    assert report['final_error_m'] == pytest.approx(0.5, abs=1e-6)
    md = (run / 'report.md').read_text()
    assert '| false fixes (> 10 m) | 1 | 0 | no |' in md
    for png in ('route.png', 'error.png'):
        assert (run / png).read_bytes()[:8] == b'\x89PNG\r\n\x1a\n'


def _sloped_bag(tmp_path: Path) -> tuple[Path, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`_bag` with a truth route that climbs 5 m from -5.6 m (map z)."""
    bag, t, xy = _bag(tmp_path)
    z = -5.6 + 5.0 * (t - t[0]) / (t[-1] - t[0])
    _tum(bag / 'truth' / 'trajectory.tum', t, xy, z=z)
    return bag, t, xy, z


def test_vertical_error_apart_and_the_3d_ape_only_with_z_estimated(tmp_path: Path):
    """With z from a DTM (variance 0.09 m^2) the vertical error is reported apart from
    the horizontal one and evo's 3D APE is quoted; with z not estimated (variance 1e6 m^2,
    the odometry's z 10.5 m off) neither is, and the summary says why."""
    from rover_bringup.evaluation import report_markdown, summary_lines

    bag, t, xy, z = _sloped_bag(tmp_path)
    run = _run_dir(tmp_path, bag)
    k = t >= T0 + 50.0
    est_xy = xy[k] + [0.0, 0.5]
    dz = np.where(np.arange(k.sum()) % 2 == 0, 0.3, -0.3)  # 0.3 m either way
    _write_estimate(run, t[k], est_xy, np.full(k.sum(), 0.3), z=z[k] + dz, var_z=0.09)
    s = evaluate(load_run(run)).summary
    assert s['final_error_m'] == pytest.approx(0.5, abs=1e-5)  # horizontal only
    assert s['rmse_after_first_fix_m'] == pytest.approx(0.5, abs=1e-5)
    assert s['z_estimated'] == 'all' and s['z_note'] is None
    assert s['vertical_final_error_m'] == pytest.approx(0.3, abs=1e-5)
    assert s['vertical_rmse_m'] == pytest.approx(0.3, abs=1e-5)
    assert s['vertical_consistency_3sigma'] == 1.0
    assert s['ape_unaligned_rmse_m'] == pytest.approx(np.hypot(0.5, 0.3), abs=1e-4)
    lines = summary_lines(s)
    assert 'final error: horizontal 0.50 m' in lines[1] and 'vertical 0.30 m' in lines[1]
    assert lines[2].startswith('RMSE after first fix: horizontal 0.50 m')
    assert lines[2].endswith('vertical 0.30 m')
    assert lines[-1] == 'evo unaligned APE (3D) RMSE 0.58 m'
    md = report_markdown(s, [])
    assert '| final vertical error | 0.30 m | - | - |' in md
    assert 'evo unaligned APE (3D) RMSE 0.58 m' in md

    # No DTM: the odometry's z, 10.5 m off, published as not estimated.
    _write_estimate(run, t[k], est_xy, np.full(k.sum(), 0.3), z=z[k] + 10.5, var_z=1e6)
    s = evaluate(load_run(run)).summary
    assert s['final_error_m'] == pytest.approx(0.5, abs=1e-5)
    assert s['z_estimated'] == 'none'
    assert s['vertical_final_error_m'] is None and s['vertical_rmse_m'] is None
    assert s['ape_unaligned_rmse_m'] is None
    assert 'no DTM beside the bag' in s['z_note'] and '3D APE not quoted' in s['z_note']
    lines = summary_lines(s)
    assert lines[1].endswith('vertical n/a (z not estimated)')
    assert lines[-1] == s['z_note'] and '10.5' not in '\n'.join(lines)
    assert '| final vertical error | n/a (z not estimated) | - | - |' in report_markdown(s, [])

    # Part of the route off the DTM: judged where z is estimated, no 3D APE.
    var_z = np.where(np.arange(k.sum()) < k.sum() // 2, 0.09, 1e6)
    _write_estimate(run, t[k], est_xy, np.full(k.sum(), 0.3), z=z[k] + dz, var_z=var_z)
    s = evaluate(load_run(run)).summary
    assert s['z_estimated'] == 'some' and s['ape_unaligned_rmse_m'] is None
    assert s['vertical_rmse_m'] == pytest.approx(0.3, abs=1e-5)
    assert f'z estimated for {k.sum() // 2} of {k.sum()} poses' in s['z_note']

    # A file of a run exported before cov_zz: z not judged, said so.
    _write_estimate(run, t[k], est_xy, np.full(k.sum(), 0.3), z=z[k] + dz)
    s = evaluate(load_run(run)).summary
    assert s['z_estimated'] is None and 'no cov_zz column' in s['z_note']
    assert s['ape_unaligned_rmse_m'] is None and s['final_error_m'] == pytest.approx(0.5)


def test_a_fix_is_judged_by_the_poses_after_it_reached_the_graph(tmp_path: Path):
    bag, t, xy = _bag(tmp_path)
    run = _run_dir(tmp_path, bag)
    # Localized at 50 s, then the pose drifts to 12 m off by 200 s. A right fix of an LN
    # stamped 200 s reaches the graph at 260 s (a detector behind a fast replay): the
    # poses between are the drifted ones, those after it 0.2 m off.
    k = t >= T0 + 50.0
    te, est = t[k], xy[k].copy()
    drift = np.clip((te - (T0 + 50.0)) / 150.0, 0.0, 1.0) * 12.0
    est[:, 1] += np.where(te < T0 + 260.0, drift, 0.2)
    _write_estimate(run, te, est, np.full(len(te), 5.0))
    rows = [f'{T0 + 50.0:.9f}\tfirst_fix\tok\t6\t5', f'{T0 + 200.0:.9f}\trefined\tok\t9\t7']
    events = run / 'matcher_events.tsv'
    # As recorded since the receive time is kept: the fix counts from 260 s.
    events.write_text('# t\tevent\treason\tln_size\tinliers\treceived\n'
                      f'{rows[0]}\t{T0 + 51.0:.9f}\n{rows[1]}\t{T0 + 260.0:.9f}\n')
    s = evaluate(load_run(run)).summary
    assert s['false_fixes'] == 0 and s['poses_over_10m'] > 0
    assert s['fix_lag_s'] == pytest.approx({'median': 30.5, 'max': 60.0})
    # An older file without the column: the fix counts from its LN's stamp, and the
    # drifted poses after 200 s make it a false fix.
    events.write_text('# t\tevent\treason\tln_size\tinliers\n' + '\n'.join(rows) + '\n')
    s = evaluate(load_run(run)).summary
    assert s['false_fixes'] == 1 and s['fix_lag_s'] is None


def test_vo_drift_is_measured_with_evo_alignment():
    from rover_bringup.evaluation import _vo_summary

    t = np.arange(0, 200.0, 0.1)
    a = t / 30.0
    truth = np.c_[t, 40 * np.cos(a), 40 * np.sin(a), np.zeros((len(t), 4)), np.ones(len(t))]
    vo = truth.copy()
    vo[:, 1:3] = truth[:, 1:3] @ np.array([[0, -1], [1, 0]]).T + [5.0, 7.0]  # rigid: no drift
    assert _vo_summary(vo, truth)['ape_aligned_rmse_m'] < 1e-6
    vo[:, 1] += 0.01 * np.arange(len(t)) * 0.1  # 1 % drift along x
    assert 0.2 < _vo_summary(vo, truth)['ape_aligned_rmse_m'] < 2.0


def test_heading_error_is_the_wrapped_yaw_difference(tmp_path: Path):
    bag, t, xy = _bag(tmp_path)
    run = _run_dir(tmp_path, bag)
    # The truth heads at 0 deg; the estimate at +1 deg, and at -179 deg (= 181 deg, 181 deg
    # off, wrapped to -179) over its last 10 s.
    yaw = np.where(t >= t[-1] - 10.0, np.radians(181.0), np.radians(1.0))
    _write_estimate(run, t, xy, np.full(len(t), 0.3))
    rows = [f'{ti:.9f} {x:.6f} {y:.6f} 0 0 0 {np.sin(a / 2):.9f} {np.cos(a / 2):.9f}\n'
            for ti, (x, y), a in zip(t, xy, yaw, strict=True)]
    (run / 'global_pose.tum').write_text('# t x y z qx qy qz qw\n' + ''.join(rows))
    s = evaluate(load_run(run)).summary
    assert s['heading_final_error_deg'] == pytest.approx(-179.0, abs=1e-4)
    n_last = int(np.sum(t >= t[-1] - 10.0))
    expected = np.sqrt(((len(t) - n_last) * 1.0 + n_last * 179.0**2) / len(t))
    assert s['heading_rmse_deg'] == pytest.approx(expected, rel=1e-5)
    # No matcher events: no fix to bound a stretch by.
    assert s['longest_stretch_without_fix_m'] is None


def test_false_fixes_without_events_count_episodes(tmp_path: Path):
    bag, t, xy = _bag(tmp_path)
    run = _run_dir(tmp_path, bag)
    est = xy.copy()
    est[100:120, 0] += 20.0
    est[500:510, 0] -= 30.0
    _tum(run / 'global_pose.tum', t, est)  # no covariance file, no events
    s = evaluate(load_run(run)).summary
    assert s['false_fixes'] == 2 and s['consistency_3sigma'] is None
    assert s['distance_before_first_fix_m'] == 0.0


def test_nothing_localized_is_reported_not_a_crash(tmp_path: Path, capsys):
    bag, _, _ = _bag(tmp_path)
    run = _run_dir(tmp_path, bag)
    (run / 'run.yaml').write_text(yaml.safe_dump({'bag': {'dir': str(bag)}, 'nodes': [
        {'name': 'rover_vo', 'status': 'not built'}, {'name': 'darces_matcher', 'status': 'ran'},
        {'name': 'gn_server', 'status': 'no input'}]}))
    (run / 'global_pose.tum').write_text('# t x y z qx qy qz qw\n')
    assert main(['eval', str(run)]) == 0
    out = capsys.readouterr().out
    assert out.startswith('not localized: the run published no /global_pose (route 300 m); '
                          'nodes that did not run: rover_vo (not built), gn_server (no input)')
    report = json.loads((run / 'report.json').read_text())
    assert report['localized'] is False and report['final_error_m'] is None
    assert (run / 'error.png').is_file() and (run / 'route.png').is_file()


def test_bad_inputs_are_one_line_errors(tmp_path: Path):
    with pytest.raises(GloblocError, match='run directory not found'):
        load_run(tmp_path / 'nope')
    bag, _, _ = _bag(tmp_path)
    run = _run_dir(tmp_path, bag)
    with pytest.raises(GloblocError, match=r'neither global_pose\.tum nor outputs/'):
        load_run(run)
    (run / 'global_pose.tum').write_text('1 2 3\n')
    with pytest.raises(GloblocError, match=r'global_pose\.tum:1: expected 8'):
        load_run(run)
    # A run that published no pose reads as no pose; a malformed table names its line.
    (run / 'global_pose.tum').write_text('# t x y z qx qy qz qw\n')
    assert load_run(run).estimate.shape == (0, 8)
    (run / 'alignment.tsv').write_text('# t tx ty yaw\n1.0\t2.0\t3.0\t0.1\n2.0\tnan\t3.0\t0.1\n')
    with pytest.raises(GloblocError, match=r'alignment\.tsv:3: expected 4 finite numbers'):
        load_run(run)
    (bag / 'truth' / 'trajectory.tum').unlink()
    with pytest.raises(GloblocError, match='no ground truth'):
        load_run(run)


def _write_outputs_bag(run: Path, t: np.ndarray, xy: np.ndarray, corrupt_one: bool = False):
    """An outputs bag as ``globloc record`` writes it: /global_pose with covariance,
    /vo/odometry, /matcher/status, /global_alignment."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_JAZZY)
    m = ts.types
    header = lambda ti: m['std_msgs/msg/Header'](  # noqa: E731
        stamp=m['builtin_interfaces/msg/Time'](sec=int(ti), nanosec=round(ti % 1 * 1e9)),
        frame_id='map')
    point = m['geometry_msgs/msg/Point']
    quat = m['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0)
    with Writer(run / 'outputs', version=9, storage_plugin=StoragePlugin.MCAP) as w:
        cp = w.add_connection('/global_pose', 'geometry_msgs/msg/PoseWithCovarianceStamped',
                              typestore=ts)
        co = w.add_connection('/vo/odometry', 'nav_msgs/msg/Odometry', typestore=ts)
        cs = w.add_connection('/matcher/status', 'diagnostic_msgs/msg/DiagnosticArray',
                              typestore=ts)
        cov = np.zeros(36)
        cov[0], cov[1], cov[6], cov[7], cov[14] = 0.04, 0.01, 0.01, 0.09, 1e6
        for i, (ti, (x, y)) in enumerate(zip(t, xy, strict=True)):
            pose = m['geometry_msgs/msg/Pose'](position=point(x=x, y=y, z=0.0), orientation=quat)
            pwc = m['geometry_msgs/msg/PoseWithCovariance'](pose=pose, covariance=cov)
            msg = m['geometry_msgs/msg/PoseWithCovarianceStamped'](header=header(ti), pose=pwc)
            raw = ts.serialize_cdr(msg, 'geometry_msgs/msg/PoseWithCovarianceStamped')
            if corrupt_one and i == 3:
                raw = raw[:10]  # truncated CDR: cannot be decoded
            w.write(cp, int(ti * 1e9), raw)
            twist = m['geometry_msgs/msg/TwistWithCovariance'](
                twist=m['geometry_msgs/msg/Twist'](
                    linear=m['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0),
                    angular=m['geometry_msgs/msg/Vector3'](x=0.0, y=0.0, z=0.0)),
                covariance=np.zeros(36))
            odom = m['nav_msgs/msg/Odometry'](header=header(ti), child_frame_id='base_link',
                                               pose=pwc, twist=twist)
            w.write(co, int(ti * 1e9), ts.serialize_cdr(odom, 'nav_msgs/msg/Odometry'))
        kv = m['diagnostic_msgs/msg/KeyValue']
        status = m['diagnostic_msgs/msg/DiagnosticStatus'](
            level=0, name='darces_matcher', message='localized', hardware_id='x',
            values=[kv(key='event', value='first_fix'), kv(key='reason', value='ok'),
                    kv(key='ln_size', value='12'), kv(key='inliers', value='9')])
        arr = m['diagnostic_msgs/msg/DiagnosticArray'](header=header(t[0]), status=[status])
        # Received 2.5 s after its LN's stamp, as a matcher behind the replay sends it.
        w.write(cs, int((t[0] + 2.5) * 1e9),
                ts.serialize_cdr(arr, 'diagnostic_msgs/msg/DiagnosticArray'))


def test_run_outputs_bag_is_exported_and_evaluated(tmp_path: Path):
    bag, t, xy = _bag(tmp_path)
    run = _run_dir(tmp_path, bag)
    k = slice(600, 1200)
    _write_outputs_bag(run, t[k], xy[k] + [0.3, 0.0], corrupt_one=True)
    ev = evaluate(load_run(run))  # no global_pose.tum yet: exported from outputs/
    assert (run / 'global_pose.tum').is_file() and (run / 'vo.tum').is_file()
    s = ev.summary
    assert s['global_poses'] == 599  # the corrupt message skipped, the others kept
    assert s['final_error_m'] == pytest.approx(0.3, abs=1e-5)
    assert s['distance_before_first_fix_m'] == pytest.approx(60.0, abs=0.11)
    assert s['matcher_events'] == {'first_fix': 1}
    assert s['fix_lag_s'] == pytest.approx({'median': 2.5, 'max': 2.5})
    data = load_run(run)
    np.testing.assert_allclose(data.covariance[0], [[0.04, 0.01], [0.01, 0.09]])
    assert data.z_variance is not None and np.all(data.z_variance == 1e6)
    assert s['z_estimated'] == 'none' and s['ape_unaligned_rmse_m'] is None
    # A cov file of four columns (exported before cov_zz) is exported again from outputs/.
    (run / 'global_pose_cov.tsv').write_text(
        '# t cov_xx cov_xy cov_yy\n' + ''.join(f'{ti:.9f} 0.04 0.01 0.09\n'
                                               for ti in data.estimate[:, 0]))
    assert load_run(run).z_variance is not None
    written = export_outputs(run)
    assert written['undecodable'] == 1 and written['vo.tum'] == 600
    # The odometry's covariance beside vo.tum, a row per pose at the same stamps (what
    # roi_detector ln reads with the odometry).
    assert written['vo_covariance.txt'] == 600
    rows = np.loadtxt(run / 'vo_covariance.txt', comments='#', ndmin=2)
    tum = np.loadtxt(run / 'vo.tum', comments='#', ndmin=2)
    assert rows.shape == (600, 37)
    np.testing.assert_array_equal(rows[:, 0], tum[:, 0])
    np.testing.assert_allclose(rows[0, 1:].reshape(6, 6)[:2, :2], [[0.04, 0.01], [0.01, 0.09]])


def test_cli_eval_json_and_errors(tmp_path: Path, globloc):
    bag, t, xy = _bag(tmp_path)
    run = _run_dir(tmp_path, bag)
    _write_estimate(run, t[::10], xy[::10] + np.array([1.0, 0.0]), np.full(len(t[::10]), 0.5))
    result = globloc(['eval', str(run), '--json', '--no-plots'])
    assert result.returncode == 0, result.stderr
    assert json.loads(result.stdout)['final_error_m'] == pytest.approx(1.0, abs=1e-6)
    result = globloc(['eval', str(tmp_path / 'missing')])
    assert result.returncode == 1 and 'Traceback' not in result.stderr
    missing = tmp_path / 'missing'
    assert result.stderr.strip() == f'globloc: error: run directory not found: {missing}'


def test_subprocess_free_of_display(tmp_path: Path):
    """The plots need no display (Agg), as on CI."""
    bag, t, xy = _bag(tmp_path)
    run = _run_dir(tmp_path, bag)
    _write_estimate(run, t, xy, np.full(len(t), 0.5))
    env = {k: v for k, v in __import__('os').environ.items() if k != 'DISPLAY'}
    env['MPLBACKEND'] = 'TkAgg'  # a GUI backend in the environment must not be used
    code = ('from pathlib import Path; from rover_bringup.report import EvalOptions, '
            f'evaluate_run; evaluate_run(EvalOptions(Path({str(run)!r})))')
    result = subprocess.run([__import__('sys').executable, '-c', code], env=env,
                            capture_output=True, text=True, timeout=120, check=False)
    assert result.returncode == 0, result.stderr
    assert (run / 'route.png').stat().st_size > 10_000


def test_stop_drift_measures_the_odometry_while_the_truth_stands_still():
    import numpy as np

    from rover_bringup.evaluation import stop_drift, stops_of

    t = np.arange(0.0, 60.0, 0.5)
    x = np.where(t < 20, 0.1 * t, np.where(t < 40, 2.0, 2.0 + 0.1 * (t - 40)))
    truth = np.column_stack([t, x, 0 * t, 0 * t, 0 * t, 0 * t, 0 * t, 1 + 0 * t])
    assert stops_of(truth) == [(20.0, 40.0)]
    vo = truth.copy()
    vo[(t > 20) & (t < 40), 1] += 0.01 * (t[(t > 20) & (t < 40)] - 20)  # creeps 1 cm/s
    out = stop_drift(vo, truth)
    assert out['stops'] == 1
    assert out['stop_drift_max_m'] == pytest.approx(0.18, abs=1e-9)  # 21 s .. 39 s
    assert out['stop_yaw_drift_max_deg'] == pytest.approx(0.0, abs=1e-9)
    assert stop_drift(vo[:10], truth) == {}  # no odometry over the stop


def test_eval_prints_a_degraded_runs_status_first(tmp_path: Path):
    """The reasons globloc run wrote in run.yaml come before the figures; an ok run adds
    no line."""
    import yaml

    from rover_bringup.evaluation import summary_lines
    from rover_bringup.run_outputs import run_status

    run = tmp_path / 'run'
    run.mkdir()
    (run / 'run.yaml').write_text(yaml.safe_dump({
        'status': 'degraded', 'exit_code': 3,
        'degraded': ['rover_vo published nothing on /vo/odometry']}))
    s = {'localized': False, 'message': 'not localized', 'run_status': run_status(run)}
    assert summary_lines(s) == ['run status: degraded',
                                '  rover_vo published nothing on /vo/odometry',
                                'not localized']
    (run / 'run.yaml').write_text(yaml.safe_dump({'status': 'ok', 'exit_code': 0}))
    assert summary_lines(s | {'run_status': run_status(run)}) == ['not localized']
