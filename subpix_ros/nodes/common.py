"""The small ROS glue shared by every subpix_ros node.

* :class:`Param` / :func:`declare_params`: parameters with descriptors and
  ranges; bad values at start-up or at run time are rejected with a message and
  the old value stays.
* :class:`Diagnostics`: the equivalent of diagnostic_updater (no wheel for it):
  one DiagnosticStatus per node on ``/diagnostics`` at 1 Hz with rates,
  latency, queue depth, drops and the last error.
* :class:`DropOldestWorker`: a bounded drop-oldest queue and a worker thread,
  so heavy work never runs in a subscription callback.
* :func:`camera_qos`, :func:`latched_qos`, :func:`qos_event_callbacks`.
* :func:`run_nodes`: the ``main`` of every console entry point.
"""

from __future__ import annotations

import collections
import math
import threading
import time
import traceback
from dataclasses import dataclass, field
from typing import Any, Callable, Iterable, Sequence

import rclpy
from diagnostic_msgs.msg import DiagnosticArray, DiagnosticStatus, KeyValue
from rcl_interfaces.msg import (
    FloatingPointRange,
    IntegerRange,
    ParameterDescriptor,
    SetParametersResult,
)
from rclpy.clock import Clock, ClockType
from rclpy.event_handler import PublisherEventCallbacks, SubscriptionEventCallbacks
from rclpy.exceptions import InvalidParameterTypeException, InvalidParameterValueException
from rclpy.executors import ExternalShutdownException, MultiThreadedExecutor
from rclpy.node import Node
from rclpy.parameter import Parameter
from rclpy.qos import (
    DurabilityPolicy,
    HistoryPolicy,
    QoSProfile,
    ReliabilityPolicy,
    qos_profile_sensor_data,
)

from ..runtime import (
    RuntimeSetupError,
    clean_stale_shm_segments,
    configure_ros_environment,
    keep_freed_memory,
)
from ..stages.params import Spec

__all__ = [
    "Param",
    "declare_params",
    "Diagnostics",
    "DropOldestWorker",
    "RateMeter",
    "camera_qos",
    "latched_qos",
    "reliable_qos",
    "qos_event_callbacks",
    "stamp_to_ns",
    "ns_to_stamp",
    "run_nodes",
]


# --------------------------------------------------------------------------- parameters
@dataclass
class Param(Spec):
    """One declared parameter: default, description and (for numbers) a range.

    The fields and :meth:`check` are :class:`subpix_ros.stages.params.Spec`'s (a stage's
    parameters are Specs; the node declares them as Params); this adds the ROS descriptor.
    """

    def descriptor(self) -> ParameterDescriptor:
        d = ParameterDescriptor(
            name=self.name, description=self.description, read_only=self.read_only
        )
        if self.min is not None and self.max is not None:
            if isinstance(self.default, bool):
                pass
            elif isinstance(self.default, int):
                d.integer_range = [
                    IntegerRange(from_value=int(self.min), to_value=int(self.max), step=0)
                ]
            elif isinstance(self.default, float):
                d.floating_point_range = [
                    FloatingPointRange(
                        from_value=float(self.min), to_value=float(self.max), step=0.0
                    )
                ]
        if self.choices:
            d.additional_constraints = "one of: " + ", ".join(self.choices)
        return d


def declare_params(
    node: Node, params: Iterable[Param], on_change: Callable[[str, Any], None] | None = None
) -> dict[str, Param]:
    """Declare ``params`` on ``node`` and guard them at run time.

    A value given at start-up (``--ros-args -p`` or ``--params-file``) that is
    of the wrong type or out of range is rejected with an error log and the
    default is kept. Changes at run time are validated by :meth:`Param.check`;
    a rejected change leaves the old value and returns the reason to the
    caller of set_parameters. ``on_change(name, value)`` runs after accepted
    run-time changes.
    """
    spec = {p.name: p for p in params}
    for p in spec.values():
        try:
            node.declare_parameter(p.name, p.default, p.descriptor())
            bad = p.check(node.get_parameter(p.name).value)
        except (InvalidParameterTypeException, InvalidParameterValueException) as exc:
            bad = str(exc).splitlines()[0]
            node.undeclare_parameter(p.name) if node.has_parameter(p.name) else None
        if bad:
            node.get_logger().error(
                f"parameter rejected at start-up, keeping default {p.default!r}: {bad}"
            )
            if node.has_parameter(p.name):
                node.undeclare_parameter(p.name)
            node.declare_parameter(p.name, p.default, p.descriptor(), ignore_override=True)

    def validate(changes: list[Parameter]) -> SetParametersResult:
        for change in changes:
            p = spec.get(change.name)
            if p is None:
                continue
            if p.read_only:
                return SetParametersResult(successful=False, reason=f"{p.name} is read-only")
            why = p.check(change.value)
            if why:
                node.get_logger().warning(f"parameter change rejected: {why}")
                return SetParametersResult(successful=False, reason=why)
        return SetParametersResult(successful=True)

    node.add_on_set_parameters_callback(validate)
    if on_change is not None:

        def after(changes: list[Parameter]) -> None:
            for change in changes:
                if change.name in spec:
                    on_change(change.name, change.value)

        node.add_post_set_parameters_callback(after)
    return spec


# --------------------------------------------------------------------------- QoS
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
    return QoSProfile(
        history=HistoryPolicy.KEEP_LAST,
        depth=depth,
        reliability=ReliabilityPolicy.RELIABLE,
        durability=DurabilityPolicy.VOLATILE,
    )


def latched_qos(depth: int = 1) -> QoSProfile:
    """Reliable + transient-local: a late joiner gets the latest message (a publisher's depth 1). A
    subscriber's ``depth`` > 1 keeps messages that arrive faster than it takes them."""
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


# --------------------------------------------------------------------------- time
def stamp_to_ns(stamp) -> int:
    return int(stamp.sec) * 1_000_000_000 + int(stamp.nanosec)


def ns_to_stamp(ns: int, cls):
    return cls(sec=int(ns // 1_000_000_000), nanosec=int(ns % 1_000_000_000))


# --------------------------------------------------------------------------- rates, queue, diagnostics
class RateMeter:
    """Events per second over a sliding window of ``window_s`` seconds."""

    def __init__(self, window_s: float = 5.0) -> None:
        self.window_s = window_s
        self._t: collections.deque[float] = collections.deque(maxlen=10_000)
        self.total = 0

        self.last: float | None = None  # time.monotonic() of the latest event

    def tick(self, now: float | None = None) -> None:
        self.last = time.monotonic() if now is None else now
        self._t.append(self.last)
        self.total += 1

    def rate(self, now: float | None = None) -> float:
        now = time.monotonic() if now is None else now
        while self._t and now - self._t[0] > self.window_s:
            self._t.popleft()
        return len(self._t) / self.window_s


class DropOldestWorker:
    """Bounded drop-oldest queue served by one worker thread.

    ``put`` never blocks: when the queue is full the oldest item is dropped
    and counted. Exceptions in ``handler`` are caught, counted and passed to
    ``on_error``; the worker keeps running.
    """

    def __init__(
        self,
        handler: Callable[[Any], None],
        maxsize: int = 4,
        name: str = "worker",
        on_error: Callable[[BaseException], None] | None = None,
    ) -> None:
        self._handler = handler
        self._on_error = on_error
        self._q: collections.deque = collections.deque()
        self._cv = threading.Condition()
        self.maxsize = max(1, int(maxsize))
        self.dropped = 0
        self.processed = 0
        self.errors = 0
        self.cpu_s = 0.0  # CPU time of the worker thread spent in the handler
        self.busy = False
        self._stop = False
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def put(self, item: Any) -> bool:
        """Queue ``item``; return False if an older item had to be dropped."""
        with self._cv:
            dropped = False
            while len(self._q) >= self.maxsize:
                self._q.popleft()
                self.dropped += 1
                dropped = True
            self._q.append(item)
            self._cv.notify()
        return not dropped

    def clear(self) -> None:
        with self._cv:
            self._q.clear()

    @property
    def depth(self) -> int:
        return len(self._q)

    def idle(self) -> bool:
        return not self._q and not self.busy

    def _run(self) -> None:
        while True:
            with self._cv:
                while not self._q and not self._stop:
                    self._cv.wait(0.5)
                if self._stop:
                    return
                item = self._q.popleft()
                self.busy = True
            t_cpu = time.thread_time()
            try:
                self._handler(item)
                self.processed += 1
            except Exception as exc:  # noqa: BLE001 - a worker must survive bad data
                self.errors += 1
                if self._on_error is not None:
                    self._on_error(exc)
                else:
                    traceback.print_exc()
            finally:
                self.cpu_s += time.thread_time() - t_cpu
                self.busy = False

    @property
    def cpu_ms_per_item(self) -> float:
        """Mean CPU time (this worker thread only) per item handled, ms."""
        n = self.processed + self.errors
        return 1000.0 * self.cpu_s / n if n else 0.0

    def stop(self, timeout: float = 2.0) -> None:
        with self._cv:
            self._stop = True
            self._cv.notify_all()
        self._thread.join(timeout)


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
        self.name = f"{node.get_name()}"
        self.hardware_id = hardware_id
        self.hold_s = hold_s
        self._status = _Status()
        self._lock = threading.Lock()
        self.rates: dict[str, RateMeter] = {}
        self.worker: DropOldestWorker | None = None
        self._latencies: collections.deque[float] = collections.deque(maxlen=self.HISTORY)
        self._durations: dict[str, collections.deque[float]] = {}
        self._watch: tuple[tuple[str, ...], Callable[[], float], float] | None = None
        self._watch_meter = "input"
        self._episode: str | None = None  # the input problem being reported (logged when it began)
        self.pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        # Wall (steady) time, not the node's clock: with use_sim_time and no /clock (the replay
        # ended or never started) a node must still report, above all that nothing arrives.
        steady = Clock(clock_type=ClockType.STEADY_TIME)
        self.timer = node.create_timer(period_s, self.publish, clock=steady)

    def rate(self, name: str) -> RateMeter:
        return self.rates.setdefault(name, RateMeter())

    def watch_inputs(
        self, topics: Sequence[str], timeout_s: Callable[[], float], meter: str = "input"
    ) -> None:
        """Report a silent main input: WARN when nothing ticked ``meter`` for ``timeout_s()`` s.

        ``topics`` (relative names are resolved with the node's remappings) are one input, e.g.
        a camera's ``image`` and ``image/compressed``. Checked at every publication (1 Hz, wall
        time): with no publisher on any of them for the timeout the status says
        ``no publisher on /x``; with publishers but nothing received it names them with their
        QoS (reliability, durability), as the ROS graph reports them. The status stays WARN
        while the silence lasts; the log has one line when it begins and one when messages
        arrive again.
        """
        self._watch = (tuple(topics), timeout_s, time.monotonic())
        self._watch_meter = meter

    def _publishers(self, topic: str) -> list[str]:
        out = []
        for info in self.node.get_publishers_info_by_topic(topic):
            qos = info.qos_profile
            name = f"{info.node_namespace.rstrip('/')}/{info.node_name}"
            out.append(f"{name} ({qos.reliability.name.lower()}, {qos.durability.name.lower()})")
        return sorted(out)

    def _input_problem(self, silent: float, limit: float, heard: bool) -> str:
        topics = self._watch[0]
        names = [self.node.resolve_topic_name(t) for t in topics]
        seen = {t: self._publishers(t) for t in names}
        if not any(seen.values()):
            return f"no publisher on {' or '.join(names)}"
        what = "; ".join(f"{t}: {len(p)} publisher(s) {', '.join(p)}" for t, p in seen.items() if p)
        word = "nothing received since the last message" if heard else "nothing received"
        return f"{word} on {' or '.join(names)} for over {limit:g} s (input_timeout_s) from {what}"

    def check_inputs(self, now: float | None = None) -> str | None:
        """The input problem now (and report it), or None; called at every publication."""
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

    def attach(self, worker: DropOldestWorker) -> None:
        self.worker = worker

    def latency(self, seconds: float) -> None:
        self._latencies.append(seconds)

    def stage_time(self, key: str, ms: float) -> None:
        """A stage's duration in ms: published as ``key`` (last), ``key_p50`` and ``key_max`` (last 200)."""
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
        with self._lock:
            for k, v in values.items():
                self._status.values[k] = f"{v:.6g}" if isinstance(v, float) else str(v)

    def ok(self, message: str = "ok") -> None:
        with self._lock:
            if time.monotonic() - self._status.last_error_time > self.hold_s:
                self._status.level = OK
                self._status.message = message

    def warn(self, message: str) -> None:
        self._report(WARN, message)

    def error(self, message: str) -> None:
        self._report(ERROR, message)

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
        return int(self._status.level)

    @property
    def message(self) -> str:
        return self._status.message

    def snapshot(self) -> DiagnosticStatus:
        with self._lock:
            if (
                self._status.level != OK
                and time.monotonic() - self._status.last_error_time > self.hold_s
            ):
                self._status.level = OK
                self._status.message = "ok"
            values = dict(self._status.values)
            st = DiagnosticStatus(
                level=bytes([self._status.level]),
                name=self.name,
                message=self._status.message,
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
        if self.worker is not None:
            values["queue_depth"] = str(self.worker.depth)
            values["dropped_frames"] = str(self.worker.dropped)
            values["worker_errors"] = str(self.worker.errors)
            values["worker_cpu_ms_per_item"] = f"{self.worker.cpu_ms_per_item:.1f}"
        st.values = [KeyValue(key=k, value=v) for k, v in sorted(values.items())]
        return st

    def publish(self) -> None:
        try:
            self.check_inputs()
        except Exception as exc:  # noqa: BLE001 - the graph query fails during shutdown
            self.node.get_logger().debug(f"input check skipped: {exc}")
        msg = DiagnosticArray()
        msg.header.stamp = self.node.get_clock().now().to_msg()
        msg.status = [self.snapshot()]
        self.pub.publish(msg)


# --------------------------------------------------------------------------- main
def run_nodes(
    factories: Sequence[Callable[[], Node]],
    args: Sequence[str] | None = None,
    threads: int | None = None,
) -> int:
    """Init rclpy, build the nodes, spin them on a MultiThreadedExecutor, shut down cleanly.

    Freed frame buffers stay in the process's heap for reuse
    (:func:`subpix_ros.runtime.keep_freed_memory`); the ROS / DDS defaults of
    :func:`subpix_ros.runtime.configure_ros_environment` are applied before the participant is
    created, or the process refuses to start with one line on stderr (exit status 2).
    """
    keep_freed_memory()
    clean_stale_shm_segments()  # segments of killed processes (64 MiB each with our profile)
    try:
        configure_ros_environment()
    except RuntimeSetupError as exc:
        import sys

        print(f"error: {exc}", file=sys.stderr)
        return 2
    rclpy.init(args=args)
    nodes: list[Node] = []
    executor = MultiThreadedExecutor(num_threads=threads)
    try:
        for make in factories:
            nodes.append(make())
            executor.add_node(nodes[-1])
        executor.spin()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        for n in nodes:
            close = getattr(n, "close", None)
            if close is not None:
                close()
            n.destroy_node()
        executor.shutdown()
        if rclpy.ok():
            rclpy.shutdown()
    return 0
