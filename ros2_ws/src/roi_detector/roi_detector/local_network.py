"""The incremental Local Network (paper Sec. 5): confirmed ROI tracks in odom, on disk.

The LN takes the confirmed tracks (``n_obs >= min_obs``) as they are updated, gives each
its own LN id, and merges two nodes of one class that the route saw twice as two tracks
(re-visit after the odometry drifted past the tracker's gate: the two centres within
the larger footprint). Each node keeps its track's covariance (stereo + odometry at the
observations; :mod:`roi_detector.tracking`), which is what the matcher reads
(``cov_xx``, ``cov_xy``, ``cov_yy``).

The LN is kept in a GeoJSON file (roi_network codec, written atomically) so that a
restarted ln_builder resumes where it was; a file that cannot be read is moved aside
and a fresh LN started.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from roi_network.files import keep_aside
from roi_network.geojson import GeoJsonFormatError, read_geojson, write_geojson
from roi_network.network import MapFrame, RoiNetwork
from roi_network.records import empty_records

#: The GeoJSON codec needs a projected CRS; the odom frame has none. The LN file carries
#: this placeholder with origin (0, 0) and ``frame_id: odom`` in its metadata: its
#: coordinates are odom metres, not georeferenced.
ODOM_PLACEHOLDER_CRS = "EPSG:32719"


#: Two same-class nodes nearer than this (or than half the larger footprint) are one
#: ROI, m.
MERGE_M = 1.0
#: A track id seen again this far from its LN node is a new ROI (the detector restarted
#: and reuses ids), m.
ID_JUMP_M = 5.0


@dataclass(frozen=True)
class LnConfig:
    """Local Network parameters.

    Attributes:
        min_obs: observations of a track before it enters the LN.
    """

    min_obs: int = 3


class LocalNetwork:
    """LN nodes in odom, fed with track records, merged on re-visit, persisted."""

    def __init__(self, cfg: LnConfig = LnConfig()) -> None:
        self.cfg = cfg
        self.records = empty_records(0)
        self._track_to_node: dict[int, int] = {}
        self._next_id = 1

    def __len__(self) -> int:
        return len(self.records)

    def update(self, tracks: np.ndarray) -> bool:
        """Upsert the confirmed tracks of ``tracks`` (ROI records, odom); True if the LN
        changed (a node added, removed by merging, or moved by more than 1 cm)."""
        before = self.records.copy()
        recs = list(self.records)
        index = {int(r["id"]): i for i, r in enumerate(recs)}
        for t in tracks[tracks["n_obs"] >= self.cfg.min_obs]:
            node = self._track_to_node.get(int(t["id"]))
            row = t.copy()
            if node is not None and node in index:
                old = recs[index[node]]
                if np.hypot(old["x"] - t["x"], old["y"] - t["y"]) > ID_JUMP_M:
                    node = None
            if node is None or node not in index:
                node = self._next_id
                self._next_id += 1
                self._track_to_node[int(t["id"])] = node
                row["id"] = node
                index[node] = len(recs)
                recs.append(row)
            else:
                row["id"] = node
                recs[index[node]] = row
        self.records = np.array(recs, dtype=before.dtype) if recs else empty_records(0)
        self._merge_revisits()
        return not _same(before, self.records)

    def _merge_revisits(self) -> None:
        """Fold same-class nodes within the larger half-footprint (or MERGE_M) into one."""
        r = self.records
        alive = np.ones(len(r), bool)
        for i in range(len(r)):
            if not alive[i]:
                continue
            for j in range(i + 1, len(r)):
                if not alive[j] or r["label"][j] != r["label"][i]:
                    continue
                d = np.hypot(r["x"][i] - r["x"][j], r["y"][i] - r["y"][j])
                if d < max(MERGE_M, 0.5 * max(r["major_m"][i], r["major_m"][j])):
                    r[i] = _fuse(r[i], r[j])
                    alive[j] = False
                    for k, v in self._track_to_node.items():
                        if v == int(r["id"][j]):
                            self._track_to_node[k] = int(r["id"][i])
        self.records = r[alive]

    def network(self, metadata: dict | None = None) -> RoiNetwork:
        """The LN as an odom-frame RoiNetwork (placeholder CRS, see the module doc)."""
        meta = {"frame_note": "odom metres; CRS is a placeholder required by the codec",
                "next_id": self._next_id,
                "track_to_node": {str(k): v for k, v in self._track_to_node.items()}}
        meta.update(metadata or {})
        return RoiNetwork(self.records.copy(), "odom", MapFrame(ODOM_PLACEHOLDER_CRS, (0.0, 0.0)),
                          meta)

    def save(self, path: str | Path, metadata: dict | None = None) -> None:
        """Write the LN to ``path`` atomically (GeoJSON, odom)."""
        write_geojson(self.network(metadata), path)

    @classmethod
    def load(cls, path: str | Path, cfg: LnConfig = LnConfig()) -> LocalNetwork:
        """Read an LN written by :meth:`save`.

        Raises:
            FileNotFoundError: no such file.
            GeoJsonFormatError: the file is not a valid LN (names file and field).
        """
        net = read_geojson(path)
        if net.frame_id != "odom":
            raise GeoJsonFormatError(f"{path}: field 'metadata.frame_id' is "
                                     f"'{net.frame_id}', expected 'odom'")
        ln = cls(cfg)
        ln.records = net.records
        ids = ln.records["id"]
        ln._next_id = int(max(net.metadata.get("next_id", 1), (ids.max() + 1) if len(ids) else 1))
        mapping = net.metadata.get("track_to_node", {})
        if isinstance(mapping, dict):
            ln._track_to_node = {int(k): int(v) for k, v in mapping.items()}
        return ln


def load_or_fresh(path: str | Path, cfg: LnConfig, report) -> LocalNetwork:
    """The LN saved at ``path``; a fresh one when there is none, or when it is corrupt
    (the corrupt file is renamed ``<path>.corrupt-<unix time>`` and ``report`` told)."""
    path = Path(path)
    if not path.exists():
        return LocalNetwork(cfg)
    try:
        return LocalNetwork.load(path, cfg)
    except (GeoJsonFormatError, ValueError, TypeError, KeyError) as exc:
        aside = keep_aside(path)
        report(f"saved LN {path} is unreadable ({exc}); kept aside as {aside}, "
               "starting a fresh LN")
        return LocalNetwork(cfg)


def _fuse(a: np.void, b: np.void) -> np.void:
    """One node from two observations of the same ROI: information-weighted centre."""
    ca = np.array([[a["cov_xx"], a["cov_xy"]], [a["cov_xy"], a["cov_yy"]]], float)
    cb = np.array([[b["cov_xx"], b["cov_xy"]], [b["cov_xy"], b["cov_yy"]]], float)
    ia, ib = np.linalg.inv(ca + 1e-9 * np.eye(2)), np.linalg.inv(cb + 1e-9 * np.eye(2))
    cov = np.linalg.inv(ia + ib)
    xy = cov @ (ia @ [a["x"], a["y"]] + ib @ [b["x"], b["y"]])
    out = a.copy()
    out["x"], out["y"] = xy
    out["cov_xx"], out["cov_xy"], out["cov_yy"] = cov[0, 0], cov[0, 1], cov[1, 1]
    out["n_obs"] = int(a["n_obs"]) + int(b["n_obs"])
    for name in ("area_m2", "height_m", "major_m", "minor_m"):
        out[name] = max(float(a[name]), float(b[name]))
    return out


def _same(a: np.ndarray, b: np.ndarray) -> bool:
    if len(a) != len(b) or not np.array_equal(a["id"], b["id"]):
        return False
    if not np.array_equal(a["label"], b["label"]):
        return False
    return bool(np.all(np.hypot(a["x"] - b["x"], a["y"] - b["y"]) < 0.01))
