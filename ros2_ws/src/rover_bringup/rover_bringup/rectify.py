"""The rectified stereo CameraInfo pair of a raw-image bag, from the stereo calibration.

A camera driver records images as the lenses made them; the pipeline reads them through a
``sensor_msgs/CameraInfo`` per side whose K and D describe the raw camera, R the rotation
into the rectified camera and P the rectified projection, the right one's with
``P[3] = -fx * baseline`` (DESIGN.md; roi_network.images.Rectifier remaps each image to its
P, as image_proc does). :func:`rectify_pair` computes that pair with OpenCV's
``stereoRectify`` from each camera's raw intrinsics, distortion and pose, read from the
EuRoC-style ``sensor.yaml`` files calibration tools write (:func:`read_sensor_yaml`:
``T_BS``, ``resolution``, ``intrinsics`` ``[fu, fv, cu, cv]``, ``distortion_model``,
``distortion_coefficients``); :func:`calibration_yaml` writes each in
camera_calibration_parsers' format (what camera_info_manager loads, with a
``camera_info_url``).

The pipeline takes ``base_to_left_camera`` as the pose of the *rectified* left camera and
never reads R: the frame the CameraInfo's header names is the rectified camera, which R
turns from the raw one. :class:`RectifiedPair` gives both rectified cameras' poses in the
calibration's body frame, for the ``/tf_static`` a bag records. No rclpy.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from rover_bringup.errors import GloblocError

#: ``distortion_model`` names of sensor.yaml files (EuRoC, Kalibr) read as ROS's plumb_bob.
PLUMB_BOB_NAMES = ('radial-tangential', 'radtan', 'plumb_bob')
#: The files :func:`write_camera_info` writes, left then right.
OUTPUT_NAMES = ('left.yaml', 'right.yaml')


class RectifyError(GloblocError):
    """A calibration file cannot be read or describes no horizontal stereo pair."""


@dataclass
class RawCamera:
    """One raw camera of a sensor.yaml file.

    Attributes:
        source: the file, named in errors.
        body_T_camera: the camera frame (optical: z forward, x right, y down) in the
            calibration's body frame, 4x4 (EuRoC's ``T_BS``).
        width, height: image size, pixels.
        k: 3x3 raw camera matrix.
        d: plumb_bob distortion ``[k1, k2, p1, p2, k3]``.
    """

    source: str
    body_T_camera: np.ndarray
    width: int
    height: int
    k: np.ndarray
    d: np.ndarray


@dataclass
class RectifiedPair:
    """The rectified pair :func:`rectify_pair` computes.

    Attributes:
        left, right: CameraInfo fields per side: ``width``, ``height``,
            ``distortion_model``, ``d``, ``k``, ``r``, ``p`` (flat, row-major).
        fx: the rectified focal length, pixels (P[0] of both).
        baseline_m: the right camera's offset along the rectified left camera's +x, m.
        rotation_deg: the angle R turns each raw camera by, ``(left, right)``, degrees.
        body_T_left, body_T_right: the rectified cameras in the body frame, 4x4.
    """

    left: dict[str, Any]
    right: dict[str, Any]
    fx: float
    baseline_m: float
    rotation_deg: tuple[float, float]
    body_T_left: np.ndarray
    body_T_right: np.ndarray


def _numbers(doc: dict, key: str, count: int | tuple[int, ...], source: str) -> np.ndarray:
    value = doc.get(key)
    if isinstance(value, dict):  # {rows, cols, data}, as EuRoC's T_BS and OpenCV's files
        value = value.get('data')
    try:
        array = np.asarray(value, float).ravel()
    except (TypeError, ValueError):
        array = None
    counts = (count,) if isinstance(count, int) else count
    if value is None or array is None or array.size not in counts:
        want = ' or '.join(str(c) for c in counts)
        raise RectifyError(f'{source}: {key}: {want} numbers expected, got {value!r}')
    if not np.all(np.isfinite(array)):
        bad = int(np.flatnonzero(~np.isfinite(array))[0])
        raise RectifyError(f'{source}: {key}[{bad}] = {array[bad]}')
    return array


def read_sensor_yaml(path: str | Path) -> RawCamera:
    """One camera of a EuRoC-style ``sensor.yaml`` (an OpenCV ``%YAML:1.0`` header and
    ``!!opencv-matrix`` tags are accepted).

    Raises:
        RectifyError: naming the file and the field that is missing or wrong.
    """
    import yaml

    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise RectifyError(f'{path}: cannot read the calibration ({exc.strerror})') from None
    text = re.sub(r'^%YAML[: ]?[0-9.]*[ \t]*$', '', text, flags=re.MULTILINE)
    try:
        doc = yaml.safe_load(text.replace('!!opencv-matrix', ''))
    except yaml.YAMLError as exc:
        raise RectifyError(f'{path}: not YAML ({exc})') from None
    if not isinstance(doc, dict):
        raise RectifyError(f'{path}: not a sensor.yaml (a mapping of T_BS, resolution, '
                           'intrinsics, distortion_model, distortion_coefficients)')
    src = str(path)
    model = str(doc.get('camera_model', 'pinhole'))
    if model != 'pinhole':
        raise RectifyError(f"{src}: camera_model '{model}': only 'pinhole' is read")
    distortion = str(doc.get('distortion_model', ''))
    if distortion not in PLUMB_BOB_NAMES:
        raise RectifyError(f"{src}: distortion_model '{distortion}': this command reads "
                           f"{', '.join(PLUMB_BOB_NAMES)}")
    body_T_camera = _numbers(doc, 'T_BS', 16, src).reshape(4, 4)
    rotation = body_T_camera[:3, :3]
    if not (np.allclose(rotation @ rotation.T, np.eye(3), atol=1e-4)
            and np.linalg.det(rotation) > 0 and np.allclose(body_T_camera[3], [0, 0, 0, 1])):
        raise RectifyError(f'{src}: T_BS is not a rigid transform (its 3x3 is no rotation, '
                           'or its last row is not 0 0 0 1)')
    width, height = (int(v) for v in _numbers(doc, 'resolution', 2, src))
    if width <= 0 or height <= 0:
        raise RectifyError(f'{src}: resolution {width}x{height} is not an image size')
    fu, fv, cu, cv = _numbers(doc, 'intrinsics', 4, src)
    for name, value in (('intrinsics[0] (fu)', fu), ('intrinsics[1] (fv)', fv)):
        if value <= 0:
            raise RectifyError(f'{src}: {name} = {value:g}: a focal length is positive')
    d = np.zeros(5)
    coefficients = _numbers(doc, 'distortion_coefficients', (4, 5), src)
    d[:coefficients.size] = coefficients
    k = np.array([[fu, 0.0, cu], [0.0, fv, cv], [0.0, 0.0, 1.0]])
    return RawCamera(src, body_T_camera, width, height, k, d)


def _angle_deg(r: np.ndarray) -> float:
    return math.degrees(Rotation.from_matrix(r).magnitude())


def rectify_pair(left: RawCamera, right: RawCamera, alpha: float = 0.0) -> RectifiedPair:
    """The rectified CameraInfo pair of two raw cameras (OpenCV's ``stereoRectify``, image
    centres aligned as ROS's stereo calibrator does).

    Args:
        left, right: the raw cameras; ``right`` must sit on ``left``'s +x side.
        alpha: 0 crops the rectified images to valid pixels only, 1 keeps every raw pixel
            (black borders), as ``stereoRectify`` and ``cameracalibrator --alpha``.

    Raises:
        RectifyError: the sizes differ, the cameras coincide, or the pair is vertical or
            mirrored (naming both files).
    """
    import cv2

    names = f'{left.source} and {right.source}'
    if (left.width, left.height) != (right.width, right.height):
        raise RectifyError(f'{names}: resolution {left.width}x{left.height} and '
                           f'{right.width}x{right.height}: a stereo pair has one image size')
    # x_right = R x_left + T: the left camera's frame in the right one's.
    right_T_left = np.linalg.inv(right.body_T_camera) @ left.body_T_camera
    rotation, translation = right_T_left[:3, :3], right_T_left[:3, 3]
    distance = float(np.linalg.norm(translation))
    if distance < 1e-6:
        raise RectifyError(f'{names}: T_BS puts both cameras at one point: no baseline')
    offset = -rotation.T @ translation  # the right camera in the left one's frame
    if abs(offset[0]) < 0.5 * distance:
        raise RectifyError(
            f'{names}: the second camera sits at {np.round(offset, 4).tolist()} m in the '
            "first one's frame, not beside it along x: the pipeline reads a horizontal pair")
    if offset[0] < 0:
        raise RectifyError(
            f"{names}: the second camera sits {-offset[0]:.4f} m on the first one's -x side "
            '(left of it): give the left camera first')
    size = (left.width, left.height)
    r1, r2, p1, p2, *_ = cv2.stereoRectify(
        left.k, left.d, right.k, right.d, size, rotation, translation,
        flags=cv2.CALIB_ZERO_DISPARITY, alpha=float(alpha))
    fx = float(p1[0, 0])
    baseline = -float(p2[0, 3]) / float(p2[0, 0])

    def fields(camera: RawCamera, r: np.ndarray, p: np.ndarray) -> dict[str, Any]:
        return {'width': camera.width, 'height': camera.height,
                'distortion_model': 'plumb_bob', 'd': camera.d.tolist(),
                'k': camera.k.ravel().tolist(), 'r': r.ravel().tolist(),
                'p': p.ravel().tolist()}

    def rectified(camera: RawCamera, r: np.ndarray) -> np.ndarray:
        out = camera.body_T_camera.copy()
        out[:3, :3] = camera.body_T_camera[:3, :3] @ r.T  # x_rect = R x_raw
        return out

    return RectifiedPair(fields(left, r1, p1), fields(right, r2, p2), fx, baseline,
                         (_angle_deg(r1), _angle_deg(r2)), rectified(left, r1),
                         rectified(right, r2))


def _matrix(rows: int, cols: int, data: list[float]) -> str:
    numbers = ', '.join(repr(float(v)) for v in data)
    return f'  rows: {rows}\n  cols: {cols}\n  data: [{numbers}]\n'


def calibration_yaml(fields: dict[str, Any], camera_name: str) -> str:
    """One side of :class:`RectifiedPair` in camera_calibration_parsers' YAML format."""
    return (f'image_width: {fields["width"]}\nimage_height: {fields["height"]}\n'
            f'camera_name: {camera_name}\n'
            f'camera_matrix:\n{_matrix(3, 3, fields["k"])}'
            f'distortion_model: {fields["distortion_model"]}\n'
            f'distortion_coefficients:\n{_matrix(1, len(fields["d"]), fields["d"])}'
            f'rectification_matrix:\n{_matrix(3, 3, fields["r"])}'
            f'projection_matrix:\n{_matrix(3, 4, fields["p"])}')


def read_calibration_yaml(path: str | Path) -> dict[str, Any]:
    """A camera_calibration_parsers YAML file as CameraInfo fields (``width``, ``height``,
    ``distortion_model``, ``d``, ``k``, ``r``, ``p``), for a bag converter.

    Raises:
        RectifyError: naming the file and the field that is missing.
    """
    import yaml

    path = Path(path)
    try:
        doc = yaml.safe_load(path.read_text())
    except (OSError, yaml.YAMLError) as exc:
        raise RectifyError(f'{path}: cannot read the calibration ({exc})') from None
    if not isinstance(doc, dict):
        raise RectifyError(f'{path}: not a camera calibration file')
    out: dict[str, Any] = {}
    for key, field in (('image_width', 'width'), ('image_height', 'height'),
                       ('distortion_model', 'distortion_model')):
        if key not in doc:
            raise RectifyError(f'{path}: no {key}')
        out[field] = doc[key]
    for key, field, count in (('camera_matrix', 'k', 9), ('rectification_matrix', 'r', 9),
                              ('projection_matrix', 'p', 12),
                              ('distortion_coefficients', 'd', (0, 4, 5, 8, 12, 14))):
        out[field] = _numbers(doc, key, count, str(path)).tolist()
    return out


def pose_list(t: np.ndarray) -> list[float]:
    """A 4x4 pose as ``[x, y, z, qx, qy, qz, qw]`` (``qw >= 0``), as rover.yaml and
    ``/tf_static`` hold it."""
    q = Rotation.from_matrix(t[:3, :3]).as_quat()
    if q[3] < 0:
        q = -q
    return [round(float(v), 9) for v in (*t[:3, 3], *q)]


def summary_lines(pair: RectifiedPair) -> list[str]:
    """What ``globloc camera-info`` tells the user about a pair."""
    left, right = (pose_list(t) for t in (pair.body_T_left, pair.body_T_right))
    return [
        f'rectified pair {pair.left["width"]}x{pair.left["height"]}: fx {pair.fx:.3f} px, '
        f'baseline {pair.baseline_m:.5f} m (right P[3] = {pair.right["p"][3]:.4f}); R turns '
        f'the left camera {pair.rotation_deg[0]:.3f} deg, the right '
        f'{pair.rotation_deg[1]:.3f} deg',
        'the pipeline takes the CameraInfo frames as the rectified cameras and ignores R: '
        'give /tf_static (or the URDF) these rectified cameras, in the body frame of T_BS '
        '([x, y, z, qx, qy, qz, qw]):',
        f'  left  {left}',
        f'  right {right}',
    ]


def write_camera_info(left_yaml: str | Path, right_yaml: str | Path,
                      out: str | Path | None = None, alpha: float = 0.0,
                      force: bool = False) -> tuple[RectifiedPair, list[Path], str]:
    """``globloc camera-info``: the rectified pair of two sensor.yaml files, written to
    ``out/left.yaml`` and ``out/right.yaml`` when ``out`` is given.

    Returns:
        The pair, the files written, and both files' text as one YAML stream (two
        documents) for printing.

    Raises:
        RectifyError: bad input (:func:`read_sensor_yaml`, :func:`rectify_pair`), or an
            output file exists and ``force`` is not given.
    """
    if not 0.0 <= alpha <= 1.0:
        raise RectifyError(f'--alpha {alpha:g}: between 0 and 1')
    pair = rectify_pair(read_sensor_yaml(left_yaml), read_sensor_yaml(right_yaml), alpha)
    texts = [calibration_yaml(pair.left, 'left'), calibration_yaml(pair.right, 'right')]
    written: list[Path] = []
    if out is not None:
        out = Path(out)
        paths = [out / name for name in OUTPUT_NAMES]
        if not force and (existing := [str(p) for p in paths if p.exists()]):
            raise RectifyError(f'{", ".join(existing)} exists: not overwritten (give --force)')
        try:
            out.mkdir(parents=True, exist_ok=True)
            for path, text in zip(paths, texts, strict=True):
                path.write_text(text)
        except OSError as exc:
            raise RectifyError(f'{out}: cannot write the calibration ({exc.strerror})') \
                from None
        written = paths
    return pair, written, '---\n'.join(texts)
