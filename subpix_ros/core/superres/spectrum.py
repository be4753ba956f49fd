"""Noise level and image prior of super-resolution, fitted to the frames.

:func:`estimate_noise_sigma` is a single-frame noise estimate (Immerkaer);
:func:`fit_spectrum` fits the stationary power-law prior ``S_x(f) = c |f|^-alpha`` and the
white-noise floor to the frames' power spectrum through the observation model;
:func:`fit_rolloff_spectrum` fits the same prior times a Gaussian roll-off
``exp(-4 pi^2 p^2 s^2 |f|^2)`` (issue 17).
"""

from __future__ import annotations

import functools

import cv2
import numpy as np

from ..filters import tukey_2d
from .dft import _rfft2_32
from .model import frame_transfer_1d, motion_transfer

__all__ = ["estimate_noise_sigma", "fit_rolloff_spectrum", "fit_spectrum"]


def estimate_noise_sigma(frame: np.ndarray, max_size: int | None = None) -> float:
    """Estimate the per-pixel noise std of one frame (robust Immerkaer estimate).

    Parameters
    ----------
    frame : numpy.ndarray
        2-D frame, at least 3x3 (any numeric dtype, DN).
    max_size : int, optional
        Use only the central ``max_size`` x ``max_size`` region (bounded cost).

    Returns
    -------
    float
        Noise std (DN).

    Notes
    -----
    The frame is filtered with ``N = [[1,-2,1],[-2,4,-2],[1,-2,1]]`` (a difference of two
    Laplacians that removes planes and most smooth image content; for white noise
    ``std(I*N) = 6 sigma``) and ``sigma = 1.4826 median(|I*N|) / 6``. Texture left in ``I*N``
    biases it upwards; quantisation noise (1/sqrt(12) DN for 8 bit) is included.

    References
    ----------
    .. [1] J. Immerkaer, "Fast noise variance estimation", Computer Vision and Image
       Understanding 64(2), 300-302, 1996. https://doi.org/10.1006/cviu.1996.0060
    """
    f = np.asarray(frame)
    if f.ndim != 2 or min(f.shape) < 3:
        raise ValueError("noise estimate needs a 2-D frame of at least 3x3")
    if max_size is not None and max(f.shape) > max_size:  # central crop: bounded cost
        r0, c0 = max(0, (f.shape[0] - max_size) // 2), max(0, (f.shape[1] - max_size) // 2)
        f = f[r0 : r0 + max_size, c0 : c0 + max_size]
    k = np.array([[1, -2, 1], [-2, 4, -2], [1, -2, 1]], dtype=np.float64)
    if f.dtype == np.uint8:
        # 8-bit: I*N is an integer in [-4080, 4080], exact in int16: its median from a histogram
        r = np.abs(cv2.filter2D(np.ascontiguousarray(f), cv2.CV_16S, k)[1:-1, 1:-1]).ravel()
        return float(1.4826 * _median_of_small_ints(r) / 6.0)
    f = np.asarray(f, dtype=np.float64)
    r = cv2.filter2D(f, cv2.CV_64F, k)[1:-1, 1:-1]
    return float(1.4826 * np.median(np.abs(r)) / 6.0)


def _median_of_small_ints(v: np.ndarray) -> float:
    """Return ``np.median(v)`` of non-negative small integers, exactly, by a histogram."""
    counts = np.cumsum(np.bincount(v))
    n = v.size
    hi = int(np.searchsorted(counts, n // 2, side="right"))  # the element at sorted index n // 2
    if n % 2:
        return float(hi)
    lo = int(np.searchsorted(counts, n // 2 - 1, side="right"))  # sorted index n // 2 - 1
    return (lo + hi) / 2.0


_SPECTRUM_CROP = 384  # fit_spectrum's default crop (LR px)


def fit_spectrum(
    frames: np.ndarray,
    p: int,
    blur_sigma: float,
    noise_sigma: float | None = None,
    max_bins: int = 8000,
    crop: int = _SPECTRUM_CROP,
    motion_blur: tuple[float, float] = (0.0, 0.0),
    pixel_fill: float = 1.0,
) -> tuple[float, float, float]:
    """Fit the stationary prior and the noise floor to the frames' power spectrum.

    Parameters
    ----------
    frames : numpy.ndarray
        (N, H, W) frames; the central ``crop`` square of the first two is used.
    p : int
        Resolution factor.
    blur_sigma : float
        Optics blur std (LR px).
    noise_sigma : float, optional
        Known per-pixel noise std (DN); then only c and alpha are fitted.
    max_bins : int, optional
        Frequency bins used (a fixed subsample of those above 0.03 cycles/LR px).
    crop : int, optional
        Side of the central region (LR px).
    motion_blur : (float, float), optional
        Image motion during the exposure ``d = (du, dv)`` (LR px; default none): its
        transfer ``M`` (:func:`~subpix_ros.core.superres.model.motion_transfer`) multiplies
        ``a_m``.
    pixel_fill : float, optional
        The pixel aperture's width (LR px; default 1), as in ``frame_transfer_1d``.

    Returns
    -------
    c : float
        Prior level, DN^2 (HR px units).
    alpha : float
        Prior exponent, in [1, 4].
    sigma : float
        Noise std (DN).

    Notes
    -----
    Model (per-pixel PSD units, f in cycles / HR px, nu in cycles / LR px)::

        E S_y(nu) = p^2 sum_m |a_m(nu)|^2 c |f_m|^-alpha + sigma^2

    the HR scene's power law ``S_x(f) = c |f|^-alpha`` seen through the observation model
    (eq. 3 with blur, aliased over the p^2 components m, ``a_m`` from ``frame_transfer_1d``,
    times the motion blur's ``M(f_m)`` if any)
    plus white noise. ``S_y`` is the Tukey-windowed periodogram averaged over the frames. For
    each alpha, (c, sigma^2) solve a weighted linear least squares (weights 1/model^2: a
    periodogram's std equals its mean; 3 reweighting passes); the alpha with the least
    relative misfit wins, searched on a 0.3 grid in [1, 4], then on the 0.1 grid within
    +-0.2 of the coarse winner.
    """
    h, w = min(frames.shape[1], crop), min(frames.shape[2], crop)
    psd = _frames_psd(frames, crop)
    mot = (float(motion_blur[0]), float(motion_blur[1]))
    fill = float(pixel_fill)
    sel, amp, logf = _spectrum_model(h, w, p, float(blur_sigma), max_bins, mot, fill)
    obs = psd.ravel()[sel]
    # coarse 0.3 grid, then the 0.1 grid within +-0.2 of the coarse best (misfit unimodal in alpha)
    key = (h, w, p, float(blur_sigma), max_bins, mot)
    coarse = _fit_exponents(
        1.0, 0.3, 11, amp, logf, obs, noise_sigma, *_exponent_terms(*key, 1.0, 0.3, 11, fill)
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
        *_exponent_terms(*key, round(lo, 10), 0.1, n_fine, fill),
    )
    return float(c), float(alpha), float(np.sqrt(s2))


def _frames_psd(frames: np.ndarray, crop: int) -> np.ndarray:
    """Return the Tukey-windowed periodogram of the central ``crop`` square, rfft half.

    Averaged over (up to) the first two frames, each with its mean removed, in single
    precision; per-pixel PSD units (divided by the window's energy).
    """
    _, h0, w0 = frames.shape
    h, w = min(h0, crop), min(w0, crop)
    sub = frames[:2, (h0 - h) // 2 : (h0 - h) // 2 + h, (w0 - w) // 2 : (w0 - w) // 2 + w]
    win = tukey_2d(h, w)
    psd = np.zeros((h, w // 2 + 1))
    for f in sub:  # (up to) two frames: mean removed, windowed, single precision
        x = np.asarray(f, dtype=np.float32)
        x = (x - np.float32(x.mean(dtype=np.float64))) * win
        psd += np.abs(_rfft2_32(x)) ** 2
    psd /= len(sub) * float(np.sum(np.square(win, dtype=np.float64)))
    return psd


ROLLOFF_GRID = (0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 1.0, 1.2, 1.5)  # s, LR px
ROLLOFF_SNR_MIN = 1.0  # s is fitted on the rings with power > (1 + this) sigma^2
ROLLOFF_MAX_EXP = 60.0  # the roll-off's exponent is capped here in the solves (e^-60)


def fit_rolloff_spectrum(
    frames: np.ndarray,
    p: int,
    blur_sigma: float,
    noise_sigma: float | None = None,
    max_bins: int = 8000,
    crop: int = _SPECTRUM_CROP,
    motion_blur: tuple[float, float] = (0.0, 0.0),
    pixel_fill: float = 1.0,
) -> tuple[float, float, float, float]:
    """Fit a power-law prior with a Gaussian roll-off and the noise floor to the frames.

    Parameters are those of :func:`fit_spectrum`.

    Returns
    -------
    c : float
        Prior level, DN^2 (HR px units).
    alpha : float
        Prior exponent, in [1, 4].
    s : float
        Roll-off width (LR px), in ``[0, ROLLOFF_GRID[-1]]``; 0: a power law.
    sigma : float
        Noise std (DN).

    Notes
    -----
    Prior (per-pixel PSD units, f in cycles / HR px, s in LR px)::

        S_x(f) = c |f|^-alpha exp(-4 pi^2 p^2 s^2 |f|^2)

    the power spectrum of a power-law scene blurred by a Gaussian of std s LR px (p s HR px):
    the roll-off has the form of the optics blur's ``|H|^2``, so it takes up softness the
    observation model does not hold (the scene's own, or blur beyond ``blur_sigma``) as
    missing scene power rather than as blur to undo. Seen through the observation model
    ``E S_y(nu) = p^2 sum_m |a_m(nu)|^2 S_x(f_m) + sigma^2`` (as in :func:`fit_spectrum`) and
    fitted on the ring means of the periodogram (:func:`_rings`; (c, sigma^2) by weighted
    least squares, :func:`_fit_levels`), in two steps:

    1. ``s = 0``: alpha on the 0.3 grid in [1, 4], then on the 0.1 grid within +-0.2 of the
       coarse winner; this gives alpha and the noise (or the given noise).
    2. At that alpha and noise, c and s on the rings whose power exceeds
       ``(1 + ROLLOFF_SNR_MIN) sigma^2`` (fewer than 4 such rings: s = 0), s in
       ``ROLLOFF_GRID``, then at the winner and half-way to its grid neighbours.

    Fitting alpha and s jointly, or s on every ring, over-estimated s on natural scenes (the
    rings near the noise floor decide it) and lost up to 2 dB (docs/design-notes.md, "A prior
    with a roll-off").
    """
    h, w = min(frames.shape[1], crop), min(frames.shape[2], crop)
    psd = _frames_psd(frames, crop)
    mot = (float(motion_blur[0]), float(motion_blur[1]))
    key = (h, w, p, float(blur_sigma), max_bins, mot, float(pixel_fill))
    ring, counts = _rings(h, w, max_bins)
    obs = psd.ravel()[_spectrum_bins(h, w, max_bins)] @ ring
    fit = functools.partial(_fit_grid, key, obs=obs, noise_sigma=noise_sigma, counts=counts)
    alpha = fit(tuple(round(1.0 + 0.3 * j, 10) for j in range(11)), (0.0,))[1]
    lo, hi = max(1.0, alpha - 0.2), min(4.0, alpha + 0.2)
    fine = tuple(round(lo + 0.1 * j, 10) for j in range(int(round((hi - lo) / 0.1)) + 1))
    c, alpha, _, s2, _ = fit(fine, (0.0,))
    keep = obs > (1.0 + ROLLOFF_SNR_MIN) * s2
    if keep.sum() < 4:
        return c, alpha, 0.0, float(np.sqrt(s2))
    fit = functools.partial(
        _fit_grid, key, obs=obs, noise_sigma=float(np.sqrt(s2)), counts=counts, keep=keep
    )
    s = fit((alpha,), ROLLOFF_GRID)[2]
    c, alpha, s, _, _ = fit((alpha,), _rolloff_neighbours(s))
    return c, alpha, s, float(np.sqrt(s2))


def _rolloff_neighbours(s: float) -> tuple[float, ...]:
    """Return ``s`` and the points half-way to its neighbours in ``ROLLOFF_GRID``."""
    g = ROLLOFF_GRID
    j = int(np.argmin(np.abs(np.asarray(g) - s)))
    out = [g[j]]
    if j > 0:
        out.insert(0, round((g[j - 1] + g[j]) / 2, 10))
    if j + 1 < len(g):
        out.append(round((g[j] + g[j + 1]) / 2, 10))
    return tuple(out)


def _fit_grid(
    key: tuple,
    alphas: tuple[float, ...],
    widths: tuple[float, ...],
    obs: np.ndarray,
    noise_sigma: float | None,
    counts: np.ndarray,
    keep: np.ndarray | None = None,
) -> tuple[float, float, float, float, float]:
    """Fit (c, sigma^2) on every (alpha, s) of ``alphas x widths``; keep the least misfit.

    Returns ``(c, alpha, s, sigma^2, misfit)`` (:func:`_fit_levels`).

    ``key`` is ``(h, w, p, blur_sigma, max_bins, motion_blur, pixel_fill)``; ``obs`` and
    ``counts`` the ring means of the periodogram and their bin counts (:func:`_rings`).
    """
    q, q2 = _rolloff_terms(*key, alphas, widths)
    if keep is not None:
        q, q2, obs, counts = q[:, keep], q2[:, keep], obs[keep], counts[keep]
    best, c, s2, err = _fit_levels(q, q2, obs, noise_sigma, counts)
    ja, js = divmod(best, len(widths))
    return c, float(alphas[ja]), float(widths[js]), s2, err


@functools.lru_cache(maxsize=64)
def _rolloff_terms(
    h: int,
    w: int,
    p: int,
    blur_sigma: float,
    max_bins: int,
    motion_blur: tuple[float, float],
    pixel_fill: float,
    alphas: tuple[float, ...],
    widths: tuple[float, ...],
) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(q, q^2)``, ``q[(a, s)] = sum_m amp_m |f_m|^-alpha_a exp(-4 pi^2 p^2 s^2 f_m^2)``.

    On :func:`_spectrum_model`'s terms averaged over :func:`_rings`, rows ordered
    alpha-major ((len(alphas) len(widths), rings)); one batched matrix product over the bins
    (alias sums), cached read-only.
    """
    _, amp, logf = _spectrum_model(h, w, p, blur_sigma, max_bins, motion_blur, pixel_fill)
    a = np.asarray(alphas)[:, None, None]
    k = np.array([rolloff_coefficient(p, v) for v in widths])[:, None, None]
    powl = amp * np.exp(-a * logf)  # (na, p^2, bins)
    roll = np.exp(-np.minimum(k * np.exp(2.0 * logf), ROLLOFF_MAX_EXP))  # (ns, p^2, bins)
    q = np.matmul(powl.transpose(2, 0, 1), roll.transpose(2, 1, 0))  # (bins, na, ns)
    q = np.ascontiguousarray(q.reshape(q.shape[0], -1).T) @ _rings(h, w, max_bins)[0]
    q2 = q * q
    q.flags.writeable = False
    q2.flags.writeable = False
    return q, q2


def rolloff_coefficient(p: int, s: float) -> float:
    """Return ``k = 4 pi^2 p^2 s^2``: the roll-off is ``exp(-k |f|^2)``, f in cycles / HR px."""
    return float(4.0 * np.pi**2 * p * p * s * s)


def rolloff_precision(f2: np.ndarray, k: float, out: np.ndarray | None = None) -> np.ndarray:
    """Return the roll-off's inverse ``exp(min(k |f|^2, ROLLOFF_MAX_EXP))``.

    ``f2`` is ``|f|^2`` (cycles / HR px, squared) and ``k`` :func:`rolloff_coefficient`; the
    factor that multiplies the power law's precision ``|f|^alpha / c`` (dtype of ``f2``;
    capped so that float32 does not overflow).
    """
    e = np.multiply(f2, k, out=out)
    np.minimum(e, ROLLOFF_MAX_EXP, out=e)
    return np.exp(e, out=e)


RING_WIDTH = 0.02  # cycles / LR px: the rings the roll-off prior is fitted on


@functools.lru_cache(maxsize=16)
def _rings(h: int, w: int, max_bins: int) -> tuple[np.ndarray, np.ndarray]:
    """Return the ring-mean matrix of :func:`_spectrum_bins`' bins and each ring's count.

    Rings of ``RING_WIDTH`` cycles / LR px in ``|nu|``; ``(bins, rings)`` with columns that
    average their bins (``obs @ m`` is the ring means), and ``(rings,)`` bin counts; rings
    with no bin are left out. Cached, read-only.
    """
    sel = _spectrum_bins(h, w, max_bins)
    ky, kx = np.unravel_index(sel, (h, w // 2 + 1))
    r = np.hypot(np.fft.fftfreq(h)[ky], np.fft.rfftfreq(w)[kx])
    idx = np.floor(r / RING_WIDTH).astype(np.int64)
    used, inv = np.unique(idx, return_inverse=True)
    counts = np.bincount(inv).astype(np.float64)
    m = np.zeros((sel.size, used.size))
    m[np.arange(sel.size), inv] = 1.0 / counts[inv]
    m.flags.writeable = False
    counts.flags.writeable = False
    return m, counts


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
    """Fit (c, sigma^2) for the exponents ``a0 + da j``, j < count, at once.

    Parameters
    ----------
    a0, da : float
        First exponent and step.
    count : int
        Number of exponents.
    amp, logf : numpy.ndarray
        (p^2, bins) model terms of :func:`_spectrum_model`.
    obs : numpy.ndarray
        (bins,) observed periodogram.
    noise_sigma : float or None
        Known noise std (DN), or None to fit it.
    q, q2 : numpy.ndarray, optional
        (count, bins) ``q[j] = sum_m amp_m |f_m|^-alpha_j`` and its square, if known
        (:func:`_exponent_terms`).

    Returns
    -------
    tuple of float
        (c, alpha, sigma^2, relative misfit) of the best exponent (:func:`_fit_levels`).
    """
    alphas = a0 + da * np.arange(count)
    if q is None:
        q = _exponent_sums(a0, da, count, amp, logf)
    if q2 is None:
        q2 = q * q
    best, c, s2, err = _fit_levels(q, q2, obs, noise_sigma)
    return c, float(alphas[best]), s2, err


def _fit_levels(
    q: np.ndarray,
    q2: np.ndarray,
    obs: np.ndarray,
    noise_sigma: float | None,
    counts: np.ndarray | None = None,
) -> tuple[int, float, float, float]:
    """Fit ``E S_y = c q[j] + sigma^2`` for every row j of ``q`` at once; keep the best.

    Parameters
    ----------
    q, q2 : numpy.ndarray
        (count, bins) the prior's shape seen through the observation model, and its square.
    obs : numpy.ndarray
        (bins,) observed periodogram.
    noise_sigma : float or None
        Known noise std (DN), or None to fit it.
    counts : numpy.ndarray, optional
        (bins,) how many periodogram bins each entry of ``obs`` averages (default 1): the
        weights are ``counts / model^2`` (a mean of n bins has variance ``model^2 / n``).

    Returns
    -------
    tuple
        (j, c, sigma^2, relative misfit) of the row with the least relative misfit
        ``sum(counts (S_y - model)^2 / model^2) / sum(counts)``.

    Notes
    -----
    Per row 3 passes of weighted least squares (weights 1/model^2); each pass's sums
    ``sum_b w q^2``, ``sum_b w q``, ``sum_b w q S_y`` are matrix-vector products in the first
    pass (one weight vector for all rows), row-wise dot products after.
    """
    count = q.shape[0]
    n_b = np.ones(obs.size) if counts is None else counts
    qy = q * obs
    w0 = n_b / np.maximum(obs, 1e-12) ** 2
    wgt = None  # first pass: the same weights 1/obs^2 for every row (matrix-vector products)
    model = np.empty_like(q)
    for it in range(3):  # reweighting passes, all rows at once
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
            np.divide(n_b, wgt, out=wgt)
    rel = np.subtract(obs, model)
    rel /= model
    err = np.einsum("ab,ab->a", rel, rel * n_b) / n_b.sum()
    best = int(np.argmin(err))
    return best, float(c_[best]), float(s2[best]), float(err[best])


def _exponent_sums(
    a0: float, da: float, count: int, amp: np.ndarray, logf: np.ndarray
) -> np.ndarray:
    """Return ``q[j] = sum_m amp_m |f_m|^-(a0 + da j)``, (count, bins).

    Computed by the recurrence ``|f|^-(alpha + da) = |f|^-alpha |f|^-da`` (no loop over bins).
    """
    step = np.exp(-da * logf)
    term = amp * np.exp(-a0 * logf)
    q = np.empty((count, amp.shape[1]))
    for a in range(count):  # exponents, not bins
        q[a] = term.sum(axis=0)
        term *= step
    return q


@functools.lru_cache(maxsize=64)
def _exponent_terms(
    h: int,
    w: int,
    p: int,
    blur_sigma: float,
    max_bins: int,
    motion_blur: tuple[float, float],
    a0: float,
    da: float,
    count: int,
    pixel_fill: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(q, q^2)`` of :func:`_exponent_sums` on :func:`_spectrum_model`'s terms.

    They depend only on the crop shape, factor, blur, motion blur, pixel fill and exponents, so
    they are cached (read-only; the fine search has one table per coarse winner).
    """
    _, amp, logf = _spectrum_model(h, w, p, blur_sigma, max_bins, motion_blur, pixel_fill)
    q = _exponent_sums(a0, da, count, amp, logf)
    q2 = q * q
    q.flags.writeable = False
    q2.flags.writeable = False
    return q, q2


@functools.lru_cache(maxsize=16)
def _spectrum_bins(h: int, w: int, max_bins: int) -> np.ndarray:
    """Return the flat indices into the h x (w//2+1) rfft half of the bins the fit uses.

    Bins above 0.03 cycles / LR px; a fixed random subsample (seed 0) of ``max_bins`` of them
    if there are more. Cached per shape (read-only).
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
    h: int,
    w: int,
    p: int,
    blur_sigma: float,
    max_bins: int,
    motion_blur: tuple[float, float] = (0.0, 0.0),
    pixel_fill: float = 1.0,
) -> tuple[np.ndarray, ...]:
    """Return the bins and model terms of :func:`fit_spectrum` for an h x w crop.

    Returns the flat bin indices ``sel`` (:func:`_spectrum_bins`), ``amp[m] = p^2 |a_m M_m|^2``
    (``M_m`` the motion blur's transfer, 1 without) and
    ``log |f_m|`` (p^2, bins) of the p^2 aliases m at those bins; cached per shape, read-only.
    """
    ay, fy = frame_transfer_1d(h, p, 0.0, blur_sigma, pixel_fill=pixel_fill)
    ax, fx = frame_transfer_1d(w, p, 0.0, blur_sigma, pixel_fill=pixel_fill)
    wc = w // 2 + 1
    ax, fx = ax[:, :wc], fx[:, :wc]
    sel = _spectrum_bins(h, w, max_bins)
    ky, kx = np.unravel_index(sel, (h, wc))
    amp = np.ascontiguousarray(
        (np.abs(ay[:, None, ky] * ax[None, :, kx]) ** 2).reshape(p * p, -1) * p * p
    )
    if motion_blur != (0.0, 0.0):
        mt = motion_transfer(fy[:, None, ky], fx[None, :, kx], p, motion_blur)
        amp = np.ascontiguousarray(amp * (mt**2).reshape(p * p, -1))
    fm = np.hypot(fy[:, None, ky], fx[None, :, kx]).reshape(p * p, -1)
    logf = np.ascontiguousarray(np.log(np.maximum(fm, 1e-9)))  # (p^2, bins), C order for the sums
    for a in (amp, logf):
        a.flags.writeable = False
    return sel, amp, logf
