"""A run's verdict: which node of the graph did not do its part, one line each. No rclpy.

``globloc run`` calls a run *degraded* when a node of the graph never started, exited
before the end of the run, was restarted, or published nothing on one of the topics it
must publish (``graph.DEFAULT_OUTPUTS``, or the graph entry's ``outputs``). Each line
says why from what the recorder kept: the message counts of the outputs bag and the last
message on the node's own status topic (``/vo/status``, ``/rois/status``,
``/matcher/status``), whose counters (pairs read, input skipped by kind, the matcher's
reason) tell what the node saw.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path

from rover_bringup.errors import GloblocError

#: The status topic of the node that publishes an output topic.
STATUS_OF = {
    '/vo/odometry': '/vo/status',
    '/rois/detections': '/rois/status',
    '/rois/tracks': '/rois/status',
    '/global_pose': '/matcher/status',
    '/global_alignment': '/matcher/status',
}
STATUS_TOPICS = ('/vo/status', '/rois/status', '/matcher/status')
#: The topic an output is made from, quoted when the node's status topic says nothing.
INPUT_OF = {'/local_network': '/rois/tracks', '/global_pose': '/local_network',
            '/matcher/status': '/local_network', '/rois/detections': '/vo/odometry',
            '/rois/tracks': '/vo/odometry'}
#: Status values quoted besides the bad-input counters, per status topic, when non-zero.
QUOTED = {
    '/vo/status': ('pairs', 'imu_samples'),
    '/rois/status': ('pairs', 'waiting_for_odometry'),
    '/matcher/status': ('state', 'reason', 'ln_size'),
}
#: Status keys of bad-input counters (rover_vo ``bad_input.<kind>``, roi_detector
#: ``skipped: <kind>``), quoted when non-zero.
COUNTER_PREFIXES = ('bad_input.', 'skipped')


@dataclass(frozen=True)
class LastStatus:
    """What a status topic said last.

    Attributes:
        messages: DiagnosticArray messages recorded on the topic.
        message: The last one's status message (``vision: 120 inliers``).
        values: The last one's key-value pairs.
    """

    messages: int
    message: str = ''
    values: dict[str, str] = field(default_factory=dict)

    def quote(self, topic: str) -> str:
        """``"<message>", pairs 0, bad_input.camera_info 95``: the message, then the
        ``QUOTED`` values and the non-zero bad-input counters."""
        parts = [f'"{self.message}"'] if self.message else []
        for key, value in self.values.items():
            counter = key.startswith(COUNTER_PREFIXES)
            if (key in QUOTED.get(topic, ()) or counter) and not (counter and value == '0'):
                parts.append(f'{key} {value}')
        return ', '.join(parts)


@dataclass(frozen=True)
class NodeRun:
    """One graph node as the run saw it.

    Attributes:
        name: Node name.
        outputs: Topics it must publish.
        not_started: Why it never started ('' when it started, or when it was skipped for
            an input the bag does not have, e.g. a GN).
        restart_codes: Exit status of each incarnation that was restarted.
        exited_early: Exit status when it ended on its own and was not restarted, else None.
    """

    name: str
    outputs: tuple[str, ...] = ()
    not_started: str = ''
    restart_codes: tuple[int, ...] = ()
    exited_early: int | None = None


def degraded_reasons(nodes: Sequence[NodeRun], counts: Mapping[str, int],
                     statuses: Mapping[str, LastStatus]) -> list[str]:
    """Why a run is degraded, one line per problem; empty when it is not.

    Args:
        nodes: The graph's nodes, in graph order.
        counts: Messages recorded per topic.
        statuses: The last message of each status topic (``read_statuses``).
    """
    reasons = []
    for node in nodes:
        if node.not_started:
            reasons.append(f'{node.name} never started: {node.not_started}')
            continue
        if node.restart_codes:
            n = len(node.restart_codes)
            codes = ', '.join(str(c) for c in node.restart_codes)
            reasons.append(f'{node.name} exited (status {codes}) and was restarted {n} '
                           f'time{"s" if n > 1 else ""}: its outputs have a gap')
        if node.exited_early is not None:
            reasons.append(f'{node.name} exited (status {node.exited_early}) before the end '
                           'of the run')
        if silent := [t for t in node.outputs if not counts.get(t)]:
            reasons.append(f'{node.name} published nothing on {", ".join(silent)}'
                           + _why_silent(node, silent, counts, statuses))
    return reasons


def _why_silent(node: NodeRun, silent: list[str], counts: Mapping[str, int],
                statuses: Mapping[str, LastStatus]) -> str:
    """What the node's own status topic said last, else how much of its input came."""
    status_topic = next((STATUS_OF[t] for t in (*silent, *node.outputs) if t in STATUS_OF),
                        None)
    if status_topic is not None and status_topic not in silent:
        last = statuses.get(status_topic)
        if last is not None and last.messages:
            return (f'; its last {status_topic} (of {last.messages}): '
                    f'{last.quote(status_topic)}')
        if (source := INPUT_OF.get(silent[0])) is None:
            return f'; no {status_topic} either (its log: logs/{node.name}.log)'
        return (f'; no {status_topic} either, {counts.get(source, 0)} {source} recorded '
                f'(its log: logs/{node.name}.log)')
    if (source := INPUT_OF.get(silent[0])) is not None:
        return f'; {counts.get(source, 0)} {source} recorded (its log: logs/{node.name}.log)'
    return f' (its log: logs/{node.name}.log)'


def read_statuses(bag: Path) -> dict[str, LastStatus]:
    """The last message of each status topic (``STATUS_TOPICS``) in an outputs bag.

    Raises:
        GloblocError: The bag cannot be read (named).
    """
    from rosbags.rosbag2 import Reader
    from rosbags.typesys import Stores, get_typestore

    typestore = get_typestore(Stores.ROS2_JAZZY)
    out: dict[str, LastStatus] = {}
    try:
        with Reader(bag) as reader:
            conns = [c for c in reader.connections if c.topic in STATUS_TOPICS]
            counts = {t: sum(c.msgcount for c in conns if c.topic == t) for t in STATUS_TOPICS}
            last_raw: dict[str, tuple[str, bytes]] = {}
            # No connection given means every message to rosbags: none, nothing to read.
            for conn, _, raw in reader.messages(connections=conns) if conns else ():
                last_raw[conn.topic] = (conn.msgtype, bytes(raw))
    except Exception as exc:  # rosbags ReaderError, truncated MCAP, ...
        raise GloblocError(f'cannot read outputs bag {bag}: {exc}') from None
    for topic, (msgtype, raw) in last_raw.items():
        try:
            msg = typestore.deserialize_cdr(raw, msgtype)
            status = msg.status[0]
        except Exception:  # undecodable, or an empty array: the count still says something
            out[topic] = LastStatus(counts[topic])
            continue
        out[topic] = LastStatus(counts[topic], status.message,
                                {v.key: v.value for v in status.values})
    return out
