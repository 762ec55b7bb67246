"""Writing recorded topics to a rosbag2 bag (MCAP storage, version 9) with rosbags. No rclpy.

The layout is a standard rosbag2 directory: ``<dir>/metadata.yaml`` and ``<dir>/<dir>.mcap``
(rosbags names the storage file after the directory), readable by rosbags, by the ``mcap``
library with ``mcap_ros2``'s decoder and by Foxglove.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from pathlib import Path

from rosbags.interfaces import Connection, Qos
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from rover_bringup.errors import GloblocError


class OutputBag:
    """A bag being recorded: topics are added when their first message arrives.

    Messages received before the first /clock (sim time 0, e.g. a transient-local network
    published at start-up) are held back and written with the first valid time stamp, so
    that the bag's timeline starts at bag time rather than at 1970.
    """

    def __init__(self, path: Path) -> None:
        """Create the bag directory.

        Args:
            path: Bag directory to create; must not exist.

        Raises:
            GloblocError: The directory exists or cannot be created.
        """
        self.path = path
        self._typestore = get_typestore(Stores.ROS2_JAZZY)
        self._writer = Writer(path, version=9, storage_plugin=StoragePlugin.MCAP)
        try:
            self._writer.open()
        except Exception as exc:  # WriterError, OSError
            raise GloblocError(f'cannot create output bag {path}: {exc}') from None
        self._connections: dict[str, Connection] = {}
        self._pending: list[tuple[str, bytes]] = []
        self.counts: dict[str, int] = {}

    def has_topic(self, topic: str) -> bool:
        """Whether ``topic`` has been added."""
        return topic in self._connections

    def add_topic(self, topic: str, msgtype: str, offered_qos: Sequence[Qos]) -> None:
        """Add a topic (a rosbag2 connection).

        Args:
            topic: Topic name.
            msgtype: Message type, ``pkg/msg/Type`` (must be in the Jazzy typestore).
            offered_qos: QoS profiles the topic's publishers offered (stored in the metadata,
                so that a player can replay the topic with them).
        """
        self._connections[topic] = self._writer.add_connection(
            topic, msgtype, typestore=self._typestore, offered_qos_profiles=list(offered_qos)
        )
        self.counts[topic] = 0

    def write(self, topic: str, stamp_ns: int | None, data: bytes) -> None:
        """Write one serialized (CDR) message.

        Args:
            topic: An added topic.
            stamp_ns: Receive time (ns); None when no clock is running yet.
            data: CDR bytes as received.
        """
        if stamp_ns is None:
            self._pending.append((topic, data))
            return
        if self._pending:
            pending, self._pending = self._pending, []
            for held_topic, held in pending:
                self._write(held_topic, stamp_ns, held)
        self._write(topic, stamp_ns, data)

    def _write(self, topic: str, stamp_ns: int, data: bytes) -> None:
        self._writer.write(self._connections[topic], stamp_ns, data)
        self.counts[topic] += 1

    def close(self) -> None:
        """Flush held-back messages (stamped with wall time: no clock ever came) and close."""
        if self._pending:
            stamp = time.time_ns()
            pending, self._pending = self._pending, []
            for topic, data in pending:
                self._write(topic, stamp, data)
        self._writer.close()


def count_messages(path: Path) -> dict[str, int]:
    """Messages per topic in a recorded bag directory.

    Raises:
        GloblocError: The bag cannot be read (e.g. the recorder was killed before closing it).
    """
    from rosbags.rosbag2 import Reader

    try:
        with Reader(path) as reader:
            counts: dict[str, int] = {}
            for conn in reader.connections:
                counts[conn.topic] = counts.get(conn.topic, 0) + conn.msgcount
            return counts
    except Exception as exc:  # ReaderError, FileNotFoundError
        raise GloblocError(f'cannot read recorded bag {path}: {exc}') from None
