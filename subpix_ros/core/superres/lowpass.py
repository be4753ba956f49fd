"""Low-passed, integer-shifted windows of frames, for the registrations of super-resolution.

The shift refinement and the tile registration (:mod:`.geometry`) read many
overlapping Gaussian-low-passed windows of the same frames at integer
pre- and post-shifts; these helpers filter only what a window needs, or
slice a whole-frame low-pass computed once.
"""

from __future__ import annotations

import cv2
import numpy as np

from .model import gaussian_kernel


def _integer_preshift(frame: np.ndarray, iu: int, iv: int) -> np.ndarray:
    """Return ``out[i, j] = frame[i + iu, j + iv]`` with reflected borders.

    The integer part of a shift: content moves by ``(-iu, -iv)``.
    """
    if iu == 0 and iv == 0:
        return frame
    h, w = frame.shape
    pu, pv = abs(iu), abs(iv)
    padded = cv2.copyMakeBorder(frame, pu, pu, pv, pv, cv2.BORDER_REFLECT_101)
    return padded[pu + iu : pu + iu + h, pv + iv : pv + iv + w]


def _preshift_window(
    frame: np.ndarray, iu: int, iv: int, r0: int, r1: int, c0: int, c1: int
) -> np.ndarray:
    """Return ``_integer_preshift(frame, iu, iv)[r0:r1, c0:c1]`` without shifting the whole frame.

    A plain slice when the window's source ``[r0+iu, r1+iu) x [c0+iv, c1+iv)`` lies inside
    the frame; otherwise the reflected full preshift is cut.
    """
    h, w = frame.shape
    if 0 <= r0 + iu and r1 + iu <= h and 0 <= c0 + iv and c1 + iv <= w:
        return frame[r0 + iu : r1 + iu, c0 + iv : c1 + iv]
    return _integer_preshift(frame, iu, iv)[r0:r1, c0:c1]


def _f64(a: np.ndarray) -> np.ndarray:
    """Return ``a`` as float64 (a copy unless it is already).

    ``cv2.sepFilter2D`` into ``CV_64F`` from an integer source rounds differently from the
    same values in float64 on some CPUs (AVX-512: up to 6e-14), and a window of a stored
    frame must give exactly the values of the float64 frame.
    """
    return a if a.dtype == np.float64 else a.astype(np.float64)


def _lowpass_window(
    frame: np.ndarray,
    g: np.ndarray,
    pre: tuple[int, int],
    post: tuple[int, int],
    rows: slice,
    cols: slice,
    whole: np.ndarray | None = None,
) -> np.ndarray:
    """Return a window of a low-passed, integer-shifted frame.

    Parameters
    ----------
    frame : numpy.ndarray
        2-D frame.
    g : numpy.ndarray
        Symmetric 1-D low-pass kernel, applied on both axes (``cv2.sepFilter2D``,
        reflected border).
    pre, post : (int, int)
        Integer shifts before and after the low-pass (:func:`_integer_preshift`).
    rows, cols : slice
        The window.
    whole : numpy.ndarray, optional
        The whole frame already low-passed (``sepFilter2D(frame, g, g)``, see
        :class:`_WholeLowpass`); the window is then sliced from it when it can be.

    Returns
    -------
    numpy.ndarray
        ``_integer_preshift(L, *post)[rows, cols]`` with
        ``L = lowpass(_integer_preshift(frame, *pre))``; float64 (float32 from ``whole``).

    Notes
    -----
    Only the window plus the kernel's radius is filtered whenever the window's source lies
    inside the frame (the values equal those of filtering the whole frame exactly: the
    margin holds real pixels, or the frame's own edge where the window touches it);
    otherwise the whole frame is filtered.
    """
    h, w = frame.shape
    r = (len(g) - 1) // 2
    r0, r1 = rows.start + post[0], rows.stop + post[0]  # window in L
    c0, c1 = cols.start + post[1], cols.stop + post[1]
    if 0 <= r0 and r1 <= h and 0 <= c0 and c1 <= w:  # the post-shift is a plain index
        if pre == (0, 0):  # margin clipped at the frame's edges: same reflection as the whole frame
            if whole is not None:
                return whole[r0:r1, c0:c1]
            a0, a1, b0, b1 = max(r0 - r, 0), min(r1 + r, h), max(c0 - r, 0), min(c1 + r, w)
            sub = cv2.sepFilter2D(
                _f64(frame[a0:a1, b0:b1]), cv2.CV_64F, g, g, borderType=cv2.BORDER_REFLECT_101
            )
            return sub[r0 - a0 : r1 - a0, c0 - b0 : c1 - b0]
        a0, a1, b0, b1 = r0 + pre[0] - r, r1 + pre[0] + r, c0 + pre[1] - r, c1 + pre[1] + r
        if 0 <= a0 and a1 <= h and 0 <= b0 and b1 <= w:  # pre-shift and margin inside
            if whole is not None:
                return whole[a0 + r : a1 - r, b0 + r : b1 - r]
            sub = cv2.sepFilter2D(
                _f64(frame[a0:a1, b0:b1]), cv2.CV_64F, g, g, borderType=cv2.BORDER_REFLECT_101
            )
            return sub[r : r + r1 - r0, r : r + c1 - c0]
    if (
        whole is not None
        and pre == (0, 0)
        and r1 - h < h - max(r0, 0)
        and -r0 < min(r1, h)
        and c1 - w < w - max(c0, 0)
        and -c0 < min(c1, w)
    ):
        # the window's part inside the frame, reflected about the frame's edges where the window
        # leaves it (the part touches those edges, so reflecting it is reflecting L)
        sub = whole[max(r0, 0) : min(r1, h), max(c0, 0) : min(c1, w)]
        return cv2.copyMakeBorder(
            sub, max(-r0, 0), max(r1 - h, 0), max(-c0, 0), max(c1 - w, 0), cv2.BORDER_REFLECT_101
        )
    low = cv2.sepFilter2D(
        _f64(_integer_preshift(frame, *pre)), cv2.CV_64F, g, g, borderType=cv2.BORDER_REFLECT_101
    )
    return _integer_preshift(low, *post)[rows, cols]


_WHOLE_LOWPASS_PX = 512 * 512  # frames up to this size are low-passed whole once


class _WholeLowpass:
    """Whole-frame low-passes ``sepFilter2D(frames[i], g, g)``, each computed once.

    The tile registration and the shift refinement (:mod:`.geometry`) read many overlapping
    low-passed windows of the same frames at different integer shifts; for small frames one
    filter pass over each whole frame, sliced by :func:`_lowpass_window`, costs less than
    filtering every window (the same values to single-precision round-off: the registration
    runs in single precision anyway). Reflected border, float32.

    Parameters
    ----------
    frames : numpy.ndarray
        (N, H, W) frames.
    lp_sigma : float, optional
        Gaussian std (px) of the low-pass.

    Notes
    -----
    :meth:`get` returns None for frames larger than ``_WHOLE_LOWPASS_PX`` pixels (their
    windows are filtered one by one: bounded memory).
    """

    def __init__(self, frames: np.ndarray, lp_sigma: float = 1.0) -> None:
        self.frames = frames
        self.lp_sigma = float(lp_sigma)
        self.g = gaussian_kernel(lp_sigma).astype(np.float32)
        self.enabled = frames.shape[1] * frames.shape[2] <= _WHOLE_LOWPASS_PX
        self._done: dict[int, np.ndarray] = {}

    def get(self, i: int, lp_sigma: float) -> np.ndarray | None:
        """Return frame ``i`` low-passed with ``lp_sigma`` (computed once), or None.

        None when disabled (large frames) or for another ``lp_sigma`` than this object's.
        """
        if not self.enabled or float(lp_sigma) != self.lp_sigma:
            return None
        low = self._done.get(i)
        if low is None:
            low = cv2.sepFilter2D(
                self.frames[i].astype(np.float32),
                cv2.CV_32F,
                self.g,
                self.g,
                borderType=cv2.BORDER_REFLECT_101,
            )
            self._done[i] = low
        return low

    @staticmethod
    def getter(lowpassed: "_WholeLowpass | None", lp_sigma: float):
        """Return ``i -> lowpassed.get(i, lp_sigma)``, or always None without a shared low-pass."""
        if lowpassed is None:
            return lambda i: None
        return lambda i: lowpassed.get(i, lp_sigma)
