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

from .stamps import steady_timer

if TYPE_CHECKING:
    from .diagnostics import Diagnostics

__all__ = [
    "camera_qos",
    "best_effort_qos",
    "reliable_qos",
    "latched_qos",
    "output_qos",
    "FollowingSubscription",
    "publish_if_subscribed",
    "qos_event_callbacks",
]


def camera_qos(reliable: bool, depth: int = 5) -> QoSProfile:
    """SensorDataQoS (best effort, volatile) by default; reliable on request."""
    return reliable_qos(depth) if reliable else best_effort_qos(depth)


def best_effort_qos(depth: int = 5) -> QoSProfile:
    """SensorDataQoS with keep-last ``depth``: best effort, volatile.

    A best-effort subscription matches reliable and best-effort publishers alike, so it is the
    one to take a driver's sensor topics with (mavros publishes with rclcpp's SensorDataQoS:
    a reliable subscription gets nothing from it).
    """
    return QoSProfile(
        history=qos_profile_sensor_data.history,
        depth=depth,
        reliability=ReliabilityPolicy.BEST_EFFORT,
        durability=DurabilityPolicy.VOLATILE,
    )


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


def output_qos(latched: bool) -> QoSProfile:
    """Return the QoS of an output image publisher: latched, or reliable volatile depth 1.

    A latched (transient-local) writer keeps its last sample for late joiners: one image more in
    the publishing process (100 MB for a 7680x4320 super-resolved image).
    """
    return latched_qos() if latched else reliable_qos(1)


class FollowingSubscription:
    """A reliable subscription whose durability follows the topic's publishers.

    A transient-local (latched) subscription does not match a volatile publisher: DDS requires
    the offered durability to be at least the requested one, and the subscriber then receives
    nothing. This one is created once a publisher is seen, transient local if every publisher
    offers it (a late joiner still gets the latched message) and volatile otherwise, as
    ``subpix record`` subscribes; a timer re-checks the publishers every ``period_s`` and
    re-subscribes when the choice changes (a publisher restarted with the other durability).

    Parameters
    ----------
    node : rclpy.node.Node
        The subscribing node.
    msg_type, topic, callback
        As for ``Node.create_subscription``.
    depth : int
        Keep-last depth of the subscription.
    period_s : float
        How often the publishers are checked (s).
    **kw
        Passed to ``Node.create_subscription`` (e.g. ``raw=True``).
    """

    def __init__(
        self,
        node: Node,
        msg_type,
        topic: str,
        callback: Callable,
        depth: int = 1,
        *,
        period_s: float = 0.5,
        **kw,
    ) -> None:
        self.node = node
        self.msg_type, self.topic, self.callback = msg_type, topic, callback
        self.depth = depth
        self.kw = kw
        self.durability: DurabilityPolicy | None = None  # None: no publisher seen yet
        self.subscription = None
        self.changes = 0  # re-subscriptions after the first
        self.check()
        self.timer = steady_timer(node, period_s, self.check)  # use_sim_time: /clock may stop

    def wanted(self) -> DurabilityPolicy | None:
        """Transient local if every publisher offers it, volatile if one does not, None if none."""
        infos = self.node.get_publishers_info_by_topic(self.topic)
        if not infos:
            return None
        if all(i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos):
            return DurabilityPolicy.TRANSIENT_LOCAL
        return DurabilityPolicy.VOLATILE

    def check(self) -> None:
        """Subscribe, or re-subscribe, if the publishers call for another durability."""
        want = self.wanted()
        if want is None or want == self.durability:
            return  # no publisher now: keep the subscription, the publisher may come back
        if self.subscription is not None:
            self.node.destroy_subscription(self.subscription)
            self.changes += 1
            self.node.get_logger().info(
                f"{self.topic}: publishers now {want.name.lower()}, re-subscribed"
            )
        qos = latched_qos(self.depth)
        qos.durability = want
        self.subscription = self.node.create_subscription(
            self.msg_type, self.topic, self.callback, qos, **self.kw
        )
        self.durability = want

    def destroy(self) -> None:
        """Stop following: the timer and the subscription."""
        self.node.destroy_timer(self.timer)
        if self.subscription is not None:
            self.node.destroy_subscription(self.subscription)
            self.subscription = None


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
    """Subscription and publisher event callbacks: QoS incompatibilities and lost messages.

    A QoS incompatibility is an ERROR. A message lost before the node took it (DDS's
    SAMPLE_LOST; Fast DDS 2.14 counts samples lost in transport, e.g. fragments of large
    best-effort frames over UDP, not samples a full keep-last history replaced) is a WARN
    naming the topic, counted in /diagnostics as ``messages_lost_<topic>``: without it such
    frames were simply never seen.
    """

    def incompatible(event) -> None:
        text = f"QoS incompatible on {topic}: policy id {event.last_policy_kind} ({event.total_count} total)"
        node.get_logger().error(text)
        if diagnostics is not None:
            diagnostics.error(text)

    key = "messages_lost_" + topic.strip("/").replace("/", "_")
    try:  # the name as remapped (image -> /camera/image_raw), for the operator
        shown = node.resolve_topic_name(topic)
    except Exception:  # noqa: BLE001 - a name rcl cannot expand: as given
        shown = topic

    def lost(event) -> None:
        if diagnostics is None:
            node.get_logger().warning(f"{shown}: {event.total_count} message(s) lost")
            return
        diagnostics.set(**{key: event.total_count})
        diagnostics.warn(
            f"{shown}: messages lost in transport before this node took them ({key} counts "
            "them): large frames over UDP from a publisher without the package's Fast DDS "
            "profile, or a network that drops"
        )

    return (
        SubscriptionEventCallbacks(
            incompatible_qos=incompatible, message_lost=lost, use_default_callbacks=False
        ),
        PublisherEventCallbacks(incompatible_qos=incompatible, use_default_callbacks=False),
    )
