"""PointCloud2 codec for ROI records (the one wire layout of detections, tracks, LN, GN).

The cloud is unorganised (height 1, width N), little-endian, one point per ROI record, with
one PointField per record field at the packed offsets of :data:`ROI_DTYPE`. Decoding reads
any cloud that carries every record field with the right datatype, whatever its offsets
or padding, so clouds written by other tools are accepted too.
"""

from __future__ import annotations

from typing import Any, Final

import numpy as np

from roi_network.records import ROI_DTYPE, ROI_FIELDS, as_records

# sensor_msgs/PointField datatype constants (kept here so decoding needs no ROS import).
_POINTFIELD_TYPES: Final[dict[np.dtype, int]] = {
    np.dtype("i1"): 1,
    np.dtype("u1"): 2,
    np.dtype("<i2"): 3,
    np.dtype("<u2"): 4,
    np.dtype("<i4"): 5,
    np.dtype("<u4"): 6,
    np.dtype("<f4"): 7,
    np.dtype("<f8"): 8,
}
_NUMPY_TYPES: Final[dict[int, np.dtype]] = {v: k for k, v in _POINTFIELD_TYPES.items()}


class PointCloudFormatError(ValueError):
    """A PointCloud2 message does not hold ROI records."""


def roi_fields() -> list[tuple[str, int, int]]:
    """The (name, offset, datatype) triples of the ROI layout, in record order."""
    return [
        (name, ROI_DTYPE.fields[name][1], _POINTFIELD_TYPES[ROI_DTYPE[name]])
        for name in ROI_FIELDS
    ]


def to_pointcloud2(records: np.ndarray, frame_id: str, stamp: Any = None) -> Any:
    """Encode ROI records as a ``sensor_msgs/msg/PointCloud2``.

    Args:
        records: 1-D array of :data:`ROI_DTYPE`, positions in ``frame_id``.
        frame_id: the header frame (``base_link``, ``odom`` or ``map``).
        stamp: a ``builtin_interfaces/msg/Time`` or an int of nanoseconds; zero if None.
    """
    from builtin_interfaces.msg import Time  # imported here: decoding needs no ROS
    from sensor_msgs.msg import PointCloud2, PointField

    records = as_records(records)
    msg = PointCloud2()
    msg.header.frame_id = frame_id
    if isinstance(stamp, int):
        msg.header.stamp = Time(sec=stamp // 1_000_000_000, nanosec=stamp % 1_000_000_000)
    elif stamp is not None:
        msg.header.stamp = stamp
    msg.height = 1
    msg.width = len(records)
    msg.fields = [
        PointField(name=name, offset=offset, datatype=datatype, count=1)
        for name, offset, datatype in roi_fields()
    ]
    msg.is_bigendian = False
    msg.point_step = ROI_DTYPE.itemsize
    msg.row_step = ROI_DTYPE.itemsize * len(records)
    msg.data = np.ascontiguousarray(records).tobytes()
    msg.is_dense = True
    return msg


def from_pointcloud2(msg: Any) -> np.ndarray:
    """Decode a PointCloud2 (rclpy or rosbags message) into ROI records.

    Raises:
        PointCloudFormatError: naming the missing or mistyped field, or the size mismatch.
    """
    if msg.is_bigendian:
        raise PointCloudFormatError("PointCloud2: field 'is_bigendian' is true; only "
                                    "little-endian ROI clouds are supported")
    fields = {f.name: f for f in msg.fields}
    offsets, formats = [], []
    for name in ROI_FIELDS:
        field = fields.get(name)
        if field is None:
            raise PointCloudFormatError(f"PointCloud2: missing ROI field '{name}'")
        if field.datatype not in _NUMPY_TYPES or _NUMPY_TYPES[field.datatype] != ROI_DTYPE[name]:
            raise PointCloudFormatError(
                f"PointCloud2: field '{name}' has datatype {field.datatype}, expected "
                f"{_POINTFIELD_TYPES[ROI_DTYPE[name]]} ({ROI_DTYPE[name]})"
            )
        if field.count != 1:
            raise PointCloudFormatError(f"PointCloud2: field '{name}' has count {field.count}")
        if field.offset + ROI_DTYPE[name].itemsize > msg.point_step:
            raise PointCloudFormatError(
                f"PointCloud2: field '{name}' at offset {field.offset} overruns point_step "
                f"{msg.point_step}"
            )
        offsets.append(field.offset)
        formats.append(ROI_DTYPE[name])
    n = int(msg.width) * int(msg.height)
    if msg.height > 1 and msg.row_step != msg.width * msg.point_step:
        raise PointCloudFormatError("PointCloud2: field 'row_step' has padding; ROI clouds "
                                    "must be unorganised (height 1)")
    data = np.frombuffer(bytes(msg.data) if not isinstance(msg.data, np.ndarray)
                         else msg.data.tobytes(), dtype=np.uint8)
    if len(data) != n * msg.point_step:
        raise PointCloudFormatError(
            f"PointCloud2: field 'data' holds {len(data)} bytes, expected "
            f"width*height*point_step = {n * msg.point_step}"
        )
    wire = np.dtype({"names": list(ROI_FIELDS), "formats": formats, "offsets": offsets,
                     "itemsize": int(msg.point_step)})
    records = np.empty(n, dtype=ROI_DTYPE)
    raw = data.view(wire) if n else np.zeros(0, dtype=wire)
    for name in ROI_FIELDS:
        records[name] = raw[name]
    try:
        return as_records(records)
    except (TypeError, ValueError) as exc:
        raise PointCloudFormatError(f"PointCloud2: {exc}") from exc
