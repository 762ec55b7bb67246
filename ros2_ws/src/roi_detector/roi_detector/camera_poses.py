"""Each stereo pair's camera pose in base_link, for the offline build and the node alike.

A rover whose ``rover.yaml`` has a pan-tilt mast (``mast.pan_joint`` set) moves its stereo
head at stops (a panorama) and drives with it at the drive pose; ``/joint_states`` gives the
angles and :class:`roi_network.mast.CameraPoser` the left camera's pose at a pair's stamp.
A rover without one has the fixed ``base_to_left_camera``, the pose every pair then takes
(the 7 numbers of rover.yaml as they are, so that its pairs are placed exactly as before
there were masts).

Bad joint input is counted per kind and said once (:class:`~roi_detector.inputs.BadInput`),
and the pair is not placed (not read at all): the stereo points, the map, the far rocks and
the in-view tests all need the pair's pose, and a guessed one would put the ROIs of a panned
view metres off. The kinds:

- ``no joint states``: rover.yaml has a mast and no /joint_states message had come by the
  pair's stamp (the first came later than the tolerance after it, or none at all);
- ``stale joint states``: the samples around the pair are further than the tolerance from it;
- ``joint states stopped``: the newest sample is older than the pair by more than the
  tolerance (the mast stopped publishing; pairs are skipped until it resumes);
- ``bad joint states`` (live only): a message the mast cannot read (unknown joint names,
  an angle outside the limits): dropped, as if it had not come. Offline it is an error.

Pure Python (no rclpy).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from roi_detector.inputs import JOINT_STATES, LEFT_INFO
from roi_network.mast import (
    JOINT_STATE_TOLERANCE_S,
    NO_JOINT_STATES,
    CameraPoser,
    MastError,
    same_pose,
)
from roi_network.params import flatten

#: The kinds of pair a mast's joint states could not place (``BadInput`` kinds).
NOT_PLACED = ("no joint states", "stale joint states", "joint states stopped")
#: A pair waits for a joint sample at or after its stamp until this many newer stereo pairs
#: have come after it and after the last /joint_states message: the mast's stream is down.
#: A live mast publishes its samples of a pair's stamp right after the pair, but a node's
#: executor takes one message per topic per turn, so a busy detector reads 10 Hz joint
#: states seconds of stamps behind its images; they still come between pairs. (A wait in
#: stamps, the inputs' newest stamp 2 s past the pair, gave such pairs up.) The last pairs
#: of a live run whose mast stopped wait for pairs that do not come; offline, the end of
#: the bag decides them.
JOINT_WAIT_PAIRS = 2


class PairPoses:
    """The left camera's pose in base_link at each pair's stamp.

    Args:
        params: the rover.yaml parameters (nested ``mast:`` or flattened ``mast.*``).
        bad: bad-input counter, called as ``bad(kind, detail)``.
        strict: a joint-state message the mast cannot read raises :class:`MastError`
            (offline); False counts it as ``bad joint states`` and drops it (live).
        tolerance_s: largest gap between a pair's stamp and the joint samples used for it.

    Raises:
        MastError: the mast's parameters are malformed (naming the field), or neither a
            mast nor ``base_to_left_camera`` is set.
    """

    def __init__(self, params: Mapping[str, Any], bad: Callable[[str, str], None],
                 strict: bool = True, tolerance_s: float = JOINT_STATE_TOLERANCE_S) -> None:
        flat = flatten(dict(params))
        self.poser = CameraPoser.from_params(flat, tolerance_s)
        self.fixed = None if self.poser.has_mast else list(flat["base_to_left_camera"])
        self.bad = bad
        self.strict = strict
        self.first: float | None = None  # the stamp of the first joint sample kept, s
        self.pairs = 0  # stereo pairs come so far
        self.pairs_at_joint = 0  # ... when the last joint message came
        self._arrival: dict[int, int] = {}  # a waiting pair's stamp (us) -> its arrival count

    @property
    def has_mast(self) -> bool:
        """Whether the pairs' poses come from /joint_states."""
        return self.poser.has_mast

    @property
    def joint_samples(self) -> int:
        """Joint-state messages kept so far."""
        return self.poser.samples

    def add(self, stamp_s: float, names: Sequence[str], positions: Sequence[float]) -> None:
        """Keep one /joint_states message (ignored without a mast).

        Raises:
            MastError: with ``strict``, a message the mast cannot read (naming its joints
                or the field).
        """
        try:
            self.poser.add(stamp_s, list(names), list(positions))
        except MastError as exc:
            if self.strict:
                raise
            self.bad("bad joint states", f"{exc}: the message is dropped, as if it had "
                     "not come")
            return
        self.pairs_at_joint = self.pairs
        if self.has_mast and (self.first is None or stamp_s < self.first):
            self.first = float(stamp_s)

    def pair_arrived(self, t: float) -> None:
        """The stereo pair stamped ``t`` has come (before asking :meth:`decidable` of it)."""
        self.pairs += 1
        self._arrival[round(t * 1e6)] = self.pairs
        if len(self._arrival) > 1000:  # pairs never asked about
            del self._arrival[next(iter(self._arrival))]

    def decidable(self, t: float) -> bool:
        """Whether the pose at ``t`` can be decided now: always without a mast; with one,
        once a joint sample at or after ``t`` has come (the interpolation's bracket), or
        :data:`JOINT_WAIT_PAIRS` newer pairs have come since both the pair and the last
        joint message (none is coming)."""
        if not self.has_mast:
            return True
        last = self.poser.last_stamp
        if last is not None and last >= t:
            return True
        since = max(self._arrival.get(round(t * 1e6), self.pairs), self.pairs_at_joint)
        return self.pairs - since >= JOINT_WAIT_PAIRS

    def pose(self, t: float):
        """The left camera's pose at ``t``: the fixed ``[x, y, z, qx, qy, qz, qw]``
        without a mast, the 4x4 ``base_T_left`` with one; None when the joint states
        cannot place the pair (counted and said once per kind, see the module)."""
        if self.fixed is not None:
            return self.fixed
        self._arrival.pop(round(t * 1e6), None)
        got = self.poser.pose_at(t)
        if not isinstance(got, str):
            return got.base_T_left
        kin = self.poser.kinematics
        last = self.poser.last_stamp
        tol = self.poser.tolerance_s
        if got == NO_JOINT_STATES or self.first is None or self.first > t + tol:
            self.bad("no joint states", f"rover.yaml has a mast (joints '{kin.pan_joint}', "
                     f"'{kin.tilt_joint}') but no {JOINT_STATES} message has come: the pair "
                     f"at {t:.3f} s is not placed")
        elif last is not None and last < t - tol:
            self.bad("joint states stopped", f"{JOINT_STATES}: the newest sample is at "
                     f"{last:.3f} s, the pair at {t:.3f} s: the mast stopped publishing; "
                     "pairs are not placed until it resumes")
        else:
            self.bad("stale joint states", f"{JOINT_STATES}: no sample within "
                     f"{tol:g} s of the pair at {t:.3f} s: not placed")
        return None


def rotation_of(pose) -> np.ndarray | None:
    """The 3x3 rotation of a 4x4 ``base_T_left`` (None for a fixed camera's 7 numbers:
    the pair spacing then reads the rover's own turn, as without a mast)."""
    m = np.asarray(pose, float)
    return m[:3, :3] if m.shape == (4, 4) else None


def read_joint_states(bag_dir: str | Path, topics: tuple[str, ...] = (LEFT_INFO,)
                      ) -> Iterator[tuple[str, float, Any]]:
    """``(topic, header stamp s, message)`` of a bag's /joint_states and ``topics``, in
    the bag's order (evaluation: where a mast pointed at each pair)."""
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    bag_dir = Path(bag_dir)
    rosbag = bag_dir / "rosbag" if (bag_dir / "rosbag").is_dir() else bag_dir
    with AnyReader([rosbag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
        conns = [c for c in reader.connections if c.topic in (JOINT_STATES, *topics)]
        for conn, _t, raw in reader.messages(connections=conns):
            msg = reader.deserialize(raw, conn.msgtype)
            stamp = int(msg.header.stamp.sec) + 1e-9 * int(msg.header.stamp.nanosec)
            yield conn.topic, stamp, msg


def moved_pair_poses(bag_dir: str | Path, params: Mapping[str, Any]
                     ) -> list[tuple[float, np.ndarray]]:
    """``(stamp s, base_T_left)`` of every stereo pair of a mast bag (one left CameraInfo
    per pair) whose camera is not at the drive pose (``base_to_left_camera``): the views
    of its panoramas. Empty without a mast. Pairs the joint states cannot place are left
    out."""
    poses = PairPoses(params, lambda kind, detail: None, strict=True)
    if not poses.has_mast:
        return []
    from roi_network.mast import pose_matrix

    drive = pose_matrix(flatten(dict(params))["base_to_left_camera"], "base_to_left_camera")
    out = []
    for topic, stamp, msg in read_joint_states(bag_dir):
        if topic == JOINT_STATES:
            poses.add(stamp, list(msg.name), list(msg.position))
            continue
        m = poses.pose(stamp)
        if m is not None and not same_pose(m, drive):
            out.append((stamp, m))
    return out
