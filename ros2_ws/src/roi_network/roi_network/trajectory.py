"""The trajectory files the packages exchange: TUM poses and their pose covariance.

- **TUM** (``t x y z qx qy qz qw``): base_link in a frame (the truth in map, rover_vo and
  a run's ``/vo/odometry`` in odom); ``t`` in seconds, 9 decimals; position in metres,
  6 decimals; unit quaternion, 9 decimals.
- **Pose covariance** (:data:`POSE_COVARIANCE_FILE`, beside an odometry's ``vo.tum``):
  ``t`` and the 36 row-major entries of the pose's 6x6 covariance ([x y z rx ry rz] in
  odom; m^2, rad^2), as ``nav_msgs/Odometry.pose.covariance`` carries it.

One row format, one writer and one reader of each: atacama_sim writes the truth,
rover_vo and ``globloc run`` write odometry and its covariance, roi_detector and the
benchmarks read them. Files are written atomically (:func:`~roi_network.files.write_atomic`);
a malformed row is an error naming the file and line.
"""

from __future__ import annotations

from collections.abc import Iterable
from pathlib import Path

import numpy as np

from roi_network.files import write_atomic

#: The columns of a TUM row.
TUM_FIELDS = "t x y z qx qy qz qw"
#: The pose covariance file rover_vo writes beside its ``vo.tum`` (``globloc run`` beside
#: a run's), which ``roi_detector ln`` reads beside the odometry it is given.
POSE_COVARIANCE_FILE = "vo_covariance.txt"
#: What a pose covariance row holds (the file's header line).
POSE_COVARIANCE_FIELDS = "t, pose covariance 6x6 row-major ([x y z rx ry rz] in odom; m^2, rad^2)"


def tum_row(t: float, p: Iterable[float], q_xyzw: Iterable[float]) -> str:
    """One TUM row (no line end) of a pose at ``t`` s: position ``p`` (m) and unit
    quaternion ``q_xyzw``."""
    x, y, z = (float(v) for v in p)
    qx, qy, qz, qw = (float(v) for v in q_xyzw)
    return f"{t:.9f} {x:.6f} {y:.6f} {z:.6f} {qx:.9f} {qy:.9f} {qz:.9f} {qw:.9f}"


def pose_covariance_row(t: float, cov: Iterable[float]) -> str:
    """One pose covariance row (no line end): ``t`` and the 36 row-major entries of a 6x6
    covariance (a (6, 6) array or the 36 values of a ROS message)."""
    values = np.asarray(cov, float).ravel()
    if values.size != 36:
        raise ValueError(f"pose covariance: {values.size} entries, not 36 (6x6)")
    return f"{t:.9f} " + " ".join(f"{v:.6e}" for v in values)


def write_rows(path: str | Path, header: str, rows: Iterable[str]) -> None:
    """Write ``# header`` and the rows, one per line, atomically."""
    lines = [f"# {header}"] if header else []
    lines += list(rows)
    write_atomic(Path(path), "\n".join(lines) + "\n")


def write_tum(path: str | Path, stamps_s, positions, quats_xyzw, header: str = "") -> None:
    """A TUM file of the poses (``header``: what they are; default the columns)."""
    write_rows(path, header or TUM_FIELDS,
               (tum_row(t, p, q) for t, p, q in zip(stamps_s, positions, quats_xyzw,
                                                    strict=True)))


def pose_covariance_header(note: str = "") -> str:
    """The header line of a pose covariance file (without ``# ``): what its rows hold,
    then ``note`` (their source) in parentheses."""
    return POSE_COVARIANCE_FIELDS + (f" ({note})" if note else "")


def write_pose_covariance(path: str | Path, stamps_s, covs, note: str = "") -> None:
    """A pose covariance file (:data:`POSE_COVARIANCE_FILE`) of (N, 6, 6) or (N, 36)
    covariances at ``stamps_s``; ``note`` is appended to the header (their source)."""
    rows = (pose_covariance_row(t, c) for t, c in zip(stamps_s, covs, strict=True))
    write_rows(path, pose_covariance_header(note), rows)


def numeric_rows(path: str | Path, what: str, row: str, width: int,
                 allow_empty: bool = False) -> list[tuple[int, list[float]]]:
    """(line number, values) of each row of a text file of ``width`` finite numbers per
    row, separated by white space (tabs included) or commas (``#`` comments and blank
    lines skipped).

    Args:
        allow_empty: a file without rows gives [] (a run that published nothing) instead
            of an error.

    Raises:
        ValueError: naming the file (and line) of an unreadable file, a malformed row
            (``row`` says what one holds) or, unless ``allow_empty``, a file without rows
            (``what`` it holds).
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise ValueError(f"{path}: cannot read {what} ({exc.strerror})") from None
    rows = []
    for n, line in enumerate(text.splitlines(), 1):
        line = line.strip()
        if not line or line.startswith("#"):
            continue
        try:
            vals = [float(v) for v in line.replace(",", " ").split()]
        except ValueError:
            raise ValueError(f"{path}:{n}: not a row of {row}") from None
        if len(vals) != width or not np.all(np.isfinite(vals)):
            raise ValueError(f"{path}:{n}: expected {width} finite numbers ({row}), got "
                             f"{len(vals)}")
        rows.append((n, vals))
    if not rows and not allow_empty:
        raise ValueError(f"{path}: no {what}")
    return rows


def numeric_table(path: str | Path, what: str, row: str, width: int,
                  allow_empty: bool = False) -> np.ndarray:
    """The rows of :func:`numeric_rows` as an (N, ``width``) array, in file order ((0,
    ``width``) for a file without rows when ``allow_empty``); same errors."""
    rows = numeric_rows(path, what, row, width, allow_empty)
    return np.array([v for _, v in rows], float).reshape(-1, width)


def read_tum_rows(path: str | Path, allow_empty: bool = False) -> np.ndarray:
    """(N, 8) rows of a TUM file, in file order ((0, 8) for a file without rows when
    ``allow_empty``).

    Raises:
        ValueError: naming the file (and line) of the first malformed row, or a file with
            no pose (unless ``allow_empty``).
    """
    return numeric_table(path, "poses", TUM_FIELDS, 8, allow_empty)


def read_pose_covariance_rows(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Stamps (N,) and (N, 6, 6) symmetrised covariances of a pose covariance file, in
    file order.

    Raises:
        ValueError: naming the file (and line) of a malformed row, a non-finite entry, a
            negative variance, or a file with no row.
    """
    stamps, covs = [], []
    for n, vals in numeric_rows(path, "pose covariance rows", "t and a 6x6 pose covariance",
                                37):
        c = np.array(vals[1:]).reshape(6, 6)
        if np.any(np.diag(c) < 0):
            raise ValueError(f"{path}:{n}: negative variance on the diagonal")
        stamps.append(vals[0])
        covs.append(0.5 * (c + c.T))
    return np.asarray(stamps), np.asarray(covs)
