"""Replay the odometry covariance model along a recorded VO trajectory, with other priors.

The covariance of ``rover_vo`` (``rover_vo.state``) depends on the steps only, so it can be
recomputed offline from ``vo.tum`` for any setting of the model and judged against the
truth the way ``vo_bench.py`` judges the published one: mean NEES of the horizontal error
(2 DOF; 2 if honest) and of the heading error (1 DOF; 1 if honest), with the share inside
the 95 % region. The replay uses the distance model only (not the refinement's own
covariance or the IMU-propagated frames' extra noise), so it approximates the published
covariance; ``vo_bench.py`` measures that one.

Usage (from the repository root, after ``source env.sh``)::

    python bench/vo_cov_replay.py bags/quick bags/atacama_1km_s1 --method paper \
        --setting 0.01,0.02,0,0 --setting 0.01,0.02,0.003,0.05

A setting is ``translation_sigma_per_m,rotation_sigma_deg_per_sqrt_m,scale_sigma,
heading_rate_sigma_deg_per_100m`` (config.py ``CovarianceOptions``).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from roi_network.trajectory import read_tum_rows
from rover_vo.state import OdomState, step_noise, systematic_prior

RUNS = Path(__file__).resolve().parent / "results" / "vo_runs"


def replay(est: np.ndarray, setting: tuple[float, float, float, float]) -> np.ndarray:
    """(N, 6, 6) pose covariances along the TUM rows ``est`` under ``setting``."""
    st, sr, ss, sb = setting
    Rs = Rotation.from_quat(est[:, 4:]).as_matrix()
    state = OdomState(est[0, 0], Rs[0], est[0, 1:4].copy(), P=systematic_prior(ss, sb))
    covs = [state.cov.copy()]
    for k in range(1, len(est)):
        dR = state.R.T @ Rs[k]
        dp = state.R.T @ (est[k, 1:4] - state.p)
        state = state.compose(est[k, 0], dR, dp, step_noise(float(np.linalg.norm(dp)), st, sr))
        state.R, state.p = Rs[k], est[k, 1:4].copy()  # stay on the recorded trajectory
        covs.append(state.cov.copy())
    return np.array(covs)


def honesty(est: np.ndarray, ref: np.ndarray, covs: np.ndarray) -> dict:
    """NEES of the horizontal position and of the heading, first poses aligned."""
    A = Rotation.from_quat(ref[0, 4:]).as_matrix() @ Rotation.from_quat(est[0, 4:]).as_matrix().T
    p = (est[:, 1:4] - est[0, 1:4]) @ A.T + ref[0, 1:4]
    err = (p - ref[:, 1:4])[:, :2]
    C = (A @ covs[:, :3, :3] @ A.T)[:, :2, :2]
    ok = np.linalg.det(C) > 1e-12
    nees = np.einsum("ni,nij,nj->n", err[ok], np.linalg.inv(C[ok]), err[ok])
    ye = Rotation.from_matrix(A @ Rotation.from_quat(est[:, 4:]).as_matrix()).as_euler("zyx")[:, 0]
    yr = Rotation.from_quat(ref[:, 4:]).as_euler("zyx")[:, 0]
    dyaw = np.angle(np.exp(1j * (ye - yr)))
    var = covs[:, 5, 5]
    okh = var > 1e-14
    hnees = dyaw[okh] ** 2 / var[okh]
    return {"nees_xy": float(np.mean(nees)), "in95_xy": float(np.mean(nees < 5.991)),
            "nees_heading": float(np.mean(hnees)), "in95_heading": float(np.mean(hnees < 3.841)),
            "final_sigma_xy_m": float(np.sqrt(np.trace(C[-1]))),
            "final_error_xy_m": float(np.linalg.norm(err[-1]))}


def load(bag: Path, method: str) -> tuple[np.ndarray, np.ndarray]:
    est = read_tum_rows(RUNS / bag.name / method / "vo.tum")
    ref = read_tum_rows(bag / "truth" / "trajectory.tum")
    idx = np.clip(np.searchsorted(ref[:, 0], est[:, 0] - 1e-4), 0, len(ref) - 1)
    ref = ref[idx]
    keep = np.abs(ref[:, 0] - est[:, 0]) < 0.02
    return est[keep], ref[keep]


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("bags", nargs="+", type=Path)
    p.add_argument("--method", default="paper")
    p.add_argument("--setting", action="append", required=True,
                   help="translation,rotation,scale,heading_rate (see the module)")
    args = p.parse_args()
    data = []
    for bag in args.bags:
        if not (RUNS / bag.name / args.method / "vo.tum").is_file():
            print(f"{RUNS / bag.name / args.method / 'vo.tum'}: no such file "
                  f"(run bench/vo_bench.py on {bag} first)", file=sys.stderr)
            return 2
        data.append(load(bag, args.method))
    print("| setting | " + " | ".join(b.name for b in args.bags) + " |")
    print("|---|" + "---|" * len(args.bags))
    for text in args.setting:
        setting = tuple(float(x) for x in text.split(","))
        if len(setting) != 4:
            p.error(f"--setting {text}: expected 4 comma-separated numbers")
        cells = []
        for est, ref in data:
            h = honesty(est, ref, replay(est, setting))
            cells.append(f"NEES xy {h['nees_xy']:.2f} ({100 * h['in95_xy']:.0f} %), heading "
                         f"{h['nees_heading']:.2f} ({100 * h['in95_heading']:.0f} %)")
        print(f"| {text} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
