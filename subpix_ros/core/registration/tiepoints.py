"""Tie-point helpers of a registration pass: candidates, bookkeeping, coarse-to-fine refinement."""

from __future__ import annotations

import cv2
import numpy as np

from .geometry import _inside, _scale_h, _valid_ref_points
from .harris import harris_peaks, select_spread
from .points import refine_gauss_newton
from .state import _Pass


def _refine_levels(
    ps: _Pass,
    p_r: np.ndarray,
    p_m: np.ndarray,
    h: np.ndarray,
    top: int,
    bottom: int,
    half: int,
    iterations: int = 6,
) -> tuple[np.ndarray, np.ndarray]:
    """Refine tie points to sub-pixel (:func:`.refine_gauss_newton`), coarse to fine.

    Parameters
    ----------
    ps : _Pass
        The pass (frames, ``template_half`` above the input level).
    p_r : ndarray, shape (N, 2)
        Reference points (integer input px, divisible by ``2^top``).
    p_m : ndarray, shape (N, 2)
        Their moving positions (input px).
    h : ndarray, shape (3, 3)
        Moving -> reference at input resolution.
    top, bottom : int
        Pyramid levels refined, ``top`` down to ``bottom``; a point must converge at each.
    half : int
        Template half-size at the input level (level 0).
    iterations : int
        Most Gauss-Newton iterations per level.

    Returns
    -------
    p_m : ndarray, shape (N, 2)
        Refined moving positions (input px).
    converged : ndarray of bool, shape (N,)
    """
    p_m = p_m.copy()
    conv = np.ones(len(p_r), bool)
    for lev in range(top, bottom - 1, -1):
        scale = 2.0**lev
        idx = np.nonzero(conv)[0]
        m_l, c_l = refine_gauss_newton(
            ps.ref.level(lev),
            ps.mov.level(lev),
            p_r[idx] / scale,
            p_m[idx] / scale,
            _scale_h(h, 1.0 / scale),
            half=ps.opts.template_half if lev > 0 else half,
            iterations=iterations,
        )
        p_m[idx[c_l]] = m_l[c_l] * scale
        conv[idx[~c_l]] = False
    return p_m, conv


def _finer_candidates(
    ps: _Pass, lev: int, h: np.ndarray, taken: np.ndarray, n_target: int, margin: float
) -> np.ndarray:
    """Return Harris maxima of level ``lev`` (finer than detection) inside the overlap of ``h``.

    At least 4 level px from the points in ``taken`` (input px, the same corners seen one level
    up); grid quota of ``n_target``; input px (x, y). The Harris response is computed on the
    overlap's bounding box only (plus a 16 px border, more than the filters' and the non-maximum
    suppression's reach), not cached.
    """
    scale = 2.0**lev
    ref_l = ps.ref.level(lev)
    valid = _valid_ref_points(
        ref_l.shape,
        ps.mov.level(lev).shape,
        _scale_h(h, 1.0 / scale),
        int(np.ceil(margin / scale)),
        margin / scale,
    )
    t = np.rint(taken / scale).astype(np.intp)
    t = t[_inside(t.astype(float), ref_l.shape, 0)]
    near = np.zeros(ref_l.shape, np.uint8)
    near[t[:, 1], t[:, 0]] = 1
    valid &= cv2.dilate(near, np.ones((9, 9), np.uint8)) == 0
    if valid.sum() < 64:
        return np.zeros((0, 2))
    rows, cols = np.flatnonzero(valid.any(axis=1)), np.flatnonzero(valid.any(axis=0))
    y0, y1 = max(0, rows[0] - 16), min(ref_l.shape[0], rows[-1] + 17)
    x0, x1 = max(0, cols[0] - 16), min(ref_l.shape[1], cols[-1] + 17)
    xs, ys, resp = harris_peaks(np.ascontiguousarray(ref_l[y0:y1, x0:x1]))
    return select_spread((xs + x0, ys + y0, resp), valid, n_target=n_target) * scale


def _point_key(q: np.ndarray) -> np.ndarray:
    """Return one number per integer pixel position (x, y) of ``q`` (N, 2), for set operations."""
    return np.rint(q[:, 1]) * 1e6 + np.rint(q[:, 0])


def _per_point(pts: np.ndarray, p_r: np.ndarray, p_m: np.ndarray) -> np.ndarray:
    """Put matches ``p_m`` of ``p_r`` (a subset of ``pts``) back in the order of ``pts``.

    Points without a match get NaN.
    """
    out = np.full((len(pts), 2), np.nan)
    if len(p_r):
        key_all = _point_key(pts)
        order = np.argsort(key_all, kind="stable")
        pos = np.searchsorted(key_all[order], _point_key(p_r))
        out[order[np.clip(pos, 0, len(pts) - 1)]] = p_m
    return out


def _candidates(
    peaks, valid: np.ndarray, n_points: int, want_inliers: int
) -> tuple[np.ndarray, np.ndarray | None]:
    """Return ``n_points`` spread tie points and the next ``2 n_points`` tier (or None).

    The second tier (only when ``want_inliers`` > 0) holds candidates for the second pass on
    weak texture.
    """
    if want_inliers <= 0:
        return select_spread(peaks, valid, n_target=n_points), None
    return select_spread(peaks, valid, n_target=n_points, n_more=2 * n_points)
