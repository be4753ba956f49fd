"""shift_node: sub-pixel shift of each aligned frame against its reference.

Subscribes ``aligned`` + ``aligned/mask`` (matched by stamp) and
``aligned/reference`` (each aligned frame belongs to the latest reference not
later than it). Publishes ``shift`` (geometry_msgs/Vector3Stamped: x = u rows,
y = v columns, z = intensity offset, in the estimator's convention: content
at (r, c) in the reference appears at (r + u, c + v) in the aligned frame;
header = the aligned frame's). Quality figures (standard errors, condition,
pixels, iterations) go to /diagnostics; a failed estimate publishes nothing
and the reason goes to /diagnostics.
"""
from __future__ import annotations

import time

import numpy as np

from geometry_msgs.msg import Vector3Stamped

from subpix_ros.core.luminance import luminance
from subpix_ros.core.shift import estimate_shift
from subpix_ros.nodes import payloads as pl
from subpix_ros.nodes.base import StageNode
from subpix_ros.nodes.aligned_input import AlignedInput
from subpix_ros.nodes.common import Param, reliable_qos, run_nodes


def gray(image: np.ndarray) -> np.ndarray:
    # float32: the estimator's working precision (a float64 frame would only be converted back)
    return luminance(image, order="bgr" if image.ndim == 3 else "mono", dtype=np.float32)


class ShiftNode(StageNode):
    MAIN_INPUTS = ("aligned",)
    PARAMS = (
        Param("queue_size", 4, "aligned frames waiting for the worker; the oldest is dropped beyond this", 1, 100),
        Param("method", "default", "estimator: default (iterative, at the accuracy limit) or seed (the paper's single solve)",
              choices=("default", "seed")),
        Param("max_std_px", 0.1, "estimates with a larger standard error are not published", 0.0001, 10.0),
        Param("use_prior", False, "start from the registration's predicted sub-pixel shift (single-process pipeline "
              "only; off by default so both layouts give identical shifts)"),
    )

    def __init__(self, *, subscribe_inputs: bool = True, name: str = "shift_node", **kw) -> None:
        super().__init__(name, subscribe_inputs=subscribe_inputs, **kw)
        self.pub = self.create_publisher(Vector3Stamped, "shift", reliable_qos(20))
        self.make_worker(self._process, self.p("queue_size"))
        self.published = 0
        self._ref_gray: tuple[int, np.ndarray] | None = None  # the reference's luminance, computed once
        self.failed = 0
        self.inputs = AlignedInput(self, self.handle_aligned) if subscribe_inputs else None

    # ---------------------------------------------------------------- work
    def handle_aligned(self, aligned: pl.Aligned) -> None:
        self.worker.put(aligned)

    def reset(self) -> None:
        self._ref_gray = None
        if self.inputs is not None:
            self.inputs.clear()
        if self.worker is not None:
            self.worker.clear()

    def _process(self, a: pl.Aligned) -> None:
        self.check_time(a.stamp_ns)
        ref = a.reference
        if ref.image.shape[:2] != a.image.shape[:2]:
            self.failed += 1
            self.diag.error(f"aligned frame {a.image.shape[:2]} and reference {ref.image.shape[:2]} differ in size")
            return
        prior = a.prior if self.p("use_prior") else None
        t0 = time.monotonic()
        if self._ref_gray is None or self._ref_gray[0] != ref.stamp_ns:
            self._ref_gray = (ref.stamp_ns, gray(ref.image))
        r = estimate_shift(self._ref_gray[1], gray(a.image), mask=a.mask, method=self.p("method"), prior=prior)
        if not r.ok:
            self.failed += 1
            self.diag.warn(f"shift not estimated: {r.reason}")
            self.diag.set(shift_failures=self.failed)
            return
        if r.misfit or not (r.u_std <= self.p("max_std_px") and r.v_std <= self.p("max_std_px")):
            self.failed += 1
            why = "residual misfit (rotation/deformation left)" if r.misfit else \
                f"standard error {max(r.u_std, r.v_std):.3g} px > {self.p('max_std_px')}"
            self.diag.warn(f"shift not published: {why}")
            self.diag.set(shift_failures=self.failed)
            return
        s = pl.Shift(a.stamp_ns, ref.stamp_ns, r.u, r.v, r.z, r.u_std, r.v_std, a.frame_id, a.received)
        self.pub.publish(pl.shift_cdr(s))
        self.emit("shift", (s, a))
        self.published += 1
        self.diag.rate("output").tick()
        self.latency_since(a.received)
        self.diag.stage_time("estimate_ms", 1000 * (time.monotonic() - t0))
        self.diag.set(u=r.u, v=r.v, u_std=r.u_std, v_std=r.v_std, cond=float(r.cond), pixels=r.n_pixels,
                      iterations=r.iterations, shifts_published=self.published)
        self.diag.ok()


def main(args=None) -> int:
    return run_nodes([ShiftNode], args)


if __name__ == "__main__":
    raise SystemExit(main())
