"""rclpy session helper shared by the globloc nodes."""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from contextlib import contextmanager

import rclpy


def ros_args(prog: str, args: Sequence[str]) -> list[str]:
    """The argv for ``rclpy.init``: program name plus ``--ros-args ...`` if any were given.

    Args:
        prog: Program name (argv[0]).
        args: ROS arguments that followed ``--ros-args`` on the command line.
    """
    return [prog, '--ros-args', *args] if args else [prog]


@contextmanager
def ros_session(args: Sequence[str]) -> Iterator[None]:
    """``rclpy.init`` ... ``rclpy.try_shutdown`` around a block.

    rclpy 7.1 (Jazzy) ``init`` is not a context manager yet (newer distros make it one); this
    gives ``with`` semantics now. ``try_shutdown`` because a SIGINT/SIGTERM has usually shut
    the context down already, and a plain ``shutdown`` would raise.

    Args:
        args: Full argv for ``rclpy.init`` (see ``ros_args``).
    """
    rclpy.init(args=list(args))
    try:
        yield
    finally:
        rclpy.try_shutdown()
