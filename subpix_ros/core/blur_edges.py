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

from typing import Sequence

import cv2
import numpy as np

from .mtf import slanted_edge_mtf

__all__ = ["edge_sigma", "find_edge_rois", "measure_edge", "spectral_cap"]

ALPHA_MIN = 1.0  # a scene's power spectrum falls at least as fast as |f|^-ALPHA_MIN (spectral cap)
MAX_LINE_RMS = 0.35  # edge positions about the fitted line (px): straighter than this
MAX_TEXTURE = 0.12  # RMS beside the edge / step height: flatter than this
MIN_CONTRAST_SNR = 12.0  # step height / noise std: at least this


def _gaussian_box_mtf(freqs: np.ndarray, sigmas: np.ndarray, angle_deg: float) -> np.ndarray:
    """Return ``exp(-2 pi^2 s^2 f^2) |sinc(f cos a) sinc(f sin a)|``, rows s, columns f."""
    th = np.deg2rad(angle_deg)
    box = np.abs(np.sinc(freqs * np.cos(th)) * np.sinc(freqs * np.sin(th)))
    return (
        np.exp(-2.0 * np.pi**2 * np.square(sigmas)[:, None] * np.square(freqs)[None, :])
        * box[None, :]
    )


_SIGMA_GRID = np.arange(0.0, 2.0001, 0.0025)


def edge_sigma(
    freqs: np.ndarray,
    mtf: np.ndarray,
    angle_deg: float,
    f_lo: float = 0.05,
    level: float = 0.15,
    motion_px: float = 0.0,
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

    Returns
    -------
    float
        ``argmin_s sum_f (M(f) - exp(-2 pi^2 s^2 f^2) |sinc(f cos a) sinc(f sin a)|)^2`` on a
        0.0025 px grid in [0, 2] (times ``|sinc(f motion_px)|`` with a motion).

    Notes
    -----
    A narrower pixel aperture than the full pixel (fill factor below 1) has a higher MTF and
    so gives a lower sigma: a bias in the safe direction.
    """
    f = np.asarray(freqs, dtype=np.float64)
    m = np.asarray(mtf, dtype=np.float64)
    models = _gaussian_box_mtf(f, _SIGMA_GRID, angle_deg)
    if motion_px:
        models = models * np.abs(np.sinc(f * motion_px))[None, :]
    band = (f >= f_lo) & (f <= 0.75)
    best = 0.0
    for _ in range(2):  # the band where the first fit's model is above `level`, then refit
        if band.sum() < 3:
            break
        err = np.sum((models[:, band] - m[band]) ** 2, axis=1)
        best = float(_SIGMA_GRID[int(np.argmin(err))])
        band = (f >= f_lo) & (f <= 0.75) & (models[int(np.argmin(err))] >= level)
    return best


def find_edge_rois(
    frame: np.ndarray,
    max_rois: int = 12,
    min_angle_deg: float = 3.0,
    max_angle_deg: float = 38.0,
    margin: int = 10,
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

    Returns
    -------
    list of tuple of int
        Longest segments first; segments whose middles lie within 8 px of a taken one are
        skipped.

    Notes
    -----
    Straight segments come from OpenCV's line segment detector (LSD) on the frame scaled to
    8 bit (at half size when its larger side exceeds 1024 px). A segment qualifies when,
    over the ROI's length along it (80 % of the segment, at most 64 px), the edge crosses at
    least 4.5 px of the other axis (the 4x oversampling of the ESF needs every sub-pixel
    phase). The ROI is centred on the segment's middle, clipped to the frame.
    """
    f = np.asarray(frame, dtype=np.float64)
    h, w = f.shape
    if min(h, w) < 24:
        return []
    lo, hi = np.percentile(f[::4, ::4], [0.5, 99.5])
    img8 = np.clip((f - lo) * (255.0 / max(hi - lo, 1e-9)), 0, 255).astype(np.uint8)
    scale = 1.0
    if (
        max(h, w) > 1024
    ):  # large frames: segments found at half size (LSD's cost), ROIs on the frame
        img8 = cv2.resize(img8, (w // 2, h // 2), interpolation=cv2.INTER_AREA)
        scale = 2.0
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


def measure_edge(
    frame: np.ndarray,
    roi: tuple[int, int, int, int],
    noise: float,
    motion_blur: tuple[float, float] = (0.0, 0.0),
) -> tuple[float, str]:
    """Measure the blur of one edge in one frame.

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
    sigma : float
        The edge's optics blur (px, :func:`edge_sigma`), or NaN.
    why_not : str
        Empty, or why the edge was rejected: no slanted-edge measurement, not straight
        (``MAX_LINE_RMS``), textured beside the edge (``MAX_TEXTURE``), or a step below
        ``MIN_CONTRAST_SNR`` times the noise.
    """
    try:
        r = slanted_edge_mtf(frame, roi)
    except ValueError as exc:
        return float("nan"), str(exc)
    if not r.line_rms_px <= MAX_LINE_RMS:
        return float("nan"), f"edge not straight (positions {r.line_rms_px:.2f} px about the line)"
    if not r.texture <= MAX_TEXTURE:
        return float("nan"), f"textured beside the edge ({r.texture:.2f} of the step)"
    if not r.contrast >= MIN_CONTRAST_SNR * max(noise, 0.5):
        return float("nan"), f"step {r.contrast:.1f} below {MIN_CONTRAST_SNR:.0f}x the noise"
    if motion_blur[0] == 0.0 and motion_blur[1] == 0.0:
        return edge_sigma(r.freqs, r.mtf, r.angle_deg), ""
    return edge_sigma(r.freqs, r.mtf, r.angle_deg, motion_px=_motion_on_normal(r, motion_blur)), ""


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


def spectral_cap(
    frames: Sequence[np.ndarray],
    noise_sigma: float,
    alpha_min: float = ALPHA_MIN,
    max_frames: int = 4,
    crop: int = 256,
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
    comes from an edge that is soft in the scene.
    """
    arrs = [np.asarray(f, dtype=np.float64) for f in frames[:max_frames]]
    h0, w0 = arrs[0].shape
    h, w = min(h0, crop), min(w0, crop)
    win = np.outer(np.hanning(h), np.hanning(w))
    ps = np.zeros((h, w))
    for a in arrs:  # frames
        x = a[(h0 - h) // 2 : (h0 - h) // 2 + h, (w0 - w) // 2 : (w0 - w) // 2 + w]
        ps += np.abs(np.fft.fft2((x - x.mean()) * win)) ** 2
    ps /= len(arrs) * float(np.sum(win**2))
    r = np.hypot(np.fft.fftfreq(h)[:, None], np.fft.fftfreq(w)[None, :])
    edges = (0.06, 0.12, 0.2, 0.28, 0.36, 0.44)
    cen, pw = [], []
    for a, b in zip(edges[:-1], edges[1:]):  # rings
        sel = (r >= a) & (r < b)
        cen.append(float(r[sel].mean()))
        pw.append(float(ps[sel].mean()) - noise_sigma**2)
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
