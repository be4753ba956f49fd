"""Super-resolution reconstruction from sub-pixel shifted frames (METHODS.md B).

Main entry point :func:`reconstruct`. Methods:

* ``"map"`` (default): the best linear / MAP estimate of eq. 9 with a
  stationary Gaussian prior, solved in the Fourier domain. For translations
  the observation model (eq. 3 plus optics blur and shift, see
  :func:`subpix_ros.core.superres_model.frame_transfer_1d`) is shift-invariant
  per frame, so the normal equations decouple over LR frequency bins: each
  bin couples only the factor^2 aliased HR frequencies, a factor^2 x factor^2
  (or N x N, eq. 9's own form, whichever is smaller) Hermitian system. Cost
  O(pixels log pixels) — linear in pixel count up to the FFT log. With
  per-frame constant noise (the normal case) each Gram entry of all bins is
  one small-inner-dimension matrix product over frames (the transfer is
  separable in rows and columns), and the systems are solved by a Cholesky
  factorisation vectorised over bins, in single precision
  (:func:`_solve_separable`); the spectra are single-precision FFTs of
  ``cv2.getOptimalDFTSize`` sizes.
  Data-driven settings: shifts are refined against frame 0 by Lucas-Kanade
  on low-passed frames (``refine_shifts``; ~0.003 px on the rendered crops;
  central region only, all frames batched);
  the noise std comes from the residual of that registration (a multi-frame
  estimate texture does not bias); the prior ``S_x(f) = c |f|^-alpha`` is
  fitted to the frames' spectrum through the observation model
  (:func:`fit_spectrum`). Boundaries: every frame is padded with one
  consistent (shifted) extension of the reference.
  Robustness: frames that fail registration or disagree with the reference
  are left out; a registration-error covariance (``shift_cov`` when shifts
  are not refined, or the refinement's own) enters the model as an expected
  transfer ``exp(-2 pi^2 f^T C f)`` plus an extra noise term, so uncertain
  frames stop contributing at high frequencies.
  Geometry beyond translation: with ``homographies`` given, or detected by
  tile registration (``geometry="auto"``, :func:`detect_geometry`, affine
  per frame), or with ``masks``, the same MAP objective is solved by
  conjugate gradients (``"map-cg"``) with the spatial operators of
  :mod:`subpix_ros.core.superres_model` — each frame's geometry inside the
  forward model, the inputs are never resampled — warm-started from the
  Fourier solution.
* ``"windowed"``: eq. 7 (normalised) as one separable filter
  (``cv2.sepFilter2D``) on the interleaved grid, then a Gaussian of
  ``WINDOWED_SMOOTH_LR_PX`` LR px (the Gaussian regularisation eq. 9 turns
  the windowed solution into); needs shifts on the k/p grid (falls back
  otherwise).
* ``"pinv"``: eq. 6, reference only (unstable; O(n^3)).
* ``"bicubic"``: bicubic upscaling of the reference frame (the baseline).

Never knowingly worse than bicubic: no sub-pixel diversity (all frames at
the same sub-pixel phase), no frame registrable to the reference, solver
failure, or shifts off the grid for eqs. 6/7 return the bicubic image with
``fell_back=True`` and a reason. (Frames that agree with each other but whose
common model is wrong — e.g. a much wrong ``blur_sigma`` — are not detected.)

Output grid: LR pixel i of frame 0 covers output pixels factor*i ..
factor*i + factor - 1 (pixel centres aligned as in ``cv2.resize``). The
outermost LR-pixel ring of a MAP result is bicubic (only the reference
observes it; see :func:`_bicubic_rim`).
Intensities keep the input scale (eq. 3 taken as a mean, not a sum).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field
from typing import Sequence

import cv2
import numpy as np

from .superres_model import (
    FrameOperator,
    frame_transfer_1d,
    gaussian_kernel,
    translation_homography,
)
from .superres_paper import grid_offsets, interleave, pinv_solution, windowed_solution

__all__ = [
    "SRResult",
    "reconstruct",
    "detect_geometry",
    "fit_spectrum",
    "reconstruct_colour",
    "bicubic_upscale",
    "estimate_noise_sigma",
    "psnr",
    "METHODS",
    "BLUR_AUTO",
]

METHODS = ("map", "windowed", "pinv", "bicubic")
WINDOWED_SMOOTH_LR_PX = 0.35  # Gaussian std (LR px) applied to the windowed eq. 7 solution
BLUR_AUTO = "auto"  # blur_sigma setting: estimate the blur from the frames (core/blur.py)
MAX_FACTOR = 4


@dataclass
class SRResult:
    """Result of :func:`reconstruct`.

    image: float64, (factor*H, factor*W), same intensity scale as the frames.
    method: the method actually used ("map", "map-cg", "windowed", "pinv",
    "bicubic"). fell_back/reason: True and why when a fallback to bicubic
    happened. noise_sigma: per-pixel noise std used (DN, estimated unless
    given). weights: per-frame relative weight at mid frequency (1 = a frame
    as good as the reference). shifts: the shifts used (refined if
    ``refine_shifts``), shift_sigma: per-frame registration error std (LR px)
    the model assumed. blur_sigma: the optics blur (LR px) the model used,
    blur_source: where it came from ("parameter", "edges", "fallback"),
    blur_reason: a one-line account (see :mod:`subpix_ros.core.blur`).
    """

    image: np.ndarray
    method: str
    fell_back: bool = False
    reason: str = ""
    noise_sigma: float = float("nan")
    weights: np.ndarray = field(default_factory=lambda: np.zeros(0))
    shifts: np.ndarray = field(default_factory=lambda: np.zeros((0, 2)))
    shift_sigma: np.ndarray = field(default_factory=lambda: np.zeros(0))
    factor: int = 1
    blur_sigma: float = float("nan")
    blur_source: str = ""
    blur_reason: str = ""


def psnr(image: np.ndarray, truth: np.ndarray, border: int = 0, peak: float = 255.0) -> float:
    """PSNR (dB) = 10 log10(peak^2 / MSE), over the interior (``border`` pixels cut)."""
    a = np.asarray(image, dtype=np.float64)
    b = np.asarray(truth, dtype=np.float64)
    if border:
        a, b = a[border:-border, border:-border], b[border:-border, border:-border]
    mse = float(np.mean((a - b) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(peak**2 / mse)


def bicubic_upscale(frame: np.ndarray, factor: int) -> np.ndarray:
    """Bicubic upscaling of one frame onto the project's output grid (float64)."""
    f = np.asarray(frame, dtype=np.float64)
    return cv2.resize(f, (f.shape[1] * factor, f.shape[0] * factor), interpolation=cv2.INTER_CUBIC)


def estimate_noise_sigma(frame: np.ndarray, max_size: int | None = None) -> float:
    """Per-pixel noise std (DN) of one frame, robust Immerkaer estimate.

    The frame is filtered with ``N = [[1,-2,1],[-2,4,-2],[1,-2,1]]`` (a
    difference of two Laplacians that removes planes and most smooth image
    content; for white noise ``std(I*N) = 6 sigma``) and
    ``sigma = 1.4826 median(|I*N|) / 6``. Texture left in ``I*N`` biases it
    upwards; quantisation noise (1/sqrt(12) DN for 8 bit) is included.
    ``max_size``: use only the central max_size x max_size region.
    """
    f = np.asarray(frame)
    if f.ndim != 2 or min(f.shape) < 3:
        raise ValueError("noise estimate needs a 2-D frame of at least 3x3")
    if max_size is not None and max(f.shape) > max_size:  # central crop: bounded cost
        r0, c0 = max(0, (f.shape[0] - max_size) // 2), max(0, (f.shape[1] - max_size) // 2)
        f = f[r0 : r0 + max_size, c0 : c0 + max_size]
    k = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], dtype=np.float64)
    if f.dtype == np.uint8:
        # 8-bit: I*N is an integer in [-4080, 4080], exact in int16; its median |I*N| from a histogram
        # (one pass instead of a partition; the same value, the mean of the two middle ones for even counts)
        r = np.abs(cv2.filter2D(np.ascontiguousarray(f), cv2.CV_16S, k)[1:-1, 1:-1]).ravel()
        return float(1.4826 * _median_of_small_ints(r) / 6.0)
    f = np.asarray(f, dtype=np.float64)
    r = cv2.filter2D(f, cv2.CV_64F, k)[1:-1, 1:-1]
    return float(1.4826 * np.median(np.abs(r)) / 6.0)


def _median_of_small_ints(v: np.ndarray) -> float:
    """``np.median(v)`` of non-negative small integers by a histogram (exact)."""
    counts = np.cumsum(np.bincount(v))
    n = v.size
    hi = int(np.searchsorted(counts, n // 2, side="right"))  # the element at sorted index n // 2
    if n % 2:
        return float(hi)
    lo = int(np.searchsorted(counts, n // 2 - 1, side="right"))  # sorted index n // 2 - 1
    return (lo + hi) / 2.0


# --------------------------------------------------------------------------- helpers


def _integer_preshift(frame: np.ndarray, iu: int, iv: int) -> np.ndarray:
    """``out[i, j] = frame[i + iu, j + iv]`` with reflected borders (integer part of a shift)."""
    if iu == 0 and iv == 0:
        return frame
    h, w = frame.shape
    pu, pv = abs(iu), abs(iv)
    padded = cv2.copyMakeBorder(frame, pu, pu, pv, pv, cv2.BORDER_REFLECT_101)
    return padded[pu + iu : pu + iu + h, pv + iv : pv + iv + w]


_SPECTRUM_CROP = 384  # fit_spectrum's default crop (LR px)


def _preshift_window(
    frame: np.ndarray, iu: int, iv: int, r0: int, r1: int, c0: int, c1: int
) -> np.ndarray:
    """``_integer_preshift(frame, iu, iv)[r0:r1, c0:c1]`` without shifting the whole frame.

    A plain slice when the window's source ``[r0+iu, r1+iu) x [c0+iv, c1+iv)``
    lies inside the frame; otherwise the reflected full preshift is cut.
    """
    h, w = frame.shape
    if 0 <= r0 + iu and r1 + iu <= h and 0 <= c0 + iv and c1 + iv <= w:
        return frame[r0 + iu : r1 + iu, c0 + iv : c1 + iv]
    return _integer_preshift(frame, iu, iv)[r0:r1, c0:c1]


def fit_spectrum(
    frames: np.ndarray,
    p: int,
    blur_sigma: float,
    noise_sigma: float | None = None,
    max_bins: int = 8000,
    crop: int = _SPECTRUM_CROP,
) -> tuple[float, float, float]:
    """Fit the stationary prior and the noise floor to the frames' power spectrum.

    Model (per-pixel PSD units, f in cycles / HR px, nu in cycles / LR px):

        E S_y(nu) = p^2 sum_m |a_m(nu)|^2 c |f_m|^-alpha + sigma^2

    — the HR scene's power law ``S_x(f) = c |f|^-alpha`` seen through the
    observation model (eq. 3 with blur, aliased over the p^2 components m,
    ``a_m`` from :func:`frame_transfer_1d`) plus white noise ``sigma^2``.
    ``S_y`` is the Tukey-windowed periodogram of the central ``crop`` x ``crop``
    region averaged over (up to) the first two frames. For each
    alpha, (c, sigma^2) solve a weighted linear least squares (weights
    1/model^2: a periodogram's std equals its mean; 3 reweighting passes);
    the alpha with the least relative misfit wins, searched on a 0.3 grid in
    [1, 4] and then on the 0.1 grid within +-0.2 of the coarse winner (16
    exponents fitted instead of 31; each stage's exponents at once, arrays
    exponents x bins). With
    ``noise_sigma`` given, only c and alpha are fitted. Uses up to
    ``max_bins`` frequency bins (fixed subsample) above 0.03 cycles/LR px.
    Returns ``(c, alpha, sigma)``; sigma in DN, c in DN^2 (HR px units).
    """
    _, h0, w0 = frames.shape
    h, w = min(h0, crop), min(w0, crop)
    sub = frames[:2, (h0 - h) // 2 : (h0 - h) // 2 + h, (w0 - w) // 2 : (w0 - w) // 2 + w]
    win = _tukey2(h, w)
    psd = np.zeros((h, w // 2 + 1))
    for f in sub:  # (up to) two frames: mean removed, windowed, single precision
        x = np.asarray(f, dtype=np.float32)
        x = (x - np.float32(x.mean(dtype=np.float64))) * win
        psd += np.abs(_rfft2_32(x)) ** 2
    psd /= len(sub) * float(np.sum(np.square(win, dtype=np.float64)))
    sel, amp, logf = _spectrum_model(h, w, p, float(blur_sigma), max_bins)
    obs = psd.ravel()[sel]
    # coarse search on a 0.3 grid, then the 0.1 grid within +-0.2 of the coarse best (misfit is smooth
    # and single-minimum in alpha on real scenes: the test compares with the full 0.1 grid)
    key = (h, w, p, float(blur_sigma), max_bins)
    coarse = _fit_exponents(
        1.0, 0.3, 11, amp, logf, obs, noise_sigma, *_exponent_terms(*key, 1.0, 0.3, 11)
    )
    a_best = coarse[1]
    lo = max(1.0, a_best - 0.2)
    n_fine = int(round((min(4.0, a_best + 0.2) - lo) / 0.1)) + 1
    c, alpha, s2, _ = _fit_exponents(
        lo,
        0.1,
        n_fine,
        amp,
        logf,
        obs,
        noise_sigma,
        *_exponent_terms(*key, round(lo, 10), 0.1, n_fine),
    )
    return float(c), float(alpha), float(np.sqrt(s2))


def _fit_exponents(
    a0: float,
    da: float,
    count: int,
    amp: np.ndarray,
    logf: np.ndarray,
    obs: np.ndarray,
    noise_sigma: float | None,
    q: np.ndarray | None = None,
    q2: np.ndarray | None = None,
) -> tuple[float, float, float, float]:
    """:func:`fit_spectrum`'s fit for the exponents ``a0 + da j``, j < count, at once.

    ``q[j] = sum_m amp_m |f_m|^-alpha_j`` by the recurrence
    ``|f|^-(alpha + da) = |f|^-alpha |f|^-da`` (no loop over bins); per exponent
    (c, sigma^2) by 3 passes of weighted least squares (weights 1/model^2).
    ``q`` (count, bins) and ``q2 = q^2``: those sums if already known (:func:`_exponent_terms`).
    Each pass's weighted sums are ``sum_b w q^2``, ``sum_b w q``, ``sum_b w q S_y``: matrix-vector
    products in the first pass (one weight vector for all exponents), row-wise dot products after.
    Returns (c, alpha, sigma^2, relative misfit) of the best exponent.
    """
    alphas = a0 + da * np.arange(count)
    if q is None:
        q = _exponent_sums(a0, da, count, amp, logf)
    if q2 is None:
        q2 = q * q
    qy = q * obs
    w0 = 1.0 / np.maximum(obs, 1e-12) ** 2
    wgt = None  # first pass: the same weights 1/obs^2 for every exponent (matrix-vector products)
    model = np.empty_like(q)
    for it in range(3):  # reweighting passes, all exponents at once
        if wgt is None:
            s_qq, s_q, s_qy = q2 @ w0, q @ w0, qy @ w0
        else:
            s_qq, s_q, s_qy = (np.einsum("ab,ab->a", wgt, t) for t in (q2, q, qy))
        if noise_sigma is None:
            ata = np.empty((count, 2, 2))
            ata[:, 0, 0] = s_qq
            ata[:, 0, 1] = ata[:, 1, 0] = s_q
            ata[:, 1, 1] = w0.sum() if wgt is None else wgt.sum(axis=1)
            rhs = np.stack([s_qy, np.full(count, w0 @ obs) if wgt is None else wgt @ obs], axis=1)
            sol = np.linalg.solve(ata, rhs[..., None])[..., 0]
            c_, s2 = sol[:, 0], np.maximum(sol[:, 1], 1e-6)
        else:
            s2 = np.full(count, noise_sigma**2)
            c_ = (s_qy - s2 * s_q) / s_qq
        c_ = np.maximum(c_, 1e-12)
        np.multiply(q, c_[:, None], out=model)
        model += s2[:, None]
        if it < 2:  # the next pass's weights
            wgt = np.square(model, out=wgt)
            np.divide(1.0, wgt, out=wgt)
    rel = np.subtract(obs, model)
    rel /= model
    err = np.einsum("ab,ab->a", rel, rel) / obs.size
    best = int(np.argmin(err))
    return float(c_[best]), float(alphas[best]), float(s2[best]), float(err[best])


def _exponent_sums(
    a0: float, da: float, count: int, amp: np.ndarray, logf: np.ndarray
) -> np.ndarray:
    """``q[j] = sum_m amp_m |f_m|^-(a0 + da j)`` (count, bins) by the recurrence of :func:`_fit_exponents`."""
    step = np.exp(-da * logf)
    term = amp * np.exp(-a0 * logf)
    q = np.empty((count, amp.shape[1]))
    for a in range(count):  # exponents, not bins
        q[a] = term.sum(axis=0)
        term *= step
    return q


@functools.lru_cache(maxsize=64)
def _exponent_terms(
    h: int, w: int, p: int, blur_sigma: float, max_bins: int, a0: float, da: float, count: int
) -> tuple[np.ndarray, np.ndarray]:
    """``(q, q^2)`` of :func:`_exponent_sums` on :func:`_spectrum_model`'s terms: they depend only on the crop
    shape, factor, blur and exponents, so they are cached (read-only; the fine search has one table per coarse
    winner)."""
    _, amp, logf = _spectrum_model(h, w, p, blur_sigma, max_bins)
    q = _exponent_sums(a0, da, count, amp, logf)
    q2 = q * q
    q.flags.writeable = False
    q2.flags.writeable = False
    return q, q2


@functools.lru_cache(maxsize=16)
def _spectrum_bins(h: int, w: int, max_bins: int) -> np.ndarray:
    """Flat indices (into the h x (w//2+1) rfft half) of the bins :func:`fit_spectrum` uses.

    Bins above 0.03 cycles / LR px; a fixed random subsample (seed 0) of
    ``max_bins`` of them if there are more. Cached per shape (read-only).
    """
    nuy = np.fft.fftfreq(h)[:, None]
    nux = np.fft.rfftfreq(w)[None, :]
    sel = np.flatnonzero((np.hypot(nuy, nux) > 0.03).ravel())
    if sel.size < 100:
        raise ValueError("frames too small to fit the image prior")
    if sel.size > max_bins:
        sel = np.sort(np.random.default_rng(0).choice(sel, max_bins, replace=False))
    sel.flags.writeable = False
    return sel


@functools.lru_cache(maxsize=16)
def _spectrum_model(
    h: int, w: int, p: int, blur_sigma: float, max_bins: int
) -> tuple[np.ndarray, ...]:
    """:func:`fit_spectrum`'s bins and model terms for an h x w crop (cached per shape, read-only).

    Returns the flat bin indices ``sel`` (:func:`_spectrum_bins`), ``amp[m] = p^2 |a_m|^2`` and
    ``log |f_m|`` (p^2, bins) of the p^2 aliases m at those bins.
    """
    ay, fy = frame_transfer_1d(h, p, 0.0, blur_sigma)
    ax, fx = frame_transfer_1d(w, p, 0.0, blur_sigma)
    wc = w // 2 + 1
    ax, fx = ax[:, :wc], fx[:, :wc]
    sel = _spectrum_bins(h, w, max_bins)
    ky, kx = np.unravel_index(sel, (h, wc))
    amp = np.ascontiguousarray(
        (np.abs(ay[:, None, ky] * ax[None, :, kx]) ** 2).reshape(p * p, -1) * p * p
    )
    fm = np.hypot(fy[:, None, ky], fx[None, :, kx]).reshape(p * p, -1)
    logf = np.ascontiguousarray(np.log(np.maximum(fm, 1e-9)))  # (p^2, bins), C order for the sums
    for a in (amp, logf):
        a.flags.writeable = False
    return sel, amp, logf


@functools.lru_cache(maxsize=16)
def _tukey2(h: int, w: int) -> np.ndarray:
    """2-D Tukey window ``outer(_tukey(h), _tukey(w))`` (float32, cached, read-only)."""
    win = np.outer(_tukey(h), _tukey(w)).astype(np.float32)
    win.flags.writeable = False
    return win


def _solve_hermitian(m: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Batched solve of Hermitian positive-definite systems ``m x = b`` (..., k, k)."""
    return np.linalg.solve(m, b[..., None])[..., 0]


def _lowpass_window(
    frame: np.ndarray,
    g: np.ndarray,
    pre: tuple[int, int],
    post: tuple[int, int],
    rows: slice,
    cols: slice,
    whole: np.ndarray | None = None,
) -> np.ndarray:
    """``_integer_preshift(L, *post)[rows, cols]`` with ``L = lowpass(_integer_preshift(frame, *pre))``.

    The low-pass is ``cv2.sepFilter2D`` with the symmetric kernel ``g`` on
    both axes (reflected border). Only the window plus the kernel's radius
    is filtered whenever the window's source lies inside the frame (then the
    values equal those of filtering the whole frame exactly: the margin holds
    real pixels, or the frame's own edge where the window touches it);
    otherwise the whole frame is filtered. float64. ``whole``: the whole
    frame already low-passed (``sepFilter2D(frame, g, g)``, see
    :class:`_WholeLowpass`); the window is then a slice of it whenever the
    window's source lies inside the frame (the same values).
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
                frame[a0:a1, b0:b1], cv2.CV_64F, g, g, borderType=cv2.BORDER_REFLECT_101
            )
            return sub[r0 - a0 : r1 - a0, c0 - b0 : c1 - b0]
        a0, a1, b0, b1 = r0 + pre[0] - r, r1 + pre[0] + r, c0 + pre[1] - r, c1 + pre[1] + r
        if (
            0 <= a0 and a1 <= h and 0 <= b0 and b1 <= w
        ):  # pre-shift and margin inside: interior values only
            if whole is not None:
                return whole[a0 + r : a1 - r, b0 + r : b1 - r]
            sub = cv2.sepFilter2D(
                frame[a0:a1, b0:b1], cv2.CV_64F, g, g, borderType=cv2.BORDER_REFLECT_101
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
        # L is the whole low-pass: the window's part inside the frame, reflected about the frame's edges
        # where the window leaves it (the part touches those edges, so reflecting it is reflecting L)
        sub = whole[max(r0, 0) : min(r1, h), max(c0, 0) : min(c1, w)]
        return cv2.copyMakeBorder(
            sub, max(-r0, 0), max(r1 - h, 0), max(-c0, 0), max(c1 - w, 0), cv2.BORDER_REFLECT_101
        )
    low = cv2.sepFilter2D(
        _integer_preshift(frame, *pre), cv2.CV_64F, g, g, borderType=cv2.BORDER_REFLECT_101
    )
    return _integer_preshift(low, *post)[rows, cols]


_WHOLE_LOWPASS_PX = (
    512 * 512
)  # frames up to this size are low-passed whole once (see _WholeLowpass)


class _WholeLowpass:
    """Whole-frame low-passes ``sepFilter2D(frames[i], g, g)`` (reflected border, single precision), computed once
    per frame.

    The tile registration (:func:`detect_geometry`) and the shift refinement
    (:func:`_refine_shifts`) read many overlapping low-passed windows of the
    same frames, several per frame at different integer shifts; for small
    frames one filter pass over each whole frame, sliced by
    :func:`_lowpass_window`, costs less than filtering every window (the
    same values to single-precision round-off: the registration transforms
    and sums are single precision anyway). ``get(i)`` is None for frames larger than
    ``_WHOLE_LOWPASS_PX`` (their windows are filtered as before: bounded cost).
    """

    def __init__(self, frames: np.ndarray, lp_sigma: float = 1.0) -> None:
        self.frames = frames
        self.lp_sigma = float(lp_sigma)
        self.g = gaussian_kernel(lp_sigma).astype(np.float32)
        self.enabled = frames.shape[1] * frames.shape[2] <= _WHOLE_LOWPASS_PX
        self._done: dict[int, np.ndarray] = {}

    def get(self, i: int, lp_sigma: float) -> np.ndarray | None:
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
        """``i -> lowpassed.get(i, lp_sigma)``, or always None without a shared low-pass."""
        if lowpassed is None:
            return lambda i: None
        return lambda i: lowpassed.get(i, lp_sigma)


def _refine_shifts(
    frames: np.ndarray,
    ishift: np.ndarray,
    resid: np.ndarray,
    lp_sigma: float = 1.0,
    border: int = 8,
    iters: int = 3,
    max_region: int = 256,
    lowpassed: _WholeLowpass | None = None,
) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    """Refine each frame's sub-pixel shift against frame 0 (Lucas-Kanade on low-passed frames).

    Both frames are low-passed (Gaussian, ``lp_sigma`` LR px) so the fit uses
    the band where aliasing is weak. With ``R`` the low-passed reference
    moved by the current shift ``s`` (Fourier shift, content moves by +s),
    the first-order model ``F ~ R - d . grad R`` gives the Gauss-Newton step
    ``d = -(G^T G)^-1 G^T (F - R)`` over the central region (at most
    ``max_region`` px square, ``border`` px from the edges: cost bounded; only
    that region, with its context, is low-passed and Fourier-shifted).
    Returns refined residual shifts (N, 2), each one's std (LR px) from
    ``var(residual) (G^T G)^-1``, and the per-pixel noise std (DN) implied by
    the residual: ``var(F - R) = 2 sigma^2 (sum g^2)^2`` for white noise
    through the separable low-pass g (median over frames) — a multi-frame
    noise estimate that texture does not bias, unlike single-frame ones —
    and the per-frame noise variances themselves (NaN for frame 0). Frames whose fit diverges (|step| > 0.5 px)
    keep their shift and get std = inf.
    """
    n, h, w = frames.shape
    g = gaussian_kernel(lp_sigma)
    out = resid.copy()
    sig = np.zeros(n)
    resvar = np.full(n, np.nan)
    rh, rw = min(h - 2 * border, max_region), min(w - 2 * border, max_region)
    region = (slice((h - rh) // 2, (h - rh) // 2 + rh), slice((w - rw) // 2, (w - rw) // 2 + rw))
    ctx = _lk_context(region, h, w)
    i0 = (int(ishift[0, 0]), int(ishift[0, 1]))
    whole = _WholeLowpass.getter(lowpassed, lp_sigma)
    ref = _lowpass_window(frames[0], g, i0, (0, 0), *ctx, whole=whole(0))

    def mov_window(i: int, iu: int, iv: int) -> np.ndarray:
        return _lowpass_window(
            frames[i], g, (int(ishift[i, 0]), int(ishift[i, 1])), (iu, iv), *ctx, whole=whole(i)
        )

    if n > 1:  # all frames against the reference at once
        s_all, sg_all, rv_all = _lk_batch(
            [ref],
            np.zeros(n - 1, dtype=int),
            mov_window,
            np.arange(1, n),
            resid[1:],
            _lk_inner(region, ctx),
            g,
            iters=iters,
        )
        for i in range(1, n):  # per frame: accept or flag
            s, sg, rv = s_all[i - 1], sg_all[i - 1], rv_all[i - 1]
            if np.isfinite(sg) and np.abs(s - resid[i]).max() < 0.5:
                out[i], sig[i], resvar[i] = s, sg, rv
            else:
                sig[i] = np.inf
    noise = float(np.sqrt(np.nanmedian(resvar))) if np.isfinite(resvar).any() else float("nan")
    return out, sig, noise, resvar


def detect_geometry(
    frames: np.ndarray,
    shifts: np.ndarray,
    tiles: int = 3,
    lp_sigma: float = 1.0,
    tol: float = 0.05,
    tile_max: int = 64,
    lowpassed: _WholeLowpass | None = None,
) -> tuple[np.ndarray | None, np.ndarray, float]:
    """Check whether frames are related by more than a translation; fit affines if so.

    Each frame is registered to frame 0 in ``tiles x tiles`` tiles (Lucas-
    Kanade on low-passed frames, started from ``shifts``, over one window
    shape for all tiles — the smallest tile, at most ``tile_max`` px square —
    at each tile's centre, moved inwards where its 16 px context would leave
    the frame, so all tiles and frames are registered in one batch; only
    those windows are low-passed, and each reference tile is Fourier-
    transformed once for all frames); the tile shifts
    ``d(r, c)`` (at the window centres) are fitted by
    ``d = s + J (r - r0, c - c0)`` (least squares, (r0, c0) the frame centre). If the
    non-translational part ``J`` moves any
    tile centre by more than ``tol`` LR px, the affine of every frame is
    returned as a homography (reference -> frame LR pixel coordinates, as
    :class:`FrameOperator` takes them), else None. Also returns the tile
    shifts (N, tiles^2, 2) and the multi-frame noise estimate (DN): from
    the lower quartile of the tiles' residual variances (the tiles a local
    translation fits best; rotation inflates the others).
    """
    n, h, w = frames.shape
    g = gaussian_kernel(lp_sigma)
    whole = _WholeLowpass.getter(lowpassed, lp_sigma)
    ty = np.linspace(0, h, tiles + 1).astype(int)
    tx = np.linspace(0, w, tiles + 1).astype(int)
    ctx_pad = 16  # _lk_context's default
    # one window shape for all tiles (the smallest tile, at most tile_max), each window moved inwards
    # where needed so that its context lies inside the frame: all tiles x frames form one batch
    ha, wa = min(int(np.diff(ty).min()), tile_max), min(int(np.diff(tx).min()), tile_max)
    wins = []
    for a in range(tiles):  # tiles, not pixels
        for b in range(tiles):
            ra, ca = (ty[a] + ty[a + 1] - ha) // 2, (tx[b] + tx[b + 1] - wa) // 2
            if h >= ha + 2 * ctx_pad:
                ra = min(max(ra, ctx_pad), h - ctx_pad - ha)
            if w >= wa + 2 * ctx_pad:
                ca = min(max(ca, ctx_pad), w - ctx_pad - wa)
            wins.append((slice(ra, ra + ha), slice(ca, ca + wa)))
    centres = np.array(
        [
            ((sl[0].start + sl[0].stop - 1) / 2.0, (sl[1].start + sl[1].stop - 1) / 2.0)
            for sl in wins
        ]
    )
    r0, c0 = (h - 1) / 2.0, (w - 1) / 2.0
    rel = centres - np.array([r0, c0])
    design = np.concatenate([np.ones((len(rel), 1)), rel], axis=1)  # (T, 3)
    tshift = np.zeros((n, len(rel), 2))
    resvar_t = np.full((n, len(rel)), np.nan)
    groups: dict[tuple, list[tuple[int, tuple[slice, slice]]]] = {}
    for k, sl in enumerate(wins):  # tiles
        ctx = _lk_context(sl, h, w, ctx_pad)
        inner = _lk_inner(sl, ctx)
        key = (
            ctx[0].stop - ctx[0].start,
            ctx[1].stop - ctx[1].start,
            inner[0].start,
            inner[0].stop,
            inner[1].start,
            inner[1].stop,
        )
        groups.setdefault(key, []).append((k, ctx))
    for (
        key,
        members,
    ) in groups.items():  # tiles whose windows have one shape: all tiles x frames at once
        refs = [
            _lowpass_window(frames[0], g, (0, 0), (0, 0), *ctx, whole=whole(0))
            for _, ctx in members
        ]
        pair_tile = np.repeat(np.arange(len(members)), n - 1)
        pair_frame = np.tile(np.arange(1, n), len(members))
        ctxs = [ctx for _, ctx in members]

        def mov_window(m: int, iu: int, iv: int) -> np.ndarray:
            i = int(pair_frame[m])
            return _lowpass_window(
                frames[i], g, (0, 0), (iu, iv), *ctxs[pair_tile[m]], whole=whole(i)
            )

        s0 = np.asarray(shifts, dtype=np.float64)[pair_frame]
        inner = (slice(key[2], key[3]), slice(key[4], key[5]))
        s_all, sg_all, rv_all = _lk_batch(
            refs, pair_tile, mov_window, np.arange(pair_tile.size), s0, inner, g
        )
        for m in range(pair_tile.size):  # tile x frame pairs
            kk, i = members[pair_tile[m]][0], pair_frame[m]
            tshift[i, kk] = s_all[m] if np.isfinite(sg_all[m]) else np.nan
            resvar_t[i, kk] = rv_all[m]
    # residual variances in the order the frames and tiles were visited before (frame-major)
    resvars = [v for v in resvar_t[1:].ravel() if np.isfinite(v)]
    nonlinear = False
    affines = np.zeros((n, 3, 3))
    affines[0] = np.eye(3)
    for i in range(1, n):  # loop over frames
        ok = np.isfinite(tshift[i, :, 0])
        if ok.sum() < 4:
            affines[i] = translation_homography(*shifts[i])
            continue
        coef, *_ = np.linalg.lstsq(design[ok], tshift[i, ok], rcond=None)  # (3, 2): s, then J rows
        s = coef[0]
        jac = coef[1:].T  # jac[out, in]: d(u, v) / d(r, c)
        if np.max(np.abs(rel @ jac.T)) > tol:
            nonlinear = True
        affines[i] = np.array(
            [
                [1 + jac[1, 1], jac[1, 0], s[1] - jac[1, 0] * r0 - jac[1, 1] * c0],
                [jac[0, 1], 1 + jac[0, 0], s[0] - jac[0, 0] * r0 - jac[0, 1] * c0],
                [0.0, 0.0, 1.0],
            ]
        )
    noise = float(np.sqrt(np.percentile(resvars, 25))) if resvars else float("nan")
    return (affines if nonlinear else None), tshift, noise


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


def _rfft2_32(img: np.ndarray) -> np.ndarray:
    """Half-plane 2-D DFT (as ``np.fft.rfft2``) in single precision via ``cv2.dft``."""
    f = cv2.dft(np.ascontiguousarray(img, dtype=np.float32), flags=cv2.DFT_COMPLEX_OUTPUT)
    return f.view(np.complex64)[..., 0][:, : img.shape[1] // 2 + 1]


def _tukey(n: int, frac: float = 0.25) -> np.ndarray:
    """Tukey (tapered cosine) window of length n, ``frac`` of it tapered."""
    t = np.ones(n)
    m = max(1, int(frac * n / 2))
    ramp = 0.5 * (1 - np.cos(np.pi * (np.arange(m) + 0.5) / m))
    t[:m] = ramp
    t[-m:] = ramp[::-1]
    return t


def _solve_separable(
    spec: np.ndarray,
    ay: np.ndarray,
    ax: np.ndarray,
    fy: np.ndarray,
    fx: np.ndarray,
    c: float,
    alpha: float,
    reg: float,
    noise_power: float,
    block_bins: int = 1 << 16,
    shifts: np.ndarray | None = None,
) -> np.ndarray:
    """Per-bin MAP solve (eq. 9, normal-equation form) when every frame's noise variance is frequency-independent.

    Normal equations per LR bin (k = p^2 aliases m = (m1, m2)):
    ``(A^H A / v + reg diag(|f_m|^alpha / c)) X = A^H Y / v`` with
    ``a_nm = ay[n, m1] ax[n, m2]`` (DC, alias (0, 0) at bin (0, 0), unregularised).
    Because ``a`` is separable, each Gram entry is a rank-N product of a row
    factor and a column factor,
    ``G[m, m'](ky, kx) = sum_n (conj(ay[n,m1]) ay[n,m1'])(ky) (conj(ax[n,m2]) ax[n,m2'])(kx)``,
    i.e. a (rows x N) @ (N x wc) matrix product: only the k (k+1) / 2
    lower-triangle entries are formed, one ``cv2.gemm`` (complex, single
    precision) per row-factor pair (m1, m1'). The right-hand side
    ``A^H Y / v`` is ``sum_n conj(ay[n,m1]) (conj(ax[n,m2]) Y_n)``: the column
    factor applied elementwise, the row factor and the sum over frames as a
    batched (p x N) @ (N x p wc) product per spectrum row. The k x k Hermitian
    systems are solved by a Cholesky factorisation ``L L^H`` vectorised over
    bins (loops over the k x k matrix indices only, in-place updates).

    With ``shifts`` (N, 2), the fractional shifts (LR px) that ``ay``/``ax``
    were built with (``frame_transfer_1d``: ``a[n, m] = h[m] exp(-2 pi i f_m p s_n)``),
    the Gram entries collapse to rank one: the frame-dependent factor
    ``conj(a[n, m]) a[n, m'] / (h-part) = exp(2 pi i (f_m - f_m') p s_n)`` depends
    on the bin only through ``p (f_m - f_m')``, an integer class (one value per
    alias pair for even p, two for odd p), so
    ``G[m, m'](ky, kx) = gy(ky) gx(kx) T[cls_y(ky), cls_x(kx)]`` with the small table
    ``T[cy, cx] = sum_n exp(2 pi i (cy u_n + cx v_n)) / v`` — an outer product
    instead of a rank-N matrix product (the same values to round-off).
    The spectrum is processed in blocks of whole rows of about ``block_bins``
    bins, so the working arrays stay in cache. complex64 / float32
    throughout. Returns X (p, p, hp, wc) complex64.
    """
    n, p, hp = ay.shape
    wc = ax.shape[2]
    xs = np.empty((p, p, hp, wc), np.complex64)
    rows = max(1, min(hp, block_bins // max(wc, 1)))
    ay32 = ay.astype(np.complex64)
    ax32 = ax.astype(np.complex64)
    cay = np.conj(ay32) * np.float32(1.0 / noise_power)  # 1/v folded into the row factors
    cax = np.conj(ax32)
    if shifts is None:
        # column factors of the Gram entries, lower triangle i >= j (i = (a1, a2), j = (b1, b2)), grouped by (a1, b1)
        col_fac = {}
        for a1 in range(p):
            for b1 in range(a1 + 1):
                cols = [
                    (a2, b2) for a2 in range(p) for b2 in range(p) if a1 * p + a2 >= b1 * p + b2
                ]
                w = np.concatenate(
                    [cax[:, a2] * ax32[:, b2] for a2, b2 in cols], axis=1
                )  # (n, len(cols) wc)
                col_fac[a1, b1] = (cols, _as_c2(w))
    else:
        col_fac = _rank_one_gram_factors(
            ay, ax, fy, fx, np.asarray(shifts, dtype=np.float64), noise_power
        )
    lam_cols = [
        (fy[m1].astype(np.float64) ** 2, fx[m2].astype(np.float64) ** 2)
        for m1 in range(p)
        for m2 in range(p)
    ]
    for r0 in range(0, hp, rows):  # blocks of spectrum rows (cache), not pixels
        r1 = min(hp, r0 + rows)
        _solve_separable_block(
            spec[:, r0:r1],
            ay32[:, :, r0:r1],
            cay[:, :, r0:r1],
            cax,
            col_fac,
            lam_cols,
            r0,
            r1,
            alpha,
            np.float32(reg / c),
            xs[:, :, r0:r1],
        )
    return xs


@dataclass
class _RankOneGram:
    """Rank-one Gram entries of :func:`_solve_separable`: ``entries[i, j] = (gy, cls_y, gx, cls_x, T)``."""

    entries: dict


def _alias_classes(f: np.ndarray, p: int, m: int, mp: int) -> tuple[np.ndarray, np.ndarray]:
    """Integer classes ``p (f[m] - f[mp])`` per bin, as (distinct values, index of each bin's value).

    ``f`` is a frequency table (:func:`frame_transfer_1d`'s, a function of its length and p only):
    the classes are cached per table content and (p, m, mp), read-only.
    """
    f = np.ascontiguousarray(f, dtype=np.float64)
    return _alias_classes_cached(f.tobytes(), f.shape, p, m, mp)


@functools.lru_cache(maxsize=256)
def _alias_classes_cached(
    fb: bytes, shape: tuple, p: int, m: int, mp: int
) -> tuple[np.ndarray, np.ndarray]:
    f = np.frombuffer(fb, dtype=np.float64).reshape(shape)
    d = np.rint(p * (f[m] - f[mp])).astype(np.int64)
    vals, inv = np.unique(d, return_inverse=True)
    inv = inv.ravel()
    vals.flags.writeable = False
    inv.flags.writeable = False
    return vals, inv


def _rank_one_gram_factors(
    ay: np.ndarray,
    ax: np.ndarray,
    fy: np.ndarray,
    fx: np.ndarray,
    shifts: np.ndarray,
    noise_power: float,
) -> _RankOneGram:
    """Factors of the rank-one Gram entries (lower triangle) for :func:`_solve_separable` with ``shifts``."""
    p = ay.shape[1]
    u, v = shifts[:, 0], shifts[:, 1]
    # shift-free transfers h[m] = a[0, m] exp(+2 pi i f_m p s_0) (frame 0's phase removed)
    hy = ay[0] * np.exp(2j * np.pi * fy * p * u[0])
    hx = ax[0] * np.exp(2j * np.pi * fx * p * v[0])
    entries = {}
    for a1 in range(p):
        for a2 in range(p):
            for b1 in range(p):
                for b2 in range(p):
                    i, j = a1 * p + a2, b1 * p + b2
                    if i < j:
                        continue
                    vy, cy = _alias_classes(fy, p, a1, b1)
                    vx, cx = _alias_classes(fx, p, a2, b2)
                    table = (
                        np.exp(2j * np.pi * (vy[:, None, None] * u + vx[None, :, None] * v)).sum(
                            axis=2
                        )
                        / noise_power
                    )
                    entries[i, j] = (
                        (np.conj(hy[a1]) * hy[b1]).astype(np.complex64),
                        cy,
                        (np.conj(hx[a2]) * hx[b2]).astype(np.complex64),
                        cx,
                        table.astype(np.complex64),
                    )
    return _RankOneGram(entries)


def _as_c2(z: np.ndarray) -> np.ndarray:
    """complex64 array -> 2-channel float32 view (OpenCV's complex matrices)."""
    z = np.ascontiguousarray(z, dtype=np.complex64)
    return z.view(np.float32).reshape(z.shape + (2,))


def _solve_separable_block(
    spec: np.ndarray,
    ay32: np.ndarray,
    cay: np.ndarray,
    cax: np.ndarray,
    col_fac: dict,
    lam_cols: list,
    r0: int,
    r1: int,
    alpha: float,
    lam_scale: np.float32,
    out: np.ndarray,
) -> None:
    """Rows r0..r1 of :func:`_solve_separable` (same arrays, cut to the block); writes ``out`` (p, p, R, wc)."""
    n, p, nr = ay32.shape
    wc = cax.shape[2]
    k = p * p
    idx = [(m1, m2) for m1 in range(p) for m2 in range(p)]
    gram: dict[tuple[int, int], np.ndarray] = {}
    if isinstance(col_fac, _RankOneGram):  # rank-one entries: outer products (see _solve_separable)
        for (i, j), (gy, cy, gx, cx, table) in col_fac.entries.items():
            gyb, cyb = gy[r0:r1], cy[r0:r1]
            if table.size == 1:
                gram[i, j] = np.multiply.outer(gyb * table[0, 0], gx)
            else:
                gram[i, j] = np.multiply.outer(gyb, gx) * table[cyb][:, cx]
    else:
        for (a1, b1), (cols, w2) in col_fac.items():  # Gram: one product per row-factor pair
            u = (cay[:, a1] * ay32[:, b1]).T  # (R, n)
            prod = cv2.gemm(_as_c2(u), w2, 1.0, None, 0.0).view(np.complex64)[..., 0]
            for q, (a2, b2) in enumerate(cols):
                gram[a1 * p + a2, b1 * p + b2] = prod[:, q * wc : (q + 1) * wc]
    # right-hand side b[m1, m2] = sum_n cay[n, m1] (cax[n, m2] Y_n)
    t = spec.transpose(1, 0, 2)[:, :, None, :] * cax[None, :, :, :]  # (R, n, p, wc)
    rhs = np.matmul(cay.transpose(2, 1, 0), t.reshape(nr, n, p * wc))  # (R, p, p wc)
    del t
    tmp_r = np.empty((nr, wc), np.float32)
    tmp_c = np.empty((nr, wc), np.complex64)
    low: dict[tuple[int, int], np.ndarray] = {}
    dinv: list[np.ndarray] = []
    for j in range(k):  # Cholesky over the k x k index, vectorised over bins
        fy2, fx2 = lam_cols[j]
        # prior precision reg / P(f) = reg |f|^alpha / c, |f|^alpha = (fy^2 + fx^2)^(alpha/2)
        np.add(fy2[r0:r1, None], fx2[None, :], out=tmp_r, casting="same_kind")
        d = cv2.pow(tmp_r, alpha / 2.0)
        d *= lam_scale
        if j == 0 and r0 == 0:
            d[0, 0] = 0.0  # alias (0, 0) at bin (0, 0) is the HR DC term
        d += gram[j, j].real
        for q in range(j):
            lq = low[j, q]
            d -= lq.real**2
            d -= lq.imag**2
        np.maximum(d, np.float32(1e-30), out=d)
        np.sqrt(d, out=d)
        np.divide(np.float32(1.0), d, out=d)
        dinv.append(d)
        dc = d.astype(np.complex64)
        for i in range(j + 1, k):
            v = gram[i, j]  # a view into this block's own product: updated in place
            for q in range(j):
                np.multiply(low[i, q], np.conj(low[j, q]), out=tmp_c)
                v -= tmp_c
            v *= dc
            low[i, j] = v
    z: list[np.ndarray] = []
    for i in range(k):  # forward substitution (in place on the right-hand side)
        m1, m2 = idx[i]
        v = rhs[:, m1, m2 * wc : (m2 + 1) * wc]
        for q in range(i):
            np.multiply(low[i, q], z[q], out=tmp_c)
            v -= tmp_c
        v *= dinv[i]
        z.append(v)
    for i in reversed(range(k)):  # back substitution with L^H, written into the result
        v = z[i]
        for q in range(i + 1, k):
            np.multiply(np.conj(low[q, i]), out[idx[q]], out=tmp_c)
            v -= tmp_c
        np.multiply(v, dinv[i], out=out[idx[i]])


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


@functools.lru_cache(maxsize=256)
def _lanczos_delay(d: float, taps: int = 8) -> np.ndarray:
    """Taps ``h[j] = sinc(k + d) L(k + d)``, ``k = j - (taps/2 - 1)``, normalised to unit DC gain (float32;
    cached per delay: a frame's padding strips share it; read-only)."""
    a = taps // 2
    t = np.arange(-a + 1, a + 1, dtype=np.float64) + d
    h = np.sinc(t) * np.sinc(t / a) * (np.abs(t) < a)
    out = (h / h.sum()).astype(
        np.float32
    )  # sepFilter2D correlates: tap j -> offset j - (a - 1) = k
    out.flags.writeable = False
    return out


def _fractional_shift(
    img: np.ndarray, du: float, dv: float, taps: int = 8, window: tuple[slice, slice] | None = None
) -> np.ndarray:
    """Move image content by (du, dv) px (|d| <= 1) with separable Lanczos-4 fractional delays.

    ``out[x] = sum_k h[k] img[x + k]`` with ``h[k] = sinc(k + d) L(k + d)``, k = -3..4,
    normalised to unit DC gain (content moves by +d: ``out[x] ~ img[x - d]``);
    reflected border. With ``window`` (rows, cols) only ``out[window]`` is
    computed, from the window plus the taps' reach (the same values).
    """
    a = taps // 2
    src = np.asarray(img, np.float32)
    if window is not None:
        h, w = src.shape
        rows, cols = window
        r0, r1 = max(rows.start - (a - 1), 0), min(rows.stop + a, h)
        c0, c1 = max(cols.start - (a - 1), 0), min(cols.stop + a, w)
        out = _fractional_shift(src[r0:r1, c0:c1], du, dv, taps)
        return out[rows.start - r0 : rows.stop - r0, cols.start - c0 : cols.stop - c0]
    return cv2.sepFilter2D(
        src,
        cv2.CV_32F,
        _lanczos_delay(float(dv), taps),
        _lanczos_delay(float(du), taps),
        anchor=(a - 1, a - 1),
        borderType=cv2.BORDER_REFLECT_101,
    )


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
                out[i][win] = _fractional_shift(ref, du, dv, window=win)
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


def _cg_map(
    frames: np.ndarray,
    homographies: np.ndarray,
    p: int,
    blur_sigma: float,
    noise_sigma: float,
    masks: Sequence[np.ndarray] | None,
    prior: tuple[float, float],
    reg: float,
    x0: np.ndarray,
    iters: int,
) -> np.ndarray:
    """MAP estimate of eq. 9 by conjugate gradients with the spatial operators.

    Solves ``(sum_n A_n^T M_n A_n / sigma^2 + reg Q) x = sum_n A_n^T M_n y_n / sigma^2``
    where ``A_n`` is :class:`FrameOperator` (blur, any homography, box
    integration; bilinear resampling), ``M_n`` the validity mask (given mask
    AND footprint inside the HR grid) and ``Q`` the stationary prior
    precision, applied by FFT: ``Q x = ifft(fft(x) / S_x(f))`` with
    ``S_x(f) = c |f|^-alpha`` (DC unregularised). Warm-started from ``x0``;
    ``iters`` CG iterations (each 2 N resamplings + 2 FFTs).
    """
    n = frames.shape[0]
    hh, hw = x0.shape
    c, alpha = prior
    fy = np.fft.fftfreq(hh)[:, None]
    fx = np.fft.rfftfreq(hw)[None, :]
    fr = np.hypot(fy, fx)
    prec = np.where(fr > 0, np.maximum(fr, 1e-6) ** alpha / c, 0.0)
    ops = []
    for i in range(n):  # one operator per frame
        op = FrameOperator(homographies[i], frames[i].shape, (hh, hw), p, p, blur_sigma)
        m = op.valid.astype(np.float64)
        if masks is not None:
            m = m * np.asarray(masks[i], dtype=bool)
        ops.append((op, m))
    inv_var = 1.0 / noise_sigma**2

    def normal(x: np.ndarray) -> np.ndarray:
        out = reg * np.fft.irfft2(np.fft.rfft2(x) * prec, s=x.shape)
        for op, m in ops:
            out += inv_var * op.adjoint(m * op.forward(x))
        return out

    b = np.zeros((hh, hw))
    for (op, m), y in zip(ops, frames):
        b += inv_var * op.adjoint(m * y)
    x = x0.copy()
    r = b - normal(x)
    d = r.copy()
    rr = float(np.sum(r * r))
    r0 = rr
    for _ in range(iters):  # CG iterations
        if rr <= 1e-12 * max(r0, 1e-30):
            break
        q = normal(d)
        alpha_k = rr / float(np.sum(d * q))
        x += alpha_k * d
        r -= alpha_k * q
        rr_new = float(np.sum(r * r))
        d = r + (rr_new / rr) * d
        rr = rr_new
    return x


def _bicubic_rim(img: np.ndarray, ref: np.ndarray, p: int) -> np.ndarray:
    """Replace the outermost LR-pixel ring (p output px) by bicubic upscaling of the reference (in place).

    Frames shifted towards the inside leave that ring observed by the
    reference alone (the rest is padding); measured on the rendered crops the
    MAP estimate there is worse than bicubic, one ring further in it is better.
    Only 4-LR-pixel strips of the reference are upscaled: the ring's bicubic
    taps reach 2 LR px inwards, so the values equal those of upscaling the
    whole frame.
    """
    h, w = ref.shape
    if min(h, w) < 8:
        bic = bicubic_upscale(ref, p)
        img[:p], img[-p:], img[:, :p], img[:, -p:] = bic[:p], bic[-p:], bic[:, :p], bic[:, -p:]
        return img
    img[:p] = bicubic_upscale(ref[:4], p)[:p]
    img[-p:] = bicubic_upscale(ref[-4:], p)[-p:]
    img[:, :p] = bicubic_upscale(ref[:, :4], p)[:, :p]
    img[:, -p:] = bicubic_upscale(ref[:, -4:], p)[:, -p:]
    return img


# --------------------------------------------------------------------------- public API


def _validate(
    frames: Sequence[np.ndarray], shifts, factor: int, masks, shift_cov, homographies
) -> tuple[list[np.ndarray], np.ndarray | None, int]:
    """Check the inputs; return the frames as arrays (not copied), shifts relative to frame 0, factor."""
    if not isinstance(factor, (int, np.integer)) or isinstance(factor, bool):
        raise ValueError(f"factor must be an integer, got {factor!r}")
    if not 2 <= int(factor) <= MAX_FACTOR:
        raise ValueError(f"factor must be in 2..{MAX_FACTOR}, got {factor}")
    if frames is None or len(frames) < 2:
        raise ValueError(
            f"super-resolution needs at least 2 frames, got {0 if frames is None else len(frames)}"
        )
    arrs = [np.asarray(f) for f in frames]
    if any(a.ndim != 2 for a in arrs):
        raise ValueError("frames must be 2-D (mono); use reconstruct_colour for colour frames")
    shape = arrs[0].shape
    if any(a.shape != shape for a in arrs):
        raise ValueError(
            f"all frames must have the same shape, got {sorted({a.shape for a in arrs})}"
        )
    if min(shape) < 16:
        raise ValueError(f"frames too small for reconstruction: {shape} (need >= 16x16)")
    if any(
        not (np.issubdtype(a.dtype, np.integer) or a.dtype == bool) and not np.isfinite(a).all()
        for a in arrs
    ):
        raise ValueError(
            "frames contain NaN or infinite values"
        )  # integer frames are always finite
    n = len(arrs)
    if shifts is None:
        if homographies is None:
            raise ValueError("give shifts (N, 2) or homographies (N, 3, 3)")
        s = None
    else:
        s = np.asarray(shifts, dtype=np.float64)
        if s.shape != (n, 2):
            raise ValueError(f"shifts must have shape ({n}, 2), got {s.shape}")
        if not np.isfinite(s).all():
            raise ValueError("shifts contain NaN or infinite values")
        s = s - s[0]  # relative to frame 0, whose grid is the output grid
    if masks is not None and (len(masks) != n or any(np.asarray(m).shape != shape for m in masks)):
        raise ValueError("masks must be one boolean array per frame, each of the frames' shape")
    if shift_cov is not None:
        c = np.asarray(shift_cov, dtype=np.float64)
        if c.shape != (n, 2, 2) or not np.isfinite(c).all():
            raise ValueError(f"shift_cov must be a finite ({n}, 2, 2) array")
    if homographies is not None:
        hs = np.asarray(homographies, dtype=np.float64)
        if hs.shape != (n, 3, 3) or not np.isfinite(hs).all():
            raise ValueError(f"homographies must be a finite ({n}, 3, 3) array")
    return arrs, s, int(factor)


def _small_ints(arrs: list[np.ndarray]) -> bool:
    """True if every frame has an integer dtype of at most 16 bits (values and p q sums exact in float32)."""
    return all(
        (np.issubdtype(a.dtype, np.integer) and a.dtype.itemsize <= 2) or a.dtype == bool
        for a in arrs
    )


def _stack64(arrs: list[np.ndarray]) -> np.ndarray:
    """The frames as one float64 (N, H, W) array (one pass per frame)."""
    out = np.empty((len(arrs),) + arrs[0].shape)
    for i, a in enumerate(arrs):  # frames
        out[i] = a
    return out


def _fallback(ref: np.ndarray, factor: int, reason: str, noise: float, n: int, shifts) -> SRResult:
    if not np.isfinite(noise):
        noise = estimate_noise_sigma(ref, max_size=256)
    return SRResult(
        image=bicubic_upscale(ref, factor),
        method="bicubic",
        fell_back=True,
        reason=reason,
        noise_sigma=noise,
        weights=np.r_[1.0, np.zeros(n - 1)],
        shifts=np.zeros((n, 2)) if shifts is None else np.asarray(shifts, dtype=np.float64),
        shift_sigma=np.zeros(n),
        factor=factor,
    )


def reconstruct(
    frames: Sequence[np.ndarray],
    shifts: np.ndarray | Sequence[Sequence[float]] | None,
    factor: int,
    *,
    blur_sigma=0.4,
    **kw,
) -> SRResult:
    """Reconstruct a factor-x super-resolved image from N >= 2 shifted LR frames.

    ``blur_sigma``: the optics blur std in LR px (Gaussian PSF of the model):
    a number (e.g. a lab calibration), ``"auto"`` (:data:`BLUR_AUTO`:
    measured on straight edges in the frames, biased low, or a low fallback
    without edges, :func:`subpix_ros.core.blur.estimate_blur`; only the
    "map" method uses a blur), or a :class:`subpix_ros.core.blur.BlurEstimate`
    (e.g. a flight's calibration, :class:`subpix_ros.core.blur.BlurCalibration`).
    The value used and its source are in the result (``blur_sigma``,
    ``blur_source``, ``blur_reason``). Other arguments: :func:`_reconstruct`.
    """
    from .blur import BlurEstimate, estimate_blur, parse_blur_sigma

    if isinstance(blur_sigma, BlurEstimate):
        est = blur_sigma
    else:
        v = parse_blur_sigma(blur_sigma)
        if v == BLUR_AUTO:
            if (
                kw.get("method", "map") == "map"
                and frames is not None
                and len(frames) >= 2
                and all(np.ndim(f) == 2 for f in frames)
            ):
                sh = None if shifts is None else np.asarray(shifts, dtype=np.float64)
                if sh is not None and (sh.shape != (len(frames), 2) or not np.isfinite(sh).all()):
                    sh = None  # malformed shifts: _reconstruct says why
                est = estimate_blur(frames, sh)
            else:  # the blur is not used (or the input is malformed: _reconstruct says why)
                est = BlurEstimate(0.0, "unused", reason="the method does not model the blur")
        else:
            est = BlurEstimate(float(v), "parameter", reason="given")
    res = _reconstruct(frames, shifts, factor, blur_sigma=est.sigma, **kw)
    res.blur_sigma, res.blur_source, res.blur_reason = float(est.sigma), est.source, est.reason
    return res


def _reconstruct(
    frames: Sequence[np.ndarray],
    shifts: np.ndarray | Sequence[Sequence[float]] | None,
    factor: int,
    *,
    method: str = "map",
    masks: Sequence[np.ndarray] | None = None,
    shift_cov: np.ndarray | None = None,
    homographies: np.ndarray | None = None,
    noise_sigma: float | None = None,
    blur_sigma: float = 0.4,
    reg: float = 1.0,
    refine_shifts: bool = True,
    geometry: str = "auto",
    window: int | None = None,
    pad: int = 16,
    cg_iters: int = 30,
) -> SRResult:
    """Reconstruct a factor-x super-resolved image from N >= 2 shifted LR frames.

    frames: N 2-D arrays (same shape; any numeric dtype, DN). shifts: (N, 2)
    ``(u, v)`` per frame in LR px relative to frame 0 (project convention:
    content at (r, c) in frame 0 is at (r+u, c+v) in frame n); any sub-pixel
    values, unequal along rows/cols. factor: 2..4. method: "map" (default,
    eq. 9), "windowed" (eq. 7, normalised), "pinv" (eq. 6, reference),
    "bicubic". window: eq. 7 window w (default factor+2: w+p-1 odd, best PSNR of the small
    windows measured). masks: optional bool per frame (True = valid), forces the CG
    solver. shift_cov: (N, 2, 2) registration-error covariance of the given
    shifts (LR px^2); ignored when ``refine_shifts`` (the refined shifts'
    own uncertainty is used). homographies: (N, 3, 3) reference -> frame LR
    pixel coordinates (replaces shifts; forces the CG solver). noise_sigma:
    per-pixel noise std in DN (estimated from the frames if None).
    blur_sigma: optics blur std in LR px (Gaussian PSF of the model).
    reg: prior strength multiplier (1 = the prior fitted to the data).
    geometry: "auto" checks (tile registration, :func:`detect_geometry`)
    whether the frames are related by more than a translation and if so puts
    the fitted affine of each frame into the forward model (CG solver);
    "translation" skips the check.

    Returns :class:`SRResult`; raises ValueError on malformed input (fewer
    than 2 frames, mismatched shapes, factor outside 2..4, bad shifts).
    """
    arrs, s, p = _validate(frames, shifts, factor, masks, shift_cov, homographies)
    n = len(arrs)
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {METHODS}")
    if geometry not in ("auto", "translation"):
        raise ValueError(f"geometry must be 'auto' or 'translation', got {geometry!r}")
    if blur_sigma < 0 or reg <= 0:
        raise ValueError("blur_sigma must be >= 0 and reg > 0")
    if noise_sigma is not None and (not np.isfinite(noise_sigma) or noise_sigma < 0):
        raise ValueError(f"noise_sigma must be finite and >= 0, got {noise_sigma}")
    # single-frame estimate for the non-MAP paths and fallbacks (MAP estimates it from the frames jointly)
    sigma = float("nan") if noise_sigma is None else float(noise_sigma)
    if noise_sigma is None and method != "map":
        sigma = estimate_noise_sigma(arrs[0], max_size=256)
    ref = np.asarray(arrs[0], dtype=np.float64)
    if method == "bicubic":
        return SRResult(
            bicubic_upscale(ref, p),
            "bicubic",
            noise_sigma=sigma,
            weights=np.r_[1.0, np.zeros(n - 1)],
            shifts=np.zeros((n, 2)) if s is None else s,
            shift_sigma=np.zeros(n),
            factor=p,
        )
    if s is not None and homographies is None:
        phase = (
            s - s[0] + 0.5
        ) % 1.0 - 0.5  # each frame's sub-pixel phase relative to frame 0, LR px
        if np.max(np.abs(phase)) < 0.05:
            return _fallback(
                ref, p, "all frames have the same sub-pixel phase: no new information", sigma, n, s
            )
    if method in ("windowed", "pinv"):
        if s is None:
            return _fallback(ref, p, f"{method} needs pure translations", sigma, n, s)
        offs = grid_offsets(s, p, p)
        if offs is None:
            return _fallback(
                ref,
                p,
                f"{method} (eq. {7 if method == 'windowed' else 6}) needs shifts on the k/{p} grid",
                sigma,
                n,
                s,
            )
        # 8/16-bit frames: float32 holds the sums exactly (averages of frames sharing a phase to float32
        # round-off); half the memory traffic, and the filter still runs in float64
        y, filled = interleave(
            arrs, offs, p, p, dtype=np.float32 if _small_ints(arrs) else np.float64
        )
        if method == "windowed":
            x = windowed_solution(y, p, p, w=p + 2 if window is None else window)
            # eq. 9's Gaussian regularisation of the windowed solution: without it eq. 7 amplifies noise
            # and aliasing below bicubic (x3, x4, and x2 at low blur; docs/design-notes.md)
            x = cv2.GaussianBlur(
                x, (0, 0), WINDOWED_SMOOTH_LR_PX * p, borderType=cv2.BORDER_REFLECT_101
            )
        else:
            h2 = (y.shape[0] // p) * p - (p - 1)
            w2 = (y.shape[1] // p) * p - (p - 1)
            x = np.zeros(y.shape)
            sol = pinv_solution(y[:h2, :w2], p, p)
            x[: sol.shape[0], : sol.shape[1]] = sol
        return SRResult(
            x,
            method,
            noise_sigma=sigma,
            weights=np.ones(n),
            shifts=s,
            shift_sigma=np.zeros(n),
            factor=p,
        )

    # method == "map"
    stack = _stack64(arrs)
    cov = np.zeros((n, 2, 2)) if shift_cov is None else np.asarray(shift_cov, dtype=np.float64)
    reason = ""
    lowpassed = _WholeLowpass(stack)  # shared by the geometry check and the shift refinement
    if homographies is None and geometry == "auto" and min(ref.shape) >= 96:
        affines, _, tile_noise = detect_geometry(stack, s, lowpassed=lowpassed)
        if affines is not None:
            homographies = affines
            reason = "frames related by more than a translation: affine geometry fitted per frame, solved by CG"
            if noise_sigma is None and np.isfinite(tile_noise):
                noise_sigma = tile_noise
    use_cg = masks is not None or homographies is not None
    trans = s
    if homographies is not None:
        hs = np.asarray(homographies, dtype=np.float64)
        h_, w_ = ref.shape
        centre = np.array([(w_ - 1) / 2.0, (h_ - 1) / 2.0, 1.0])
        trans = np.empty((n, 2))
        for i in range(n):  # the translation each homography applies at the frame centre
            q = hs[i] @ centre
            trans[i] = (q[1] / q[2] - centre[1], q[0] / q[2] - centre[0])
        if noise_sigma is None and min(ref.shape) >= 96:
            # multi-frame noise estimate from local (tile) registrations, where a translation fits
            _, _, tile_noise = detect_geometry(stack, trans, lowpassed=lowpassed)
            if np.isfinite(tile_noise):
                noise_sigma = tile_noise
    try:
        ints = (
            True
            if all(np.issubdtype(a.dtype, np.integer) or a.dtype == bool for a in arrs)
            else None
        )
        sol = _fourier_map(
            stack,
            trans,
            p,
            blur_sigma,
            noise_sigma,
            cov,
            reg,
            refine_shifts and not use_cg,
            pad,
            integer_valued=ints,
            lowpassed=lowpassed,
        )
    except (ValueError, np.linalg.LinAlgError) as exc:
        return _fallback(ref, p, f"MAP solve failed: {exc}", sigma, n, s)
    img = sol["image"]
    weights = sol["weights"]
    sigma = sol["noise_sigma"]
    method_used = "map"
    if use_cg:
        hs = (
            np.asarray(homographies, dtype=np.float64)
            if homographies is not None
            else np.stack([translation_homography(*si) for si in s])
        )
        img = _cg_map(
            stack, hs, p, blur_sigma, sol["noise_sigma"], masks, sol["prior"], reg, img, cg_iters
        )
        method_used = "map-cg"
    if not np.isfinite(img).all():
        return _fallback(ref, p, "MAP solution not finite", sigma, n, s)
    img = _bicubic_rim(img, ref, p)
    kept = sol.get("kept")
    if kept is not None and not kept.all():
        dropped = ", ".join(str(i) for i in np.flatnonzero(~kept))
        reason = (
            reason + "; " if reason else ""
        ) + f"frames {dropped} left out (registration failed or they disagree with the reference)"
    eff = float(np.sum(weights[1:]))
    if eff < 0.05:
        return _fallback(
            ref,
            p,
            "no frame other than the reference agrees with it (registration errors too large)",
            sigma,
            n,
            sol["shifts"],
        )
    return SRResult(
        image=img,
        method=method_used,
        noise_sigma=sigma,
        weights=weights,
        shifts=sol["shifts"],
        shift_sigma=sol["shift_sigma"],
        factor=p,
        reason=reason,
    )


def reconstruct_colour(
    frames_bgr: Sequence[np.ndarray],
    shifts: np.ndarray | Sequence[Sequence[float]] | None,
    factor: int,
    **kwargs,
) -> SRResult:
    """Super-resolve colour frames: luminance by :func:`reconstruct`, chroma upsampled.

    Frames are HxWx3 BGR (OpenCV order) or 2-D (then this is
    :func:`reconstruct`). Each frame's luminance Y (ITU-R BT.601, as
    ``cv2.COLOR_BGR2YCrCb`` on the frames' own scale, single precision) is
    reconstructed with ``reconstruct(..., **kwargs)``; Cr and Cb of the
    reference frame are bicubic-upscaled (the eye and most uses need
    far less chroma resolution, and chroma would triple the cost). The
    result's image is float32 BGR, (factor*H, factor*W, 3), on the same
    output grid (single precision holds 8- and 16-bit data with room to
    spare, and halves the cost of the largest arrays); ``method``/``fell_back``/``reason`` are those of the
    luminance reconstruction.
    """
    if frames_bgr is None or len(frames_bgr) == 0:
        raise ValueError("no frames")
    arrs = [np.asarray(f) for f in frames_bgr]
    if all(a.ndim == 2 for a in arrs):
        return reconstruct(arrs, shifts, factor, **kwargs)
    if any(a.ndim != 3 or a.shape[2] != 3 for a in arrs):
        raise ValueError("colour frames must all be HxWx3 (BGR)")
    # luminance of every frame (Y of YCrCb is BGR2GRAY's weighted sum), chroma of the reference only
    ys = [cv2.cvtColor(a.astype(np.float32), cv2.COLOR_BGR2GRAY) for a in arrs]
    res = reconstruct(ys, shifts, factor, **kwargs)
    p = res.factor
    h, w = arrs[0].shape[:2]
    ycc0 = cv2.cvtColor(arrs[0].astype(np.float32), cv2.COLOR_BGR2YCrCb)
    chroma = cv2.resize(
        np.ascontiguousarray(ycc0[..., 1:]), (w * p, h * p), interpolation=cv2.INTER_CUBIC
    )
    # YCrCb offsets: OpenCV uses delta = 128 for 8-bit, 0.5 for float in [0, 1]; frames keep their scale,
    # so the offset was taken from the data's own convention by converting back with OpenCV
    merged = cv2.merge([res.image.astype(np.float32), chroma[..., 0], chroma[..., 1]])
    res.image = cv2.cvtColor(merged, cv2.COLOR_YCrCb2BGR)
    return res
