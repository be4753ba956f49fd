"""Incremental overview mosaic with bounded memory (METHODS.md C).

Each new frame ``k`` is registered to the previous accepted frame
(:func:`subpix_ros.core.registration.register`), giving ``H_k`` (frame k px
-> frame k-1 px, METHODS C eq. P).

Transition h(y) (METHODS C, eq. 3). The paper draws frame k with

    F(x) = h(y) H_k(x) + (1 - h(y)) x,
    h(y) = 1 for y < H_k,  0 for y > H_(k+1),  1 - (y - H_k) / (H_(k+1) - H_k) between,

so the frame follows its predecessor's geometry where it overlaps it
(``h = 1``) and keeps its OWN geometry where the next frame will overlap it
(``h = 0``); the next frame's ``H_(k+1)``, measured against the frame's own
pixels, then applies there unchanged and perspective never accumulates
along the chain. Here, with a drone that yaws between frames, "y" is the
coordinate along the flight direction in frame k's pixels, and "own
geometry" is the frame placed by a similarity:

    D_k(x) = P_(k-1)( h(t) H_k(x) + (1 - h(t)) A_k(x) ),   P_k = P_(k-1) A_k      (eq. 3, generalised)

``A_k`` is the least-squares similarity (rotation, scale, translation)
closest to ``H_k`` over the frame, ``P_k`` the frame's placement (frame px
-> mosaic px, the first frame's pixels), ``t = (x - c_k) . d`` with ``d``
the unit flight direction in frame k (from the previous frame's centre,
mapped into frame k, to frame k's centre ``c_k``) and ``a`` the advance
(px). h is 1 for ``t <= t1``, 0 for ``t >= t2``, linear between, with

* ``t2 = t_min + a``: where the next frame's trailing edge will be, if it
  advances as this one did (a live mosaic does not know frame k+1 yet: the
  paper's ``H_(k+1)`` is predicted from steady flight);
* ``t1 = min(end of the overlap with frame k-1, t2 - (t2 - t_min)/2)``: the
  paper's ``H_k``; when the overlaps exceed 50 % (the paper assumed at most
  50 %) the transition band is kept at least half as wide as the part of the
  frame that stays visible, so the frame bends gently.

Where frame k overlaps frame k-1's own-geometry region, ``D_(k-1) =
P_(k-1)`` and ``D_k = P_(k-1) H_k``: the two agree at the seam up to the
registration residual.

Drawing: newest frame on top; ``D_k`` is inverted per canvas pixel by a
fixed-point iteration on a coarse grid (every 8 canvas px, bilinear in
between) and the frame resampled with ``cv2.remap``; across its border the
frame's weight ramps linearly from 0 to 1 over ``blend_px`` canvas px.

Bounded memory: the canvas never exceeds ``max_size_px`` on either side.
When the flight leaves it, the canvas grows (padding) up to that size, and
beyond it the whole canvas is downscaled by the needed factor (the scale,
and so the metres/pixel, coarsens) -- never a full-resolution canvas that
grows without bound. Per frame only its geometry (a few 3x3 matrices) is
kept.

Drift report: ``seam_residual_px`` is the RMS disagreement
``|D_(k-1)(x_prev) - P_(k-1) H_k(x_new)|`` over the tie points: the
predecessor as drawn against the new frame's geometry at its seam (where
``h_k = 1``), in frame k's pixels (divided by the scale of ``P_(k-1)``). It
holds the registration residual plus any mismatch left by the predecessor's
transition inside the overlap. ``overlap_residual_px`` is
``|D_(k-1)(x_prev) - D_k(x_new)|``: it adds the intended bending
``(1 - h) |H_k - A_k|`` in the hidden part of the overlap.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np

from .registration import (
    Normaliser,
    RegistrationResult,
    apply_h,
    distort_points,
    prepare_reference,
    register,
    undistort_points,
)

__all__ = ["Mosaic", "MosaicUpdate", "FrameGeometry", "PairModel"]


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
    overlap_residual_px: float | None = (
        None  # tie points through both frames' drawing maps (new-frame px)
    )


def _similarity_to(
    h: "PairModel", shape: tuple[int, int], prev_shape: tuple[int, int]
) -> np.ndarray:
    """Similarity ``A`` (3x3, x -> s R x + t) closest to ``H`` over the overlap, symmetric under reversal.

    Point pairs: a 17x17 grid over this frame kept where ``H`` maps it inside
    the previous frame, plus a 17x17 grid over the previous frame kept where
    ``H^-1`` maps it inside this frame (the overlap, where ``H`` is measured,
    not extrapolated). Estimator symmetric in its two point sets:
    ``t`` from the centroids, ``R`` the rotation by ``atan2(sum a x b, sum a . b)``
    of the centred sets ``a, b``, ``s = sqrt(sum |b|^2 / sum |a|^2)``. Going
    back over the same frames (``H' = H^-1``) gives exactly ``A' = A^-1``, so
    the placement chain ``P_k`` does not drift by construction.
    """

    def grid(sh: tuple[int, int]) -> np.ndarray:
        ys, xs = np.mgrid[0 : sh[0] - 1 : 17j, 0 : sh[1] - 1 : 17j]
        return np.stack([xs.ravel(), ys.ravel()], axis=1)

    def inside(p: np.ndarray, sh: tuple[int, int]) -> np.ndarray:
        return (
            np.isfinite(p).all(axis=1)
            & (p[:, 0] >= 0)
            & (p[:, 0] <= sh[1] - 1)
            & (p[:, 1] >= 0)
            & (p[:, 1] <= sh[0] - 1)
        )

    gk, gp = grid(shape), grid(prev_shape)
    fk, bp = h.fwd(gk), h.inv(gp)
    ik, ip = inside(fk, prev_shape), inside(bp, shape)
    if ik.sum() + ip.sum() >= 8:
        src = np.concatenate([gk[ik], bp[ip]])
        dst = np.concatenate([fk[ik], gp[ip]])
    else:
        ok = np.isfinite(fk).all(axis=1)
        src, dst = gk[ok], fk[ok]
    ms, md = src.mean(axis=0), dst.mean(axis=0)
    a0, b0 = src - ms, dst - md
    th = np.arctan2(np.sum(a0[:, 0] * b0[:, 1] - a0[:, 1] * b0[:, 0]), np.sum(a0 * b0))
    sc = np.sqrt(np.sum(b0 * b0) / np.sum(a0 * a0))
    r = sc * np.array([[np.cos(th), -np.sin(th)], [np.sin(th), np.cos(th)]])
    out = np.eye(3)
    out[:2, :2] = r
    out[:2, 2] = md - r @ ms
    return out


@dataclass(frozen=True)
class PairModel:
    """Frame k px -> frame k-1 px: ``H`` or, with a radial term, ``D(H_u(U(x)))`` (registration's full model)."""

    h: np.ndarray
    hu: np.ndarray | None = None
    lam: float = 0.0
    ref_shape: tuple[int, int] = (0, 0)

    @classmethod
    def of(cls, reg: RegistrationResult) -> "PairModel":
        if reg.distortion == 0.0 or reg.homography_undistorted is None:
            return cls(reg.homography)
        return cls(
            reg.homography, reg.homography_undistorted, float(reg.distortion), tuple(reg.ref_shape)
        )

    def fwd(self, pts: np.ndarray) -> np.ndarray:
        if self.hu is None:
            return apply_h(self.h, pts)
        n = Normaliser.for_shape(self.ref_shape)
        return distort_points(apply_h(self.hu, undistort_points(pts, self.lam, n)), self.lam, n)

    def inv(self, pts: np.ndarray) -> np.ndarray:
        if self.hu is None:
            return apply_h(np.linalg.inv(self.h), pts)
        n = Normaliser.for_shape(self.ref_shape)
        return distort_points(
            apply_h(np.linalg.inv(self.hu), undistort_points(pts, self.lam, n)), self.lam, n
        )


@dataclass
class FrameGeometry:
    """Where one frame is drawn: ``D(x) = P_prev(h H(x) + (1 - h) A(x))`` (module docstring, eq. 3)."""

    p_prev: np.ndarray  # P_(k-1): previous frame px -> mosaic px (similarity)
    h: PairModel  # H_k: this frame px -> previous frame px (with the pair's radial term, if any)
    a: np.ndarray  # A_k: similarity closest to H_k
    shape: tuple[int, int]
    centre: np.ndarray  # c_k (x, y) px
    direction: np.ndarray  # unit flight direction d in this frame's px
    t1: float  # h = 1 for t <= t1 (px along d)
    t2: float  # h = 0 for t >= t2
    blend: bool = True  # False: the first frame (no predecessor), h = 0

    @property
    def placement(self) -> np.ndarray:
        """``P_k = P_(k-1) A_k``: the frame's own geometry in the mosaic (similarity)."""
        return self.p_prev @ self.a

    def weight(self, pts: np.ndarray) -> np.ndarray:
        """h at frame pixels ``pts`` (N, 2): 1 -> predecessor's geometry, 0 -> own geometry."""
        if not self.blend:
            return np.zeros(len(pts))
        if not np.isfinite(
            self.t2
        ):  # no advance / turning back: the frame's own geometry throughout
            return np.zeros(len(pts))
        t = (np.asarray(pts, float) - self.centre) @ self.direction
        return np.clip((self.t2 - t) / max(self.t2 - self.t1, 1e-9), 0.0, 1.0)

    def to_mosaic(self, pts: np.ndarray) -> np.ndarray:
        """``D_k``: frame px (N, 2) (x, y) -> mosaic px."""
        pts = np.asarray(pts, float).reshape(-1, 2)
        w = self.weight(pts)[:, None]
        return apply_h(self.p_prev, w * self.h.fwd(pts) + (1.0 - w) * apply_h(self.a, pts))

    @classmethod
    def first(cls, shape: tuple[int, int]) -> "FrameGeometry":
        e = np.eye(3)
        c = np.array([(shape[1] - 1) / 2.0, (shape[0] - 1) / 2.0])
        return cls(e, PairModel(e), e, shape, c, np.array([0.0, 1.0]), 0.0, 0.0, blend=False)

    @classmethod
    def chained(
        cls,
        p_prev: np.ndarray,
        h: PairModel,
        shape: tuple[int, int],
        prev_shape: tuple[int, int],
        h_next: PairModel | None = None,
        next_shape: tuple[int, int] | None = None,
        min_advance_px: float = 2.0,
    ) -> "FrameGeometry":
        """Geometry of frame k from ``P_(k-1)``, ``H_k`` and, when known, ``H_(k+1)`` (next frame px -> this frame px).

        Without ``h_next`` the next frame's footprint is predicted as this frame
        displaced by its own advance (steady flight). The flight direction ``d``
        is from the previous frame's centre to this frame's centre; ``t2`` is
        the smallest ``t`` of the next frame's footprint (at least ``t_min``:
        a next frame that comes back over the trailing edge -- a turn -- leaves
        the whole frame in its own geometry), ``t1 = max(t_min, min(t_prev_end,
        t2 - (t2 - t_min) / 2))``. No advance (under ``min_advance_px``): own
        geometry throughout.
        """
        a = _similarity_to(h, shape, prev_shape)
        c = _centre(shape)
        c_prev = h.inv(_centre(prev_shape)[None])[0]
        prev_fp = h.inv(_corners(prev_shape))
        adv = float(np.hypot(*(c - c_prev)))
        if not np.isfinite(adv) or adv < min_advance_px:  # hovering: no transition, own geometry
            return cls(p_prev, h, a, shape, c, np.array([0.0, 1.0]), np.inf, np.inf)
        d = (c - c_prev) / adv
        if (
            h_next is None
        ):  # steady flight: the next frame is this one displaced by the same advance
            next_fp = _corners(shape) + (c - c_prev)
        else:
            next_fp = h_next.fwd(_corners(next_shape))
            if not np.isfinite(next_fp).all():
                return cls(p_prev, h, a, shape, c, d, np.inf, np.inf)
        t_min = float(((_corners(shape) - c) @ d).min())
        t2 = max(float(((next_fp - c) @ d).min()), t_min)
        t_prev_end = float(((prev_fp - c) @ d).max())
        t1 = max(t_min, min(t_prev_end, t2 - (t2 - t_min) / 2.0))
        return cls(p_prev, h, a, shape, c, d, t1, t2)


def _corners(shape: tuple[int, int]) -> np.ndarray:
    hh, ww = shape[:2]
    return np.array([[0, 0], [ww - 1, 0], [ww - 1, hh - 1], [0, hh - 1]], float)


def _centre(shape: tuple[int, int]) -> np.ndarray:
    return np.array([(shape[1] - 1) / 2.0, (shape[0] - 1) / 2.0])


def _border(shape: tuple[int, int], n: int = 33) -> np.ndarray:
    """``4 n`` points along a frame's border (x, y), in order."""
    hh, ww = shape
    s = np.linspace(0.0, 1.0, n, endpoint=False)
    top = np.stack([s * (ww - 1), np.zeros(n)], 1)
    right = np.stack([np.full(n, ww - 1.0), s * (hh - 1)], 1)
    bottom = np.stack([(1 - s) * (ww - 1), np.full(n, hh - 1.0)], 1)
    left = np.stack([np.zeros(n), (1 - s) * (hh - 1)], 1)
    return np.concatenate([top, right, bottom, left])


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
    ``frame_max_px``: frames whose larger side exceeds it are first reduced
    (``cv2.INTER_AREA``) to that size, and every geometry (``transforms``,
    ``geometries``, residuals) then refers to the reduced frame's pixels;
    a preview canvas rarely needs more, and registration cost falls with
    the square of the size. None: frames are used as given.

    Each frame's registration-side work (luminance, pyramid, tie-point
    candidates, coarse features: :func:`prepare_reference`) is done once: it
    serves as the moving frame of its own pair and as the reference of the
    next.
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
        self._s = np.eye(3)  # mosaic (first-frame px) -> canvas px
        self._prev: np.ndarray | None = (
            None  # previous accepted frame (as drawn: reduced to frame_max_px)
        )
        self._prev_prepared = None  # its registration-side work (ReferenceFrame)
        self._prev_geo: FrameGeometry | None = None  # its geometry
        self._prev_index = -1  # its index in ``geometries``
        self._prev_prev_shape: tuple[int, int] | None = None  # shape of the frame before it
        #: per added frame: its placement P_k (frame px -> mosaic px, a similarity; None if rejected)
        self.transforms: list[np.ndarray | None] = []
        #: per added frame: its full drawing geometry D_k (None if rejected)
        self.geometries: list[FrameGeometry | None] = []
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

    def _draw(self, frame: np.ndarray, geo: FrameGeometry) -> None:
        """Resample ``frame`` through ``S D_k`` onto the canvas, newest on top with a linear seam ramp."""
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
        # Canvas -> frame map on a grid every g px (one cell beyond the ROI on each side), so that
        # cv2.resize (pixel-centre aligned) interpolates it bilinearly onto every ROI pixel.
        g = 8
        nx, ny = -(-(x1 - x0) // g) + 2, -(-(y1 - y0) // g) + 2
        gx = x0 + (np.arange(nx) - 1) * g + (g - 1) / 2.0
        gy = y0 + (np.arange(ny) - 1) * g + (g - 1) / 2.0
        fx, fy = self._canvas_to_frame(geo, *np.meshgrid(gx, gy))
        # small px i covers frame px k i .. k i + k - 1: centre k i + (k - 1) / 2
        fx, fy = (fx - (k - 1) / 2.0) / k, (fy - (k - 1) / 2.0) / k
        mx = cv2.resize(fx.astype(np.float32), (nx * g, ny * g), interpolation=cv2.INTER_LINEAR)[
            g : g + y1 - y0, g : g + x1 - x0
        ]
        my = cv2.resize(fy.astype(np.float32), (nx * g, ny * g), interpolation=cv2.INTER_LINEAR)[
            g : g + y1 - y0, g : g + x1 - x0
        ]
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
        """Map frame ``index``'s pixels (N, 2) (x, y) to current canvas pixels (``S D_k``)."""
        geo = self.geometries[index]
        if geo is None:
            raise ValueError(f"frame {index} was rejected: {self.updates[index].reason}")
        return apply_h(self._s, geo.to_mosaic(pts))

    # -- public ----------------------------------------------------------------
    def add(self, frame: np.ndarray) -> MosaicUpdate:
        """Register ``frame`` (HxW mono or HxWx3 BGR, uint8) to the previous one and draw it."""
        t0 = time.perf_counter()
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
        kw = {
            k: self.register_kwargs[k]
            for k in ("coarse_size", "detect_size")
            if k in self.register_kwargs
        }
        prepared = prepare_reference(img, **kw)
        idx = len(self.transforms)
        hf, wf = img.shape[:2]
        if self._prev is None:
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
            up = MosaicUpdate(
                True,
                "",
                idx,
                0.0,
                0,
                None,
                time.perf_counter() - t0,
                self.scale,
                self._canvas.shape[:2],
            )
            self.updates.append(up)
            return up
        reg = register(self._prev_prepared, prepared, **self.register_kwargs)
        if not reg.ok:
            self.transforms.append(None)
            self.geometries.append(None)
            up = MosaicUpdate(
                False,
                reg.reason,
                idx,
                None,
                0,
                None,
                time.perf_counter() - t0,
                self.scale,
                self._canvas.shape[:2],
                reg,
            )
            self.updates.append(up)
            return up
        prev = self._prev_geo
        if (
            prev.blend
        ):  # the paper's h for the previous frame, now that its successor's overlap is known
            prev = FrameGeometry.chained(
                prev.p_prev, prev.h, prev.shape, self._prev_prev_shape, PairModel.of(reg), (hf, wf)
            )
            self._draw(self._prev, prev)
            self.geometries[self._prev_index] = prev
        geo = FrameGeometry.chained(
            prev.placement, PairModel.of(reg), (hf, wf), self._prev.shape[:2]
        )
        # Drift report (new-frame px): the predecessor as drawn against the new frame's seam geometry
        # (h = 1: P_(k-1) H_k), and against the new frame as drawn (with its transition).
        pr, pm = reg.points[:, :2], reg.points[:, 2:]
        ls = _local_scale(prev.placement, pr.mean(axis=0))
        q_prev = prev.to_mosaic(pr)
        seam = (
            float(
                np.sqrt(
                    np.mean(np.sum((q_prev - apply_h(prev.placement, geo.h.fwd(pm))) ** 2, axis=1))
                )
            )
            / ls
        )
        over = float(np.sqrt(np.mean(np.sum((q_prev - geo.to_mosaic(pm)) ** 2, axis=1)))) / ls
        self._fit_canvas(geo.to_mosaic(_border((hf, wf))))
        self._draw(img, geo)
        self._accept(img, geo, prepared)
        up = MosaicUpdate(
            True,
            "",
            idx,
            seam,
            reg.inliers,
            reg.rms_px,
            time.perf_counter() - t0,
            self.scale,
            self._canvas.shape[:2],
            reg,
            over,
        )
        self.updates.append(up)
        return up

    def _accept(self, img: np.ndarray, geo: FrameGeometry, prepared) -> None:
        self._prev_prev_shape = None if self._prev is None else self._prev.shape[:2]
        self._prev_prepared = prepared
        self._prev_index = len(self.transforms)
        self._prev, self._prev_geo = img, geo
        self.transforms.append(geo.placement)
        self.geometries.append(geo)
