"""Test support shared by the packages' tests: a bag directory's copy with raw images.

The simulator records the contract's compressed images; a field bag often carries raw
``sensor_msgs/Image`` instead (roi_network.images). :func:`write_raw_image_copy` makes
the second kind from the first, pixel for pixel, so a test can check that the pipeline
reads both alike.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import numpy as np

from roi_network import images


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
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    bag_dir, out_dir = Path(bag_dir), Path(out_dir)
    out_dir.mkdir(parents=True)
    for item in bag_dir.iterdir():
        if item.name != "rosbag":
            copy = shutil.copytree if item.is_dir() else shutil.copy2
            copy(item, out_dir / item.name)
    store = get_typestore(Stores.ROS2_JAZZY)
    raw_topic = {c: r for c, r in zip(images.STEREO_TOPICS[images.COMPRESSED],
                                      images.STEREO_TOPICS[images.RAW], strict=True)}
    image_type = images.MSGTYPES[images.RAW]
    with AnyReader([bag_dir / "rosbag"], default_typestore=store) as reader, \
            Writer(out_dir / "rosbag", version=9, storage_plugin=StoragePlugin.MCAP) as writer:
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
