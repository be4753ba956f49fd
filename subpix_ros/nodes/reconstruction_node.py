"""reconstruction_node: super-resolution from sets of shifted, aligned frames.

Subscribes ``aligned/reference``, ``aligned`` + ``aligned/mask`` and
``shift`` (matched to the aligned frames by header stamp within
``time_tolerance_s``). A set is the reference frame plus the next
``n_frames - 1`` aligned frames of that reference that have a shift (or, if
the next reference starts first, the ``min_frames`` or more it has); when a
set completes the node publishes ``super_resolved`` (sensor_msgs/Image,
``factor`` x the input size; mono8 for mono input, bgr8 for colour input:
luminance is super-resolved and the chroma upsampled; header = the reference
frame's, since the image lies on its grid). Output pixel grid:
low-resolution pixel i of the reference covers output pixels
factor*i .. factor*i + factor - 1.
"""
from __future__ import annotations

import time

import numpy as np

from geometry_msgs.msg import Vector3Stamped
from sensor_msgs.msg import Image

from subpix_ros.core.superres_masks import reconstruct_aligned
from subpix_ros.nodes import payloads as pl
from subpix_ros.nodes.base import StageNode
from subpix_ros.nodes.aligned_input import AlignedInput
from subpix_ros.nodes.common import Param, latched_qos, reliable_qos, run_nodes


class ReconstructionNode(StageNode):
    MAIN_INPUTS = ("aligned",)
    PARAMS = (
        Param("factor", 2, "resolution factor", 2, 4),
        Param("n_frames", 8, "frames per super-resolved image (the reference included)", 2, 64),
        Param("min_frames", 4, "an incomplete set (frames dropped or without a shift) is still used if it has "
              "this many frames when the next reference starts", 2, 64),
        Param("method", "map", "reconstruction method", choices=("map", "windowed", "pinv", "bicubic")),
        Param("check_geometry", False, "re-check inside the reconstruction whether frames differ by more than a "
              "translation (the registration node already warps out rotation and perspective beyond its threshold)"),
        Param("refine_shifts", False, "re-estimate the shifts inside the reconstruction (off: the shift node's "
              "estimates, already at the accuracy limit and screened by its max_std_px, are used as they are)"),
        Param("time_tolerance_s", 0.001, "shift and frame stamps closer than this match", 0.0, 1.0),
        Param("queue_size", 2, "complete sets waiting for the worker; the oldest is dropped beyond this", 1, 20),
    )

    def __init__(self, *, subscribe_inputs: bool = True, name: str = "reconstruction_node", **kw) -> None:
        super().__init__(name, subscribe_inputs=subscribe_inputs, **kw)
        self.pub = self.create_publisher(Image, "super_resolved", latched_qos())
        self.make_worker(self._process, self.p("queue_size"))
        self._pending_frames: dict[int, pl.Aligned] = {}
        self._pending_shifts: list[pl.Shift] = []
        self.sets: dict[int, list[tuple[pl.Shift, pl.Aligned]]] = {}
        self.published = 0
        self.inputs = None
        if subscribe_inputs:
            self.inputs = AlignedInput(self, self._frame_ready, depth=20)
            self.create_subscription(Vector3Stamped, "shift", self._on_shift, reliable_qos(20), raw=True)

    # ---------------------------------------------------------------- DDS inputs
    def _frame_ready(self, a: pl.Aligned) -> None:
        self._pending_frames[a.stamp_ns] = a
        self._match()

    def _on_shift(self, raw: bytes) -> None:
        try:
            s = pl.shift_from_cdr(raw)
        except Exception as exc:  # noqa: BLE001
            self.diag.error(f"bad shift message: {exc}")
            return
        if not (np.isfinite(s.u) and np.isfinite(s.v)):
            self.diag.error("shift message with non-finite u/v ignored")
            return
        self._pending_shifts.append(s)
        self._match()

    def _match(self) -> None:
        tol = int(self.p("time_tolerance_s") * 1e9)
        still = []
        for s in self._pending_shifts:
            stamp = min(self._pending_frames, key=lambda t: abs(t - s.stamp_ns), default=None)
            if stamp is not None and abs(stamp - s.stamp_ns) <= tol:
                a = self._pending_frames.pop(stamp)
                s.reference_stamp_ns = a.reference.stamp_ns
                self.handle_shift((s, a))
            else:
                still.append(s)
        self._pending_shifts = still[-64:]
        if len(self._pending_frames) > 64:
            for t in sorted(self._pending_frames)[:-64]:
                del self._pending_frames[t]

    # ---------------------------------------------------------------- sets
    def handle_shift(self, item: tuple[pl.Shift, pl.Aligned]) -> None:
        """Add one (shift, aligned frame) to its reference's set; queue the set when complete."""
        s, a = item
        self.diag.rate("shifts_in").tick()
        self.check_time(s.stamp_ns)
        key = a.reference.stamp_ns
        members = self.sets.setdefault(key, [])
        members.append((s, a))
        for old in [k for k in self.sets if k < key]:
            # a newer reference started: the old set can no longer grow (frames were dropped or
            # had no shift); reconstruct it if it still has min_frames, else say why it is dropped
            partial = self.sets.pop(old)
            if len(partial) + 1 >= self.p("min_frames"):
                self.worker.put((partial[0][1].reference, partial))
            else:
                self.diag.warn(f"set of reference {old / 1e9:.3f} s dropped: {len(partial) + 1} frames "
                               f"< min_frames {self.p('min_frames')}")
        if len(members) + 1 >= self.p("n_frames"):
            del self.sets[key]
            self.worker.put((a.reference, members))

    def reset(self) -> None:
        self.sets.clear()
        if self.inputs is not None:
            self.inputs.clear()
        self._pending_frames.clear()
        self._pending_shifts.clear()
        if self.worker is not None:
            self.worker.clear()

    def _process(self, item) -> None:
        ref, members = item
        t0 = time.monotonic()
        frames = [ref.image] + [a.image for _, a in members]
        masks = [np.ones(ref.image.shape[:2], bool)] + [a.mask for _, a in members]
        shifts = np.array([[0.0, 0.0]] + [[s.u, s.v] for s, _ in members])
        if any(f.shape != ref.image.shape for f in frames):
            self.diag.error("frames of one set differ in size: set dropped")
            return
        res = reconstruct_aligned(frames, shifts, self.p("factor"), masks=masks, method=self.p("method"),
                                  geometry="auto" if self.p("check_geometry") else "translation",
                                  refine_shifts=self.p("refine_shifts"))
        img = res.image
        if not np.all(np.isfinite(img)):
            self.diag.error("reconstruction produced non-finite pixels: not published")
            return
        out = np.rint(img)  # to 8 bit in place: a 4K colour image is 25 M values
        np.clip(out, 0, 255, out=out)
        out = out.astype(np.uint8)
        # the image is on the reference frame's grid: it carries the reference's stamp
        self.pub.publish(pl.image_cdr(out, ref.stamp_ns, ref.frame_id))
        self.emit("super_resolved", (out, res, ref, members))
        self.published += 1
        self.diag.rate("output").tick()
        self.latency_since(ref.received)
        self.diag.stage_time("reconstruction_ms", 1000 * (time.monotonic() - t0))
        self.diag.set(method=res.method, fell_back=res.fell_back, fallback_reason=res.reason,
                      noise_sigma=float(res.noise_sigma), frames=len(frames),
                      images_published=self.published)
        if res.fell_back:
            self.diag.warn(f"super-resolution fell back to {res.method}: {res.reason}")
        else:
            self.diag.ok()


def main(args=None) -> int:
    return run_nodes([ReconstructionNode], args)


if __name__ == "__main__":
    raise SystemExit(main())
