"""``rover_vo``: one executable for the node and the offline CLI.

``rover_vo odometry ...`` and ``rover_vo eval ...`` are the offline CLI (no ROS graph);
anything else (no arguments, ``--ros-args ...``, as ``ros2 run`` and ``globloc run`` start
it) runs the node.
"""

from __future__ import annotations

import sys

CLI_COMMANDS = ("odometry", "eval", "-h", "--help")


def main() -> int:
    argv = sys.argv[1:]
    if argv and argv[0] in CLI_COMMANDS:
        from rover_vo.cli import main as cli_main

        return cli_main(argv)
    from rover_vo.vo_node import main as node_main

    return node_main(sys.argv)


if __name__ == "__main__":
    sys.exit(main())
