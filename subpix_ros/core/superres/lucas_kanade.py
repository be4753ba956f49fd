"""Batched Lucas-Kanade sub-pixel translation of window pairs (super-resolution registration)."""

from __future__ import annotations

import cv2
import numpy as np

from .dft import _rfft2_32


def _lk_context(sl: tuple[slice, slice], h: int, w: int, pad: int = 16) -> tuple[slice, slice]:
    """Region ``sl`` widened by ``pad`` px of context (clipped to the frame), as :func:`_lk` works on it."""
    return (
        slice(max(sl[0].start - pad, 0), min(sl[0].stop + pad, h)),
        slice(max(sl[1].start - pad, 0), min(sl[1].stop + pad, w)),
    )


def _lk_inner(sl: tuple[slice, slice], ctx: tuple[slice, slice]) -> tuple[slice, slice]:
    """The part of region ``sl`` (4 px in from its edges) that the fit uses, relative to its context window."""
    ra, ca = ctx[0].start, ctx[1].start
    return (
        slice(sl[0].start - ra + 4, sl[0].stop - ra - 4),
        slice(sl[1].start - ca + 4, sl[1].stop - ca - 4),
    )


def _lk_batch(
    refs: list[np.ndarray],
    ref_of: np.ndarray,
    mov_window,
    keys: np.ndarray,
    s0: np.ndarray,
    inner: tuple[slice, slice],
    g: np.ndarray,
    iters: int = 3,
    pad: int = 8,
    tol: float = 1e-3,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Lucas-Kanade shifts of M (reference, moving) window pairs at once (all windows one shape).

    Pair m: ``mov ~ shift(ref, s)`` with ``ref = refs[ref_of[m]]`` (a low-passed
    reference window) and the moving window ``mov_window(keys[m], iu, iv)``
    (low-passed, preshifted by the integer part (iu, iv) of the current s).
    Gauss-Newton from ``s0[m]`` on ``F ~ R - d . grad R`` over ``inner``:
    ``R`` is the reference moved by the fractional part of s in the Fourier
    domain (reflect-padded by ``pad`` px, phase ``exp(-2 pi i k.s)``, real
    ``cos(pi s)`` at Nyquist; each reference transformed once; single-precision
    transforms, only the rows the fit reads inverted), ``grad R`` by
    central differences ``(R[i+1] - R[i-1]) / 2``, step ``d = -(G^T G)^-1 G^T (F - R)``, at most ``iters``
    steps; a pair whose step falls below ``tol`` px has converged and takes no
    more (the next would change s by far less). All unconverged pairs'
    transforms, gradients and 2x2 solves are batched. A pair whose step is
    not finite or exceeds 0.5 px (or whose G^T G is singular) stops with its
    current s, std inf and NaN variance. Returns s (M, 2), the std of s
    ``sqrt(var(r) tr((G^T G)^-1) / 2)`` and the noise variance per pixel
    ``var(r) / (2 (sum g^2)^2)`` implied by the final residual r (M each),
    ``r = F - R(s + d) ~ (F - R) + d . grad R``. All sums (G^T G, G^T e, e.e, sum e, sum G) are
    the entries of one single-precision product ``z z^T`` per pair, z the rows
    (grad_y R, grad_x R, e, 1) (BLAS accumulation: relative error ~1e-6, far below the
    shifts' own uncertainty); var(r) follows from them without another pass.
    """
    m_all = len(ref_of)
    hh, ww = refs[0].shape[0] + 2 * pad, refs[0].shape[1] + 2 * pad
    spec = np.empty((len(refs), hh, ww // 2 + 1), np.complex64)  # once per reference
    for t, rf in enumerate(
        refs
    ):  # references (tiles), not pixels: reflect-padded (as np.pad "reflect")
        spec[t] = _rfft2_32(
            cv2.copyMakeBorder(
                np.asarray(rf, np.float32), pad, pad, pad, pad, cv2.BORDER_REFLECT_101
            )
        )
    wy = -2j * np.pi * np.fft.fftfreq(hh)
    wx = -2j * np.pi * np.fft.rfftfreq(ww)
    r0, r1, c0, c1 = inner[0].start, inner[0].stop, inner[1].start, inner[1].stop
    rows = slice(pad + r0 - 1, pad + r1 + 1)  # the rows the fit and its row differences read
    s = np.asarray(s0, dtype=np.float64).copy()
    sig = np.full(m_all, np.inf)
    resvar = np.full(m_all, np.nan)
    active = np.ones(m_all, dtype=bool)
    cache: dict[tuple[int, int, int], np.ndarray] = {}
    g2 = 2.0 * float(np.sum(g**2)) ** 2
    for _ in range(iters):  # Gauss-Newton iterations, all unconverged pairs at once
        act = np.flatnonzero(active)
        if act.size == 0:
            break
        ii = np.rint(s[act]).astype(np.int64)
        frac = s[act] - ii
        movc = []
        for m, (iu, iv) in zip(act, ii):  # pairs (windows), not pixels
            key = (int(keys[m]), int(iu), int(iv))
            if key not in cache:
                cache[key] = mov_window(*key)
            movc.append(cache[key])
        ty = np.exp(wy[None, :] * frac[:, 0, None])
        tx = np.exp(wx[None, :] * frac[:, 1, None])
        if hh % 2 == 0:
            ty[:, hh // 2] = np.cos(np.pi * frac[:, 0])
        if ww % 2 == 0:
            tx[:, -1] = np.cos(np.pi * frac[:, 1])
        # inverse 2-D real FFT as column ifft then row irfft (as np.fft.irfft2), rows limited to the fit's;
        # the column phase tx is constant along the column ifft's axis, so it is applied after it, on the
        # fit's rows only
        shifted = spec[ref_of[act]] * ty.astype(np.complex64)[:, :, None]
        half = np.fft.ifft(shifted, axis=1)[:, rows]
        half *= tx.astype(np.complex64)[:, None, :]
        pred_rows = np.fft.irfft(half, n=ww, axis=2)
        pred = pred_rows[
            :, :, pad + c0 - 1 : pad + c1 + 1
        ]  # rows r0-1 .. r1, cols c0-1 .. c1 (float32)
        # rows of z per pair: grad_y R, grad_x R, e = F - R, 1 — all the sums the step and the residual's
        # variance need are entries of z z^T (one batched matrix product instead of a pass per sum).
        # Central differences (as np.gradient in the interior; ``inner`` is >= 4 px from the window's edge)
        na = act.size
        z = np.empty((na, 4, r1 - r0, c1 - c0), np.float32)
        np.subtract(pred[:, 2:, 1:-1], pred[:, :-2, 1:-1], out=z[:, 0])
        np.subtract(pred[:, 1:-1, 2:], pred[:, 1:-1, :-2], out=z[:, 1])
        z[:, :2] *= 0.5
        for j, mv in enumerate(movc):  # pairs
            np.subtract(mv[r0:r1, c0:c1], pred[j, 1:-1, 1:-1], out=z[j, 2])
        z[:, 3] = 1.0
        z = z.reshape(na, 4, -1)
        zz = np.matmul(z, z.transpose(0, 2, 1)).astype(np.float64)  # (M, 4, 4)
        ata = np.ascontiguousarray(zz[:, :2, :2])
        rhs = zz[:, :2, 2]
        ok = np.abs(np.linalg.det(ata)) > 0
        step = np.full((na, 2), np.nan)
        if ok.any():
            step[ok] = -np.linalg.solve(ata[ok], rhs[ok][..., None])[..., 0]
        good = np.isfinite(step).all(axis=1) & (np.abs(step).max(axis=1) <= 0.5)
        bad = act[~good]
        active[bad] = False
        sig[bad], resvar[bad] = np.inf, np.nan
        if good.any():  # the residual after this step: its variance and the shift's std
            idx, st = act[good], step[good]
            s[idx] += st
            # the residual after the step, r = F - R(s + d) ~ e + G d, and var(r) from the sums in zz (no
            # further pass over the pixels): sum r^2 = e.e + 2 d.(G^T e) + d^T (G^T G) d, sum r = sum e + d.(sum G)
            zg = zz[good]
            npx = z.shape[2]
            s_rr = (
                zg[:, 2, 2]
                + 2.0 * np.einsum("ai,ai->a", st, zg[:, :2, 2])
                + np.einsum("ai,aij,aj->a", st, zg[:, :2, :2], st)
            )
            s_r = zg[:, 2, 3] + np.einsum("ai,ai->a", st, zg[:, :2, 3])
            vr = np.maximum(s_rr / npx - (s_r / npx) ** 2, 0.0)
            resvar[idx] = vr / g2
            sig[idx] = np.sqrt(vr * np.trace(np.linalg.inv(ata[good]), axis1=1, axis2=2) / 2.0)
            active[idx[np.abs(st).max(axis=1) < tol]] = False  # converged: no further iterations
    return s, sig, resvar
