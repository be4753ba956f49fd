"""Where each frame of the mosaic is drawn: the pair model H_k and the transition of eq. (3)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from subpix_ros.core.registration import (
    Normaliser,
    RegistrationResult,
    apply_h,
    distort_points,
    undistort_points,
)

__all__ = ["PairModel", "FrameGeometry"]


@dataclass(frozen=True)
class PairModel:
    """Map frame k px to frame k-1 px: ``H``, or ``D(H_u(U(x)))`` with a radial term.

    Parameters
    ----------
    h : ndarray, shape (3, 3)
        Homography ``H`` (frame k px -> frame k-1 px).
    hu : ndarray, shape (3, 3), or None
        Homography between undistorted pixels when the pair has a radial
        term (registration's full model), else None.
    lam : float
        Radial distortion coefficient of ``D``/``U`` (0: none).
    ref_shape : tuple of int
        Shape of the reference frame, which fixes the distortion's normalisation.
    """

    h: np.ndarray
    hu: np.ndarray | None = None
    lam: float = 0.0
    ref_shape: tuple[int, int] = (0, 0)

    @classmethod
    def of(cls, reg: RegistrationResult) -> "PairModel":
        """Return the pair model of a registration result (with its radial term, if any)."""
        if reg.distortion == 0.0 or reg.homography_undistorted is None:
            return cls(reg.homography)
        return cls(
            reg.homography, reg.homography_undistorted, float(reg.distortion), tuple(reg.ref_shape)
        )

    def fwd(self, pts: np.ndarray) -> np.ndarray:
        """Map frame k points (N, 2) (x, y) to frame k-1 px."""
        if self.hu is None:
            return apply_h(self.h, pts)
        n = Normaliser.for_shape(self.ref_shape)
        return distort_points(apply_h(self.hu, undistort_points(pts, self.lam, n)), self.lam, n)

    def inv(self, pts: np.ndarray) -> np.ndarray:
        """Map frame k-1 points (N, 2) (x, y) to frame k px."""
        if self.hu is None:
            return apply_h(np.linalg.inv(self.h), pts)
        n = Normaliser.for_shape(self.ref_shape)
        return distort_points(
            apply_h(np.linalg.inv(self.hu), undistort_points(pts, self.lam, n)), self.lam, n
        )


def _grid(shape: tuple[int, int]) -> np.ndarray:
    """Return a 17x17 grid of points (x, y) over a frame."""
    ys, xs = np.mgrid[0 : shape[0] - 1 : 17j, 0 : shape[1] - 1 : 17j]
    return np.stack([xs.ravel(), ys.ravel()], axis=1)


def _inside(pts: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """Tell which points (N, 2) (x, y) are finite and inside a frame."""
    return (
        np.isfinite(pts).all(axis=1)
        & (pts[:, 0] >= 0)
        & (pts[:, 0] <= shape[1] - 1)
        & (pts[:, 1] >= 0)
        & (pts[:, 1] <= shape[0] - 1)
    )


def _similarity_to(
    pair: PairModel, shape: tuple[int, int], prev_shape: tuple[int, int]
) -> np.ndarray:
    """Return the similarity ``A`` closest to ``H`` over the overlap, symmetric under reversal.

    Parameters
    ----------
    pair : PairModel
        ``H``: this frame px -> previous frame px.
    shape, prev_shape : tuple of int
        Shapes of this frame and of the previous one.

    Returns
    -------
    ndarray, shape (3, 3)
        ``A`` (``x -> s R x + t``).

    Notes
    -----
    Point pairs: a 17x17 grid over this frame kept where ``H`` maps it inside
    the previous frame, plus a 17x17 grid over the previous frame kept where
    ``H^-1`` maps it inside this frame (the overlap, where ``H`` is measured,
    not extrapolated). Estimator symmetric in its two point sets:
    ``t`` from the centroids, ``R`` the rotation by ``atan2(sum a x b, sum a . b)``
    of the centred sets ``a, b``, ``s = sqrt(sum |b|^2 / sum |a|^2)``. Going
    back over the same frames (``H' = H^-1``) gives exactly ``A' = A^-1``, so
    the placement chain ``P_k`` does not drift by construction.
    """
    gk, gp = _grid(shape), _grid(prev_shape)
    fk, bp = pair.fwd(gk), pair.inv(gp)
    ik, ip = _inside(fk, prev_shape), _inside(bp, shape)
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


def _corners(shape: tuple[int, int]) -> np.ndarray:
    """Return the four corners (x, y) of a frame, clockwise from the top left."""
    hh, ww = shape[:2]
    return np.array([[0, 0], [ww - 1, 0], [ww - 1, hh - 1], [0, hh - 1]], float)


def _centre(shape: tuple[int, int]) -> np.ndarray:
    """Return the centre (x, y) of a frame, px."""
    return np.array([(shape[1] - 1) / 2.0, (shape[0] - 1) / 2.0])


def _border(shape: tuple[int, int], n: int = 33) -> np.ndarray:
    """Return ``4 n`` points along a frame's border (x, y), in order."""
    hh, ww = shape
    s = np.linspace(0.0, 1.0, n, endpoint=False)
    top = np.stack([s * (ww - 1), np.zeros(n)], 1)
    right = np.stack([np.full(n, ww - 1.0), s * (hh - 1)], 1)
    bottom = np.stack([(1 - s) * (ww - 1), np.full(n, hh - 1.0)], 1)
    left = np.stack([np.zeros(n), (1 - s) * (hh - 1)], 1)
    return np.concatenate([top, right, bottom, left])


def _local_scale(h: np.ndarray, pt: np.ndarray) -> float:
    """Return sqrt(|det J|) of the homography ``h`` at ``pt`` (x, y), by central differences."""
    e = 0.5
    p = np.array([[pt[0] - e, pt[1]], [pt[0] + e, pt[1]], [pt[0], pt[1] - e], [pt[0], pt[1] + e]])
    q = apply_h(h, p)
    j = np.array([q[1] - q[0], q[3] - q[2]]).T / (2 * e)
    return float(np.sqrt(abs(np.linalg.det(j))))


@dataclass
class FrameGeometry:
    """Where one frame is drawn: ``D(x) = P_prev(h H(x) + (1 - h) A(x))`` (eq. 3).

    Parameters
    ----------
    p_prev : ndarray, shape (3, 3)
        ``P_(k-1)``: previous frame px -> mosaic px (a similarity).
    h : PairModel
        ``H_k``: this frame px -> previous frame px (with the pair's radial
        term, if any).
    a : ndarray, shape (3, 3)
        ``A_k``: the similarity closest to ``H_k``.
    shape : tuple of int
        Frame shape (rows, columns).
    centre : ndarray, shape (2,)
        ``c_k`` (x, y), px.
    direction : ndarray, shape (2,)
        Unit flight direction ``d`` in this frame's px.
    t1, t2 : float
        ``h = 1`` for ``t <= t1``, ``h = 0`` for ``t >= t2`` (px along ``d``).
    blend : bool
        False for the first frame (no predecessor): ``h = 0``.
    """

    p_prev: np.ndarray
    h: PairModel
    a: np.ndarray
    shape: tuple[int, int]
    centre: np.ndarray
    direction: np.ndarray
    t1: float
    t2: float
    blend: bool = True

    @property
    def placement(self) -> np.ndarray:
        """``P_k = P_(k-1) A_k``: the frame's own geometry in the mosaic (similarity)."""
        return self.p_prev @ self.a

    def weight(self, pts: np.ndarray) -> np.ndarray:
        """Return h at frame px ``pts`` (N, 2): 1 -> predecessor's geometry, 0 -> own geometry."""
        if not self.blend:
            return np.zeros(len(pts))
        # no advance / turning back: the frame's own geometry throughout
        if not np.isfinite(self.t2):
            return np.zeros(len(pts))
        t = (np.asarray(pts, float) - self.centre) @ self.direction
        return np.clip((self.t2 - t) / max(self.t2 - self.t1, 1e-9), 0.0, 1.0)

    def to_mosaic(self, pts: np.ndarray) -> np.ndarray:
        """Map frame px (N, 2) (x, y) to mosaic px through ``D_k``."""
        pts = np.asarray(pts, float).reshape(-1, 2)
        w = self.weight(pts)[:, None]
        return apply_h(self.p_prev, w * self.h.fwd(pts) + (1.0 - w) * apply_h(self.a, pts))

    @classmethod
    def first(cls, shape: tuple[int, int]) -> "FrameGeometry":
        """Return the geometry of the first frame: the identity, no transition."""
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
        """Return the geometry of frame k from its predecessor's and, when known, its successor's.

        Parameters
        ----------
        p_prev : ndarray, shape (3, 3)
            ``P_(k-1)``.
        h : PairModel
            ``H_k``: this frame px -> previous frame px.
        shape, prev_shape : tuple of int
            Shapes of this frame and of the previous one.
        h_next : PairModel or None
            ``H_(k+1)``: next frame px -> this frame px, when known.
        next_shape : tuple of int or None
            Shape of the next frame (with ``h_next``).
        min_advance_px : float
            Below this advance (px) the frame keeps its own geometry throughout.

        Returns
        -------
        FrameGeometry
            The frame's drawing geometry.

        Notes
        -----
        Without ``h_next`` the next frame's footprint is predicted as this frame
        displaced by its own advance (steady flight). The flight direction ``d``
        is from the previous frame's centre to this frame's centre; ``t2`` is
        the smallest ``t`` of the next frame's footprint (at least ``t_min``:
        a next frame that comes back over the trailing edge -- a turn -- leaves
        the whole frame in its own geometry), ``t1 = max(t_min, min(t_prev_end,
        t2 - (t2 - t_min) / 2))``.
        """
        a = _similarity_to(h, shape, prev_shape)
        c = _centre(shape)
        c_prev = h.inv(_centre(prev_shape)[None])[0]
        prev_fp = h.inv(_corners(prev_shape))
        adv = float(np.hypot(*(c - c_prev)))
        if not np.isfinite(adv) or adv < min_advance_px:  # hovering: no transition, own geometry
            return cls(p_prev, h, a, shape, c, np.array([0.0, 1.0]), np.inf, np.inf)
        d = (c - c_prev) / adv
        if h_next is None:  # steady flight: the next frame is this one moved by the same advance
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
