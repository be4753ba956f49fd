"""Pipeline: registration -> shift -> reconstruction, and the mosaic, chained by callbacks."""

from __future__ import annotations

import threading
from collections import defaultdict, deque
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, Callable, Mapping

from subpix_ros.core.telemetry import TelemetrySample
from subpix_ros.stages.mosaic import MosaicStage
from subpix_ros.stages.reconstruction import FrameSet, ReconstructionStage
from subpix_ros.stages.registration import RegistrationStage
from subpix_ros.stages.shift import ShiftStage
from subpix_ros.stages.stats import StageStats
from subpix_ros.stages.types import Aligned, Frame, NewReference, Shift, Skipped, SuperResolved

KINDS = ("aligned", "reference", "skipped", "shift", "super_resolved", "mosaic", "warning", "error")


class _InCaller:
    """An executor that runs each job at once in the caller's thread (``solve_thread=False``)."""

    def submit(self, fn, *args) -> Future:
        """Run ``fn(*args)`` now; return its finished future."""
        fut: Future = Future()
        fut.set_result(fn(*args))
        return fut

    def shutdown(self, wait: bool = True, cancel_futures: bool = False) -> None:
        """Nothing to stop."""


class Pipeline:
    """The processing chain of the nodes, in the caller's thread, without ROS.

    ``params`` is keyed by node name as in ``config/*.yaml`` (``registration_node``,
    ``shift_node``, ``reconstruction_node``, ``mosaic_node``; missing: defaults).
    Callbacks, registered with :meth:`on`, receive:

    * ``aligned``: :class:`Aligned`; ``reference``: :class:`NewReference`;
    * ``skipped``: ``(stage name, Skipped)``; ``shift``: ``(Shift, Aligned)``;
    * ``super_resolved``: :class:`SuperResolved`;
    * ``mosaic``: the :class:`Frame` just drawn (the canvas: ``pipe.mosaic.canvas()``);
    * ``warning`` / ``error``: ``(stage name, message)``; an exception inside a stage is
      reported as an error and the frame is dropped, the pipeline goes on.

    A frame stamped earlier than the previous one (a looped bag) resets every
    stage. An incomplete set is reconstructed when a frame comes
    ``flush_after_s`` of stream time after its newest member, and at :meth:`flush`.

    With ``overlap=True`` a set's reconstruction runs on one worker thread while
    the caller goes on registering the next frames (the solver's FFTs and OpenCV
    release the GIL, so a second core is used). Its image, and the warnings and
    errors raised while making it, are emitted in the caller's thread when the
    next set is handed to the worker (waiting for it if need be), at
    :meth:`flush` and at :meth:`reset`: the same events in the same order as
    without overlap, one set later, whatever the timing. At most one set is being
    solved at a time. Call :meth:`close` (or use ``with``) to stop the worker.
    ``solve_thread=False`` (with ``overlap``) solves in the caller's thread but emits at the
    same points: the events of a machine without a core to spare are the same as with one.
    """

    def __init__(
        self,
        params: Mapping[str, Mapping[str, Any]] | None = None,
        with_mosaic: bool = True,
        overlap: bool = False,
        solve_thread: bool = True,
    ) -> None:
        params = params or {}
        self.registration = RegistrationStage.from_params(params.get("registration_node"))
        self.shift = ShiftStage.from_params(params.get("shift_node"))
        self.reconstruction = ReconstructionStage.from_params(params.get("reconstruction_node"))
        self.mosaic = MosaicStage.from_params(params.get("mosaic_node")) if with_mosaic else None
        self._callbacks: dict[str, list[Callable[[Any], None]]] = defaultdict(list)
        self._last_stamp_ns: int | None = None
        for name, stage in self.stages().items():
            stage.on_problem = self._reporter(name)
        self._pool: ThreadPoolExecutor | None = None
        self._pending: deque[Future] = deque()
        self._in_worker = threading.local()
        if overlap:
            self._pool = (
                ThreadPoolExecutor(1, thread_name_prefix="reconstruction")
                if solve_thread
                else _InCaller()
            )
            self.reconstruction.on_problem = self._worker_reporter(
                self._reporter("reconstruction_node")
            )

    def stages(self) -> dict:
        """Return the stages by their node's name (``registration_node``, ...), in order."""
        out = {
            "registration_node": self.registration,
            "shift_node": self.shift,
            "reconstruction_node": self.reconstruction,
        }
        if self.mosaic is not None:
            out["mosaic_node"] = self.mosaic
        return out

    def _reporter(self, name: str):
        """Return the ``on_problem`` callback of stage ``name``: its problems as events."""

        def report(level: str, message: str) -> None:
            self._emit("error" if level == "error" else "warning", (name, message))

        return report

    def _worker_reporter(self, report):
        """Problems raised on the worker are kept with the set's result, emitted with it."""

        def problem(level: str, message: str) -> None:
            kept = getattr(self._in_worker, "problems", None)
            if kept is None:
                report(level, message)
            else:
                kept.append((level, message))

        return problem

    def on(self, kind: str, callback: Callable[[Any], None]) -> "Pipeline":
        """Call ``callback(payload)`` on every event of ``kind`` (one of ``KINDS``); return self.

        Raises
        ------
        ValueError
            On an unknown kind.
        """
        if kind not in KINDS:
            raise ValueError(f"unknown kind {kind!r}: one of {', '.join(KINDS)}")
        self._callbacks[kind].append(callback)
        return self

    def _emit(self, kind: str, payload: Any) -> None:
        """Pass an event to the callbacks of its kind."""
        for cb in self._callbacks[kind]:
            cb(payload)

    def add_telemetry(self, sample: TelemetrySample) -> None:
        """Give the registration stage a telemetry sample (frame selection)."""
        self.registration.add_telemetry(sample)

    def _guard(self, name: str, call: Callable[[], Any]) -> Any:
        """Run a stage's step; an exception becomes that stage's error and None."""
        try:
            return call()
        except Exception as exc:  # noqa: BLE001 - one bad frame must not stop the stream
            self.stages()[name].error(f"{type(exc).__name__}: {exc}")
            return None

    def add(self, frame: Frame) -> list[SuperResolved]:
        """Run one camera frame through every stage; returns the images it completed."""
        if self._last_stamp_ns is not None and frame.stamp_ns < self._last_stamp_ns:
            self.reset()
        self._last_stamp_ns = frame.stamp_ns
        if self.mosaic is not None and self._guard("mosaic_node", lambda: self.mosaic.add(frame)):
            self._emit("mosaic", frame)
        images = self._solve(
            self._guard(
                "reconstruction_node",
                lambda: self.reconstruction.idle_sets(stamp_ns=frame.stamp_ns),
            )
        )
        outcome = self._guard("registration_node", lambda: self.registration.add(frame))
        if isinstance(outcome, Skipped):
            self._emit("skipped", ("registration_node", outcome))
        elif isinstance(outcome, NewReference):
            self._emit("reference", outcome)
        elif isinstance(outcome, Aligned):
            self._emit("aligned", outcome)
            images += self._after_aligned(outcome)
        return images

    def _after_aligned(self, aligned: Aligned) -> list[SuperResolved]:
        """Run an aligned frame through the shift and reconstruction stages."""
        shift = self._guard("shift_node", lambda: self.shift.add(aligned))
        if isinstance(shift, Skipped):
            self._emit("skipped", ("shift_node", shift))
        if not isinstance(shift, Shift):
            return []
        self._emit("shift", (shift, aligned))
        return self._solve(
            self._guard("reconstruction_node", lambda: self.reconstruction.assemble(shift, aligned))
        )

    def _solve(self, sets: list[FrameSet] | None) -> list[SuperResolved]:
        """Reconstruct closed sets (or hand them to the worker); emit the images now due."""
        if self._pool is None:
            images = [
                self._guard(
                    "reconstruction_node", lambda fs=fs: self.reconstruction.reconstruct(fs)
                )
                for fs in sets or []
            ]
            return self._emit_images(images)
        for fs in sets or []:
            self._pending.append(self._pool.submit(self._solve_on_worker, fs))
        return self._collect(keep=1)

    def _solve_on_worker(self, fs: FrameSet) -> tuple[SuperResolved | None, list, str | None]:
        """Reconstruct one set on the worker: (image or None, problems raised, failure)."""
        self._in_worker.problems = problems = []
        try:
            return self.reconstruction.reconstruct(fs), problems, None
        except Exception as exc:  # noqa: BLE001 - reported in the caller's thread, stream goes on
            return None, problems, f"{type(exc).__name__}: {exc}"
        finally:
            self._in_worker.problems = None

    def _collect(self, keep: int = 0) -> list[SuperResolved]:
        """Emit the worker's results, oldest first, until ``keep`` sets are left in flight."""
        images = []
        while len(self._pending) > keep:
            sr, problems, failure = self._pending.popleft().result()
            report = self._reporter("reconstruction_node")
            for level, message in problems:
                report(level, message)
            if failure is not None:
                self.reconstruction.error(failure)
            images.append(sr)
        return self._emit_images(images)

    def _emit_images(self, images: list[SuperResolved | None]) -> list[SuperResolved]:
        """Emit the images a step completed and return them as a list."""
        done = [sr for sr in images if sr is not None]
        for sr in done:
            self._emit("super_resolved", sr)
        return done

    def flush(self) -> list[SuperResolved]:
        """End of stream: reconstruct the sets still open (``min_frames`` or more)."""
        images = self._solve(self._guard("reconstruction_node", self.reconstruction.flush_sets))
        return images + self._collect()

    def close(self, emit: bool = True) -> None:
        """Stop the worker (``overlap=True``; else nothing to do).

        ``emit``: emit the images it still has first; False (an interruption) drops them and
        waits only for the set being solved.
        """
        if self._pool is None:
            return
        if emit:
            self._collect()
        else:
            self._pending.clear()
        self._pool.shutdown(wait=True, cancel_futures=True)
        self._pool = None

    def __enter__(self) -> "Pipeline":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def stats(self) -> dict[str, StageStats]:
        """Return each stage's statistics by its node's name."""
        return {name: stage.stats for name, stage in self.stages().items()}

    def reset(self) -> None:
        """Forget the stream in every stage (a new flight; done by itself when time jumps back).

        The sets already being reconstructed are finished and emitted first.
        """
        self._collect()
        for stage in self.stages().values():
            stage.reset()
        self._last_stamp_ns = None
