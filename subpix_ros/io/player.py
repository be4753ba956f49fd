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

from subpix_ros.io.bags import BagError, BagWriter, bag_topics, read_messages

__all__ = ["message_class", "Player", "Recorder", "ReplayStats"]


def message_class(msgtype: str):
    """The rclpy message class for ``pkg/msg/Type`` (BagError if unknown)."""
    parts = msgtype.split("/")
    if len(parts) == 2:
        parts = [parts[0], "msg", parts[1]]
    if len(parts) != 3 or not all(parts):
        raise BagError(f"unknown message type {msgtype!r}")
    try:
        return getattr(importlib.import_module(f"{parts[0]}.{parts[1]}"), parts[2])
    except (ImportError, AttributeError):
        raise BagError(f"unknown message type {msgtype!r} (no Python message package {parts[0]} installed)") from None


@dataclass
class ReplayStats:
    published: int = 0
    loops: int = 0
    late_ms_max: float = 0.0


class Player:
    """Replay one bag through an rclpy node."""

    def __init__(self, node, bag: str | Path, *, topics: Sequence[str] | None = None, rate: float = 1.0,
                 loop: bool = False, clock: bool = False, qos_depth: int = 100,
                 remap: dict[str, str] | None = None) -> None:
        from rclpy.qos import DurabilityPolicy, HistoryPolicy, QoSProfile, ReliabilityPolicy

        if not rate > 0:
            raise BagError(f"rate must be > 0, got {rate}")
        self.node = node
        self.bag = Path(bag)
        self.rate = float(rate)
        self.loop = loop
        self.stats = ReplayStats()
        info = bag_topics(self.bag)
        present = {t.name: t for t in info}
        if topics:
            missing = [t for t in topics if t not in present]
            if missing:
                raise BagError(f"topic(s) not in bag {self.bag}: {', '.join(missing)} (bag has: {', '.join(sorted(present))})")
            info = [present[t] for t in topics]
        if not info:
            raise BagError(f"bag {self.bag} has no messages")
        self.topics = [t.name for t in info]
        qos = QoSProfile(history=HistoryPolicy.KEEP_LAST, depth=qos_depth,
                         reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.VOLATILE)
        remap = remap or {}
        self.publishers = {t.name: node.create_publisher(message_class(t.msgtype), remap.get(t.name, t.name), qos)
                           for t in info}
        self._clock_pub = None
        if clock:
            from rosgraph_msgs.msg import Clock

            self._clock_cls = Clock
            self._clock_pub = node.create_publisher(Clock, "/clock", 10)
        self._stop = threading.Event()

    def stop(self) -> None:
        self._stop.set()

    @property
    def stopped(self) -> bool:
        return self._stop.is_set()

    def wait_for_acks(self, timeout_s: float) -> bool:
        """Block until every reliable subscriber has acknowledged every message published so far
        (``Publisher.wait_for_all_acked``, the same wait as ``ros2 bag play --wait-for-all-acked``), at
        most ``timeout_s`` seconds in all. False if some were still unacknowledged: a subscriber that is
        slow, stalled or gone (a dead reader stays matched until its DDS lease runs out)."""
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

    def wait_for_subscribers(self, topics: Sequence[str], timeout_s: float = 10.0) -> bool:
        """Block until every topic in ``topics`` has a matched subscriber."""
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not self._stop.is_set():
            pubs = {**self.publishers, "/clock": self._clock_pub}
            if all(pubs[t] is not None and pubs[t].get_subscription_count() > 0 for t in topics):
                return True
            time.sleep(0.05)
        return False

    def wait_for_any_subscriber(self, timeout_s: float = 15.0) -> bool:
        """Block until some replayed topic (not ``/clock``) has a matched subscriber.

        Returns False on timeout. The default of ``subpix replay``: a new publisher is matched
        with subscribers already running only after discovery, so a short bag replayed at once
        can be over before anyone receives it (docs/design-notes.md, "Camera frames between
        processes")."""
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
            for m in read_messages(self.bag, self.topics):
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
            self.stats.loops += 1
            if not self.loop:
                break
        return self.stats


class Recorder:
    """Subscribe raw to topics and write them to a rosbag2 (mcap) file."""

    def __init__(self, node, output: str | Path, topics: Sequence[str], *, discover_timeout_s: float = 10.0,
                 storage: str = "mcap") -> None:
        from rclpy.qos import QoSProfile, ReliabilityPolicy

        self.node = node
        self.count = 0
        self._lock = threading.Lock()
        types = self._discover(topics, discover_timeout_s)
        self.writer = BagWriter(output, storage=storage)
        self.subs = []
        for topic in topics:
            # Reliable unless a publisher only offers best effort (as ros2 bag does).
            offered = [i.qos_profile.reliability for i in node.get_publishers_info_by_topic(topic)]
            best_effort = any(r == ReliabilityPolicy.BEST_EFFORT for r in offered)
            qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.BEST_EFFORT if best_effort
                             else ReliabilityPolicy.RELIABLE)
            msgtype = types[topic]
            cls = message_class(msgtype)
            self.subs.append(node.create_subscription(cls, topic, self._make_cb(topic, msgtype), qos, raw=True))

    def _discover(self, topics: Sequence[str], timeout_s: float) -> dict[str, str]:
        deadline = time.monotonic() + timeout_s
        names = {}
        while True:
            for name, types in self.node.get_topic_names_and_types():
                if types:
                    names[name] = types[0]
            want = {t: names[t] for t in topics if t in names}
            if len(want) == len(topics):
                return want
            if time.monotonic() > deadline:
                missing = [t for t in topics if t not in names]
                raise BagError(f"no publisher found for topic(s): {', '.join(missing)} within {timeout_s:.0f} s")
            time.sleep(0.1)

    def _make_cb(self, topic: str, msgtype: str):
        def cb(raw: bytes) -> None:
            t = time.time_ns()
            with self._lock:
                self.writer.write(topic, msgtype, t, raw)
                self.count += 1

        return cb

    def close(self) -> None:
        with self._lock:
            self.writer.close()
