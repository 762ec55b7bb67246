"""``globloc eval``: a run's /global_pose judged against the bag's ground truth. No rclpy.

Metrics (DESIGN.md, "Global pose"; docs/evaluation.md says how to read them), all on the
*unaligned* horizontal error ``|p_est - p_true|`` in the ``map`` frame, each /global_pose
associated with the truth pose of the nearest stamp (evo's ``associate_trajectories``):

- ``distance_before_first_fix_m``: distance driven (along the true route) before the
  first /global_pose;
- ``final_error_m``: error of the last /global_pose (``final_pose_gap_m`` says how much of
  the route was left after it);
- ``rmse_after_first_fix_m``: RMSE over every /global_pose (they start at the first fix);
- ``false_fixes``: fixes (first fix, refinement, switch on /matcher/status) after which the
  published pose is more than 10 m off, "after" counted from when the fix reached the
  graph (the status's receive time; its LN's stamp when the run did not record it);
  without matcher events, the number of episodes of /global_pose more than 10 m off.
  ``fix_lag_s``: how long after their LN's stamp the fixes arrived (median, max; bag
  seconds);
- ``longest_stretch_without_fix_m``: the longest distance driven (along the true route)
  between two fixes after the first, or from the last fix to the end of the route;
  ``error_at_stretch_end_m``: the error of the last /global_pose before that stretch's
  closing fix (the final error when the route ends it): how far the pose drifted with no
  landmark to correct it;
- ``heading_final_error_deg``, ``heading_rmse_deg``: the /global_pose yaw minus the true
  yaw (wrapped to +-180 deg), at the last pose and over every pose;
- ``consistency_3sigma``: fraction of poses whose truth lies inside the published 3-sigma
  ellipse (horizontal covariance, squared Mahalanobis distance <= 9). A Gaussian that is
  exactly right gives 98.9 % (chi-square, 2 degrees of freedom); the target >= 99 % asks
  for a covariance that errs, if at all, on the large side.

Vertical error, apart: ``z_est - z_true`` of the poses whose z is estimated (the matcher
took it from an orbital DTM: its variance, ``cov_zz`` of ``global_pose_cov.tsv``, is below
roi_network.dtm's unknown mark); ``vertical_final_error_m`` (absolute),
``vertical_rmse_m``, ``vertical_max_error_m``, ``vertical_consistency_3sigma`` (share
within 3 sigma_z). evo's unaligned 3D APE of /global_pose (``ape_unaligned_rmse_m``) is
quoted only when every pose has its z estimated; otherwise it is null and ``z_note`` says
why (a z not estimated would make it the odometry's height error). When the run has
``vo.tum``: evo's SE(3)-aligned APE of the visual odometry (the drift the localization
corrects).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from roi_network.dtm import UNKNOWN_THRESHOLD_M2
from roi_network.trajectory import TUM_FIELDS, numeric_table
from rover_bringup.errors import GloblocError
from rover_bringup.gn_check import check_truth_frame
from rover_bringup.run_outputs import (
    ALIGNMENT,
    EVENTS,
    GLOBAL_POSE_COV,
    GLOBAL_POSE_TUM,
    OUTPUTS,
    VO_TUM,
    export_outputs,
    run_status_lines,
)

#: A /global_pose more than this far from the truth is a false fix (DESIGN.md), metres.
FALSE_FIX_M = 10.0
#: The paper's end-of-route error on its 1 km traverse, metres.
PAPER_FINAL_ERROR_M = 13.34
#: Squared Mahalanobis radius of the 3-sigma ellipse.
THREE_SIGMA_CHI2 = 9.0
#: Largest stamp difference for associating a pose with the truth, seconds.
MAX_STAMP_DIFF_S = 0.06
#: Matcher events after which the published alignment changed.
FIX_EVENTS = ('first_fix', 'refined', 'switched')
#: The targets a run is judged against (report.json's ``meets_targets``).
TARGETS = {
    'final_error_m': 1.0,
    'rmse_after_first_fix_m': 1.0,
    'false_fixes': 0,
    'distance_before_first_fix_m': 200.0,
    'consistency_3sigma': 0.99,
}


def read_tum(path: Path) -> np.ndarray:
    """A TUM file as an (N, 8) array (t x y z qx qy qz qw); (0, 8) when it has no rows
    (a run that published no pose).

    Raises:
        GloblocError: Unreadable, or a row that is not 8 finite numbers (the message names
            the file and the line).
    """
    return _read_table(path, 8, TUM_FIELDS)


def _read_table(path: Path, columns: int, row: str) -> np.ndarray:
    """(N, ``columns``) rows of one of the run's files (``row`` says what a row holds);
    (0, ``columns``) for a file without rows; GloblocError naming the file and line."""
    try:
        return numeric_table(path, "rows", row, columns, allow_empty=True)
    except ValueError as exc:
        raise GloblocError(str(exc)) from None


def read_events(path: Path) -> list[tuple[float, str, float | None]]:
    """``matcher_events.tsv`` as (stamp s, event, received s or None) rows; [] when the
    file is absent. ``received`` is when the recorder got the status; files without the
    column give None."""
    if not path.is_file():
        return []
    rows = []
    for line in path.read_text().splitlines():
        if line.startswith('#') or not line.strip():
            continue
        parts = line.split('\t')
        try:
            received = float(parts[5]) if len(parts) > 5 and parts[5].strip() else None
            rows.append((float(parts[0]), parts[1] if len(parts) > 1 else '', received))
        except ValueError:
            continue  # one bad row does not hide the others
    return rows


@dataclass
class RunData:
    """What a run produced and what it is judged against.

    Attributes:
        run_dir: The run directory.
        bag_dir: The bag directory (holds ``truth/``, ``orbital.tif``, ``gn.geojson``).
        estimate: (N, 8) /global_pose, TUM rows (map).
        covariance: (N, 2, 2) horizontal covariance per pose, or None (not recorded).
        z_variance: (N,) variance of each pose's z (m^2; 1e6: not estimated), or None
            (not recorded: a cov file of 4 columns).
        truth: (M, 8) ground-truth base_link poses, TUM rows (map).
        vo: (K, 8) /vo/odometry, TUM rows (odom), or None.
        events: (stamp s, event, received s or None) from /matcher/status
            (:func:`read_events`).
        alignment: (J, 4) /global_alignment rows t tx ty yaw (map -> odom).
        not_run: nodes of the graph that did not run, with why (from run.yaml).
    """

    run_dir: Path
    bag_dir: Path
    estimate: np.ndarray
    covariance: np.ndarray | None
    truth: np.ndarray
    vo: np.ndarray | None = None
    events: list[tuple[float, str, float | None]] = field(default_factory=list)
    alignment: np.ndarray = field(default_factory=lambda: np.zeros((0, 4)))
    not_run: list[str] = field(default_factory=list)
    z_variance: np.ndarray | None = None


def bag_dir_of(run_dir: Path) -> Path:
    """The bag directory a run was made from (``bag.dir`` of its ``run.yaml``)."""
    path = run_dir / 'run.yaml'
    try:
        run = yaml.safe_load(path.read_text())
        bag = Path(run['bag']['dir'])
    except OSError:
        raise GloblocError(f'{run_dir} is not a run directory: no run.yaml '
                           '(give the bag with --bag)') from None
    except (yaml.YAMLError, KeyError, TypeError) as exc:
        raise GloblocError(f'{path}: no bag.dir ({exc})') from None
    return bag


def load_run(run_dir: Path, bag_dir: Path | None = None) -> RunData:
    """Read a run directory (exporting ``outputs/`` to TUM files first if needed).

    Args:
        run_dir: ``out/<bag>/<run>/``.
        bag_dir: The bag directory; default: the one ``run.yaml`` records.

    Raises:
        GloblocError: No such run directory, no /global_pose file and no outputs bag to
            make it from, no truth trajectory, a GN in another map frame than the truth,
            or an unreadable file (named).
    """
    if not run_dir.is_dir():
        raise GloblocError(f'run directory not found: {run_dir}')
    bag_dir = bag_dir if bag_dir is not None else bag_dir_of(run_dir)
    if not (run_dir / GLOBAL_POSE_TUM).is_file():
        if not (run_dir / OUTPUTS).is_dir():
            raise GloblocError(f'{run_dir}: neither {GLOBAL_POSE_TUM} nor {OUTPUTS}/')
        export_outputs(run_dir)
    elif _cov_columns(run_dir / GLOBAL_POSE_COV) == 4 and (run_dir / OUTPUTS).is_dir():
        export_outputs(run_dir)  # exported before the files had cov_zz: export again
    truth_path = bag_dir / 'truth' / 'trajectory.tum'
    if not truth_path.is_file():
        raise GloblocError(f'no ground truth for this run: {truth_path} not found')
    check_truth_frame(bag_dir)
    truth = read_tum(truth_path)
    if len(truth) < 2:
        raise GloblocError(f'{truth_path}: fewer than 2 poses')
    estimate = read_tum(run_dir / GLOBAL_POSE_TUM)
    covariance = z_variance = None
    if (cov_path := run_dir / GLOBAL_POSE_COV).is_file():
        columns = _cov_columns(cov_path) or 5
        cov = _read_table(cov_path, columns, 't cov_xx cov_xy cov_yy cov_zz'
                          if columns == 5 else 't cov_xx cov_xy cov_yy')
        if len(cov) == len(estimate) and np.allclose(cov[:, 0], estimate[:, 0], atol=1e-6):
            covariance = np.stack([np.c_[cov[:, 1], cov[:, 2]], np.c_[cov[:, 2], cov[:, 3]]],
                                  axis=1)
            z_variance = cov[:, 4] if columns == 5 else None
        elif len(estimate):
            raise GloblocError(f'{cov_path}: stamps do not match {GLOBAL_POSE_TUM}')
    # Recorded in arrival order; a restarted matcher can interleave stamps: sort by stamp.
    order = np.argsort(estimate[:, 0], kind='stable')
    estimate = estimate[order]
    covariance = covariance[order] if covariance is not None else None
    z_variance = z_variance[order] if z_variance is not None else None
    vo = read_tum(run_dir / VO_TUM) if (run_dir / VO_TUM).is_file() else None
    alignment = (_read_table(run_dir / ALIGNMENT, 4, 't tx ty yaw')
                 if (run_dir / ALIGNMENT).is_file() else np.zeros((0, 4)))
    return RunData(run_dir, bag_dir, estimate, covariance, truth, vo,
                   read_events(run_dir / EVENTS), alignment, _not_run(run_dir), z_variance)


def _cov_columns(path: Path) -> int | None:
    """Columns of the first data row of ``global_pose_cov.tsv`` (None: no file, no row)."""
    try:
        with path.open() as f:
            for line in f:
                if line.strip() and not line.startswith('#'):
                    return len(line.split())
    except OSError:
        return None
    return None


def _not_run(run_dir: Path) -> list[str]:
    """'name (status)' of the graph's nodes that did not run, from run.yaml ([] if none)."""
    try:
        nodes = yaml.safe_load((run_dir / 'run.yaml').read_text()).get('nodes') or []
        return [f"{n['name']} ({n['status']})" for n in nodes if n.get('status') != 'ran']
    except (OSError, yaml.YAMLError, AttributeError, KeyError, TypeError):
        return []


def longest_stretch(fixes: list[tuple[float, float, str]], t: np.ndarray, error: np.ndarray,
                    route_end_m: float) -> dict[str, float | None]:
    """The longest stretch of route without a fix, after the first, and the error at its
    end (module docstring).

    Args:
        fixes: (time, distance along the route, event) of each fix, in time order.
        t, error: stamp and horizontal error of every associated /global_pose.
        route_end_m: the route's length.
    """
    if not fixes:
        return {'longest_stretch_without_fix_m': None, 'error_at_stretch_end_m': None}
    fixes = sorted(fixes)
    ends = [(d, te) for te, d, _ in fixes[1:]] + [(route_end_m, None)]
    starts = [d for _, d, _ in fixes]
    length, (_, end_t) = max(((end - start, (end, te)) for start, (end, te)
                              in zip(starts, ends, strict=True)), key=lambda x: x[0])
    k = len(t) - 1 if end_t is None else int(np.searchsorted(t, end_t)) - 1
    return {'longest_stretch_without_fix_m': float(length),
            'error_at_stretch_end_m': float(error[k]) if 0 <= k < len(t) else None}


def _trajectory(rows: np.ndarray):
    from evo.core.trajectory import PoseTrajectory3D

    # TUM stores qx qy qz qw; evo wants qw qx qy qz.
    return PoseTrajectory3D(positions_xyz=rows[:, 1:4],
                            orientations_quat_wxyz=rows[:, [7, 4, 5, 6]], timestamps=rows[:, 0])


@dataclass
class Evaluation:
    """Per-pose series (for plots) and the summary (for report.json).

    Attributes:
        summary: the metrics (module docstring), JSON-serialisable.
        t: (N,) stamps of the associated /global_pose, s.
        distance_m: (N,) distance driven at each, along the true route, m.
        error_m: (N,) horizontal error, m.
        vertical_error_m: (N,) signed vertical error z_est - z_true, m; NaN where z is
            not estimated.
        sigma3_m: (N,) 3-sigma bound (3 x the largest horizontal standard deviation), m;
            NaN without covariance.
        estimate_xy: (N, 2) estimated positions (map).
        truth_xy: (N, 2) the associated true positions (map).
        truth_route: (M, 2) the whole true route (map).
        fixes: (stamp, distance driven, event) of each fix event.
    """

    summary: dict[str, Any]
    t: np.ndarray
    distance_m: np.ndarray
    error_m: np.ndarray
    sigma3_m: np.ndarray
    estimate_xy: np.ndarray
    truth_xy: np.ndarray
    truth_route: np.ndarray
    fixes: list[tuple[float, float, str]]
    vertical_error_m: np.ndarray = field(default_factory=lambda: np.zeros(0))


def _cumulative_distance(xy: np.ndarray) -> np.ndarray:
    return np.r_[0.0, np.cumsum(np.linalg.norm(np.diff(xy, axis=0), axis=1))]


def _vo_summary(vo: np.ndarray | None, truth: np.ndarray) -> dict[str, Any] | None:
    """evo's SE(3)-aligned APE of the odometry against the truth (its drift)."""
    if vo is None or len(vo) < 3:
        return None
    from evo.core import metrics, sync

    try:
        ref, est = sync.associate_trajectories(_trajectory(truth), _trajectory(vo),
                                               max_diff=MAX_STAMP_DIFF_S)
        est.align(ref, correct_scale=False)  # Umeyama, SE(3), in place
        ape = metrics.APE(metrics.PoseRelation.translation_part)
        ape.process_data((ref, est))
    except Exception as exc:  # evo raises its own errors on degenerate input
        return {'error': f'evo could not align the odometry: {exc}'}
    stats = ape.get_all_statistics()
    return {'poses': len(vo), 'ape_aligned_rmse_m': float(stats['rmse']),
            'ape_aligned_max_m': float(stats['max']), **stop_drift(vo, truth)}


def stops_of(truth: np.ndarray) -> list[tuple[float, float]]:
    """``(start, end)`` stamps of the truth's stops, as rover_vo's evaluation finds them
    (:func:`rover_vo.evaluation.truth_stops`: still within 2 mm for 10 s or more)."""
    from rover_vo.evaluation import truth_stops

    return truth_stops(truth)


def stop_drift(vo: np.ndarray, truth: np.ndarray) -> dict[str, Any]:
    """How far the odometry moves while the rover stands still (a panorama's stop): per
    truth stop, the odometry's position and yaw change between its poses nearest the
    stop's ends (inside it by 1 s, clear of the braking and the start). Empty without
    stops covered by the odometry."""
    from scipy.spatial.transform import Rotation

    moved, turned = [], []
    for t0, t1 in stops_of(truth):
        a, b = t0 + 1.0, t1 - 1.0
        ia, ib = np.searchsorted(vo[:, 0], a), np.searchsorted(vo[:, 0], b, 'right') - 1
        if ia >= len(vo) or ib < 0 or ib <= ia or vo[ib, 0] < a or vo[ia, 0] > b:
            continue
        moved.append(float(np.linalg.norm(vo[ib, 1:4] - vo[ia, 1:4])))
        ya, yb = (Rotation.from_quat(vo[k, 4:8]).as_euler('ZYX')[0] for k in (ia, ib))
        turned.append(float(np.degrees(abs((yb - ya + np.pi) % (2 * np.pi) - np.pi))))
    if not moved:
        return {}
    return {'stops': len(moved), 'stop_drift_median_m': float(np.median(moved)),
            'stop_drift_max_m': float(np.max(moved)),
            'stop_yaw_drift_median_deg': float(np.median(turned)),
            'stop_yaw_drift_max_deg': float(np.max(turned))}


def evaluate(data: RunData) -> Evaluation:
    """Compute the metrics of the module docstring.

    A run with no /global_pose (nothing localized) gets ``localized: false`` and null
    metrics, not an error.
    """
    truth = data.truth
    route_xy = truth[:, 1:3]
    route_d = _cumulative_distance(route_xy)
    counts: dict[str, int] = {}
    for _, event, _ in data.events:
        counts[event] = counts.get(event, 0) + 1
    # How long after their LN's stamp the fixes reached the graph (bag seconds).
    lags = [received - stamp for stamp, event, received in data.events
            if event in FIX_EVENTS and received is not None]
    summary: dict[str, Any] = {
        'run_dir': str(data.run_dir),
        'bag_dir': str(data.bag_dir),
        'route_length_m': float(route_d[-1]),
        'route_duration_s': float(truth[-1, 0] - truth[0, 0]),
        'global_poses': len(data.estimate),
        'matcher_events': counts,
        'fix_lag_s': ({'median': float(np.median(lags)), 'max': float(np.max(lags))}
                      if lags else None),
        'paper_final_error_m': PAPER_FINAL_ERROR_M,
        'targets': TARGETS,
        'vo': _vo_summary(data.vo, truth),
        'nodes_not_run': data.not_run,
    }
    empty = np.zeros(0)
    nothing = Evaluation(summary, empty, empty, empty, empty, np.zeros((0, 2)),
                         np.zeros((0, 2)), route_xy, [])
    keys = ('distance_before_first_fix_m', 'first_fix_t', 'final_error_m', 'final_pose_gap_m',
            'rmse_after_first_fix_m', 'median_error_m', 'max_error_m', 'false_fixes',
            'longest_stretch_without_fix_m', 'error_at_stretch_end_m',
            'heading_final_error_deg', 'heading_rmse_deg',
            'poses_over_10m', 'consistency_3sigma', 'ape_unaligned_rmse_m', 'z_estimated',
            'vertical_final_error_m', 'vertical_rmse_m', 'vertical_max_error_m',
            'vertical_consistency_3sigma', 'z_note')
    summary.update(dict.fromkeys(keys))
    if len(data.estimate) == 0:
        summary['localized'] = False
        summary['message'] = ('not localized: the run published no /global_pose '
                              f'(route {route_d[-1]:.0f} m)')
        if data.not_run:
            summary['message'] += '; nodes that did not run: ' + ', '.join(data.not_run)
        return nothing

    from evo.core import metrics, sync

    try:
        ref, est = sync.associate_trajectories(_trajectory(truth), _trajectory(data.estimate),
                                               max_diff=MAX_STAMP_DIFF_S)
    except Exception as exc:  # evo.core.sync.SyncException: no common stamps
        summary['localized'] = True
        summary['message'] = (f'{len(data.estimate)} /global_pose but none at a truth stamp '
                              f'(within {MAX_STAMP_DIFF_S} s): {exc}')
        return nothing
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, est))
    est_i = np.searchsorted(data.estimate[:, 0], est.timestamps)
    ref_i = np.clip(np.searchsorted(truth[:, 0], ref.timestamps), 0, len(truth) - 1)
    t = est.timestamps
    est_xy, true_xy = est.positions_xyz[:, :2], ref.positions_xyz[:, :2]
    error = np.linalg.norm(est_xy - true_xy, axis=1)
    distance = route_d[ref_i]

    sigma3 = np.full(len(t), np.nan)
    consistency = None
    if data.covariance is not None:
        cov = data.covariance[est_i]
        eig = np.linalg.eigvalsh(cov)
        valid = (eig[:, 0] > 0) & np.all(np.isfinite(cov.reshape(-1, 4)), axis=1)
        sigma3[valid] = 3.0 * np.sqrt(eig[valid, 1])
        d = (est_xy - true_xy)[valid]
        m2 = np.einsum('ni,nij,nj->n', d, np.linalg.inv(cov[valid]), d)
        consistency = float(np.mean(m2 <= THREE_SIGMA_CHI2)) if valid.any() else None
        summary['poses_with_covariance'] = int(valid.sum())

    vertical = _vertical(data, est_i, est.positions_xyz[:, 2] - ref.positions_xyz[:, 2])
    summary.update(vertical.pop('summary'))
    if summary['z_estimated'] == 'all':
        summary['ape_unaligned_rmse_m'] = float(ape.get_statistic(metrics.StatisticsType.rmse))

    fixes: list[tuple[float, float, str]] = []
    false_fixes = 0
    for stamp, event, received in data.events:
        # A fix is judged by the poses after it reached the graph (its LN's stamp in files
        # recorded without the receive time).
        te = received if received is not None else stamp
        if event not in FIX_EVENTS:
            continue
        k = int(np.searchsorted(t, te))
        d_at = float(np.interp(te, truth[:, 0], route_d))
        fixes.append((te, d_at, event))
        if k < len(t) and error[k] > FALSE_FIX_M:
            false_fixes += 1
    over = error > FALSE_FIX_M
    if not fixes:  # no matcher events recorded: count episodes of large error
        false_fixes = int(over[0]) + int(np.sum(over[1:] & ~over[:-1]))
    first_t = float(data.estimate[0, 0])
    summary.update(longest_stretch(fixes, t, error, float(route_d[-1])))
    # evo's associated trajectories: yaw is the z angle of the static xyz Euler angles.
    dyaw = est.get_orientations_euler()[:, 2] - ref.get_orientations_euler()[:, 2]
    dyaw = np.degrees(np.arctan2(np.sin(dyaw), np.cos(dyaw)))
    summary.update(heading_final_error_deg=float(dyaw[-1]),
                   heading_rmse_deg=float(np.sqrt(np.mean(dyaw**2))))
    summary.update(
        localized=True,
        message=f'localized after {float(np.interp(first_t, truth[:, 0], route_d)):.1f} m',
        first_fix_t=first_t,
        distance_before_first_fix_m=float(np.interp(first_t, truth[:, 0], route_d)),
        final_error_m=float(error[-1]),
        final_pose_gap_m=float(route_d[-1] - distance[-1]),
        rmse_after_first_fix_m=float(np.sqrt(np.mean(error**2))),
        median_error_m=float(np.median(error)),
        max_error_m=float(error.max()),
        false_fixes=int(false_fixes),
        false_fix_rule=('fix events followed by a pose > 10 m off' if fixes
                        else 'episodes of poses > 10 m off (no matcher events recorded)'),
        poses_over_10m=int(over.sum()),
        associated_poses=len(t),
        consistency_3sigma=consistency,
    )
    summary['meets_targets'] = {
        'final_error_m': summary['final_error_m'] <= TARGETS['final_error_m'],
        'rmse_after_first_fix_m':
            summary['rmse_after_first_fix_m'] <= TARGETS['rmse_after_first_fix_m'],
        'false_fixes': false_fixes == 0,
        'distance_before_first_fix_m': summary['distance_before_first_fix_m']
        <= TARGETS['distance_before_first_fix_m'],
        'consistency_3sigma': consistency is not None
        and consistency >= TARGETS['consistency_3sigma'],
    }
    return Evaluation(summary, t, distance, error, sigma3, est_xy, true_xy, route_xy, fixes,
                      vertical['error'])


def _vertical(data: RunData, est_i: np.ndarray, dz: np.ndarray) -> dict[str, Any]:
    """The vertical error of the associated poses whose z is estimated.

    Returns:
        ``summary``: ``z_estimated`` (``all``, ``some``, ``none``, or None when the run
        did not record z's variance), the ``vertical_*`` metrics (null without an
        estimated z) and ``z_note`` (why z, or the 3D APE, is not judged); ``error``:
        (N,) signed error, NaN where z is not estimated.
    """
    out: dict[str, Any] = dict.fromkeys(('vertical_final_error_m', 'vertical_rmse_m',
                                         'vertical_max_error_m',
                                         'vertical_consistency_3sigma'))
    error = np.full(len(dz), np.nan)
    if data.z_variance is None:
        out.update(z_estimated=None, z_note=(
            f'z not judged: {GLOBAL_POSE_COV} has no cov_zz column (exported before it; '
            f'no {OUTPUTS}/ to export it again); evo\'s 3D APE not quoted'))
        return {'summary': out, 'error': error}
    var = data.z_variance[est_i]
    known = np.isfinite(var) & (var >= 0.0) & (var < UNKNOWN_THRESHOLD_M2)
    if not known.any():
        out.update(z_estimated='none', z_note=(
            'z not estimated: /global_pose z variance >= 1e4 m^2 (no DTM beside the bag, '
            'BAG/dtm.tif); evo\'s 3D APE not quoted (it would be the odometry\'s height '
            'since the start against the map\'s altitude)'))
        return {'summary': out, 'error': error}
    error[known] = dz[known]
    e = dz[known]
    out.update(
        z_estimated='all' if known.all() else 'some',
        vertical_final_error_m=float(abs(e[-1])),
        vertical_rmse_m=float(np.sqrt(np.mean(e**2))),
        vertical_max_error_m=float(np.max(np.abs(e))),
        vertical_consistency_3sigma=float(np.mean(e**2 <= THREE_SIGMA_CHI2 * var[known])),
        z_note=None if known.all() else (
            f'z estimated for {int(known.sum())} of {len(known)} poses (the others off the '
            'DTM); the vertical figures are over those; evo\'s 3D APE not quoted'),
    )
    return {'summary': out, 'error': error}


def _fmt(value: Any, unit: str = '', digits: int = 2) -> str:
    if value is None:
        return 'n/a'
    if isinstance(value, float):
        return f'{value:.{digits}f}{unit}'
    return f'{value}{unit}'


def summary_lines(s: dict[str, Any]) -> list[str]:
    """The few lines ``globloc eval`` (and ``make demo``) print."""
    status = run_status_lines(s.get('run_status'))
    if not s.get('localized'):
        return [*status, s['message']]
    cons = s['consistency_3sigma']
    return [*status,
        f"first fix after {_fmt(s['distance_before_first_fix_m'], ' m', 1)} of "
        f"{_fmt(s['route_length_m'], ' m', 0)}",
        f"final error: horizontal {_fmt(s['final_error_m'], ' m')} (paper: "
        f"{PAPER_FINAL_ERROR_M} m at the end of its 1 km route), vertical "
        f"{_vertical_fmt(s, 'vertical_final_error_m')}",
        f"RMSE after first fix: horizontal {_fmt(s['rmse_after_first_fix_m'], ' m')} (max "
        f"{_fmt(s['max_error_m'], ' m')}), vertical {_vertical_fmt(s, 'vertical_rmse_m')}",
        f"false fixes (> 10 m) {s['false_fixes']}",
        f"longest stretch without a fix {_fmt(s.get('longest_stretch_without_fix_m'), ' m', 1)}"
        f", {_fmt(s.get('error_at_stretch_end_m'), ' m')} off at its end; heading "
        f"{_fmt(s.get('heading_final_error_deg'), ' deg')} off at the end",
        f"3-sigma consistency {_fmt(None if cons is None else 100 * cons, ' %', 1)} "
        "(horizontal)",
        _ape_3d_text(s),
    ]


def _vertical_fmt(s: dict[str, Any], key: str) -> str:
    """A vertical figure, or why there is none."""
    if s.get(key) is None:
        return 'n/a (z not estimated)' if s.get('z_estimated') == 'none' else 'n/a'
    return _fmt(s[key], ' m')


def _ape_3d_text(s: dict[str, Any]) -> str:
    """evo's 3D APE when z is estimated at every pose, else why it is not quoted."""
    if s.get('ape_unaligned_rmse_m') is not None:
        return f"evo unaligned APE (3D) RMSE {_fmt(s['ape_unaligned_rmse_m'], ' m')}"
    return s.get('z_note') or "evo's 3D APE not quoted"


def report_markdown(s: dict[str, Any], plots: list[str]) -> str:
    """``report.md``: the summary table, targets and the plots."""
    out = [f"# Run {Path(s['run_dir']).name} on {Path(s['bag_dir']).name}", '',
           f"**{s['message']}**", '']
    if s.get('localized') and s.get('final_error_m') is not None:
        meets = s['meets_targets']
        cons = s['consistency_3sigma']
        rows = [
            ('distance driven before the first fix', _fmt(s['distance_before_first_fix_m'],
                                                          ' m', 1),
             '<= 200 m', meets['distance_before_first_fix_m']),
            ('final horizontal error', _fmt(s['final_error_m'], ' m'),
             f'<= 1 m (paper {PAPER_FINAL_ERROR_M} m)', meets['final_error_m']),
            ('horizontal RMSE after the first fix', _fmt(s['rmse_after_first_fix_m'], ' m'),
             '<= 1 m',
             meets['rmse_after_first_fix_m']),
            ('false fixes (> 10 m)', str(s['false_fixes']), '0', meets['false_fixes']),
            ('3-sigma consistency (horizontal)',
             _fmt(None if cons is None else 100 * cons, ' %', 1), '>= 99 %',
             meets['consistency_3sigma']),
            ('longest stretch without a fix / error at its end',
             f"{_fmt(s.get('longest_stretch_without_fix_m'), ' m', 1)} / "
             f"{_fmt(s.get('error_at_stretch_end_m'), ' m')}", '-', None),
            ('heading error, final / RMSE', f"{_fmt(s.get('heading_final_error_deg'), ' deg')} / "
             f"{_fmt(s.get('heading_rmse_deg'), ' deg')}", '-', None),
            ('final vertical error', _vertical_fmt(s, 'vertical_final_error_m'), '-', None),
            ('vertical RMSE after the first fix', _vertical_fmt(s, 'vertical_rmse_m'), '-',
             None),
        ]
        out += ['| metric | value | target | met |', '|---|---|---|---|']
        out += [f'| {a} | {b} | {c} | {"-" if d is None else "yes" if d else "no"} |'
                for a, b, c, d in rows]
        out += ['', f"Route {_fmt(s['route_length_m'], ' m', 0)}; "
                f"{s['global_poses']} /global_pose; the last one "
                f"{_fmt(s['final_pose_gap_m'], ' m', 1)} before the end of the route; "
                f"median error {_fmt(s['median_error_m'], ' m')}, max "
                f"{_fmt(s['max_error_m'], ' m')}; {_ape_3d_text(s)}. False fixes counted "
                f"as: {s['false_fix_rule']}."]
    if s.get('matcher_events'):
        out += ['', 'Matcher events: ' + ', '.join(f'{k} {v}' for k, v in
                                                   sorted(s['matcher_events'].items()))]
    if s.get('fix_lag_s'):
        out += ['', f"Fixes reached the graph {s['fix_lag_s']['median']:.1f} s (median) and at "
                    f"most {s['fix_lag_s']['max']:.1f} s (bag time) after their LN's stamp."]
    if s.get('vo') and 'ape_aligned_rmse_m' in s['vo']:
        out += ['', f"Visual odometry: {s['vo']['poses']} poses, evo SE(3)-aligned APE RMSE "
                f"{_fmt(s['vo']['ape_aligned_rmse_m'], ' m')}."]
        if s['vo'].get('stops'):
            v = s['vo']
            out += [f"Through its {v['stops']} stops the odometry moved "
                    f"{_fmt(v['stop_drift_median_m'] * 1000, ' mm', 1)} median, "
                    f"{_fmt(v['stop_drift_max_m'] * 1000, ' mm', 1)} at most, and turned "
                    f"{_fmt(v['stop_yaw_drift_max_deg'], ' deg', 3)} at most."]
    out += ['']
    out += [f'![{p}]({p})' for p in plots]
    return '\n'.join(out) + '\n'
