"""Fourier-domain MAP super-resolution of translated frames (METHODS.md B, eq. 9)."""

from __future__ import annotations

import functools

import cv2
import numpy as np

from ..filters import fractional_shift
from .dft import _rfft2_32
from .geometry import _refine_shifts
from .lowpass import _preshift_window, _WholeLowpass
from .model import frame_transfer_1d
from .separable import _solve_separable
from .spectrum import _SPECTRUM_CROP, fit_spectrum


def _solve_hermitian(m: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched solve of Hermitian positive-definite systems ``m x = b`` (..., k, k)."""
    return np.linalg.solve(m, b[..., None])[..., 0]


def _consistent_padding(
    frames: np.ndarray, ishift: np.ndarray, resid: np.ndarray, pad: int, hp: int, wp: int
) -> np.ndarray:
    """Pad every frame to (hp, wp) with one consistent extension of the scene.

    The reference is reflect-padded; every other frame's padding (and the
    strip its integer shift leaves empty) is that padded reference moved by the
    frame's sub-pixel shift (band-limited Fourier shift), so all frames see
    the same scene outside the image, as the periodic model assumes (the
    shift is an 8-tap Lanczos fractional delay: only the padding uses it, so
    it is computed on the padding strips only). Frame n's
    own pixels fill the area they cover. float32, (n, hp, wp).
    """
    n, h, w = frames.shape
    out = np.empty((n, hp, wp), dtype=np.float32)
    ref = cv2.copyMakeBorder(
        frames[0].astype(np.float32), pad, hp - h - pad, pad, wp - w - pad, cv2.BORDER_REFLECT_101
    )
    for i in range(n):  # per frame
        iu, iv = int(ishift[i, 0] - ishift[0, 0]), int(ishift[i, 1] - ishift[0, 1])
        du, dv = float(resid[i, 0] - resid[0, 0]), float(resid[i, 1] - resid[0, 1])
        # frame i's pixel (r, c) sits at preshifted position (r - iu, c - iv)
        r0, r1 = max(0, -iu), min(h, h - iu)
        c0, c1 = max(0, -iv), min(w, w - iv)
        if r1 > r0 and c1 > c0:
            inner = (slice(pad + r0, pad + r1), slice(pad + c0, pad + c1))
            out[i][inner] = frames[i, r0 + iu : r1 + iu, c0 + iv : c1 + iv]
            rest = [
                (slice(0, inner[0].start), slice(0, wp)),
                (slice(inner[0].stop, hp), slice(0, wp)),
                (inner[0], slice(0, inner[1].start)),
                (inner[0], slice(inner[1].stop, wp)),
            ]
        else:
            rest = [(slice(0, hp), slice(0, wp))]
        for win in rest:  # the padding strips (4 at most)
            if win[0].stop <= win[0].start or win[1].stop <= win[1].start:
                continue
            if i == 0 or (du == 0 and dv == 0):
                out[i][win] = ref[win]
            else:
                out[i][win] = fractional_shift(ref, du, dv, window=win)
    return out


@functools.lru_cache(maxsize=32)
def _transfer_base(n_lr: int, p: int, blur_sigma: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`frame_transfer_1d` at zero shift, ``(a0, f)`` (cached per length, factor and blur; read-only)."""
    a0, f = frame_transfer_1d(n_lr, p, 0.0, blur_sigma)
    a0.flags.writeable = False
    f.flags.writeable = False
    return a0, f


def _frame_transfers(
    n_lr: int, p: int, shifts: np.ndarray, blur_sigma: float, keep: int | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """:func:`frame_transfer_1d` for every shift at once: ``a[n] = a0 exp(-2 pi i f p s_n)`` (N, p, keep), and f.

    ``a0`` is the zero-shift transfer (cached); the shift enters as the phase factor only, as in
    frame_transfer_1d (the same values to round-off). ``keep``: the first columns only (rfft half).
    """
    a0, f = _transfer_base(n_lr, p, float(blur_sigma))
    if keep is not None:
        a0, f = a0[:, :keep], f[:, :keep]
    s = np.asarray(shifts, dtype=np.float64)
    return a0[None] * np.exp((-2j * np.pi * p) * f[None] * s[:, None, None]), f


def _fourier_map(
    frames: np.ndarray,
    shifts: np.ndarray,
    p: int,
    blur_sigma: float,
    noise_sigma: float | None,
    shift_cov: np.ndarray,
    reg: float,
    refine_shifts: bool,
    pad: int,
    integer_valued: bool | None = None,
    lowpassed: _WholeLowpass | None = None,
) -> dict:
    """MAP estimate of eq. 9 for translated frames, solved per LR frequency bin.

    Per LR bin the model is ``Y_n = sum_m a_nm X_m + e_n`` over the p^2 aliased
    HR bins m, with ``a_nm`` from :func:`frame_transfer_1d` (box, blur, shift,
    times the expected-transfer factor ``E_nm = exp(-2 pi^2 f_m^T C_n f_m)`` of
    the registration error covariance ``C_n``), noise variance
    ``v_n = HW sigma^2 + sum_m |a_nm|^2 P_m (1 - E_nm^2)`` and the prior
    ``E|X_m|^2 = P_m = c |f_m|^-alpha`` (DC unregularised). The MAP solution
    ``X = (A^H V^-1 A + reg P^-1)^-1 A^H V^-1 Y`` (or eq. 9's form
    ``X = P A^H (A P A^H + V/reg)^-1 Y`` when N < p^2, identical) is computed
    for all bins at once (batched small solves); boundaries by reflected
    padding of ``pad`` LR px. Returns the HR image and diagnostics.
    """
    n, h, w = frames.shape
    ishift = np.rint(shifts).astype(np.int64)
    resid = shifts - ishift
    hp = cv2.getOptimalDFTSize(h + 2 * pad)
    wp = cv2.getOptimalDFTSize(w + 2 * pad)
    wc = wp // 2 + 1
    shift_sigma_fit = np.zeros(n)
    lk_noise = float("nan")
    keep = np.ones(n, dtype=bool)
    if refine_shifts or noise_sigma is None:
        # registration against frame 0: refined shifts (used if refine_shifts), their std, and the
        # multi-frame noise estimate (used if noise_sigma is None)
        refined, shift_sigma_fit, lk_noise, resvar = _refine_shifts(
            frames, ishift, resid, lowpassed=lowpassed
        )
        if refine_shifts:
            resid = refined
        else:
            shift_sigma_fit = np.where(np.isfinite(shift_sigma_fit), 0.0, np.inf)
        # frames whose registration failed, or that disagree with the reference far beyond the
        # others (residual variance > 9x the median: moving objects, wrong frame), are left out
        keep = np.isfinite(shift_sigma_fit)
        if np.isfinite(resvar[1:]).any():
            keep[1:] &= np.isfinite(resvar[1:]) & (
                resvar[1:] <= 9.0 * np.nanmedian(resvar[1:]) + 1e-12
            )
        keep[0] = True
        if keep.sum() < 2:
            raise ValueError("no frame other than the reference could be registered to it")
        if not keep.all():
            full_n = n
            frames, ishift, resid, shift_sigma_fit = (
                frames[keep],
                ishift[keep],
                resid[keep],
                shift_sigma_fit[keep],
            )
            shift_cov = np.asarray(shift_cov)[keep]
            n = int(keep.sum())
    padded = _consistent_padding(frames, ishift, resid, pad, hp, wp)
    spec = np.empty((n, hp, wc), np.complex64)
    for i in range(n):  # per frame: single-precision DFT, rfft half
        spec[i] = _rfft2_32(padded[i])
    # fit_spectrum reads only the central crop of the first two (integer-preshifted) frames: cut just that
    ch, cw = min(h, _SPECTRUM_CROP), min(w, _SPECTRUM_CROP)
    rc, cc = (h - ch) // 2, (w - cw) // 2
    pre = np.stack(
        [
            _preshift_window(
                frames[i], int(ishift[i, 0]), int(ishift[i, 1]), rc, rc + ch, cc, cc + cw
            )
            for i in range(min(n, 2))
        ]
    )
    if noise_sigma is None and np.isfinite(lk_noise):
        noise_sigma = lk_noise  # multi-frame estimate (see _refine_shifts)
    c_psd, alpha, sig_fit = fit_spectrum(pre, p, blur_sigma, noise_sigma)
    if noise_sigma is None:
        # integer-valued data carry at least the rounding noise 1/sqrt(12) DN
        if integer_valued is None:  # (integer dtypes are known to be; float data are checked)
            integer_valued = bool(np.all(frames == np.rint(frames)))
        floor = 1.0 / np.sqrt(12.0) if integer_valued else 0.05
        noise_sigma = max(sig_fit, floor)
        if sig_fit < floor:  # refit the prior level with the floor as the noise
            c_psd, alpha, _ = fit_spectrum(pre, p, blur_sigma, noise_sigma)
    noise_sigma = max(noise_sigma, 0.05)
    noise_power = hp * wp * noise_sigma**2
    c = c_psd * p * p * hp * wp  # prior in HR DFT units: E|X|^2 = (p hp)(p wp) S_x

    # registration-error covariance per frame (LR px^2); frame 0 defines the grid
    cov = np.array(shift_cov, dtype=np.float64).copy()
    if refine_shifts:
        fit_var = np.where(np.isfinite(shift_sigma_fit), shift_sigma_fit**2, 1.0)
        # after refinement the error is the refinement's (floor 0.01 px for alias bias)
        cov = np.eye(2)[None] * (np.maximum(fit_var, 0.003**2))[:, None, None]
    cov[0] = 0.0

    ay, fy = _frame_transfers(hp, p, resid[:, 0], blur_sigma)
    ax, fx = _frame_transfers(wp, p, resid[:, 1], blur_sigma, wc)
    # registration error negligible at all frequencies (< 1e-3 relative transfer loss): constant weights
    max_var = float(np.max(cov[:, 0, 0] + cov[:, 1, 1]))
    resid_ratio = np.full(n, np.nan)
    if 2.0 * np.pi**2 * max_var * 0.5 < 1e-3:
        xs = _solve_separable(spec, ay, ax, fy, fx, c, alpha, reg, noise_power, shifts=resid)
        wsum = np.sum(np.abs(ay[:, 0]) ** 2, axis=1) * np.sum(np.abs(ax[:, 0]) ** 2, axis=1)
    else:
        k = p * p
        xs = np.zeros((p, p, hp, wc), dtype=np.complex64)
        resid_ratio = np.zeros(n)
        wsum = np.zeros(n)
        chunk = max(1, int(4e5 // (n * k * wc)))
        for r0 in range(0, hp, chunk):  # chunks of LR spectrum rows (memory bound)
            r1 = min(hp, r0 + chunk)
            fyc = fy[:, r0:r1]  # (p, R)
            f2y = fyc[:, None, :, None] ** 2  # (p,1,R,1)
            f2x = fx[None, :, None, :] ** 2  # (1,p,1,wc)
            fxy = fyc[:, None, :, None] * fx[None, :, None, :]
            fr = np.sqrt(f2y + f2x)
            prior = np.where(fr > 0, c * np.maximum(fr, 1e-6) ** (-alpha), 1e30)  # (p,p,R,wc)
            a0 = ay[:, :, None, r0:r1, None] * ax[:, None, :, None, :]  # (n,p,p,R,wc)
            e = np.exp(
                -2.0
                * np.pi**2
                * p
                * p
                * (
                    cov[:, 0, 0, None, None, None, None] * f2y
                    + 2 * cov[:, 0, 1, None, None, None, None] * fxy
                    + cov[:, 1, 1, None, None, None, None] * f2x
                )
            )
            a = a0 * e
            var = noise_power + np.sum(
                np.abs(a0) ** 2 * prior * (1.0 - e**2), axis=(1, 2)
            )  # (n,R,wc)
            # batch layout (bins, n, k)
            ab = a.reshape(n, k, -1).transpose(2, 0, 1)
            vb = var.reshape(n, -1).T
            yb = spec[:, r0:r1, :].reshape(n, -1).T
            pb = prior.reshape(k, -1).T / reg
            if n >= k:
                aw = np.conj(ab).transpose(0, 2, 1) / vb[:, None, :]  # (B,k,n)
                m = aw @ ab
                idx = np.arange(k)
                m[:, idx, idx] += 1.0 / pb
                sol = _solve_hermitian(m, (aw @ yb[..., None])[..., 0])
            else:
                s = (ab * pb[:, None, :]) @ np.conj(ab).transpose(0, 2, 1)
                idx = np.arange(n)
                s[:, idx, idx] += vb
                z = _solve_hermitian(s, yb)
                sol = pb * (np.conj(ab).transpose(0, 2, 1) @ z[..., None])[..., 0]
            xs[:, :, r0:r1, :] = sol.T.reshape(p, p, r1 - r0, wc)
            res = yb - (ab @ sol[..., None])[..., 0]
            resid_ratio += np.sum(np.abs(res) ** 2 / vb, axis=0)
            wsum += np.sum(np.abs(ab[:, :, 0]) ** 2 / vb, axis=0)

        resid_ratio /= hp * wc
    img = _assemble_hr(xs, hp, wp)
    out = img[p * pad : p * (pad + h), p * pad : p * (pad + w)].astype(np.float64)
    if not keep.all():  # report per input frame; dropped frames: weight 0, shift as given, std inf
        w_full = np.zeros(full_n)
        w_full[keep] = wsum / max(wsum[0], 1e-30)
        sh_full = shifts.astype(np.float64).copy()
        sh_full[keep] = ishift + resid
        sg_full = np.full(full_n, np.inf)
        sg_full[keep] = np.sqrt(np.maximum(cov[:, 0, 0], cov[:, 1, 1]))
        return {
            "image": out,
            "shifts": sh_full,
            "shift_sigma": sg_full,
            "weights": w_full,
            "resid_ratio": None,
            "prior": (c_psd, alpha),
            "noise_sigma": noise_sigma,
            "kept": keep,
        }
    return {
        "kept": keep,
        "image": out,
        "shifts": ishift + resid,
        "shift_sigma": np.sqrt(np.maximum(cov[:, 0, 0], cov[:, 1, 1])),
        "weights": wsum / max(wsum[0], 1e-30),
        "resid_ratio": resid_ratio,
        "prior": (c_psd, alpha),
        "noise_sigma": noise_sigma,
    }


def _assemble_hr(xs: np.ndarray, hp: int, wp: int) -> np.ndarray:
    """HR image from the solved alias components ``xs[m1, m2, ky, kx]`` (LR rfft half).

    HR bin (m1 hp + ky, m2 wp + kx) holds ``xs[m1, m2, ky, kx]``; HR rfft columns whose
    LR bin lies outside the rfft half come from Hermitian symmetry
    ``X[-K] = conj(X[K])``. Inverse real FFT of size (p hp, p wp), single precision
    (float32 result): ``cv2.dft`` on OpenCV's packed (CCS) half spectrum when
    both sizes are even (the half spectrum is written straight into it), else
    ``np.fft.irfft2``.
    """
    p = xs.shape[0]
    wc = xs.shape[3]
    nh, nw = p * hp, p * wp
    nc = nw // 2 + 1  # HR rfft columns
    ccs_path = nh % 2 == 0 and nw % 2 == 0 and nw >= 4
    if ccs_path:
        ccs = np.empty((nh, nw), np.float32)
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
            blk = xs[:, p - 1 - m2, :, cs:ce].reshape(nh, ce - cs)[
                :, ::-1
            ]  # rows K, columns wp - kx
            put(slice(0, 1), lo, hi, blk[:1], conj=True)
            put(slice(1, nh), lo, hi, blk[:0:-1], conj=True)
    if not ccs_path:
        return np.fft.irfft2(half, s=(nh, nw))
    for col, e in (
        (0, edge[0]),
        (nw - 1, edge[1]),
    ):  # CCS packing of the two real-symmetric columns
        ccs[0, col] = e[0].real
        ccs[1 : nh - 1 : 2, col] = e[1 : nh // 2].real
        ccs[2 : nh - 1 : 2, col] = e[1 : nh // 2].imag
        ccs[nh - 1, col] = e[nh // 2].real
    return cv2.dft(ccs, flags=cv2.DFT_INVERSE | cv2.DFT_REAL_OUTPUT | cv2.DFT_SCALE)
