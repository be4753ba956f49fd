"""QoS profiles, lazy publishing and QoS-incompatibility callbacks shared by the nodes."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any, Callable

from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.node import Node
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSPolicyKind,
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
    "SequenceGaps",
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

    A QoS incompatibility is an ERROR, logged once by the node's logger and reported in
    ``diagnostics`` when given, in one line: ``QoS incompatible on /cam/image_raw
    (reliability): this node requests reliable; /camera_driver offers best_effort (1 total)``:
    the topic as remapped, the policy's name and what each side offers or requests (read from
    the ROS graph when it happens), counted in /diagnostics as ``qos_incompatible_<topic>``. A message lost before
    the node took it (DDS's SAMPLE_LOST; Fast DDS 2.14 counts samples lost in transport, e.g.
    fragments of large best-effort frames over UDP, not samples a full keep-last history
    replaced) is a WARN naming the topic, counted in /diagnostics as
    ``messages_lost_<topic>``: without it such frames were simply never seen.

    Parameters
    ----------
    node : rclpy.node.Node
        The node that subscribes or publishes ``topic``.
    topic : str
        The topic as the node names it (relative names are resolved with its remappings).
    diagnostics : Diagnostics, optional
        Where the problems are reported (None: the node's log only).

    Returns
    -------
    tuple
        ``(SubscriptionEventCallbacks, PublisherEventCallbacks)``.
    """
    suffix = topic.strip("/").replace("/", "_")
    key, incompatible_key = "messages_lost_" + suffix, "qos_incompatible_" + suffix
    try:  # the name as remapped (image -> /camera/image_raw), for the operator
        shown = node.resolve_topic_name(topic)
    except Exception:  # noqa: BLE001 - a name rcl cannot expand: as given
        shown = topic

    def incompatible(event, publishing: bool) -> None:
        policy = policy_name(event.last_policy_kind)
        sides = _qos_sides(node, shown, policy, publishing)
        text = (
            f"QoS incompatible on {shown} ({policy})"
            + (f": {sides}" if sides else "")
            + f" ({event.total_count} total)"
        )
        # one line per event (rare: one per mismatched peer), not throttled with the node's
        # other errors; /diagnostics does not log it again
        node.get_logger().error(text)
        if diagnostics is not None:
            diagnostics.set(**{incompatible_key: event.total_count})
            diagnostics.error(text, log=False)

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
            incompatible_qos=lambda event: incompatible(event, False),
            message_lost=lost,
            use_default_callbacks=False,
        ),
        PublisherEventCallbacks(
            incompatible_qos=lambda event: incompatible(event, True), use_default_callbacks=False
        ),
    )


def policy_name(kind) -> str:
    """Return a QoS policy kind (rmw's enum, as a QoS event gives it) as ``reliability`` etc."""
    try:
        name = QoSPolicyKind(int(kind)).name
    except (TypeError, ValueError):
        name = str(kind).rsplit("POLICY_", 1)[-1]
    return name.lower().replace("_", " ")


def _qos_value(qos: QoSProfile, policy: str) -> str | None:
    """Return ``qos``'s setting of ``policy`` (``reliable``, ``transient_local``, ``0.5 s``)."""
    value = getattr(qos, policy.replace(" ", "_"), None)
    if value is None:
        return None
    if hasattr(value, "nanoseconds"):  # 0 (the default) or DDS's largest: none
        ns = value.nanoseconds
        return "infinite" if ns <= 0 or ns >= 10**18 else f"{ns / 1e9:g} s"
    return value.name.lower() if hasattr(value, "name") else str(value)


#: Settings in the order DDS ranks them: an offer below the request does not match.
_RANKED = {
    "reliability": ("best_effort", "reliable"),
    "durability": ("volatile", "transient_local"),
}


def _incompatible(offered: str, requested: str, policy: str) -> bool:
    """Return True if ``offered`` does not satisfy ``requested`` (any difference, if unranked)."""
    ranks = _RANKED.get(policy, ())
    if offered in ranks and requested in ranks:
        return ranks.index(offered) < ranks.index(requested)
    return offered != requested


def _qos_sides(node: Node, topic: str, policy: str, publishing: bool) -> str:
    """Say what this node and the incompatible peers on ``topic`` offer / request of ``policy``.

    From the ROS graph as it is when the incompatibility is reported ("" if it cannot say):
    ``this node offers best_effort; /monitor requests reliable``.
    """
    try:
        pubs = node.get_publishers_info_by_topic(topic)
        subs = node.get_subscriptions_info_by_topic(topic)
    except Exception:  # noqa: BLE001 - the graph is gone during shutdown
        return ""
    mine, theirs = (pubs, subs) if publishing else (subs, pubs)
    ours, other = ("offers", "requests") if publishing else ("requests", "offers")
    me = (node.get_name(), node.get_namespace())
    own = {_qos_value(i.qos_profile, policy) for i in mine if (i.node_name, i.node_namespace) == me}
    own.discard(None)

    def clash(value: str) -> bool:
        if not own:
            return True
        pairs = [(o, value) if publishing else (value, o) for o in own]
        return any(_incompatible(offered, requested, policy) for offered, requested in pairs)

    peers = sorted(
        f"{i.node_namespace.rstrip('/')}/{i.node_name} {other} {value}"
        for i in theirs
        if (i.node_name, i.node_namespace) != me
        and (value := _qos_value(i.qos_profile, policy)) is not None
        and clash(value)
    )
    if not own and not peers:
        return ""
    said = [f"this node {ours} {', '.join(sorted(own))}"] if own else []
    return "; ".join(said + peers)


class SequenceGaps:
    """Messages of one publisher that never reached this node's callback, from DDS's sequence numbers.

    Fast DDS reports a sample lost in transport (``qos_event_callbacks``: ``message_lost``), but
    not a sample its keep-last history replaced before the node's executor took it: a node
    that falls behind at its subscription (a burst, a loaded machine) loses frames there
    without a word and counts only what it got. Every published message carries its writer's
    sequence number (``publication_sequence_number`` of rclpy's message info, 1, 2, 3 ...);
    a jump by more than one is that many messages missed, whatever the cause.

    Parameters
    ----------
    node : rclpy.node.Node
        The subscribing node.
    topic : str
        The topic as the node names it (shown resolved, with its remappings).
    diagnostics : Diagnostics
        Where the count (``messages_missed_<topic>``) and a WARN naming the topic go.
    depth : int
        The subscription's history depth (said in the warning).
    what : str
        What a message is, in the warning ("camera frames").

    Notes
    -----
    ``missed += seq - last - 1`` when ``seq > last + 1``. The numbers are one writer's: with
    more than one publisher on the topic they interleave, and nothing is counted (the message
    info does not say which writer sent a message). A number not above the last one is a
    publisher that restarted (or a second one): counting starts again from it.
    """

    def __init__(
        self, node: Node, topic: str, diagnostics: "Diagnostics", depth: int, what: str
    ) -> None:
        self.node, self.topic, self.depth, self.what = node, topic, depth, what
        self.diagnostics = diagnostics
        self.key = "messages_missed_" + topic.strip("/").replace("/", "_")
        try:
            self.shown = node.resolve_topic_name(topic)
        except Exception:  # noqa: BLE001 - a name rcl cannot expand: as given
            self.shown = topic
        self.subscription = None  # made by subscribe()
        self.last: int | None = None
        self.missed = 0

    def subscribe(self, msg_type, callback: Callable[[Any], None], qos, **kwargs):
        """Create the node's raw subscription of the topic, counted; return it.

        ``callback(message)`` is called for each message; ``kwargs`` go to
        ``create_subscription`` (``event_callbacks``).
        """
        self.subscription = self.node.create_subscription(
            msg_type, self.topic, self.wrap(callback), qos, raw=True, **kwargs
        )
        return self.subscription

    def wrap(self, callback: Callable[[Any], None]) -> Callable[[Any, dict], None]:
        """Return a subscription callback taking (message, info): counts, then ``callback(message)``."""

        def take(msg, info) -> None:
            self.see(info.get("publication_sequence_number") if isinstance(info, dict) else None)
            callback(msg)

        return take

    def see(self, seq: int | None) -> int:
        """Count the messages missed before sequence number ``seq``; return how many just now."""
        if not seq:  # an RMW that does not number its messages (0 or None)
            return 0
        last, self.last = self.last, int(seq)
        if last is None or seq <= last + 1:
            return 0
        # a jump: the graph is asked only now (not per message) whether one writer numbers them
        sub = self.subscription
        if sub is not None and sub.get_publisher_count() > 1:
            return 0  # interleaved numbers of several writers: not attributable
        gap = int(seq) - last - 1
        self.missed += gap
        self.diagnostics.set(**{self.key: self.missed})
        self.diagnostics.warn(
            f"{self.shown}: {self.what} missed before this node took them ({self.key} counts "
            f"them, from the publisher's sequence numbers): lost in transport, or replaced in "
            f"the subscription's history of {self.depth} while the node fell behind"
        )
        return gap
