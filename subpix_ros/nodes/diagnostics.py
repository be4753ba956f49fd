"""One DiagnosticStatus per node on ``/diagnostics`` (the diagnostic_updater equivalent)."""

from __future__ import annotations

import collections
import math
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rclpy.node import Node

from .stamps import steady_timer
from .worker import DropOldestWorker, RateMeter

__all__ = ["Diagnostics", "OK", "WARN", "ERROR"]


OK, WARN, ERROR = 0, 1, 2  # DiagnosticStatus levels (the message field is one octet)


@dataclass
class _Status:
    level: int = OK
    message: str = "ok"
    last_error: str = ""
    last_error_time: float = 0.0
    values: dict[str, str] = field(default_factory=dict)
    recent: collections.deque = field(default_factory=lambda: collections.deque(maxlen=5))
    warnings: int = 0
    errors: int = 0


class Diagnostics:
    """One node's DiagnosticStatus on /diagnostics (diagnostic_updater equivalent).

    The status is named by the node's fully qualified name without its leading slash
    (:attr:`name`): ``registration_node`` in the root namespace, ``drone1/registration_node``
    in /drone1, so that the same node in two namespaces is two rows on a health table, not one
    whose process id changes twice a second.

    Stages report with :meth:`set` (key/values), :meth:`stage_time` (a
    duration: the last one as ``<key>``, and the median and maximum of the
    last 200 as ``<key>_p50`` / ``<key>_max``, since one value jumps with the
    frame and the machine's load), :meth:`warn` / :meth:`error` (with a
    message that stays visible for ``hold_s`` seconds) and :meth:`ok`. Rates,
    latency, queue depth and drops come from the meters and worker attached
    with :meth:`attach`.
    """

    HISTORY = 200  # durations kept per stage_time key (and latencies)

    def __init__(
        self,
        node: Node,
        hardware_id: str = "subpix_ros",
        period_s: float = 1.0,
        hold_s: float = 5.0,
    ) -> None:
        self.node = node
        #: The status name: the node's fully qualified name without the leading slash.
        self.name = node.get_fully_qualified_name().lstrip("/")
        self.hardware_id = hardware_id
        self.hold_s = hold_s
        self._status = _Status()
        self._lock = threading.Lock()
        self.rates: dict[str, RateMeter] = {}
        self.worker: DropOldestWorker | None = None
        self._worker_items = "frame(s)"
        self._drops_seen = 0
        self._sources: list[Callable[[], dict[str, str]]] = []
        self._latencies: collections.deque[float] = collections.deque(maxlen=self.HISTORY)
        self._durations: dict[str, collections.deque[float]] = {}
        self._watch: tuple[tuple[str, ...], Callable[[], float], float] | None = None
        self._watch_meter = "input"
        self._watch_describe: Callable[[float, bool], str | None] | None = None
        self._episode: str | None = None  # the input problem being reported (logged when it began)
        self._lasting: dict[str, tuple[int, str]] = {}  # held until cleared (hold_lasting)
        self.pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        # Wall (steady) time, not the node's clock: with use_sim_time and no /clock (the replay
        # ended or never started) a node must still report, above all that nothing arrives.
        self.timer = steady_timer(node, period_s, self.publish)

    def rate(self, name: str) -> RateMeter:
        """Return the rate meter ``name`` (created on first use)."""
        return self.rates.setdefault(name, RateMeter())

    def watch_inputs(
        self,
        topics: Sequence[str],
        timeout_s: Callable[[], float],
        meter: str = "input",
        describe: Callable[[float, bool], str | None] | None = None,
    ) -> None:
        """Report a silent main input: WARN when nothing ticked ``meter`` for ``timeout_s()`` s.

        Parameters
        ----------
        topics : sequence of str
            One input (relative names are resolved with the node's remappings), e.g. a
            camera's ``image`` and ``image/compressed``.
        timeout_s : callable
            Returns the silence (s) after which the input is reported.
        meter : str
            The rate meter that the input ticks.
        describe : callable, optional
            ``describe(limit, heard)`` returns the problem to report for a silence of over
            ``limit`` s (``heard``: something arrived before), or None if the silence is not
            a problem now; for an input that is not a ROS topic (a MAVLink link). Keep the
            text the same while the silence lasts: a new text is a new episode (logged).
            Default: the ROS graph's view of ``topics``.

        Notes
        -----
        Checked at every publication (1 Hz, wall time): with no publisher on any of the
        topics for the timeout the status says ``no publisher on /x``; with publishers but
        nothing received it names them with their QoS (reliability, durability), as the ROS
        graph reports them. The status stays WARN while the silence lasts; the log has one
        line when it begins and one when messages arrive again. The silence is counted from
        this call until the first message.
        """
        self._watch = (tuple(topics), timeout_s, time.monotonic())
        self._watch_meter = meter
        self._watch_describe = describe

    def publishers(self, topic: str) -> list[str]:
        """Return the publishers of ``topic`` as ``/ns/node (reliability, durability)``, sorted."""
        out = []
        for info in self.node.get_publishers_info_by_topic(topic):
            qos = info.qos_profile
            name = f"{info.node_namespace.rstrip('/')}/{info.node_name}"
            out.append(f"{name} ({qos.reliability.name.lower()}, {qos.durability.name.lower()})")
        return sorted(out)

    def _input_problem(self, silent: float, limit: float, heard: bool) -> str:
        topics = self._watch[0]
        names = [self.node.resolve_topic_name(t) for t in topics]
        seen = {t: self.publishers(t) for t in names}
        if not any(seen.values()):
            return f"no publisher on {' or '.join(names)}"
        what = "; ".join(f"{t}: {len(p)} publisher(s) {', '.join(p)}" for t, p in seen.items() if p)
        word = "nothing received since the last message" if heard else "nothing received"
        return f"{word} on {' or '.join(names)} for over {limit:g} s (input_timeout_s) from {what}"

    def check_inputs(self, now: float | None = None) -> str | None:
        """Return the input problem now (and report it), or None; called at every publication."""
        if self._watch is None:
            return None
        _, timeout_s, since = self._watch
        now = time.monotonic() if now is None else now
        meter = self.rates.get(self._watch_meter)
        last = meter.last if meter is not None else None
        silent = now - (last if last is not None else since)
        limit = float(timeout_s())
        problem = None
        if silent >= limit:
            if self._watch_describe is not None:
                problem = self._watch_describe(limit, last is not None)
            else:
                problem = self._input_problem(silent, limit, last is not None)
            self.set(input_silent_s=round(silent, 1))
        else:
            self.set(input_silent_s=0.0)
        if problem is None:
            if self._episode is not None:
                self.node.get_logger().info(f"input arriving again after: {self._episode}")
            self._episode = None
            return None
        first = problem != self._episode
        self._episode = problem
        if first:
            self._report(WARN, problem, log=False)
            # once per episode, not throttled together with the node's other warnings
            self.node.get_logger().warning(problem)
        else:
            self._hold(WARN, problem)
        return problem

    def add_values(self, source: Callable[[], dict[str, str]]) -> None:
        """Publish the key/values ``source()`` returns, computed at each publication (1 Hz)."""
        self._sources.append(source)

    def attach(self, worker: DropOldestWorker, items: str = "frame(s)") -> None:
        """Report the queue depth, drops and errors of ``worker`` (its queue holds ``items``).

        Drops at its queue make the status WARN (:meth:`check_drops`): a node that sheds input
        because it cannot keep up does not say "ok".
        """
        self.worker = worker
        self._worker_items = items
        self._drops_seen = worker.dropped

    def check_drops(self) -> str | None:
        """Warn when the worker dropped input since the last check; return the warning or None.

        Called with each status (1 Hz). The text stays the same while it lasts (the count is
        ``dropped_frames``), so the log says it once per ``hold_s``-long episode.
        """
        w = self.worker
        if w is None or w.dropped <= self._drops_seen:
            return None
        self._drops_seen = w.dropped
        problem = (
            f"falling behind: {self._worker_items} dropped at the worker's queue "
            f"(queue_size {w.maxsize}): the work per input takes longer than the inputs come; "
            "dropped_frames counts them"
        )
        self.warn(problem)
        return problem

    def latency(self, seconds: float) -> None:
        """Record one end-to-end latency (s)."""
        self._latencies.append(seconds)

    def stage_time(self, key: str, ms: float) -> None:
        """Record a stage's duration in ms.

        Published as ``key`` (last), ``key_p50`` and ``key_max`` (of the last 200).
        """
        ms = float(ms)
        if not math.isfinite(ms) or ms < 0:
            raise ValueError(f"stage_time {key!r}: duration must be finite and >= 0, got {ms}")
        with self._lock:
            self._durations.setdefault(key, collections.deque(maxlen=self.HISTORY)).append(ms)
            self._status.values[key] = f"{ms:.6g}"

    def clear_stage_times(self) -> None:
        """Forget the durations behind ``_p50`` / ``_max`` (a new stream: a looped or another bag)."""
        with self._lock:
            self._durations.clear()

    def set(self, **values: Any) -> None:
        """Set key/values of the status (floats to 6 significant digits)."""
        with self._lock:
            for k, v in values.items():
                self._status.values[k] = f"{v:.6g}" if isinstance(v, float) else str(v)

    def ok(self, message: str = "ok") -> None:
        """Return to OK with ``message`` unless a problem was reported in the last ``hold_s``."""
        with self._lock:
            if time.monotonic() - self._status.last_error_time > self.hold_s:
                self._status.level = OK
                self._status.message = message

    def warn(self, message: str) -> None:
        """Report a warning (logged, throttled, held for ``hold_s``)."""
        self._report(WARN, message)

    def error(self, message: str, log: bool = True) -> None:
        """Report an error (logged, throttled, held for ``hold_s``; ``log=False``: logged already)."""
        self._report(ERROR, message, log=log)

    def hold_lasting(self, key: str, level: int, message: str) -> None:
        """Hold the status at ``level`` with ``message`` until :meth:`clear_lasting` ``(key)``.

        For a condition that lasts until someone acts (e.g. parameters rejected at start-up),
        not ``hold_s`` seconds; :meth:`ok` does not end it. Nothing is logged or counted here.
        """
        with self._lock:
            self._lasting[key] = (level, message)

    def clear_lasting(self, key: str) -> None:
        """End the lasting condition ``key`` (see :meth:`hold_lasting`), if held."""
        with self._lock:
            self._lasting.pop(key, None)

    def _effective(self) -> tuple[int, str]:
        """Return the level and message with the lasting conditions (caller holds the lock)."""
        level, message = int(self._status.level), self._status.message
        # the lasting condition's message at its level (a new problem: last_error, recent_problems)
        for lasting_level, lasting_message in self._lasting.values():
            if lasting_level >= level:
                level, message = lasting_level, lasting_message
        return level, message

    def hold_warning(self, message: str) -> None:
        """Keep the status at WARN for a lasting condition whose warning was logged and counted."""
        self._hold(WARN, message)

    def hold_error(self, message: str) -> None:
        """Keep the status at ERROR for a lasting condition whose error was logged and counted."""
        self._hold(ERROR, message)

    def _hold(self, level: int, message: str) -> None:
        """Keep reporting a condition already logged and counted (no new log line, no count)."""
        with self._lock:
            self._status.level = max(self._status.level, level)
            if self._status.level == level:
                self._status.message = message
            self._status.last_error_time = time.monotonic()

    def _report(self, level: int, message: str, log: bool = True) -> None:
        with self._lock:
            now = time.monotonic()
            held = now - self._status.last_error_time <= self.hold_s
            if level >= self._status.level or not held:
                self._status.level = level
                self._status.message = message
            self._status.last_error = message
            self._status.last_error_time = now
            if message not in self._status.recent:
                self._status.recent.append(message)
            if level == ERROR:
                self._status.errors += 1
            else:
                self._status.warnings += 1
        if not log:
            return
        log = self.node.get_logger()
        # rclpy keys throttling by call site, and one call site may not change severity
        if level == ERROR:
            log.error(message, throttle_duration_sec=2.0)
        else:
            log.warning(message, throttle_duration_sec=2.0)

    @property
    def level(self) -> int:
        """Current level (0 OK, 1 WARN, 2 ERROR), lasting conditions included."""
        with self._lock:
            return self._effective()[0]

    @property
    def message(self) -> str:
        """Current status message, lasting conditions included."""
        with self._lock:
            return self._effective()[1]

    def snapshot(self) -> DiagnosticStatus:
        """Build the DiagnosticStatus as of now (levels past ``hold_s`` fall back to OK)."""
        with self._lock:
            if (
                self._status.level != OK
                and time.monotonic() - self._status.last_error_time > self.hold_s
            ):
                self._status.level = OK
                self._status.message = "ok"
            values = dict(self._status.values)
            level, message = self._effective()
            st = DiagnosticStatus(
                level=bytes([level]),
                name=self.name,
                message=message,
                hardware_id=self.hardware_id,
            )
            values["last_error"] = self._status.last_error
            values["recent_problems"] = " | ".join(self._status.recent)
            values["errors_total"] = str(self._status.errors)
            values["warnings_total"] = str(self._status.warnings)
            for key, hist in self._durations.items():
                d = sorted(hist)
                values[f"{key}_p50"] = f"{d[len(d) // 2]:.6g}"
                values[f"{key}_max"] = f"{d[-1]:.6g}"
        for name, meter in self.rates.items():
            values[f"{name}_hz"] = f"{meter.rate():.3f}"
            values[f"{name}_total"] = str(meter.total)
        if self._latencies:
            lat = sorted(self._latencies)
            values["latency_p50_ms"] = f"{1000 * lat[len(lat) // 2]:.1f}"
            values["latency_max_ms"] = f"{1000 * lat[-1]:.1f}"
        for source in self._sources:
            values.update(source())
        if self.worker is not None:
            values["queue_depth"] = str(self.worker.depth)
            values["dropped_frames"] = str(self.worker.dropped)
            values["worker_errors"] = str(self.worker.errors)
            values["worker_cpu_ms_per_item"] = f"{self.worker.cpu_ms_per_item:.1f}"
        st.values = [KeyValue(key=k, value=v) for k, v in sorted(values.items())]
        return st

    def publish(self) -> None:
        """Check the inputs and publish the status on /diagnostics (the 1 Hz timer)."""
        try:
            self.check_inputs()
        except Exception as exc:  # noqa: BLE001 - the graph query fails during shutdown
            self.node.get_logger().debug(f"input check skipped: {exc}")
        self.check_drops()
        msg = DiagnosticArray()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.status = [self.snapshot()]
        self.pub.publish(msg)
