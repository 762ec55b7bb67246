"""VO metrics with evo (DESIGN.md "Metrics"): KITTI-style relative translation error over
100..800 m segments, heading drift over 100 m segments, aligned APE, final position error
as a share of the distance travelled. Evaluation code only: this is where truth is read.
"""

from __future__ import annotations

import copy
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

SEGMENTS_M = (100.0, 200.0, 300.0, 400.0, 500.0, 600.0, 700.0, 800.0)


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
        ape_rmse_m: RMSE of the position after an SE(3) Umeyama alignment.
        final_error_m, final_error_pct: end-point error with the first poses aligned, and
            as % of distance_m.
        per_length: {length_m: translation error %} of each segment length with data.
    """

    distance_m: float
    poses: int
    kitti_drift_pct: float
    kitti_rot_deg_per_100m: float
    segments: int
    heading_drift_deg_per_100m: float
    ape_rmse_m: float
    final_error_m: float
    final_error_pct: float
    per_length: dict

    def as_dict(self) -> dict:
        return asdict(self)


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
    aligned = copy.deepcopy(est)
    aligned.align(ref, correct_scale=False)
    ape = metrics.APE(metrics.PoseRelation.translation_part)
    ape.process_data((ref, aligned))
    origin = copy.deepcopy(est)
    origin.align_origin(ref)
    final = float(np.linalg.norm(origin.positions_xyz[-1] - ref.positions_xyz[-1]))
    return VoMetrics(
        distance_m=round(distance, 3), poses=int(est.num_poses),
        kitti_drift_pct=round(kitti, 4), kitti_rot_deg_per_100m=round(kitti_rot, 4),
        segments=n_seg, heading_drift_deg_per_100m=round(heading, 4),
        ape_rmse_m=round(float(ape.get_statistic(metrics.StatisticsType.rmse)), 4),
        final_error_m=round(final, 4),
        final_error_pct=round(100.0 * final / distance, 4) if distance > 0 else float("nan"),
        per_length=per_length)


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
