"""Incremental overview mosaic with bounded memory (METHODS.md C).

Each new frame is registered to the previous accepted frame
(:func:`subpix_ros.core.registration.register`), its homography chained into
the mosaic frame (the pixel coordinates of the first frame):

    M_k = M_(k-1) H_(k -> k-1)                                   (chaining, eq. P composed)

and drawn onto a preview canvas ``canvas = S M_k x`` with ``S`` a scaling
plus offset (``scale`` canvas px per first-frame px).

Transition and blend (METHODS C, h(y)): the newest frame is drawn on top,
so each frame keeps its own geometry where the next frame does not cover
it; across the seam its weight ramps linearly from 0 at the frame border to
1 at ``blend_px`` canvas px inside it (the paper's
``h = 1 - (y - H_k) / (H_(k+1) - H_k)`` in the transition band, with the
distance to the new frame's border playing the role of ``y``). The paper
also blends the geometry (``F_x = h u + (1 - h) x``); a preview mosaic
drawn newest-on-top does not need that, and it is not implemented.

Bounded memory: the canvas never exceeds ``max_size_px`` on either side.
When the flight leaves it, the canvas grows (padding) up to that size, and
beyond it the whole canvas is downscaled by the needed factor (the scale,
and so the metres/pixel, coarsens) -- never a full-resolution canvas that
grows without bound.

Drift report: ``seam_residual_px`` is the RMS disagreement of the tie
points across the seam, in the new frame's pixels:
``|M_(k-1)(x_prev) - M_k(x_new)|`` divided by the local scale of
``M_(k-1)``.
"""
from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from .registration import RegistrationResult, register, to_gray32
from .registration_points import apply_h

__all__ = ["Mosaic", "MosaicUpdate"]


@dataclass
class MosaicUpdate:
    """Outcome of :meth:`Mosaic.add`."""

    ok: bool
    reason: str
    index: int  # index of the frame in the order it was added
    seam_residual_px: float | None  # RMS tie-point disagreement across the seam (new-frame px)
    inliers: int
    rms_px: float | None  # registration residual (full model) to the previous frame
    time_s: float  # wall time of this add (registration + drawing)
    scale: float  # canvas px per first-frame px after this add
    canvas_shape: tuple[int, int]
    registration: RegistrationResult | None = None


def _local_scale(h: np.ndarray, pt: np.ndarray) -> float:
    """sqrt(|det J|) of the homography ``h`` at point ``pt`` (x, y), by central differences."""
    e = 0.5
    p = np.array([[pt[0] - e, pt[1]], [pt[0] + e, pt[1]], [pt[0], pt[1] - e], [pt[0], pt[1] + e]])
    q = apply_h(h, p)
    j = np.array([q[1] - q[0], q[3] - q[2]]).T / (2 * e)
    return float(np.sqrt(abs(np.linalg.det(j))))


class Mosaic:
    """Live overview mosaic; see the module docstring.

    ``max_size_px``: maximum canvas side (px). ``scale``: initial canvas px
    per frame px (default: the first frame fills a quarter of the canvas
    side). ``blend_px``: width of the seam blend (canvas px). ``gsd_m``:
    ground sampling distance of the first frame (m/px), to report the
    canvas' metres/pixel. ``register_kwargs`` go to :func:`register`.
    """

    def __init__(
        self,
        max_size_px: int = 2048,
        scale: float | None = None,
        blend_px: int = 24,
        gsd_m: float | None = None,
        register_kwargs: dict | None = None,
    ) -> None:
        if max_size_px < 64:
            raise ValueError("max_size_px must be at least 64")
        self.max_size_px = int(max_size_px)
        self._scale0 = scale
        self.blend_px = int(blend_px)
        self.gsd_m = gsd_m
        self.register_kwargs = dict(register_kwargs or {})
        self._canvas: np.ndarray | None = None
        self._s = np.eye(3)  # mosaic (first-frame px) -> canvas px
        self._prev: np.ndarray | None = None  # previous accepted frame (as given)
        self._prev_m: np.ndarray | None = None  # its chain M_(k-1)
        self.transforms: list[np.ndarray | None] = []  # M_k per added frame (None if rejected)
        self.updates: list[MosaicUpdate] = []

    @property
    def scale(self) -> float:
        return float(self._s[0, 0])

    @property
    def metres_per_px(self) -> float | None:
        """Canvas metres per pixel, if ``gsd_m`` was given."""
        return None if self.gsd_m is None else self.gsd_m / self.scale

    def image(self) -> np.ndarray:
        """The current preview canvas (uint8 BGR copy); empty (0x0x3) before the first frame."""
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
        self._canvas = cv2.warpAffine(self._canvas, shift[:2], (nw, nh), flags=cv2.INTER_AREA if f < 1 else cv2.INTER_NEAREST)
        self._s = shift @ self._s

    def _draw(self, frame: np.ndarray, m: np.ndarray) -> None:
        """Warp ``frame`` (chain ``m``) onto the canvas, newest on top with a linear seam ramp."""
        hf, wf = frame.shape[:2]
        t = self._s @ m  # frame px -> canvas px
        corners = np.array([[0, 0], [wf - 1, 0], [wf - 1, hf - 1], [0, hf - 1]], float)
        q = apply_h(t, corners)
        hc, wc = self._canvas.shape[:2]
        x0, y0 = np.maximum(np.floor(q.min(axis=0)).astype(int), 0)
        x1, y1 = np.minimum(np.ceil(q.max(axis=0)).astype(int) + 1, [wc, hc])
        if x1 <= x0 or y1 <= y0:
            return
        # Pre-shrink the frame so the warp does not alias (local scale of t).
        sc = _local_scale(t, np.array([wf / 2, hf / 2]))
        img = frame
        pre = np.eye(3)
        if sc < 0.5:
            k = max(1, int(1 / sc / 1.5))
            img = cv2.resize(frame, (max(1, wf // k), max(1, hf // k)), interpolation=cv2.INTER_AREA)
            # pixel centre convention: small px i covers big px k i .. k i + k - 1
            pre = np.array([[k, 0, (k - 1) / 2], [0, k, (k - 1) / 2], [0, 0, 1.0]])
        roi = np.array([[1, 0, -x0], [0, 1, -y0], [0, 0, 1.0]])
        tt = roi @ t @ pre
        size = (int(x1 - x0), int(y1 - y0))
        warped = cv2.warpPerspective(img, tt, size, flags=cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT)
        valid = cv2.warpPerspective(np.full(img.shape[:2], 255, np.uint8), tt, size, flags=cv2.INTER_NEAREST,
                                    borderMode=cv2.BORDER_CONSTANT)
        dist = cv2.distanceTransform((valid > 0).astype(np.uint8), cv2.DIST_L2, 3)
        alpha = np.clip(dist / max(self.blend_px, 1), 0.0, 1.0)[:, :, None]
        dst = self._canvas[y0:y1, x0:x1]
        empty = (dst.max(axis=2) == 0)[:, :, None] & (valid > 0)[:, :, None]
        alpha = np.where(empty, 1.0, alpha)
        self._canvas[y0:y1, x0:x1] = np.clip(dst * (1 - alpha) + warped * alpha + 0.5, 0, 255).astype(np.uint8)

    # -- public ----------------------------------------------------------------
    def add(self, frame: np.ndarray) -> MosaicUpdate:
        """Register ``frame`` (HxW mono or HxWx3 BGR, uint8) to the previous one and draw it."""
        t0 = time.perf_counter()
        img = np.asarray(frame)
        to_gray32(img, "frame")  # validates shape / dtype / finiteness
        if img.dtype != np.uint8:
            raise ValueError(f"frame must be uint8, got {img.dtype}")
        if img.ndim == 2:
            img = cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
        idx = len(self.transforms)
        hf, wf = img.shape[:2]
        corners = np.array([[0, 0], [wf - 1, 0], [wf - 1, hf - 1], [0, hf - 1]], float)
        if self._prev is None:
            s = self._scale0 if self._scale0 is not None else min(1.0, self.max_size_px / (4.0 * max(wf, hf)))
            self._s = np.diag([s, s, 1.0])
            self._canvas = np.zeros((max(1, int(np.ceil(hf * s))), max(1, int(np.ceil(wf * s))), 3), np.uint8)
            m = np.eye(3)
            self._fit_canvas(corners)
            self._draw(img, m)
            self._prev, self._prev_m = img, m
            self.transforms.append(m)
            up = MosaicUpdate(True, "", idx, 0.0, 0, None, time.perf_counter() - t0, self.scale, self._canvas.shape[:2])
            self.updates.append(up)
            return up
        reg = register(self._prev, img, **self.register_kwargs)
        if not reg.ok:
            self.transforms.append(None)
            up = MosaicUpdate(False, reg.reason, idx, None, 0, None, time.perf_counter() - t0, self.scale,
                              self._canvas.shape[:2], reg)
            self.updates.append(up)
            return up
        m = self._prev_m @ reg.homography
        m = m / m[2, 2]
        # Seam residual: tie points of both frames through their chains, in new-frame px.
        pr, pm = reg.points[:, :2], reg.points[:, 2:]
        d = apply_h(self._prev_m, pr) - apply_h(m, pm)
        ls = _local_scale(self._prev_m, pr.mean(axis=0))
        seam = float(np.sqrt(np.mean((d * d).sum(axis=1))) / max(ls, 1e-12))
        self._fit_canvas(apply_h(m, corners))
        self._draw(img, m)
        self._prev, self._prev_m = img, m
        self.transforms.append(m)
        up = MosaicUpdate(True, "", idx, seam, reg.inliers, reg.rms_px, time.perf_counter() - t0, self.scale,
                          self._canvas.shape[:2], reg)
        self.updates.append(up)
        return up
