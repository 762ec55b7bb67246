import numpy as np
import pytest
from hypothesis import given, settings
from roi_strategies import roi_records
from sensor_msgs.msg import PointCloud2, PointField

from roi_network.pointcloud import PointCloudFormatError, from_pointcloud2, to_pointcloud2
from roi_network.records import ROI_DTYPE, empty_records


@settings(deadline=None, max_examples=60)
@given(roi_records())
def test_round_trip_is_exact(records):
    msg = to_pointcloud2(records, "odom", stamp=1_700_000_000_123_456_789)
    assert msg.header.frame_id == "odom"
    assert msg.header.stamp.sec == 1_700_000_000 and msg.header.stamp.nanosec == 123_456_789
    assert msg.width == len(records) and msg.point_step == ROI_DTYPE.itemsize
    back = from_pointcloud2(msg)
    assert back.dtype == ROI_DTYPE
    assert back.tobytes() == records.tobytes()


def test_decodes_padded_layout_from_another_tool():
    records = empty_records(3)
    records["x"] = [1.5, -2.0, 3.25]
    records["label"] = [1, 2, 1]
    records["n_obs"] = [4, 5, 6]
    # Same fields, reversed order, 8-byte aligned: what a C++ struct would produce.
    names = list(ROI_DTYPE.names)[::-1]
    padded = np.dtype({"names": names, "formats": [ROI_DTYPE[n] for n in names],
                       "offsets": [8 * i for i in range(len(names))],
                       "itemsize": 8 * len(names)})
    wire = np.zeros(3, dtype=padded)
    for n in names:
        wire[n] = records[n]
    msg = to_pointcloud2(records, "map")
    types = {f.name: f.datatype for f in msg.fields}
    msg.fields = [PointField(name=n, offset=8 * i, datatype=types[n], count=1)
                  for i, n in enumerate(names)]
    msg.point_step = padded.itemsize
    msg.row_step = padded.itemsize * 3
    msg.data = wire.tobytes()
    assert from_pointcloud2(msg).tobytes() == records.tobytes()


def _cloud(n=2):
    records = empty_records(n)
    records["label"] = 1
    return to_pointcloud2(records, "odom")


def test_missing_field_is_named():
    msg = _cloud()
    msg.fields = [f for f in msg.fields if f.name != "area_m2"]
    with pytest.raises(PointCloudFormatError, match="'area_m2'"):
        from_pointcloud2(msg)


def test_wrong_type_is_named():
    msg = _cloud()
    msg.fields[3].datatype = PointField.FLOAT32  # id is uint32
    with pytest.raises(PointCloudFormatError, match="'id'"):
        from_pointcloud2(msg)


def test_truncated_data_is_reported():
    msg = _cloud()
    msg.data = bytes(msg.data)[:-1]
    with pytest.raises(PointCloudFormatError, match="'data'"):
        from_pointcloud2(msg)


def test_unknown_class_is_named():
    msg = _cloud()
    raw = bytearray(msg.data)
    raw[ROI_DTYPE.fields["label"][1]] = 7
    msg.data = bytes(raw)
    with pytest.raises(PointCloudFormatError, match="'label'"):
        from_pointcloud2(msg)


def test_encoder_rejects_foreign_dtype():
    with pytest.raises(TypeError, match="'area_m2'"):
        to_pointcloud2(np.zeros(2, dtype=[("x", "<f8"), ("y", "<f8"), ("z", "<f8"),
                                          ("id", "<u4"), ("label", "u1"),
                                          ("area_m2", "<f8")]), "odom")


def test_empty_cloud_round_trips():
    msg = to_pointcloud2(empty_records(0), "map")
    assert isinstance(msg, PointCloud2)
    assert len(from_pointcloud2(msg)) == 0
