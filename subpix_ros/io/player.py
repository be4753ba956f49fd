"""Bag replay and record over ROS 2, with raw CDR pass-through.

``Player`` publishes a bag's messages with their original timing (scaled by
``rate``), as the recorded bytes (``publisher.publish(raw)``: no
re-serialisation), optionally with ``/clock`` so nodes run with
``use_sim_time``. ``Recorder`` subscribes with ``raw=True`` and writes what
arrives into a rosbag2 file. Both need an initialised rclpy context.
"""

from __future__ import annotations

import importlib
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

from subpix_ros.io.bags import BagError, BagWriter, ReadReport, bag_topics, read_messages

__all__ = ["message_class", "Player", "Recorder", "ReplayStats"]


def message_class(msgtype: str):
    """Return the rclpy message class for ``pkg/msg/Type`` (BagError if unknown)."""
    parts = msgtype.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise BagError(f"unknown message type {msgtype!r}")
    try:
        return getattr(importlib.import_module(f"{parts[0]}.{parts[1]}"), parts[2])
    except (ImportError, AttributeError):
        raise BagError(
            f"unknown message type {msgtype!r} (no Python message package {parts[0]} installed)"
        ) from None


@dataclass
class ReplayStats:
    """Counters of a replay: messages published, loops done, worst lateness (ms)."""

    published: int = 0
    loops: int = 0
    late_ms_max: float = 0.0


class Player:
    """Replay one bag through an rclpy node."""

    def __init__(
        self,
        node,
        bag: str | Path,
        *,
        topics: Sequence[str] | None = None,
        rate: float = 1.0,
        loop: bool = False,
        clock: bool = False,
        qos_depth: int = 100,
        remap: dict[str, str] | None = None,
        skip_corrupt: bool = False,
    ) -> None:
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        if not rate > 0:
            raise BagError(f"rate must be > 0, got {rate}")
        self.node = node
        self.bag = Path(bag)
        self.rate = float(rate)
        self.loop = loop
        self.stats = ReplayStats()
        self.skip_corrupt = skip_corrupt
        #: what the bag reader skipped (--skip-corrupt), summed over loops
        self.read_report = ReadReport()
        info = bag_topics(self.bag)
        present = {t.name: t for t in info}
        if topics:
            missing = [t for t in topics if t not in present]
            if missing:
                raise BagError(
                    f"topic(s) not in bag {self.bag}: {', '.join(missing)} (bag has: {', '.join(sorted(present))})"
                )
            info = [present[t] for t in topics]
        if not info:
            raise BagError(f"bag {self.bag} has no messages")
        self.topics = [t.name for t in info]
        from rosbags.interfaces import QosDurability

        def qos(t):
            # Reliable always (a subscriber of either kind matches); transient local when every
            # recorded publisher offered it (a latched topic stays latched), as ros2 bag play does.
            latched = bool(t.qos) and all(
                q.durability == QosDurability.TRANSIENT_LOCAL for q in t.qos
            )
            return QoSProfile(
                history=HistoryPolicy.KEEP_LAST,
                depth=qos_depth,
                reliability=ReliabilityPolicy.RELIABLE,
                durability=DurabilityPolicy.TRANSIENT_LOCAL
                if latched
                else DurabilityPolicy.VOLATILE,
            )

        remap = remap or {}
        self.publishers = {
            t.name: node.create_publisher(
                message_class(t.msgtype), remap.get(t.name, t.name), qos(t)
            )
            for t in info
        }
        self._clock_pub = None
        if clock:
            from rosgraph_msgs.msg import Clock

            self._clock_cls = Clock
            self._clock_pub = node.create_publisher(Clock, "/clock", 10)
        self._stop = threading.Event()

    def stop(self) -> None:
        """Ask the replay to stop (it checks between messages)."""
        self._stop.set()

    @property
    def stopped(self) -> bool:
        """Whether a stop was asked for."""
        return self._stop.is_set()

    def wait_for_acks(self, timeout_s: float) -> bool:
        """Wait until every reliable subscriber has acknowledged every message published so far.

        The same wait as ``ros2 bag play --wait-for-all-acked`` (``Publisher.wait_for_all_acked``),
        at most ``timeout_s`` seconds in all. False if some were still unacknowledged: a
        subscriber that is slow, stalled or gone (a dead reader stays matched until its DDS lease
        runs out).
        """
        from rclpy.duration import Duration

        deadline = time.monotonic() + max(0.0, timeout_s)
        for pub in self.publishers.values():
            left = max(0.0, deadline - time.monotonic())
            try:
                if not pub.wait_for_all_acked(Duration(nanoseconds=int(left * 1e9))):
                    return False
            except Exception:  # noqa: BLE001 - the context is already shut down (Ctrl-C): nothing to wait for
                return False
        return True

    def wait_for_subscribers(
        self, topics: Sequence[str], timeout_s: float = 10.0, count: int = 1
    ) -> bool:
        """Block until every topic in ``topics`` has ``count`` matched subscribers (or more)."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not self._stop.is_set():
            pubs = {**self.publishers, "/clock": self._clock_pub}
            if all(
                pubs[t] is not None and pubs[t].get_subscription_count() >= count for t in topics
            ):
                return True
            time.sleep(0.05)
        return False

    def wait_for_any_subscriber(self, timeout_s: float = 15.0) -> bool:
        """Block until some replayed topic (not ``/clock``) has a matched subscriber.

        Returns False on timeout. The default of ``subpix replay``: a new publisher is matched
        with subscribers already running only after discovery, so a short bag replayed at once
        can be over before anyone receives it (docs/design-notes.md, "Camera frames between
        processes").
        """
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not self._stop.is_set():
            if any(pub.get_subscription_count() > 0 for pub in self.publishers.values()):
                return True
            time.sleep(0.05)
        return False

    def _publish_clock(self, bag_ns: int) -> None:
        if self._clock_pub is not None:
            msg = self._clock_cls()
            msg.clock.sec, msg.clock.nanosec = divmod(int(bag_ns), 1_000_000_000)
            self._clock_pub.publish(msg)

    def _sleep_until(self, wall_target: float, bag_at: Callable[[float], int]) -> None:
        while not self._stop.is_set():
            now = time.monotonic()
            if now >= wall_target:
                return
            self._publish_clock(bag_at(now))
            time.sleep(min(0.02, wall_target - now))

    def play(self, on_message: Callable[[str, int], None] | None = None) -> ReplayStats:
        """Publish the bag (again and again with ``loop``) until done or stopped."""
        while not self._stop.is_set():
            wall0 = None
            bag0 = None
            report = ReadReport()
            for m in read_messages(
                self.bag, self.topics, skip_corrupt=self.skip_corrupt, report=report
            ):
                if self._stop.is_set():
                    break
                if wall0 is None:
                    wall0, bag0 = time.monotonic(), m.timestamp_ns
                target = wall0 + (m.timestamp_ns - bag0) / 1e9 / self.rate
                self._sleep_until(target, lambda now: bag0 + int((now - wall0) * self.rate * 1e9))
                late = (time.monotonic() - target) * 1000.0
                self.stats.late_ms_max = max(self.stats.late_ms_max, late)
                self._publish_clock(m.timestamp_ns)
                self.publishers[m.topic].publish(m.raw)
                self.stats.published += 1
                if on_message is not None:
                    on_message(m.topic, m.timestamp_ns)
            if self.stats.loops == 0:
                self.read_report = report
            self.stats.loops += 1
            if not self.loop:
                break
        return self.stats


def _bag_qos(q):
    """Convert an rclpy QoSProfile to the rosbags ``Qos`` of a bag's offered_qos_profiles.

    The policies share rmw's integer values.
    """
    from rosbags.interfaces import (
        Qos,
        QosDurability,
        QosHistory,
        QosLiveliness,
        QosReliability,
        QosTime,
    )

    def t(d):
        sec, nsec = divmod(int(d.nanoseconds), 1_000_000_000)
        return QosTime(sec, nsec)

    return Qos(
        QosHistory(int(q.history)),
        int(q.depth),
        QosReliability(int(q.reliability)),
        QosDurability(int(q.durability)),
        t(q.deadline),
        t(q.lifespan),
        QosLiveliness(int(q.liveliness)),
        t(q.liveliness_lease_duration),
        bool(q.avoid_ros_namespace_conventions),
    )


class Recorder:
    """Subscribe raw to topics and write them to a rosbag2 file, as ``ros2 bag record`` does.

    A topic is subscribed when its first publisher appears (call :meth:`poll` now and then; it
    returns the topics subscribed by that call), with the publishers' QoS: best effort if any
    publisher offers only best effort, transient local if every publisher offers it (so a
    latched last sample is recorded), reliable and volatile otherwise. Topics that appear later
    are recorded from when they appear. The bag is created with the first subscription and is
    complete after :meth:`close`.
    """

    def __init__(
        self, node, output: str | Path, topics: Sequence[str], *, storage: str = "mcap"
    ) -> None:
        if not topics:
            raise BagError("no topic to record")
        self.node = node
        self.output = Path(output)
        self.storage = storage
        self.count = 0
        self.counts: dict[str, int] = {t: 0 for t in topics}
        #: messages DDS reported lost before the recorder took them, per topic (not in the bag)
        self.lost: dict[str, int] = {}
        self.pending = list(dict.fromkeys(topics))
        self.subscribed: dict[str, str] = {}  # topic -> message type
        self._lock = threading.Lock()
        self.writer: BagWriter | None = None
        if self.output.exists():  # refuse now, not when the first publisher appears
            raise BagError(f"output exists: {self.output}")
        if not self.output.parent.is_dir():
            raise BagError(f"output folder does not exist: {self.output.parent}")
        self.subs = []

    def poll(self) -> list[str]:
        """Subscribe every pending topic that now has a publisher; the topics subscribed."""
        from rclpy.event_handler import SubscriptionEventCallbacks
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        new = []
        for topic in list(self.pending):
            infos = self.node.get_publishers_info_by_topic(topic)
            if not infos:
                continue
            msgtype = infos[0].topic_type
            others = {i.topic_type for i in infos} - {msgtype}
            if others:
                raise BagError(
                    f"topic {topic} is published with several types: {msgtype}, {', '.join(others)}"
                )
            cls = message_class(msgtype)
            best_effort = any(
                i.qos_profile.reliability == ReliabilityPolicy.BEST_EFFORT for i in infos
            )
            latched = all(
                i.qos_profile.durability == DurabilityPolicy.TRANSIENT_LOCAL for i in infos
            )
            qos = QoSProfile(
                depth=100,
                reliability=ReliabilityPolicy.BEST_EFFORT
                if best_effort
                else ReliabilityPolicy.RELIABLE,
                durability=DurabilityPolicy.TRANSIENT_LOCAL
                if latched
                else DurabilityPolicy.VOLATILE,
            )
            with self._lock:
                if self.writer is None:
                    self.writer = BagWriter(self.output, storage=self.storage)
                self.writer.add_topic(topic, msgtype, [_bag_qos(i.qos_profile) for i in infos])
            self.subs.append(
                self.node.create_subscription(
                    cls,
                    topic,
                    self._make_cb(topic, msgtype),
                    qos,
                    raw=True,
                    event_callbacks=SubscriptionEventCallbacks(
                        message_lost=self._make_lost_cb(topic), use_default_callbacks=False
                    ),
                )
            )
            self.subscribed[topic] = msgtype
            self.pending.remove(topic)
            new.append(topic)
        return new

    def _make_lost_cb(self, topic: str):
        def lost(event) -> None:  # DDS's SAMPLE_LOST: cumulative per subscription
            with self._lock:
                self.lost[topic] = int(event.total_count)

        return lost

    def _make_cb(self, topic: str, msgtype: str):
        def cb(raw: bytes) -> None:
            t = time.time_ns()
            with self._lock:
                if self.writer is None:
                    return  # closed
                self.writer.write(topic, msgtype, t, raw)
                self.count += 1
                self.counts[topic] += 1

        return cb

    def close(self) -> None:
        """Close the recorded bag; later messages are not written."""
        with self._lock:
            if self.writer is not None:
                self.writer.close()
                self.writer = None
