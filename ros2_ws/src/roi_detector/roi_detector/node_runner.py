"""The process around a node: init, spin until shutdown, a one-line error on bad setup."""

from __future__ import annotations

import sys

from roi_network.spin import spin_until_shutdown


def run_node(node_class, name: str, args: list[str] | None = None) -> int:
    """Create ``node_class()`` and spin it until SIGINT/SIGTERM.

    Returns 0, or 1 after printing ``<name>: error: ...`` when the node cannot start
    (bad parameter, unreadable model or file: OSError, ValueError).
    """
    import rclpy

    rclpy.init(args=args)
    node = None
    try:
        node = node_class()
        spin_until_shutdown(node)
    except KeyboardInterrupt:
        pass
    except (OSError, ValueError) as exc:
        print(f"{name}: error: {exc}", file=sys.stderr)
        return 1
    finally:
        if node is not None:
            node.destroy_node()
        rclpy.try_shutdown()
    return 0
