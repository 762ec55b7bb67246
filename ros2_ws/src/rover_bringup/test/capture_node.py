"""Test helper process: subscribes to played topics and writes what it received to JSON.

Run as ``python capture_node.py OUT.json --expect TOPIC=N ... --clock-until NS``. It exits
when every topic got its expected count and /clock reached ``NS`` (or on timeout, or on
SIGTERM), after writing the JSON: per topic the received messages (stamp and the field that
encodes the sequence number, or the image's SHA-256), and every /clock value.
"""

from __future__ import annotations

import argparse
import faulthandler
import hashlib
import json
import sys
import time
from pathlib import Path

import rclpy
from geometry_msgs.msg import PoseStamped
from rclpy.executors import ExternalShutdownException, SingleThreadedExecutor
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CompressedImage, Imu

DEPTH = 2000  # deep reader queue: the test is about the player losing nothing
LINGER_S = 15.0  # at most this long, once complete, waiting for the player to leave


def _stamp(header: object) -> int:
    return header.stamp.sec * 1_000_000_000 + header.stamp.nanosec  # type: ignore[attr-defined]


class Capture(Node):
    """Records received messages per topic."""

    def __init__(self, expect: dict[str, int], clock_until: int) -> None:
        super().__init__('capture')
        self.expect = expect
        self.clock_until = clock_until
        self.received: dict[str, list[dict]] = {t: [] for t in expect}
        self.clock: list[int] = []
        best_effort = QoSProfile(depth=DEPTH, reliability=ReliabilityPolicy.BEST_EFFORT)
        reliable = QoSProfile(depth=DEPTH, reliability=ReliabilityPolicy.RELIABLE)
        # /clock first: the player then sees it matched no later than the data topics.
        self.create_subscription(Clock, '/clock', self._on_clock, reliable)
        handlers = {
            '/imu/data': (Imu, self._on_imu, best_effort),
            '/stereo/left/image_raw/compressed': (CompressedImage, self._on_image, best_effort),
            '/ground_truth/pose': (PoseStamped, self._on_pose, reliable),
        }
        for topic in expect:
            cls, cb, qos = handlers[topic]
            self.create_subscription(cls, topic, cb, qos)

    def _on_clock(self, msg: Clock) -> None:
        self.clock.append(msg.clock.sec * 1_000_000_000 + msg.clock.nanosec)

    def _on_imu(self, msg: Imu) -> None:
        self.received['/imu/data'].append(
            {'stamp': _stamp(msg.header), 'seq': round(msg.linear_acceleration.x)}
        )

    def _on_image(self, msg: CompressedImage) -> None:
        self.received['/stereo/left/image_raw/compressed'].append(
            {
                'stamp': _stamp(msg.header),
                'format': msg.format,
                'sha256': hashlib.sha256(bytes(msg.data)).hexdigest(),
            }
        )

    def _on_pose(self, msg: PoseStamped) -> None:
        self.received['/ground_truth/pose'].append(
            {'stamp': _stamp(msg.header), 'seq': round(msg.pose.position.x)}
        )

    def complete(self) -> bool:
        """Whether everything expected has arrived."""
        return all(len(self.received[t]) >= n for t, n in self.expect.items()) and bool(
            self.clock and self.clock[-1] >= self.clock_until
        )


def main() -> int:
    """Capture until complete, timeout or SIGTERM; write the JSON."""
    parser = argparse.ArgumentParser()
    parser.add_argument('out', type=Path)
    parser.add_argument('--expect', nargs='+', required=True, metavar='TOPIC=N')
    parser.add_argument('--clock-until', type=int, required=True)
    parser.add_argument('--timeout', type=float, default=60.0)
    args = parser.parse_args()
    expect = {k: int(v) for k, v in (e.split('=') for e in args.expect)}
    # A capture still alive 5 s past its own deadline is hung (seen in 4 of ~25 CI runs,
    # after the player had finished; the last one showed destroy_node): print every
    # thread's stack to stderr, where pytest shows it, so that a failure says where.
    faulthandler.dump_traceback_later(args.timeout + LINGER_S + 5.0, exit=False)
    rclpy.init()
    node = Capture(expect, args.clock_until)
    executor = SingleThreadedExecutor()
    executor.add_node(node)
    deadline = time.monotonic() + args.timeout
    try:
        while not node.complete() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.1)
        # Let the player leave first (it waits for our acknowledgements, then exits):
        # one CI run in ~25 hung in this process's destroy_node below, Fast DDS deleting
        # its participant while the player's was being deleted too.
        linger = time.monotonic() + LINGER_S
        while node.count_publishers('/clock') > 0 and time.monotonic() < linger:
            executor.spin_once(timeout_sec=0.1)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        args.out.write_text(json.dumps({'topics': node.received, 'clock': node.clock}))
        node.destroy_node()
        rclpy.try_shutdown()
    return 0


if __name__ == '__main__':
    sys.exit(main())
