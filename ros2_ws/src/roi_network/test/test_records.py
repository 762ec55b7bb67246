import numpy as np
import pytest

from roi_network import ROI_DTYPE, ROI_FIELDS, RoiNetwork, as_records, empty_records, xy


def test_record_layout_is_the_design_contract():
    assert ROI_FIELDS == ("x", "y", "z", "id", "label", "area_m2", "height_m", "major_m",
                          "minor_m", "angle_rad", "score", "cov_xx", "cov_xy", "cov_yy",
                          "n_obs")
    assert ROI_DTYPE.itemsize == 3 * 8 + 4 + 1 + 9 * 4 + 4  # packed, no padding


def test_as_records_names_the_problem():
    with pytest.raises(TypeError, match="missing field 'n_obs'"):
        as_records(np.zeros(1, dtype=[(n, ROI_DTYPE[n]) for n in ROI_FIELDS[:-1]]))
    wrong = np.dtype([(n, "<f8" if n == "score" else ROI_DTYPE[n]) for n in ROI_FIELDS])
    with pytest.raises(TypeError, match="'score'"):
        as_records(np.zeros(1, dtype=wrong))
    with pytest.raises(ValueError, match="'label'"):
        as_records(empty_records(2))  # label 0 is no class
    with pytest.raises(TypeError):
        as_records(np.zeros(3))


def test_network_container():
    records = empty_records(3)
    records["label"] = [1, 2, 1]
    records["x"], records["y"] = [1, 2, 3], [4, 5, 6]
    net = RoiNetwork(records, "odom")
    assert len(net) == 3 and len(net.by_label(1)) == 2
    np.testing.assert_array_equal(xy(net.records), [[1, 4], [2, 5], [3, 6]])
    assert len(RoiNetwork.empty("map")) == 0
    with pytest.raises(ValueError, match="'frame_id'"):
        RoiNetwork(records, "")
