"""Super-resolution reconstruction from sub-pixel shifted frames (METHODS.md B).

Entry points :func:`reconstruct` (mono) and :func:`reconstruct_colour` (BGR). Methods:

* ``"map"`` (default): the MAP estimate of eq. 9 with a stationary Gaussian prior,
  solved in the Fourier domain (:mod:`.fourier_map`): per LR frequency bin a
  factor^2 x factor^2 (or N x N, eq. 9's own form, whichever is smaller) Hermitian
  system, O(pixels log pixels). Data-driven settings: shifts refined against frame 0
  (:mod:`.geometry`), the noise std from the residual of that registration, the prior
  ``S_x(f) = c |f|^-alpha`` fitted to the frames' spectrum (:mod:`.spectrum`).
  Frames that fail registration or disagree with the reference are left out; a
  registration-error covariance enters the model as an expected transfer
  ``exp(-2 pi^2 f^T C f)`` plus an extra noise term. With homographies (given, or
  affines detected by tile registration, ``geometry="auto"``) or masks, the same
  objective is solved by conjugate gradients (``"map-cg"``, :mod:`.cg_map`) with each
  frame's geometry inside the forward model, warm-started from the Fourier solution.
* ``"windowed"``: eq. 7 (normalised) as one separable filter on the interleaved grid,
  then a Gaussian of ``WINDOWED_SMOOTH_LR_PX`` LR px (eq. 9's Gaussian
  regularisation); needs shifts on the k/p grid.
* ``"pinv"``: eq. 6, reference only (unstable; O(n^3)).
* ``"bicubic"``: bicubic upscaling of the reference frame (the baseline).

No sub-pixel diversity, no frame registrable to the reference, a solver failure, or
shifts off the grid for eqs. 6/7 return the bicubic image with ``fell_back=True`` and
a reason. Frames that agree with each other under a wrong common model (e.g. a much
wrong ``blur_sigma``) are not detected.

Output grid: LR pixel i of frame 0 covers output pixels ``factor i .. factor i +
factor - 1`` (pixel centres aligned as in ``cv2.resize``); the outermost LR-pixel
ring of a MAP result is bicubic (only the reference observes it). Intensities keep
the input scale (eq. 3 taken as a mean, not a sum).

References
----------
.. [1] S. A. Stankevich, S. V. Shklyar, N. S. Lubskyi, "Increasing the spatial
   resolution of aerial imaging by sub-pixel image registration", 2013
   (docs/METHODS.md, B: eqs. 3-9).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from ..blur import BlurEstimate, estimate_blur, parse_blur_sigma
from .cg_map import _cg_map
from .fourier_map import PRIORS, MapSolution, _fourier_map
from .geometry import detect_geometry
from .lowpass import _WholeLowpass
from .luma import frame_luminance, packed_dtype
from .model import motion_blur_vector, translation_homography
from .paper import grid_offsets, interleave, pinv_solution, windowed_solution
from .result import (
    BLUR_AUTO,
    WINDOWED_SMOOTH_LR_PX,
    NonFiniteImageError,
    SRResult,
    _bicubic_rim,
    _fallback,
    bicubic_upscale,
    context_bands,
    to_integer_image,
)
from .spectrum import estimate_noise_sigma, rolloff_coefficient
from .validation import FrameStack, _check_options, _small_ints, _validate
from .workspace import Workspace, work_array

__all__ = ["reconstruct", "reconstruct_colour"]

DIVERGED_SPANS = 4.0  # a MAP image further than this many intensity spans out of range diverged


def reconstruct(
    frames: Sequence[np.ndarray],
    shifts: np.ndarray | Sequence[Sequence[float]] | None,
    factor: int,
    *,
    blur_sigma=0.4,
    pixel_fill: float | None = None,
    **kw,
) -> SRResult:
    """Reconstruct a factor-x super-resolved image from N >= 2 shifted LR frames.

    Parameters
    ----------
    frames : sequence of numpy.ndarray
        N 2-D frames of one shape (any numeric dtype, DN); frame 0 is the reference.
    shifts : array_like or None
        (N, 2) shifts ``(u, v)`` in LR px: content at (r, c) in frame 0 is at
        (r + u, c + v) in frame n. None with ``homographies``.
    factor : int
        Resolution factor, 2 to 4.
    blur_sigma : float, str or BlurEstimate, optional
        Optics blur std in LR px (Gaussian PSF of the model): a number (e.g. a lab
        calibration), ``"auto"`` (:data:`BLUR_AUTO`: measured on straight edges in the
        frames, :func:`subpix_ros.core.blur.estimate_blur`; only "map" uses a blur), or a
        :class:`subpix_ros.core.blur.BlurEstimate` (e.g. a flight's calibration).
    pixel_fill : float, optional
        The pixel aperture's width (LR px, the fill factor, in (0, 1]); default None: the
        blur estimate's ``fill_factor`` (measured with ``"auto"`` or a BlurEstimate, else 1:
        the full pixel, the model of before bit for bit). Used by the Fourier solve; the CG
        refinement (masks, homographies) keeps the full pixel.
    **kw
        Keyword-only options:

        - ``method``: "map" (default, eq. 9), "windowed" (eq. 7, normalised), "pinv"
          (eq. 6, reference only) or "bicubic";
        - ``masks``: a bool array per frame (True = valid); forces the CG solver;
        - ``shift_cov``: (N, 2, 2) registration-error covariance of the given shifts
          (LR px^2); ignored when ``refine_shifts`` (the refinement's own is used);
        - ``homographies``: (N, 3, 3) reference -> frame LR pixel coordinates (replaces
          shifts; forces the CG solver);
        - ``motion_blur``: ``(du, dv)``, the image motion during the exposure (LR px, rows
          and cols, e.g. exposure x image velocity; default None = none): the PSF becomes
          optics Gaussian x pixel box x a 1-D box of length ``|(du, dv)|`` along it, common
          to every frame (only "map" uses it; see Notes);
        - ``noise_sigma``: per-pixel noise std (DN); estimated from the frames if None;
        - ``reg``: prior strength multiplier (1 = the prior fitted to the data);
        - ``prior``: the image prior of "map", ``"powerlaw"`` (default,
          ``S_x(f) = c |f|^-alpha``) or ``"rolloff"`` (that times a Gaussian roll-off
          ``exp(-4 pi^2 p^2 s^2 |f|^2)``, s in LR px fitted with c and alpha:
          :func:`~subpix_ros.core.superres.spectrum.fit_rolloff_spectrum`);
        - ``refine_shifts``: refine the shifts against frame 0 (default True);
        - ``geometry``: "auto" (default) checks by tile registration
          (:func:`detect_geometry`) whether the frames are related by more than a
          translation and if so solves with each frame's fitted affine (CG);
          "translation" skips the check;
        - ``window``: eq. 7 window w (default factor + 2);
        - ``pad``: reflected padding of the Fourier solve (LR px, default 16);
        - ``cg_iters``: conjugate-gradient iterations (default 30);
        - ``hr_dtype``: ``numpy.float64`` (default) or ``numpy.float32``, the image's type
          from the Fourier solve (float32: its single-precision values without a
          double-precision copy; the CG refinement returns float64 either way);
        - ``workspace``: a :class:`~subpix_ros.core.superres.workspace.Workspace` whose
          buffers the Fourier solve reuses (frame spectra, padded frame, HR spectrum) instead
          of allocating them anew: pass the same one for every set of a stream.

    Returns
    -------
    SRResult
        With the blur used and its source (``blur_sigma``, ``blur_source``, ``blur_reason``).

    Raises
    ------
    ValueError
        On malformed input (fewer than 2 frames, mismatched shapes, factor outside 2..4,
        bad shifts, unknown method, a motion blur that is not two finite numbers).

    Notes
    -----
    The motion blur's transfer is ``M(nu) = sinc(nu . d)``, ``d = (du, dv)`` LR px, ``nu``
    in cycles / LR px (numpy's ``sinc``; real and even: the sign of ``d`` does not matter).
    It multiplies the optics and pixel transfers; the frame's shift is its mid-exposure
    position. The Fourier solve estimates ``Z = M X`` with the prior ``|M|^2 P`` and returns
    ``X = Z / M``; the CG solve filters the HR grid by the same transfer
    (:func:`~subpix_ros.core.superres.model.motion_filter`).

    A pixel fill ``w != 1`` replaces the model's pixel box (the mean over the p x p HR
    pixels of an LR pixel) by a continuous box of ``w`` LR px about the pixel centre, per
    axis ``sinc(w nu)`` (``frame_transfer_1d``).
    """
    est = _resolve_blur(blur_sigma, frames, shifts, kw.get("method", "map"), kw.get("motion_blur"))
    fill = float(getattr(est, "fill_factor", 1.0)) if pixel_fill is None else float(pixel_fill)
    if not 0.0 < fill <= 1.0:
        raise ValueError(f"pixel_fill must be in (0, 1] (LR px), got {pixel_fill!r}")
    res = _reconstruct(frames, shifts, factor, blur_sigma=est.sigma, pixel_fill=fill, **kw)
    res.blur_sigma, res.blur_source, res.blur_reason = float(est.sigma), est.source, est.reason
    return res


def _resolve_blur(blur_sigma, frames, shifts, method: str, motion_blur=None) -> BlurEstimate:
    """Turn a ``blur_sigma`` setting into a :class:`BlurEstimate` (measured for "auto").

    "auto" measures the edges with the motion blur taken out (``estimate_blur``).
    """
    if isinstance(blur_sigma, BlurEstimate):
        return blur_sigma
    value = parse_blur_sigma(blur_sigma)
    if value != BLUR_AUTO:
        return BlurEstimate(float(value), "parameter", reason="given")
    if (
        method == "map"
        and frames is not None
        and len(frames) >= 2
        and all(np.ndim(f) == 2 for f in frames)
    ):
        sh = None if shifts is None else np.asarray(shifts, dtype=np.float64)
        if sh is not None and (sh.shape != (len(frames), 2) or not np.isfinite(sh).all()):
            sh = None  # malformed shifts: _reconstruct says why
        return estimate_blur(frames, sh, motion_blur=motion_blur_vector(motion_blur))
    # the blur is not used (or the input is malformed: _reconstruct says why)
    return BlurEstimate(0.0, "unused", reason="the method does not model the blur")


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
    prior: str = "powerlaw",
    refine_shifts: bool = True,
    geometry: str = "auto",
    window: int | None = None,
    pad: int = 16,
    cg_iters: int = 30,
    motion_blur: tuple[float, float] | None = None,
    pixel_fill: float = 1.0,
    hr_dtype=np.float64,
    workspace: Workspace | None = None,
) -> SRResult:
    """Reconstruct with a numeric blur; the options of :func:`reconstruct`."""
    if np.dtype(hr_dtype) not in (np.float32, np.float64):
        raise ValueError(f"hr_dtype must be float32 or float64, got {hr_dtype!r}")
    motion = motion_blur_vector(motion_blur)
    arrs, rel, p = _validate(frames, shifts, factor, masks, shift_cov, homographies)
    n = len(arrs)
    _check_options(method, geometry, blur_sigma, reg, noise_sigma)
    if prior not in PRIORS:
        raise ValueError(f"unknown prior {prior!r}; choose from {PRIORS}")
    # single-frame estimate for the non-MAP paths and fallbacks (MAP estimates it jointly)
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
            shifts=np.zeros((n, 2)) if rel is None else rel,
            shift_sigma=np.zeros(n),
            factor=p,
        )
    if rel is not None and homographies is None:
        phase = (rel - rel[0] + 0.5) % 1.0 - 0.5  # sub-pixel phase relative to frame 0, LR px
        if np.max(np.abs(phase)) < 0.05:
            return _fallback(
                ref,
                p,
                "all frames have the same sub-pixel phase: no new information",
                sigma,
                n,
                rel,
            )
    if method in ("windowed", "pinv"):
        return _paper_method(arrs, rel, p, method, window, sigma)
    opts = _MapOptions(
        noise_sigma=noise_sigma,
        masks=masks,
        shift_cov=shift_cov,
        homographies=homographies,
        blur_sigma=blur_sigma,
        reg=reg,
        prior=prior,
        refine_shifts=refine_shifts,
        geometry=geometry,
        pad=pad,
        cg_iters=cg_iters,
        motion_blur=motion,
        pixel_fill=pixel_fill,
        hr_dtype=np.dtype(hr_dtype),
        workspace=workspace,
    )
    res = _map_method(arrs, rel, p, sigma, opts, ref)
    if not res.fell_back:
        res.motion_blur = motion
        res.pixel_fill = float(pixel_fill)
    return res


def _paper_method(
    arrs: list[np.ndarray],
    rel: np.ndarray | None,
    p: int,
    method: str,
    window: int | None,
    sigma: float,
) -> SRResult:
    """Reconstruct by eq. 7 ("windowed", then eq. 9's Gaussian) or eq. 6 ("pinv").

    Both need pure translations on the k/p grid; otherwise the bicubic fallback.
    """
    n = len(arrs)
    ref = np.asarray(arrs[0], dtype=np.float64)
    if rel is None:
        return _fallback(ref, p, f"{method} needs pure translations", sigma, n, rel)
    offs = grid_offsets(rel, p, p)
    if offs is None:
        eq = 7 if method == "windowed" else 6
        return _fallback(
            ref, p, f"{method} (eq. {eq}) needs shifts on the k/{p} grid", sigma, n, rel
        )
    # 8/16-bit frames: float32 holds the sums exactly; half the memory traffic
    y, _ = interleave(arrs, offs, p, p, dtype=np.float32 if _small_ints(arrs) else np.float64)
    if method == "windowed":
        x = windowed_solution(y, p, p, w=p + 2 if window is None else window)
        # eq. 9's Gaussian regularisation: without it eq. 7 amplifies noise and aliasing
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
        shifts=rel,
        shift_sigma=np.zeros(n),
        factor=p,
    )


@dataclass
class _MapOptions:
    """The options of a MAP reconstruction (see :func:`reconstruct`)."""

    noise_sigma: float | None
    masks: Sequence[np.ndarray] | None
    shift_cov: np.ndarray | None
    homographies: np.ndarray | None
    blur_sigma: float
    reg: float
    refine_shifts: bool
    geometry: str
    pad: int
    cg_iters: int
    motion_blur: tuple[float, float] = (0.0, 0.0)
    pixel_fill: float = 1.0
    hr_dtype: np.dtype = np.dtype(np.float64)
    workspace: Workspace | None = None
    prior: str = "powerlaw"


def _map_method(
    arrs: list[np.ndarray],
    rel: np.ndarray | None,
    p: int,
    sigma: float,
    opts: _MapOptions,
    ref: np.ndarray,
) -> SRResult:
    """Reconstruct by the MAP estimate: Fourier solve, then CG with geometry or masks.

    ``sigma`` is the noise level reported by a fallback before the solve; ``ref`` is frame 0
    in float64 (fallback and bicubic rim).
    """
    n = len(arrs)
    stack = FrameStack(arrs)  # frames read as float64 one at a time, never all at once
    cov = (
        np.zeros((n, 2, 2))
        if opts.shift_cov is None
        else np.asarray(opts.shift_cov, dtype=np.float64)
    )
    lowpassed = _WholeLowpass(stack)  # shared by the geometry check and the shift refinement
    homographies, trans, noise_sigma, reason = _map_geometry(
        stack, rel, opts.homographies, opts.geometry, opts.noise_sigma, lowpassed
    )
    use_cg = opts.masks is not None or homographies is not None
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
            opts.blur_sigma,
            noise_sigma,
            cov,
            opts.reg,
            opts.refine_shifts and not use_cg,
            opts.pad,
            integer_valued=ints,
            lowpassed=lowpassed,
            motion_blur=opts.motion_blur,
            pixel_fill=opts.pixel_fill,
            hr_dtype=np.float64 if use_cg else opts.hr_dtype,
            workspace=opts.workspace,
            prior=opts.prior,
        )
    except (ValueError, np.linalg.LinAlgError) as exc:
        return _fallback(ref, p, f"MAP solve failed: {exc}", sigma, n, rel)
    img = sol.image
    method_used = "map"
    if use_cg:
        hs = (
            np.asarray(homographies, dtype=np.float64)
            if homographies is not None
            else np.stack([translation_homography(*si) for si in sol.shifts])
        )
        img = _cg_map(
            stack,
            hs,
            p,
            opts.blur_sigma,
            sol.noise_sigma,
            opts.masks,
            sol.prior,
            opts.reg,
            img,
            opts.cg_iters,
            opts.motion_blur,
            rolloff_coefficient(p, sol.rolloff),
        )
        method_used = "map-cg"
    return _map_result(img, ref, p, sol, method_used, reason, rel)


def _map_geometry(
    stack: np.ndarray,
    rel: np.ndarray | None,
    homographies: np.ndarray | None,
    geometry: str,
    noise_sigma: float | None,
    lowpassed: _WholeLowpass,
) -> tuple[np.ndarray | None, np.ndarray, float | None, str]:
    """Settle the geometry of a MAP solve: ``(homographies, translations, noise_sigma, reason)``.

    With ``geometry="auto"`` and frames of at least 96 px, affines detected by tile
    registration replace the translations. With homographies, the Fourier solve uses
    the translation each applies at the frame centre, and an unknown noise level comes
    from the tile registration (where a local translation fits).
    """
    n, h, w = stack.shape
    reason = ""
    if homographies is None and geometry == "auto" and min(h, w) >= 96:
        affines, _, tile_noise = detect_geometry(stack, rel, lowpassed=lowpassed)
        if affines is not None:
            homographies = affines
            reason = (
                "frames related by more than a translation: affine geometry fitted per frame, "
                "solved by CG"
            )
            if noise_sigma is None and np.isfinite(tile_noise):
                noise_sigma = tile_noise
    trans = rel
    if homographies is not None:
        hs = np.asarray(homographies, dtype=np.float64)
        centre = np.array([(w - 1) / 2.0, (h - 1) / 2.0, 1.0])
        trans = np.empty((n, 2))
        for i in range(n):  # the translation each homography applies at the frame centre
            q = hs[i] @ centre
            trans[i] = (q[1] / q[2] - centre[1], q[0] / q[2] - centre[0])
        if noise_sigma is None and min(h, w) >= 96:
            _, _, tile_noise = detect_geometry(stack, trans, lowpassed=lowpassed)
            if np.isfinite(tile_noise):
                noise_sigma = tile_noise
    return homographies, trans, noise_sigma, reason


def _map_result(
    img: np.ndarray,
    ref: np.ndarray,
    p: int,
    sol: MapSolution,
    method_used: str,
    reason: str,
    rel: np.ndarray | None,
) -> SRResult:
    """Check a MAP image (finite, frames other than the reference contributing) and report it.

    An image reaching more than ``DIVERGED_SPANS`` times the reference's intensity span
    beyond its range is a diverged solve (ringing at edges stays far inside that), not an
    estimate: it falls back to bicubic with the reason.
    """
    n = sol.kept.size
    sigma = sol.noise_sigma
    lo_img, hi_img = float(np.min(img)), float(np.max(img))  # NaN and inf propagate
    if not (np.isfinite(lo_img) and np.isfinite(hi_img)):
        return _fallback(ref, p, "MAP solution not finite", sigma, n, rel)
    lo, hi = float(np.min(ref)), float(np.max(ref))
    span = max(hi - lo, 0.25 * max(abs(lo), abs(hi)), 1.0)  # a flat reference: its level
    if lo_img < lo - DIVERGED_SPANS * span or hi_img > hi + DIVERGED_SPANS * span:
        return _fallback(
            ref,
            p,
            f"MAP solution diverged: values {lo_img:.3g} .. {hi_img:.3g} against the frames' "
            f"{lo:.3g} .. {hi:.3g}",
            sigma,
            n,
            rel,
        )
    img = _bicubic_rim(img, ref, p)
    if not sol.kept.all():
        dropped = ", ".join(str(i) for i in np.flatnonzero(~sol.kept))
        reason = (
            reason + "; " if reason else ""
        ) + f"frames {dropped} left out (registration failed or they disagree with the reference)"
    bad = np.zeros(0, int) if sol.disputed is None else np.flatnonzero(sol.disputed > 0)
    if bad.size:
        reason = (reason + "; " if reason else "") + (
            f"given shifts of frames {', '.join(str(i) for i in bad)} disagree with the frames "
            f"by up to {sol.disputed.max():.3f} px: the frames' own registration used for them"
        )
    if float(np.sum(sol.weights[1:])) < 0.05:
        return _fallback(
            ref,
            p,
            "no frame other than the reference agrees with it (registration errors too large)",
            sigma,
            n,
            sol.shifts,
        )
    return SRResult(
        image=img,
        method=method_used,
        noise_sigma=sigma,
        weights=sol.weights,
        shifts=sol.shifts,
        shift_sigma=sol.shift_sigma,
        factor=p,
        reason=reason,
        shifts_disputed=int(bad.size),
    )


def reconstruct_colour(
    frames_bgr: Sequence[np.ndarray],
    shifts: np.ndarray | Sequence[Sequence[float]] | None,
    factor: int,
    out_dtype=None,
    **kwargs,
) -> SRResult:
    """Super-resolve colour frames: luminance by :func:`reconstruct`, chroma upscaled.

    Parameters
    ----------
    frames_bgr : sequence of numpy.ndarray
        HxWx3 BGR frames (OpenCV order), or 2-D frames (then this is :func:`reconstruct`).
        With a BGR frame 0, a 2-D frame after it is a member packed by
        :func:`~subpix_ros.core.superres.luma.pack_luminance` (its luminance; only frame 0's
        chroma is used).
    shifts, factor
        As :func:`reconstruct`.
    out_dtype : numpy dtype, optional
        ``numpy.uint8`` or ``numpy.uint16``: the image rounded (half to even) and clipped
        into that type, as ``to_integer_image`` would round the float32 image. Default None:
        float32.
    **kwargs
        Passed to :func:`reconstruct` (with ``workspace``, the frames' luminance is written
        into its buffer ``"luminance"`` too).

    Returns
    -------
    SRResult
        ``image`` BGR, ``(factor H, factor W, 3)``, float32 (or ``out_dtype``), on the same
        output grid; ``method``, ``fell_back`` and ``reason`` are those of the luminance
        reconstruction.

    Raises
    ------
    NonFiniteImageError
        With ``out_dtype``, if the luminance has a NaN or infinite pixel.

    Notes
    -----
    Each frame's luminance Y (ITU-R BT.601, as ``cv2.COLOR_BGR2YCrCb`` on the frames' own
    scale, single precision) is reconstructed; Cr and Cb of the reference frame are
    bicubic-upscaled (chroma needs far less resolution and would triple the cost).
    Single precision holds 8- and 16-bit data and halves the cost of the largest arrays.
    With ``out_dtype`` the same values are rounded band by band (no whole float32 colour
    image: a quarter of the memory and of its traffic).
    """
    if frames_bgr is None or len(frames_bgr) == 0:
        raise ValueError("no frames")
    arrs = [np.asarray(f) for f in frames_bgr]
    if all(a.ndim == 2 for a in arrs):
        res = reconstruct(arrs, shifts, factor, **kwargs)
        if out_dtype is not None:
            if not np.isfinite(res.image).all():
                raise NonFiniteImageError("reconstruction produced non-finite pixels")
            res.image = to_integer_image(res.image, out_dtype)
        return res
    if (
        arrs[0].ndim != 3
        or arrs[0].shape[2] != 3
        or any(not _member_ok(a, arrs[0]) for a in arrs[1:])
    ):
        raise ValueError(
            "colour frames must be HxWx3 (BGR); a 2-D member must be packed "
            "(pack_luminance: uint16 for uint8 BGR, float32 for uint16 BGR)"
        )
    # luminance of every frame (Y of YCrCb is BGR2GRAY's weighted sum), chroma of the reference
    if all(a.shape[:2] == arrs[0].shape[:2] for a in arrs):  # else reconstruct says which differ
        shape = (len(arrs),) + arrs[0].shape[:2]
        stack = work_array(kwargs.get("workspace"), "luminance", shape, np.float32)
        ys = [frame_luminance(a, out=stack[i]) for i, a in enumerate(arrs)]
    else:
        ys = [frame_luminance(a) for a in arrs]
    # float32 luminance: the colour image is assembled in float32 (no float64 copy of it)
    res = reconstruct(ys, shifts, factor, **{"hr_dtype": np.float32, **kwargs})
    p = res.factor
    h, w = arrs[0].shape[:2]
    if out_dtype is not None:
        res.image = _colour_integer(res.image, arrs[0], p, out_dtype)
        return res
    ycc0 = cv2.cvtColor(arrs[0].astype(np.float32), cv2.COLOR_BGR2YCrCb)
    chroma = cv2.resize(
        np.ascontiguousarray(ycc0[..., 1:]), (w * p, h * p), interpolation=cv2.INTER_CUBIC
    )
    # OpenCV's YCrCb offset depends on the data's scale: converting back with OpenCV keeps it
    merged = cv2.merge([res.image.astype(np.float32), chroma[..., 0], chroma[..., 1]])
    res.image = cv2.cvtColor(merged, cv2.COLOR_YCrCb2BGR, dst=merged)  # in place: 100 MB at 4K
    return res


def _member_ok(frame: np.ndarray, ref: np.ndarray) -> bool:
    """Return True for a member of a colour set: HxWx3 BGR, or packed (:func:`pack_luminance`)."""
    if frame.ndim == 2:
        return frame.dtype == packed_dtype(ref)
    return frame.ndim == 3 and frame.shape[2] == 3


def _colour_integer(
    lum: np.ndarray, ref: np.ndarray, factor: int, dtype, rows: int = 64
) -> np.ndarray:
    """Assemble the BGR image of type ``dtype`` from the HR luminance and the reference's chroma.

    The values are those of the float32 assembly of :func:`reconstruct_colour` rounded by
    :func:`~subpix_ros.core.superres.result.to_integer_image`, made ``rows`` LR rows at a time
    (the chroma of each band upscaled with 4 LR rows of context: :func:`context_bands`), so
    that no whole-frame float colour image exists. NonFiniteImageError if a pixel of ``lum``
    is NaN or infinite.
    """
    if not np.isfinite(lum).all():
        raise NonFiniteImageError("reconstruction produced non-finite pixels")
    h, w = ref.shape[:2]
    p = factor
    out = np.empty((p * h, p * w, 3), dtype)
    for a0, a1, e0, e1 in context_bands(h, rows):
        ycc = cv2.cvtColor(ref[e0:e1].astype(np.float32), cv2.COLOR_BGR2YCrCb)
        chroma = cv2.resize(
            np.ascontiguousarray(ycc[..., 1:]),
            (w * p, (e1 - e0) * p),
            interpolation=cv2.INTER_CUBIC,
        )[p * (a0 - e0) : p * (a1 - e0)]
        band = cv2.merge([lum[p * a0 : p * a1].astype(np.float32), chroma[..., 0], chroma[..., 1]])
        cv2.cvtColor(band, cv2.COLOR_YCrCb2BGR, dst=band)
        out[p * a0 : p * a1] = to_integer_image(band, dtype)
    return out
