"""Straight edges in the frames, and the frames' spectrum, as evidence of the optics blur.

The pieces of :func:`subpix_ros.core.blur.estimate_blur`: candidate edge ROIs
(:func:`find_edge_rois`), the blur of one edge from its slanted-edge MTF
(:func:`edge_sigma`, :func:`measure_edge`) and the upper bound the frames' power
spectrum puts on the blur (:func:`spectral_cap`).

References
----------
.. [1] ISO 12233:2017, Photography -- Electronic still picture imaging -- Resolution
   and spatial frequency responses.
.. [2] R. Grompone von Gioi, J. Jakubowicz, J.-M. Morel, G. Randall, "LSD: a fast line
   segment detector with a false detection control", IEEE TPAMI 32(4), 722-732, 2010.
   https://doi.org/10.1109/TPAMI.2008.300
"""

from __future__ import annotations

from typing import NamedTuple, Sequence

import cv2
import numpy as np

from .mtf import is_lazy_frame, slanted_edge_mtf

__all__ = [
    "EdgeFit",
    "count_lines",
    "edge_fill",
    "edge_line",
    "edge_misfit",
    "edge_sigma",
    "find_edge_rois",
    "frames_periodogram",
    "measure_edge",
    "spectral_cap",
]

ALPHA_MIN = 1.0  # a scene's power spectrum falls at least as fast as |f|^-ALPHA_MIN (spectral cap)
MAX_LINE_RMS = 0.35  # edge positions about the fitted line (px): straighter than this
MAX_TEXTURE = 0.12  # RMS beside the edge / step height: flatter than this
MIN_CONTRAST_SNR = 12.0  # step height / noise std: at least this


def _gaussian_box_mtf(
    freqs: np.ndarray, sigmas: np.ndarray, angle_deg: float, fill: float = 1.0
) -> np.ndarray:
    """Return ``exp(-2 pi^2 s^2 f^2) |sinc(w f cos a) sinc(w f sin a)|``, rows s, columns f.

    ``w`` is the pixel fill factor ``fill`` (the aperture's width, px).
    """
    th = np.deg2rad(angle_deg)
    fw = freqs * fill if fill != 1.0 else freqs
    box = np.abs(np.sinc(fw * np.cos(th)) * np.sinc(fw * np.sin(th)))
    return (
        np.exp(-2.0 * np.pi**2 * np.square(sigmas)[:, None] * np.square(freqs)[None, :])
        * box[None, :]
    )


_SIGMA_GRID = np.arange(0.0, 2.0001, 0.0025)
FILL_GRID = (0.7, 0.75, 0.8, 0.85, 0.9, 0.95, 1.0)  # pixel fill factors tried (aperture width, px)
FILL_GATE_FREQ = 0.8  # the fill is fitted only when the edge's MTF is above `level` up to here
FILL_MAX_FREQ = 1.3  # highest frequency of the fill fit (cycles/px)
FILL_MAX_RMS = 0.02  # the joint fit's RMS residual (MTF units) must be below this to be used


def edge_sigma(
    freqs: np.ndarray,
    mtf: np.ndarray,
    angle_deg: float,
    f_lo: float = 0.05,
    level: float = 0.15,
    motion_px: float = 0.0,
    fill: float = 1.0,
) -> float:
    """Fit the Gaussian optics std (px) whose MTF, times the pixel box, matches an edge MTF.

    Parameters
    ----------
    freqs, mtf : numpy.ndarray
        The measured MTF along the edge normal (cycles/px), as :func:`slanted_edge_mtf` gives.
    angle_deg : float
        The edge's angle from the pixel grid (the box's MTF along the normal depends on it).
    f_lo : float, optional
        Lowest frequency used.
    level : float, optional
        Frequencies where the model MTF is below this are left out (noise dominates there);
        the fit is repeated once with the band of its first answer.
    motion_px : float, optional
        The image motion during the exposure projected on the edge normal (px; default 0):
        its box ``|sinc(f motion_px)|`` multiplies the model, so the fit returns the optics
        blur without it.
    fill : float, optional
        The pixel aperture's width ``w`` (px, the fill factor; default 1: the full pixel).

    Returns
    -------
    float
        ``argmin_s sum_f (M(f) - exp(-2 pi^2 s^2 f^2) |sinc(w f cos a) sinc(w f sin a)|)^2`` on
        a 0.0025 px grid in [0, 2] (times ``|sinc(f motion_px)|`` with a motion), over
        ``f_lo <= f <= 0.75`` cycles/px.

    Notes
    -----
    A narrower pixel aperture than the one assumed has a higher MTF and so gives a lower
    sigma (about ``sqrt(s^2 - (w^2 - w_true^2) / 12)``): a bias in the safe direction.
    :func:`edge_fill` measures ``w``.
    """
    f = np.asarray(freqs, dtype=np.float64)
    m = np.asarray(mtf, dtype=np.float64)
    used = f <= 0.75  # the models only where the fit can look
    f, m = f[used], m[used]
    models = _gaussian_box_mtf(f, _SIGMA_GRID, angle_deg, fill)
    if motion_px:
        models = models * np.abs(np.sinc(f * motion_px))[None, :]
    best, _ = _band_fit(models, f, m, f_lo, 0.75, level)
    return 0.0 if best < 0 else float(_SIGMA_GRID[best])


def edge_misfit(
    freqs: np.ndarray,
    mtf: np.ndarray,
    angle_deg: float,
    sigma: float,
    f_lo: float = 0.05,
    level: float = 0.15,
    motion_px: float = 0.0,
) -> float:
    """Bound the blur error (px) that an edge MTF's misfit to the fitted model could cause.

    Parameters
    ----------
    freqs, mtf : numpy.ndarray
        The measured MTF along the edge normal (cycles/px).
    angle_deg : float
        The edge's angle from the pixel grid.
    sigma : float
        The blur fitted to it with the full pixel (:func:`edge_sigma`, px).
    f_lo, level, motion_px : float, optional
        As in :func:`edge_sigma` (the same band: ``f_lo <= f <= 0.75`` where the model is
        at least ``level``).

    Returns
    -------
    float
        ``sqrt(sigma^2 + d) - sigma`` (px) with ``d = r / rms_f(2 pi^2 f^2 M_sigma(f))``: ``r``
        the RMS residual ``M(f) - M_sigma(f)`` on the band (MTF units), ``M_sigma`` the model
        ``exp(-2 pi^2 sigma^2 f^2) |sinc(f cos a) sinc(f sin a)|`` and ``2 pi^2 f^2 M_sigma``
        its sensitivity to ``sigma^2`` (px^2); ``inf`` when fewer than 3 frequencies are in
        the band.

    Notes
    -----
    A least-squares fit moves by ``<r, J> / <J, J>`` for a perturbation ``r`` of the data,
    at most ``rms(r) / rms(J)`` (Cauchy-Schwarz): a residual that large could have moved the
    fitted ``sigma^2`` by ``d``. Noise averages out over the frames; texture beside the edge
    does not (it is in the scene, the same in every frame) and raises the measured MTF
    (a lower blur) while bending it away from the model: the misfit is the per-edge
    uncertainty the frames' scatter does not show (:func:`subpix_ros.core.blur.estimate_blur`).
    """
    f = np.asarray(freqs, dtype=np.float64)
    m = np.asarray(mtf, dtype=np.float64)
    model = _gaussian_box_mtf(f, np.array([sigma]), angle_deg)[0]
    if motion_px:
        model = model * np.abs(np.sinc(f * motion_px))
    band = (f >= f_lo) & (f <= 0.75) & (model >= level)
    if band.sum() < 3:
        return float("inf")
    r = float(np.sqrt(np.mean((m[band] - model[band]) ** 2)))
    sens = float(np.sqrt(np.mean((2.0 * np.pi**2 * f[band] ** 2 * model[band]) ** 2)))
    return float(np.sqrt(sigma**2 + r / sens) - sigma)


def _band_fit(
    models: np.ndarray, f: np.ndarray, m: np.ndarray, f_lo: float, f_hi: float, level: float
) -> tuple[int, float]:
    """Pick the model closest to a measured MTF on its own band: ``(flat index, RMS)``.

    ``models`` is (..., F) over the frequencies ``f``; the least-squares fit runs over
    ``f_lo <= f <= f_hi``, then once more where the chosen model is at least ``level`` (below
    it noise dominates). ``(-1, inf)`` when fewer than 3 frequencies are in the first band.
    """
    flat = models.reshape(-1, models.shape[-1])
    band = (f >= f_lo) & (f <= f_hi)
    best, rms = -1, np.inf
    for _ in range(2):  # the band where the first fit's model is above `level`, then refit
        if band.sum() < 3:
            break
        err = np.sum((flat[:, band] - m[band]) ** 2, axis=1)
        best = int(np.argmin(err))
        rms = float(np.sqrt(err[best] / band.sum()))
        band = (f >= f_lo) & (f <= f_hi) & (flat[best] >= level)
    return best, rms


def edge_fill(
    freqs: np.ndarray,
    mtf: np.ndarray,
    angle_deg: float,
    f_lo: float = 0.05,
    level: float = 0.15,
    motion_px: float = 0.0,
    sigma_full: float | None = None,
) -> float:
    """Fit the pixel fill factor (aperture width, px) jointly with the optics blur at an edge.

    Parameters
    ----------
    freqs, mtf : numpy.ndarray
        The measured MTF along the edge normal (cycles/px), up to at least
        :data:`FILL_MAX_FREQ` (``slanted_edge_mtf(..., f_max=...)``: the 4x oversampled ESF
        measures it beyond the pixel Nyquist frequency).
    angle_deg : float
        The edge's angle from the pixel grid.
    f_lo, level : float, optional
        Lowest frequency used, and the model MTF below which a frequency is left out.
    motion_px : float, optional
        Image motion projected on the edge normal (px), as in :func:`edge_sigma`.
    sigma_full : float, optional
        :func:`edge_sigma` of this MTF with the full pixel, if already known.

    Returns
    -------
    float
        The ``w`` of :data:`FILL_GRID` of the best joint fit ``argmin_{s, w} sum_f (M(f) -
        exp(-2 pi^2 s^2 f^2) |sinc(w f cos a) sinc(w f sin a)|)^2`` over ``f_lo <= f <=
        FILL_MAX_FREQ`` where the model is above ``level`` (one refit on that band); 1.0 (the
        full pixel, :func:`edge_sigma`'s assumption) when the data cannot tell: the full-box
        fit's model is below ``level`` at :data:`FILL_GATE_FREQ`, or the joint fit's RMS
        residual on its band is above :data:`FILL_MAX_RMS`.

    Notes
    -----
    Below about 0.75 cycles/px the box and the Gaussian trade against each other (both lower
    the MTF as ``1 - c f^2``); they part near the box's first zero, at ``1 / w`` cycles/px
    along an axis. A larger blur leaves no signal there, so the fill is fitted only for
    sharp edges (about ``s <= 0.2`` px). A fill below the truth raises the sigma fitted with
    it, hence the gate and the conservative pooling (:func:`subpix_ros.core.blur.estimate_blur`).
    """
    f = np.asarray(freqs, dtype=np.float64)
    m = np.asarray(mtf, dtype=np.float64)
    motion = np.abs(np.sinc(f * motion_px)) if motion_px else np.ones_like(f)
    s_full = (
        edge_sigma(f, m, angle_deg, f_lo, level, motion_px) if sigma_full is None else sigma_full
    )
    at_gate = _gaussian_box_mtf(np.array([FILL_GATE_FREQ]), np.array([s_full]), angle_deg)[0, 0]
    if at_gate * abs(np.sinc(FILL_GATE_FREQ * motion_px)) < level or f.max() < FILL_GATE_FREQ:
        return 1.0
    models = np.stack([_gaussian_box_mtf(f, _SIGMA_GRID, angle_deg, w) for w in FILL_GRID])
    models = models * motion  # (fills, sigmas, freqs)
    best, rms = _band_fit(models, f, m, f_lo, FILL_MAX_FREQ, level)
    if best < 0 or not rms <= FILL_MAX_RMS:  # the model does not explain the edge (texture)
        return 1.0
    return float(FILL_GRID[best // len(_SIGMA_GRID)])


def _scaled_8bit(f: np.ndarray, rows: int = 256) -> np.ndarray | None:
    """Return the frame scaled to 8 bit between its 0.5 and 99.5 percentiles (None if tiny).

    ``clip((f - lo) * 255 / (hi - lo), 0, 255)`` in float64, truncated to uint8, computed
    ``rows`` rows at a time: the values of the whole-frame float64 computation without its
    frame-sized float64 temporaries (200 MB for a 4K frame).
    """
    h, w = f.shape
    if min(h, w) < 24:
        return None
    lo, hi = np.percentile(f[::4, ::4].astype(np.float64), [0.5, 99.5])
    scale = 255.0 / max(hi - lo, 1e-9)
    img8 = np.empty((h, w), np.uint8)
    for r0 in range(0, h, rows):
        blk = np.asarray(f[r0 : r0 + rows], dtype=np.float64)
        img8[r0 : r0 + rows] = np.clip((blk - lo) * scale, 0, 255).astype(np.uint8)
    return img8


def find_edge_rois(
    frame: np.ndarray,
    max_rois: int = 12,
    min_angle_deg: float = 3.0,
    max_angle_deg: float = 38.0,
    margin: int = 10,
    detect_max_px: int | None = None,
) -> list[tuple[int, int, int, int]]:
    """Find ROIs ``(x, y, w, h)`` around straight edges that suit the slanted-edge method.

    Parameters
    ----------
    frame : numpy.ndarray
        2-D frame.
    max_rois : int, optional
        Most ROIs returned.
    min_angle_deg, max_angle_deg : float, optional
        Range of a segment's angle from the nearest pixel axis.
    margin : int, optional
        Px added on each side across the edge.
    detect_max_px : int, optional
        The segments are found on the frame halved until its larger side is at most this
        (LSD's cost grows with the pixels; the ROIs stay on the frame). Default: halved once
        when the larger side exceeds 1024 px.

    Returns
    -------
    list of tuple of int
        Longest segments first; segments whose middles lie within 8 px of a taken one are
        skipped.

    Notes
    -----
    Straight segments come from OpenCV's line segment detector (LSD) on the frame scaled to
    8 bit, reduced by ``INTER_AREA`` as ``detect_max_px`` says. A segment qualifies when,
    over the ROI's length along it (80 % of the segment, at most 64 px), the edge crosses at
    least 4.5 px of the other axis (the 4x oversampling of the ESF needs every sub-pixel
    phase). The ROI is centred on the segment's middle, clipped to the frame.
    """
    img8 = _scaled_8bit(np.asarray(frame))
    if img8 is None:
        return []
    h, w = img8.shape
    k = 1
    if detect_max_px is None:
        k = 2 if max(h, w) > 1024 else 1
    else:
        while max(h, w) > detect_max_px * k and min(h, w) >= 48 * k:
            k *= 2
    scale = float(k)
    if k > 1:  # large frames: segments found at 1/k size (LSD's cost), ROIs on the frame
        img8 = cv2.resize(img8, (w // k, h // k), interpolation=cv2.INTER_AREA)
    segs = cv2.createLineSegmentDetector().detect(img8)[0]
    if segs is None:
        return []
    segs = segs.reshape(-1, 4).astype(np.float64) * scale
    dx, dy = segs[:, 2] - segs[:, 0], segs[:, 3] - segs[:, 1]
    length = np.hypot(dx, dy)
    ang = np.degrees(np.arctan2(dy, dx)) % 180.0  # segment direction from +x
    off = np.abs(((ang + 45.0) % 90.0) - 45.0)  # from the nearest axis
    rois: list[tuple[int, int, int, int]] = []
    mids: list[tuple[float, float]] = []
    for i in np.argsort(-length):  # segments, longest first
        if len(rois) >= max_rois or length[i] < 16:
            break
        if not min_angle_deg <= off[i] <= max_angle_deg:
            continue
        t = np.tan(np.deg2rad(off[i]))
        along = int(min(0.8 * length[i], 64))
        cross = along * t
        if cross < 4.5:
            continue
        mx, my = (segs[i, 0] + segs[i, 2]) / 2, (segs[i, 1] + segs[i, 3]) / 2
        if any(abs(mx - a) < 8 and abs(my - b) < 8 for a, b in mids):
            continue
        width = int(np.ceil(cross)) + 2 * margin
        near_vertical = abs(dy[i]) > abs(dx[i])
        rw, rh = (width, along) if near_vertical else (along, width)
        if rw > w or rh > h:
            continue
        x0 = min(max(int(round(mx - rw / 2)), 0), w - rw)
        y0 = min(max(int(round(my - rh / 2)), 0), h - rh)
        mids.append((mx, my))
        rois.append((x0, y0, rw, rh))
    return rois


class EdgeFit(NamedTuple):
    """One edge measured in one frame (:func:`measure_edge`)."""

    sigma: float  # optics blur with the full pixel (px), or NaN
    fill: float  # the fill factor the edge shows (1.0: cannot tell), or NaN
    why_not: str  # empty, or why the edge was rejected
    mtf: tuple | None = None  # (freqs, mtf, angle_deg, motion_px) for refits at another fill
    misfit: float = 0.0  # the blur error the MTF's misfit to the model could cause (px)

    def sigma_at(self, fill: float) -> float:
        """Return the optics blur fitted with the pixel fill ``fill`` (:func:`edge_sigma`)."""
        if fill == 1.0 or self.mtf is None:
            return self.sigma
        freqs, mtf, angle_deg, motion_px = self.mtf
        return edge_sigma(freqs, mtf, angle_deg, motion_px=motion_px, fill=fill)


def edge_line(frame: np.ndarray, roi: tuple[int, int, int, int]) -> tuple[float, float, float]:
    """Return the straight line an edge ROI shows: its normal's angle and a point on it.

    Parameters
    ----------
    frame : numpy.ndarray
        2-D frame (the reference).
    roi : (int, int, int, int)
        ``(x, y, w, h)`` around the edge (:func:`find_edge_rois`).

    Returns
    -------
    (float, float, float)
        ``(theta, x, y)``: the normal's angle in [0, pi) (rad, from +x towards +y) and a
        point of the line (frame px; NaN for a flat ROI).

    Notes
    -----
    The normal is the dominant gradient orientation of the ROI, from the structure tensor
    ``J = sum (g_x^2, g_x g_y; g_x g_y, g_y^2)``: ``theta = atan2(2 J_xy, J_xx - J_yy) / 2``;
    the point is the centroid of the squared gradient magnitude.
    """
    x, y, w, h = roi
    a = np.asarray(frame[y : y + h, x : x + w], dtype=np.float32)
    gx = cv2.Sobel(a, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(a, cv2.CV_32F, 0, 1, ksize=3)
    jxx, jyy, jxy = float(np.sum(gx * gx)), float(np.sum(gy * gy)), float(np.sum(gx * gy))
    theta = float(0.5 * np.arctan2(2.0 * jxy, jxx - jyy) % np.pi)
    m = gx * gx + gy * gy
    tot = float(m.sum())
    if tot <= 0:
        return theta, float("nan"), float("nan")
    cx = x + float(np.sum(m.sum(axis=0) * np.arange(w))) / tot
    cy = y + float(np.sum(m.sum(axis=1) * np.arange(h))) / tot
    return theta, cx, cy


def count_lines(
    lines: Sequence[tuple[float, float, float]],
    max_angle_deg: float = 5.0,
    max_offset_px: float = 3.0,
) -> int:
    """Return how many distinct straight lines the edges ``(theta, x, y)`` lie on (:func:`edge_line`).

    Parameters
    ----------
    lines : sequence of (float, float, float)
        Each edge's normal angle (rad) and a point of it (px).
    max_angle_deg : float, optional
        Largest difference of two normals (mod 180 degrees) on one line, and the angular
        tolerance of the offset below.
    max_offset_px : float, optional
        Offset allowed between two close points.

    Returns
    -------
    int
        Lines found greedily in the given order (each edge against the first edge of a line);
        an edge without a point is a line of its own.

    Notes
    -----
    Two edges are on one line when their normals differ by at most ``max_angle_deg`` and the
    vector ``d`` between their points is along the line: ``|d . n| <= max(max_offset_px,
    |d| tan(max_angle_deg))`` with ``n`` the mean normal (each normal's own error, a few
    degrees where texture lies beside the edge, moves a distant point by ``|d|`` times it).
    """
    tol = np.deg2rad(max_angle_deg)
    firsts: list[tuple[float, float, float]] = []

    def same(a: tuple[float, float, float], b: tuple[float, float, float]) -> bool:
        da = (b[0] - a[0] + np.pi / 2) % np.pi - np.pi / 2  # in [-pi/2, pi/2)
        if abs(da) > tol:
            return False
        t = a[0] + da / 2  # the mean normal
        dx, dy = b[1] - a[1], b[2] - a[2]
        off = abs(dx * np.cos(t) + dy * np.sin(t))
        return bool(off <= max(max_offset_px, np.hypot(dx, dy) * np.tan(tol)))

    for e in lines:  # edges
        if not (np.isfinite(e[1]) and np.isfinite(e[2])) or not any(
            np.isfinite(f[1]) and same(f, e) for f in firsts
        ):
            firsts.append(e)
    return len(firsts)


def measure_edge(
    frame: np.ndarray,
    roi: tuple[int, int, int, int],
    noise: float,
    motion_blur: tuple[float, float] = (0.0, 0.0),
) -> EdgeFit:
    """Measure the blur and the pixel fill factor of one edge in one frame.

    Parameters
    ----------
    frame : numpy.ndarray
        2-D frame.
    roi : (int, int, int, int)
        ``(x, y, w, h)`` around the edge.
    noise : float
        Per-pixel noise std (DN).
    motion_blur : (float, float), optional
        Image motion during the exposure ``d = (du, dv)`` (px, rows and cols; default none):
        the edge is blurred by a box of ``|d . n|`` along its normal n, which the fit takes
        out (:func:`edge_sigma`).

    Returns
    -------
    EdgeFit
        ``sigma``: the edge's optics blur with the full pixel (px, :func:`edge_sigma`), or
        NaN; ``fill``: the fill factor the edge shows (:func:`edge_fill`; 1.0 when it cannot
        tell); ``why_not``: empty, or why the edge was rejected: no slanted-edge measurement,
        not straight (``MAX_LINE_RMS``), textured beside the edge (``MAX_TEXTURE``), or a step
        below ``MIN_CONTRAST_SNR`` times the noise; ``misfit``: the blur error the MTF's
        misfit to the model could cause (px, :func:`edge_misfit`); ``sigma_at(w)`` refits
        with fill ``w``.
    """
    nan = float("nan")
    try:
        r = slanted_edge_mtf(frame, roi, f_max=FILL_MAX_FREQ)
    except ValueError as exc:
        return EdgeFit(nan, nan, str(exc))
    if not r.line_rms_px <= MAX_LINE_RMS:
        return EdgeFit(
            nan, nan, f"edge not straight (positions {r.line_rms_px:.2f} px about the line)"
        )
    if not r.texture <= MAX_TEXTURE:
        return EdgeFit(nan, nan, f"textured beside the edge ({r.texture:.2f} of the step)")
    if not r.contrast >= MIN_CONTRAST_SNR * max(noise, 0.5):
        return EdgeFit(nan, nan, f"step {r.contrast:.1f} below {MIN_CONTRAST_SNR:.0f}x the noise")
    motion = 0.0
    if motion_blur[0] != 0.0 or motion_blur[1] != 0.0:
        motion = _motion_on_normal(r, motion_blur)
    sigma = edge_sigma(r.freqs, r.mtf, r.angle_deg, motion_px=motion)
    fill = edge_fill(r.freqs, r.mtf, r.angle_deg, motion_px=motion, sigma_full=sigma)
    misfit = edge_misfit(r.freqs, r.mtf, r.angle_deg, sigma, motion_px=motion)
    return EdgeFit(sigma, fill, "", (r.freqs, r.mtf, r.angle_deg, motion), misfit)


def _motion_on_normal(r, motion_blur: tuple[float, float]) -> float:
    """Return the motion ``d`` projected on the normal of a slanted-edge result's edge (px).

    The edge is ``col = a + b row`` with ``b = tan(angle)`` (rows and columns swapped when
    ``r.transposed``): its normal is ``(-b, 1) / sqrt(1 + b^2)`` in (row, col).
    """
    b = np.tan(np.deg2rad(r.angle_deg))
    n = np.array([-b, 1.0]) / np.hypot(b, 1.0)
    if r.transposed:
        n = n[::-1]
    return float(abs(n[0] * motion_blur[0] + n[1] * motion_blur[1]))


def frames_periodogram(
    frames: Sequence[np.ndarray], max_frames: int = 4, crop: int = 256
) -> np.ndarray:
    """Return the mean Hann-windowed periodogram of the frames' central square (DN^2 per bin).

    Parameters
    ----------
    frames : sequence of numpy.ndarray
        2-D frames (or lazy luminance frames); the first ``max_frames`` are used.
    max_frames, crop : int, optional
        Frames and the side of the central square.

    Returns
    -------
    numpy.ndarray
        ``mean_k |FFT((x_k - mean x_k) w)|^2 / sum w^2``, shape of the square (FFT order).
    """
    h0, w0 = np.shape(frames[0])[:2]
    h, w = min(h0, crop), min(w0, crop)
    win = np.outer(np.hanning(h), np.hanning(w))
    ps = np.zeros((h, w))
    used = frames[:max_frames]
    rows = slice((h0 - h) // 2, (h0 - h) // 2 + h)
    cols = slice((w0 - w) // 2, (w0 - w) // 2 + w)
    for f in used:  # frames
        if is_lazy_frame(f):  # the central rows only, full width (the same layout, same sums)
            x = np.asarray(f[rows, :], dtype=np.float64)[:, cols]
        else:
            x = np.asarray(f, dtype=np.float64)[rows, cols]
        ps += np.abs(np.fft.fft2((x - x.mean()) * win)) ** 2
    ps /= len(used) * float(np.sum(win**2))
    return ps


def spectral_cap(
    frames: Sequence[np.ndarray],
    noise_sigma: float,
    alpha_min: float = ALPHA_MIN,
    max_frames: int = 4,
    crop: int = 256,
    ring: str = "mean",
    periodogram: np.ndarray | None = None,
) -> float:
    """Return the largest blur (px) the frames' power spectrum allows; ``inf`` if it says nothing.

    Parameters
    ----------
    frames : sequence of numpy.ndarray
        2-D frames (the central ``crop`` square of the first ``max_frames`` is used).
    noise_sigma : float
        Per-pixel noise std (DN), subtracted as a white floor.
    alpha_min : float, optional
        The scene's power spectrum is taken to fall at least as ``|f|^-alpha_min``.
    max_frames, crop : int, optional
        Frames and central square used.
    ring : {"mean", "median"}, optional
        A ring's power: its mean, or its median over ``ln 2`` (an exponential law's median
        against its mean). A long straight edge puts its power on one line through the
        origin, which the mean takes in (loosening the cap by the very edge it is to check)
        and the median leaves out.
    periodogram : numpy.ndarray, optional
        :func:`frames_periodogram` of the frames, made once for several caps (``frames``,
        ``max_frames`` and ``crop`` are then not used).

    Returns
    -------
    float
        The median over the bands b = [0.12, 0.2), [0.2, 0.28), [0.28, 0.36), [0.36, 0.44)
        cycles/px of the sigma solving
        ``exp(-4 pi^2 s^2 (f_b^2 - f_0^2)) = R_b (f_b / f_0)^alpha_min / B_b``.

    Notes
    -----
    With ``S_y(f) = G(f)^2 B(f) S_x(f) + n^2`` (G the Gaussian optics, B the squared
    pixel-box transfer ``sinc^2``), the ratio ``R_b = (S_y(f_b) - n^2) / (S_y(f_0) - n^2)``
    of the Hann-windowed periodogram's ring means against the band [0.06, 0.12) (centre f_0)
    bounds the blur from above if ``S_x(f_b) / S_x(f_0) <= (f_b / f_0)^-alpha_min``. Aliasing
    only raises ``R_b`` (a lower cap, the safe side). A slanted-edge value above the cap
    comes from an edge that is soft in the scene. The ring medians with ``alpha_min`` 2
    (natural images' ``|f|^-2`` [1]_) make the stricter cap that edges on one straight line
    must pass (:func:`~subpix_ros.core.blur.estimate_blur`).

    References
    ----------
    .. [1] van der Schaaf, A., van Hateren, J. H. (1996). Modelling the power spectra of
       natural images: statistics and information. Vision Research 36(17), 2759-2770.
    """
    ps = frames_periodogram(frames, max_frames, crop) if periodogram is None else periodogram
    h, w = ps.shape
    r = np.hypot(np.fft.fftfreq(h)[:, None], np.fft.fftfreq(w)[None, :])
    edges = (0.06, 0.12, 0.2, 0.28, 0.36, 0.44)
    cen, pw = [], []
    if ring not in ("mean", "median"):
        raise ValueError(f"ring must be 'mean' or 'median', got {ring!r}")
    to_mean = 1.0 / np.log(2.0)  # one scene's periodogram: one exponential law per bin
    for a, b in zip(edges[:-1], edges[1:]):  # rings
        sel = (r >= a) & (r < b)
        cen.append(float(r[sel].mean()))
        level = float(ps[sel].mean()) if ring == "mean" else float(np.median(ps[sel])) * to_mean
        pw.append(level - noise_sigma**2)
    if pw[0] <= 0:
        return float("inf")
    caps = []
    for fb, pb in zip(cen[1:], pw[1:]):
        if pb <= 0:
            continue
        g = pb / pw[0] * (fb / cen[0]) ** alpha_min * (np.sinc(cen[0]) / np.sinc(fb)) ** 2
        caps.append(
            0.0 if g >= 1 else float(np.sqrt(-np.log(g) / (4 * np.pi**2 * (fb**2 - cen[0] ** 2))))
        )
    return float(np.median(caps)) if caps else float("inf")
