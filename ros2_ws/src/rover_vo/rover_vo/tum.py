"""rover_vo's states as TUM files (:mod:`roi_network.trajectory`'s format), written
atomically."""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

from scipy.spatial.transform import Rotation

from roi_network.trajectory import tum_row, write_rows
from rover_vo.state import OdomState


def tum_line(state: OdomState) -> str:
    """One TUM line of ``odom_T_base``: stamp (s, 9 decimals), position (m), quaternion."""
    return tum_row(state.t, state.p, Rotation.from_matrix(state.R).as_quat())


def write_tum(path: str | Path, states: Iterable[OdomState], header: str = "") -> None:
    """Write the states as a TUM file (base_link in odom), atomically."""
    write_rows(path, header, (tum_line(s) for s in states))

