"""Reading rosbag2 bags (MCAP or sqlite3) for playback, with rosbags; no rclpy here.

Two directory layouts are accepted: the rosbag2 directory itself (the one holding
``metadata.yaml``) and a project bag directory ``bags/<name>/`` whose rosbag2 directory is
``rosbag/`` next to ``rover.yaml``, ``orbital.tif`` and the ground truth.
"""

from __future__ import annotations

from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType

from rosbags.interfaces import Connection, ConnectionExtRosbag2
from rosbags.rosbag2 import Reader

from rover_bringup.errors import GloblocError
from rover_bringup.qos import TopicQos, qos_from_offers
from rover_bringup.topics import design_qos

METADATA = 'metadata.yaml'
ROSBAG_SUBDIR = 'rosbag'


class BagReadError(GloblocError):
    """The bag cannot be opened or a message in it cannot be read."""


@dataclass(frozen=True)
class BagLocation:
    """Where a bag and the files around it are.

    Attributes:
        root: The project bag directory (``bags/<name>/``, holds ``rover.yaml``), or the
            rosbag2 directory itself when it stands alone.
        rosbag: The rosbag2 directory (holds ``metadata.yaml``).
    """

    root: Path
    rosbag: Path

    @property
    def name(self) -> str:
        """The bag's name, used for ``out/<bag>/``."""
        return self.root.resolve().name


def locate_bag(path: str | Path) -> BagLocation:
    """Resolve a user-given bag path to its rosbag2 directory.

    Args:
        path: A rosbag2 directory, or a project bag directory with a ``rosbag/`` inside.

    Returns:
        The bag's location.

    Raises:
        BagReadError: The directory does not exist or holds no rosbag2 bag.
    """
    given = Path(path)
    if not given.is_dir():
        raise BagReadError(f'bag directory not found: {given}')
    if (given / METADATA).is_file():
        # bags/<name>/rosbag given directly: the files next to it still belong to the bag.
        root = given.parent if given.resolve().name == ROSBAG_SUBDIR else given
        return BagLocation(root=root, rosbag=given)
    if (given / ROSBAG_SUBDIR / METADATA).is_file():
        return BagLocation(root=given, rosbag=given / ROSBAG_SUBDIR)
    raise BagReadError(
        f'cannot read bag {given}: no {METADATA} in it or in its {ROSBAG_SUBDIR}/ directory'
    )


@dataclass(frozen=True)
class BagTopic:
    """A topic of a bag.

    Attributes:
        name: Topic name.
        msgtype: Message type, ``pkg/msg/Type``.
        count: Number of messages in the whole bag.
        qos: QoS to replay it with: the recorded offers combined, or the design's QoS.
        qos_recorded: Whether ``qos`` comes from the bag (False: design fallback).
    """

    name: str
    msgtype: str
    count: int
    qos: TopicQos
    qos_recorded: bool


class Bag:
    """An open bag: its topics and a time-ordered message stream.

    Use as a context manager; every rosbags failure is raised as ``BagReadError`` naming the
    bag, whether it happens at open time or while reading messages.
    """

    def __init__(self, location: BagLocation) -> None:
        """Open the bag.

        Args:
            location: Where the bag is (see ``locate_bag``).

        Raises:
            BagReadError: Unreadable metadata or storage file, or inconsistent topics.
        """
        self.location = location
        try:
            self._reader = Reader(location.rosbag)
            self._reader.open()
        except Exception as exc:  # rosbags raises ReaderError but also raw decode errors
            raise self._error(exc) from None
        self.topics = self._collect_topics(self._reader.connections)

    def _error(self, exc: BaseException) -> BagReadError:
        reason = str(exc).strip() or type(exc).__name__
        if 'end magic' in reason.lower():
            # An MCAP file is closed by a footer and end magic: without them the recording
            # was cut short (recorder killed, disk full, copy interrupted).
            reason += (' (the MCAP file has no end marker: the recording was cut short; '
                       '`globloc salvage BAG --out NEW_BAG` copies its complete chunks '
                       'into a new bag)')
        return BagReadError(f'cannot read bag {self.location.rosbag}: {reason}')

    def _collect_topics(self, connections: Sequence[Connection]) -> dict[str, BagTopic]:
        by_topic: dict[str, list[Connection]] = {}
        for conn in connections:
            by_topic.setdefault(conn.topic, []).append(conn)
        topics: dict[str, BagTopic] = {}
        for name, conns in sorted(by_topic.items()):
            msgtypes = sorted({c.msgtype for c in conns})
            if len(msgtypes) > 1:
                raise BagReadError(
                    f'cannot read bag {self.location.rosbag}: topic {name} has several message '
                    f'types ({", ".join(msgtypes)})'
                )
            offers = [
                q for c in conns if isinstance(c.ext, ConnectionExtRosbag2)
                for q in c.ext.offered_qos_profiles
            ]
            recorded = qos_from_offers(offers)
            topics[name] = BagTopic(
                name=name,
                msgtype=msgtypes[0],
                count=sum(c.msgcount for c in conns),
                qos=recorded if recorded is not None else design_qos(name),
                qos_recorded=recorded is not None,
            )
        return topics

    @property
    def start_ns(self) -> int:
        """Time stamp (ns) of the first message."""
        return self._reader.start_time

    @property
    def end_ns(self) -> int:
        """Time stamp (ns) of the last message."""
        # rosbags reports the end as last + 1 ns (an exclusive bound).
        return max(self._reader.end_time - 1, self._reader.start_time)

    @property
    def message_count(self) -> int:
        """Number of messages in the bag."""
        return self._reader.message_count

    def select(self, topics: Sequence[str] | None) -> list[BagTopic]:
        """The bag topics to play.

        Args:
            topics: Requested topic names; None or empty for all.

        Returns:
            The selected topics, sorted by name.

        Raises:
            BagReadError: A requested topic is not in the bag.
        """
        if not topics:
            return list(self.topics.values())
        missing = sorted(set(topics) - set(self.topics))
        if missing:
            raise BagReadError(
                f'topic {missing[0]} is not in bag {self.location.rosbag} '
                f'(it has: {", ".join(self.topics)})'
            )
        return [self.topics[t] for t in sorted(set(topics))]

    def messages(
        self, topics: Sequence[str], start_ns: int | None = None
    ) -> Iterator[tuple[str, int, bytes]]:
        """Messages of ``topics`` in time order, as stored (serialized CDR).

        Args:
            topics: Topic names to read.
            start_ns: Skip messages stamped before this bag time (ns).

        Yields:
            (topic, bag time in ns, CDR bytes).

        Raises:
            BagReadError: A chunk or record of the storage file is corrupt.
        """
        wanted = set(topics)
        connections = [c for c in self._reader.connections if c.topic in wanted]
        if not connections:
            return
        try:
            for conn, stamp, data in self._reader.messages(connections, start=start_ns):
                yield conn.topic, stamp, bytes(data)
        except Exception as exc:  # corrupt chunks surface as assorted decode errors
            raise self._error(exc) from None

    def close(self) -> None:
        """Close the storage files."""
        if self._reader.is_open:
            self._reader.close()

    def __enter__(self) -> Bag:
        """Return self (the bag is opened by the constructor)."""
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        """Close the bag."""
        self.close()


def open_bag(path: str | Path) -> Bag:
    """Locate and open a bag (see ``locate_bag`` for accepted layouts)."""
    return Bag(locate_bag(path))
