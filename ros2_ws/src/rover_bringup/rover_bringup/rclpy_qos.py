"""Conversions between ``TopicQos``, rclpy ``QoSProfile`` and the rosbags ``Qos`` record.

The only QoS module that imports rclpy; the policy decisions live in ``qos.py``.
"""

from __future__ import annotations

from enum import Enum
from typing import TypeVar

from rclpy.duration import Duration
from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy
from rosbags.interfaces import (
    Qos,
    QosDurability,
    QosHistory,
    QosLiveliness,
    QosReliability,
    QosTime,
)

from rover_bringup.qos import TopicQos

_E = TypeVar('_E', bound=Enum)


def to_profile(qos: TopicQos) -> QoSProfile:
    """The rclpy profile for ``qos`` (deadline, lifespan, liveliness at their defaults)."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_ALL if qos.keep_all else HistoryPolicy.KEEP_LAST,
        depth=qos.depth,
        reliability=ReliabilityPolicy.RELIABLE if qos.reliable else ReliabilityPolicy.BEST_EFFORT,
        durability=(
            DurabilityPolicy.TRANSIENT_LOCAL if qos.transient_local else DurabilityPolicy.VOLATILE
        ),
    )


def _same_value(enum: type[_E], value: int, unknown: _E) -> _E:
    # rclpy's and rosbags' QoS enums both mirror rmw's numbering.
    try:
        return enum(int(value))
    except ValueError:
        return unknown


def _qos_time(duration: Duration) -> QosTime:
    sec, nsec = divmod(duration.nanoseconds, 1_000_000_000)
    return QosTime(sec=sec, nsec=nsec)


def to_bag_qos(profile: QoSProfile) -> Qos:
    """The rosbags record of a profile a publisher offered (as the graph API reports it)."""
    return Qos(
        history=_same_value(QosHistory, profile.history, QosHistory.UNKNOWN),
        depth=profile.depth,
        reliability=_same_value(QosReliability, profile.reliability, QosReliability.UNKNOWN),
        durability=_same_value(QosDurability, profile.durability, QosDurability.UNKNOWN),
        deadline=_qos_time(profile.deadline),
        lifespan=_qos_time(profile.lifespan),
        liveliness=_same_value(QosLiveliness, profile.liveliness, QosLiveliness.UNKNOWN),
        liveliness_lease_duration=_qos_time(profile.liveliness_lease_duration),
        avoid_ros_namespace_conventions=profile.avoid_ros_namespace_conventions,
    )
