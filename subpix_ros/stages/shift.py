"""ShiftStage: the sub-pixel shift of each aligned frame against its reference (METHODS A)."""

from __future__ import annotations

import time

import numpy as np

from subpix_ros.core.luminance import luminance
from subpix_ros.core.shift import estimate_shift
from subpix_ros.stages.base import Stage
from subpix_ros.stages.params import Spec
from subpix_ros.stages.stats import ShiftStats
from subpix_ros.stages.types import Aligned, Shift, Skipped

PARAMS = (
    Spec(
        "method",
        "default",
        "estimator: default (iterative, at the accuracy limit) or seed (the paper's single solve)",
        choices=("default", "seed"),
    ),
    Spec(
        "max_std_px", 0.1, "estimates with a larger standard error are not published", 0.0001, 10.0
    ),
    Spec(
        "use_prior",
        False,
        "start from the registration's predicted sub-pixel shift (single-process "
        "pipeline only; off by default so both layouts give identical shifts)",
    ),
)


def gray(image: np.ndarray) -> np.ndarray:
    """Luminance as float32: the estimator's working precision (float64 would be converted back)."""
    return luminance(image, order="bgr" if image.ndim == 3 else "mono", dtype=np.float32)


class ShiftStage(Stage):
    """The (u, v) of each aligned frame: content at (r, c) in the reference is at (r + u, c + v).

    ``add(aligned)`` returns a :class:`Shift`, or :class:`Skipped` with reason
    ``"size"`` (frame and reference differ in size), ``"failed"`` (no
    estimate), ``"misfit"`` (rotation/deformation left) or ``"std"``
    (standard error above ``max_std_px``).
    """

    PARAMS = PARAMS
    STATS = ShiftStats

    def __init__(self, **params) -> None:
        super().__init__(**params)
        self._ref_gray: tuple[int, np.ndarray] | None = None  # the reference's luminance, once

    def reset(self) -> None:
        """Forget the reference's luminance."""
        super().reset()
        self._ref_gray = None

    def _skip(self, aligned: Aligned, reason: str, detail: str) -> Skipped:
        """Count a skip and return it."""
        self.stats.skip(reason)
        return Skipped(aligned.stamp_ns, reason, detail)

    def add(self, aligned: Aligned) -> Shift | Skipped:
        """Estimate the shift of an aligned frame against its reference (see the class)."""
        self.stats.frames_in += 1
        self.check_time(aligned.stamp_ns)
        ref = aligned.reference
        if ref.image.shape[:2] != aligned.image.shape[:2]:
            why = (
                f"aligned frame {aligned.image.shape[:2]} and reference {ref.image.shape[:2]} "
                "differ in size"
            )
            self.error(why)
            return self._skip(aligned, "size", why)
        prior = aligned.prior if self.param("use_prior") else None
        t0 = time.monotonic()
        if self._ref_gray is None or self._ref_gray[0] != ref.stamp_ns:
            self._ref_gray = (ref.stamp_ns, gray(ref.image))
        result = estimate_shift(
            self._ref_gray[1],
            gray(aligned.image),
            mask=aligned.valid_mask(),
            method=self.param("method"),
            prior=prior,
        )
        if not result.ok:
            self.warn(f"shift not estimated: {result.reason}")
            return self._skip(aligned, "failed", result.reason)
        limit = self.param("max_std_px")
        if result.misfit or not (result.u_std <= limit and result.v_std <= limit):
            why = (
                "residual misfit (rotation/deformation left)"
                if result.misfit
                else f"standard error {max(result.u_std, result.v_std):.3g} px > {limit}"
            )
            self.warn(f"shift not published: {why}")
            return self._skip(aligned, "misfit" if result.misfit else "std", why)
        st = self.stats
        st.kept += 1
        st.times.add(1000 * (time.monotonic() - t0))
        st.u, st.v, st.u_std, st.v_std = result.u, result.v, result.u_std, result.v_std
        st.cond, st.pixels, st.iterations = float(result.cond), result.n_pixels, result.iterations
        return Shift(
            aligned.stamp_ns,
            ref.stamp_ns,
            result.u,
            result.v,
            result.z,
            result.u_std,
            result.v_std,
            aligned.frame_id,
            aligned.received,
        )

    @property
    def failed(self) -> int:
        """Aligned frames without a published shift."""
        return self.stats.skipped
