"""Find the Python class of a ROS 2 message type, without rclpy or rosidl_runtime_py.

A bag names its types as ``pkg/msg/Type``; in Python that is ``pkg.msg.Type``. A type is only
usable when its package is installed *and* its C type support loads, which is what rclpy
needs to create a publisher, so both are checked here before anything is published.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping

from rover_bringup.errors import GloblocError


class UnavailableTypeError(GloblocError):
    """A message type is not installed (or not loadable) in this ROS environment."""


def message_class(msgtype: str) -> type:
    """Import the message class of ``msgtype`` and load its type support.

    Args:
        msgtype: Type name as stored in rosbag2, e.g. ``sensor_msgs/msg/Imu``.

    Returns:
        The generated message class, e.g. ``sensor_msgs.msg.Imu``.

    Raises:
        UnavailableTypeError: Malformed name, package not installed, type not in the package
            or its type support library does not load.
    """
    parts = msgtype.split('/')
    if len(parts) != 3 or parts[1] != 'msg' or not all(parts):
        raise UnavailableTypeError(f'{msgtype!r} is not a ROS 2 message type name (pkg/msg/Type)')
    package, _, name = parts
    try:
        module = importlib.import_module(f'{package}.msg')
        cls = getattr(module, name)
        # rclpy loads this C extension lazily at create_publisher(); load it now so that a
        # broken install is reported before playback starts, not in the middle of it.
        cls.__class__.__import_type_support__()
    except (ImportError, AttributeError, OSError) as exc:
        raise UnavailableTypeError(f'{msgtype}: {exc}') from None
    return cls


def message_classes(topic_types: Mapping[str, str]) -> dict[str, type]:
    """Message classes of several topics, all checked before any is used.

    Args:
        topic_types: Topic name -> message type name.

    Returns:
        Topic name -> message class.

    Raises:
        UnavailableTypeError: Names the first topic (sorted) whose type is not available.
    """
    classes: dict[str, type] = {}
    for topic in sorted(topic_types):
        msgtype = topic_types[topic]
        try:
            classes[topic] = message_class(msgtype)
        except UnavailableTypeError:
            raise UnavailableTypeError(
                f'topic {topic} has message type {msgtype} which is not available in this ROS '
                'install'
            ) from None
    return classes
