"""Bring a registered frame onto the reference grid to pixel accuracy (:func:`align`)."""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .result import RegistrationResult

_MAP_STEP = 8  # px between exact samples of align()'s warp map


@dataclass
class AlignResult:
    """The moving frame on the reference grid, to pixel accuracy (see :func:`align`).

    Attributes
    ----------
    aligned : ndarray
        Same shape (and dtype) as the reference.
    mask : ndarray of bool
        True where the pixel really came from the moving frame.
    prior_shift : tuple of float
        ``(u, v)`` (rows, columns; px): content moved from the reference to ``aligned``.
    integer_offset : tuple of int
        ``(rows, cols)`` integer translation removed.
    warped : bool
        True if rotation/perspective exceeded the threshold and the frame was resampled.
    deviation_px : float
        Largest deviation of the model from a pure translation over the overlap (px).
    box : tuple of int or None
        ``(r0, r1, c0, c1)`` when ``mask`` is exactly that rectangle (an integer crop: rows
        r0..r1-1, columns c0..c1-1), else None.
    """

    aligned: np.ndarray
    mask: np.ndarray
    prior_shift: tuple[float, float]
    integer_offset: tuple[int, int]
    warped: bool
    deviation_px: float
    box: tuple[int, int, int, int] | None = None


def _warp_maps(
    registration: RegistrationResult, fr: np.ndarray, hr: int, wr: int
) -> tuple[np.ndarray, np.ndarray]:
    """Return the moving-frame coordinates (x, y maps, float32) of reference pixel ``x - fr``.

    The full model (homography and radial term) is evaluated exactly every ``_MAP_STEP`` px
    and interpolated bilinearly in between: the map is smooth (homography and radial term bend
    it by ~1e-5 px^-1). A grid point without a finite image (behind the horizon) falls back to
    the exact map.
    """
    st = _MAP_STEP
    gy = np.arange(0, hr - 1 + st, st, dtype=np.float64)
    gx = np.arange(0, wr - 1 + st, st, dtype=np.float64)
    gxx, gyy = np.meshgrid(gx - fr[0], gy - fr[1])
    mp = registration.inverse_transfer(np.stack([gxx.ravel(), gyy.ravel()], axis=1))
    if np.isfinite(mp).all():
        cx = mp[:, 0].reshape(gyy.shape).astype(np.float32)
        cy = mp[:, 1].reshape(gyy.shape).astype(np.float32)
        # bilinear interpolation of the coarse maps at (x / st, y / st): cv2.remap on them
        qx = np.broadcast_to(np.arange(wr, dtype=np.float32) / st, (hr, wr))
        qy = np.broadcast_to((np.arange(hr, dtype=np.float32) / st)[:, None], (hr, wr))
        qx, qy = np.ascontiguousarray(qx), np.ascontiguousarray(qy)
        return (
            cv2.remap(cx, qx, qy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE),
            cv2.remap(cy, qx, qy, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE),
        )
    yy, xx = np.mgrid[0:hr, 0:wr]
    mp = registration.inverse_transfer(np.stack([xx.ravel() - fr[0], yy.ravel() - fr[1]], axis=1))
    return mp[:, 0].reshape(hr, wr).astype(np.float32), mp[:, 1].reshape(hr, wr).astype(np.float32)


def _mean_motion(registration: RegistrationResult, ref_shape, mov_shape):
    """Return the mean of ``s(x) = M^-1(x) - x`` over the overlap and its largest deviation.

    Sampled on a grid of about 64 steps along the shorter side.

    Raises
    ------
    ValueError
        If the registration puts no part of the moving frame on the reference.
    """
    hr, wr = ref_shape
    hm, wm = mov_shape
    step = max(1, min(hr, wr) // 64)
    ys, xs = np.mgrid[0:hr:step, 0:wr:step]
    grid = np.stack([xs.ravel(), ys.ravel()], axis=1).astype(np.float64)
    pm = registration.inverse_transfer(grid)
    inside = (
        (pm[:, 0] >= 0)
        & (pm[:, 0] <= wm - 1)
        & (pm[:, 1] >= 0)
        & (pm[:, 1] <= hm - 1)
        & np.isfinite(pm).all(axis=1)
    )
    if not inside.any():
        raise ValueError("the registration puts no part of the moving frame on the reference")
    motion = pm[inside] - grid[inside]
    mean = motion.mean(axis=0)
    return mean, float(np.max(np.hypot(*(motion - mean).T)))


def _checked_frames(reference, moving, registration: RegistrationResult):
    """Return the frames as arrays; ValueError if the registration failed or shapes differ."""
    registration._require_ok()
    ref = np.asarray(reference)
    mov = np.asarray(moving)
    if ref.shape[:2] != tuple(registration.ref_shape) or mov.shape[:2] != tuple(
        registration.mov_shape
    ):
        raise ValueError(
            f"frame shapes {ref.shape[:2]}, {mov.shape[:2]} differ from the registration's "
            f"{tuple(registration.ref_shape)}, {tuple(registration.mov_shape)}"
        )
    return ref, mov


def align(
    reference: np.ndarray,
    moving: np.ndarray,
    registration: RegistrationResult,
    *,
    warp_threshold_px: float = 0.5,
) -> AlignResult:
    """Bring ``moving`` onto the reference grid to pixel accuracy, keeping the sub-pixel rest.

    Parameters
    ----------
    reference, moving : ndarray
        The registered frames (shapes as in ``registration``).
    registration : RegistrationResult
        A successful registration of ``moving`` to ``reference``.
    warp_threshold_px : float
        Largest deviation from a translation (px) still aligned by an integer crop.

    Returns
    -------
    AlignResult
        ``prior_shift = (f_y, f_x)`` is the sub-pixel translation left in ``aligned``
        (content at (r, c) in the reference is at (r + f_y, c + f_x) in ``aligned``), the
        prior for the shift estimator; ``integer_offset = (n_y, n_x)``; ``mask`` marks pixels
        that came from the moving frame (for the warp: whose bicubic support lies inside it).

    Raises
    ------
    ValueError
        If the registration failed, its shapes differ from the frames', or it puts no part
        of the moving frame on the reference.

    Notes
    -----
    Let ``s(x) = M^-1(x) - x`` (reference px, x/y) be where the model puts reference point
    ``x`` in the moving frame, ``s0`` its mean over the overlap, ``n = round(s0)`` and
    ``f = s0 - n`` (each component in [-0.5, 0.5]). If ``max |s(x) - s0|`` over the overlap
    is at most ``warp_threshold_px``, ``aligned[r, c] = moving[r + n_y, c + n_x]`` (an integer
    crop, no resampling); otherwise ``aligned(x) = moving(M^-1(x - f))`` (bicubic): rotation,
    scale and perspective are removed but the content stays displaced by exactly ``f``.
    """
    ref, mov = _checked_frames(reference, moving, registration)
    hr, wr = ref.shape[:2]
    hm, wm = mov.shape[:2]
    s0, dev = _mean_motion(registration, (hr, wr), (hm, wm))
    n = np.rint(s0).astype(int)
    fr = s0 - n
    out = np.zeros(ref.shape[:2] + mov.shape[2:], dtype=mov.dtype)
    if dev <= warp_threshold_px:
        ny, nx = int(n[1]), int(n[0])
        r0, r1 = max(0, -ny), min(hr, hm - ny)
        c0, c1 = max(0, -nx), min(wr, wm - nx)
        mask = np.zeros((hr, wr), bool)
        box = None
        if r1 > r0 and c1 > c0:
            out[r0:r1, c0:c1] = mov[r0 + ny : r1 + ny, c0 + nx : c1 + nx]
            mask[r0:r1, c0:c1] = True
            box = (int(r0), int(r1), int(c0), int(c1))
        return AlignResult(out, mask, (float(fr[1]), float(fr[0])), (ny, nx), False, dev, box)
    mx, my = _warp_maps(registration, fr, hr, wr)
    finite = np.isfinite(mx) & np.isfinite(my)
    mx = np.where(finite, mx, -10).astype(np.float32)
    my = np.where(finite, my, -10).astype(np.float32)
    warped = cv2.remap(mov, mx, my, cv2.INTER_CUBIC, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    mask = finite & (mx >= 1) & (mx <= wm - 2) & (my >= 1) & (my <= hm - 2)
    warped[~mask] = 0
    return AlignResult(
        warped.astype(mov.dtype, copy=False),
        mask,
        (float(fr[1]), float(fr[0])),
        (int(n[1]), int(n[0])),
        True,
        dev,
    )
