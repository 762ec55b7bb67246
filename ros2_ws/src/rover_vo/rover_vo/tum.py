"""rover_vo's states as the shared trajectory files (:mod:`roi_network.trajectory`): TUM
poses and their pose covariance, written atomically."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from roi_network.trajectory import (
    POSE_COVARIANCE_FIELDS,
    pose_covariance_row,
    tum_row,
    write_rows,
)
from rover_vo.state import OdomState


def tum_line(state: OdomState) -> str:
    """One TUM line of ``odom_T_base``: stamp (s, 9 decimals), position (m), quaternion."""
    return tum_row(state.t, state.p, Rotation.from_matrix(state.R).as_quat())


def write_tum(path: str | Path, states: Iterable[OdomState], header: str = "") -> None:
    """Write the states as a TUM file (base_link in odom), atomically."""
    write_rows(path, header, (tum_line(s) for s in states))


def write_pose_covariance(path: str | Path, states: Iterable[OdomState], note: str = "") -> None:
    """Write each state's pose covariance (:data:`~roi_network.trajectory.POSE_COVARIANCE_FILE`
    format: ``t`` and its 36 row-major entries, [x y z rx ry rz] in odom), atomically."""
    header = POSE_COVARIANCE_FIELDS + (f" ({note})" if note else "")
    write_rows(path, header, (pose_covariance_row(s.t, s.cov) for s in states))


def read_tum_array(path: str | Path) -> np.ndarray:
    """(N, 8) array of a TUM file (comments skipped)."""
    return np.loadtxt(path, comments="#", ndmin=2)
