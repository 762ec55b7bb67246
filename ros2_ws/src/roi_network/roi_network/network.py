"""A network of ROIs: records in one frame, with the metadata that places that frame."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from roi_network.records import ROI_DTYPE, as_records


@dataclass(frozen=True)
class MapFrame:
    """How the ``map`` frame sits in a projected CRS.

    ``map`` coordinates are CRS coordinates minus ``origin`` (metres, x east, y north), so
    that they stay small enough for float32 consumers (DESIGN.md, Frames).

    Attributes:
        crs: the projected CRS as an authority string, e.g. ``"EPSG:32719"``.
        origin: (easting, northing) of the map-frame origin in the CRS, metres.
    """

    crs: str
    origin: tuple[float, float] = (0.0, 0.0)


@dataclass
class RoiNetwork:
    """ROI records in one frame: a detection set, a track set, an LN or a GN.

    Attributes:
        records: 1-D array of :data:`~roi_network.records.ROI_DTYPE`.
        frame_id: ROS frame of the record positions (``map``, ``odom``, ``base_link``).
        map_frame: CRS and origin, for networks georeferenced in ``map`` (the GN).
        metadata: free-form provenance (source image, ground sample distance, ...);
            values must be JSON-serialisable.
    """

    records: np.ndarray
    frame_id: str
    map_frame: MapFrame | None = None
    metadata: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        self.records = as_records(self.records)
        if not self.frame_id:
            raise ValueError("RoiNetwork: field 'frame_id' must be a non-empty string")

    def __len__(self) -> int:
        return len(self.records)

    @classmethod
    def empty(cls, frame_id: str, **kwargs: Any) -> RoiNetwork:
        """An empty network in ``frame_id``."""
        return cls(np.zeros(0, dtype=ROI_DTYPE), frame_id, **kwargs)

    def by_label(self, label: int) -> np.ndarray:
        """Records of one class label."""
        return self.records[self.records["label"] == label]
