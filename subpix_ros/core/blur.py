"""The camera's optics blur as a measured property (issue 17): ``blur_sigma: auto | <px>``.

The super-resolution model (:mod:`subpix_ros.core.superres`) needs the std
``sigma`` of the Gaussian optics blur in input pixels. With translation-only
motion the blur commutes with the shifts, so the frames alone cannot tell it
(METHODS.md B); only the scene can. Sources, in order:

* ``parameter``: an explicit number (a lab calibration);
* ``edges``: straight, sharp edges in the flight's own frames (roofs, road
  markings), measured by the slanted-edge method of :mod:`subpix_ros.core.mtf`
  (:func:`estimate_blur`);
* ``fallback``: no usable edge in view: a fixed low value
  (:data:`FALLBACK_SIGMA`), because over-estimating the blur costs far more
  than under-estimating it.

Every estimate is biased low on purpose: the pooled edge value minus its
standard error. :func:`resolve_blur` turns a ``blur_sigma`` setting into a
:class:`BlurEstimate` saying which source gave the value.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import cv2
import numpy as np

from .mtf import slanted_edge_mtf

__all__ = [
    "BlurEstimate",
    "BLUR_SIGMA_MAX",
    "FALLBACK_SIGMA",
    "parse_blur_sigma",
    "estimate_blur",
    "find_edge_rois",
    "edge_sigma",
    "resolve_blur",
    "spectral_cap",
    "BlurCalibration",
]

BLUR_SIGMA_MAX = 3.0  # largest blur (input px) accepted as a setting
FALLBACK_SIGMA = 0.2  # used when no usable edge is in view (input px)
ALPHA_MIN = 1.0  # a scene's power spectrum falls at least as fast as |f|^-ALPHA_MIN (spectral cap)
MAX_LINE_RMS = 0.35  # edge positions about the fitted line (px): straighter than this
MAX_TEXTURE = 0.12  # RMS beside the edge / step height: flatter than this
MIN_CONTRAST_SNR = 12.0  # step height / noise std: at least this


@dataclass
class BlurEstimate:
    """A blur value for the super-resolution model and where it came from.

    ``sigma``: the value to use (input px, Gaussian std). ``source``: "edges",
    "fallback" or "parameter". ``uncertainty``: standard error of the pooled
    edge value (px; NaN otherwise). ``raw``: the pooled edge value before the
    low bias (px; NaN otherwise). ``n_edges``: edges pooled (each measured in
    every frame). ``reason``: a one-line account.
    """

    sigma: float
    source: str
    uncertainty: float = float("nan")
    raw: float = float("nan")
    n_edges: int = 0
    reason: str = ""


def parse_blur_sigma(value) -> str | float:
    """Validate a ``blur_sigma`` setting: ``"auto"`` or a number in [0, BLUR_SIGMA_MAX].

    A string is parsed ("auto" in any case, or a number).

    Returns ``"auto"`` or the float; raises ValueError with the reason otherwise.
    """
    if isinstance(value, str):
        v = value.strip().lower()
        if v == "auto":
            return "auto"
        try:
            value = float(v)
        except ValueError:
            raise ValueError(
                f"blur_sigma must be 'auto' or a number of input px in 0..{BLUR_SIGMA_MAX}, "
                f"got {value!r}"
            ) from None
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise ValueError(f"blur_sigma must be 'auto' or a number, got {value!r}")
    v = float(value)
    if not np.isfinite(v) or not 0.0 <= v <= BLUR_SIGMA_MAX:
        raise ValueError(f"blur_sigma must be in 0..{BLUR_SIGMA_MAX} input px, got {value!r}")
    return v


def _gaussian_box_mtf(freqs: np.ndarray, sigmas: np.ndarray, angle_deg: float) -> np.ndarray:
    """``exp(-2 pi^2 s^2 f^2) |sinc(f cos a) sinc(f sin a)|`` for every s (rows) and f (columns)."""
    th = np.deg2rad(angle_deg)
    box = np.abs(np.sinc(freqs * np.cos(th)) * np.sinc(freqs * np.sin(th)))
    return (
        np.exp(-2.0 * np.pi**2 * np.square(sigmas)[:, None] * np.square(freqs)[None, :])
        * box[None, :]
    )


_SIGMA_GRID = np.arange(0.0, 2.0001, 0.0025)


def edge_sigma(
    freqs: np.ndarray, mtf: np.ndarray, angle_deg: float, f_lo: float = 0.05, level: float = 0.15
) -> float:
    """Gaussian optics std (px) whose MTF, times the pixel box, fits a measured edge MTF.

    Parameters
    ----------
    freqs, mtf : the measured MTF along the edge normal (cycles/px), as :func:`slanted_edge_mtf`
        gives.
    angle_deg : the edge's angle from the pixel grid (the box's MTF along the normal depends on it).
    f_lo : lowest frequency used. level : frequencies where the model MTF is below this are left out
        (noise dominates there); the fit is repeated once with the band of its first answer.

    Returns
    -------
    float
        ``argmin_s sum_f (M(f) - exp(-2 pi^2 s^2 f^2) |sinc(f cos a) sinc(f sin a)|)^2``
        on a 0.0025 px
        grid in [0, 2].

    Notes
    -----
    A narrower pixel aperture than the full pixel (fill factor below 1) has a
    higher MTF and so gives a lower sigma: a bias in the safe direction.
    """
    f = np.asarray(freqs, dtype=np.float64)
    m = np.asarray(mtf, dtype=np.float64)
    models = _gaussian_box_mtf(f, _SIGMA_GRID, angle_deg)
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
    """Candidate ROIs ``(x, y, w, h)`` around straight edges that suit the slanted-edge method.

    Straight segments come from OpenCV's line segment detector (LSD) on the
    frame scaled to 8 bit (at half size when its larger side exceeds 1024
    px). A segment qualifies when it lies ``min_angle_deg`` ..
    ``max_angle_deg`` from the nearest pixel axis and is long enough that,
    over the ROI's length along it (80 % of the segment, at most 64 px), the
    edge crosses at least 4.5 px of the other axis (the 4x oversampling of
    the ESF needs every sub-pixel phase). The ROI is centred on the segment's
    middle, ``margin`` px wider on each side than that crossing, clipped to the
    frame. Longest segments first; segments whose middles lie within 8 px of a
    taken one are skipped.
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


def _measure(frame: np.ndarray, roi: tuple[int, int, int, int], noise: float) -> tuple[float, str]:
    """sigma of one edge in one frame, or (NaN, why not)."""
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
    return edge_sigma(r.freqs, r.mtf, r.angle_deg), ""


def spectral_cap(
    frames: Sequence[np.ndarray],
    noise_sigma: float,
    alpha_min: float = ALPHA_MIN,
    max_frames: int = 4,
    crop: int = 256,
) -> float:
    """Largest blur (px) the frames' power spectrum allows; ``inf`` when it says nothing.

    Parameters
    ----------
    frames : 2-D frames (the central ``crop`` square of the first ``max_frames`` is used).
    noise_sigma : per-pixel noise std (DN), subtracted as a white floor.
    alpha_min : the scene's power spectrum is taken to fall at least as ``|f|^-alpha_min``.

    Returns
    -------
    float
        The median over the bands ``b`` = [0.12, 0.2), [0.2, 0.28), [0.28, 0.36), [0.36, 0.44)
        cycles/px
        of the sigma solving ``exp(-4 pi^2 s^2 (f_b^2 - f_0^2)) = R_b (f_b / f_0)^alpha_min / B_b``.

    Notes
    -----
    With ``S_y(f) = G(f)^2 B(f) S_x(f) + n^2`` (G the Gaussian optics, B the squared pixel-box
    transfer
    ``sinc^2``), the ratio ``R_b = (S_y(f_b) - n^2) / (S_y(f_0) - n^2)`` of the Hann-windowed
    periodogram's ring means against the band [0.06, 0.12) (centre f_0) bounds the blur from above
    if ``S_x(f_b) / S_x(f_0) <= (f_b / f_0)^-alpha_min``. Aliasing only raises ``R_b`` (a lower cap,
    the safe side). A slanted-edge value above the cap comes from an edge that is soft in the scene.
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


def estimate_blur(
    frames: Sequence[np.ndarray],
    shifts: np.ndarray | None = None,
    *,
    max_edges: int = 8,
    noise_sigma: float | None = None,
    fallback: float = FALLBACK_SIGMA,
    masks: Sequence[np.ndarray] | None = None,
) -> BlurEstimate:
    """Estimate the optics blur (Gaussian std, input px) from straight edges in the frames.

    Parameters
    ----------
    frames : N 2-D frames of one scene (mono; any numeric dtype), frame 0 the reference.
    shifts : (N, 2) shifts (u, v) of each frame relative to frame 0 (project convention: a feature
        at (r, c) in frame 0 is at (r + u, c + v) in frame n), or None (frames aligned to the
        pixel).
    max_edges : edge ROIs searched in frame 0 (:func:`find_edge_rois`).
    noise_sigma : per-pixel noise std (DN); estimated from frame 0 if None.
    fallback : the value used when no edge passes the checks.
    masks : optional bool array per frame (True = valid pixel); an ROI is measured in a frame only
        where all its pixels are valid.

    Returns
    -------
    BlurEstimate
        source "edges" with ``sigma = max(0, raw - uncertainty)``, or "fallback".

    Notes
    -----
    Each ROI is measured in every frame (moved by the frame's rounded shift;
    an ROI that fails in frame 0 is not tried further:
    other sub-pixel phases and noise) with :func:`slanted_edge_mtf` and
    :func:`edge_sigma`; measurements of edges that are not straight
    (``line_rms_px``), textured beside the edge, or of low contrast are
    dropped. Per edge: the median over frames, its standard error
    ``1.25 std / sqrt(n)`` (floor 0.005 px). A scene edge is never sharper than the camera makes
    it (a soft field boundary only adds its own width), so the pooled value is
    that of the sharpest edges: the inverse-variance mean of the edges within
    two standard errors of the lowest one; its uncertainty the larger of that
    mean's standard error and the group's spread over sqrt(n). Edges above the
    frames' spectral cap (:func:`spectral_cap`) are soft in the scene and left
    out; when none is left, the fallback is used.
    """
    from .superres import estimate_noise_sigma  # superres imports this module

    arrs = [np.asarray(f, dtype=np.float32) for f in frames]
    if not arrs or any(a.ndim != 2 for a in arrs):
        raise ValueError("estimate_blur needs 2-D (mono) frames")
    n = len(arrs)
    sh = np.zeros((n, 2)) if shifts is None else np.asarray(shifts, dtype=np.float64).reshape(n, 2)
    noise = (
        estimate_noise_sigma(arrs[0], max_size=256) if noise_sigma is None else float(noise_sigma)
    )
    rois = find_edge_rois(arrs[0], max_rois=max_edges)
    per_edge, why = _measure_edges(arrs, sh, rois, noise, masks)
    if not per_edge:
        common = max(set(why), key=why.count) if why else "no straight edge found"
        return BlurEstimate(
            fallback,
            "fallback",
            reason=f"no usable edge ({len(rois)} candidates: {common}); fallback {fallback:.2f} px",
        )
    return _pool_edges(per_edge, spectral_cap(arrs, noise), fallback)


def _measure_edges(
    arrs: list[np.ndarray],
    shifts: np.ndarray,
    rois: list[tuple[int, int, int, int]],
    noise: float,
    masks: Sequence[np.ndarray] | None,
) -> tuple[list[tuple[float, float]], list[str]]:
    """Measure every ROI in every frame; return (median, standard error) per edge, and why not.

    An ROI moves with the frame's rounded shift, is skipped where it leaves the frame or
    covers an invalid pixel, and is not tried further when it fails in frame 0. An edge
    counts when it passed in at least half the frames: the median over frames, standard
    error ``1.25 std / sqrt(n)`` (0.05 px for one frame; floor 0.005 px).
    """
    n = len(arrs)
    h, w = arrs[0].shape
    per_edge = []
    why = []
    for x, y, rw, rh in rois:  # edges
        vals = []
        for i, (a, (u, v)) in enumerate(zip(arrs, shifts)):  # frames
            if not (np.isfinite(u) and np.isfinite(v)):
                continue
            xx, yy = x + int(round(v)), y + int(round(u))
            if xx < 0 or yy < 0 or xx + rw > w or yy + rh > h:
                continue
            if masks is not None and not np.all(np.asarray(masks[i])[yy : yy + rh, xx : xx + rw]):
                continue
            s, reason = _measure(a, (xx, yy, rw, rh), noise)
            if np.isfinite(s):
                vals.append(s)
            else:
                why.append(reason)
                if i == 0:  # not an edge to measure in the reference: not measured in the others
                    break
        if len(vals) >= max(1, (n + 1) // 2):  # the edge passed in at least half the frames
            v = np.asarray(vals)
            se = max(1.25 * float(np.std(v)) / np.sqrt(v.size) if v.size > 1 else 0.05, 0.005)
            per_edge.append((float(np.median(v)), se))
    return per_edge, why


def _pool_edges(per_edge: list[tuple[float, float]], cap: float, fallback: float) -> BlurEstimate:
    """Pool the sharpest edges below the spectral cap into one low-biased estimate.

    Edges within two standard errors of the lowest one are averaged with inverse-variance
    weights; the uncertainty is the larger of that mean's standard error and the group's
    spread over sqrt(n); the estimate is the mean minus it. All edges above ``cap``: the
    fallback.
    """
    vals = np.array([e[0] for e in per_edge])
    ses = np.array([e[1] for e in per_edge])
    if vals.min() > cap:
        return BlurEstimate(
            fallback,
            "fallback",
            reason=f"edges measured {vals.min():.2f} px or more, above what the frames' spectrum "
            f"allows ({cap:.2f} px): edges soft in the scene; fallback {fallback:.2f} px",
        )
    keep = vals <= cap
    vals, ses = vals[keep], ses[keep]
    lo = int(np.argmin(vals))
    group = vals <= vals[lo] + 2.0 * np.hypot(ses, ses[lo])
    wts = 1.0 / ses[group] ** 2
    raw = float(np.sum(wts * vals[group]) / wts.sum())
    unc = float(
        max(
            1.0 / np.sqrt(wts.sum()),
            np.std(vals[group]) / np.sqrt(group.sum()) if group.sum() > 1 else 0.0,
        )
    )
    sigma = max(0.0, raw - unc)
    return BlurEstimate(
        sigma,
        "edges",
        uncertainty=unc,
        raw=raw,
        n_edges=int(group.sum()),
        reason=f"{int(group.sum())} of {len(per_edge)} measured edges pooled "
        f"({raw:.3f} +- {unc:.3f} px), minus one standard error",
    )


def resolve_blur(
    setting, frames: Sequence[np.ndarray], shifts: np.ndarray | None = None, **kw
) -> BlurEstimate:
    """A ``blur_sigma`` setting (``"auto"`` or a number) as a :class:`BlurEstimate`.

    A number is used as given (source "parameter"); ``"auto"`` runs :func:`estimate_blur` on the
    frames (mono) with ``kw``.
    """
    v = parse_blur_sigma(setting)
    if v != "auto":
        return BlurEstimate(float(v), "parameter", reason="given")
    return estimate_blur(frames, shifts, **kw)


class BlurCalibration:
    """The blur of one flight, kept across frame sets and refreshed slowly.

    ``setting`` is a ``blur_sigma`` setting (:func:`parse_blur_sigma`). With a
    number every set gets it (source "parameter"). With ``"auto"``,
    :func:`estimate_blur` runs on the first set and then on every
    ``refresh_sets``-th set (the calibration can cost as much as a set's
    reconstruction, so it is not repeated for every set); an edge estimate
    stays in use until a later set gives a new one (a set without edges in
    view does not discard it); until the first edge estimate the fallback is used.
    """

    def __init__(self, setting="auto", refresh_sets: int = 10) -> None:
        self.setting = parse_blur_sigma(setting)
        self.refresh_sets = max(1, int(refresh_sets))
        self.current: BlurEstimate | None = None
        self._sets = 0

    @property
    def due(self) -> bool:
        """Whether the next :meth:`update` measures the frames (else they are not looked at)."""
        return self.setting == "auto" and (
            self.current is None or self._sets % self.refresh_sets == 0
        )

    def update(
        self,
        frames: Sequence[np.ndarray],
        shifts: np.ndarray | None = None,
        masks: Sequence[np.ndarray] | None = None,
    ) -> BlurEstimate:
        """The blur for this set (mono frames; masks: valid pixels per frame or None).

        Re-estimated when due (see the class)."""
        if self.setting != "auto":
            if self.current is None:
                self.current = BlurEstimate(float(self.setting), "parameter", reason="given")
            return self.current
        due = self.due
        self._sets += 1
        if due:
            new = estimate_blur(frames, shifts, masks=masks)
            if new.source == "edges" or self.current is None or self.current.source != "edges":
                self.current = new
        return self.current
