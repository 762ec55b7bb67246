"""BagPlayer: publishes stored CDR bytes of bag messages, paced by bag time, plus /clock."""

from __future__ import annotations

import time
from collections.abc import Iterable, Mapping, Sequence

from builtin_interfaces.msg import Time
from rclpy.duration import Duration
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.publisher import Publisher
from rclpy.serialization import deserialize_message
from rosgraph_msgs.msg import Clock

from rover_bringup.bag import BagTopic
from rover_bringup.playback import NS_PER_S, PlaybackClock, Progress
from rover_bringup.qos import playback_qos
from rover_bringup.rclpy_qos import to_profile
from rover_bringup.topics import CLOCK_TOPIC, design_qos

#: Longest single sleep: bounds how late a shutdown request or a progress line can be.
_MAX_SLEEP_S = 0.05
#: Poll period while waiting for subscribers.
_POLL_S = 0.02


class BagPlayer(Node):
    """Replays bag topics with the bag's QoS and publishes /clock from bag time.

    The node never spins: it has no subscriptions, and publishing from one loop keeps the
    order of messages exactly the bag's order.
    """

    def __init__(self, topics: Sequence[BagTopic], classes: Mapping[str, type]) -> None:
        """Create one publisher per topic plus /clock.

        Args:
            topics: Topics to play; QoS as recorded (or design fallback).
            classes: Topic name -> message class (checked to be importable beforehand).
        """
        super().__init__('globloc_player')
        self._topic_pubs: dict[str, Publisher] = {}
        self._reliable: dict[str, Publisher] = {}
        for topic in topics:
            qos = playback_qos(topic.qos)
            pub = self.create_publisher(classes[topic.name], topic.name, to_profile(qos))
            self._topic_pubs[topic.name] = pub
            if qos.reliable:
                self._reliable[topic.name] = pub
            self.get_logger().info(
                f'{topic.name}: {topic.msgtype}, {topic.count} msgs, QoS {qos.describe()} '
                f'({"as recorded" if topic.qos_recorded else "design default: none recorded"})'
            )
        self._classes = {t.name: classes[t.name] for t in topics}
        #: Messages skipped because their CDR bytes do not decode, per topic.
        self.corrupt: dict[str, int] = {}
        self._clock_pub = self.create_publisher(
            Clock, CLOCK_TOPIC, to_profile(playback_qos(design_qos(CLOCK_TOPIC)))
        )
        self._reliable[CLOCK_TOPIC] = self._clock_pub
        self._last_clock_ns = -1

    def _check_ok(self) -> None:
        # SIGINT/SIGTERM shut the context down (rclpy's handler); this loop does not spin, so
        # it turns that into the exception a spinning node would see.
        if not self.context.ok():
            raise ExternalShutdownException()

    def wait_for_subscribers(
        self, topics: Sequence[str], clock_subscribers: int, timeout_s: float
    ) -> list[str]:
        """Block until the given topics are matched, or the timeout passes.

        Args:
            topics: Topics that need at least one matched subscription.
            clock_subscribers: Matched /clock subscriptions needed (one per node started with
                ``use_sim_time``).
            timeout_s: Upper bound of the wait.

        Returns:
            What is still unmatched (empty when everything matched).
        """
        deadline = time.monotonic() + timeout_s
        while True:
            self._check_ok()
            missing = [t for t in topics if self._topic_pubs[t].get_subscription_count() == 0]
            clock_count = self._clock_pub.get_subscription_count()
            if clock_count < clock_subscribers:
                missing.append(f'{CLOCK_TOPIC} ({clock_count}/{clock_subscribers} subscribers)')
            if not missing or time.monotonic() >= deadline:
                return missing
            time.sleep(_POLL_S)

    def publish_clock(self, stamp_ns: int) -> None:
        """Publish /clock = ``stamp_ns`` unless that would not advance it (stays monotonic)."""
        if stamp_ns <= self._last_clock_ns:
            return
        sec, nanosec = divmod(stamp_ns, NS_PER_S)
        self._clock_pub.publish(Clock(clock=Time(sec=sec, nanosec=nanosec)))
        self._last_clock_ns = stamp_ns

    def play(
        self,
        messages: Iterable[tuple[str, int, bytes]],
        clock: PlaybackClock,
        progress: Progress,
        clock_period_s: float,
    ) -> None:
        """Publish every message at its bag time (scaled by the rate).

        /clock ticks at most once every ``clock_period_s`` wall seconds, as rosbag2's
        ``--clock`` does: to a message's stamp right before the message goes out when the
        period has elapsed, and to the bag time of the moment while waiting for the next
        message (so sim-time timers keep running through gaps in the bag). Every process
        started with ``use_sim_time`` takes every /clock message in Python: one per bag
        message (IMU at 100 Hz, 5x) cost each of them ~0.1 core. A node's ``now()`` may lag
        a message being delivered by up to ``clock_period_s`` wall seconds. The last
        message's stamp is always published.

        Args:
            messages: (topic, bag time ns, CDR bytes) in time order.
            clock: Bag time <-> wall time mapping.
            progress: Progress counter (its ``sent`` is updated).
            clock_period_s: Wall seconds between /clock ticks while waiting.

        Raises:
            ExternalShutdownException: The context was shut down (SIGINT/SIGTERM).
        """
        logger = self.get_logger()
        self.publish_clock(clock.bag_start_ns)
        next_tick = time.monotonic() + clock_period_s
        last_stamp: int | None = None
        for topic, stamp, data in messages:
            due = clock.wall_time_of(stamp)
            while True:
                self._check_ok()
                now = time.monotonic()
                if progress.due(now):
                    logger.info(progress.line(max(self._last_clock_ns, clock.bag_start_ns)))
                if now >= due:
                    break
                if now >= next_tick:
                    self.publish_clock(min(clock.bag_time_at(now), stamp))
                    next_tick = now + clock_period_s
                time.sleep(min(due - now, next_tick - now, _MAX_SLEEP_S))
            if not self._decodes(topic, stamp, data):
                continue
            last_stamp = stamp
            if now >= next_tick:
                self.publish_clock(stamp)
                next_tick = now + clock_period_s
            self._topic_pubs[topic].publish(data)
            progress.sent += 1
        if last_stamp is not None:
            self.publish_clock(last_stamp)

    def _decodes(self, topic: str, stamp: int, data: bytes) -> bool:
        """Whether a message's CDR bytes decode as its type; a corrupt one is reported.

        A corrupt message is not sent: a subscriber's middleware would fail to take it and
        rclpy raises in the subscriber's executor, which kills the node. It is skipped
        (the rest of the bag plays), warned about with its topic and bag time (the first
        5 per topic, then every 100th) and counted in the final line.
        """
        try:
            deserialize_message(data, self._classes[topic])
            return True
        except Exception:  # rclpy raises assorted errors on bad CDR
            n = self.corrupt[topic] = self.corrupt.get(topic, 0) + 1
            if n <= 5 or n % 100 == 0:
                self.get_logger().warning(
                    f'{topic}: corrupt message at bag time {stamp / NS_PER_S:.3f} s (its '
                    f'bytes do not decode as {self._classes[topic].__name__}): skipped '
                    f'({n} on this topic so far)')
            return False

    def wait_for_acks(self, timeout_s: float) -> list[str]:
        """Wait until every subscriber acknowledged everything sent on reliable topics.

        Best-effort topics cannot be acknowledged (no acks exist in that mode): nothing can
        tell whether their last samples arrived.

        Args:
            timeout_s: Upper bound of the whole wait.

        Returns:
            Reliable topics with unacknowledged samples at the timeout.
        """
        deadline = time.monotonic() + timeout_s
        unacked = []
        for topic, pub in self._reliable.items():
            remaining = max(deadline - time.monotonic(), 0.0)
            if not pub.wait_for_all_acked(Duration(nanoseconds=round(remaining * NS_PER_S))):
                unacked.append(topic)
        return unacked

    def has_best_effort_subscribers(self) -> bool:
        """Whether any best-effort topic has a matched subscriber."""
        return any(
            pub.get_subscription_count() > 0
            for topic, pub in self._topic_pubs.items()
            if topic not in self._reliable
        )
