"""Single-precision discrete Fourier transforms through OpenCV."""

from __future__ import annotations

import cv2
import numpy as np

from ..filters import rfft2_32
from .workspace import Workspace, work_array

_rfft2_32 = rfft2_32  # the half-plane DFT the solver's spectra use (core/filters.py)


def _as_c2(z: np.ndarray) -> np.ndarray:
    """Return a complex64 array as a 2-channel float32 view (OpenCV's complex matrices)."""
    z = np.ascontiguousarray(z, dtype=np.complex64)
    return z.view(np.float32).reshape(z.shape + (2,))


def _assemble_hr(
    xs: np.ndarray, hp: int, wp: int, workspace: Workspace | None = None
) -> np.ndarray:
    """Return the HR image whose spectrum holds the solved alias components.

    Parameters
    ----------
    xs : numpy.ndarray
        complex, shape ``(p, p, hp, wp // 2 + 1)``: alias component ``(m1, m2)`` of every
        LR bin ``(ky, kx)`` of the rfft half.
    hp, wp : int
        LR DFT size.
    workspace : Workspace or None, optional
        Reused buffer for the packed HR spectrum (the image returned is a new array).

    Returns
    -------
    numpy.ndarray
        float32 (float64 on the odd-size path), shape ``(p hp, p wp)``.

    Notes
    -----
    HR bin ``(m1 hp + ky, m2 wp + kx)`` holds ``xs[m1, m2, ky, kx]``; HR rfft columns whose
    LR bin lies outside the rfft half come from Hermitian symmetry ``X[-K] = conj(X[K])``.
    The inverse real DFT is ``cv2.dft`` on OpenCV's packed (CCS) half spectrum when both
    sizes are even (the half spectrum is written straight into it), else ``np.fft.irfft2``.
    """
    p = xs.shape[0]
    wc = xs.shape[3]
    nh, nw = p * hp, p * wp
    nc = nw // 2 + 1  # HR rfft columns
    ccs_path = nh % 2 == 0 and nw % 2 == 0 and nw >= 4
    if ccs_path:
        ccs = work_array(workspace, "hr_spectrum", (nh, nw), np.float32)
        mid = ccs[:, 1 : nw - 1].view(np.complex64)  # half-spectrum columns 1 .. nc - 2
        edge = np.empty((2, nh), np.complex64)  # columns 0 and nc - 1 (packed separately)

        def put(rows: slice, a: int, b: int, values: np.ndarray, conj: bool = False) -> None:
            # half[rows, a:b] = values (conjugated if asked), split over edge / mid
            for lo, hi, dst in ((0, 1, None), (1, nc - 1, mid), (nc - 1, nc, None)):
                s, e = max(a, lo), min(b, hi)
                if e <= s:
                    continue
                v = values[:, s - a : e - a]
                target = (
                    edge[0 if lo == 0 else 1, rows][:, None]
                    if dst is None
                    else dst[rows, s - 1 : e - 1]
                )
                if conj:
                    np.conjugate(v, out=target)
                else:
                    target[...] = v
    else:
        half = np.empty((nh, nc), dtype=np.complex64)

        def put(rows: slice, a: int, b: int, values: np.ndarray, conj: bool = False) -> None:
            if conj:
                np.conjugate(values, out=half[rows, a:b])
            else:
                half[rows, a:b] = values

    for m2 in range(p):  # alias columns, not pixels
        c0 = m2 * wp
        n_direct = min(wc, nc - c0)
        if n_direct > 0:
            for m1 in range(p):  # alias rows
                put(slice(m1 * hp, (m1 + 1) * hp), c0, c0 + n_direct, xs[m1, m2, :, :n_direct])
        lo, hi = c0 + wc, min(c0 + wp, nc)
        if hi > lo:  # kx in [wc, wp): conj of alias p-1-m2 at LR column wp - kx, HR row -K mod nh
            cs, ce = wp - (hi - c0) + 1, wp - (lo - c0) + 1
            blk = xs[:, p - 1 - m2, :, cs:ce].reshape(nh, ce - cs)[:, ::-1]  # rows K, cols wp - kx
            put(slice(0, 1), lo, hi, blk[:1], conj=True)
            put(slice(1, nh), lo, hi, blk[:0:-1], conj=True)
    if not ccs_path:
        return np.fft.irfft2(half, s=(nh, nw))
    return _inverse_ccs(ccs, edge)


def _inverse_ccs(ccs: np.ndarray, edge: np.ndarray) -> np.ndarray:
    """Pack the two real-symmetric columns into OpenCV's CCS layout and invert it.

    Parameters
    ----------
    ccs : numpy.ndarray
        float32, shape ``(nh, nw)``, both even: the packed half spectrum, its columns
        ``1 .. nw - 2`` already written (modified in place).
    edge : numpy.ndarray
        complex64, shape ``(2, nh)``: half-spectrum columns 0 and ``nw // 2``.

    Returns
    -------
    numpy.ndarray
        float32, shape ``(nh, nw)``: the scaled inverse real DFT.
    """
    nh, nw = ccs.shape
    for col, e in ((0, edge[0]), (nw - 1, edge[1])):  # columns 0 and nc - 1 of the half
        ccs[0, col] = e[0].real
        ccs[1 : nh - 1 : 2, col] = e[1 : nh // 2].real
        ccs[2 : nh - 1 : 2, col] = e[1 : nh // 2].imag
        ccs[nh - 1, col] = e[nh // 2].real
    return cv2.dft(ccs, flags=cv2.DFT_INVERSE | cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)
