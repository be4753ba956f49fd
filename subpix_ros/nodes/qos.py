"""QoS profiles, lazy publishing and QoS-incompatibility callbacks shared by the nodes."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable

from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

if TYPE_CHECKING:
    from .diagnostics import Diagnostics

__all__ = [
    "camera_qos",
    "reliable_qos",
    "latched_qos",
    "publish_if_subscribed",
    "qos_event_callbacks",
]


def camera_qos(reliable: bool, depth: int = 5) -> QoSProfile:
    """SensorDataQoS (best effort, volatile) by default; reliable on request."""
    if not reliable:
        return QoSProfile(
            history=qos_profile_sensor_data.history,
            depth=depth,
            reliability=ReliabilityPolicy.BEST_EFFORT,
            durability=DurabilityPolicy.VOLATILE,
        )
    return reliable_qos(depth)


def reliable_qos(depth: int = 10) -> QoSProfile:
    """Reliable, volatile, keep-last ``depth``."""
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


def latched_qos(depth: int = 1) -> QoSProfile:
    """Reliable and transient-local: a late joiner gets the latest message.

    A publisher's depth is 1; a subscriber's ``depth`` > 1 keeps messages that arrive faster
    than it takes them.
    """
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.TRANSIENT_LOCAL,
    )


def publish_if_subscribed(publisher, make: Callable[[], Any]) -> bool:
    """Build the message with ``make()`` and publish it only if something subscribes (volatile topics).

    The lazy publishing of image_transport: a 1080p frame is a 6 MB copy
    that nobody needs when, say, the single-process pipeline hands it on in
    memory. Not for transient-local topics (a late joiner must find the
    latest message). Returns True if published.
    """
    if publisher.get_subscription_count() == 0:
        return False
    publisher.publish(make())
    return True


def qos_event_callbacks(node: Node, topic: str, diagnostics: "Diagnostics | None" = None):
    """Subscription and publisher event callbacks that log QoS incompatibilities."""

    def incompatible(event) -> None:
        text = f"QoS incompatible on {topic}: policy id {event.last_policy_kind} ({event.total_count} total)"
        node.get_logger().error(text)
        if diagnostics is not None:
            diagnostics.error(text)

    return (
        SubscriptionEventCallbacks(incompatible_qos=incompatible, use_default_callbacks=False),
        PublisherEventCallbacks(incompatible_qos=incompatible, use_default_callbacks=False),
    )
