"""Hypothesis strategies for ROI records, shared by the codec tests."""

from __future__ import annotations

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from roi_network.records import LABEL_NAMES, ROI_DTYPE


def _finite(dtype: np.dtype) -> st.SearchStrategy:
    if dtype.kind == "f":
        width = 32 if dtype.itemsize == 4 else 64
        return st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False, width=width)
    if dtype.kind == "u":
        return st.integers(0, 2 ** (8 * dtype.itemsize) - 1)
    raise AssertionError(dtype)


@st.composite
def roi_records(draw: st.DrawFn, max_size: int = 40) -> np.ndarray:
    """Arrays of ROI records with every field drawn over its range (labels valid)."""
    n = draw(st.integers(0, max_size))
    records = np.zeros(n, dtype=ROI_DTYPE)
    for name in ROI_DTYPE.names:
        if name == "label":
            elements = st.sampled_from(sorted(LABEL_NAMES))
        else:
            elements = _finite(ROI_DTYPE[name])
        records[name] = draw(hnp.arrays(ROI_DTYPE[name], n, elements=elements))
    return records
