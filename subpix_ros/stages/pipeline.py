"""Pipeline: registration -> shift -> reconstruction, and the mosaic, chained by callbacks."""

from __future__ import annotations

from collections import defaultdict
from typing import Any, Callable, Mapping

from subpix_ros.core.telemetry import TelemetrySample
from subpix_ros.stages.mosaic import MosaicStage
from subpix_ros.stages.reconstruction import ReconstructionStage
from subpix_ros.stages.registration import RegistrationStage
from subpix_ros.stages.shift import ShiftStage
from subpix_ros.stages.stats import StageStats
from subpix_ros.stages.types import Aligned, Frame, NewReference, Shift, Skipped, SuperResolved

KINDS = ("aligned", "reference", "skipped", "shift", "super_resolved", "mosaic", "warning", "error")


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
    """

    def __init__(
        self, params: Mapping[str, Mapping[str, Any]] | None = None, with_mosaic: bool = True
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
        images = self._emit_images(
            self._guard(
                "reconstruction_node", lambda: self.reconstruction.tick(stamp_ns=frame.stamp_ns)
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
        return self._emit_images(
            self._guard("reconstruction_node", lambda: self.reconstruction.add(shift, aligned))
        )

    def _emit_images(self, images: list[SuperResolved] | None) -> list[SuperResolved]:
        """Emit the images a step completed and return them as a list."""
        for sr in images or []:
            self._emit("super_resolved", sr)
        return list(images or [])

    def flush(self) -> list[SuperResolved]:
        """End of stream: reconstruct the sets still open (``min_frames`` or more)."""
        return self._emit_images(self._guard("reconstruction_node", self.reconstruction.flush))

    def stats(self) -> dict[str, StageStats]:
        """Return each stage's statistics by its node's name."""
        return {name: stage.stats for name, stage in self.stages().items()}

    def reset(self) -> None:
        """Forget the stream in every stage (a new flight; done by itself when time jumps back)."""
        for stage in self.stages().values():
            stage.reset()
        self._last_stamp_ns = None
