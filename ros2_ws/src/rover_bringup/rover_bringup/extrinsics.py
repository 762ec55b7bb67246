"""A field bag's ``rover.yaml``, from the calibration the bag itself records.

The nodes take the rover's extrinsics from parameters (DESIGN.md: ``rover.yaml`` beside
each bag; the simulator writes it). A field bag has no such file, but records what it
holds: the sensor frames in ``/tf_static`` (``tf2_msgs/TFMessage``, what
robot_state_publisher latches from the URDF), each sensor's frame in its messages'
``header.frame_id``, the stereo baseline in the right CameraInfo's P, and the IMU rate in
its stamps. :func:`bag_calibration` reads those and :func:`rover_parameters` composes
them into the parameters the nodes read:

- ``base_to_left_camera`` / ``base_to_right_camera`` / ``base_to_imu``: each sensor frame
  in the base frame, ``[x, y, z, qx, qy, qz, qw]``, composed along the tree whatever the
  frames between them (a mast, a pan-tilt unit);
- ``baseline_m``, ``camera_height_m``, ``camera_tilt_deg``, ``image_width``,
  ``image_height``, ``fx``, ``fy``, ``cx``, ``cy``: from the CameraInfo and the left
  camera's pose (what the simulator's file says alongside);
- ``imu_rate_hz`` from the IMU's stamps. The IMU's noise densities are not in a bag: they
  are written at rover_vo's defaults and flagged for the user to set from the datasheet.

Checks, each naming the frame or topic: the camera frames must be optical (REP-103: z
forward, x right, y down), the baseline of the tree must agree with the CameraInfo's, and
the right camera must sit on the left camera's +x axis (a rectified pair). Every
CameraInfo is checked (:func:`info_problem`: positive focal lengths in K and P,
finite numbers, an image size, the right one's baseline): an unusable one among usable
ones is skipped and named once with its topic, stamp and field; a topic with none usable,
left and right CameraInfo of different sizes, or a first image of another size than its
CameraInfo is refused. No rclpy, no tf2: the transforms are composed here with numpy and
scipy.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from roi_network.camera_info import camera_info_problem
from rover_bringup.errors import GloblocError
from rover_bringup.topics import TF_STATIC
from rover_bringup.urdf import (
    JOINT_STATES,
    ROBOT_DESCRIPTION,
    UrdfError,
    mast_of,
    parse_urdf,
    tree_at,
)

LEFT_INFO, RIGHT_INFO = '/stereo/left/camera_info', '/stereo/right/camera_info'
IMU = '/imu/data'
#: rover_vo's IMU noise defaults (rover_vo.config.ImuOptions), written when the bag has none.
IMU_DEFAULTS = {'gyro_noise_density': 0.00017, 'gyro_bias_random_walk': 2.0e-05,
                'gravity': 9.81}
#: Most IMU samples read for the rate.
IMU_SAMPLES = 2000
#: The tree's baseline and the CameraInfo's may differ by this much before it is an error.
BASELINE_TOLERANCE_M = 0.005


class CalibrationError(GloblocError):
    """The bag does not record what ``rover.yaml`` needs, or records it inconsistently."""


@dataclass
class BagCalibration:
    """What a bag records of its rover's calibration.

    Attributes:
        source: the bag, named in errors.
        transforms: ``(parent, child) -> 4x4`` of every ``/tf_static`` transform (the
            latest of each pair).
        frames: the sensors' ``header.frame_id``: ``left``, ``right`` (their CameraInfo,
            else images), ``imu``.
        left_info, right_info: the first usable CameraInfo of each side
            (:func:`info_problem`).
        infos_read: CameraInfo messages read, by topic.
        infos_unusable: by topic, the first unusable CameraInfo's problem and how many
            were unusable.
        image_sizes: by side, the first image's topic, stamp (s), width and height (only
            images that decode).
        imu_stamps_ns: the first IMU stamps, for the rate.
        urdf: the first ``/robot_description`` (URDF text), None when not recorded.
        joint_angles: the first ``/joint_states`` message's angles by joint name, None
            when not recorded.
    """

    source: str
    transforms: dict[tuple[str, str], np.ndarray] = field(default_factory=dict)
    frames: dict[str, str] = field(default_factory=dict)
    left_info: Any = None
    right_info: Any = None
    infos_read: dict[str, int] = field(default_factory=dict)
    infos_unusable: dict[str, tuple[str, int]] = field(default_factory=dict)
    image_sizes: dict[str, tuple[str, float, int, int]] = field(default_factory=dict)
    imu_stamps_ns: list[int] = field(default_factory=list)
    urdf: str | None = None
    joint_angles: dict[str, float] | None = None


def _matrix(translation: Any, rotation: Any) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = Rotation.from_quat([rotation.x, rotation.y, rotation.z, rotation.w]).as_matrix()
    t[:3, 3] = [translation.x, translation.y, translation.z]
    return t


def _stamp_s(msg: Any) -> float:
    return msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9


#: The CameraInfo numbers a calibration cannot do without: (field, index, meaning).


def info_problem(info: Any, topic: str) -> str | None:
    """What makes one CameraInfo unusable (:func:`roi_network.camera_info.camera_info_problem`)
    as ``<topic> at <stamp> s: <field> = <value>``
    (``/stereo/left/camera_info at 1403715273.712 s: K[0] (fx) = 0``), None when usable."""
    problem = camera_info_problem(info, "right" if topic == RIGHT_INFO else "left")
    return None if problem is None else f"{topic} at {_stamp_s(info):.3f} s: {problem}"


def bag_calibration(rosbag: str | Path) -> BagCalibration:
    """Read the calibration a rosbag2 directory records (see the module).

    Raises:
        CalibrationError: naming the bag when it cannot be read.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from roi_network import images

    rosbag = Path(rosbag)
    cal = BagCalibration(str(rosbag))
    try:
        with AnyReader([rosbag], default_typestore=get_typestore(Stores.ROS2_JAZZY)) as reader:
            wanted = {TF_STATIC, LEFT_INFO, RIGHT_INFO, IMU, ROBOT_DESCRIPTION, JOINT_STATES,
                      *images.IMAGE_TOPICS}
            conns = [c for c in reader.connections if c.topic in wanted]
            frame_of: dict[str, str] = {}
            for conn, _t, raw in reader.messages(connections=conns):
                topic = conn.topic
                if topic == IMU and len(cal.imu_stamps_ns) >= IMU_SAMPLES:
                    continue
                if topic in images.IMAGE_TOPICS and topic in frame_of:
                    continue
                if (topic == ROBOT_DESCRIPTION and cal.urdf is not None) or \
                        (topic == JOINT_STATES and cal.joint_angles is not None):
                    continue
                msg = reader.deserialize(raw, conn.msgtype)
                if topic == ROBOT_DESCRIPTION:
                    cal.urdf = str(msg.data)
                    continue
                if topic == JOINT_STATES:
                    cal.joint_angles = {str(n): float(p) for n, p in
                                        zip(msg.name, msg.position, strict=False)}
                    continue
                if topic == TF_STATIC:
                    for tf in msg.transforms:
                        key = (tf.header.frame_id.lstrip('/'), tf.child_frame_id.lstrip('/'))
                        cal.transforms[key] = _matrix(tf.transform.translation,
                                                      tf.transform.rotation)
                    continue
                if topic in (LEFT_INFO, RIGHT_INFO):
                    _read_info(cal, topic, msg)
                    if msg is (cal.left_info if topic == LEFT_INFO else cal.right_info):
                        frame_of.setdefault(topic, msg.header.frame_id.lstrip('/'))
                    continue
                frame_of.setdefault(topic, msg.header.frame_id.lstrip('/'))
                if topic == IMU:
                    cal.imu_stamps_ns.append(msg.header.stamp.sec * 1_000_000_000
                                             + msg.header.stamp.nanosec)
                else:  # the first image of a side
                    pixels = images.decode_image(msg)
                    side = images.side_of(topic)
                    if pixels is not None and side not in cal.image_sizes:
                        cal.image_sizes[side] = (topic, _stamp_s(msg), pixels.shape[1],
                                                 pixels.shape[0])
    except (OSError, ValueError, KeyError) as exc:  # rosbags' errors derive from these
        raise CalibrationError(f'{rosbag}: cannot read the bag ({exc})') from exc
    for side, info in (('left', LEFT_INFO), ('right', RIGHT_INFO)):
        image = next((frame_of[t] for t in sorted(images.IMAGE_TOPICS)
                      if images.side_of(t) == side and t in frame_of), None)
        if frame_of.get(info) or image:
            cal.frames[side] = frame_of.get(info) or image
    if frame_of.get(IMU):
        cal.frames['imu'] = frame_of[IMU]
    return cal


def _read_info(cal: BagCalibration, topic: str, msg: Any) -> None:
    cal.infos_read[topic] = cal.infos_read.get(topic, 0) + 1
    problem = info_problem(msg, topic)
    if problem is not None:
        first, count = cal.infos_unusable.get(topic, (problem, 0))
        cal.infos_unusable[topic] = (first, count + 1)
    elif topic == LEFT_INFO and cal.left_info is None:
        cal.left_info = msg
    elif topic == RIGHT_INFO and cal.right_info is None:
        cal.right_info = msg


def camera_info_checks(cal: BagCalibration, warnings: list[str]) -> None:
    """Refuse a bag whose CameraInfo cannot be used; name each topic's skipped ones once.

    Raises:
        CalibrationError: a CameraInfo topic with no usable message (naming the first
            unusable one and the field), left and right of different sizes, or a first
            image of another size than its CameraInfo.
    """
    src = cal.source
    for topic, info in ((LEFT_INFO, cal.left_info), (RIGHT_INFO, cal.right_info)):
        first, unusable = cal.infos_unusable.get(topic, (None, 0))
        read = cal.infos_read.get(topic, 0)
        if info is None and unusable:
            every = 'its only message' if read == 1 else f'every one of its {read} messages'
            raise CalibrationError(f'{src}: {first} ({every} is unusable): rover.yaml needs '
                                   "the camera's calibration; fix the CameraInfo the bag "
                                   'records (globloc camera-info computes the pair from the '
                                   'stereo calibration)')
        if info is None:
            raise CalibrationError(f'{src}: no {topic} message: the intrinsics and the '
                                   'baseline come from the CameraInfo')
        if unusable:
            more = f', with {unusable - 1} more' if unusable > 1 else ''
            warnings.append(f'{first}: skipped{more} ({unusable} of the {read} messages of '
                            f'{topic}); the calibration is that of the one at '
                            f'{_stamp_s(info):.3f} s')
    sizes = {topic: (int(info.width), int(info.height))
             for topic, info in ((LEFT_INFO, cal.left_info), (RIGHT_INFO, cal.right_info))}
    if sizes[LEFT_INFO] != sizes[RIGHT_INFO]:
        (lw, lh), (rw, rh) = sizes[LEFT_INFO], sizes[RIGHT_INFO]
        raise CalibrationError(f'{src}: {LEFT_INFO} says {lw}x{lh}, {RIGHT_INFO} {rw}x{rh}: '
                               'a rectified pair has one image size')
    for side, info_topic in (('left', LEFT_INFO), ('right', RIGHT_INFO)):
        if side not in cal.image_sizes:
            continue
        topic, stamp, width, height = cal.image_sizes[side]
        if (width, height) != sizes[info_topic]:
            w, h = sizes[info_topic]
            raise CalibrationError(f'{src}: {topic} at {stamp:.3f} s is {width}x{height}, '
                                   f'{info_topic} says {w}x{h}: the CameraInfo is not '
                                   "this camera's")


#: :func:`stereo_stamp_offsets` reads at most this many times the images it needs of one
#: camera while waiting for the other's.
READ_LIMIT = 4


def stereo_stamp_offsets(rosbag: str | Path, pairs: int = 20) -> list[float]:
    """How far apart a bag's left and right images are stamped: for each of its first
    ``pairs`` left images taken while the right camera streamed (within one of its
    intervals of its first and last image read), the distance to the nearest right
    image's stamp among the first images, seconds, sorted. Empty when the bag has no
    stereo pair.

    Reads the bag's first images only: it stops once both cameras gave ``2 pairs``
    images, or one of them ``READ_LIMIT`` times that (the other stopped early, or streams
    far slower).

    Raises:
        CalibrationError: naming the bag when it cannot be read.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    from roi_network import images

    stamps: dict[str, list[int]] = {'left': [], 'right': []}
    seen = {'left': 0, 'right': 0}
    try:
        with AnyReader([Path(rosbag)], default_typestore=get_typestore(Stores.ROS2_JAZZY)) \
                as reader:
            try:
                transport = images.bag_transport(
                    {c.topic: c.msgtype for c in reader.connections}, str(rosbag))
            except ValueError:
                return []
            conns = [c for c in reader.connections
                     if c.topic in images.STEREO_TOPICS[transport]]
            for conn, _t, raw in reader.messages(connections=conns):
                side = images.side_of(conn.topic)
                seen[side] += 1
                if len(stamps[side]) < 2 * pairs:
                    h = reader.deserialize(raw, conn.msgtype).header.stamp
                    stamps[side].append(h.sec * 1_000_000_000 + h.nanosec)
                if min(seen.values()) >= 2 * pairs \
                        or max(seen.values()) >= READ_LIMIT * 2 * pairs:
                    break
    except (OSError, ValueError, KeyError) as exc:
        raise CalibrationError(f'{rosbag}: cannot read the bag ({exc})') from exc
    right = np.sort(np.asarray(stamps['right'], np.int64))
    if not len(right):
        return []
    step = int(np.median(np.diff(right))) if len(right) > 1 else 1_000_000_000
    left = [t for t in stamps['left'] if right[0] - step <= t <= right[-1] + step][:pairs]
    return sorted(float(np.min(np.abs(right - t))) * 1e-9 for t in left)


def frame_transform(transforms: dict[tuple[str, str], np.ndarray], parent: str,
                    child: str, source: str) -> np.ndarray:
    """``child`` in ``parent`` (4x4: child-frame points to parent-frame points), composed
    along the tree of ``transforms`` in either direction.

    Raises:
        CalibrationError: naming both frames, ``source`` and the frames the tree holds,
            when no chain of transforms joins them.
    """
    edges: dict[str, list[tuple[str, np.ndarray]]] = {}
    for (p, c), t in transforms.items():
        edges.setdefault(p, []).append((c, t))
        edges.setdefault(c, []).append((p, np.linalg.inv(t)))
    # Breadth first from the parent: pose[f] = f in parent.
    pose = {parent: np.eye(4)}
    todo = deque([parent])
    while todo:
        f = todo.popleft()
        for g, t in edges.get(f, []):
            if g not in pose:
                pose[g] = pose[f] @ t
                todo.append(g)
    if child not in pose:
        known = ', '.join(sorted(edges)) or 'none'
        raise CalibrationError(f'{source}: {TF_STATIC} joins no chain from frame '
                               f"'{parent}' to frame '{child}' (frames: {known})")
    return pose[child]


def _pose_list(t: np.ndarray) -> list[float]:
    q = Rotation.from_matrix(t[:3, :3]).as_quat()
    if q[3] < 0:
        q = -q
    return [round(float(v), 9) for v in (*t[:3, 3], *q)]


def _mast_tree(cal: BagCalibration, base_frame: str, left_frame: str,
               warnings: list[str]) -> tuple[dict[tuple[str, str], np.ndarray], Any]:
    """The frame tree to compose the sensors' poses in, and the pan-tilt mast carrying the
    left camera (None for a fixed one).

    With a ``/robot_description`` the URDF's joints at the first ``/joint_states`` angles
    join ``/tf_static``'s transforms (which win where both give a pair), and the mast comes
    from the URDF. Without one the tree is ``/tf_static`` alone; a bag that records
    ``/joint_states`` then gets a note that its moving joints could not be read.

    Raises:
        CalibrationError: the URDF cannot be read or its mast is not a pan-tilt pair, or
            the tree breaks between the base and the camera where joints move.
    """
    src = cal.source
    names = sorted(cal.joint_angles or {})
    if cal.urdf is None:
        if names:
            try:
                frame_transform(cal.transforms, base_frame, left_frame, src)
            except CalibrationError as exc:
                raise CalibrationError(
                    f'{exc}. The bag records {JOINT_STATES} ({", ".join(names)}) but no '
                    f'{ROBOT_DESCRIPTION}: the camera hangs on moving joints whose origins '
                    f'and axes only the URDF states; record {ROBOT_DESCRIPTION} (what '
                    'robot_state_publisher latches), or write the mast.* parameters by hand '
                    '(docs/bring_your_own_bag.md)') from None
            warnings.append(f'the bag records {JOINT_STATES} ({", ".join(names)}) but no '
                            f'{ROBOT_DESCRIPTION}: the camera is taken as fixed at its '
                            f'{TF_STATIC} pose; if it moves on those joints, record '
                            f'{ROBOT_DESCRIPTION} and run this again')
        return cal.transforms, None
    try:
        joints = parse_urdf(cal.urdf, f'{src} {ROBOT_DESCRIPTION}')
        mast = mast_of(joints, base_frame, left_frame, names, f'{src} {ROBOT_DESCRIPTION}')
    except UrdfError as exc:
        raise CalibrationError(str(exc)) from None
    if mast is not None:
        angles = cal.joint_angles or {}
        warnings.append(
            f"mast joints '{mast.pan_joint}' and '{mast.tilt_joint}' read from "
            f'{ROBOT_DESCRIPTION}; base_to_left_camera and base_to_right_camera are the '
            f'cameras at the first {JOINT_STATES} angles ('
            + ', '.join(f'{n} {angles[n]:.4f} rad' for n in mast.joints) + ')')
    return {**tree_at(joints, cal.joint_angles or {}), **cal.transforms}, mast


def rover_parameters(cal: BagCalibration, base_frame: str = 'base_link',
                     frames: dict[str, str] | None = None) -> tuple[dict, list[str]]:
    """The ``rover.yaml`` parameters of a bag's calibration, and warnings for the user.

    Args:
        cal: :func:`bag_calibration`'s reading.
        base_frame: the rover body frame (REP-105's ``base_link``).
        frames: ``left``, ``right``, ``imu`` frames in place of those the messages name.

    Raises:
        CalibrationError: naming what is missing or inconsistent.
    """
    src = cal.source
    frames = {**cal.frames, **(frames or {})}
    if not cal.transforms and cal.urdf is None:
        raise CalibrationError(f'{src}: no {TF_STATIC} transforms: the bag does not record '
                               'its sensors\' frames; write rover.yaml by hand '
                               '(docs/bring_your_own_bag.md)')
    warnings: list[str] = []
    camera_info_checks(cal, warnings)
    for need, topic in (('left', LEFT_INFO), ('right', RIGHT_INFO)):
        if not frames.get(need):
            raise CalibrationError(f'{src}: no frame for the {need} camera: {topic} and '
                                   f'its images carry no header.frame_id (give --{need}-frame)')
    transforms, mast = _mast_tree(cal, base_frame, frames['left'], warnings)
    pose = {side: frame_transform(transforms, base_frame, frames[side], src)
            for side in ('left', 'right')}
    for side in ('left', 'right'):
        r = pose[side][:3, :3]
        # Optical (REP-103): x right, y down; in base_link x forward, y left, z up.
        if r[:, 1] @ [0, 0, 1] > -0.3 or r[:, 0] @ [0, 1, 0] > 0.3:
            raise CalibrationError(
                f"{src}: frame '{frames[side]}' ({side} camera) is not an optical frame "
                f'(REP-103: z forward, x right, y down): in {base_frame} its x axis points '
                f'{np.round(r[:, 0], 2).tolist()} and its y axis {np.round(r[:, 1], 2).tolist()}'
                f'; give the optical child frame (--{side}-frame)')
    p_right = np.asarray(cal.right_info.p, float)
    p_left = np.asarray(cal.left_info.p, float)
    baseline = -p_right[3] / p_right[0]
    right_in_left = np.linalg.inv(pose['left']) @ pose['right']
    offset = right_in_left[:3, 3]
    if abs(np.linalg.norm(offset) - baseline) > BASELINE_TOLERANCE_M:
        raise CalibrationError(
            f"{src}: the tree puts '{frames['right']}' {np.linalg.norm(offset):.4f} m from "
            f"'{frames['left']}', {RIGHT_INFO}'s P a baseline of {baseline:.4f} m")
    if offset[0] <= 0 or np.hypot(offset[1], offset[2]) > 0.1 * baseline:
        warnings.append(f"'{frames['right']}' is not on the +x axis of '{frames['left']}' "
                        f'({np.round(offset, 4).tolist()} m): the CameraInfo must describe '
                        'the rectified pair, whose frames are the rectified cameras\'')
    fx, fy, cx, cy = p_left[0], p_left[5], p_left[2], p_left[6]
    axis = pose['left'][:3, 2]
    params: dict[str, Any] = {
        'base_frame': base_frame,
        'left_camera_frame': frames['left'],
        'right_camera_frame': frames['right'],
        'base_to_left_camera': _pose_list(pose['left']),
        'base_to_right_camera': _pose_list(pose['right']),
    }
    if frames.get('imu'):
        params['imu_frame'] = frames['imu']
        params['base_to_imu'] = _pose_list(
            frame_transform(transforms, base_frame, frames['imu'], src))
    else:
        warnings.append(f'no {IMU} frame: base_to_imu left out (the IMU taken as aligned '
                        f'with {base_frame})')
    params.update({
        'baseline_m': round(float(baseline), 6),
        'camera_height_m': round(float(pose['left'][2, 3]), 6),
        'camera_tilt_deg': round(float(np.degrees(np.arcsin(-np.clip(axis[2], -1, 1)))), 4),
        'image_width': int(cal.left_info.width), 'image_height': int(cal.left_info.height),
        'fx': float(fx), 'fy': float(fy), 'cx': float(cx), 'cy': float(cy),
    })
    stamps = np.unique(cal.imu_stamps_ns)
    if len(stamps) >= 10:
        params['imu_rate_hz'] = round(float(1e9 / np.median(np.diff(stamps))), 3)
    else:
        warnings.append(f'{IMU}: {len(stamps)} samples: imu_rate_hz left out '
                        '(rover_vo assumes 50 Hz)')
    if mast is not None:
        params['mast'] = {k.split('.', 1)[1]: [round(x, 9) for x in v]
                          if isinstance(v, list) else v for k, v in mast.to_params().items()}
    params.update(IMU_DEFAULTS)
    warnings.append('gyro_noise_density, gyro_bias_random_walk and gravity are rover_vo\'s '
                    'defaults, not this IMU\'s: set them from its datasheet and the site '
                    '(docs/bring_your_own_bag.md, "IMU noise parameters")')
    return params, warnings


HEADER = """\
# Rover extrinsics and sensor constants for this bag, as ROS 2 node parameters
# (use with --ros-args --params-file rover.yaml). Written by `globloc rover-yaml` from
# {source}: the frames of /tf_static, the sensors' header.frame_id, the CameraInfo and
# the IMU's stamps (rover_bringup.extrinsics). Same layout as the simulator's rover.yaml.
# base_to_*: pose of a sensor frame in the base frame as [x, y, z, qx, qy, qz, qw]
#   (metres; quaternion rotates sensor-frame vectors into the base frame).
{notes}"""


def rover_yaml_text(params: dict, warnings: list[str], source: str) -> str:
    """The text of ``rover.yaml``: a header naming the source, the warnings as comments,
    and the parameters under ``/**: ros__parameters``."""
    import yaml

    notes = ''.join(f'# NOTE: {w}\n' for w in warnings)
    body = yaml.safe_dump({'/**': {'ros__parameters': params}}, sort_keys=False,
                          default_flow_style=None, width=100)
    return HEADER.format(source=source, notes=notes) + body


def write_rover_yaml(bag: str | Path, out: str | Path | None = None,
                     base_frame: str = 'base_link', frames: dict[str, str] | None = None,
                     force: bool = False) -> tuple[Path, list[str]]:
    """Write a bag directory's ``rover.yaml`` (default ``BAG/rover.yaml``) from what the bag
    records; returns the file and the warnings.

    Raises:
        CalibrationError: the bag lacks or contradicts what the file needs, or the file
            exists and ``force`` is not given (it is never overwritten silently).
    """
    from rover_bringup.bag import locate_bag

    location = locate_bag(bag)
    path = Path(out) if out is not None else location.root / 'rover.yaml'
    if path.exists() and not force:
        raise CalibrationError(f'{path} exists: not overwritten (give --force, or --out)')
    params, warnings = rover_parameters(bag_calibration(location.rosbag), base_frame, frames)
    tmp = path.with_name(path.name + '.tmp')
    tmp.write_text(rover_yaml_text(params, warnings, str(location.rosbag)))
    tmp.replace(path)
    return path, warnings
