"""TUM trajectory files (``t x y z qx qy qz qw``), written atomically."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from rover_vo.state import OdomState


def tum_line(state: OdomState) -> str:
    """One TUM line of ``odom_T_base``: stamp (s, 9 decimals), position (m), quaternion."""
    q = Rotation.from_matrix(state.R).as_quat()
    p = state.p
    return (f"{state.t:.9f} {p[0]:.6f} {p[1]:.6f} {p[2]:.6f} "
            f"{q[0]:.9f} {q[1]:.9f} {q[2]:.9f} {q[3]:.9f}")


def write_atomic(path: str | Path, text: str) -> None:
    """Write ``text`` to ``path`` through a temporary file and a rename (no partial file)."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(text)
    tmp.replace(path)


def write_tum(path: str | Path, states: Iterable[OdomState], header: str = "") -> None:
    """Write the states as a TUM file (base_link in odom), atomically."""
    lines = [f"# {header}"] if header else []
    lines += [tum_line(s) for s in states]
    write_atomic(path, "\n".join(lines) + "\n")


def read_tum_array(path: str | Path) -> np.ndarray:
    """(N, 8) array of a TUM file (comments skipped)."""
    return np.loadtxt(path, comments="#", ndmin=2)
