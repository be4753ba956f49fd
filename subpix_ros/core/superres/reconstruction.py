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

from dataclasses import dataclass, field
from typing import Sequence

import cv2
import numpy as np

from ..blur import BlurEstimate, estimate_blur, parse_blur_sigma
from .cg_map import _cg_map
from .fourier_map import _fourier_map
from .geometry import detect_geometry
from .lowpass import _WholeLowpass
from .model import translation_homography
from .paper import grid_offsets, interleave, pinv_solution, windowed_solution
from .spectrum import estimate_noise_sigma

__all__ = [
    "SRResult",
    "reconstruct",
    "reconstruct_colour",
    "bicubic_upscale",
    "psnr",
    "METHODS",
    "BLUR_AUTO",
    "MAX_FACTOR",
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
    img = sol.image
    weights = sol.weights
    sigma = sol.noise_sigma
    method_used = "map"
    if use_cg:
        hs = (
            np.asarray(homographies, dtype=np.float64)
            if homographies is not None
            else np.stack([translation_homography(*si) for si in s])
        )
        img = _cg_map(
            stack, hs, p, blur_sigma, sol.noise_sigma, masks, sol.prior, reg, img, cg_iters
        )
        method_used = "map-cg"
    if not np.isfinite(img).all():
        return _fallback(ref, p, "MAP solution not finite", sigma, n, s)
    img = _bicubic_rim(img, ref, p)
    kept = sol.kept
    if not kept.all():
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
            sol.shifts,
        )
    return SRResult(
        image=img,
        method=method_used,
        noise_sigma=sigma,
        weights=weights,
        shifts=sol.shifts,
        shift_sigma=sol.shift_sigma,
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
