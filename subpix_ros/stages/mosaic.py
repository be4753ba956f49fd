"""MosaicStage: the live overview mosaic (METHODS.md C), the core :class:`Mosaic` with its gate."""

from __future__ import annotations

import threading

import numpy as np

from subpix_ros.core.mosaic import Mosaic
from subpix_ros.stages.base import Stage
from subpix_ros.stages.params import Spec
from subpix_ros.stages.stats import MosaicStats
from subpix_ros.stages.types import Frame

PARAMS = (
    Spec(
        "min_interval_s",
        0.0,
        "frames closer in time than this to the last frame taken for the mosaic "
        "are skipped (not counted as dropped)",
        0.0,
        60.0,
    ),
    Spec(
        "max_size_px",
        2048,
        "largest side of the preview canvas (px); the scale shrinks to fit",
        256,
        16384,
    ),
    Spec(
        "frame_max_px",
        1280,
        "frames are reduced to this larger side before registration and drawing "
        "(0: as received); the preview rarely needs more",
        0,
        16384,
    ),
    Spec(
        "n_points",
        150,
        "tie points per frame pair of the preview's registration (two thirds of them are "
        "enough to stop early); more is slower for the same seams",
        16,
        2000,
    ),
)


class MosaicStage(Stage):
    """Chain frames into a bounded preview canvas.

    :meth:`take` is the ``min_interval_s`` gate (by stamp; a frame too close to
    the last one taken is skipped, reason ``"min_interval"``), :meth:`draw`
    registers and draws a taken frame; ``add(frame) -> bool`` does both.
    :meth:`canvas` may be called from another thread.
    """

    PARAMS = PARAMS
    STATS = MosaicStats

    def __init__(self, **params) -> None:
        super().__init__(**params)
        self._lock = threading.Lock()
        self.mosaic = self._new_mosaic()
        self._last_taken_ns: int | None = None
        self.last_stamp_ns = 0  # the latest frame drawn

    def _new_mosaic(self) -> Mosaic:
        """Return an empty mosaic sized by the parameters."""
        fmax = self.param("frame_max_px")
        n = int(self.param("n_points"))
        return Mosaic(
            max_size_px=self.param("max_size_px"),
            frame_max_px=max(64, fmax) if fmax else None,
            register_kwargs={"n_points": n, "want_inliers": max(16, 2 * n // 3)},
        )

    def reset(self) -> None:
        """Start a new canvas."""
        super().reset()
        with self._lock:
            self.mosaic = self._new_mosaic()
        self._last_taken_ns = None
        self.stats.in_canvas = 0

    def take(self, frame: Frame) -> bool:
        """Gate a frame: True if it is at least ``min_interval_s`` after the last frame taken."""
        self.stats.frames_in += 1
        last = self._last_taken_ns
        if last is not None and 0 <= frame.stamp_ns - last < self.param("min_interval_s") * 1e9:
            self.stats.skip("min_interval")  # by design, not a drop
            return False
        # on what was taken: frames arriving meanwhile wait their turn
        self._last_taken_ns = frame.stamp_ns
        return True

    def draw(self, frame: Frame) -> bool:
        """Register ``frame`` to the previous one and draw it; False (a warning) if not added."""
        self.check_time(frame.stamp_ns)
        with self._lock:
            upd = self.mosaic.add(frame.image, stamp_s=frame.stamp_s)
        if not upd.ok:
            self.warn(f"frame not added to the mosaic: {upd.reason}")
            return False
        self.last_stamp_ns = frame.stamp_ns
        self.stats.kept += 1
        self.stats.in_canvas += 1
        seam = upd.seam_residual_px
        self.stats.seam_residual_px = float(seam) if seam is not None else None
        self.stats.times.add(1000 * float(upd.time_s))
        return True

    def add(self, frame: Frame) -> bool:
        """Gate, register and draw one frame: True if it was added to the mosaic."""
        return self.take(frame) and self.draw(frame)

    def canvas(self) -> np.ndarray | None:
        """Return the current mosaic (BGR), or None before the first frame."""
        with self._lock:
            img = self.mosaic.image()
        return None if img is None or img.size == 0 else img
