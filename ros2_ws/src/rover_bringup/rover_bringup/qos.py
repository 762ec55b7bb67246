"""QoS as far as bag playback and recording care about it, without importing rclpy.

A bag stores, per topic, the QoS profiles its publishers *offered*. Only reliability,
durability and history/depth decide whether data reaches a subscriber; deadline, lifespan and
liveliness are left at their defaults on purpose (a finite lifespan would drop late samples
when a bag is played slower than recorded, and no node here relies on the others).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

#: History depth ROS uses when nothing else is known (rclcpp/rclpy default profile).
DEFAULT_DEPTH = 10

#: Minimum history depth of a player's volatile publisher. History is not part of QoS matching,
#: so a deeper writer history is invisible to subscribers; it only keeps a burst (several
#: messages sharing one timestamp, or a catch-up after a slow read) from overwriting samples the
#: middleware has not sent yet.
PLAYBACK_MIN_DEPTH = 1000


@dataclass(frozen=True)
class TopicQos:
    """The QoS policies that decide delivery.

    Attributes:
        reliable: RELIABLE when True, BEST_EFFORT when False.
        transient_local: TRANSIENT_LOCAL (late joiners get the last ``depth`` samples) when
            True, VOLATILE when False.
        depth: KEEP_LAST history depth (ignored when ``keep_all``).
        keep_all: KEEP_ALL history.
    """

    reliable: bool = True
    transient_local: bool = False
    depth: int = DEFAULT_DEPTH
    keep_all: bool = False

    def describe(self) -> str:
        """Short human-readable form, e.g. ``reliable/volatile/keep_last(10)``."""
        history = 'keep_all' if self.keep_all else f'keep_last({self.depth})'
        return '/'.join(
            (
                'reliable' if self.reliable else 'best_effort',
                'transient_local' if self.transient_local else 'volatile',
                history,
            )
        )


#: ROS "default" profile: reliable, volatile, keep last 10.
DEFAULT_QOS = TopicQos()
#: ROS "sensor data" profile: best effort, volatile, keep last 5.
SENSOR_DATA_QOS = TopicQos(reliable=False, depth=5)
#: Data published once and needed by late joiners (a map, a network, an alignment).
LATCHED_QOS = TopicQos(transient_local=True, depth=1)


def qos_from_offers(offers: Sequence[Qos]) -> TopicQos | None:
    """Combine the QoS profiles a bag recorded for one topic into one publisher QoS.

    Follows what ``ros2 bag play`` does with several recorded publishers: reliable only if every
    publisher was reliable, transient local only if every publisher was, so that whatever
    subscribed to the original publishers is still compatible.

    Args:
        offers: Offered QoS profiles from the bag's connection metadata (may be empty).

    Returns:
        The combined QoS, or None when the bag recorded none (old bags, some converters).
    """
    if not offers:
        return None
    reliable = all(q.reliability == QosReliability.RELIABLE for q in offers)
    transient_local = all(q.durability == QosDurability.TRANSIENT_LOCAL for q in offers)
    keep_all = any(q.history == QosHistory.KEEP_ALL for q in offers)
    # Jazzy records history UNKNOWN / depth 0 (DDS does not propagate history): fall back to
    # the ROS default depth then.
    depths = [q.depth for q in offers if q.history == QosHistory.KEEP_LAST and q.depth > 0]
    depth = max(depths) if depths else DEFAULT_DEPTH
    return TopicQos(
        reliable=reliable, transient_local=transient_local, depth=depth, keep_all=keep_all
    )


def playback_qos(recorded: TopicQos, min_depth: int = PLAYBACK_MIN_DEPTH) -> TopicQos:
    """QoS of the player's publisher for a topic recorded with ``recorded``.

    Reliability and durability are kept (they are what subscribers match against). Volatile
    topics get a history of at least ``min_depth`` so that a fast playback never overwrites an
    unsent sample. Transient-local topics keep their recorded depth: there the depth is
    semantic (how many old samples a late joiner receives).

    Args:
        recorded: QoS recorded in the bag (or the design fallback).
        min_depth: Minimum KEEP_LAST depth for volatile topics.

    Returns:
        The publisher QoS.
    """
    if recorded.transient_local or recorded.keep_all:
        return recorded
    return replace(recorded, depth=max(recorded.depth, min_depth))


_INFINITE = QosTime(sec=0, nsec=0)  # rosbag2 writes 0/0 for "default" (infinite) durations


def to_bag_qos(qos: TopicQos) -> Qos:
    """The rosbags ``Qos`` record of ``qos`` (other policies at ROS defaults)."""
    return Qos(
        history=QosHistory.KEEP_ALL if qos.keep_all else QosHistory.KEEP_LAST,
        depth=0 if qos.keep_all else qos.depth,
        reliability=QosReliability.RELIABLE if qos.reliable else QosReliability.BEST_EFFORT,
        durability=(
            QosDurability.TRANSIENT_LOCAL if qos.transient_local else QosDurability.VOLATILE
        ),
        deadline=_INFINITE,
        lifespan=_INFINITE,
        liveliness=QosLiveliness.AUTOMATIC,
        liveliness_lease_duration=_INFINITE,
        avoid_ros_namespace_conventions=False,
    )
