"""Base class of the subpix_ros processing nodes.

A :class:`StageNode` is a thin adapter around a ROS-free stage
(``subpix_ros.stages``): parameters, decoding, ``stage.add``, publishing and
/diagnostics from the stage's statistics. It publishes its outputs to ROS topics and, in the
single-process ``pipeline``, also hands them to in-process listeners
(:meth:`listen` / :meth:`emit`), so stages inside one process exchange
objects, not DDS messages. ``subscribe_inputs=False`` makes a node skip its
input subscriptions because the pipeline feeds it directly.
"""

from __future__ import annotations

import dataclasses
import inspect
import os
import time
import traceback
from collections import defaultdict
from typing import Any, Callable, Sequence

import cv2
from rcl_interfaces.msg import SetParametersResult
from rclpy.node import Node
from rclpy.parameter import Parameter

from subpix_ros.nodes.delivery import DeliveryDelay
from subpix_ros.nodes.diagnostics import ERROR, Diagnostics
from subpix_ros.nodes.params import Param, declare_params, explain_rejection, short_reason
from subpix_ros.nodes.qos import qos_event_callbacks
from subpix_ros.nodes.run import executor_kind
from subpix_ros.nodes.worker import DropOldestWorker
from subpix_ros.runtime import ProcessLoad, profile_in_use
from subpix_ros.stages.base import Stage
from subpix_ros.stages.params import Spec


def ros_params(specs: Sequence[Spec]) -> tuple[Param, ...]:
    """Turn a stage's parameter specs into node parameters (names, defaults, ranges, checks)."""
    return tuple(
        Param(**{f.name: getattr(s, f.name) for f in dataclasses.fields(Spec)}) for s in specs
    )


#: Declared by every stage with a main input (``MAIN_INPUTS``), after its own parameters.
INPUT_PARAMS: tuple[Param, ...] = (
    Param(
        "input_timeout_s",
        5.0,
        "main input (camera or aligned frames) silent this long, with "
        "or without a publisher: diagnostics WARN naming the topic and the publishers seen with "
        "their QoS",
        0.5,
        3600.0,
    ),
)


#: Declared by nodes that take camera frames (``CAMERA_INPUT``).
CAMERA_PARAMS: tuple[Param, ...] = (
    Param(
        "camera_delay_warn_ms",
        300.0,
        "a camera frame received this long after its stamp (this node's clock): diagnostics WARN "
        "(a camera publishing large frames from a process without the package's Fast DDS "
        "profile delivers them late, in bursts); camera_delay_ms_p50/_max show the delays",
        1.0,
        3.6e6,
    ),
)


#: Seconds a node's ``close()`` lets its worker handle what is still queued (StageNode.close).
CLOSE_DRAIN_S = 10.0


class StageNode(Node):
    """A node around one ROS-free stage: parameters, diagnostics, worker, in-process hand-off."""

    PARAMS: Sequence[Param] = ()
    #: What the worker's queue holds, as said when some is left at shutdown.
    queued_items = "frame(s)"
    #: The topics of the node's main input (one input: any of them counts), watched for silence
    #: (Diagnostics.watch_inputs) when the node subscribes its inputs itself.
    MAIN_INPUTS: Sequence[str] = ()
    #: True for nodes whose main input is the camera: frames' delivery delays are measured.
    CAMERA_INPUT = False

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        extra = (INPUT_PARAMS if cls.MAIN_INPUTS else ()) + (
            CAMERA_PARAMS if cls.CAMERA_INPUT else ()
        )
        own = {p.name for p in cls.PARAMS}
        cls.PARAMS = tuple(cls.PARAMS) + tuple(p for p in extra if p.name not in own)

    def __init__(self, name: str, *, subscribe_inputs: bool = True, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.subscribe_inputs = subscribe_inputs
        self.diag = Diagnostics(self)
        # a process setting (runtime.configure_opencv_threads), shown so an operator sees it
        self.diag.set(opencv_threads=cv2.getNumThreads())
        # and the Fast DDS profile (its shared-memory segment: 64 MiB or 1 MiB of RSS)
        self.diag.set(fastdds_profile=profile_in_use())
        # the process, so that a restart shows (the monitor says so when the pid changes)
        self.diag.set(pid=os.getpid(), started_unix_s=round(time.time(), 1))
        # the process's CPU (cores) and resident memory, for an onboard budget
        self.diag.add_values(ProcessLoad().values)
        try:  # the process's executor (nodes/run.py), shown beside it
            self.diag.set(executor=executor_kind())
        except ValueError:
            self.diag.set(executor="invalid SUBPIX_EXECUTOR")
        # parameters given at start-up and rejected: name -> "name value (what it accepts)"
        self.rejected_at_start: dict[str, str] = {}
        self.params = declare_params(
            self, self.PARAMS, self._on_param_change, self._rejected_at_start
        )
        self._show_rejected_at_start()
        if subscribe_inputs and self.MAIN_INPUTS:
            self.diag.watch_inputs(self.MAIN_INPUTS, lambda: self.param("input_timeout_s"))
        self._listeners: dict[str, list[Callable[[Any], None]]] = defaultdict(list)
        self._last_stamp_ns: int | None = None
        self._callback_errors: set[str] = set()  # logged with their traceback once each
        self.worker: DropOldestWorker | None = None
        self.stage: Stage | None = None
        self.delivery = DeliveryDelay()
        if self.CAMERA_INPUT:
            self.diag.add_values(self.delivery.values)  # sorted at 1 Hz, not per frame

    def make_stage(self, cls: type[Stage]) -> Stage:
        """Build the node's stage from its current parameters; its problems go to /diagnostics."""
        self.stage = cls.from_params({name: self.param(name) for name in self.params})
        self.stage.on_problem = self._stage_problem
        return self.stage

    def _stage_problem(self, level: str, message: str) -> None:
        (self.diag.error if level == "error" else self.diag.warn)(message)

    # ---------------------------------------------------------------- parameters
    def param(self, name: str) -> Any:
        """Return the current value of parameter ``name``."""
        return self.get_parameter(name).value

    def _on_param_change(self, name: str, value: Any) -> None:
        self.get_logger().info(f"parameter {name} = {value!r}")
        if self.stage is not None and (name in self.stage.params or name in self.stage.extra):
            self.stage.configure(**{name: value})  # already checked against the same range
        if name == "queue_size" and self.worker is not None:
            self.worker.resize(value)
        if self.rejected_at_start.pop(name, None) is not None:
            self._show_rejected_at_start()

    def _rejected_at_start(self, param: Param, value: Any, reason: str) -> None:
        """Count a start-up rejection (logged already) for /diagnostics."""
        self.rejected_at_start[param.name] = (
            f"{param.name} {value!r} ({short_reason(param, value, reason)})"
        )
        self.diag.error(
            f"parameter {param.name} = {value!r} rejected at start-up: {reason}", log=False
        )

    def _show_rejected_at_start(self) -> None:
        """Hold /diagnostics at ERROR while a parameter rejected at start-up has not been set."""
        if not self.rejected_at_start:
            self.diag.clear_lasting("parameters")
            return
        self.diag.hold_lasting(
            "parameters",
            ERROR,
            f"{len(self.rejected_at_start)} parameter(s) rejected at start-up, defaults used: "
            + ", ".join(self.rejected_at_start.values()),
        )

    def set_parameters(self, parameter_list: list[Parameter]) -> list[SetParametersResult]:
        """Set parameters (rclpy's), logging each refused change with its reason."""
        results = super().set_parameters(parameter_list)
        return [
            explain_rejection(self, getattr(self, "params", {}), [change], result)
            for change, result in zip(parameter_list, results)
        ]

    def set_parameters_atomically(self, parameter_list: list[Parameter]) -> SetParametersResult:
        """Set parameters together (rclpy's; the set_parameters service), logging a refusal."""
        result = super().set_parameters_atomically(parameter_list)
        return explain_rejection(self, getattr(self, "params", {}), parameter_list, result)

    # ---------------------------------------------------------------- in-process hand-off
    def listen(self, kind: str, callback: Callable[[Any], None]) -> None:
        """Call ``callback(payload)`` for each ``kind`` this node emits (in-process pipeline)."""
        self._listeners[kind].append(callback)

    def emit(self, kind: str, payload: Any) -> None:
        """Hand ``payload`` to the in-process listeners of ``kind``."""
        for cb in self._listeners[kind]:
            cb(payload)

    # ---------------------------------------------------------------- helpers
    def create_subscription(self, msg_type, topic, callback, *args, **kwargs):
        """Subscribe as :meth:`rclpy.node.Node.create_subscription`, the callback guarded.

        An exception escaping a callback (a bug, an input no check foresaw) would end the
        node's executor and the process, its /diagnostics falling silent. Here it is an ERROR
        in /diagnostics and one log line with the traceback per distinct error; the node keeps
        taking messages.
        """
        return super().create_subscription(
            msg_type, topic, self._guarded(callback, topic), *args, **kwargs
        )

    def _guarded(self, callback: Callable[..., None], topic: str) -> Callable[..., None]:
        """Return ``callback`` guarded, taking what it takes: (message) or (message, info)."""

        def call(*msg_and_info: Any) -> None:
            try:
                callback(*msg_and_info)
            except Exception as exc:  # noqa: BLE001 - keep the node alive, say it loudly
                text = f"{topic} callback failed: {type(exc).__name__}: {exc}"
                self.diag.error(text)
                if text not in self._callback_errors and len(self._callback_errors) < 100:
                    self._callback_errors.add(text)
                    self.get_logger().error(f"{text}\n{traceback.format_exc()}")

        def call_with_info(msg: Any, info: Any) -> None:  # rclpy passes the info by arity
            call(msg, info)

        try:
            inspect.signature(callback).bind(object(), object())
            return call_with_info
        except TypeError:
            return lambda msg: call(msg)

    def make_worker(self, handler: Callable[[Any], None], maxsize: int) -> DropOldestWorker:
        """Start the node's drop-oldest worker; its errors go to /diagnostics."""

        def on_error(exc: BaseException) -> None:
            self.diag.error(f"{type(exc).__name__}: {exc}")

        self.worker = DropOldestWorker(
            handler, maxsize=maxsize, name=f"{self.get_name()}_worker", on_error=on_error
        )
        self.diag.attach(self.worker, self.queued_items)
        return self.worker

    def events(self, topic: str):
        """Return QoS event callbacks for ``topic`` that report to /diagnostics."""
        return qos_event_callbacks(self, topic, self.diag)

    def output_events(self, topic: str):
        """Return the publisher event callbacks of output ``topic``.

        A subscriber whose QoS does not match the publisher's (it gets nothing) is an ERROR in
        /diagnostics naming the topic as remapped and what each side offers and requests.
        """
        return self.events(topic)[1]

    def check_time(self, stamp_ns: int) -> bool:
        """Reset the node when time jumps back (looped bag); return True if it did.

        The rule is the stage's (:meth:`Stage.check_time`: it warns and resets itself); the
        node then drops its queued work and held inputs. A node without a stage keeps the
        same rule itself.
        """
        if self.stage is not None:
            jumped = self.stage.check_time(stamp_ns)
        else:
            last, self._last_stamp_ns = self._last_stamp_ns, stamp_ns
            jumped = last is not None and stamp_ns < last
            if jumped:
                self.diag.warn(
                    f"time jumped back by {(last - stamp_ns) / 1e9:.3f} s: pipeline state reset"
                )
        if jumped:
            self.reset()
            self.diag.clear_stage_times()  # the new stream's stage times are not mixed with the old one's
            self.emit("reset", stamp_ns)
            return True
        return False

    def reset(self) -> None:
        """Forget per-stream state: the stage's and the queued work (extended by nodes that keep more)."""
        if self.stage is not None:
            self.stage.reset()
        if self.worker is not None:
            self.worker.clear()

    def output(
        self, kind: str, payload: Any, received: float, time_key: str, **values: Any
    ) -> None:
        """Report a published result.

        Called after publishing: in-process listeners of ``kind``, output rate, latency since
        ``received``, the stage's last time as ``time_key`` and ``values`` on /diagnostics.
        """
        self.emit(kind, payload)
        self.diag.rate("output").tick()
        self.latency_since(received)
        self.diag.stage_time(time_key, self.stage.stats.times.last)
        self.diag.set(**values)

    def camera_frame_received(self, stamp_ns: int) -> None:
        """Measure how late a camera frame arrived (its stamp against this node's clock).

        The delays go to /diagnostics (``camera_delay_ms_p50``, ``camera_delay_ms_max``); one
        over ``camera_delay_warn_ms`` is a warning that names the likely cause.
        """
        delay = self.delivery.add(stamp_ns, self.get_clock().now().nanoseconds)
        problem = self.delivery.problem(delay, self.param("camera_delay_warn_ms") / 1000.0)
        if problem:
            self.diag.warn(problem)

    def latency_since(self, received: float) -> None:
        """Record the latency since ``received`` (time.monotonic())."""
        self.diag.latency(time.monotonic() - received)

    def close(self) -> None:
        """Handle what the worker still has queued, then stop it (before the node is destroyed).

        The queued inputs are handled and their outputs published (the context is still up), so
        that a node stopped as the camera stops passes its last frames on: in ``pipeline`` the
        registration's last frames then reach the shift and reconstruction stages, whose
        ``close()`` comes after. What is left after :data:`CLOSE_DRAIN_S` is said.
        """
        if self.worker is not None:
            left = self.worker.stop(drain_s=CLOSE_DRAIN_S)
            if left:
                self.get_logger().warning(
                    f"{left} queued {self.queued_items} not processed: shutting down "
                    f"(still queued after {CLOSE_DRAIN_S:.0f} s)"
                )
