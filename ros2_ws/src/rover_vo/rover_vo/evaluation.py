"""VO metrics with evo (DESIGN.md "Metrics"): KITTI-style relative translation error over
100..800 m segments, heading drift over 100 m segments, aligned APE, final position error
as a share of the distance travelled; and how far the estimate moved across each stop of
the truth (a stop, mast panorama or not, must neither drift nor jump). Evaluation code
only: this is where truth is read.
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

SEGMENTS_M = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)
#: A stop: the truth stays within this of its first pose (m) ...
STOP_STILL_M = 0.002
#: ... for at least this long (s), as ``globloc eval`` counts stops.
STOP_MIN_S = 10.0
#: The poses of a stop are those this far inside its ends (s): clear of braking and
#: starting.
STOP_MARGIN_S = 1.0


class EvalError(ValueError):
    """A trajectory file that cannot be evaluated (the message names it)."""


@dataclass
class VoMetrics:
    """Figures of one estimated trajectory against the truth.

    Attributes:
        distance_m: path length of the truth over the estimate's time span.
        poses: associated poses.
        kitti_drift_pct: mean translation error over all 100..800 m segments (% of length).
        kitti_rot_deg_per_100m: mean rotation error over those segments (deg per 100 m).
        segments: number of segment pairs averaged (all lengths).
        heading_drift_deg_per_100m: mean |heading change error| over 100 m segments.
        heading_error_deg_max, heading_error_deg_final: the heading's error from the
            start (the first poses' headings aligned, no fit): largest and last |error|;
            what an absolute heading reference (a sun sensor) bounds.
        ape_rmse_m: RMSE of the position after an SE(3) Umeyama alignment.
        final_error_m, final_error_pct: end-point error with the first poses aligned, and
            as % of distance_m.
        per_length: {length_m: translation error %} of each segment length with data.
        stops: stops of the truth with at least two estimated poses (:func:`stop_drift`).
        stop_position_mm_max, stop_position_mm_mean: the estimate's position change from
            the first to the last pose of a stop (mm), largest and mean over the stops.
        stop_yaw_deg_max: largest |yaw change| from the first to the last pose of a stop.
        stop_excursion_mm_max: largest distance of any pose of a stop from its first (mm):
            a jump that comes back shows here, not in the change.
        stop_error_mm_max, stop_error_mm_mean: error of the estimate's motion from the
            last pose before a stop to its last pose in it, against the truth's (mm):
            what the change counts of the rover's creep into the stop after its last pair
            is not an error.
        stop_yaw_error_deg_max: largest |yaw error| of that motion.
    """

    distance_m: float
    poses: int
    kitti_drift_pct: float
    kitti_rot_deg_per_100m: float
    segments: int
    heading_drift_deg_per_100m: float
    heading_error_deg_max: float
    heading_error_deg_final: float
    ape_rmse_m: float
    final_error_m: float
    final_error_pct: float
    per_length: dict
    stops: int = 0
    stop_position_mm_max: float = float("nan")
    stop_position_mm_mean: float = float("nan")
    stop_yaw_deg_max: float = float("nan")
    stop_excursion_mm_max: float = float("nan")
    stop_error_mm_max: float = float("nan")
    stop_error_mm_mean: float = float("nan")
    stop_yaw_error_deg_max: float = float("nan")

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass
class StopDrift:
    """The estimate across one stop of the truth.

    Attributes:
        start_s, end_s: the stop (truth stamps, s).
        poses: estimated poses inside it.
        position_mm: position change from the first to the last of them (mm).
        yaw_deg: yaw change from the first to the last (deg, signed).
        excursion_mm: largest distance of any of them from the first (mm).
        error_mm: error of the estimate's motion from its last pose before them to the
            last of them, against the truth's (in the body frame of the former; mm). A
            rover that stops after its last pair and takes no pair before its mast pans
            creeps into the stop unseen; the change shows the creep, this does not.
        yaw_error_deg: the yaw error of that motion (deg, signed).
    """

    start_s: float
    end_s: float
    poses: int
    position_mm: float
    yaw_deg: float
    excursion_mm: float
    error_mm: float = float("nan")
    yaw_error_deg: float = float("nan")


def truth_stops(truth: np.ndarray) -> list[tuple[float, float]]:
    """``(start, end)`` stamps of the truth's stops (``truth``: TUM rows): runs of poses
    within :data:`STOP_STILL_M` of the run's first, at least :data:`STOP_MIN_S` long."""
    stops, i, n = [], 0, len(truth)
    while i < n:
        j = i
        while j + 1 < n and np.linalg.norm(truth[j + 1, 1:4] - truth[i, 1:4]) < STOP_STILL_M:
            j += 1
        if truth[j, 0] - truth[i, 0] >= STOP_MIN_S:
            stops.append((float(truth[i, 0]), float(truth[j, 0])))
        i = j + 1
    return stops


def stop_drift(estimate: np.ndarray, truth: np.ndarray) -> list[StopDrift]:
    """How the estimate moved across each stop of the truth (both TUM rows; the pose
    change needs no alignment): its poses from :data:`STOP_MARGIN_S` after the stop's
    start to as long before its end. Stops with fewer than two of them are left out."""
    from scipy.spatial.transform import Rotation, Slerp

    def wrap_deg(a: float) -> float:
        return float(np.degrees(np.angle(np.exp(1j * a))))

    t = estimate[:, 0]
    slerp = Slerp(truth[:, 0], Rotation.from_quat(truth[:, 4:8]))
    out = []
    for t0, t1 in truth_stops(truth):
        window = np.flatnonzero((t >= t0 + STOP_MARGIN_S) & (t <= t1 - STOP_MARGIN_S))
        if len(window) < 2:
            continue
        inside = estimate[window]
        p = inside[:, 1:4]
        yaw = Rotation.from_quat(inside[[0, -1], 4:8]).as_euler("ZYX")[:, 0]
        d = StopDrift(start_s=t0, end_s=t1, poses=len(inside),
                      position_mm=float(np.linalg.norm(p[-1] - p[0]) * 1e3),
                      yaw_deg=wrap_deg(yaw[1] - yaw[0]),
                      excursion_mm=float(np.linalg.norm(p - p[0], axis=1).max() * 1e3))
        a, b = window[0] - 1, window[-1]
        if a >= 0 and truth[0, 0] <= t[a]:
            ta, tb = t[a], t[b]
            p_true = [np.array([np.interp(s, truth[:, 0], truth[:, k]) for k in (1, 2, 3)])
                      for s in (ta, tb)]
            R_true = slerp([ta, tb])
            R_est = Rotation.from_quat(estimate[[a, b], 4:8])
            moved_true = R_true[0].inv().apply(p_true[1] - p_true[0])
            moved_est = R_est[0].inv().apply(estimate[b, 1:4] - estimate[a, 1:4])
            d.error_mm = float(np.linalg.norm(moved_est - moved_true) * 1e3)
            yaw_true = R_true.as_euler("ZYX")[:, 0]
            yaw_est = R_est.as_euler("ZYX")[:, 0]
            d.yaw_error_deg = wrap_deg((yaw_est[1] - yaw_est[0]) - (yaw_true[1] - yaw_true[0]))
        out.append(d)
    return out


def read_tum(path: str | Path):
    """An evo PoseTrajectory3D of a TUM file; EvalError when unreadable or empty."""
    from evo.tools import file_interface

    path = Path(path)
    if not path.is_file():
        raise EvalError(f"{path}: no such file")
    try:
        traj = file_interface.read_tum_trajectory_file(str(path))
    except Exception as exc:  # evo raises its own FileInterfaceException and numpy errors
        raise EvalError(f"{path}: not a TUM trajectory (t x y z qx qy qz qw): {exc}") from exc
    if traj.num_poses < 2:
        raise EvalError(f"{path}: fewer than 2 poses")
    return traj


def _yaw(R: np.ndarray) -> np.ndarray:
    return np.arctan2(R[..., 1, 0], R[..., 0, 0])


def evaluate(est_path: str | Path, truth_path: str | Path,
             segments_m: tuple[float, ...] = SEGMENTS_M) -> VoMetrics:
    """Evaluate the estimate against the truth (both TUM; associated by stamp)."""
    from evo.core import filters, metrics, sync
    from evo.core.units import Unit

    est = read_tum(est_path)
    ref = read_tum(truth_path)
    try:
        ref, est = sync.associate_trajectories(ref, est, max_diff=0.02)
    except sync.SyncException as exc:
        raise EvalError(f"{est_path}: no stamps in common with {truth_path}: {exc}") from exc
    distance = float(ref.path_length)
    errs, rots, per_length = [], [], {}
    for length in segments_m:
        if length > distance:
            break
        try:
            rpe = metrics.RPE(metrics.PoseRelation.translation_part, delta=length,
                              delta_unit=Unit.meters, rel_delta_tol=0.1, all_pairs=True)
            rpe.process_data((ref, est))
            rpe_r = metrics.RPE(metrics.PoseRelation.rotation_angle_deg, delta=length,
                                delta_unit=Unit.meters, rel_delta_tol=0.1, all_pairs=True)
            rpe_r.process_data((ref, est))
        except (metrics.MetricsException, filters.FilterException):
            continue  # no segment of that length in the associated poses
        e = rpe.error / length * 100.0
        errs.append(e)
        rots.append(rpe_r.error / length * 100.0)
        per_length[int(length)] = round(float(np.mean(e)), 4)
    kitti = float(np.mean(np.concatenate(errs))) if errs else float("nan")
    kitti_rot = float(np.mean(np.concatenate(rots))) if rots else float("nan")
    n_seg = int(sum(len(e) for e in errs))
    # Heading drift: error of the heading change (yaw about the vertical) over 100 m.
    heading = float("nan")
    if distance >= 100.0:
        ids = filters.filter_pairs_by_path(ref.poses_se3, 100.0, 10.0, all_pairs=True)
        if ids:
            i, j = np.array(ids).T
            Rr = np.array(ref.poses_se3)[:, :3, :3]
            Re = np.array(est.poses_se3)[:, :3, :3]
            d_ref = _yaw(Rr[j]) - _yaw(Rr[i])
            d_est = _yaw(Re[j]) - _yaw(Re[i])
            err = np.abs(np.angle(np.exp(1j * (d_est - d_ref))))
            lengths = np.abs(np.array([ref.distances[b] - ref.distances[a] for a, b in ids]))
            heading = float(np.mean(np.degrees(err) / lengths * 100.0))
    yaw_ref = _yaw(np.array(ref.poses_se3)[:, :3, :3])
    yaw_est = _yaw(np.array(est.poses_se3)[:, :3, :3])
    from_start = np.degrees(np.abs(np.angle(np.exp(1j * ((yaw_est - yaw_est[0])
                                                          - (yaw_ref - yaw_ref[0]))))))
    aligned = copy.deepcopy(est)
    aligned.align(ref, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, aligned))
    origin = copy.deepcopy(est)
    origin.align_origin(ref)
    final = float(np.linalg.norm(origin.positions_xyz[-1] - ref.positions_xyz[-1]))
    stops = stop_drift(_tum_rows(est_path), _tum_rows(truth_path))
    stop_figures = {}
    if stops:
        mm = [d.position_mm for d in stops]
        stop_figures = {
            "stop_position_mm_max": round(max(mm), 3),
            "stop_position_mm_mean": round(float(np.mean(mm)), 3),
            "stop_yaw_deg_max": round(max(abs(d.yaw_deg) for d in stops), 4),
            "stop_excursion_mm_max": round(max(d.excursion_mm for d in stops), 3)}
        err = [d for d in stops if np.isfinite(d.error_mm)]
        if err:
            stop_figures.update({
                "stop_error_mm_max": round(max(d.error_mm for d in err), 3),
                "stop_error_mm_mean": round(float(np.mean([d.error_mm for d in err])), 3),
                "stop_yaw_error_deg_max": round(max(abs(d.yaw_error_deg) for d in err), 4)})
    return VoMetrics(
        distance_m=round(distance, 3), poses=int(est.num_poses),
        kitti_drift_pct=round(kitti, 4), kitti_rot_deg_per_100m=round(kitti_rot, 4),
        segments=n_seg, heading_drift_deg_per_100m=round(heading, 4),
        heading_error_deg_max=round(float(from_start.max()), 4),
        heading_error_deg_final=round(float(from_start[-1]), 4),
        ape_rmse_m=round(float(ape.get_statistic(metrics.StatisticsType.rmse)), 4),
        final_error_m=round(final, 4),
        final_error_pct=round(100.0 * final / distance, 4) if distance > 0 else float("nan"),
        per_length=per_length, stops=len(stops), **stop_figures)


def grid_heading_error_deg(est_path: str | Path, truth_path: str | Path,
                           odom_grid_yaw_deg: float) -> float:
    """Error of the absolute heading at the estimate's last pose, deg (signed).

    The absolute heading is the odometry's yaw plus the yaw of the odom frame in the map's
    grid that the sun heading estimated (rover_vo's status ``sun.odom_grid_yaw_deg``); the
    truth (map frame) is taken at the truth row nearest the estimate's last stamp. What a
    sun sensor bounds, where the heading error from the start is what the odometry alone
    keeps."""
    est, truth = _tum_rows(est_path), _tum_rows(truth_path)
    k = int(np.argmin(np.abs(truth[:, 0] - est[-1, 0])))
    from scipy.spatial.transform import Rotation

    yaw_est = _yaw(Rotation.from_quat(est[-1, 4:8]).as_matrix())
    yaw_truth = _yaw(Rotation.from_quat(truth[k, 4:8]).as_matrix())
    err = yaw_est + np.radians(odom_grid_yaw_deg) - yaw_truth
    return float(np.degrees(np.angle(np.exp(1j * err))))


def _tum_rows(path: str | Path) -> np.ndarray:
    from roi_network.trajectory import read_tum_rows

    try:
        return read_tum_rows(path)
    except ValueError as exc:
        raise EvalError(str(exc)) from None


def plot_trajectories(est_path: str | Path, truth_path: str | Path, out_png: str | Path,
                      title: str = "") -> None:
    """Top view of the estimate (first pose aligned) over the truth, written to a PNG."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from evo.core import sync

    est, ref = read_tum(est_path), read_tum(truth_path)
    ref, est = sync.associate_trajectories(ref, est, max_diff=0.02)
    est.align_origin(ref)
    fig, ax = plt.subplots(figsize=(7, 7))
    ax.plot(*ref.positions_xyz[:, :2].T, "k-", lw=1.5, label="truth")
    ax.plot(*est.positions_xyz[:, :2].T, "r-", lw=1.0, label="rover_vo (first pose aligned)")
    ax.plot(*ref.positions_xyz[0, :2], "go", label="start")
    ax.set_aspect("equal")
    ax.set_xlabel("x (m, map)")
    ax.set_ylabel("y (m, map)")
    ax.legend()
    ax.set_title(title or Path(est_path).name)
    out_png = Path(out_png)
    tmp = out_png.with_name(out_png.name + ".tmp.png")
    fig.savefig(tmp, dpi=110)
    plt.close(fig)
    tmp.replace(out_png)
