"""Super-resolution of aligned frames whose validity masks are border strips.

Pixel alignment by an integer crop (:func:`subpix_ros.core.registration.align`)
leaves each moving frame with invalid strips along its borders. Passing those
masks to :func:`subpix_ros.core.superres.reconstruct` would force its general
conjugate-gradient solver (far slower than the Fourier-domain MAP
solution). When the pixels valid in *every* frame form a rectangle, this
module reconstructs that rectangle with the fast solver (no masks needed
there) and fills the rest of the output with the bicubic upscale of the
reference frame, which is the only frame that observes it. Output grid as
:func:`reconstruct`: LR pixel i of frame 0 covers output pixels
factor*i .. factor*i + factor - 1. Masks that are not rectangles go to
:func:`reconstruct` unchanged.
"""

from __future__ import annotations

from dataclasses import replace
from typing import Sequence

import numpy as np

from ..validity import box_mask, common_region
from .reconstruction import reconstruct_colour
from .result import SRResult, bicubic_upscale, to_integer_image

__all__ = ["reconstruct_aligned", "bicubic_outside"]

MIN_SIDE = 32  # LR px: a smaller common rectangle is not worth the fast path


def reconstruct_aligned(
    frames: Sequence[np.ndarray],
    shifts: np.ndarray,
    factor: int,
    masks: Sequence[np.ndarray] | None = None,
    boxes: Sequence[tuple[int, int, int, int]] | None = None,
    **kw,
) -> SRResult:
    """Reconstruct mono or BGR frames whose validity masks are border strips, on the fast path.

    Parameters
    ----------
    frames : sequence of numpy.ndarray
        Mono 2-D or HxWx3 BGR frames of one shape; frame 0 the reference.
    shifts : numpy.ndarray
        (N, 2) shifts ``(u, v)`` (LR px): content at (r, c) in frame 0 is at (r + u, c + v)
        in frame n.
    factor : int
        Resolution factor.
    masks : sequence of numpy.ndarray, optional
        A bool array per frame (True = valid).
    boxes : sequence of (int, int, int, int), optional
        Instead of ``masks``: each frame's valid pixels as a rectangle ``(r0, r1, c0, c1)``
        (:func:`~subpix_ros.core.validity.box_mask`). The result is the same; the masks are
        made only if the masked solver needs them (a common rectangle under ``MIN_SIDE``).
    **kw
        Passed to :func:`~subpix_ros.core.superres.reconstruct_colour` (``out_dtype``: the
        image rounded into that integer type, the bicubic border as well) and on to
        :func:`~subpix_ros.core.superres.reconstruct`.

    Returns
    -------
    SRResult
        On the usual output grid.

    Notes
    -----
    When the pixels valid in every frame form a rectangle of at least ``MIN_SIDE`` LR px,
    that rectangle is reconstructed without masks and the rest is the bicubic upscale of the
    reference (:func:`bicubic_outside`); other masks go to the masked (CG) solver.
    """
    solve = reconstruct_colour  # mono frames: reconstruct, with out_dtype applied
    h, w = np.asarray(frames[0]).shape[:2]
    if masks is None and boxes is None:
        return solve(frames, shifts, factor, **kw)
    box = common_region((h, w), masks, boxes)
    if boxes is not None and (box is None or min(box[1] - box[0], box[3] - box[2]) < MIN_SIDE):
        masks = [box_mask((h, w), b) for b in boxes]  # the masked solver needs them
    if box is None or min(box[1] - box[0], box[3] - box[2]) < MIN_SIDE:
        return solve(frames, shifts, factor, masks=masks, **kw)
    r0, r1, c0, c1 = box
    if (r0, r1, c0, c1) == (0, h, 0, w):
        return solve(frames, shifts, factor, **kw)
    res = solve([np.asarray(f)[r0:r1, c0:c1] for f in frames], shifts, factor, **kw)
    out = np.empty((factor * h, factor * w) + res.image.shape[2:], dtype=res.image.dtype)
    out[factor * r0 : factor * r1, factor * c0 : factor * c1] = res.image
    convert = None
    if np.issubdtype(out.dtype, np.integer):  # kw's out_dtype: strips rounded as the float
        ftype = np.float32 if out.ndim == 3 else np.float64  # image (float32 colour) holds them
        convert = lambda v: to_integer_image(v.astype(ftype, copy=False), out.dtype)  # noqa: E731
    bicubic_outside(out, np.asarray(frames[0]), factor, box, convert=convert)
    return replace(res, image=out)


def bicubic_outside(
    out: np.ndarray,
    ref: np.ndarray,
    p: int,
    box: tuple[int, int, int, int],
    convert=None,
) -> None:
    """Fill ``out`` outside the output box of ``box`` with the bicubic upscale of ``ref``.

    Parameters
    ----------
    out : numpy.ndarray
        HR output, ``(p H, p W[, 3])``; modified in place.
    ref : numpy.ndarray
        Reference frame, mono or BGR.
    p : int
        Resolution factor.
    box : (int, int, int, int)
        ``(r0, r1, c0, c1)`` LR rectangle left as it is.
    convert : callable, optional
        Applied to each strip's values before they are stored (e.g. rounding into an
        integer ``out``); default: stored as they are.

    Notes
    -----
    Only the strips are upscaled, each from the reference strip plus 4 LR px of context
    (bicubic taps reach 2 LR px), so the values are those of upscaling the whole frame (to
    OpenCV's single-precision weights).
    """
    h, w = ref.shape[:2]
    r0, r1, c0, c1 = box
    ctx = 4

    def strip(a0: int, a1: int, b0: int, b1: int) -> None:
        """Upscale the LR rectangle rows a0..a1, cols b0..b1 into ``out``."""
        if a1 <= a0 or b1 <= b0:
            return
        e0, e1, f0, f1 = max(a0 - ctx, 0), min(a1 + ctx, h), max(b0 - ctx, 0), min(b1 + ctx, w)
        up = bicubic_upscale(ref[e0:e1, f0:f1], p)
        vals = up[p * (a0 - e0) : p * (a1 - e0), p * (b0 - f0) : p * (b1 - f0)]
        out[p * a0 : p * a1, p * b0 : p * b1] = vals if convert is None else convert(vals)

    strip(0, r0, 0, w)  # top
    strip(r1, h, 0, w)  # bottom
    strip(r0, r1, 0, c0)  # left
    strip(r0, r1, c1, w)  # right
