"""Public entry point :func:`estimate_shift`: input checks, method dispatch, fine stage."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np

from ..validity import common_valid_box
from .coarse import _coarse_start
from .covariance import _statistics
from .gauss_newton import _gauss_newton, _GaussNewtonRun
from .inputs import MaskArg, _as_working, _fill_invalid, _is_constant, _masks
from .level import _BLOCK, _Level
from .noise import _noise_variance
from .prefilter import _ADAPTIVE_SIGMAS, _DEFAULT_SIGMA, predicted_shift_variance
from .result import ShiftResult, _fail
from .seed import _seed_iterated, _seed_result

METHODS = ("default", "seed", "seed-iterated")

_NOISE_LIMITED_PX = 0.005  # standard error (px) above which a pair counts as noise-limited
_NOISY_PIXEL_FACTOR = 4  # a noise-limited pair gets this many times the max_pixels budget
_BORDER = 2  # pixels kept clear of the frame edges by the Gauss-Newton stage
_DIVERGED_PX = 0.05  # a run that did not converge is accepted if its last step was below this


@dataclass(frozen=True)
class _Options:
    """Options of the Gauss-Newton estimator (``method="default"``), as :func:`estimate_shift`."""

    max_iterations: int
    tol: float
    taps: int
    sigma: Optional[float]  # None: adaptive (``_DEFAULT_SIGMA``, re-chosen when noise-limited)
    band: float
    max_pixels: Optional[int]
    coarse_size: int
    misfit_px: float


# long: the numpydoc Parameters of 13 options; the body is ~40 lines
def estimate_shift(
    reference: np.ndarray,
    moving: np.ndarray,
    *,
    mask: MaskArg = None,
    method: str = "default",
    prior: Optional[Sequence[float]] = None,
    max_iterations: int = 10,
    tol: float = 1e-3,
    taps: int = 8,
    prefilter_sigma: Optional[float] = None,
    band: float = 0.85,
    max_pixels: Optional[int] = 1 << 18,
    coarse_size: int = 256,
    misfit_px: float = 0.05,
    seed_iterations: int = 3,
) -> ShiftResult:
    """Estimate the shift ``(u, v)`` of the scene content from ``reference`` to ``moving``.

    Parameters
    ----------
    reference, moving : ndarray
        2-D arrays of equal shape, any integer or float dtype (use
        :func:`subpix_ros.core.luminance.luminance` for colour).
    mask : ndarray of bool or tuple, optional
        True = valid in both frames, or a pair ``(reference_mask, moving_mask)``. NaN/inf
        pixels and integer pixels at the dtype's maximum (saturated) are invalid too. Invalid
        pixels, and every pixel whose filter support touches one, are left out of all sums.
    method : {"default", "seed", "seed-iterated"}
        ``"default"``: coarse phase correlation + designed-filter Gauss-Newton;
        ``"seed"``: the paper's single solve (METHODS.md A; no mask, no prior);
        ``"seed-iterated"``: the seed re-solved after cubic warps.
    prior : sequence of float, optional
        Starting ``(u, v)``; replaces the coarse stage.
    max_iterations : int
        Most fine Gauss-Newton solves.
    tol : float
        Convergence threshold on the Gauss-Newton step (px).
    taps : int
        Length of the designed filter (even, >= 4).
    prefilter_sigma : float, optional
        Gaussian prefilter (px). None: 0.8 px, re-chosen for noise-limited pairs from the
        noise estimated in the data; a number fixes it.
    band : float
        Design band of the filter (fraction of Nyquist).
    max_pixels : int or None
        Above this many pixels only the most textured 128x128 tiles (up to that total; 4x that
        on noise-limited pairs) enter the fine stage. None: all.
    coarse_size : int
        The coarse stage's pyramid halves the frames while their larger side exceeds this.
    misfit_px : float
        RMS spread of 3x3-grid local shifts above which (and statistically significant) the
        result is flagged ``misfit``.
    seed_iterations : int
        Solves of ``"seed-iterated"``.

    Returns
    -------
    ShiftResult
        ``ok=False`` with ``u = v = z = None`` and a reason for textureless, constant,
        all-invalid, too small or non-overlapping input.

    Raises
    ------
    ValueError
        For an unknown method, wrong argument types or shapes.

    Notes
    -----
    Sign convention: a feature at ``(r, c)`` in ``reference`` appears at ``(r + u, c + v)``
    in ``moving`` (pixels; rows, columns), i.e. ``moving(x + s) = reference(x) + z``.
    The default method (:mod:`subpix_ros.core.shift`) solves, by Gauss-Newton on
    ``(u, v, z)``::

        min sum_x w(x) ((H_t * M)(x + k) - (H_0 * R)(x) - z)^2,   k = floor(s), t = s - k

    with ``H_t`` a Gaussian prefilter combined with a fractional delay ``t``.
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {METHODS}")
    ref_work, ref_valid = _as_working(reference, "reference")
    mov_work, mov_valid = _as_working(moving, "moving")
    if ref_work.shape != mov_work.shape:
        raise ValueError(
            f"reference {ref_work.shape} and moving {mov_work.shape} must have the same shape"
        )
    if taps < 4 or taps % 2:
        raise ValueError("taps must be an even number >= 4")
    ref_mask, mov_mask = _masks(mask, ref_work.shape)
    if ref_mask is not None and not ref_mask.all():
        ref_valid = ref_mask if ref_valid is None else (ref_valid & ref_mask)
    if mov_mask is not None and not mov_mask.all():
        mov_valid = mov_mask if mov_valid is None else (mov_valid & mov_mask)
    if method == "default":
        ref_work, mov_work, ref_valid, mov_valid = _crop_to_valid_box(
            ref_work, mov_work, ref_valid, mov_valid
        )
    why = _unusable(ref_work, mov_work, ref_valid, mov_valid, method, taps, prior)
    if why is not None:
        return why
    if method in ("seed", "seed-iterated"):
        return _estimate_seed(reference, moving, mask, method, seed_iterations)
    opts = _Options(
        int(max_iterations),
        float(tol),
        int(taps),
        None if prefilter_sigma is None else float(prefilter_sigma),
        float(band),
        max_pixels,
        int(coarse_size),
        float(misfit_px),
    )
    return _estimate_gauss_newton(ref_work, mov_work, ref_valid, mov_valid, prior, opts)


def _crop_to_valid_box(ref_work, mov_work, ref_valid, mov_valid):
    """Crop to the validity when it is a rectangle (an integer-crop alignment): no mask needed."""
    # one mask for both frames (the usual aligned pair) is looked at once
    masks = (ref_valid,) if ref_valid is mov_valid else (ref_valid, mov_valid)
    box = common_valid_box([m for m in masks if m is not None])
    if box is not None:
        r0, r1, c0, c1 = box
        ref_work, mov_work = ref_work[r0:r1, c0:c1], mov_work[r0:r1, c0:c1]
        ref_valid = mov_valid = None
    return ref_work, mov_work, ref_valid, mov_valid


def _unusable(ref_work, mov_work, ref_valid, mov_valid, method, taps, prior):
    """Return a failed result for input no method can measure, else None.

    Raises
    ------
    ValueError
        For a prior that is not a finite pair.
    """
    min_side = 8 if method == "seed" else 2 * (taps // 2 + 2) + 2 * _BLOCK
    if min(ref_work.shape) < min_side:
        return _fail(
            f"input too small: {ref_work.shape[0]}x{ref_work.shape[1]} px, "
            f"need at least {min_side} px per side",
            method,
        )
    if (ref_valid is not None and not ref_valid.any()) or (
        mov_valid is not None and not mov_valid.any()
    ):
        return _fail("no valid pixels (all NaN, masked or saturated)", method)
    if prior is not None:
        pr = np.asarray(prior, dtype=np.float64).reshape(-1)
        if pr.size != 2 or not np.all(np.isfinite(pr)):
            raise ValueError("prior must be a finite (u, v) pair")
    if _is_constant(ref_work, ref_valid) or _is_constant(mov_work, mov_valid):
        return _fail("textureless input: constant frame", method)
    return None


def _estimate_seed(reference, moving, mask, method: str, seed_iterations: int) -> ShiftResult:
    """Run the published method (no mask: saturated pixels enter as they are)."""
    x = np.asarray(reference, dtype=np.float64)  # full precision: float64 accumulation
    y = np.asarray(moving, dtype=np.float64)
    if mask is not None or not (np.isfinite(x).all() and np.isfinite(y).all()):
        return _fail(
            f"method {method!r} has no validity mask: input has NaN/inf or a mask was given",
            method,
        )
    if method == "seed":
        return _seed_result(x, y, "seed", 1, False)
    return _seed_iterated(x, y, seed_iterations)


def _run_fine(lv: _Level, start: np.ndarray, opts: _Options) -> _GaussNewtonRun:
    """Run the fine Gauss-Newton stage from ``start``, falling back to the start (0, 0)."""
    run = _gauss_newton(lv, start, opts.max_iterations, opts.tol, _BORDER, blocks=True)
    failed = run.reason or (not run.converged and run.last > _DIVERGED_PX)
    if failed and np.max(np.abs(start)) > 0.5:
        # the coarse start was wrong (e.g. a noise peak in the phase correlation):
        # try the co-registered start (0, 0) and keep it if that converges
        run0 = _gauss_newton(lv, np.zeros(2), opts.max_iterations, opts.tol, _BORDER, blocks=True)
        if run0.converged:
            run = run0
    return run


def _estimate_gauss_newton(
    ref_work, mov_work, ref_valid, mov_valid, prior, opts: _Options
) -> ShiftResult:
    """Run the default method: coarse start, fine Gauss-Newton, statistics, noise refit."""
    method = "default"
    adaptive = opts.sigma is None
    sigma = _DEFAULT_SIGMA if adaptive else opts.sigma
    h, w = ref_work.shape
    start, coarse, score = _coarse_start(
        ref_work, mov_work, ref_valid, mov_valid, prior, opts, sigma, _BORDER
    )
    lv = _Level(
        ref_work,
        mov_work,
        ref_valid,
        mov_valid,
        opts.taps,
        sigma,
        opts.band,
        opts.max_pixels,
        score,
        kmax=int(np.max(np.abs(start))) + 3,
    )
    lv.blocks = True
    run = _run_fine(lv, start, opts)
    if run.reason:
        return _fail(run.reason, method, iterations=run.it, coarse=coarse)
    if not run.converged and run.last > _DIVERGED_PX:
        return _fail(
            f"Gauss-Newton did not converge (last step {run.last:.3g} px)",
            method,
            iterations=run.it,
            coarse=coarse,
        )
    res = _statistics(run, lv, h, w, opts.misfit_px, coarse)
    noise_limited = res.ok and not res.misfit and max(res.u_std, res.v_std) > _NOISE_LIMITED_PX
    if adaptive and noise_limited:
        res = _refit_noise_limited(
            ref_work, mov_work, ref_valid, mov_valid, run, res, sigma, score, opts, coarse
        )
    return res


def _refit_noise_limited(
    ref_work, mov_work, ref_valid, mov_valid, run, res, sigma, score, opts: _Options, coarse
) -> ShiftResult:
    """Re-run the fine stage of a noise-limited pair with the prefilter of least variance.

    The aliasing bias (< 0.003 px) no longer matters: the prefilter is re-chosen among
    ``sigma`` and ``_ADAPTIVE_SIGMAS`` by :func:`.predicted_shift_variance` from the frames'
    own spectrum and the noise estimated from the least-squares residual, the tile budget
    grows ``_NOISY_PIXEL_FACTOR`` times, and Gauss-Newton restarts from the estimate. The
    refit replaces ``res`` only if it converges to an ``ok``, misfit-free result.
    """
    se = run.s_eval
    sig2 = _noise_variance(
        run.A, run.b, run.sse, run.n, opts.taps, sigma, opts.band, se - np.floor(se)
    )
    if sig2 is None or not sig2 > 0:
        return res
    cands = (sigma,) + tuple(x for x in _ADAPTIVE_SIGMAS if x != sigma)
    pv = predicted_shift_variance(
        _fill_invalid(ref_work, ref_valid), _fill_invalid(mov_work, mov_valid), sig2, cands
    )
    best = cands[int(np.argmin(pv))]
    # tiles only (a pixel budget): noise-limited precision grows with the pixel count
    tiled = run.rects is not None and len(run.rects) > 1
    budget = opts.max_pixels * _NOISY_PIXEL_FACTOR if tiled else opts.max_pixels
    if not ((best != sigma or tiled) and np.isfinite(pv.min())):
        return res
    start = np.array([res.u, res.v])
    lv = _Level(
        ref_work,
        mov_work,
        ref_valid,
        mov_valid,
        opts.taps,
        best,
        opts.band,
        budget,
        score,
        kmax=int(np.max(np.abs(start))) + 3,
    )
    lv.blocks = True
    refit = _gauss_newton(lv, start, opts.max_iterations, opts.tol, _BORDER, blocks=True)
    if refit.reason or not (refit.converged or refit.last <= _DIVERGED_PX):
        return res
    h, w = ref_work.shape
    res_refit = _statistics(refit, lv, h, w, opts.misfit_px, coarse)
    if res_refit.ok and not res_refit.misfit:
        res_refit.iterations += res.iterations
        return res_refit
    return res
