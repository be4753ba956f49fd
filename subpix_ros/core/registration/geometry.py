"""Geometry of co-registration: homographies applied to points, overlaps, valid regions.

Pixel coordinates are ``(x, y) = (column, row)`` with pixel centres at integers;
homographies map MOVING (x, y) to REFERENCE (x, y).
"""

from __future__ import annotations

import cv2
import numpy as np


def apply_h(h: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """Apply a 3x3 homography to points.

    Parameters
    ----------
    h : ndarray, shape (3, 3)
        The homography.
    pts : ndarray, shape (N, 2)
        Points (x, y).

    Returns
    -------
    ndarray, shape (N, 2)
        ``p' = H [x, y, 1]^T`` dehomogenised (float64).
    """
    p = np.asarray(pts, dtype=np.float64)
    x, y = p[:, 0], p[:, 1]
    w = h[2, 0] * x + h[2, 1] * y + h[2, 2]
    out = np.empty(p.shape, dtype=np.float64)
    out[:, 0] = (h[0, 0] * x + h[0, 1] * y + h[0, 2]) / w
    out[:, 1] = (h[1, 0] * x + h[1, 1] * y + h[1, 2]) / w
    return out


def centre_shift(h: np.ndarray, shape: tuple[int, ...]) -> tuple[float, float] | None:
    """Return how far the reference's centre moved into the moving frame, ``(u, v)`` px.

    Parameters
    ----------
    h : ndarray, shape (3, 3)
        Homography MOVING -> REFERENCE (x, y).
    shape : tuple of int
        The reference frame's shape (rows, cols, ...).

    Returns
    -------
    tuple of float or None
        ``(u, v)`` = (rows, columns): the centre ``c`` appears at ``H^-1 c`` in the moving
        frame (the project's shift convention: content at ``c`` in the reference is at
        ``c + (u, v)`` in the moving frame); None for a singular homography or a point at
        infinity.
    """
    try:
        inverse = np.linalg.inv(np.asarray(h, dtype=np.float64))
    except np.linalg.LinAlgError:
        return None
    cy, cx = (shape[0] - 1) / 2.0, (shape[1] - 1) / 2.0
    q = inverse @ np.array([cx, cy, 1.0])
    if not np.isfinite(q).all() or abs(q[2]) < 1e-12:
        return None
    return float(q[1] / q[2] - cy), float(q[0] / q[2] - cx)


def overlap_fraction(
    h_mr: np.ndarray, shape_ref: tuple[int, ...], shape_mov: tuple[int, ...]
) -> float:
    """Return the fraction of the reference frame's area the moving frame covers.

    Parameters
    ----------
    h_mr : ndarray, shape (3, 3)
        Moving -> reference homography (px).
    shape_ref, shape_mov : tuple of int
        Frame shapes (rows, cols, ...).

    Returns
    -------
    float
        Area of the intersection of the reference frame and the moving frame's image under
        ``h_mr``, over the reference frame's area (0 for a non-finite image).
    """
    hm, wm = shape_mov[:2]
    hr, wr = shape_ref[:2]
    q = apply_h(h_mr, np.array([[0, 0], [wm - 1, 0], [wm - 1, hm - 1], [0, hm - 1]], float)).astype(
        np.float32
    )
    rr = np.array([[0, 0], [wr - 1, 0], [wr - 1, hr - 1], [0, hr - 1]], np.float32)
    if not np.isfinite(q).all():
        return 0.0
    if cv2.contourArea(q, oriented=True) < 0:
        q = q[::-1].copy()
    area, _ = cv2.intersectConvexConvex(q, rr)
    return float(max(area, 0.0) / ((wr - 1) * (hr - 1)))


def _scale_h(h: np.ndarray, factor: float) -> np.ndarray:
    """Return the homography between coordinates scaled by ``factor`` (x' = factor x)."""
    s = np.diag([factor, factor, 1.0])
    out = s @ h @ np.linalg.inv(s)
    return out / out[2, 2]


def _inside(p: np.ndarray, shape: tuple[int, ...], margin: float) -> np.ndarray:
    """Mark the points (x, y) at least ``margin`` px inside a frame of ``shape`` (finite)."""
    return (
        np.isfinite(p).all(axis=1)
        & (p[:, 0] >= margin)
        & (p[:, 0] <= shape[1] - 1 - margin)
        & (p[:, 1] >= margin)
        & (p[:, 1] <= shape[0] - 1 - margin)
    )


def _valid_grid(shape_ref, shape_mov, h_mr, margin_mov: float, step: int) -> np.ndarray:
    """Return a bool mask on the reference grid ``[0:h:step, 0:w:step]``.

    True where the prediction lies inside the moving frame with ``margin_mov + step`` px to
    spare.
    """
    hr, wr = shape_ref
    ys, xs = np.mgrid[0:hr:step, 0:wr:step]
    pm = apply_h(np.linalg.inv(h_mr), np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64))
    return _inside(pm, shape_mov, margin_mov + step).reshape(xs.shape)


def _valid_ref_points(
    shape_ref, shape_mov, h_mr, margin_ref: int, margin_mov: float, step: int = 4
) -> np.ndarray:
    """Return the mask (reference shape) of pixels whose prediction lies inside the moving frame.

    ``margin_ref`` / ``margin_mov`` px are kept clear of either frame's border. The moving frame
    shrunk by ``margin_mov + 1`` maps to a convex quadrilateral under ``h_mr`` (a homography maps
    lines to lines), which is filled; if a corner crosses the perspective horizon the mask is
    evaluated on a grid every ``step`` px instead (expanded, nearest, ``step`` px more margin).
    """
    hr, wr = shape_ref
    hm, wm = shape_mov
    m = margin_mov + 1
    quad = np.array([[m, m], [wm - 1 - m, m], [wm - 1 - m, hm - 1 - m], [m, hm - 1 - m]], float)
    w = h_mr[2, 0] * quad[:, 0] + h_mr[2, 1] * quad[:, 1] + h_mr[2, 2]
    if m < min(hm, wm) / 2 and np.all(w > 0):
        q = apply_h(h_mr, quad)
        inside = np.zeros((hr, wr), np.uint8)
        if np.isfinite(q).all() and np.abs(q).max() < 1e6:
            cv2.fillConvexPoly(
                inside, np.rint(q * 16).astype(np.int32), 1, lineType=cv2.LINE_8, shift=4
            )
        inside = inside.astype(bool)
    else:
        small = _valid_grid(shape_ref, shape_mov, h_mr, margin_mov, step)
        inside = np.repeat(np.repeat(small, step, axis=0), step, axis=1)[:hr, :wr].copy()
    inside[:margin_ref] = False
    inside[hr - margin_ref :] = False
    inside[:, :margin_ref] = False
    inside[:, wr - margin_ref :] = False
    return inside
