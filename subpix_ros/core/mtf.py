"""Slanted-edge MTF measurement in the ISO 12233 manner (METHODS.md B, evaluation).

The paper measures resolution as the frequency where the modulation transfer
function falls to 0.3 (MTF30), read off edge targets. Steps here:

1. edge location per row: centroid of the row derivative in a Hamming
   window around a robust first estimate;
2. edge fit: a straight line ``c = a + b r`` (least squares), angle ``atan b``
   (an edge closer to horizontal is handled by transposing);
3. edge spread function (ESF): every pixel binned by its signed distance to
   the fitted edge, measured along the edge normal, in bins of 1/4 pixel
   (4x oversampling). Bin-phase correction: the distances of the pixels
   falling into one bin are not spread evenly over it (their phases follow
   the lattice ``r tan(angle) mod 1``), so a bin's mean sits at its samples'
   mean distance ``k + 1/2 + delta_k`` (bins) rather than at its centre; it
   is moved to the centre to first order, ``ESF_k -= ESF'_k delta_k``;
4. line spread function (LSF): central difference of the ESF, times a
   Tukey window (flat over the central half) centred on the LSF centroid,
   half-width ``max(3 px, 3 x the ESF's 10-90 % rise)``, widened to cover
   lobes of the LSF above its noise;
5. MTF = |FFT(LSF)| normalised to 1 at zero frequency, divided by the
   transfer of the central difference (``sinc(2 f d)``) and of the binning
   (``sinc(f d)``), ``d = 1/4`` px; frequencies in cycles/pixel along the
   edge normal.

MTF50 / MTF30 are the first frequencies where the MTF falls to 0.5 / 0.3
(linear interpolation between samples); with a pixel pitch they are also
given in cycles (line pairs) per mm. Accuracy against the analytic MTF:
``benchmarks/bench_mtf.py`` and docs/design-notes.md.

References
----------
.. [1] ISO 12233:2017, Photography -- Electronic still picture imaging -- Resolution
   and spatial frequency responses.
.. [2] P. D. Burns, "Slanted-edge MTF for digital camera and scanner analysis",
   Proc. IS&T PICS 2000, pp. 135-138.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .filters import tukey_taper

__all__ = ["MTFResult", "bt601_luminance", "slanted_edge_mtf", "mtf_crossing", "gaussian_pixel_mtf"]

OVERSAMPLE = 4
WINDOW_RISES = 3.0  # LSF window half-width in ESF 10-90 % rises ...
WINDOW_MIN_PX = 3.0  # ... and at least this many pixels
SUPPORT_SIGMAS = 5.0  # LSF lobes this far above the noise widen the window


@dataclass
class MTFResult:
    """Result of :func:`slanted_edge_mtf` (frequencies in cycles/pixel along the edge normal).

    Attributes
    ----------
    freqs, mtf : numpy.ndarray
        The MTF, up to ``f_max`` (default 1 cycle/px).
    mtf50, mtf30 : float
        First frequencies where the MTF falls to 0.5 and 0.3.
    angle_deg : float
        Edge angle from the pixel column (or row, if transposed) direction.
    transposed : bool
        True when the edge was closer to horizontal (rows and columns swapped).
    esf : numpy.ndarray
        Oversampled edge spread function (bin width 1/OVERSAMPLE px).
    lsf : numpy.ndarray
        Windowed line spread function.
    pixel_pitch_m : float or None
        Pixel pitch given (m).
    mtf50_lp_mm, mtf30_lp_mm : float or None
        MTF50 and MTF30 in line pairs per mm (with a pixel pitch).
    line_rms_px : float
        RMS of the per-row edge positions about the fitted line (px).
    contrast : float
        Step height between the ESF's plateaus (intensity units).
    texture : float
        RMS of the pixels more than 2 px from the edge about the ESF, relative to the step.

    Notes
    -----
    The last three describe the edge's quality; :mod:`subpix_ros.core.blur` screens edges by
    them.
    """

    freqs: np.ndarray
    mtf: np.ndarray
    mtf50: float
    mtf30: float
    angle_deg: float
    transposed: bool
    esf: np.ndarray
    lsf: np.ndarray
    pixel_pitch_m: float | None = None
    mtf50_lp_mm: float | None = None
    mtf30_lp_mm: float | None = None
    line_rms_px: float = float("nan")
    contrast: float = float("nan")
    texture: float = float("nan")


def mtf_crossing(freqs: np.ndarray, mtf: np.ndarray, level: float) -> float:
    """Return the first frequency where ``mtf`` falls to ``level`` (linear interpolation).

    Parameters
    ----------
    freqs, mtf : numpy.ndarray
        The curve.
    level : float
        Level to cross, e.g. 0.5 or 0.3.

    Returns
    -------
    float
        Frequency (units of ``freqs``).

    Raises
    ------
    ValueError
        If the curve never falls to ``level`` in the measured range.
    """
    below = np.flatnonzero(mtf < level)
    if below.size == 0 or below[0] == 0:
        raise ValueError(f"MTF does not fall to {level} within the measured range")
    i = below[0]
    f0, f1, m0, m1 = freqs[i - 1], freqs[i], mtf[i - 1], mtf[i]
    return float(f0 + (m0 - level) * (f1 - f0) / (m0 - m1))


def gaussian_pixel_mtf(freqs: np.ndarray, sigma_px: float, angle_deg: float) -> np.ndarray:
    """Return the analytic MTF of Gaussian optics times the square pixel aperture.

    Parameters
    ----------
    freqs : numpy.ndarray
        Frequencies (cycles/pixel) along the normal of the edge.
    sigma_px : float
        Optics std (px).
    angle_deg : float
        Edge angle from the pixel grid.

    Returns
    -------
    numpy.ndarray
        ``exp(-2 pi^2 sigma^2 f^2) |sinc(f cos a) sinc(f sin a)|``: the reference the
        slanted-edge method is validated against.
    """
    f = np.asarray(freqs, dtype=np.float64)
    th = np.deg2rad(angle_deg)
    return np.exp(-2 * np.pi**2 * sigma_px**2 * f**2) * np.abs(
        np.sinc(f * np.cos(th)) * np.sinc(f * np.sin(th))
    )


def _edge_centroids(img: np.ndarray, half_window: int = 8) -> tuple[np.ndarray, np.ndarray]:
    """Locate the edge in every row: the centroid of |d/dc| in a Hamming window.

    Returns ``(rows, column of the edge per row)`` (NaN where a row has no derivative). First
    pass: the column of the largest smoothed derivative in each row and a robust line through
    them (median of row-pair slopes); second pass: the derivative centroid within
    +-``half_window`` px of that line, Hamming-weighted (ISO 12233), so noise far from the
    edge does not pull it towards the ROI centre.
    """
    d = np.zeros_like(img)
    d[:, 1:-1] = 0.5 * (img[:, 2:] - img[:, :-2])
    d = np.abs(d)
    rows = np.arange(img.shape[0], dtype=np.float64)
    cols = np.arange(img.shape[1], dtype=np.float64)
    sm = d.copy()
    sm[:, 1:-1] = (d[:, :-2] + 2 * d[:, 1:-1] + d[:, 2:]) / 4
    peak = np.argmax(sm, axis=1).astype(np.float64)
    # robust line through the per-row peaks: median slope between rows half the ROI apart
    half = img.shape[0] // 2
    slope = float(np.median((peak[half : half * 2] - peak[:half]) / half)) if half else 0.0
    icpt = float(np.median(peak - slope * rows))
    pred = icpt + slope * rows
    rel = (cols[None, :] - pred[:, None]) / half_window
    win = np.where(np.abs(rel) <= 1, 0.54 + 0.46 * np.cos(np.pi * np.clip(rel, -1, 1)), 0.0)
    dw = d * win
    w2 = dw.sum(axis=1)
    ok = w2 > 0
    c = np.where(ok, (dw * cols).sum(axis=1) / np.where(ok, w2, 1), np.nan)
    return rows, c


def _rise_10_90(esf: np.ndarray) -> float:
    """Return the 10-90 % rise distance (px) of a dark-to-bright ESF in 1/OVERSAMPLE px bins.

    Levels from the means of the first and last 2 px; the ESF is made monotone (running
    maximum) first so noise cannot cross a level twice.
    """
    n = 2 * OVERSAMPLE
    lo, hi = float(esf[:n].mean()), float(esf[-n:].mean())
    e = np.maximum.accumulate((esf - lo) / max(hi - lo, 1e-12))
    pos = np.arange(esf.size, dtype=np.float64)
    return float(np.interp(0.9, e, pos) - np.interp(0.1, e, pos)) / OVERSAMPLE


def _window_half_width(lsf: np.ndarray, centre: float, rise_px: float) -> float:
    """Return the LSF window's half-width (bins): the rise and every LSF part above its noise.

    Core: ``WINDOW_RISES`` 10-90 % rises, at least ``WINDOW_MIN_PX`` px. Support: the farthest
    distance from ``centre`` where the LSF, averaged over 1 px, exceeds ``SUPPORT_SIGMAS``
    times its noise there (noise std of the single bins from the MAD of the LSF outside the
    core, divided by 2 for the 4-bin average). Ringing lobes of deconvolved or sharpened
    images must stay inside the flat part of the window (the half-width is at least twice the
    support); a blurred edge has no such lobes, so noise alone is kept out.
    """
    pos = np.arange(lsf.size, dtype=np.float64) - centre
    core = max(WINDOW_MIN_PX, WINDOW_RISES * rise_px) * OVERSAMPLE
    outer = np.abs(pos) > core
    hw = core
    if outer.sum() >= 4 * OVERSAMPLE:
        noise = 1.4826 * float(np.median(np.abs(lsf[outer] - np.median(lsf[outer]))))
        avg = np.convolve(lsf, np.full(OVERSAMPLE, 1.0 / OVERSAMPLE), mode="same")
        above = np.abs(avg) > SUPPORT_SIGMAS * noise / np.sqrt(OVERSAMPLE)
        if above.any():
            hw = max(hw, 2.0 * float(np.abs(pos[above]).max()))
    return min(hw, lsf.size / 2.0)


def slanted_edge_mtf(
    image: np.ndarray,
    roi: tuple[int, int, int, int] | None = None,
    pixel_pitch_m: float | None = None,
    min_contrast: float = 0.05,
    span: float | None = None,
    f_max: float = 1.0,
) -> MTFResult:
    """Measure the MTF of a straight, slanted edge in an image.

    Parameters
    ----------
    image : numpy.ndarray
        Mono 2-D image, or HxWx3 BGR (its luminance is used), or a
        :class:`~subpix_ros.core.superres.luma.LazyLuminance` (with ``roi``: only
        the ROI and the intensity range are computed).
    roi : (int, int, int, int), optional
        ``(x, y, w, h)`` in pixels (x = column). The ROI must contain one edge crossing it
        from side to side, tilted 2-40 deg from the pixel grid.
    pixel_pitch_m : float, optional
        Pixel pitch (m) for line-pairs/mm read-outs.
    min_contrast : float, optional
        Least edge contrast, as a fraction of the image's intensity range.
    span : float, optional
        That intensity range (DN), when the caller knows it; default: ``max - min`` of
        ``image`` (all channels).
    f_max : float, optional
        Highest frequency returned (cycles/px; default 1). The 4x oversampled ESF carries the
        MTF beyond the pixel Nyquist frequency: up to about 1.7 cycles/px the correction of
        the central difference and the binning stays above 0.1.

    Returns
    -------
    MTFResult
        Frequencies in cycles/pixel along the edge normal.

    Raises
    ------
    ValueError
        When there is no usable edge: contrast below ``min_contrast``, too few rows, the
        edge too close to the grid direction to oversample, or the MTF never falls to 0.3
        below 1 cycle/px.
    """
    img = _roi_image(image, roi)
    # orientation: the edge should cross rows (strong horizontal gradient), else transpose
    gx = np.abs(np.diff(img, axis=1)).sum()
    gy = np.abs(np.diff(img, axis=0)).sum()
    transposed = bool(gy > gx)
    if transposed:
        img = img.T
    lo, hi = np.percentile(img, [2, 98])
    if span is None:  # no float64 copy of the whole image
        a = image if is_lazy_frame(image) else np.asarray(image)
        span = float(a.max()) - float(a.min())
    span = float(span) or 1.0
    if hi - lo < min_contrast * max(span, 1e-12) or hi - lo <= 0:
        raise ValueError("no edge: contrast too low in the ROI")
    rows, a, b, line_rms = _fit_edge_line(img)
    angle = float(np.degrees(np.arctan(b)))
    esf, step, texture = _edge_spread(img, rows, a, b)
    freqs, mtf, lsfw = _mtf_from_esf(esf, f_max)
    upto1 = freqs <= 1.0  # the crossings (and the check that the MTF falls) up to 1 cycle/px
    mtf50 = mtf_crossing(freqs[upto1], mtf[upto1], 0.5)
    mtf30 = mtf_crossing(freqs[upto1], mtf[upto1], 0.3)
    res = MTFResult(
        freqs=freqs,
        mtf=mtf,
        mtf50=mtf50,
        mtf30=mtf30,
        angle_deg=angle,
        transposed=transposed,
        esf=esf,
        lsf=lsfw,
        pixel_pitch_m=pixel_pitch_m,
        line_rms_px=line_rms,
        contrast=step,
        texture=texture,
    )
    if pixel_pitch_m is not None:
        if not pixel_pitch_m > 0:
            raise ValueError("pixel_pitch_m must be > 0")
        per_mm = 1.0 / (pixel_pitch_m * 1e3)  # pixels per mm
        res.mtf50_lp_mm = mtf50 * per_mm
        res.mtf30_lp_mm = mtf30 * per_mm
    return res


def bt601_luminance(image: np.ndarray) -> np.ndarray:
    """Return the float64 luminance of a BGR image (a mono image as float64).

    Parameters
    ----------
    image : numpy.ndarray
        HxWx3 BGR (OpenCV order) or HxW.

    Returns
    -------
    numpy.ndarray
        ``Y = 0.114 B + 0.587 G + 0.299 R`` (ITU-R BT.601), float64, HxW.

    Notes
    -----
    A colour image is converted in blocks of 64 rows (each block's float64 copy stays small),
    not as one HxWx3 float64 temporary (the same sums, block by block).
    """
    a = np.asarray(image)
    if a.ndim != 3:
        return a.astype(np.float64, copy=False)
    w = np.array([0.114, 0.587, 0.299])
    out = np.empty(a.shape[:2], np.float64)
    for r0 in range(0, a.shape[0], 64):
        np.matmul(a[r0 : r0 + 64].astype(np.float64), w, out=out[r0 : r0 + 64])
    return out


def is_lazy_frame(image) -> bool:
    """Return True for a frame computed where it is sliced (``LazyLuminance``), not an array.

    Such a frame has ``shape``, ``ndim``, ``min()``, ``max()`` and ``[r0:r1, c0:c1]``; callers
    slice it before converting instead of converting it whole.
    """
    return (
        not isinstance(image, np.ndarray)
        and hasattr(image, "shape")
        and hasattr(image, "__getitem__")
    )


def _roi_image(image: np.ndarray, roi: tuple[int, int, int, int] | None) -> np.ndarray:
    """Return the ROI of the image's luminance as float64; ValueError if unusable."""
    # a lazy frame is cropped before anything is computed (only the ROI is)
    img = image if is_lazy_frame(image) and roi is not None else np.asarray(image)
    colour = img.ndim == 3 and img.shape[2] == 3
    if img.ndim != 2 and not colour:
        raise ValueError(f"image must be 2-D (or HxWx3 BGR), got shape {np.shape(image)}")
    if roi is not None:  # crop first: only the ROI is converted
        x, y, w, h = (int(v) for v in roi)
        if w <= 0 or h <= 0 or x < 0 or y < 0 or x + w > img.shape[1] or y + h > img.shape[0]:
            raise ValueError(f"roi {roi} outside the image {img.shape[1]}x{img.shape[0]}")
        img = np.asarray(img[y : y + h, x : x + w])
    img = bt601_luminance(img)
    if min(img.shape) < 16:
        raise ValueError(f"ROI too small for an edge measurement: {img.shape}")
    if not np.isfinite(img).all():
        raise ValueError("image contains NaN or infinite values")
    return img


def _fit_edge_line(img: np.ndarray) -> tuple[np.ndarray, float, float, float]:
    """Fit the edge line ``c = a + b r``; return ``(rows, a, b, rms of the row positions)``.

    Rows whose centroid lies beyond ``max(3 std, 1 px)`` of a first fit are dropped and the
    line refitted. ValueError when too few rows have an edge, or the edge's angle does not
    suit the 4x oversampling (it must move >= 1 px over the rows; at most 40 deg).
    """
    rows, cent = _edge_centroids(img)
    good = np.isfinite(cent)
    if good.sum() < 8:
        raise ValueError("no edge found in enough rows")
    b, a = np.polyfit(rows[good], cent[good], 1)
    resid = cent[good] - (a + b * rows[good])
    keep = np.abs(resid) < max(3 * np.std(resid), 1.0)  # drop rows where the centroid failed
    b, a = np.polyfit(rows[good][keep], cent[good][keep], 1)
    line_rms = float(np.sqrt(np.mean((cent[good][keep] - (a + b * rows[good][keep])) ** 2)))
    angle = float(np.degrees(np.arctan(b)))
    if abs(b) * img.shape[0] < OVERSAMPLE:
        raise ValueError(
            f"edge angle {angle:.2f} deg too close to the pixel grid for {OVERSAMPLE}x "
            f"oversampling over {img.shape[0]} rows (tilt it a few degrees)"
        )
    if abs(angle) > 40:
        raise ValueError(f"edge angle {angle:.1f} deg too far from the pixel grid (use 2-40 deg)")
    return rows, a, b, line_rms


def _edge_spread(
    img: np.ndarray, rows: np.ndarray, a: float, b: float
) -> tuple[np.ndarray, float, float]:
    """Return the oversampled, bin-phase-corrected ESF (dark to bright), step height, texture.

    Pixels within the band of +-half-width around the edge that lies inside the ROI in
    every row are binned by their distance along the edge normal (``1/OVERSAMPLE`` px
    bins). Texture: RMS of the pixels more than 2 px from the edge about the ESF, relative
    to the step between the ESF's plateaus.
    """
    cc, rr = np.meshgrid(np.arange(img.shape[1], dtype=np.float64), rows)
    dist = (cc - (a + b * rr)) / np.sqrt(1.0 + b * b)  # signed distance along the normal, px
    edge_c = a + b * rows
    half = min(edge_c.min(), (img.shape[1] - 1 - edge_c).min()) / np.sqrt(1.0 + b * b)
    if half < 4:
        raise ValueError("edge too close to the ROI border")
    nb = int(np.floor(half * OVERSAMPLE))
    sel = np.abs(dist) < nb / OVERSAMPLE
    idx = np.floor(dist[sel] * OVERSAMPLE).astype(np.int64) + nb
    cnt = np.bincount(idx, minlength=2 * nb)[: 2 * nb]
    acc = np.bincount(idx, weights=img[sel], minlength=2 * nb)[: 2 * nb]
    filled = cnt > 0
    if filled.sum() < 0.9 * cnt.size:
        raise ValueError("edge spread function has too many empty bins")
    centres = np.arange(2 * nb)
    esf = np.interp(centres, centres[filled], acc[filled] / cnt[filled])
    # bin phase: mean position of each bin's samples relative to the bin centre, in bins
    pos_in_bin = dist[sel] * OVERSAMPLE - np.floor(dist[sel] * OVERSAMPLE) - 0.5
    delta = np.bincount(idx, weights=pos_in_bin, minlength=2 * nb)[: 2 * nb] / np.maximum(cnt, 1)
    esf = esf - np.gradient(esf) * delta  # first-order move of each bin mean to its bin centre
    far = np.abs(dist[sel]) > 2.0
    n_pl = min(2 * OVERSAMPLE, esf.size // 4)
    step = abs(float(esf[-n_pl:].mean() - esf[:n_pl].mean()))
    texture = (
        float(np.sqrt(np.mean((img[sel][far] - esf[idx[far]]) ** 2)) / max(step, 1e-12))
        if far.any()
        else np.inf
    )
    if esf[-OVERSAMPLE:].mean() < esf[:OVERSAMPLE].mean():
        esf = esf[::-1]  # dark-to-bright along +distance
    return esf, step, texture


def _mtf_from_esf(esf: np.ndarray, f_max: float = 1.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return ``(freqs, mtf, windowed lsf)`` of an ESF, up to ``f_max`` cycles/px.

    The LSF (central difference) is windowed (:func:`~subpix_ros.core.filters.tukey_taper`)
    about its centroid; the MTF is divided by the transfers of the central difference
    ``sinc(2 f d)`` and of the binning ``sinc(f d)``, ``d = 1/OVERSAMPLE``.
    """
    lsf = np.zeros_like(esf)
    lsf[1:-1] = 0.5 * (esf[2:] - esf[:-2])
    if lsf.sum() <= 0:
        raise ValueError("edge spread function is not monotone enough to measure")
    pos = np.arange(lsf.size, dtype=np.float64)
    centre = float((lsf * pos).sum() / lsf.sum())
    hw = _window_half_width(lsf, centre, _rise_10_90(esf))
    lsfw = lsf * tukey_taper(pos - centre, hw)
    spec = np.abs(np.fft.rfft(lsfw))
    if spec[0] <= 0:
        raise ValueError("line spread function has no area")
    mtf = spec / spec[0]
    d = 1.0 / OVERSAMPLE
    freqs = np.fft.rfftfreq(lsf.size, d=d)  # cycles / pixel
    corr = np.sinc(2 * freqs * d) * np.sinc(freqs * d)
    keep_f = freqs <= f_max
    mtf = (mtf / np.where(np.abs(corr) > 0.1, corr, 1.0))[keep_f]
    return freqs[keep_f], mtf, lsfw
