"""Base class of the subpix_ros processing nodes.

A :class:`StageNode` publishes its outputs to ROS topics and, in the
single-process ``pipeline``, also hands them to in-process listeners
(:meth:`listen` / :meth:`emit`), so stages inside one process exchange
objects, not DDS messages. ``subscribe_inputs=False`` makes a node skip its
input subscriptions because the pipeline feeds it directly.
"""
from __future__ import annotations

import time
from collections import defaultdict
from typing import Any, Callable, Sequence

from rclpy.node import Node

from subpix_ros.nodes.common import Diagnostics, DropOldestWorker, Param, declare_params, qos_event_callbacks


#: Declared by every stage with a main input (``MAIN_INPUTS``), after its own parameters.
INPUT_PARAMS: tuple[Param, ...] = (
    Param("input_timeout_s", 5.0, "main input (camera or aligned frames) silent this long, with "
          "or without a publisher: diagnostics WARN naming the topic and the publishers seen with "
          "their QoS", 0.5, 3600.0),
)


class StageNode(Node):
    PARAMS: Sequence[Param] = ()
    #: The topics of the node's main input (one input: any of them counts), watched for silence
    #: (Diagnostics.watch_inputs) when the node subscribes its inputs itself.
    MAIN_INPUTS: Sequence[str] = ()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if cls.MAIN_INPUTS:
            own = {p.name for p in cls.PARAMS}
            cls.PARAMS = tuple(cls.PARAMS) + tuple(p for p in INPUT_PARAMS if p.name not in own)

    def __init__(self, name: str, *, subscribe_inputs: bool = True, **kwargs: Any) -> None:
        super().__init__(name, **kwargs)
        self.subscribe_inputs = subscribe_inputs
        self.diag = Diagnostics(self)
        self.params = declare_params(self, self.PARAMS, self._on_param_change)
        if subscribe_inputs and self.MAIN_INPUTS:
            self.diag.watch_inputs(self.MAIN_INPUTS, lambda: self.p("input_timeout_s"))
        self._listeners: dict[str, list[Callable[[Any], None]]] = defaultdict(list)
        self._last_stamp_ns: int | None = None
        self.worker: DropOldestWorker | None = None

    # ---------------------------------------------------------------- parameters
    def p(self, name: str) -> Any:
        return self.get_parameter(name).value

    def _on_param_change(self, name: str, value: Any) -> None:
        self.get_logger().info(f"parameter {name} = {value!r}")

    # ---------------------------------------------------------------- in-process hand-off
    def listen(self, kind: str, callback: Callable[[Any], None]) -> None:
        self._listeners[kind].append(callback)

    def emit(self, kind: str, payload: Any) -> None:
        for cb in self._listeners[kind]:
            cb(payload)

    # ---------------------------------------------------------------- helpers
    def make_worker(self, handler: Callable[[Any], None], maxsize: int) -> DropOldestWorker:
        def on_error(exc: BaseException) -> None:
            self.diag.error(f"{type(exc).__name__}: {exc}")

        self.worker = DropOldestWorker(handler, maxsize=maxsize, name=f"{self.get_name()}_worker", on_error=on_error)
        self.diag.attach(self.worker)
        return self.worker

    def events(self, topic: str):
        return qos_event_callbacks(self, topic, self.diag)

    def check_time(self, stamp_ns: int) -> bool:
        """Detect a time jump backwards (looped bag); return True if state was reset."""
        last = self._last_stamp_ns
        self._last_stamp_ns = stamp_ns
        if last is not None and stamp_ns < last:
            self.diag.warn(f"time jumped back by {(last - stamp_ns) / 1e9:.3f} s: pipeline state reset")
            self.reset()
            self.diag.clear_stage_times()  # the new stream's stage times are not mixed with the old one's
            self.emit("reset", stamp_ns)
            return True
        return False

    def reset(self) -> None:
        """Forget per-stream state (overridden by stages that keep any)."""

    def latency_since(self, received: float) -> None:
        self.diag.latency(time.monotonic() - received)

    def close(self) -> None:
        if self.worker is not None:
            self.worker.stop()
