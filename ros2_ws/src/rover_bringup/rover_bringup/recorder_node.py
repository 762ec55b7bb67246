"""OutputRecorder: subscribes to output topics as raw CDR and writes them to an OutputBag."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import replace
from functools import partial

from rclpy.event_handler import QoSRequestedIncompatibleQoSInfo, SubscriptionEventCallbacks
from rclpy.node import Node

from rover_bringup.msgtypes import message_class
from rover_bringup.qos import PLAYBACK_MIN_DEPTH
from rover_bringup.rclpy_qos import to_bag_qos, to_profile
from rover_bringup.recording import OutputBag
from rover_bringup.topics import TopicContract


class OutputRecorder(Node):
    """Records topics with the QoS the design gives them, stamped with receive (sim) time.

    Subscriptions request the design QoS (reliable; transient local where the design says so,
    so that data latched before the recorder matched is still delivered). A publisher that
    offers less (best effort, or volatile for a latched topic) cannot match: that is logged as
    an error naming the topic rather than silently recording nothing.
    """

    def __init__(self, out: OutputBag, topics: Mapping[str, TopicContract]) -> None:
        """Subscribe to every topic.

        Args:
            out: Bag to write to.
            topics: Topic name -> design contract (type and QoS).
        """
        super().__init__('globloc_recorder')
        self._out = out
        for topic, contract in sorted(topics.items()):
            # A deep reader queue: this callback is cheap, but bursts (a network plus its
            # tracks at once) must not overwrite each other while it runs.
            qos = replace(contract.qos, depth=max(contract.qos.depth, PLAYBACK_MIN_DEPTH))
            self.create_subscription(
                message_class(contract.msgtype),
                topic,
                partial(self._on_message, topic, contract.msgtype),
                to_profile(qos),
                raw=True,
                event_callbacks=SubscriptionEventCallbacks(
                    incompatible_qos=partial(self._on_incompatible, topic, qos.describe())
                ),
            )
        self.get_logger().info(f'recording {len(topics)} topics to {out.path}')

    def _on_message(self, topic: str, msgtype: str, data: bytes) -> None:
        if not self._out.has_topic(topic):
            # The publisher is known by now (its message is here): store what it offered.
            offered = [to_bag_qos(i.qos_profile) for i in self.get_publishers_info_by_topic(topic)]
            self._out.add_topic(topic, msgtype, offered)
            self.get_logger().info(f'first message on {topic}')
        now = self.get_clock().now().nanoseconds
        # Sim time is 0 until the first /clock: let the bag hold such messages back.
        self._out.write(topic, now if now > 0 else None, data)

    def _on_incompatible(
        self, topic: str, requested: str, info: QoSRequestedIncompatibleQoSInfo
    ) -> None:
        self.get_logger().error(
            f'{topic}: a publisher offers a QoS incompatible with the requested {requested} '
            f'(policy id {info.last_policy_kind}): its messages are not recorded'
        )
