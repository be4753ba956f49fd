"""Coarse stage of the shift estimator: phase correlation on a pyramid, then small-level GN.

References
----------
.. [1] C. D. Kuglin and D. C. Hines, "The phase correlation image alignment method",
   Proc. IEEE Conference on Cybernetics and Society, 163-165, 1975.
"""

from __future__ import annotations

from typing import Optional, Tuple

import cv2
import numpy as np

from .gauss_newton import _gauss_newton
from .inputs import _fill_invalid
from .level import _Level, _pyr, _pyr_mask, _texture_scorer

_SMALL_LEVEL = 1 << 18  # pixels: Gauss-Newton runs on pyramid levels up to this size only


def coarse_shift(
    reference: np.ndarray,
    moving: np.ndarray,
    max_size: int = 512,
) -> Tuple[Tuple[float, float], float, int]:
    """Estimate the shift by phase correlation on a pyramid level of at most ``max_size`` px.

    Parameters
    ----------
    reference, moving : ndarray
        The two frames, equal shapes.
    max_size : int
        Largest side (px) of the level the correlation runs on.

    Returns
    -------
    shift : tuple of float
        ``(u, v)`` in full-resolution px (rows, columns; content reference -> moving).
    response : float
        Peak response in [0, 1].
    level : int
        The pyramid level ``L`` used.

    Notes
    -----
    Both frames are block-averaged (INTER_AREA) by ``2^L`` so the larger side is at most
    ``max_size``, blurred by a 1 px Gaussian (keeps noise-dominated high frequencies out of
    the whitened spectrum), then ``cv2.phaseCorrelate`` with a Hanning window [1]_ gives the
    shift at that level, scaled back by ``2^L``.
    """
    h, w = reference.shape
    level = 0
    while max(h, w) / 2**level > max_size and min(h, w) / 2 ** (level + 1) >= 32:
        level += 1
    ref, mov = reference, moving
    if level:
        # a multiple of 2^L keeps INTER_AREA on its fast integer-factor path
        hc, wc = (h >> level) << level, (w >> level) << level
        size = (max(w >> level, 1), max(h >> level, 1))
        ref = cv2.resize(reference[:hc, :wc], size, interpolation=cv2.INTER_AREA)
        mov = cv2.resize(moving[:hc, :wc], size, interpolation=cv2.INTER_AREA)
    ref = cv2.GaussianBlur(ref.astype(np.float64), (0, 0), 1.0)
    mov = cv2.GaussianBlur(mov.astype(np.float64), (0, 0), 1.0)
    win = cv2.createHanningWindow((ref.shape[1], ref.shape[0]), cv2.CV_64F)
    (dx, dy), resp = cv2.phaseCorrelate(ref, mov, win)
    return (dy * 2**level, dx * 2**level), float(resp), level


def _pyramid(reference, moving, ref_valid, mov_valid, coarse_size: int):
    """Halve the frames and masks while the larger side exceeds ``coarse_size`` (>= 64 px)."""
    refs, movs, ref_valids, mov_valids = [reference], [moving], [ref_valid], [mov_valid]
    while min(refs[-1].shape) / 2 >= 64 and max(refs[-1].shape) > coarse_size:
        refs.append(_pyr(refs[-1]))
        movs.append(_pyr(movs[-1]))
        ref_valids.append(_pyr_mask(ref_valids[-1]))
        mov_valids.append(_pyr_mask(mov_valids[-1]))
    return refs, movs, ref_valids, mov_valids


def _coarse_start(reference, moving, ref_valid, mov_valid, prior, opts, sigma: float, border: int):
    """Return the fine stage's start, the coarse shift and the tile texture scorer.

    Parameters
    ----------
    reference, moving, ref_valid, mov_valid : ndarray
        Working frames and validity (None: all valid).
    prior : array_like or None
        Starting ``(u, v)``; replaces the phase correlation.
    opts : _Options
        The estimator's options (``taps``, ``band``, ``coarse_size``).
    sigma : float
        Prefilter width (px).
    border : int
        Pixels kept clear of the frame edges.

    Returns
    -------
    start : ndarray, shape (2,)
        ``(u, v)`` at full resolution.
    coarse : tuple of float or None
        The phase-correlation shift (None with a prior).
    score : callable or None
        Texture scorer of the coarsest level, for choosing tiles.
    """
    refs, movs, ref_valids, mov_valids = _pyramid(
        reference, moving, ref_valid, mov_valid, opts.coarse_size
    )
    levels = len(refs) - 1
    coarse: Optional[Tuple[float, float]] = None
    if prior is not None:
        s = np.asarray(prior, dtype=np.float64).reshape(2) / 2**levels
    else:
        (cu, cv), _, _ = coarse_shift(
            _fill_invalid(refs[-1], ref_valids[-1]),
            _fill_invalid(movs[-1], mov_valids[-1]),
            max_size=1 << 30,
        )
        coarse = (cu * 2**levels, cv * 2**levels)
        s = np.array([cu, cv], dtype=np.float64)
    # Gauss-Newton on the small pyramid levels only (the big ones cost more than they save)
    for lev in range(levels, 0, -1):
        if refs[lev].size > _SMALL_LEVEL and lev < levels:
            s = s * 2.0
            continue
        scorer = _texture_scorer(refs[-1], 2.0 ** (lev - levels)) if lev < levels else None
        lv = _Level(
            refs[lev].astype(np.float32),
            movs[lev].astype(np.float32),
            ref_valids[lev],
            mov_valids[lev],
            opts.taps,
            sigma,
            opts.band,
            _SMALL_LEVEL,
            scorer,
            kmax=int(np.max(np.abs(s))) + 3,
        )
        run = _gauss_newton(lv, s, 8, 0.01, border)
        if not run.reason:
            s = run.s
        s = s * 2.0
    score = _texture_scorer(refs[-1], 2.0 ** (-levels)) if levels else None
    return s, coarse, score
