"""Field bags for the bring-your-own-bag tests: EuRoC's stereo calibration as its
``sensor.yaml`` files, and bags of raw mono8 stereo pairs, their CameraInfo, an IMU and
``/tf_static``, written with rosbags as a recorder would (Jazzy types, MCAP).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from rover_bringup.rectify import read_sensor_yaml, rectify_pair

#: EuRoC's MAV calibration (mav0/cam0 and cam1/sensor.yaml), as the dataset ships it.
EUROC_CAM = """\
# General sensor definitions.
sensor_type: camera
comment: VI-Sensor {name} (MT9M034)

# Sensor extrinsics wrt. the body-frame.
T_BS:
  cols: 4
  rows: 4
  data: [{t_bs}]

# Camera specific definitions.
rate_hz: 20
resolution: [752, 480]
camera_model: pinhole
intrinsics: [{intrinsics}] #fu, fv, cu, cv
distortion_model: radial-tangential
distortion_coefficients: [{distortion}]
"""
EUROC = {
    'cam0': dict(
        t_bs='0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975, '
             '0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768, '
             '-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949, '
             '0.0, 0.0, 0.0, 1.0',
        intrinsics='458.654, 457.296, 367.215, 248.375',
        distortion='-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05'),
    'cam1': dict(
        t_bs='0.0125552670891, -0.999755099723, 0.0182237714554, -0.0198435579556, '
             '0.999598781151, 0.0130119051815, 0.0251588363115, 0.0453689425024, '
             '-0.0253898008918, 0.0179005838253, 0.999517347078, 0.00786212447038, '
             '0.0, 0.0, 0.0, 1.0',
        intrinsics='457.587, 456.134, 379.999, 255.238',
        distortion='-0.28368365, 0.07451284, -0.00010473, -3.55590700e-05'),
}
#: EuRoC's first stereo stamp (MH_01), ns.
T0_NS = 1_403_715_273_712_143_104
#: The body (IMU) frame on the rover: 1.1 m above base_link, 0.3 m ahead, the cameras'
#: z axis (the body's z) pointing forward and 15 deg down.
BODY_IN_BASE = np.eye(4)
BODY_IN_BASE[:3, :3] = (Rotation.from_euler('y', 15, degrees=True).as_matrix()
                        @ np.array([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]]))
BODY_IN_BASE[:3, 3] = [0.3, 0.0, 1.1]


def write_euroc(root: Path) -> tuple[Path, Path]:
    """EuRoC's cam0/sensor.yaml and cam1/sensor.yaml under ``root``."""
    paths = []
    for name, values in EUROC.items():
        path = root / name / 'sensor.yaml'
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(EUROC_CAM.format(name=name, **values))
        paths.append(path)
    return paths[0], paths[1]


def _texture(seed: int, width: int, height: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    small = rng.integers(0, 256, (height // 8 + 1, width // 8 + 1), dtype=np.uint8)
    return np.kron(small, np.ones((8, 8), np.uint8))[:height, :width]


def write_field_bag(path: Path, infos: dict[str, list[dict]], frames=('cam0', 'cam1'),
                    tf: list[tuple[str, str, np.ndarray]] | None = None,
                    image_sizes: dict[str, tuple[int, int]] | None = None) -> Path:
    """A bag directory ``path`` (its rosbag2 in ``rosbag/``): one raw mono8 stereo pair at
    20 Hz per entry of ``infos['left']`` / ``infos['right']`` (the CameraInfo fields of
    each pair, :func:`read_calibration_yaml`'s), stamped from :data:`T0_NS`; an IMU at
    200 Hz over the pairs (still, gravity in the IMU frame ``imu0``); ``/tf_static``
    holding ``tf`` (parent, child, 4x4). Images are 752x480 unless ``image_sizes`` says
    otherwise for a side."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    T = store.types

    def header(ns: int, frame: str):
        return T['std_msgs/msg/Header'](
            stamp=T['builtin_interfaces/msg/Time'](sec=ns // 10**9, nanosec=ns % 10**9),
            frame_id=frame)

    path.mkdir(parents=True)
    pairs = len(infos['left'])
    with Writer(path / 'rosbag', version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        conns = {}

        def write(topic: str, msgtype: str, msg, ns: int) -> None:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(conns[topic], ns, store.serialize_cdr(msg, msgtype))

        tfs = []
        for parent, child, m in tf or []:
            q = Rotation.from_matrix(m[:3, :3]).as_quat()
            tfs.append(T['geometry_msgs/msg/TransformStamped'](
                header=header(T0_NS, parent), child_frame_id=child,
                transform=T['geometry_msgs/msg/Transform'](
                    translation=T['geometry_msgs/msg/Vector3'](x=m[0, 3], y=m[1, 3], z=m[2, 3]),
                    rotation=T['geometry_msgs/msg/Quaternion'](x=q[0], y=q[1], z=q[2],
                                                               w=q[3]))))
        write('/tf_static', 'tf2_msgs/msg/TFMessage', T['tf2_msgs/msg/TFMessage'](tfs), T0_NS)
        v3 = T['geometry_msgs/msg/Vector3']
        g = BODY_IN_BASE[:3, :3].T @ [0.0, 0.0, 9.81]
        for k in range(round(pairs * 10) + 20):
            ns = T0_NS - 50_000_000 + k * 5_000_000
            write('/imu/data', 'sensor_msgs/msg/Imu', T['sensor_msgs/msg/Imu'](
                header=header(ns, 'imu0'),
                orientation=T['geometry_msgs/msg/Quaternion'](x=0.0, y=0.0, z=0.0, w=1.0),
                orientation_covariance=np.array([-1.0, 0, 0, 0, 0, 0, 0, 0, 0]),
                angular_velocity=v3(x=0.0, y=0.0, z=0.0),
                angular_velocity_covariance=np.zeros(9),
                linear_acceleration=v3(x=g[0], y=g[1], z=g[2]),
                linear_acceleration_covariance=np.zeros(9)), ns)
        for i in range(pairs):
            ns = T0_NS + i * 50_000_000
            for side, frame in zip(('left', 'right'), frames, strict=True):
                f = infos[side][i]
                info = T['sensor_msgs/msg/CameraInfo'](
                    header=header(ns, frame), height=int(f['height']), width=int(f['width']),
                    distortion_model=f['distortion_model'], d=np.asarray(f['d'], float),
                    k=np.asarray(f['k'], float), r=np.asarray(f['r'], float),
                    p=np.asarray(f['p'], float), binning_x=0, binning_y=0,
                    roi=T['sensor_msgs/msg/RegionOfInterest'](
                        x_offset=0, y_offset=0, height=0, width=0, do_rectify=False))
                write(f'/stereo/{side}/camera_info', 'sensor_msgs/msg/CameraInfo', info, ns)
                width, height = (image_sizes or {}).get(side, (752, 480))
                pixels = _texture(i * 2 + (side == 'right'), width, height)
                write(f'/stereo/{side}/image_raw', 'sensor_msgs/msg/Image',
                      T['sensor_msgs/msg/Image'](
                          header=header(ns, frame), height=height, width=width,
                          encoding='mono8', is_bigendian=0, step=width,
                          data=pixels.ravel()), ns)
    return path


def euroc_pair(root: Path):
    """EuRoC's rectified pair (files under ``root/calib``) and the ``/tf_static`` of a
    rover carrying it: base_link -> imu0 (:data:`BODY_IN_BASE`) -> cam0, cam1."""
    cam0, cam1 = write_euroc(root / 'calib')
    pair = rectify_pair(read_sensor_yaml(cam0), read_sensor_yaml(cam1))
    tf = [('base_link', 'imu0', BODY_IN_BASE), ('imu0', 'cam0', pair.body_T_left),
          ('imu0', 'cam1', pair.body_T_right)]
    return pair, tf


def with_value(fields: dict, name: str, index: int, value: float) -> dict:
    """CameraInfo ``fields`` with ``fields[name][index] = value``."""
    out = {**fields, name: list(fields[name])}
    out[name][index] = value
    return out
