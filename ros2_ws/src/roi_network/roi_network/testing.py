"""Test support shared by the packages' tests: copies of a bag directory as a field bag
would record it.

The simulator records the contract's compressed images, left and right with one stamp; a
field bag often carries raw ``sensor_msgs/Image`` instead (roi_network.images), and two
cameras stamped apart. :func:`write_raw_image_copy` makes the raw kind from the first,
pixel for pixel, and :func:`write_stamp_offset_copy` moves the right images' stamps, so
a test can check that the pipeline reads them alike.
"""

from __future__ import annotations

import shutil
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from roi_network import images


@contextmanager
def _copying(bag_dir: Path, out_dir: Path, leave_out: tuple[str, ...] = ()):
    """Open a copy of bag directory ``bag_dir`` at ``out_dir``: its side files copied
    (but ``leave_out``), and ``(typestore, reader, writer)`` of its rosbag2 given."""
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    out_dir.mkdir(parents=True)
    for item in bag_dir.iterdir():
        if item.name != "rosbag" and item.name not in leave_out:
            copy = shutil.copytree if item.is_dir() else shutil.copy2
            copy(item, out_dir / item.name)
    store = get_typestore(Stores.ROS2_JAZZY)
    with AnyReader([bag_dir / "rosbag"], default_typestore=store) as reader, \
            Writer(out_dir / "rosbag", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
        yield store, reader, writer


def _mirror(store, reader, writer) -> dict:
    """Each of the reader's connections added to the writer as recorded (topic, type,
    offered QoS): reader connection id -> writer connection."""
    return {c.id: writer.add_connection(
        c.topic, c.msgtype, typestore=store,
        offered_qos_profiles=getattr(c.ext, "offered_qos_profiles", []))
        for c in reader.connections}


def write_raw_image_copy(bag_dir: str | Path, out_dir: str | Path,
                         keep_compressed: bool = False,
                         distortion: tuple[float, ...] | None = None,
                         encoding: str = "rgb8") -> Path:
    """Copy bag directory ``bag_dir`` (``rosbag/`` + side files) to ``out_dir`` with each
    stereo CompressedImage replaced by the ``rgb8`` Image of its decoded pixels, on the
    raw transport's topic (beside it, with ``keep_compressed``: a bag with both
    transports); every other message is copied as recorded.

    With ``distortion`` (plumb_bob coefficients k1 k2 p1 p2 k3), the raw images are those
    a lens with that distortion would have taken (each pixel sampled where the rectified
    image holds it), and both CameraInfo carry it: what a camera driver records.
    ``encoding`` ``mono8`` stores the grey image (OpenCV's BGR -> grey) in place of the
    colour one: a monochrome navigation camera's.

    Returns:
        ``out_dir``.
    """
    bag_dir, out_dir = Path(bag_dir), Path(out_dir)
    raw_topic = {c: r for c, r in zip(images.STEREO_TOPICS[images.COMPRESSED],
                                      images.STEREO_TOPICS[images.RAW], strict=True)}
    image_type = images.MSGTYPES[images.RAW]
    with _copying(bag_dir, out_dir) as (store, reader, writer):
        out, raw_out = {}, {}
        for conn in reader.connections:
            qos = getattr(conn.ext, "offered_qos_profiles", [])
            if conn.topic in raw_topic:
                raw_out[conn.id] = writer.add_connection(raw_topic[conn.topic], image_type,
                                                         typestore=store,
                                                         offered_qos_profiles=qos)
            if conn.topic not in raw_topic or keep_compressed:
                out[conn.id] = writer.add_connection(conn.topic, conn.msgtype,
                                                     typestore=store,
                                                     offered_qos_profiles=qos)
        maps = None
        if distortion is not None:  # the images come before their CameraInfo
            info_conns = [c for c in reader.connections
                          if c.msgtype == "sensor_msgs/msg/CameraInfo"]
            for conn, _t, data in reader.messages(connections=info_conns):
                info = reader.deserialize(data, conn.msgtype)
                info.d = np.asarray(distortion, float)
                maps = _distortion_maps(info)
                break
        for conn, t_ns, data in reader.messages():
            if conn.id in out:
                if distortion is not None and conn.msgtype == "sensor_msgs/msg/CameraInfo":
                    info = reader.deserialize(data, conn.msgtype)
                    info.d = np.asarray(distortion, float)
                    info.distortion_model = "plumb_bob"
                    data = store.serialize_cdr(info, conn.msgtype)
                writer.write(out[conn.id], t_ns, data)
            if conn.id in raw_out:
                msg = reader.deserialize(data, conn.msgtype)
                bgr = images.decode_image(msg, colour=True)
                if distortion is not None:
                    import cv2

                    if maps is None:
                        raise ValueError(f"{bag_dir}: an image before any CameraInfo")
                    bgr = cv2.remap(bgr, maps[0], maps[1], cv2.INTER_LINEAR)
                if encoding == "mono8":
                    import cv2

                    pixels = cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
                elif encoding == "rgb8":
                    pixels = np.ascontiguousarray(bgr[:, :, ::-1])
                else:
                    raise ValueError(f"encoding '{encoding}': rgb8 or mono8")
                channels = 1 if pixels.ndim == 2 else 3
                image = store.types[image_type](
                    header=msg.header, height=pixels.shape[0], width=pixels.shape[1],
                    encoding=encoding, is_bigendian=0, step=pixels.shape[1] * channels,
                    data=pixels.reshape(-1))
                writer.write(raw_out[conn.id], t_ns, store.serialize_cdr(image, image_type))
    return out_dir


def _distortion_maps(info) -> tuple[np.ndarray, np.ndarray]:
    """For each pixel of the distorted image, where the rectified image (P) holds it."""
    import cv2

    k = np.asarray(info.k, float).reshape(3, 3)
    p = np.asarray(info.p, float).reshape(3, 4)[:, :3]
    u, v = np.meshgrid(np.arange(info.width, dtype=np.float64),
                       np.arange(info.height, dtype=np.float64))
    pts = np.stack([u.ravel(), v.ravel()], axis=1).reshape(-1, 1, 2)
    rect = cv2.undistortPoints(pts, k, np.asarray(info.d, float), P=p).reshape(
        info.height, info.width, 2).astype(np.float32)
    return rect[:, :, 0], rect[:, :, 1]


def write_stamp_offset_copy(bag_dir: str | Path, out_dir: str | Path,
                            right_offset_s: float, jitter_s: float = 0.0,
                            seed: int = 0) -> Path:
    """Copy bag directory ``bag_dir`` to ``out_dir`` with the right stereo images' header
    stamps moved by ``right_offset_s`` (plus a uniform jitter of +-``jitter_s`` per image,
    from ``seed``), either transport; every other message, the right images' pixels and
    the log times as recorded. Two cameras triggered together and stamped by their own
    drivers record this.

    Returns:
        ``out_dir``.
    """
    rng = np.random.default_rng(seed)
    right = {topic for topic in images.IMAGE_TOPICS if images.side_of(topic) == "right"}
    with _copying(Path(bag_dir), Path(out_dir)) as (store, reader, writer):
        out = _mirror(store, reader, writer)
        for conn, t_ns, data in reader.messages():
            if conn.topic in right:
                msg = reader.deserialize(data, conn.msgtype)
                stamp = msg.header.stamp.sec * 1_000_000_000 + msg.header.stamp.nanosec
                stamp += round((right_offset_s + rng.uniform(-jitter_s, jitter_s)) * 1e9)
                msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(stamp, 1_000_000_000)
                data = store.serialize_cdr(msg, conn.msgtype)
            writer.write(out[conn.id], t_ns, data)
    return Path(out_dir)


def write_tf_static_copy(bag_dir: str | Path, out_dir: str | Path) -> Path:
    """Copy bag directory ``bag_dir`` to ``out_dir`` as a field bag records its calibration:
    a ``/tf_static`` message (``tf2_msgs/TFMessage``, latched, at the bag's first time)
    holding the base frame -> each sensor frame of its ``rover.yaml``, and no
    ``rover.yaml`` (``globloc rover-yaml`` writes it back from the bag). Every message as
    recorded.

    Returns:
        ``out_dir``.
    """
    import yaml
    from rosbags.interfaces import Qos, QosDurability, QosHistory, QosLiveliness
    from rosbags.interfaces import QosReliability as Rel
    from rosbags.interfaces import QosTime as Time

    bag_dir = Path(bag_dir)
    doc = yaml.safe_load((bag_dir / "rover.yaml").read_text())
    params = next(v["ros__parameters"] for v in doc.values() if "ros__parameters" in v)
    latched = Qos(QosHistory.KEEP_LAST, 1, Rel.RELIABLE, QosDurability.TRANSIENT_LOCAL,
                  Time(0, 0), Time(0, 0), QosLiveliness.AUTOMATIC, Time(0, 0), False)
    with _copying(bag_dir, Path(out_dir), ("rover.yaml",)) as (store, reader, writer):
        T = store.types
        out = _mirror(store, reader, writer)
        start = reader.start_time
        stamp = T["builtin_interfaces/msg/Time"](sec=start // 10**9, nanosec=start % 10**9)
        transforms = []
        for key, frame in (("base_to_left_camera", "left_camera_frame"),
                           ("base_to_right_camera", "right_camera_frame"),
                           ("base_to_imu", "imu_frame")):
            x, y, z, qx, qy, qz, qw = (float(v) for v in params[key])
            transforms.append(T["geometry_msgs/msg/TransformStamped"](
                header=T["std_msgs/msg/Header"](stamp=stamp, frame_id=params["base_frame"]),
                child_frame_id=params[frame],
                transform=T["geometry_msgs/msg/Transform"](
                    translation=T["geometry_msgs/msg/Vector3"](x=x, y=y, z=z),
                    rotation=T["geometry_msgs/msg/Quaternion"](x=qx, y=qy, z=qz, w=qw))))
        msgtype = "tf2_msgs/msg/TFMessage"
        tf = writer.add_connection("/tf_static", msgtype, typestore=store,
                                   offered_qos_profiles=[latched])
        writer.write(tf, start, store.serialize_cdr(T[msgtype](transforms=transforms), msgtype))
        for conn, t_ns, data in reader.messages():
            writer.write(out[conn.id], t_ns, data)
    return Path(out_dir)
