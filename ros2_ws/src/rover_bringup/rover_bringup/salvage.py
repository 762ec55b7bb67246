"""``globloc salvage``: the complete chunks of a cut-short MCAP bag, as a new bag. No rclpy.

A rosbag2 MCAP file ends with a summary, a footer and the end magic; a recording that was
cut short (recorder killed, disk full, copy interrupted) has none of them, and readers that
start from the summary (rosbags, ``globloc play``) refuse it. Its chunks are still there:
this reads the file from the start, record by record (``mcap``'s stream reader), and copies
every message of every complete chunk, with its channel's type and offered QoS, into a new
rosbag2 directory (MCAP, Jazzy types). The incomplete last chunk is dropped and said so.
"""

from __future__ import annotations

import shutil
from dataclasses import dataclass
from pathlib import Path

from rover_bringup.errors import GloblocError


@dataclass(frozen=True)
class SalvageReport:
    """What was salvaged.

    Attributes:
        source: The MCAP file read.
        out: The new bag directory.
        messages: Messages copied.
        topics: Messages copied per topic.
        last_time_ns: Log time of the last message copied (None if none).
        stopped: Why reading stopped before the end of a well-formed file ('' if it did
            not).
    """

    source: Path
    out: Path
    messages: int
    topics: dict[str, int]
    last_time_ns: int | None
    stopped: str


def _source_file(bag: Path) -> Path:
    rosbag = bag / 'rosbag' if (bag / 'rosbag').is_dir() else bag
    files = sorted(rosbag.glob('*.mcap')) if rosbag.is_dir() else []
    if bag.is_file() and bag.suffix == '.mcap':
        return bag
    if len(files) != 1:
        raise GloblocError(f'{bag}: expected one .mcap file in {rosbag}, found {len(files)}')
    return files[0]


def salvage(bag: Path, out: Path) -> SalvageReport:
    """Copy the readable messages of a (cut-short) MCAP bag into a new bag at ``out``.

    Args:
        bag: A bag directory (``bags/<name>/`` or its ``rosbag/``) or the .mcap file.
        out: The rosbag2 directory to create (must not exist).

    Raises:
        GloblocError: No single .mcap file, ``out`` exists, no message could be read, or a
            channel's message type is not a ROS 2 Jazzy type.
    """
    from mcap.records import Channel, Message, Schema
    from mcap.stream_reader import StreamReader
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.rosbag2.metadata import parse_qos
    from rosbags.typesys import Stores, get_typestore

    source = _source_file(bag)
    if out.exists():
        raise GloblocError(f'output bag {out} exists already')
    typestore = get_typestore(Stores.ROS2_JAZZY)
    schemas: dict[int, Schema] = {}
    channels: dict[int, Channel] = {}
    counts: dict[str, int] = {}
    last: int | None = None
    stopped = ''
    writer = Writer(out, version=9, storage_plugin=StoragePlugin.MCAP)
    try:
        writer.open()
        conns = {}
        with source.open('rb') as fh:
            try:
                for record in StreamReader(fh).records:
                    if isinstance(record, Schema):
                        schemas[record.id] = record
                    elif isinstance(record, Channel):
                        channels[record.id] = record
                    elif isinstance(record, Message):
                        channel = channels.get(record.channel_id)
                        if channel is None or channel.schema_id not in schemas:
                            continue
                        if channel.id not in conns:
                            msgtype = schemas[channel.schema_id].name
                            if msgtype not in typestore.types:
                                raise GloblocError(f'{source}: topic {channel.topic} has type '
                                                   f'{msgtype}, not a ROS 2 Jazzy type')
                            qos = parse_qos(channel.metadata.get('offered_qos_profiles', ''))
                            conns[channel.id] = writer.add_connection(
                                channel.topic, msgtype, typestore=typestore,
                                offered_qos_profiles=qos)
                        writer.write(conns[channel.id], record.log_time, record.data)
                        counts[channel.topic] = counts.get(channel.topic, 0) + 1
                        last = record.log_time
            except GloblocError:
                raise
            except Exception as exc:  # EndOfFile, a bad record: the rest is lost
                stopped = f'{type(exc).__name__}: {exc}'.rstrip(': ')
    except BaseException:
        writer.close()
        shutil.rmtree(out, ignore_errors=True)
        raise
    writer.close()
    if not counts:
        shutil.rmtree(out, ignore_errors=True)
        raise GloblocError(f'{source}: no complete chunk to salvage ({stopped or "empty"})')
    return SalvageReport(source, out, sum(counts.values()), counts, last, stopped)
