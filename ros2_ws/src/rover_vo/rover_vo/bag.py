"""Reading a bag directory (DESIGN.md layout) for the offline CLI: the input topics in
bag order with ``rosbags`` (no ROS graph), ``/joint_states`` and ``/sun_sensor`` among
them when the bag has them, and the rover.yaml parameters.
"""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import Any

from roi_network.images import bag_transport
from rover_vo.config import read_ros_params
from rover_vo.messages import TOPIC_JOINT_STATES, TOPIC_SUN, input_topics


class BagError(ValueError):
    """A bag directory that cannot be read (the message names the file)."""


def rover_params(bag_dir: str | Path) -> dict[str, Any]:
    """The flat parameters of ``BAG_DIR/rover.yaml`` (extrinsics, sensor constants)."""
    path = Path(bag_dir) / "rover.yaml"
    if not path.is_file():
        raise BagError(f"{path}: no such file (the bag's extrinsics)")
    return read_ros_params(path)


def read_messages(bag_dir: str | Path) -> Iterator[tuple[str, Any]]:
    """``(topic, message)`` of the VO input topics in bag (log time) order, with the
    mast's ``/joint_states`` and the sun sensor's ``/sun_sensor`` when the bag carries them.

    The stereo images are those of the transport the bag carries (compressed, the
    contract, when it carries both; :func:`roi_network.images.bag_transport`).

    Raises:
        BagError: naming the bag when it cannot be read or carries no stereo pair.
    """
    from rosbags.highlevel import AnyReader
    from rosbags.typesys import Stores, get_typestore

    path = Path(bag_dir) / "rosbag"
    if not path.is_dir():
        raise BagError(f"{path}: no such directory (expected BAG_DIR/rosbag/)")
    try:
        reader = AnyReader([path], default_typestore=get_typestore(Stores.ROS2_JAZZY))
        reader.open()
    except Exception as exc:  # rosbags raises several unrelated types for bad bags
        raise BagError(f"{path}: cannot open rosbag2: {exc}") from exc
    try:
        try:
            transport = bag_transport({c.topic: c.msgtype for c in reader.connections},
                                      str(path))
        except ValueError as exc:
            raise BagError(str(exc)) from None
        topics = (*input_topics(transport), TOPIC_JOINT_STATES, TOPIC_SUN)
        conns = [c for c in reader.connections if c.topic in topics]
        for conn, _, raw in reader.messages(connections=conns):
            yield conn.topic, reader.deserialize(raw, conn.msgtype)
    finally:
        reader.close()
