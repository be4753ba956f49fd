"""Batched Lucas-Kanade sub-pixel translation of many window pairs at once.

The shift package's second estimator, beside the pairwise one of :func:`estimate_shift`:
that one estimates one pair at the accuracy limit (masks, prefilter, covariance); this one
fits hundreds of small low-passed windows against their references in one vectorised pass
(a few Gauss-Newton steps each, the reference moved by a Fourier shift) and gives each
pair's residual noise variance. The super-resolution uses it to screen frames, estimate the
noise jointly over the frames and check the geometry tile by tile.

References
----------
.. [1] B. D. Lucas and T. Kanade, "An iterative image registration technique with an
   application to stereo vision", Proc. IJCAI 1981, pp. 674-679.
"""

from __future__ import annotations

import cv2
import numpy as np

from ..filters import rfft2_32 as _rfft2_32

__all__ = ["lucas_kanade_batch", "lk_window_context", "lk_inner_region"]


def lk_window_context(
    sl: tuple[slice, slice], h: int, w: int, pad: int = 16
) -> tuple[slice, slice]:
    """Return region ``sl`` widened by ``pad`` px of context, clipped to an h x w frame."""
    return (
        slice(max(sl[0].start - pad, 0), min(sl[0].stop + pad, h)),
        slice(max(sl[1].start - pad, 0), min(sl[1].stop + pad, w)),
    )


def lk_inner_region(sl: tuple[slice, slice], ctx: tuple[slice, slice]) -> tuple[slice, slice]:
    """Return the part of region ``sl`` the fit uses (4 px in), relative to its context ``ctx``."""
    ra, ca = ctx[0].start, ctx[1].start
    return (
        slice(sl[0].start - ra + 4, sl[0].stop - ra - 4),
        slice(sl[1].start - ca + 4, sl[1].stop - ca - 4),
    )


def lucas_kanade_batch(
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
    """Estimate the shifts of M (reference, moving) window pairs at once by Lucas-Kanade.

    Parameters
    ----------
    refs : list of numpy.ndarray
        Low-passed reference windows, all of one shape.
    ref_of : numpy.ndarray
        (M,) index into ``refs`` of each pair's reference.
    mov_window : callable
        ``mov_window(keys[m], iu, iv)``: pair m's low-passed moving window, preshifted by
        the integer part (iu, iv) of the current shift (same shape as the references).
    keys : numpy.ndarray
        (M,) the key of each pair's moving window.
    s0 : numpy.ndarray
        (M, 2) starting shifts (px).
    inner : (slice, slice)
        The region of the windows the fit uses (at least 4 px from their edges).
    g : numpy.ndarray
        The 1-D low-pass kernel the windows were filtered with (for the noise variance).
    iters : int, optional
        Most Gauss-Newton steps.
    pad : int, optional
        Reflected padding of the references before their DFT (px).
    tol : float, optional
        A pair whose step falls below ``tol`` px has converged and takes no more.

    Returns
    -------
    shifts : numpy.ndarray
        (M, 2) estimated shifts.
    sigma : numpy.ndarray
        (M,) std of each shift, ``sqrt(var(r) tr((G^T G)^-1) / 2)`` (inf if the fit failed).
    noise_var : numpy.ndarray
        (M,) per-pixel noise variance ``var(r) / (2 (sum g^2)^2)`` implied by the final
        residual r (NaN if the fit failed).

    Notes
    -----
    Pair m: ``F ~ shift(R, s)``. Gauss-Newton on ``F ~ R - d . grad R``: R is the
    reference moved by the fractional part of s in the Fourier domain (phase
    ``exp(-2 pi i k.s)``, real ``cos(pi s)`` at Nyquist; each reference transformed once,
    single precision, only the rows the fit reads inverted), ``grad R`` by central
    differences, step ``d = -(G^T G)^-1 G^T (F - R)``. A step that is not finite or
    exceeds 0.5 px (or a singular G^T G) stops the pair with its current s. All sums
    (G^T G, G^T e, e.e, sum e, sum G) are the entries of one single-precision product
    ``z z^T`` per pair, z the rows (grad_y R, grad_x R, e, 1); the residual after the step,
    ``r ~ e + G d``, has its variance from them without another pass.
    """
    m_all = len(ref_of)
    spec = _reference_spectra(refs, pad)
    width = refs[0].shape[1] + 2 * pad
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
        movc = _moving_windows(cache, mov_window, keys, act, ii)
        pred = _shifted_references(spec[ref_of[act]], frac, inner, pad, width)
        zz, npx = _normal_sums(pred, movc, inner)
        _gauss_newton_step(zz, npx, act, s, sig, resvar, active, g2, tol)
    return s, sig, resvar


def _moving_windows(cache: dict, mov_window, keys: np.ndarray, act: np.ndarray, ii: np.ndarray):
    """Return the active pairs' moving windows at their integer shifts (cached per key)."""
    movc = []
    for m, (iu, iv) in zip(act, ii):  # pairs (windows), not pixels
        key = (int(keys[m]), int(iu), int(iv))
        if key not in cache:
            cache[key] = mov_window(*key)
        movc.append(cache[key])
    return movc


def _reference_spectra(refs: list[np.ndarray], pad: int) -> np.ndarray:
    """Return the single-precision half spectra of the reflect-padded references."""
    hh, ww = refs[0].shape[0] + 2 * pad, refs[0].shape[1] + 2 * pad
    spec = np.empty((len(refs), hh, ww // 2 + 1), np.complex64)
    for t, rf in enumerate(refs):  # references (tiles), not pixels
        spec[t] = _rfft2_32(
            cv2.copyMakeBorder(
                np.asarray(rf, np.float32), pad, pad, pad, pad, cv2.BORDER_REFLECT_101
            )
        )
    return spec


def _shifted_references(
    spec: np.ndarray, frac: np.ndarray, inner: tuple[slice, slice], pad: int, ww: int
) -> np.ndarray:
    """Return the references moved by ``frac`` (M, 2), on ``inner`` plus one px around it.

    ``spec`` holds their half spectra (M, hh, ww // 2 + 1), ``ww`` the padded width.

    The inverse 2-D real DFT runs as a column ifft then a row irfft (as ``np.fft.irfft2``),
    rows limited to the fit's; the column phase is constant along the column ifft's axis,
    so it is applied after it, on those rows only. float32.
    """
    hh = spec.shape[1]
    r0, r1, c0, c1 = inner[0].start, inner[0].stop, inner[1].start, inner[1].stop
    rows = slice(pad + r0 - 1, pad + r1 + 1)  # the rows the fit and its row differences read
    wy = -2j * np.pi * np.fft.fftfreq(hh)
    wx = -2j * np.pi * np.fft.rfftfreq(ww)
    ty = np.exp(wy[None, :] * frac[:, 0, None])
    tx = np.exp(wx[None, :] * frac[:, 1, None])
    if hh % 2 == 0:
        ty[:, hh // 2] = np.cos(np.pi * frac[:, 0])
    if ww % 2 == 0:
        tx[:, -1] = np.cos(np.pi * frac[:, 1])
    shifted = spec * ty.astype(np.complex64)[:, :, None]
    half = np.fft.ifft(shifted, axis=1)[:, rows]
    half *= tx.astype(np.complex64)[:, None, :]
    pred_rows = np.fft.irfft(half, n=ww, axis=2)
    return pred_rows[:, :, pad + c0 - 1 : pad + c1 + 1]  # rows r0-1 .. r1, cols c0-1 .. c1


def _normal_sums(
    pred: np.ndarray, movc: list[np.ndarray], inner: tuple[slice, slice]
) -> tuple[np.ndarray, int]:
    """Return ``z z^T`` per pair (M, 4, 4) and the pixel count, z = (grad_y R, grad_x R, e, 1).

    Central differences ``(R[i+1] - R[i-1]) / 2`` (as ``np.gradient`` in the interior),
    ``e = F - R``; one batched single-precision matrix product instead of a pass per sum.
    """
    r0, r1, c0, c1 = inner[0].start, inner[0].stop, inner[1].start, inner[1].stop
    na = pred.shape[0]
    z = np.empty((na, 4, r1 - r0, c1 - c0), np.float32)
    np.subtract(pred[:, 2:, 1:-1], pred[:, :-2, 1:-1], out=z[:, 0])
    np.subtract(pred[:, 1:-1, 2:], pred[:, 1:-1, :-2], out=z[:, 1])
    z[:, :2] *= 0.5
    for j, mv in enumerate(movc):  # pairs
        np.subtract(mv[r0:r1, c0:c1], pred[j, 1:-1, 1:-1], out=z[j, 2])
    z[:, 3] = 1.0
    z = z.reshape(na, 4, -1)
    return np.matmul(z, z.transpose(0, 2, 1)).astype(np.float64), z.shape[2]


def _gauss_newton_step(
    zz: np.ndarray,
    npx: int,
    act: np.ndarray,
    s: np.ndarray,
    sig: np.ndarray,
    resvar: np.ndarray,
    active: np.ndarray,
    g2: float,
    tol: float,
) -> None:
    """Take one Gauss-Newton step for the active pairs ``act`` (updates the arrays in place).

    A failed step (singular, not finite, or > 0.5 px) stops the pair with std inf and NaN
    variance. After a good step the residual's sums follow from ``zz``:
    ``sum r^2 = e.e + 2 d.(G^T e) + d^T (G^T G) d``, ``sum r = sum e + d.(sum G)``.
    """
    na = act.size
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
    if not good.any():
        return
    idx, st = act[good], step[good]
    s[idx] += st
    zg = zz[good]
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
