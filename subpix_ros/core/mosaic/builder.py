"""The live mosaic: register each frame to its predecessor, place it and draw it on a canvas."""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from subpix_ros.core.mosaic.geometry import (
    FrameGeometry,
    PairModel,
    _border,
    _local_scale,
)
from subpix_ros.core.motion import MotionTracker
from subpix_ros.core.registration import (
    RegistrationResult,
    apply_h,
    prepare_reference,
    register,
)

__all__ = ["Mosaic", "MosaicUpdate"]


@dataclass
class MosaicUpdate:
    """Outcome of :meth:`Mosaic.add`.

    Parameters
    ----------
    ok : bool
        Whether the frame was added.
    reason : str
        Why not ('' when ok).
    index : int
        Index of the frame in the order it was added.
    seam_residual_px : float or None
        RMS tie-point disagreement across the seam, new-frame px.
    inliers : int
        Registration inliers to the previous frame.
    rms_px : float or None
        Registration residual (full model) to the previous frame, px.
    time_s : float
        Wall time of this add (registration and drawing), s.
    scale : float
        Canvas px per first-frame px after this add.
    canvas_shape : tuple of int
        Canvas shape (rows, columns) after this add.
    registration : RegistrationResult or None
        The registration to the previous frame.
    overlap_residual_px : float or None
        Tie points through both frames' drawing maps, new-frame px.
    """

    ok: bool
    reason: str
    index: int
    seam_residual_px: float | None
    inliers: int
    rms_px: float | None
    time_s: float
    scale: float
    canvas_shape: tuple[int, int]
    registration: RegistrationResult | None = None
    overlap_residual_px: float | None = None


class Mosaic:
    """Live overview mosaic with bounded memory (METHODS.md C; see :mod:`subpix_ros.core.mosaic`).

    Each frame's registration-side work (luminance, pyramid, tie-point
    candidates, coarse features: :func:`prepare_reference`) is done once: it
    serves as the moving frame of its own pair and as the reference of the
    next.

    Parameters
    ----------
    max_size_px : int
        Maximum canvas side, px (at least 64).
    scale : float or None
        Initial canvas px per frame px (default: the first frame fills a
        quarter of the canvas side).
    blend_px : int
        Width of the seam blend, canvas px.
    gsd_m : float or None
        Ground sampling distance of the first frame (m/px), to report the
        canvas' metres per pixel.
    register_kwargs : dict or None
        Keyword arguments of :func:`register`.
    frame_max_px : int or None
        Frames whose larger side exceeds it are first reduced
        (``cv2.INTER_AREA``) to that size, and every geometry
        (``transforms``, ``geometries``, residuals) then refers to the reduced
        frame's pixels; a preview canvas rarely needs more, and registration
        cost falls with the square of the size. None: frames are used as given.

    Attributes
    ----------
    transforms : list of ndarray or None
        Per added frame: its placement ``P_k`` (frame px -> mosaic px, a
        similarity; None if rejected).
    geometries : list of FrameGeometry or None
        Per added frame: its full drawing geometry ``D_k`` (None if rejected).
    updates : list of MosaicUpdate
        Per added frame: the outcome of :meth:`add`.
    """

    def __init__(
        self,
        max_size_px: int = 2048,
        scale: float | None = None,
        blend_px: int = 24,
        gsd_m: float | None = None,
        register_kwargs: dict | None = None,
        frame_max_px: int | None = None,
    ) -> None:
        if max_size_px < 64:
            raise ValueError("max_size_px must be at least 64")
        if frame_max_px is not None and frame_max_px < 64:
            raise ValueError("frame_max_px must be at least 64 (or None)")
        self.frame_max_px = frame_max_px
        self.max_size_px = int(max_size_px)
        self._scale0 = scale
        self.blend_px = int(blend_px)
        self.gsd_m = gsd_m
        self.register_kwargs = dict(register_kwargs or {})
        self._canvas: np.ndarray | None = None
        self._s = np.eye(3)  # S: mosaic (first-frame px) -> canvas px
        self._prev: np.ndarray | None = None  # previous accepted frame (reduced to frame_max_px)
        self._prev_prepared = None  # its registration-side work (ReferenceFrame)
        self._prev_geo: FrameGeometry | None = None  # its geometry
        self._prev_index = -1  # its index in ``geometries``
        self._prev_prev_shape: tuple[int, int] | None = None  # shape of the frame before it
        self.transforms: list[np.ndarray | None] = []
        self.geometries: list[FrameGeometry | None] = []
        self.updates: list[MosaicUpdate] = []
        self._motion = MotionTracker()  # predicts the next pair from the last (stamped frames)

    @property
    def scale(self) -> float:
        """Canvas px per first-frame px."""
        return float(self._s[0, 0])

    @property
    def metres_per_px(self) -> float | None:
        """Canvas metres per pixel, if ``gsd_m`` was given."""
        return None if self.gsd_m is None else self.gsd_m / self.scale

    def image(self) -> np.ndarray:
        """Return the preview canvas (uint8 BGR copy); empty (0x0x3) before the first frame."""
        if self._canvas is None:
            return np.zeros((0, 0, 3), np.uint8)
        return self._canvas.copy()

    # -- canvas management -------------------------------------------------
    def _fit_canvas(self, corners_m: np.ndarray) -> None:
        """Grow (pad) or rescale the canvas so the mosaic-frame polygon ``corners_m`` fits."""
        q = apply_h(self._s, corners_m)
        h, w = self._canvas.shape[:2]
        x0, y0 = np.floor(q.min(axis=0)) - 2
        x1, y1 = np.ceil(q.max(axis=0)) + 2
        nx0, ny0 = min(0.0, x0), min(0.0, y0)
        nx1, ny1 = max(float(w), x1), max(float(h), y1)
        need_w, need_h = nx1 - nx0, ny1 - ny0
        f = min(1.0, self.max_size_px / need_w, self.max_size_px / need_h)
        if nx0 == 0 and ny0 == 0 and nx1 == w and ny1 == h:
            return
        # new canvas: translate by (-nx0, -ny0) then scale by f
        shift = np.array([[f, 0, -f * nx0], [0, f, -f * ny0], [0, 0, 1.0]])
        nw = int(min(self.max_size_px, np.ceil(need_w * f)))
        nh = int(min(self.max_size_px, np.ceil(need_h * f)))
        self._canvas = cv2.warpAffine(
            self._canvas, shift[:2], (nw, nh), flags=cv2.INTER_AREA if f < 1 else cv2.INTER_NEAREST
        )
        self._s = shift @ self._s

    def _canvas_to_frame(
        self, geo: FrameGeometry, xc: np.ndarray, yc: np.ndarray, iterations: int = 5
    ) -> tuple[np.ndarray, np.ndarray]:
        """Invert ``C = S D_k`` at canvas points (arrays of any shape): frame px (x, y).

        Fixed-point iteration ``x <- x - L^-1 (C(x) - y)`` from ``x0 = (S P_k)^-1 y``,
        ``L`` the linear part of the similarity ``S P_k``; ``D_k`` departs from
        ``P_k`` only by ``h (H_k - A_k)``, so a few steps converge.
        """
        y = np.stack([xc.ravel(), yc.ravel()], axis=1).astype(np.float64)
        sp = self._s @ geo.placement
        x = apply_h(np.linalg.inv(sp), y)
        linv = np.linalg.inv(sp[:2, :2])
        for _ in range(iterations):
            x = x - (apply_h(self._s, geo.to_mosaic(x)) - y) @ linv.T
        return x[:, 0].reshape(xc.shape), x[:, 1].reshape(xc.shape)

    def _remap_grid(
        self, geo: FrameGeometry, roi: tuple[int, int, int, int], shrink: int
    ) -> tuple[np.ndarray, np.ndarray]:
        """Return the canvas -> frame maps over ``roi = (x0, y0, x1, y1)``, in shrunk-frame px.

        The map is computed on a grid every 8 px (one cell beyond the ROI on
        each side), so that ``cv2.resize`` (pixel-centre aligned) interpolates
        it bilinearly onto every ROI pixel.
        """
        x0, y0, x1, y1 = roi
        g = 8
        nx, ny = -(-(x1 - x0) // g) + 2, -(-(y1 - y0) // g) + 2
        gx = x0 + (np.arange(nx) - 1) * g + (g - 1) / 2.0
        gy = y0 + (np.arange(ny) - 1) * g + (g - 1) / 2.0
        fx, fy = self._canvas_to_frame(geo, *np.meshgrid(gx, gy))
        # small px i covers frame px k i .. k i + k - 1: centre k i + (k - 1) / 2
        k = shrink
        fx, fy = (fx - (k - 1) / 2.0) / k, (fy - (k - 1) / 2.0) / k
        mx = cv2.resize(fx.astype(np.float32), (nx * g, ny * g), interpolation=cv2.INTER_LINEAR)[
            g : g + y1 - y0, g : g + x1 - x0
        ]
        my = cv2.resize(fy.astype(np.float32), (nx * g, ny * g), interpolation=cv2.INTER_LINEAR)[
            g : g + y1 - y0, g : g + x1 - x0
        ]
        return mx, my

    def _draw(self, frame: np.ndarray, geo: FrameGeometry) -> None:
        """Resample ``frame`` through ``S D_k`` onto the canvas, on top, with a linear seam ramp."""
        hf, wf = frame.shape[:2]
        q = apply_h(self._s, geo.to_mosaic(_border((hf, wf))))
        hc, wc = self._canvas.shape[:2]
        x0, y0 = np.maximum(np.floor(q.min(axis=0)).astype(int), 0)
        x1, y1 = np.minimum(np.ceil(q.max(axis=0)).astype(int) + 1, [wc, hc])
        if x1 <= x0 or y1 <= y0:
            return
        # Pre-shrink the frame so the resampling does not alias (scale of S P_k).
        sp = self._s @ geo.placement
        sc = float(np.sqrt(abs(np.linalg.det(sp[:2, :2]))))
        img, k = frame, 1
        if sc < 0.5:
            k = max(1, int(1 / sc / 1.5))
            img = cv2.resize(
                frame, (max(1, wf // k), max(1, hf // k)), interpolation=cv2.INTER_AREA
            )
        mx, my = self._remap_grid(geo, (x0, y0, x1, y1), k)
        warped = cv2.remap(img, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        hs, ws = img.shape[:2]
        valid = (mx >= 0) & (mx <= ws - 1) & (my >= 0) & (my <= hs - 1)
        dist = cv2.distanceTransform(valid.astype(np.uint8), cv2.DIST_L2, 3)
        alpha = np.clip(dist / max(self.blend_px, 1), 0.0, 1.0)[:, :, None]
        dst = self._canvas[y0:y1, x0:x1]
        empty = (dst.max(axis=2) == 0)[:, :, None] & valid[:, :, None]
        alpha = np.where(empty, 1.0, alpha)
        self._canvas[y0:y1, x0:x1] = np.clip(
            dst * (1 - alpha) + warped * alpha + 0.5, 0, 255
        ).astype(np.uint8)

    def to_canvas(self, index: int, pts: np.ndarray) -> np.ndarray:
        """Map frame ``index``'s pixels (N, 2) (x, y) to current canvas pixels (``S D_k``).

        Raises
        ------
        ValueError
            If that frame was rejected.
        """
        geo = self.geometries[index]
        if geo is None:
            raise ValueError(f"frame {index} was rejected: {self.updates[index].reason}")
        return apply_h(self._s, geo.to_mosaic(pts))

    # -- adding a frame --------------------------------------------------------
    def add(self, frame: np.ndarray, stamp_s: float | None = None) -> MosaicUpdate:
        """Register a frame to the previous one and draw it.

        Parameters
        ----------
        frame : ndarray of uint8
            HxW mono or HxWx3 BGR image, at least 32x32.
        stamp_s : float, optional
            The frame's time (s). With stamps, the motion between the last two frames
            predicts where this one lies (constant velocity, :class:`~subpix_ros.core.motion.
            MotionTracker`) and the registration tracks its tie points from there (a
            search of ``track_radius`` px instead of a coarse match over the whole frame);
            it falls back to the full search when tracking fails. Without a stamp every
            frame is searched in full.

        Returns
        -------
        MosaicUpdate
            Whether the frame was added, why not, and its residuals.

        Raises
        ------
        ValueError
            On a frame that is not uint8, or of the wrong shape.
        """
        t0 = time.perf_counter()
        img = self._as_bgr(frame)
        kw = {
            k: self.register_kwargs[k]
            for k in ("coarse_size", "detect_size")
            if k in self.register_kwargs
        }
        prepared = prepare_reference(img, **kw)
        idx = len(self.transforms)
        if self._prev is None:
            self._start(img, prepared)
            if stamp_s is not None:
                self._motion.restart(float(stamp_s))
            return self._record(MosaicUpdate(True, "", idx, 0.0, 0, None, *self._status(t0)))
        prior = None if stamp_s is None else self._motion.predict(float(stamp_s))
        reg = register(self._prev_prepared, prepared, prior=prior, **self.register_kwargs)
        if not reg.ok:
            self._motion.forget()
            self.transforms.append(None)
            self.geometries.append(None)
            return self._record(
                MosaicUpdate(False, reg.reason, idx, None, 0, None, *self._status(t0), reg)
            )
        seam, over = self._chain(img, reg, prepared)
        if stamp_s is not None:  # this frame is the next one's "reference": the chain restarts
            self._motion.update(reg.homography, float(stamp_s))
            self._motion.restart(float(stamp_s))
        else:
            self._motion = MotionTracker()
        return self._record(
            MosaicUpdate(True, "", idx, seam, reg.inliers, reg.rms_px, *self._status(t0), reg, over)
        )

    def _as_bgr(self, frame: np.ndarray) -> np.ndarray:
        """Check a frame and return it as BGR uint8, reduced to ``frame_max_px`` when set."""
        img = np.asarray(frame)
        if img.dtype != np.uint8:
            raise ValueError(f"frame must be uint8, got {img.dtype}")
        if img.ndim == 3 and img.shape[2] == 1:
            img = img[:, :, 0]
        if not (img.ndim == 2 or (img.ndim == 3 and img.shape[2] == 3)) or min(img.shape[:2]) < 32:
            raise ValueError(
                f"frame: expected HxW or HxWx3 (BGR) of at least 32x32, got shape {img.shape}"
            )
        if img.ndim == 2:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        if self.frame_max_px is not None and max(img.shape[:2]) > self.frame_max_px:
            f = self.frame_max_px / max(img.shape[:2])
            size = (max(32, round(img.shape[1] * f)), max(32, round(img.shape[0] * f)))
            img = cv2.resize(img, size, interpolation=cv2.INTER_AREA)
        return img

    def _status(self, t0: float) -> tuple[float, float, tuple[int, int]]:
        """Return the time since ``t0``, the canvas scale and the canvas shape."""
        return time.perf_counter() - t0, self.scale, self._canvas.shape[:2]

    def _record(self, update: MosaicUpdate) -> MosaicUpdate:
        """Keep an update in ``updates`` and return it."""
        self.updates.append(update)
        return update

    def _start(self, img: np.ndarray, prepared) -> None:
        """Open the canvas with the first frame, drawn in its own pixels scaled by S."""
        hf, wf = img.shape[:2]
        s = (
            self._scale0
            if self._scale0 is not None
            else min(1.0, self.max_size_px / (4.0 * max(wf, hf)))
        )
        self._s = np.diag([s, s, 1.0])
        self._canvas = np.zeros(
            (max(1, int(np.ceil(hf * s))), max(1, int(np.ceil(wf * s))), 3), np.uint8
        )
        geo = FrameGeometry.first((hf, wf))
        self._fit_canvas(geo.to_mosaic(_border((hf, wf))))
        self._draw(img, geo)
        self._accept(img, geo, prepared)

    def _chain(self, img: np.ndarray, reg: RegistrationResult, prepared) -> tuple[float, float]:
        """Place a registered frame after its predecessor and draw both; return the residuals.

        The predecessor is redrawn with the paper's h now that its successor's
        overlap is known. Returns the seam and overlap residuals (new-frame px):
        the predecessor as drawn against the new frame's seam geometry
        (``h = 1``: ``P_(k-1) H_k``), and against the new frame as drawn (with
        its transition), module docstring.
        """
        hf, wf = img.shape[:2]
        prev = self._prev_geo
        if prev.blend:
            prev = FrameGeometry.chained(
                prev.p_prev, prev.h, prev.shape, self._prev_prev_shape, PairModel.of(reg), (hf, wf)
            )
            self._draw(self._prev, prev)
            self.geometries[self._prev_index] = prev
        geo = FrameGeometry.chained(
            prev.placement, PairModel.of(reg), (hf, wf), self._prev.shape[:2]
        )
        pr, pm = reg.points[:, :2], reg.points[:, 2:]
        ls = _local_scale(prev.placement, pr.mean(axis=0))
        q_prev = prev.to_mosaic(pr)
        seam_sq = np.sum((q_prev - apply_h(prev.placement, geo.h.fwd(pm))) ** 2, axis=1)
        seam = float(np.sqrt(np.mean(seam_sq))) / ls
        over = float(np.sqrt(np.mean(np.sum((q_prev - geo.to_mosaic(pm)) ** 2, axis=1)))) / ls
        self._fit_canvas(geo.to_mosaic(_border((hf, wf))))
        self._draw(img, geo)
        self._accept(img, geo, prepared)
        return seam, over

    def _accept(self, img: np.ndarray, geo: FrameGeometry, prepared) -> None:
        """Make an added frame the predecessor of the next one."""
        self._prev_prev_shape = None if self._prev is None else self._prev.shape[:2]
        self._prev_prepared = prepared
        self._prev_index = len(self.transforms)
        self._prev, self._prev_geo = img, geo
        self.transforms.append(geo.placement)
        self.geometries.append(geo)
