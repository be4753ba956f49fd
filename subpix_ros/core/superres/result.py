"""The result of a super-resolution, its bicubic baseline and fallback, and PSNR."""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np

from .spectrum import estimate_noise_sigma

__all__ = [
    "SRResult",
    "psnr",
    "bicubic_upscale",
    "bicubic_integer",
    "context_bands",
    "to_integer_image",
    "NonFiniteImageError",
    "METHODS",
    "BLUR_AUTO",
    "MAX_FACTOR",
]

METHODS = ("map", "windowed", "pinv", "bicubic")
WINDOWED_SMOOTH_LR_PX = 0.35  # Gaussian std (LR px) applied to the windowed eq. 7 solution
BLUR_AUTO = "auto"  # blur_sigma setting: estimate the blur from the frames (core/blur.py)
MAX_FACTOR = 4


class NonFiniteImageError(ValueError):
    """A reconstruction produced NaN or infinite pixels (never published as an image)."""


def to_integer_image(img: np.ndarray, dtype) -> np.ndarray:
    """Round (half to even) and clip a float image to ``dtype`` (uint8 or uint16).

    Parameters
    ----------
    img : numpy.ndarray
        Float image (any shape; colour with at most 4 channels takes OpenCV's one pass).
    dtype : numpy dtype
        ``numpy.uint8`` or ``numpy.uint16``.

    Returns
    -------
    numpy.ndarray
        ``clip(rint(img), 0, max(dtype))`` as ``dtype``: OpenCV's saturating conversion
        (``cv2.add(img, 0, dtype=...)``) rounds half to even as ``numpy.rint`` does, in one
        pass (8 ms against 70-126 ms for a 4K colour image).
    """
    depth = {np.dtype(np.uint8): cv2.CV_8U, np.dtype(np.uint16): cv2.CV_16U}.get(np.dtype(dtype))
    a = np.asarray(img)
    if (
        depth is not None
        and a.dtype in (np.float32, np.float64)
        and (a.ndim == 2 or a.shape[2] <= 4)
    ):
        return cv2.add(a, 0.0, dtype=depth)
    out = np.rint(a)
    np.clip(out, 0, np.iinfo(dtype).max, out=out)
    return out.astype(dtype)


@dataclass
class SRResult:
    """Result of :func:`~subpix_ros.core.superres.reconstruct`.

    Attributes
    ----------
    image : numpy.ndarray
        float64 (float32 BGR from ``reconstruct_colour``), ``(factor H, factor W)``, on the
        frames' intensity scale.
    method : str
        The method actually used: "map", "map-cg", "windowed", "pinv" or "bicubic".
    fell_back : bool
        True when the result fell back to bicubic upscaling; ``reason`` says why.
    reason : str
        Why it fell back, or what else the solver decided (e.g. frames left out).
    noise_sigma : float
        Per-pixel noise std used (DN; estimated unless given).
    weights : numpy.ndarray
        (N,) each frame's relative weight (1 = as good as the reference, 0 = left out).
    shifts : numpy.ndarray
        (N, 2) shifts used (LR px; refined if ``refine_shifts``).
    shift_sigma : numpy.ndarray
        (N,) registration error std the model assumed per frame (LR px).
    factor : int
        Resolution factor.
    blur_sigma : float
        Optics blur the model used (LR px).
    blur_source : str
        Where the blur came from: "parameter", "edges", "fallback" or "unused".
    blur_reason : str
        A one-line account of the blur (see :mod:`subpix_ros.core.blur`).
    shifts_disputed : int
        Frames whose given shift disagreed with the frames' own registration and was replaced
        by it (only when the shifts are used as given, ``refine_shifts=False``).
    motion_blur : (float, float)
        Image motion during the exposure the model used, ``(du, dv)`` LR px ((0, 0): none
        modelled, e.g. the method does not model blur or the result fell back).
    pixel_fill : float
        The pixel aperture's width the model used (LR px; 1.0: the full pixel).
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
    shifts_disputed: int = 0
    motion_blur: tuple[float, float] = (0.0, 0.0)
    pixel_fill: float = 1.0


def psnr(image: np.ndarray, truth: np.ndarray, border: int = 0, peak: float = 255.0) -> float:
    """Return the peak signal-to-noise ratio of an image against the truth.

    Parameters
    ----------
    image, truth : numpy.ndarray
        Arrays of one shape.
    border : int, optional
        Pixels cut from every side before comparing.
    peak : float, optional
        Peak value (255 for 8-bit data).

    Returns
    -------
    float
        ``10 log10(peak^2 / MSE)`` in dB (inf for identical arrays).
    """
    a = np.asarray(image, dtype=np.float64)
    b = np.asarray(truth, dtype=np.float64)
    if border:
        a, b = a[border:-border, border:-border], b[border:-border, border:-border]
    mse = float(np.mean((a - b) ** 2))
    return float("inf") if mse == 0 else 10.0 * np.log10(peak**2 / mse)


def bicubic_upscale(frame: np.ndarray, factor: int) -> np.ndarray:
    """Upscale one frame bicubically onto the project's output grid.

    Parameters
    ----------
    frame : numpy.ndarray
        2-D frame (or HxWxC).
    factor : int
        Resolution factor.

    Returns
    -------
    numpy.ndarray
        float64, ``(factor H, factor W)``: LR pixel i covers output pixels
        ``factor i .. factor i + factor - 1`` (``cv2.resize``, ``INTER_CUBIC``).
    """
    f = np.asarray(frame, dtype=np.float64)
    return cv2.resize(f, (f.shape[1] * factor, f.shape[0] * factor), interpolation=cv2.INTER_CUBIC)


def context_bands(h: int, rows: int, ctx: int = 4):
    """Yield ``(a0, a1, e0, e1)``: blocks ``a0..a1`` of ``rows`` of ``h`` rows, with context.

    ``e0..e1`` is the block with ``ctx`` rows on each side (clipped to the frame). A bicubic
    upscale (4 taps: 2 LR rows each side) of rows ``e0..e1``, cut to the output rows of
    ``a0..a1``, has the values of upscaling the whole frame, without a whole-frame result.
    """
    for a0 in range(0, h, rows):
        a1 = min(a0 + rows, h)
        yield a0, a1, max(a0 - ctx, 0), min(a1 + ctx, h)


def bicubic_integer(image: np.ndarray, factor: int, dtype, rows: int = 64) -> np.ndarray:
    """Return ``image`` upscaled ``factor`` x by bicubic interpolation, rounded to ``dtype``.

    Parameters
    ----------
    image : numpy.ndarray
        Mono or BGR frame, uint8 or uint16.
    factor : int
        Resolution factor (the project's output grid, as :func:`bicubic_upscale`).
    dtype : numpy dtype
        ``numpy.uint8`` or ``numpy.uint16``.
    rows : int, optional
        Input rows per block.

    Returns
    -------
    numpy.ndarray
        ``to_integer_image(cv2.resize(float32 image, INTER_CUBIC), dtype)``, made ``rows``
        input rows at a time (:func:`context_bands`): the values of the whole-image resize
        without its whole float32 result (100 MB for a 4K colour image).
    """
    h, w = image.shape[:2]
    p = int(factor)
    out = np.empty((h * p, w * p) + image.shape[2:], dtype)
    for a0, a1, e0, e1 in context_bands(h, rows):
        up = cv2.resize(
            image[e0:e1].astype(np.float32), (w * p, (e1 - e0) * p), interpolation=cv2.INTER_CUBIC
        )
        out[p * a0 : p * a1] = to_integer_image(up[p * (a0 - e0) : p * (a1 - e0)], dtype)
    return out


def _bicubic_rim(img: np.ndarray, ref: np.ndarray, p: int) -> np.ndarray:
    """Replace the outermost LR-pixel ring of ``img`` by the bicubic upscale of ``ref``.

    Parameters
    ----------
    img : numpy.ndarray
        HR image, ``(p H, p W)``; modified in place and returned.
    ref : numpy.ndarray
        The reference frame, ``(H, W)``.
    p : int
        Resolution factor (the ring is p output px wide).

    Returns
    -------
    numpy.ndarray
        ``img``.

    Notes
    -----
    Frames shifted towards the inside leave that ring observed by the reference alone
    (the rest is padding). Only 4-LR-pixel strips of the reference are upscaled: the
    ring's bicubic taps reach 2 LR px inwards, so the values equal those of upscaling
    the whole frame.
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


def _fallback(ref: np.ndarray, factor: int, reason: str, noise: float, n: int, shifts) -> SRResult:
    """Return the bicubic upscale of the reference as a fallen-back result, with the reason.

    ``noise`` is estimated on the reference if not finite; the reference has weight 1, the
    other ``n - 1`` frames 0; ``shifts`` (or zeros) are reported as given.
    """
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
