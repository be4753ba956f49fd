"""Fourier-domain MAP super-resolution of translated frames (METHODS.md B, eq. 9).

For translations the observation model (eq. 3 with optics blur and shift, see
:func:`~subpix_ros.core.superres.model.frame_transfer_1d`) is shift-invariant per
frame, so the normal equations decouple over LR frequency bins: each bin couples
only the factor^2 aliased HR frequencies. :func:`_fourier_map` registers the
frames (:func:`~subpix_ros.core.superres.geometry._refine_shifts`), pads them
consistently, fits the prior and the noise (:mod:`.spectrum`) and solves every
bin: by :func:`~subpix_ros.core.superres.separable._solve_separable` when the
registration error is negligible, else by the batched solves of
:func:`_solve_uncertain`, where the registration-error covariance enters as an
expected transfer and an extra noise term.
"""

from __future__ import annotations

import functools
from collections.abc import Iterator
from dataclasses import dataclass

import cv2
import numpy as np

from ..filters import fractional_shift
from .dft import _assemble_hr, _rfft2_32
from .geometry import _refine_shifts
from .lowpass import _preshift_window, _WholeLowpass
from .model import _frame_transfers, motion_transfer
from .separable import _solve_separable
from .spectrum import (
    _SPECTRUM_CROP,
    fit_rolloff_spectrum,
    fit_spectrum,
    rolloff_coefficient,
    rolloff_precision,
)
from .validation import FrameStack, stored
from .workspace import Workspace, work_array


@dataclass
class MapSolution:
    """Result of :func:`_fourier_map`, reported per input frame.

    Attributes
    ----------
    image : numpy.ndarray
        float64, ``(factor H, factor W)``: the HR estimate.
    shifts : numpy.ndarray
        (N, 2) shifts used (LR px; refined if asked; as given for dropped frames).
    shift_sigma : numpy.ndarray
        (N,) registration error std assumed per frame (LR px; inf for dropped frames).
    weights : numpy.ndarray
        (N,) each frame's weight at DC relative to the reference (0 for dropped frames).
    prior : tuple of float
        ``(c, alpha)`` of the fitted prior ``S_x(f) = c |f|^-alpha`` (per-pixel PSD units).
    noise_sigma : float
        Per-pixel noise std used (DN).
    kept : numpy.ndarray
        (N,) bool, the frames that entered the solve.
    resid_ratio : numpy.ndarray or None
        (N,) mean ``|Y - A X|^2 / v`` per frame on the uncertain-registration path (NaN on
        the white-noise path; None when frames were dropped).
    disputed : numpy.ndarray or None
        (N,) how far (LR px, largest axis) each given shift was from the frames' own
        registration where the two disagreed and the latter was used instead (0 elsewhere);
        None when the refinement did not run or the shifts were refined anyway.
    rolloff : float
        Width s (LR px) of the prior's Gaussian roll-off ``exp(-4 pi^2 p^2 s^2 |f|^2)``
        (0: none, ``prior="powerlaw"``).
    """

    image: np.ndarray
    shifts: np.ndarray
    shift_sigma: np.ndarray
    weights: np.ndarray
    prior: tuple[float, float]
    noise_sigma: float
    kept: np.ndarray
    resid_ratio: np.ndarray | None = None
    disputed: np.ndarray | None = None
    rolloff: float = 0.0


PRIORS = ("powerlaw", "rolloff")  # the image priors of the MAP solve


@dataclass
class _Registered:
    """The frames that enter the solve, after registration against the reference."""

    frames: np.ndarray
    ishift: np.ndarray  # integer part of each shift
    resid: np.ndarray  # sub-pixel part (refined if asked)
    shift_sigma: np.ndarray  # the refinement's std per frame (0 without refinement)
    shift_cov: np.ndarray  # the given registration-error covariance of the kept frames
    keep: np.ndarray  # bool per input frame
    lk_noise: float  # the refinement's multi-frame noise estimate (NaN if not run)
    disputed: np.ndarray | None = None  # per input frame: given-vs-registered gap used (LR px)


def _solve_hermitian(m: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve the batched Hermitian positive-definite systems ``m x = b``, shape (..., k, k)."""
    return np.linalg.solve(m, b[..., None])[..., 0]


def _consistent_padding(
    frames: np.ndarray,
    ishift: np.ndarray,
    resid: np.ndarray,
    pad: int,
    hp: int,
    wp: int,
    buf: np.ndarray | None = None,
) -> Iterator[np.ndarray]:
    """Pad every frame to ``(hp, wp)`` with one consistent extension of the scene, one by one.

    Parameters
    ----------
    frames : numpy.ndarray
        (N, H, W) frames, frame 0 the reference.
    ishift, resid : numpy.ndarray
        (N, 2) integer and sub-pixel parts of each frame's shift (LR px).
    pad : int
        LR px of padding before the first row and column.
    hp, wp : int
        Padded size.
    buf : numpy.ndarray, optional
        float32 ``(hp, wp)`` array to pad into (default: a new one).

    Yields
    ------
    numpy.ndarray
        Each frame padded, float32 (hp, wp), in order (one buffer, overwritten at the next
        frame: use it before asking for the next).

    Notes
    -----
    The reference is reflect-padded; every other frame's padding (and the strip its
    integer shift leaves empty) is that padded reference moved by the frame's sub-pixel
    shift (an 8-tap Lanczos fractional delay, :func:`~subpix_ros.core.filters.fractional_shift`,
    computed on the padding strips only), so all frames see the same scene outside the
    image, as the periodic model assumes. Frame n's own pixels fill the area they cover.
    """
    n, h, w = frames.shape
    if buf is None:
        buf = np.empty((hp, wp), dtype=np.float32)
    ref = cv2.copyMakeBorder(
        np.asarray(stored(frames, 0), dtype=np.float32),  # a FrameStack's own pixels
        pad,
        hp - h - pad,
        pad,
        wp - w - pad,
        cv2.BORDER_REFLECT_101,
    )
    for i in range(n):  # per frame
        iu, iv = int(ishift[i, 0] - ishift[0, 0]), int(ishift[i, 1] - ishift[0, 1])
        du, dv = float(resid[i, 0] - resid[0, 0]), float(resid[i, 1] - resid[0, 1])
        # frame i's pixel (r, c) sits at preshifted position (r - iu, c - iv)
        r0, r1 = max(0, -iu), min(h, h - iu)
        c0, c1 = max(0, -iv), min(w, w - iv)
        if r1 > r0 and c1 > c0:
            inner = (slice(pad + r0, pad + r1), slice(pad + c0, pad + c1))
            buf[inner] = stored(frames, i, slice(r0 + iu, r1 + iu), slice(c0 + iv, c1 + iv))
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
                buf[win] = ref[win]
            else:
                buf[win] = fractional_shift(ref, du, dv, window=win)
        yield buf


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
    motion_blur: tuple[float, float] = (0.0, 0.0),
    pixel_fill: float = 1.0,
    hr_dtype=np.float64,
    workspace: Workspace | None = None,
    prior: str = "powerlaw",
) -> MapSolution:
    """Compute the MAP estimate of eq. 9 for translated frames, per LR frequency bin.

    Parameters
    ----------
    frames : numpy.ndarray
        (N, H, W) float64 frames, frame 0 the reference.
    shifts : numpy.ndarray
        (N, 2) shifts ``(u, v)`` (LR px) relative to frame 0: content at (r, c) in frame 0
        is at (r + u, c + v) in frame n.
    p : int
        Resolution factor.
    blur_sigma : float
        Optics blur std (LR px).
    noise_sigma : float or None
        Per-pixel noise std (DN); estimated from the frames if None.
    shift_cov : numpy.ndarray
        (N, 2, 2) registration-error covariance of the given shifts (LR px^2).
    reg : float
        Prior strength multiplier.
    refine_shifts : bool
        Refine the shifts (:func:`~subpix_ros.core.superres.geometry._refine_shifts`).
    pad : int
        Reflected padding (LR px).
    integer_valued : bool or None, optional
        Whether the data are integers (rounding-noise floor); checked on the data if None.
    lowpassed : _WholeLowpass or None, optional
        Shared whole-frame low-passes of ``frames``.
    motion_blur : (float, float), optional
        Image motion during the exposure ``d = (du, dv)`` (LR px, rows and cols; default
        none), common to every frame.
    pixel_fill : float, optional
        The pixel aperture's width (LR px; default 1: the full pixel), as in
        ``frame_transfer_1d``.
    hr_dtype : numpy dtype, optional
        The image's type: float64 (default) or float32 (the single-precision solve's own
        values, a view of its padded output: no double-precision copy of the HR image).
    workspace : Workspace or None, optional
        Buffers reused for the frame spectra, the padded frame and the HR spectrum (the
        returned image is never one of them).
    prior : {"powerlaw", "rolloff"}, optional
        The image prior: ``c |f|^-alpha`` (default) or that times a Gaussian roll-off
        ``exp(-4 pi^2 p^2 s^2 |f|^2)``, s fitted too
        (:func:`~subpix_ros.core.superres.spectrum.fit_rolloff_spectrum`).

    Returns
    -------
    MapSolution

    Raises
    ------
    ValueError
        If no frame other than the reference can be registered to it.

    Notes
    -----
    Per LR bin the model is ``Y_n = sum_m a_nm X_m + e_n`` over the p^2 aliased HR bins m,
    with ``a_nm`` from ``frame_transfer_1d`` (box, blur, shift, times the expected-transfer
    factor ``E_nm = exp(-2 pi^2 f_m^T C_n f_m)`` of the registration error covariance
    ``C_n``), noise variance ``v_n = HW sigma^2 + sum_m |a_nm|^2 P_m (1 - E_nm^2)`` and the
    prior ``E|X_m|^2 = P_m = c |f_m|^-alpha`` (times ``exp(-4 pi^2 p^2 s^2 |f_m|^2)`` with
    ``prior="rolloff"``; DC unregularised). The MAP solution
    ``X = (A^H V^-1 A + reg P^-1)^-1 A^H V^-1 Y``, all bins at once, in this information form
    whatever N (eq. 9's covariance form ``X = P A^H (A P A^H + V/reg)^-1 Y``, smaller when
    N < p^2, loses every component to the DC's unbounded prior variance in round-off).
    """
    h, w = frames.shape[1:]
    hp = cv2.getOptimalDFTSize(h + 2 * pad)
    wp = cv2.getOptimalDFTSize(w + 2 * pad)
    wc = wp // 2 + 1
    registered = _register(frames, shifts, shift_cov, noise_sigma, refine_shifts, lowpassed)
    n = registered.frames.shape[0]
    padded = _consistent_padding(
        registered.frames,
        registered.ishift,
        registered.resid,
        pad,
        hp,
        wp,
        buf=work_array(workspace, "padded", (hp, wp), np.float32),
    )
    spec = work_array(workspace, "spectra", (n, hp, wc), np.complex64)
    for i, frame in enumerate(padded):  # per frame: single-precision DFT, rfft half
        _rfft2_32(frame, out=spec[i])
    c_psd, alpha, s_roll, noise_sigma = _fit_prior(
        registered, p, blur_sigma, noise_sigma, integer_valued, motion_blur, pixel_fill, prior
    )
    noise_power = hp * wp * noise_sigma**2
    c = c_psd * p * p * hp * wp  # prior in HR DFT units: E|X|^2 = (p hp)(p wp) S_x
    cov = _error_covariance(registered.shift_cov, registered.shift_sigma, refine_shifts)
    xs, wsum, resid_ratio = _solve_bins(
        spec,
        registered.resid,
        p,
        blur_sigma,
        cov,
        c,
        alpha,
        reg,
        noise_power,
        (hp, wp),
        motion_blur,
        pixel_fill,
        rolloff_coefficient(p, s_roll),
    )
    img = _assemble_hr(xs, hp, wp, workspace)
    out = img[p * pad : p * (pad + h), p * pad : p * (pad + w)]
    if out.dtype != hr_dtype:
        out = out.astype(hr_dtype)
    sol = _per_input_frame(
        out, shifts, registered, cov, wsum, resid_ratio, (c_psd, alpha), noise_sigma
    )
    sol.rolloff = s_roll
    return sol


def _register(
    frames: np.ndarray,
    shifts: np.ndarray,
    shift_cov: np.ndarray,
    noise_sigma: float | None,
    refine_shifts: bool,
    lowpassed: _WholeLowpass | None,
) -> _Registered:
    """Register the frames against frame 0 and leave out those that fail or disagree.

    The refinement runs when the shifts are refined or the noise is to be estimated (its
    residual gives the multi-frame noise estimate). Frames whose registration failed, or
    whose residual variance exceeds 9x the median (moving objects, a wrong frame), are
    left out; ValueError if none but the reference is left.
    """
    n = frames.shape[0]
    ishift = np.rint(shifts).astype(np.int64)
    resid = shifts - ishift
    shift_sigma_fit = np.zeros(n)
    lk_noise = float("nan")
    keep = np.ones(n, dtype=bool)
    disputed = None
    if refine_shifts or noise_sigma is None:
        refined, shift_sigma_fit, lk_noise, resvar = _refine_shifts(
            frames, ishift, resid, lowpassed=lowpassed
        )
        if refine_shifts:
            resid = refined
        else:
            disputed = _disputed_shifts(refined, resid, shift_sigma_fit)
            resid = np.where(disputed[:, None] > 0, refined, resid)
            shift_cov = np.array(shift_cov, dtype=np.float64)
            var = np.maximum(np.where(disputed > 0, shift_sigma_fit, 0.0) ** 2, 0.003**2)
            shift_cov[disputed > 0] = np.eye(2) * var[disputed > 0, None, None]
            shift_sigma_fit = np.where(np.isfinite(shift_sigma_fit), 0.0, np.inf)
        keep = np.isfinite(shift_sigma_fit)
        if np.isfinite(resvar[1:]).any():
            keep[1:] &= np.isfinite(resvar[1:]) & (
                resvar[1:] <= 9.0 * np.nanmedian(resvar[1:]) + 1e-12
            )
        keep[0] = True
        if keep.sum() < 2:
            raise ValueError("no frame other than the reference could be registered to it")
        if not keep.all():
            frames, ishift, resid, shift_sigma_fit = (
                frames[keep],
                ishift[keep],
                resid[keep],
                shift_sigma_fit[keep],
            )
            shift_cov = np.asarray(shift_cov)[keep]
    return _Registered(frames, ishift, resid, shift_sigma_fit, shift_cov, keep, lk_noise, disputed)


DISPUTE_MIN_PX = 0.03  # a given shift this far (and 8 std) from the frames' own is not used
DISPUTE_SIGMAS = 8.0


def _disputed_shifts(refined: np.ndarray, given: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """Return per frame how far a given shift is from the frames' own registration, if too far.

    Parameters
    ----------
    refined : numpy.ndarray
        (N, 2) sub-pixel shifts registered on the frames
        (:func:`~subpix_ros.core.superres.geometry._refine_shifts`, LR px).
    given : numpy.ndarray
        (N, 2) sub-pixel parts of the given shifts (LR px).
    sigma : numpy.ndarray
        (N,) std of the registered shifts (LR px; inf where it failed).

    Returns
    -------
    numpy.ndarray
        (N,) ``d = max(|refined - given|)`` over the two axes where
        ``d > max(DISPUTE_MIN_PX, DISPUTE_SIGMAS sigma)``, else 0 (always 0 for frame 0
        and for frames whose registration failed).

    Notes
    -----
    Shifts given by the shift stage agree with the refinement to <= 0.02 px on the
    independent degradation model's flights (30-50 dB, blur 0.2-0.9 px, x2-x4); a shift
    off by more is an unmodelled registration error that, used as given, can put the
    reconstruction below bicubic (see docs/design-notes.md, "Given shifts checked").
    """
    d = np.abs(np.asarray(refined) - np.asarray(given)).max(axis=1)
    ok = np.isfinite(sigma) & np.isfinite(d)
    bad = ok & (d > np.maximum(DISPUTE_MIN_PX, DISPUTE_SIGMAS * np.where(ok, sigma, 0.0)))
    bad[0] = False
    return np.where(bad, d, 0.0)


def _fit_prior(
    registered: _Registered,
    p: int,
    blur_sigma: float,
    noise_sigma: float | None,
    integer_valued: bool | None,
    motion_blur: tuple[float, float] = (0.0, 0.0),
    pixel_fill: float = 1.0,
    prior: str = "powerlaw",
) -> tuple[float, float, float, float]:
    """Fit the prior and settle the noise level: ``(c_psd, alpha, s, noise_sigma)``.

    The prior is fitted (:func:`~subpix_ros.core.superres.spectrum.fit_spectrum`, or
    ``fit_rolloff_spectrum`` with ``prior="rolloff"``, else s = 0; through the
    motion blur's transfer too if any) on the central crop of the first two integer-preshifted
    frames. An unknown noise level is the
    registration's multi-frame estimate, else the fit's, floored at the rounding noise
    ``1/sqrt(12)`` DN of integer data (0.05 DN otherwise; the prior is refitted with the
    floor); the result is never below 0.05 DN.
    """
    frames, ishift = registered.frames, registered.ishift
    n, h, w = frames.shape
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
    if noise_sigma is None and np.isfinite(registered.lk_noise):
        noise_sigma = registered.lk_noise
    kw = dict(motion_blur=motion_blur, pixel_fill=pixel_fill)
    fit = functools.partial(_fit_shape, prior, pre, p, blur_sigma, **kw)
    c_psd, alpha, s_roll, sig_fit = fit(noise_sigma)
    if noise_sigma is None:
        if integer_valued is None:  # integer dtypes are known to be; float data are checked
            integer_valued = (
                frames.all_integer_valued()
                if isinstance(frames, FrameStack)
                else bool(np.all(frames == np.rint(frames)))
            )
        floor = 1.0 / np.sqrt(12.0) if integer_valued else 0.05
        noise_sigma = max(sig_fit, floor)
        if sig_fit < floor:  # refit the prior level with the floor as the noise
            c_psd, alpha, s_roll, _ = fit(noise_sigma)
    return c_psd, alpha, s_roll, max(noise_sigma, 0.05)


def _fit_shape(prior: str, pre, p, blur_sigma, noise_sigma, **kw) -> tuple[float, ...]:
    """Return ``(c_psd, alpha, s, sigma)`` of the prior ``prior`` (s = 0 for "powerlaw")."""
    if prior == "rolloff":
        return fit_rolloff_spectrum(pre, p, blur_sigma, noise_sigma, **kw)
    c_psd, alpha, sig = fit_spectrum(pre, p, blur_sigma, noise_sigma, **kw)
    return c_psd, alpha, 0.0, sig


def _error_covariance(
    shift_cov: np.ndarray, shift_sigma_fit: np.ndarray, refine_shifts: bool
) -> np.ndarray:
    """Return the registration-error covariance per frame (LR px^2); frame 0's is zero.

    Refined shifts carry the refinement's own variance (isotropic, floor ``0.003^2``;
    1 for a frame whose std is not finite); otherwise the given ``shift_cov``.
    """
    cov = np.array(shift_cov, dtype=np.float64).copy()
    if refine_shifts:
        fit_var = np.where(np.isfinite(shift_sigma_fit), shift_sigma_fit**2, 1.0)
        cov = np.eye(2)[None] * (np.maximum(fit_var, 0.003**2))[:, None, None]
    cov[0] = 0.0
    return cov


def _solve_bins(
    spec: np.ndarray,
    resid: np.ndarray,
    p: int,
    blur_sigma: float,
    cov: np.ndarray,
    c: float,
    alpha: float,
    reg: float,
    noise_power: float,
    padded_shape: tuple[int, int],
    motion_blur: tuple[float, float] = (0.0, 0.0),
    pixel_fill: float = 1.0,
    rolloff: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solve every LR bin: ``(xs, wsum, resid_ratio)``.

    When the registration error is negligible at all frequencies (relative transfer loss
    ``2 pi^2 max tr(C) / 2 < 1e-3``) the weights are constant and the separable solver is
    used; otherwise :func:`_solve_uncertain`. ``wsum`` is each frame's summed ``|a|^2``
    weight at DC (alias 0, row and column 0). A motion blur enters as a prior gain
    ``|M|^2`` on ``Z = M X``, then ``X = Z / M`` (see :func:`_fourier_map`). ``rolloff`` is
    ``k`` of the prior's roll-off ``exp(-k |f|^2)`` (0: none).
    """
    hp, wp = padded_shape
    n = spec.shape[0]
    ay, fy = _frame_transfers(hp, p, resid[:, 0], blur_sigma, pixel_fill=pixel_fill)
    ax, fx = _frame_transfers(wp, p, resid[:, 1], blur_sigma, wp // 2 + 1, pixel_fill)
    max_var = float(np.max(cov[:, 0, 0] + cov[:, 1, 1]))
    moving = tuple(motion_blur) != (0.0, 0.0)
    if 2.0 * np.pi**2 * max_var * 0.5 < 1e-3:
        gain = None
        if moving:
            gain = [
                functools.partial(_motion_prior_gain, fy[m1], fx[m2], p, motion_blur)
                for m1 in range(p)
                for m2 in range(p)
            ]
        xs = _solve_separable(
            spec,
            ay,
            ax,
            fy,
            fx,
            c,
            alpha,
            reg,
            noise_power,
            shifts=resid,
            prior_gain=gain,
            rolloff=rolloff,
        )
        wsum = np.sum(np.abs(ay[:, 0]) ** 2, axis=1) * np.sum(np.abs(ax[:, 0]) ** 2, axis=1)
        out = xs, wsum, np.full(n, np.nan)
    else:
        out = _solve_uncertain(
            spec,
            ay,
            ax,
            fy,
            fx,
            cov,
            c,
            alpha,
            reg,
            noise_power,
            motion_blur if moving else None,
            rolloff,
        )
    if moving:
        xs = out[0]
        for m1 in range(p):  # X = Z / M, alias by alias (memory: one (hp, wc) gain at a time)
            for m2 in range(p):
                xs[m1, m2] /= _motion_gain(fy[m1][:, None], fx[m2][None, :], p, motion_blur)
    return out


MOTION_MIN_GAIN = 1e-3  # |M| floor of the motion blur's transfer in the model (X = Z / M)


def _motion_gain(fy: np.ndarray, fx: np.ndarray, p: int, motion_blur) -> np.ndarray:
    """Return the motion blur's transfer ``M`` with ``|M|`` floored at ``MOTION_MIN_GAIN``.

    float32, broadcast of ``fy`` and ``fx`` (cycles / HR px); the sign is kept (+ at 0).
    """
    m = motion_transfer(fy, fx, p, motion_blur)
    return np.where(
        np.abs(m) < MOTION_MIN_GAIN, np.where(m < 0, -MOTION_MIN_GAIN, MOTION_MIN_GAIN), m
    ).astype(np.float32)


def _motion_prior_gain(
    fy: np.ndarray, fx: np.ndarray, p: int, motion_blur, r0: int, r1: int
) -> np.ndarray:
    """Return ``|M|^2`` (:func:`_motion_gain`) of spectrum rows ``r0 .. r1``: (R, wc) float32."""
    return np.square(_motion_gain(fy[r0:r1, None], fx[None, :], p, motion_blur))


def _solve_uncertain(
    spec: np.ndarray,
    ay: np.ndarray,
    ax: np.ndarray,
    fy: np.ndarray,
    fx: np.ndarray,
    cov: np.ndarray,
    c: float,
    alpha: float,
    reg: float,
    noise_power: float,
    motion_blur: tuple[float, float] | None = None,
    rolloff: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solve every bin with per-frame expected transfers and noise (see :func:`_fourier_map`).

    Chunks of LR spectrum rows bound the memory. With ``motion_blur`` the prior is that of
    ``Z = M X`` (``|M|^2 P``; the caller divides by M); ``rolloff`` is ``k`` of the prior's
    roll-off ``exp(-k |f|^2)``. Returns ``(xs, wsum, resid_ratio)``: the
    alias components, each frame's summed weight ``|a|^2 / v`` at kx = 0, and its mean
    normalised residual ``|Y - A X|^2 / v`` over the bins.
    """
    n, p, hp = ay.shape
    wc = ax.shape[2]
    k = p * p
    xs = np.zeros((p, p, hp, wc), dtype=np.complex64)
    resid_ratio = np.zeros(n)
    wsum = np.zeros(n)
    chunk = max(1, int(4e5 // (n * k * wc)))
    for r0 in range(0, hp, chunk):  # chunks of LR spectrum rows (memory bound)
        r1 = min(hp, r0 + chunk)
        sol, res2, w2 = _solve_rows(
            spec[:, r0:r1, :],
            ay[:, :, r0:r1],
            ax,
            fy[:, r0:r1],
            fx,
            cov,
            c,
            alpha,
            reg,
            noise_power,
            motion_blur,
            rolloff,
        )
        xs[:, :, r0:r1, :] = sol.T.reshape(p, p, r1 - r0, wc)
        resid_ratio += res2
        wsum += w2
    resid_ratio /= hp * wc
    return xs, wsum, resid_ratio


def _solve_rows(
    spec_rows: np.ndarray,
    ay_rows: np.ndarray,
    ax: np.ndarray,
    fyc: np.ndarray,
    fx: np.ndarray,
    cov: np.ndarray,
    c: float,
    alpha: float,
    reg: float,
    noise_power: float,
    motion_blur: tuple[float, float] | None = None,
    rolloff: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Solve the bins of a block of LR spectrum rows (:func:`_solve_uncertain`).

    Returns the solution in batch layout (bins, k), and the block's per-frame sums of
    ``|Y - A X|^2 / v`` and of ``|a|^2 / v`` at kx = 0.
    """
    n, p = ay_rows.shape[:2]
    k = p * p
    f2y = fyc[:, None, :, None] ** 2  # (p,1,R,1)
    f2x = fx[None, :, None, :] ** 2  # (1,p,1,wc)
    fxy = fyc[:, None, :, None] * fx[None, :, None, :]
    fr = np.sqrt(f2y + f2x)
    prior = np.where(fr > 0, c * np.maximum(fr, 1e-6) ** (-alpha), 1e30)  # (p,p,R,wc)
    if rolloff > 0:  # P(f) exp(-k |f|^2), the exponent capped
        prior = prior / rolloff_precision(f2y + f2x, rolloff)
    if motion_blur is not None:  # the prior of Z = M X
        prior = prior * np.square(
            _motion_gain(fyc[:, None, :, None], fx[None, :, None, :], p, motion_blur),
            dtype=np.float64,
        )
    a0 = ay_rows[:, :, None, :, None] * ax[:, None, :, None, :]  # (n,p,p,R,wc)
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
    var = noise_power + np.sum(np.abs(a0) ** 2 * prior * (1.0 - e**2), axis=(1, 2))  # (n,R,wc)
    # batch layout (bins, n, k)
    ab = a.reshape(n, k, -1).transpose(2, 0, 1)
    vb = var.reshape(n, -1).T
    yb = spec_rows.reshape(n, -1).T
    pb = prior.reshape(k, -1).T / reg
    # information form (k x k per bin) whatever n: the covariance form (n x n, cheaper for
    # n < k) mixes the DC's 1e30 prior variance with the rest of C_yy and loses every other
    # component to round-off (a finite image hundreds of dB off, measured for n < p^2)
    aw = np.conj(ab).transpose(0, 2, 1) / vb[:, None, :]  # (B,k,n)
    gram = aw @ ab
    idx = np.arange(k)
    gram[:, idx, idx] += 1.0 / pb
    sol = _solve_hermitian(gram, (aw @ yb[..., None])[..., 0])
    res = yb - (ab @ sol[..., None])[..., 0]
    return sol, np.sum(np.abs(res) ** 2 / vb, axis=0), np.sum(np.abs(ab[:, :, 0]) ** 2 / vb, axis=0)


def _per_input_frame(
    image: np.ndarray,
    shifts: np.ndarray,
    registered: _Registered,
    cov: np.ndarray,
    wsum: np.ndarray,
    resid_ratio: np.ndarray,
    prior: tuple[float, float],
    noise_sigma: float,
) -> MapSolution:
    """Report the solve per input frame: dropped frames get weight 0, their shift, std inf."""
    keep = registered.keep
    disputed = registered.disputed
    if disputed is not None and not keep.all():
        disputed = disputed.copy()
        disputed[~keep] = 0.0
    shift_sigma = np.sqrt(np.maximum(cov[:, 0, 0], cov[:, 1, 1]))
    weights = wsum / max(wsum[0], 1e-30)
    used = registered.ishift + registered.resid
    if keep.all():
        return MapSolution(
            image, used, shift_sigma, weights, prior, noise_sigma, keep, resid_ratio, disputed
        )
    w_full = np.zeros(keep.size)
    w_full[keep] = weights
    sh_full = shifts.astype(np.float64).copy()
    sh_full[keep] = used
    sg_full = np.full(keep.size, np.inf)
    sg_full[keep] = shift_sigma
    return MapSolution(image, sh_full, sg_full, w_full, prior, noise_sigma, keep, None, disputed)
