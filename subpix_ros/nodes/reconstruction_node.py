"""reconstruction_node: super-resolution from sets of shifted, aligned frames.

Subscribes ``aligned/reference``, ``aligned`` + ``aligned/mask`` and
``shift`` (matched to the aligned frames by header stamp within
``time_tolerance_s``). A set is the reference frame plus the next
``n_frames - 1`` aligned frames of that reference that have a shift; an
incomplete set of ``min_frames`` or more is used when the next reference
starts, when no new frame has come for ``flush_after_s`` (the end of a
flight) and at shutdown. For each set the node publishes ``super_resolved``
(sensor_msgs/Image, reliable and transient local; with ``latch_output`` false
volatile and only while subscribed; ``factor`` x the input size; mono8 for mono input
(mono16 for mono16), bgr8 for colour input: luminance is super-resolved and
the chroma upsampled; header = the reference frame's, since the image lies
on its grid). Output pixel grid: low-resolution pixel i of the reference
covers output pixels factor*i .. factor*i + factor - 1. The optics blur of
the model is ``blur_sigma``: a number (lab calibration) or ``auto``, measured
on straight edges in the frames (first set, then every 10th); the value used
and its source are in the diagnostics (``blur_sigma``, ``blur_source``, ``pixel_fill``,
``blur_reason``). With ``exposure_s`` > 0 the model also has the motion blur
of the exposure: the image velocity fitted to each set's shifts against their
stamps, times ``exposure_s`` (``motion_blur_px`` in the diagnostics: ``du,
dv`` input px, or ``none``). Set assembly, the blur calibration and the solve are
:class:`~subpix_ros.stages.ReconstructionStage`'s.
"""

from __future__ import annotations

import threading
import time

from geometry_msgs.msg import Vector3Stamped
from sensor_msgs.msg import Image

from subpix_ros.nodes import payloads as pl
from subpix_ros.nodes.aligned_input import AlignedInput
from subpix_ros.nodes.base import StageNode, ros_params
from subpix_ros.nodes.params import Param
from subpix_ros.nodes.qos import output_qos, reliable_qos
from subpix_ros.nodes.run import run_nodes
from subpix_ros.nodes.stamps import steady_timer
from subpix_ros.stages import ReconstructionStage
from subpix_ros.stages.reconstruction import FrameSet

IDLE_CHECK_S = 0.2  # how often the idle flush is checked (wall time)


class ReconstructionNode(StageNode):
    """The reconstruction stage as a node: aligned frames in, super-resolved images out."""

    MAIN_INPUTS = ("aligned",)
    queued_items = "set(s)"
    PARAMS = (
        *ros_params(ReconstructionStage.PARAMS),
        Param(
            "queue_size",
            2,
            "complete sets waiting for the worker; the oldest is dropped beyond this",
            1,
            20,
        ),
        Param(
            "latch_output",
            True,
            "super_resolved transient local: a late subscriber gets the latest image, which the "
            "DDS writer keeps (one image of memory, 100 MB at 4K); false: volatile, and "
            "super_resolved published only while something subscribes to it",
            read_only=True,
        ),
    )

    def __init__(
        self, *, subscribe_inputs: bool = True, name: str = "reconstruction_node", **kw
    ) -> None:
        super().__init__(name, subscribe_inputs=subscribe_inputs, **kw)
        self.make_stage(ReconstructionStage)
        self._lock = (
            threading.Lock()
        )  # set assembly: subscriptions, the idle timer, the pipeline's shift worker
        self.pub = self.create_publisher(
            Image,
            "super_resolved",
            output_qos(self.param("latch_output")),
            event_callbacks=self.output_events("super_resolved"),
        )
        self.sent = 0  # images published (latch_output false: only while subscribed)
        self.make_worker(self._process, self.param("queue_size"))
        # wall time: with use_sim_time the node's clock stops with /clock (a replay that ended),
        # and the last incomplete set must still be flushed
        self.idle_timer = steady_timer(self, IDLE_CHECK_S, self._on_idle_check)
        self.inputs = None
        self._shift_missing = False
        self._shift_checked = 0.0  # time.monotonic() of the last check for a shift publisher
        if subscribe_inputs:
            self.inputs = AlignedInput(self, self._frame_ready, depth=20)
            self.create_subscription(
                Vector3Stamped, "shift", self._on_shift, reliable_qos(20), raw=True
            )

    published = property(lambda self: self.stage.stats.kept)
    sets = property(lambda self: self.stage.sets)

    # ---------------------------------------------------------------- DDS inputs
    def _frame_ready(self, a: pl.Aligned) -> None:
        for pair in self.stage.match_aligned(a):
            self.handle_shift(pair)

    def _on_shift(self, raw: bytes) -> None:
        try:
            s = pl.shift_from_cdr(raw)
        except Exception as exc:  # noqa: BLE001
            self.diag.error(f"bad shift message: {exc}")
            return
        for pair in self.stage.match_shift(s):
            self.handle_shift(pair)

    # ---------------------------------------------------------------- sets
    def handle_shift(self, item: tuple[pl.Shift, pl.Aligned]) -> None:
        """Add one (shift, aligned frame) to its reference's set; queue the sets it closes."""
        self.diag.rate("shifts_in").tick()
        with self._lock:
            self.check_time(item[0].stamp_ns)
            self._queue(self.stage.assemble(*item))

    def _on_idle_check(self) -> None:
        with self._lock:
            self._queue(self.stage.idle_sets())
        self.diag.set(frames_without_shift=self.stage.stats.frames_without_shift)
        now = time.monotonic()
        if self.inputs is not None and now - self._shift_checked >= 1.0:  # a graph query: 1 Hz
            self._shift_checked = now
            self._check_shift_input()

    def _check_shift_input(self) -> None:
        """WARN while aligned frames arrive but nothing publishes the shifts to pair them with."""
        meter = self.diag.rates.get("input")
        recent = (
            meter is not None
            and meter.last is not None
            and (time.monotonic() - meter.last < self.param("input_timeout_s"))
        )
        topic = self.resolve_topic_name("shift")
        missing = recent and self.count_publishers(topic) == 0
        if missing:
            text = (
                f"no publisher on {topic}: aligned frames arrive but no shift comes to pair them "
                "with (is shift_node running?)"
            )
            if not self._shift_missing:
                self.get_logger().warning(text)
            self.diag.hold_warning(text)
        self._shift_missing = missing

    def _queue(self, sets: list[FrameSet]) -> None:
        for fs in sets:
            if not fs.complete:
                self.get_logger().info(
                    f"incomplete set of reference {fs.reference.stamp_ns / 1e9:.3f} s "
                    f"({fs.n_frames} frames, {fs.why}) reconstructed"
                )
            self.worker.put(fs)

    def reset(self) -> None:
        """Drop the stage's sets and the frames waiting to be assembled."""
        super().reset()
        if self.inputs is not None:
            self.inputs.clear()

    def _process(self, fs: FrameSet) -> None:
        sr = self.stage.reconstruct(fs)
        if sr is None:
            return
        ref = sr.reference  # the image is on the reference's grid: it carries the reference's stamp
        # always when latched (a late joiner finds the latest), else only for subscribers
        if self.param("latch_output") or self.pub.get_subscription_count():
            raw = pl.image_cdr(sr.image, ref.stamp_ns, ref.frame_id)
            pl.adopt_pixels(sr, raw)  # a large image: its pixels once while published, not twice
            self.pub.publish(raw)
            self.sent += 1
        st = self.stage.stats
        self.output(
            "super_resolved",
            sr,
            ref.received,
            "reconstruction_ms",
            method=sr.method,
            fell_back=sr.fell_back,
            fallback_reason=sr.reason,
            noise_sigma=sr.noise_sigma,
            frames=sr.n_frames,
            images_made=st.kept,
            images_published=self.sent,  # latch_output false: only while subscribed
            images_fell_back=st.fallbacks,
            sets_incomplete=st.sets_incomplete,
            sets_flushed=st.sets_flushed,
            sets_dropped=st.sets_dropped,
            sets_skipped_budget=st.sets_skipped_budget,  # max_cpu_cores
            set_cpu_time_s=round(st.set_cpu_time_s or 0.0, 3),
            frames_used=st.frames,
            memory_estimate_mb=st.memory_estimate_mb,
            memory_reduction=st.memory_reduction,
            memory_reduced=st.memory_reduced,
            workspace_mb=st.workspace_mb,
            shifts_disputed=st.shifts_disputed,
            blur_sigma="n/a" if sr.blur_sigma is None else sr.blur_sigma,
            blur_source=sr.blur_source or "n/a",
            blur_reason=getattr(sr.result, "blur_reason", "") or "n/a",
            pixel_fill=float(getattr(sr.result, "pixel_fill", 1.0)),
            motion_blur_px=(
                "none"
                if st.motion_blur_px is None
                else f"{st.motion_blur_px[0]:.3f}, {st.motion_blur_px[1]:.3f}"
            ),
        )
        if not sr.fell_back:
            self.diag.ok()

    def close(self) -> None:
        """Reconstruct and publish the open sets at shutdown.

        The open sets of ``min_frames`` or more are reconstructed and published first (when
        the ROS context is still up: after Ctrl-C nothing can be published any more).
        """
        with self._lock:
            sets = self.stage.flush_sets()
        if sets and not self.context.ok():
            self.get_logger().warning(f"{len(sets)} incomplete set(s) not published: shutting down")
            sets = []
        self._queue(sets)
        deadline = time.monotonic() + 30.0
        while self.worker is not None and not self.worker.idle() and time.monotonic() < deadline:
            time.sleep(0.05)
        super().close()


def main(args=None) -> int:
    """Run the reconstruction node (console entry point)."""
    return run_nodes([ReconstructionNode], args)


if __name__ == "__main__":
    raise SystemExit(main())
