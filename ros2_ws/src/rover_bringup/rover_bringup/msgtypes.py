"""Find the Python class of a ROS 2 message type, without rclpy or rosidl_runtime_py.

A bag names its types as ``pkg/msg/Type``; in Python that is ``pkg.msg.Type``. A type is only
usable when its package is installed *and* its C type support loads, which is what rclpy
needs to create a publisher, so both are checked here before anything is published.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping

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


def playable_classes(topic_types: Mapping[str, str], requested: bool,
                     warn: Callable[[str], None]) -> dict[str, type]:
    """The message classes of the topics that can be played, the others left out.

    A field bag records topics of message packages this ROS install does not have
    (``/tf`` and ``/tf_static`` as ``tf2_msgs/TFMessage``, vendor drivers' types). No node
    of the graph reads them, so they are left out, named in one ``warn`` line; the
    pipeline's inputs are all of installed packages (DESIGN.md: standard message types).

    Args:
        topic_types: Topic name -> message type name.
        requested: the topics were named by the user (``--topics``): any unavailable one
            is an error, as :func:`message_classes` raises it.
        warn: told once, naming the topics left out and their types.

    Raises:
        UnavailableTypeError: ``requested`` and a type is unavailable, or no topic is left.
    """
    if requested:
        return message_classes(topic_types)
    classes: dict[str, type] = {}
    left_out: dict[str, str] = {}
    for topic in sorted(topic_types):
        try:
            classes[topic] = message_class(topic_types[topic])
        except UnavailableTypeError:
            left_out[topic] = topic_types[topic]
    if not classes:
        topic = next(iter(left_out))
        raise UnavailableTypeError(
            f'topic {topic} has message type {left_out[topic]} which is not available in this '
            'ROS install' + (f' (nor are the types of the other {len(left_out) - 1} topics)'
                             if len(left_out) > 1 else ''))
    if left_out:
        warn('not played, their message types are not installed in this ROS environment '
             '(no node of the graph reads them): '
             + ', '.join(f'{t} ({m})' for t, m in left_out.items()))
    return classes
