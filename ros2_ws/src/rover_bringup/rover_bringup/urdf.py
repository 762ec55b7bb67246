"""A rover's joints from its URDF, as robot_state_publisher latches it on
``/robot_description``: the frame tree at given joint angles, and the pan-tilt mast
between base_link and a camera as ``roi_network.mast`` models it.

``/tf_static`` holds only a robot's fixed joints; a camera on a pan-tilt head hangs below
two moving ones, whose origins and axes only the URDF states. :func:`parse_urdf` reads the
joints (``origin xyz rpy``, ``axis``, ``limit``), :func:`tree_at` gives every joint's
transform at the angles a ``/joint_states`` message holds, and :func:`mast_of` finds the
two revolute joints on the chain from the base frame to the camera and composes the fixed
joints around them into :class:`roi_network.mast.MastKinematics`.
"""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from scipy.spatial.transform import Rotation

from roi_network.mast import MastKinematics
from rover_bringup.errors import GloblocError

ROBOT_DESCRIPTION = '/robot_description'
JOINT_STATES = '/joint_states'
#: Joint types that move with an angle (``continuous`` has no limits).
REVOLUTE = ('revolute', 'continuous')


class UrdfError(GloblocError):
    """A URDF that cannot be read, or a joint chain the mast model does not describe."""


@dataclass(frozen=True)
class Joint:
    """One URDF joint.

    Attributes:
        name: joint name (as in ``/joint_states``).
        kind: URDF joint type (``fixed``, ``revolute``, ``continuous``, ...).
        parent: parent link.
        child: child link.
        origin: 4x4 pose of the joint frame in the parent link.
        axis: unit rotation axis in the joint frame.
        limits: ``(lower, upper)`` rad (``(-pi, pi)`` for a continuous joint).
    """

    name: str
    kind: str
    parent: str
    child: str
    origin: np.ndarray
    axis: np.ndarray
    limits: tuple[float, float]

    def at(self, angle: float) -> np.ndarray:
        """The child link in the parent link at ``angle`` (rad; ignored when fixed)."""
        if self.kind not in REVOLUTE:
            return self.origin
        m = np.eye(4)
        m[:3, :3] = Rotation.from_rotvec(self.axis * angle).as_matrix()
        return self.origin @ m


def _floats(text: str | None, n: int, default: list[float], where: str) -> list[float]:
    if text is None:
        return default
    try:
        v = [float(x) for x in text.split()]
    except ValueError:
        v = []
    if len(v) != n or not all(math.isfinite(x) for x in v):
        raise UrdfError(f'{where}: expected {n} numbers, got {text!r}')
    return v


def parse_urdf(text: str, source: str) -> dict[str, Joint]:
    """The joints of a URDF document, by child link.

    Raises:
        UrdfError: naming ``source`` and the joint when the XML or a joint is malformed.
    """
    try:
        root = ET.fromstring(text)
    except ET.ParseError as exc:
        raise UrdfError(f'{source}: not a URDF document ({exc})') from exc
    if root.tag != 'robot':
        raise UrdfError(f'{source}: not a URDF document (root element <{root.tag}>, '
                        'not <robot>)')
    joints: dict[str, Joint] = {}
    for el in root.iter('joint'):
        name, kind = el.get('name', ''), el.get('type', '')
        where = f"{source}: joint '{name}'"
        parent, child = el.find('parent'), el.find('child')
        if parent is None or child is None or not parent.get('link') or not child.get('link'):
            raise UrdfError(f'{where} has no <parent link> or <child link>')
        org = el.find('origin')
        xyz = _floats(None if org is None else org.get('xyz'), 3, [0.0] * 3, f'{where} xyz')
        rpy = _floats(None if org is None else org.get('rpy'), 3, [0.0] * 3, f'{where} rpy')
        origin = np.eye(4)
        origin[:3, :3] = Rotation.from_euler('xyz', rpy).as_matrix()  # URDF: Rz Ry Rx
        origin[:3, 3] = xyz
        ax = el.find('axis')
        axis = np.asarray(_floats(None if ax is None else ax.get('xyz'), 3, [1.0, 0, 0],
                                  f'{where} axis'))
        if np.linalg.norm(axis) < 1e-9:
            raise UrdfError(f'{where} has a zero axis')
        lim = el.find('limit')
        if kind == 'continuous' or lim is None:
            limits = (-math.pi, math.pi)
        else:
            limits = (float(lim.get('lower', '-3.141592653589793')),
                      float(lim.get('upper', '3.141592653589793')))
        joints[child.get('link')] = Joint(name, kind, parent.get('link'), child.get('link'),
                                          origin, axis / np.linalg.norm(axis), limits)
    return joints


def tree_at(joints: Mapping[str, Joint], angles: Mapping[str, float],
            ) -> dict[tuple[str, str], np.ndarray]:
    """``(parent, child) -> 4x4`` of every joint, moving ones at ``angles`` (0 when absent),
    in the form :func:`rover_bringup.extrinsics.frame_transform` composes."""
    return {(j.parent, j.child): j.at(float(angles.get(j.name, 0.0))) for j in joints.values()}


def _chain(joints: Mapping[str, Joint], base: str, frame: str, source: str) -> list[Joint]:
    """The joints from ``base`` down to ``frame``, base first."""
    out: list[Joint] = []
    link = frame
    while link != base:
        j = joints.get(link)
        if j is None:
            raise UrdfError(f"{source}: no joint chain from '{base}' to '{frame}' (link "
                            f"'{link}' has no parent joint)")
        out.append(j)
        link = j.parent
        if len(out) > len(joints):
            raise UrdfError(f'{source}: the joints form a loop at link {link!r}')
    return out[::-1]


def mast_of(joints: Mapping[str, Joint], base: str, camera_frame: str, joint_names: list[str],
            source: str) -> MastKinematics | None:
    """The pan-tilt mast carrying ``camera_frame``, or None when every joint between it and
    ``base`` is fixed.

    Args:
        joints: :func:`parse_urdf`'s reading.
        base: the rover body frame.
        camera_frame: the left optical frame.
        joint_names: the names ``/joint_states`` carries (empty: none recorded).
        source: named in errors.

    Raises:
        UrdfError: the chain has moving joints other than two revolute ones (naming them),
            or a mast joint is not among ``joint_names``.
    """
    chain = _chain(joints, base, camera_frame, source)
    moving = [j for j in chain if j.kind != 'fixed']
    if not moving:
        return None
    if len(moving) != 2 or any(j.kind not in REVOLUTE for j in moving):
        raise UrdfError(f"{source}: the chain from '{base}' to '{camera_frame}' moves on "
                        + ', '.join(f"'{j.name}' ({j.kind})" for j in moving)
                        + ': the mast model takes one pan and one tilt revolute joint')
    absent = [j.name for j in moving if j.name not in joint_names]
    if absent:
        raise UrdfError(f'{source}: mast joint {" and ".join(repr(a) for a in absent)} not in '
                        f'the names of {JOINT_STATES} ({joint_names or "none recorded"})')
    pan, tilt = moving
    i, k = chain.index(pan), chain.index(tilt)

    def fixed(part: list[Joint]) -> np.ndarray:
        m = np.eye(4)
        for j in part:
            m = m @ j.origin
        return m

    return MastKinematics(
        pan.name, fixed(chain[:i]) @ pan.origin, pan.axis, pan.limits,
        tilt.name, fixed(chain[i + 1:k]) @ tilt.origin, tilt.axis, tilt.limits,
        fixed(chain[k + 1:]))
