"""Sharpness of a super-resolved image against the bicubic one, at the scene's own edges."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from subpix_ros.core.blur_edges import MAX_LINE_RMS, MAX_TEXTURE, find_edge_rois
from subpix_ros.core.mtf import bt601_luminance, slanted_edge_mtf

__all__ = ["EdgeSharpness", "edge_sharpness"]

#: The report's edges are found on the reference reduced to at most this many px (larger side):
#: the long edges it shows are found there too, at a third of LSD's cost at 1080p.
DETECT_MAX_PX = 512


@dataclass(frozen=True)
class EdgeSharpness:
    """MTF50 and MTF30 of one straight edge in the bicubic and the super-resolved image.

    Frequencies are in cycles per *input* pixel (the input's Nyquist is 0.5), so the two
    images and the input are on one scale. ``roi`` is ``(x, y, w, h)`` in input pixels.
    """

    roi: tuple[int, int, int, int]
    angle_deg: float
    bicubic_mtf50: float
    sr_mtf50: float
    bicubic_mtf30: float
    sr_mtf30: float
    freqs: np.ndarray  # cycles per input px
    bicubic_mtf: np.ndarray
    sr_mtf: np.ndarray


def edge_sharpness(
    reference: np.ndarray,
    bicubic: np.ndarray,
    super_resolved: np.ndarray,
    factor: int,
    max_edges: int = 3,
) -> list[EdgeSharpness]:
    """Measure the slanted-edge MTF of both upscaled images at the reference's straight edges.

    Parameters
    ----------
    reference : ndarray
        The set's reference frame (H, W) or (H, W, 3) BGR, input pixels.
    bicubic, super_resolved : ndarray
        The reference upscaled by bicubic interpolation, and the super-resolved image, both
        ``factor`` times the reference's size, on the same grid.
    factor : int
        Resolution factor.
    max_edges : int
        Most edges returned (the longest straight edges first).

    Returns
    -------
    list of EdgeSharpness
        One entry per edge both images could be measured at (straight, not textured beside
        it: the screening of :mod:`subpix_ros.core.blur`); empty when the scene has none.

    Notes
    -----
    Edges are found in the reference (:func:`~subpix_ros.core.blur.find_edge_rois`, on the
    reference reduced to at most ``DETECT_MAX_PX`` px; each ROI on the full frames) and
    measured (contrast relative to the reference's luminance range) by the slanted-edge
    method (ISO 12233, :func:`~subpix_ros.core.mtf.slanted_edge_mtf`) in the ROI scaled by
    ``factor``. A frequency ``f`` in cycles per output pixel is ``f *
    factor`` cycles per input pixel. A super-resolved image that only sharpens noise shows no
    gain here; one that rings shows an MTF above 1 at low frequencies.

    References
    ----------
    ISO 12233:2017, Photography: electronic still picture imaging, resolution and spatial
    frequency responses.
    """
    p = int(factor)
    lum = bt601_luminance(reference)
    big_b, big_s = np.asarray(bicubic), np.asarray(super_resolved)  # converted per ROI only
    if big_b.shape[:2] != (lum.shape[0] * p, lum.shape[1] * p) or big_s.shape != big_b.shape:
        raise ValueError(
            f"bicubic {big_b.shape[:2]} and super-resolved {big_s.shape[:2]} must be {p}x the "
            f"reference {lum.shape}"
        )
    out: list[EdgeSharpness] = []
    span = float(lum.max()) - float(lum.min())  # the reference's: no full-size conversion
    for x, y, w, h in find_edge_rois(lum, max_rois=4 * max_edges, detect_max_px=DETECT_MAX_PX):
        roi_hr = (x * p, y * p, w * p, h * p)
        try:  # the bicubic edge is screened before the super-resolved one is measured
            b = slanted_edge_mtf(big_b, roi_hr, span=span)
            if not (b.line_rms_px <= MAX_LINE_RMS * p and b.texture <= MAX_TEXTURE):
                continue
            s = slanted_edge_mtf(big_s, roi_hr, span=span)
        except ValueError:
            continue
        n = min(len(b.freqs), len(s.freqs))
        out.append(
            EdgeSharpness(
                (x, y, w, h),
                float(b.angle_deg),
                b.mtf50 * p,
                s.mtf50 * p,
                b.mtf30 * p,
                s.mtf30 * p,
                b.freqs[:n] * p,
                b.mtf[:n],
                s.mtf[:n],
            )
        )
        if len(out) >= max_edges:
            break
    return out
