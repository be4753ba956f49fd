"""Scoring reconstructions against rendered ground truth (demo, tests, benchmarks).

Conventions as in :mod:`subpix_ros.core.render`: a frame whose true shift
against frame 0 is ``(u, v)`` LR px has its own truth equal to frame 0's HR
truth with content moved by ``factor * (u, v)`` HR px.
"""

from __future__ import annotations

import numpy as np

from subpix_ros.core.luminance import luminance
from subpix_ros.core.mtf import slanted_edge_mtf
from subpix_ros.core.render import fourier_shift_blur, render_sequence, slanted_edge_scene
from subpix_ros.core.superres import bicubic_upscale, psnr, reconstruct


def truth_on_grid(truth0: np.ndarray, shift_lr: tuple[float, float], factor: int) -> np.ndarray:
    """Return the HR truth on the grid of a frame shifted by ``shift_lr`` (LR px) from frame 0.

    ``T_k(X) = T_0(X - factor * s_k)`` (band-limited Fourier shift; the
    border of width ``factor * |s_k|`` wraps and must be excluded).
    """
    t = luminance(truth0, "bgr") if truth0.ndim == 3 else np.asarray(truth0, dtype=np.float64)
    return fourier_shift_blur(
        t,
        (factor * shift_lr[0], factor * shift_lr[1]),
        0.0,
        pad=int(np.ceil(factor * max(abs(shift_lr[0]), abs(shift_lr[1])))) + 32,
    )


def gain_over_bicubic(
    sr: np.ndarray, reference_lr: np.ndarray, truth: np.ndarray, factor: int, border: int
) -> tuple[float, float]:
    """Return (PSNR of ``sr``, PSNR of bicubic(``reference_lr``)) against ``truth`` (luminance, dB).

    Colour inputs (BGR) are compared on luminance; ``border`` HR pixels are
    cut from every side.
    """
    y_sr = luminance(sr, "bgr") if sr.ndim == 3 else np.asarray(sr, np.float64)
    y_ref = (
        luminance(reference_lr, "bgr")
        if reference_lr.ndim == 3
        else np.asarray(reference_lr, np.float64)
    )
    y_t = luminance(truth, "bgr") if truth.ndim == 3 else np.asarray(truth, np.float64)
    if y_sr.shape != y_t.shape:
        raise ValueError(f"super-resolved image {y_sr.shape} and truth {y_t.shape} differ in size")
    return psnr(y_sr, y_t, border), psnr(bicubic_upscale(y_ref, factor), y_t, border)


def wrapped_error(estimate: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Return ``estimate - truth`` folded into [-0.5, 0.5).

    Compares sub-pixel parts when whole pixels were removed by alignment.
    """
    d = np.asarray(estimate, np.float64) - np.asarray(truth, np.float64)
    return (d + 0.5) % 1.0 - 0.5


def max_bin_bias(
    err: np.ndarray, truth: np.ndarray, nbins: int = 5, min_count: int = 5
) -> tuple[float, int]:
    """Measure the bias of a shift estimator across the sub-pixel phase.

    ``err`` and ``truth`` are (N, 2) arrays (px). The fractional part of the
    true shift is split into ``nbins`` bins per axis; returns the largest
    ``|mean error|`` over the bins holding at least ``min_count`` pairs, and
    the smallest bin count (so callers can require enough pairs per bin).
    """
    frac = np.mod(np.asarray(truth, np.float64), 1.0)
    err = np.asarray(err, np.float64)
    worst, fewest = 0.0, len(err)
    for ax in (0, 1):
        b = np.minimum((frac[:, ax] * nbins).astype(int), nbins - 1)
        counts = np.bincount(b, minlength=nbins)
        sums = np.bincount(b, weights=err[:, ax], minlength=nbins)
        ok = counts >= min_count
        if ok.any():
            worst = max(worst, float(np.max(np.abs(sums[ok] / counts[ok]))))
        fewest = min(fewest, int(counts.min()))
    return worst, fewest


def mtf30_evaluation(
    crop: np.ndarray,
    factor: int,
    lr: int = 160,
    methods: tuple[str, ...] = ("map",),
    blur_sigma: float = 0.4,
    snr_db: float = 40.0,
    seed: int = 1,
) -> dict[str, float]:
    """Measure MTF30 of a slanted-edge target through the degradation (METHODS B).

    The paper's resolution measurement.

    A slanted edge is put into the real ``crop``
    (:func:`~subpix_ros.core.render.slanted_edge_scene`),
    ``factor^2`` frames on the k/factor grid are rendered (optics blur ``blur_sigma`` LR px, pixel
    integration, noise at ``snr_db``) and reconstructed. Returns MTF30 in cycles per *input* pixel
    for ``"input"`` (one frame), ``"ceiling"`` (the optics-blurred HR truth: no pixel aperture),
    ``"bicubic"`` and each of ``methods`` (:func:`~subpix_ros.core.superres.reconstruct`; NaN if a
    method cannot run on these frames).
    """
    p = int(factor)
    hr, roi = slanted_edge_scene(crop, p, lr=lr)
    seq = render_sequence(
        hr,
        p,
        [(a / p, b / p) for a in range(p) for b in range(p)],
        blur_sigma,
        snr_db=snr_db,
        seed=seed,
    )
    x, y, w, h = roi
    roi_hr = (x * p, y * p, w * p, h * p)
    out = {
        "input": slanted_edge_mtf(seq.frames[0], roi).mtf30,
        "ceiling": slanted_edge_mtf(seq.truth_blurred, roi_hr).mtf30 * p,
        "bicubic": slanted_edge_mtf(bicubic_upscale(seq.frames[0], p), roi_hr).mtf30 * p,
    }
    for m in methods:
        try:
            image = reconstruct(seq.frames, seq.shifts, p, method=m).image
        except ValueError:
            out[m] = float("nan")
            continue
        out[m] = slanted_edge_mtf(image, roi_hr).mtf30 * p
    return out
