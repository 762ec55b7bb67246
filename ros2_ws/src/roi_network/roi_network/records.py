"""The ROI record: one row per rock or outcrop, shared by detections, tracks, LN and GN.

One numpy structured dtype, one field order, used by every part of the system and by the
PointCloud2 and GeoJSON codecs. Positions are in metres in the frame of the network that
holds the records (``base_link``, ``odom`` or ``map``).
"""

from __future__ import annotations

from typing import Final

import numpy as np

ROCK: Final = 1
OUTCROP: Final = 2
#: Class label (uint8 in the record) -> class name used in files.
LABEL_NAMES: Final[dict[int, str]] = {ROCK: "rock", OUTCROP: "outcrop"}
#: Class name -> label.
LABELS: Final[dict[str, int]] = {name: label for label, name in LABEL_NAMES.items()}

#: Field order and types of DESIGN.md's ROI record. Packed (no padding) so that the
#: PointCloud2 layout is exactly these fields back to back.
ROI_DTYPE: Final = np.dtype(
    [
        ("x", "<f8"),
        ("y", "<f8"),
        ("z", "<f8"),
        ("id", "<u4"),
        ("label", "u1"),
        ("area_m2", "<f4"),
        ("height_m", "<f4"),
        ("major_m", "<f4"),
        ("minor_m", "<f4"),
        ("angle_rad", "<f4"),
        ("score", "<f4"),
        ("cov_xx", "<f4"),
        ("cov_xy", "<f4"),
        ("cov_yy", "<f4"),
        ("n_obs", "<u4"),
    ]
)

#: Names of the record fields, in order.
ROI_FIELDS: Final[tuple[str, ...]] = tuple(ROI_DTYPE.names or ())


def empty_records(n: int = 0) -> np.ndarray:
    """Return ``n`` zeroed ROI records."""
    return np.zeros(n, dtype=ROI_DTYPE)


def as_records(array: np.ndarray) -> np.ndarray:
    """Validate that ``array`` is a 1-D array of ROI records and return it.

    Raises:
        TypeError: if the dtype is not :data:`ROI_DTYPE` (names the first differing field).
        ValueError: if the array is not 1-D or holds an unknown class label.
    """
    if not isinstance(array, np.ndarray) or array.dtype.names is None:
        raise TypeError("ROI records must be a numpy structured array with ROI_DTYPE")
    if array.dtype != ROI_DTYPE:
        for name in ROI_FIELDS:
            if name not in array.dtype.names:
                raise TypeError(f"ROI records: missing field '{name}'")
            if array.dtype[name] != ROI_DTYPE[name]:
                raise TypeError(
                    f"ROI records: field '{name}' has type {array.dtype[name]}, "
                    f"expected {ROI_DTYPE[name]}"
                )
        extra = [n for n in array.dtype.names if n not in ROI_FIELDS]
        raise TypeError(f"ROI records: unexpected field(s) {extra} or field order differs")
    if array.ndim != 1:
        raise ValueError(f"ROI records must be 1-D, got shape {array.shape}")
    bad = ~np.isin(array["label"], list(LABEL_NAMES))
    if bad.any():
        raise ValueError(
            f"ROI records: field 'label' has unknown class {int(array['label'][bad][0])} "
            f"(known: {LABEL_NAMES})"
        )
    return array


def xy(records: np.ndarray) -> np.ndarray:
    """Return the (N, 2) float64 array of record positions."""
    return np.column_stack([records["x"], records["y"]]).astype(np.float64, copy=False)
