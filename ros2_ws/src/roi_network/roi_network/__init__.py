"""Shared data model: ROI records and networks, 2D rigid transforms, GeoJSON and
PointCloud2 codecs. Pure Python: nothing here starts a node."""

from roi_network.network import MapFrame, RoiNetwork
from roi_network.records import (
    LABEL_NAMES,
    LABELS,
    OUTCROP,
    ROCK,
    ROI_DTYPE,
    ROI_FIELDS,
    as_records,
    empty_records,
    xy,
)
from roi_network.transform import Rigid2D, wrap_angle

__all__ = [
    "LABELS",
    "LABEL_NAMES",
    "OUTCROP",
    "ROCK",
    "ROI_DTYPE",
    "ROI_FIELDS",
    "MapFrame",
    "Rigid2D",
    "RoiNetwork",
    "as_records",
    "empty_records",
    "wrap_angle",
    "xy",
]
