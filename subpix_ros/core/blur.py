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

Every estimate is biased low on purpose: the pooled edge value minus the
standard error of the frames' scatter. :func:`resolve_blur` turns a
``blur_sigma`` setting into a :class:`BlurEstimate` saying which source gave
the value.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Sequence

import numpy as np

from .blur_edges import (
    FILL_GRID,
    count_lines,
    edge_fill,
    edge_line,
    edge_sigma,
    find_edge_rois,
    frames_periodogram,
    measure_edge,
    spectral_cap,
)
from .mtf import is_lazy_frame

__all__ = [
    "BlurEstimate",
    "BLUR_SIGMA_MAX",
    "FALLBACK_SIGMA",
    "parse_blur_sigma",
    "estimate_blur",
    "find_edge_rois",
    "edge_sigma",
    "edge_fill",
    "resolve_blur",
    "spectral_cap",
    "BlurCalibration",
    "check_given_blur",
    "pool_estimates",
]

BLUR_SIGMA_MAX = 3.0  # largest blur (input px) accepted as a setting
GIVEN_CHECK_MIN_PX = (
    0.1  # a given blur this far (and 3 standard errors) above the edges' is not used
)
GIVEN_CHECK_SIGMAS = 3.0
FALLBACK_SIGMA = 0.2  # used when no usable edge is in view (input px)
ONE_LINE_ALPHA = 2.0  # the spectral cap's scene fall-off for edges on one straight line


@dataclass
class BlurEstimate:
    """A blur value for the super-resolution model and where it came from.

    Attributes
    ----------
    sigma : float
        The value to use (input px, Gaussian std).
    source : str
        "edges", "fallback", "parameter" (or "unused" when the method has no blur).
    uncertainty : float
        Standard error of the pooled edge value ``raw`` (px; NaN otherwise): the frames'
        scatter and each edge's misfit to the edge model (texture beside the edge).
    raw : float
        The pooled edge value before the low bias (px; NaN otherwise).
    n_edges : int
        Edges pooled (each measured in every frame).
    reason : str
        A one-line account.
    fill_factor : float
        The pixel aperture's width (px) the edges show and ``sigma`` was fitted with
        (:func:`~subpix_ros.core.blur_edges.edge_fill`); 1.0 (the full pixel) when not
        measured.
    bias : float
        The low bias ``raw - sigma`` before the floor at 0 (px): the standard error of the
        frames' scatter alone, at most ``uncertainty``; NaN: ``uncertainty`` (an estimate made
        by hand).
    n_lines : int
        Distinct straight lines the pooled edges lie on (:func:`~subpix_ros.core.blur_edges.
        count_lines`; 0 without edges). With one, ``sigma`` passed the stricter spectral
        cap (:func:`estimate_blur`).
    """

    sigma: float
    source: str
    uncertainty: float = float("nan")
    raw: float = float("nan")
    n_edges: int = 0
    reason: str = ""
    fill_factor: float = 1.0
    bias: float = float("nan")
    n_lines: int = 0

    @property
    def low_bias(self) -> float:
        """Return ``bias``, or ``uncertainty`` where ``bias`` is NaN (px)."""
        return self.uncertainty if np.isnan(self.bias) else self.bias


def parse_blur_sigma(value) -> str | float:
    """Validate a ``blur_sigma`` setting: ``"auto"`` or a number in [0, BLUR_SIGMA_MAX].

    Parameters
    ----------
    value : str or float
        The setting; a string is parsed ("auto" in any case, or a number).

    Returns
    -------
    str or float
        ``"auto"`` or the number.

    Raises
    ------
    ValueError
        With the reason, for anything else.
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


#: What a fallback's reason ends with (the value used); :func:`check_given_blur` drops it.
_FALLBACK_NOTE = "; fallback {:.2f} px"


def _fallback(value: float, why: str) -> BlurEstimate:
    """Return the fallback estimate, its reason ``why`` followed by :data:`_FALLBACK_NOTE`."""
    return BlurEstimate(value, "fallback", reason=why + _FALLBACK_NOTE.format(value))


def estimate_blur(
    frames: Sequence[np.ndarray],
    shifts: np.ndarray | None = None,
    *,
    max_edges: int = 8,
    noise_sigma: float | None = None,
    fallback: float = FALLBACK_SIGMA,
    masks: Sequence[np.ndarray] | None = None,
    motion_blur: tuple[float, float] | None = None,
    fit_fill: bool = True,
    boxes: Sequence[tuple[int, int, int, int]] | None = None,
) -> BlurEstimate:
    """Estimate the optics blur (Gaussian std, input px) from straight edges in the frames.

    Parameters
    ----------
    frames : sequence of numpy.ndarray
        N 2-D frames of one scene (mono; any numeric dtype), frame 0 the reference; frames
        after the first may be
        :class:`~subpix_ros.core.superres.luma.LazyLuminance` (read only where the
        edges are, the same numbers).
    shifts : numpy.ndarray, optional
        (N, 2) shifts (u, v) relative to frame 0 (a feature at (r, c) in frame 0 is at
        (r + u, c + v) in frame n); None: frames aligned to the pixel.
    max_edges : int, optional
        Edge ROIs searched in frame 0 (:func:`find_edge_rois`).
    noise_sigma : float, optional
        Per-pixel noise std (DN); estimated from frame 0 if None.
    fallback : float, optional
        The value used when no edge passes the checks.
    masks : sequence of numpy.ndarray, optional
        A bool array per frame (True = valid); an ROI is measured in a frame only where all
        its pixels are valid.
    motion_blur : (float, float), optional
        Image motion during each exposure ``(du, dv)`` (input px; default none): each edge's
        fit takes out the box it makes along the edge normal (:func:`measure_edge`), so the
        estimate is the optics blur alone.
    fit_fill : bool, optional
        Measure the pixel fill factor too (default True; False: the full pixel assumed, as
        before the fill was measured).
    boxes : sequence of (int, int, int, int), optional
        Instead of ``masks``: each frame's valid pixels as a rectangle ``(r0, r1, c0, c1)``
        (frames aligned by integer crops); an ROI is measured where it lies inside it.

    Returns
    -------
    BlurEstimate
        Source "edges" with ``sigma = max(0, raw - bias)`` (``bias`` the frames' standard
        error, ``uncertainty`` that and the edges' misfit) and the ``fill_factor`` it was
        fitted with, or "fallback".

    Notes
    -----
    Each ROI is measured in every frame (moved by the frame's rounded shift) with
    :func:`slanted_edge_mtf` and :func:`edge_sigma`; edges that are not straight, textured
    beside the edge, or of low contrast are dropped (:func:`_measure_edges`). A scene edge is
    never sharper than the camera makes it, so the pooled value is that of the sharpest edges
    (:func:`_pool_edges`), each weighed by its uncertainty including its misfit to the edge
    model (texture beside the edge reads sharper); edges above the frames' spectral cap
    (:func:`spectral_cap`) are soft in the scene and left out. The fill factor is measured
    where sharp edges show it (:func:`~subpix_ros.core.blur_edges.edge_fill`); the largest
    of the pooled edges' is used, 1.0 where they cannot tell. When the pooled edges all lie
    on one straight line (:func:`~subpix_ros.core.blur_edges.count_lines`), nothing in the
    scene confirms that the line is as sharp as the camera makes it (a shadow's penumbra, a
    rounded eave read higher), so the estimate must also pass the stricter cap: each ring's
    median power (the texture around the line, not the line's own power) and the scene
    falling as ``|f|^-ONE_LINE_ALPHA`` (natural images' ``|f|^-2``); above it, the fallback.
    """
    from .superres import estimate_noise_sigma  # superres imports this module

    # frames after the first may be LazyLuminance: only their ROIs, range and centre are read
    arrs = [np.asarray(f, dtype=np.float32) for f in frames[:1]] + [
        f if is_lazy_frame(f) else np.asarray(f, dtype=np.float32) for f in frames[1:]
    ]
    if not arrs or any(a.ndim != 2 for a in arrs):
        raise ValueError("estimate_blur needs 2-D (mono) frames")
    n = len(arrs)
    sh = np.zeros((n, 2)) if shifts is None else np.asarray(shifts, dtype=np.float64).reshape(n, 2)
    noise = (
        estimate_noise_sigma(arrs[0], max_size=256) if noise_sigma is None else float(noise_sigma)
    )
    rois = find_edge_rois(arrs[0], max_rois=max_edges)
    motion = (0.0, 0.0) if motion_blur is None else (float(motion_blur[0]), float(motion_blur[1]))
    per_edge, why = _measure_edges(arrs, sh, rois, noise, masks, motion, boxes)
    if not per_edge:
        common = max(why, key=why.count) if why else "no straight edge found"  # ties: first
        return _fallback(fallback, f"no usable edge ({len(rois)} candidates: {common})")
    ps = frames_periodogram(arrs)  # once, for the usual cap and the stricter one
    est = _pool_edges(per_edge, spectral_cap(arrs, noise, periodogram=ps), fallback, fit_fill)
    if est.source == "edges" and est.n_lines == 1:
        strict = spectral_cap(arrs, noise, alpha_min=ONE_LINE_ALPHA, ring="median", periodogram=ps)
        if est.raw > strict:
            return replace(
                _fallback(
                    fallback,
                    f"the only straight line measured {est.raw:.2f} px, above what the "
                    f"texture's spectrum allows ({strict:.2f} px): an edge soft in the scene "
                    "(e.g. a shadow's border) cannot be taken for the camera's blur",
                ),
                n_edges=est.n_edges,
                n_lines=1,
            )
    return est


def _median_and_se(vals: Sequence[float]) -> tuple[float, float]:
    """Return the median of one edge's per-frame values and its standard error (px).

    ``1.25 std / sqrt(n)`` (0.05 px for one frame), floored at 0.005 px.
    """
    v = np.asarray(vals)
    se = 1.25 * float(np.std(v)) / np.sqrt(v.size) if v.size > 1 else 0.05
    return float(np.median(v)), max(se, 0.005)


def _measure_edges(
    arrs: list[np.ndarray],
    shifts: np.ndarray,
    rois: list[tuple[int, int, int, int]],
    noise: float,
    masks: Sequence[np.ndarray] | None,
    motion_blur: tuple[float, float] = (0.0, 0.0),
    boxes: Sequence[tuple[int, int, int, int]] | None = None,
) -> tuple[list[tuple[float, float, float, list, float]], list[str]]:
    """Measure every ROI in every frame; per edge (median, standard error, fill, fits, misfit).

    The median and standard error (:func:`_median_and_se`) are over the frames' full-pixel
    blurs; the fill is the median of the frames' (:func:`edge_fill`), rounded up to
    ``FILL_GRID``; the fits (:class:`~subpix_ros.core.blur_edges.EdgeFit`) refit at another
    fill; the misfit is the median of the frames'
    (:func:`~subpix_ros.core.blur_edges.edge_misfit`, px). An ROI moves with the frame's
    rounded shift, is skipped where it leaves the frame or covers an invalid pixel, and is
    not tried further when it fails in frame 0. An edge counts when it passed in at least
    half the frames.
    """
    n = len(arrs)
    h, w = arrs[0].shape
    per_edge = []
    why = []
    for x, y, rw, rh in rois:  # edges
        fits = []
        for i, (a, (u, v)) in enumerate(zip(arrs, shifts)):  # frames
            if not (np.isfinite(u) and np.isfinite(v)):
                continue
            xx, yy = x + int(round(v)), y + int(round(u))
            if xx < 0 or yy < 0 or xx + rw > w or yy + rh > h:
                continue
            if masks is not None and not np.all(np.asarray(masks[i])[yy : yy + rh, xx : xx + rw]):
                continue
            if boxes is not None and not (
                boxes[i][0] <= yy
                and yy + rh <= boxes[i][1]
                and boxes[i][2] <= xx
                and xx + rw <= boxes[i][3]
            ):  # the ROI leaves the frame's valid rectangle
                continue
            fit = measure_edge(a, (xx, yy, rw, rh), noise, motion_blur)
            if np.isfinite(fit.sigma):
                fits.append(fit)
            else:
                why.append(fit.why_not)
                if i == 0:  # not an edge to measure in the reference: not measured in the others
                    break
        if len(fits) >= max(1, (n + 1) // 2):  # the edge passed in at least half the frames
            med, se = _median_and_se([f.sigma for f in fits])
            fill_med = float(np.median([f.fill for f in fits]))
            fill = min(g for g in FILL_GRID if g >= fill_med - 1e-9)  # on the grid, rounded up
            misfit = float(np.median([f.misfit for f in fits]))
            per_edge.append((med, se, fill, fits, misfit, edge_line(arrs[0], (x, y, rw, rh))))
    return per_edge, why


def _consistent_with_lowest(vals: np.ndarray, unc: np.ndarray) -> np.ndarray:
    """Return which values lie within ``2 hypot(u_i, u_lo)`` of the lowest one (bool array)."""
    lo = int(np.argmin(vals))
    return vals <= vals[lo] + 2.0 * np.hypot(unc, unc[lo])


def _pooled_mean(
    vals: np.ndarray, unc: np.ndarray, biases: np.ndarray
) -> tuple[float, float, float]:
    """Return ``(mean, error, low bias)`` of values pooled with weights ``w = 1 / unc^2``.

    ``error = max(1 / sqrt(sum w), spread / sqrt(n))`` and ``low bias = max(sqrt(sum w^2
    b^2) / sum w, spread / sqrt(n))``, ``spread`` the weighted standard deviation of ``vals``
    about the mean and ``b`` each value's own low bias (at most its ``unc``).
    """
    wts = 1.0 / unc**2
    mean = float(np.sum(wts * vals) / wts.sum())
    spread = float(np.sqrt(np.sum(wts * (vals - mean) ** 2) / wts.sum()))
    scatter = spread / np.sqrt(vals.size) if vals.size > 1 else 0.0
    error = max(float(1.0 / np.sqrt(wts.sum())), scatter)
    bias = max(float(np.sqrt(np.sum(wts**2 * biases**2)) / wts.sum()), scatter)
    return mean, error, bias


def _pool_edges(
    per_edge: list[tuple[float, float, float, list, float]],
    cap: float,
    fallback: float,
    fit_fill: bool = True,
) -> BlurEstimate:
    """Pool the sharpest edges below the spectral cap into one low-biased estimate.

    Each edge's uncertainty is ``u = hypot(se, misfit)``: the frames' scatter (noise) and the
    model misfit (texture beside the edge, the same in every frame, which the scatter does
    not show; :func:`~subpix_ros.core.blur_edges.edge_misfit`). Edges within
    ``2 hypot(u, u_lo)`` of the lowest one (full-pixel fits) are averaged with weights
    ``1 / u^2``, the mean capped at the lowest edge plus ``2 u_lo`` (a scene edge is never
    sharper than the camera makes it: the sharpest edge bounds the blur within its own
    uncertainty). The mean's standard error is the larger of ``1 / sqrt(sum w)`` (each edge's
    frames' scatter and misfit) and the weighted spread of the group over sqrt(n). The low
    bias is the larger of its part from the frames' scatter alone, ``sqrt(sum w^2 se^2) /
    sum w``, and the same spread term; the estimate is the mean minus it. The fill factor is
    the largest of the group's (the widest aperture: the lowest blur); when it is below 1,
    the group's edges are refitted with it in every frame and pooled the same way
    (``fit_fill`` False: the full pixel). All edges above ``cap``: the fallback; an edge
    without a finite misfit (too short a band for the model) is not pooled. ``n_lines``: the
    distinct straight lines of the pooled edges (:func:`~subpix_ros.core.blur_edges.
    count_lines` on each edge's sixth item, its line; without it, the pooled edges' count).
    """
    vals = np.array([e[0] for e in per_edge])
    ses = np.array([e[1] for e in per_edge])
    if vals.min() > cap:
        return _fallback(
            fallback,
            f"edges measured {vals.min():.2f} px or more, above what the frames' spectrum "
            f"allows ({cap:.2f} px): edges soft in the scene",
        )
    misfits = np.array([e[4] for e in per_edge])
    keep = (vals <= cap) & np.isfinite(misfits)  # no misfit: the model's band was too short
    if not keep.any():
        return _fallback(
            fallback,
            f"{len(per_edge)} measured edges, none with a usable fit to the edge model "
            f"below the frames' spectral cap ({cap:.2f} px)",
        )
    edges = [e for e, k in zip(per_edge, keep) if k]
    vals, ses, misfits = vals[keep], ses[keep], misfits[keep]
    unc_edge = np.hypot(ses, misfits)  # frames' scatter and the model misfit
    group = _consistent_with_lowest(vals, unc_edge)
    fill = 1.0
    if fit_fill:
        fill = max(e[2] for e, g in zip(edges, group) if g)
    if fill < 1.0:  # the group's edges refitted with the pooled fill, frame by frame
        refits = [
            _median_and_se([f.sigma_at(fill) for f in e[3]]) if g else (v, s)
            for e, g, v, s in zip(edges, group, vals, ses)
        ]
        vals, ses = np.array([r[0] for r in refits]), np.array([r[1] for r in refits])
        unc_edge = np.hypot(ses, misfits)
    v, s, u = vals[group], ses[group], unc_edge[group]
    raw, unc, bias = _pooled_mean(v, u, s)  # the low bias: the frames' scatter alone
    lo_g = int(np.argmin(v))
    raw = min(raw, float(v[lo_g] + 2.0 * u[lo_g]))  # at most two uncertainties above the lowest
    fill_note = f", fill factor {fill:.2f}" if fill < 1.0 else ""
    lines = [e[5] for e, g in zip(edges, group) if g and len(e) > 5]
    n_lines = count_lines(lines) if lines else int(group.sum())
    return BlurEstimate(
        max(0.0, raw - bias),
        "edges",
        uncertainty=unc,
        raw=raw,
        n_edges=int(group.sum()),
        reason=f"{int(group.sum())} of {len(per_edge)} measured edges pooled "
        f"({raw:.3f} +- {unc:.3f} px{fill_note}), minus the frames' standard error "
        f"{bias:.3f} px",
        fill_factor=float(fill),
        bias=bias,
        n_lines=n_lines,
    )


def resolve_blur(
    setting, frames: Sequence[np.ndarray], shifts: np.ndarray | None = None, **kw
) -> BlurEstimate:
    """Turn a ``blur_sigma`` setting (``"auto"`` or a number) into a :class:`BlurEstimate`.

    A number is used as given (source "parameter"); ``"auto"`` runs :func:`estimate_blur` on
    the (mono) frames with ``kw``.
    """
    v = parse_blur_sigma(setting)
    if v != "auto":
        return BlurEstimate(float(v), "parameter", reason="given")
    return estimate_blur(frames, shifts, **kw)


def check_given_blur(given: float, measured: BlurEstimate) -> BlurEstimate:
    """Check a given blur against the edges' measurement: the safety net of a lab calibration.

    Parameters
    ----------
    given : float
        The ``blur_sigma`` set as a number (input px).
    measured : BlurEstimate
        :func:`estimate_blur` on the flight's frames.

    Returns
    -------
    BlurEstimate
        The measured estimate (source "edges", the reason saying why) when the edges measure
        a blur lower than the given one by more than ``max(GIVEN_CHECK_MIN_PX,
        GIVEN_CHECK_SIGMAS x low_bias)`` (the frames' standard error,
        :attr:`BlurEstimate.low_bias`), comparing the pooled value before its low bias
        (``raw``); else the given value (source "parameter"; its reason says whether the edges
        were consistent with it or none was usable: "given; not checked: ...").

    Notes
    -----
    A scene edge is never sharper than the camera makes it, so edges measuring clearly less
    than the given blur mean the given value is too high, the expensive direction: over by
    0.2 px the reconstruction can fall below bicubic (docs/design-notes.md). A higher
    measurement is not used against the given value (scene edges may be soft). The margin
    counts the frames' scatter, not the edges' misfit to the model (in ``uncertainty``):
    texture beside an edge mostly reads sharper, so a margin widened by it would let a given
    value that is too high pass where edges are textured.
    """
    if measured.source == "edges" and np.isfinite(measured.raw):
        unc = measured.uncertainty if np.isfinite(measured.uncertainty) else 0.0
        scatter = measured.low_bias if np.isfinite(measured.low_bias) else 0.0
        margin = max(GIVEN_CHECK_MIN_PX, GIVEN_CHECK_SIGMAS * scatter)
        if given - measured.raw > margin:
            return BlurEstimate(
                measured.sigma,
                "edges",
                uncertainty=measured.uncertainty,
                raw=measured.raw,
                n_edges=measured.n_edges,
                n_lines=measured.n_lines,
                reason=f"blur_sigma {given:.3f} px given, but the edges measure {measured.raw:.3f}"
                f" +- {unc:.3f} px, lower by more than {margin:.3f} px: the given value would "
                f"over-deconvolve; measured {measured.sigma:.3f} px used ({measured.reason})",
                fill_factor=measured.fill_factor,
                bias=measured.bias,
            )
        return BlurEstimate(
            float(given),
            "parameter",
            reason=f"given (edges measure {measured.raw:.3f} +- {unc:.3f} px: consistent)",
        )
    # no usable edge: the given value stands, and says that nothing checked it (and why)
    why = (measured.reason or "nothing measured").removesuffix(
        _FALLBACK_NOTE.format(measured.sigma)
    )
    return BlurEstimate(float(given), "parameter", reason=f"given; not checked: {why}")


def pool_estimates(estimates: Sequence[BlurEstimate]) -> BlurEstimate:
    """Pool blur estimates of independent frames (other scenes, other moments) into one.

    Parameters
    ----------
    estimates : sequence of BlurEstimate
        :func:`estimate_blur` of each frame (or set); only those of source "edges" count.

    Returns
    -------
    BlurEstimate
        Source "edges": ``sigma = max(0, r - b)`` with the pooled ``raw`` r, its
        ``uncertainty`` u and low ``bias`` b (input px), ``n_edges`` the pooled estimates' edges,
        ``fill_factor`` the largest of theirs; "fallback" (:data:`FALLBACK_SIGMA`) when no
        estimate has edges.

    Notes
    -----
    The camera's blur is one number; a scene's edges are never sharper than the camera
    makes them, so the lowest raw value ``r_lo`` (uncertainty ``u_lo``) bounds it. As
    :func:`_pool_edges` does for the edges of one set: the estimates with
    ``r_i <= r_lo + 2 hypot(u_i, u_lo)`` are averaged with weights ``w_i = 1 / u_i^2``,
    ``r = min(sum w_i r_i / sum w_i, r_lo + 2 u_lo)``, and ``u`` is the larger of
    ``1 / sqrt(sum w_i)`` and the weighted spread over ``sqrt(n)``. The result is biased
    low as every edge estimate is (over-estimating the blur costs far more than
    under-estimating it): by ``b``, the larger of ``sqrt(sum w_i^2 b_i^2) / sum w_i`` (each
    estimate's own low bias ``b_i``, :attr:`BlurEstimate.low_bias`) and the same spread term.
    """
    usable = [
        e
        for e in estimates
        if e.source == "edges" and np.isfinite(e.raw) and np.isfinite(e.uncertainty)
    ]
    if not usable:
        return _fallback(FALLBACK_SIGMA, f"no usable edge in {len(estimates)} frames")
    r = np.array([e.raw for e in usable])
    u = np.maximum(np.array([e.uncertainty for e in usable]), 0.005)
    group = _consistent_with_lowest(r, u)
    rg, ug = r[group], u[group]
    pooled = [e for e, g in zip(usable, group) if g]
    b = np.minimum(np.array([e.low_bias for e in pooled]), ug)
    mean, unc, bias = _pooled_mean(rg, ug, b)
    lo = int(np.argmin(r))
    raw = min(mean, float(r[lo] + 2.0 * u[lo]))
    n_lines = sum(e.n_lines for e in pooled)  # lines of different frames are not compared
    return BlurEstimate(
        max(0.0, raw - bias),
        "edges",
        uncertainty=unc,
        raw=raw,
        n_edges=sum(e.n_edges for e in pooled),
        reason=f"{len(pooled)} of {len(estimates)} frames' edge estimates pooled "
        f"({raw:.3f} +- {unc:.3f} px), minus their frames' standard error {bias:.3f} px",
        fill_factor=max(e.fill_factor for e in pooled),
        bias=bias,
        n_lines=n_lines,
    )


class BlurCalibration:
    """The blur of one flight, kept across frame sets and refreshed slowly.

    Parameters
    ----------
    setting : str or float, optional
        A ``blur_sigma`` setting (:func:`parse_blur_sigma`).
    refresh_sets : int, optional
        Once an edge has been measured, measure again every ``refresh_sets``-th set.
    search_sets : int, optional
        Until then (no edge measured yet in the flight), measure every ``search_sets``-th
        set: the first set is always measured.
    check_given : bool, optional
        With a number, measure on the same schedule too and replace the number by the
        measurement when it is clearly lower (:func:`check_given_blur`); default False (the
        number is used as given, the frames not looked at).

    Notes
    -----
    With a number every set gets it (source "parameter"). With ``"auto"``,
    :func:`estimate_blur` runs on the first set, then on every ``search_sets``-th set until
    a set shows a usable edge (the flight may reach a road or a roof only later), and from
    then on every ``refresh_sets``-th set (the calibration can cost a sizeable part of a
    set's reconstruction). The blur in use is the lowest of the last ``keep_edges`` edge
    estimates (a set without edges in view does not discard them): an edge soft in the scene
    (a shadow's border) only ever reads above the camera's blur, so a set that shows only
    such an edge does not replace a sharper edge measured a few refreshes before, while a
    real change of the camera's blur is taken once ``keep_edges`` refreshes have seen it.
    Until the first edge estimate the fallback is used. A given number checked against the
    edges (``check_given``) follows the same schedule.
    """

    def __init__(
        self,
        setting="auto",
        refresh_sets: int = 10,
        check_given: bool = False,
        search_sets: int = 1,
        keep_edges: int = 3,
    ) -> None:
        self.setting = parse_blur_sigma(setting)
        self.keep_edges = max(1, int(keep_edges))
        self._edges: list[BlurEstimate] = []  # the last keep_edges edge estimates, oldest first
        self.refresh_sets = max(1, int(refresh_sets))
        self.search_sets = max(1, int(search_sets))
        self.check_given = bool(check_given)
        self.current: BlurEstimate | None = None
        self.edges_seen = False  # whether any measurement so far found a usable edge
        self._since = 0  # sets since the last measurement

    @property
    def due(self) -> bool:
        """Whether the next :meth:`update` measures the frames (else they are not looked at)."""
        if self.setting != "auto" and not self.check_given:
            return False
        every = self.refresh_sets if self.edges_seen else self.search_sets
        return self.current is None or self._since >= every

    def update(
        self,
        frames: Sequence[np.ndarray],
        shifts: np.ndarray | None = None,
        masks: Sequence[np.ndarray] | None = None,
        motion_blur: tuple[float, float] | None = None,
        boxes: Sequence[tuple[int, int, int, int]] | None = None,
    ) -> BlurEstimate:
        """Return the blur for this set, re-estimated when due (see the class).

        Parameters
        ----------
        frames : sequence of numpy.ndarray
            The set's mono frames.
        shifts : numpy.ndarray, optional
            (N, 2) shifts relative to frame 0.
        masks : sequence of numpy.ndarray, optional
            Valid pixels per frame.
        motion_blur : (float, float), optional
            This set's image motion during the exposure (input px), taken out of the edges
            (:func:`estimate_blur`).
        boxes : sequence of (int, int, int, int), optional
            Valid rectangles per frame, instead of ``masks`` (:func:`estimate_blur`).

        Returns
        -------
        BlurEstimate
        """
        if self.setting != "auto" and not self.check_given:
            if self.current is None:
                self.current = BlurEstimate(float(self.setting), "parameter", reason="given")
            return self.current
        if not self.due:
            self._since += 1
            return self.current
        self._since = 1
        new = estimate_blur(frames, shifts, masks=masks, motion_blur=motion_blur, boxes=boxes)
        self.edges_seen = self.edges_seen or new.source == "edges"
        if self.setting != "auto":  # a given number, checked against the edges
            self.current = check_given_blur(float(self.setting), new)
        elif new.source == "edges":
            self._edges = [*self._edges, new][-self.keep_edges :]
            self.current = _lowest_recent(self._edges)
        elif self.current is None or self.current.source != "edges":
            self.current = new
        return self.current


def _lowest_recent(edges: Sequence[BlurEstimate]) -> BlurEstimate:
    """Return the lowest of recent edge estimates, its reason saying so when it is not the newest.

    A scene edge is never sharper than the camera makes it (an edge soft in the scene reads
    higher), so of estimates a few sets apart the lowest is the camera's.
    """
    newest = edges[-1]
    low = min(edges, key=lambda e: e.sigma)
    if low is newest:
        return newest
    return replace(
        low,
        reason=f"{low.reason}; kept over the newest measurement {newest.sigma:.3f} px "
        f"(the lowest of the last {len(edges)}: an edge soft in the scene reads higher)",
    )
