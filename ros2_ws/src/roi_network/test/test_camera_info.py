"""The one CameraInfo check every stereo consumer uses: each unusable field named."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
import pytest

from roi_network.camera_info import camera_info_problem

FX, BASELINE = 400.0, 0.2


def info(side: str = "left", **changes):
    tx = -FX * BASELINE if side == "right" else 0.0
    msg = SimpleNamespace(width=640, height=480, d=[0.0] * 5,
                          k=[FX, 0, 320, 0, FX, 240, 0, 0, 1], r=list(np.eye(3).ravel()),
                          p=[FX, 0, 320, tx, 0, FX, 240, 0, 0, 0, 1, 0])
    for name, value in changes.items():
        if "_" in name:
            field, index = name.split("_")
            getattr(msg, field)[int(index)] = value
        else:
            setattr(msg, name, value)
    return msg


@pytest.mark.parametrize(("side", "changes", "problem"), [
    ("left", {}, None),
    ("right", {}, None),
    ("left", {"k": [0.0] * 9}, None),  # no calibration of the raw camera: P describes it
    ("left", {"k_0": 0.0}, "K[0] (fx) = 0"),
    ("left", {"k_4": -1.0}, "K[4] (fy) = -1"),
    ("left", {"p_5": float("nan")}, "P[5] = nan"),
    ("left", {"d_1": float("inf")}, "D[1] = inf"),
    ("left", {"p": [1.0] * 11}, "P has 11 values, expected 12"),
    ("left", {"width": 0}, "width = 0"),
    ("right", {"p_3": 0.0}, "P[3] (-fx * baseline) = 0: no baseline"),
    ("right", {"p_3": 80.0}, "P[3] (-fx * baseline) = 80 > 0: the right camera sits left "
                             "of the left one; are the left and right topics swapped?"),
])
def test_each_unusable_field_is_named(side, changes, problem):
    assert camera_info_problem(info(side, **changes), side) == problem


def test_a_side_that_is_neither_is_a_programming_error():
    with pytest.raises(ValueError, match="side"):
        camera_info_problem(info(), "middle")
