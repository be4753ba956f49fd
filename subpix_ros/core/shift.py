"""Sub-pixel shift between two frames (METHODS.md A), at the accuracy limit.

Sign convention (used everywhere in subpix_ros)
-----------------------------------------------
``(u, v)`` = (rows, columns) in pixels is how far the scene content moved
from the ``reference`` frame to the ``moving`` frame: a feature at ``(r, c)``
in the reference appears at ``(r + u, c + v)`` in the moving frame, i.e.
``moving(x + s) = reference(x) + z`` with ``s = (u, v)`` and ``z`` an
intensity offset (moving minus reference, in the input's digital numbers).

Methods
-------
``method="seed"``: the published estimator exactly (METHODS.md A): the
matrices D, E, F on the ``(m-2) x (n-2)`` interior, ``A C = B`` with means
of Hadamard products, float64 accumulation, one closed-form solve. The paper
leaves sign and scale open; d and e are two-pixel central differences summed
over both frames (``d ~ 4 dI/dr``, ``e ~ 4 dI/dc``) and ``f = y - x ~ -s.grad I
+ z``, so the paper's ``C = (c_u, c_v, z)`` relates to our shift by
``u = -4 c_u``, ``v = -4 c_v`` (checked by tests against known shifts).
:func:`seed_solve` returns the raw ``C``.

``method="seed-iterated"``: the seed's normal equations re-solved after
warping the moving frame by the current estimate with OpenCV INTER_CUBIC,
3 solves (the reference point quoted in the issue; biased by the cubic warp).

``method="default"``: coarse stage + Gauss-Newton refinement:

1. Coarse: a pyramid (INTER_AREA halvings while the larger side exceeds
   ``coarse_size`` px); on its coarsest level ``cv2.phaseCorrelate`` (Hanning
   window, after a 1 px Gaussian blur) unless a ``prior`` is given, then a
   few Gauss-Newton iterations on each pyramid level of at most 2^18 px.
2. Fine: Gauss-Newton on ``(u, v, z)`` at full resolution with the
   reference-side Jacobian (inverse compositional): minimise
   ``sum w ((H_t * M)(x + k) - (H_0 * R)(x) - z)^2`` where ``k = floor(s)``,
   ``t = s - k`` and ``H_t`` is a short separable FIR filter designed by
   least squares so that its frequency response approximates
   ``G(w) exp(i w t)`` for ``|w| <= band * pi``: a Gaussian prefilter ``G``
   (``prefilter_sigma`` px, so both frames see the same ``G``) combined with
   an accurate fractional delay. The prefilter removes most of the aliased
   near-Nyquist content that biases every translation estimator, and the
   designed delay has no interpolation bias to speak of (measured on the
   rendered Seneca pairs: linear interpolation ~0.015 px bias, Lanczos-4
   0.004 px, this filter < 0.001 px). The step uses the slope of the
   estimating equation with the reference-noise energy removed (see
   :func:`_signal_matrix`), is capped at 1 px and damped when it oscillates;
   if the coarse start does not converge, the co-registered start (0, 0) is
   tried. The whole overlap of the frames (less the filter margins) is used;
   above ``max_pixels`` only the most textured 128x128 tiles (spread over a
   3x3 grid of the frame) enter the fine stage: at high SNR the precision is
   set by aliasing, not by the pixel count.
3. Noise-limited pairs (reported standard error above 0.005 px, when the
   aliasing bias < 0.003 px no longer matters), unless ``prefilter_sigma``
   is given: the prefilter is re-chosen among 0.8, 0.7, 0.6, 0.5, 0.4 px by
   the smallest variance predicted by :func:`predicted_shift_variance` from
   the frames' own spectrum and the noise variance estimated from the
   least-squares residual (:func:`_noise_variance`), the tile budget grows
   4x, and the fine stage is re-run from the estimate. Why not reach the
   Cramer-Rao bound ``2 sigma^2 J^-1``: a gradient / cross-correlation
   estimator with frequency weight ``W`` between two noisy frames of an
   unknown scene has a noise-times-noise term in its score, ``var ~ sum_k
   W^2 w^2 (2 P n + n^2) / (sum_k W w^2 P)^2`` over frequencies ``k``
   (signal power ``P``, noise power ``n``), which the bound lacks. The best
   weight ``W = P / (2 P n + n^2)`` needs the scene's own noise-free power
   per frequency; weights estimated from the noisy frames (smoothed
   periodograms, radial or polar averages) do no better than the best
   Gaussian, which is what is used (computed with this formula from the
   noise-free references of the noisy benchmark set, periodic frames: ideal
   weight 1.26x the bound, best Gaussian 1.37x, before edge losses).
   Symmetric gradients (mean of both frames') give the same score: in the
   Fourier domain ``Im[conj((X + Y) / 2) (Y - X)] = Im[conj(X) Y]``, so they
   are not used. A NON-linear denoised scene for the Jacobian was tried too
   (score ``sum grad(D(a)) e`` with ``a = (H_0 R + (H_t M)(x + k)) / 2`` and
   D a denoiser) and is not used: the scene must be rebuilt at every ``s``
   (one built at the start ``s0`` anchors the answer to ``s0``: its noise
   term vanishes at ``s = s0``), i.e. Newton on the fixed point with a
   finite-difference slope (3 denoiser calls), which keeps the sandwich
   covariance calibrated (RMSE / reported std 0.97-1.02). On the noisy
   benchmark set (RMSE / bound over the pixels used, now 1.40) the
   noise-free scene would give 1.09, but real denoisers recover little of
   that: bilateral 1.37, 8x8 DCT threshold + Wiener 1.36, non-local means
   (h = 0.8 sigma) 1.32-1.33, NLM + DCT Wiener 1.32 (paired RMSE ratio
   0.96-0.98, 95 % intervals reaching 1.0), at 3x (bilateral) to 20x (NLM)
   the time of a 1080p noise-limited pair. BM3D (the ``bm3d`` package, whose
   licence allows non-commercial use only, so it cannot be a dependency)
   did hardly better on 80 of the pairs: RMSE 0.0211 px against NLM's
   0.0215, the noise-free scene's 0.0161 and the shipped estimator's 0.0225
   (/CRB 1.48, 1.51, 1.13, 1.58 on that subset; 0.94 x the shipped 1.47 on
   the whole set would be about 1.38),
   at 7.8 s per 176x176 pair. Spatial weighting does not help
   either: pixel weights ``J_loc / (J_loc + k n_g)`` from the local gradient
   energy (box 9-33 px, ``n_g`` the gradient noise energy, k 0.5-4), even
   with ``J_loc`` from the noise-free frame, changed the RMSE by -4 % to
   +20 % (60 noisy pairs, paired differences within their standard errors
   at best): the Seneca texture is too even for it.
4. Quality: the covariance of (u, v) is the cluster-robust "sandwich"
   ``S^-1 M S^-T`` over 16x16-pixel blocks of the final residual scores
   ``b_k``: ``M = sum_k b_k b_k^T`` plus the cross products of neighbouring
   blocks (spatial HAC, for the noise the filters correlate across block
   edges), valid for correlated noise and for model error; ``S`` is the
   measured slope of the estimating equation (:func:`_score_slope`; the
   Gauss-Newton matrix ``sum J J^T`` understates it by 10-25 % on noisy,
   lightly prefiltered pairs).
   Local shifts over a 3x3 grid of the frame measure residual misfit
   (rotation, scale, parallax): ``misfit`` is set when their RMS spread
   exceeds ``misfit_px`` and is significant (chi-square) against the noise
   covariance from block scores demeaned within each grid cell; a flagged
   result carries the spread in its covariance.

Failure: textureless, constant, all-NaN, too small or non-overlapping input
gives ``ok=False`` with a ``reason`` and ``u = v = z = None`` (never NaN or a
made-up number). Wrong argument types/shapes raise ``ValueError``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from functools import lru_cache
from typing import Optional, Sequence, Tuple, Union

import cv2
import numpy as np

from .validity import common_valid_box

__all__ = [
    "ShiftResult",
    "estimate_shift",
    "seed_system",
    "seed_solve",
    "fractional_shift_kernel",
    "coarse_shift",
    "predicted_shift_variance",
    "METHODS",
]

METHODS = ("default", "seed", "seed-iterated")

MaskArg = Union[None, np.ndarray, Tuple[Optional[np.ndarray], Optional[np.ndarray]]]


@dataclass
class ShiftResult:
    """Outcome of :func:`estimate_shift`.

    ``u``, ``v``: shift in pixels (rows, cols), scene content reference ->
    moving (see module docstring); ``z``: intensity offset moving - reference
    (input DN). All three are None when ``ok`` is False, and ``reason`` then
    says why. ``cov``: 2x2 covariance of (u, v) in px^2 (None if unknown),
    ``u_std``/``v_std`` its square roots. ``cond``: 2-norm condition number
    of the normal matrix A. ``n_pixels``: pixels in the final sums.
    ``iterations``: fine Gauss-Newton solves; ``converged``: the last update
    was below the tolerance. ``residual_rms``: RMS of the final residual (DN).
    ``misfit``: the translation model does not fit (local shifts across the
    frame disagree, e.g. rotation); ``misfit_px`` the RMS spread of the local
    shifts about the global one (px), ``warning`` a human-readable note.
    """

    ok: bool
    reason: str = ""
    u: Optional[float] = None
    v: Optional[float] = None
    z: Optional[float] = None
    cov: Optional[np.ndarray] = None
    u_std: Optional[float] = None
    v_std: Optional[float] = None
    cond: Optional[float] = None
    n_pixels: int = 0
    iterations: int = 0
    converged: bool = False
    residual_rms: Optional[float] = None
    misfit: bool = False
    misfit_px: Optional[float] = None
    warning: str = ""
    method: str = "default"
    coarse: Optional[Tuple[float, float]] = None

    @property
    def shift(self) -> Optional[Tuple[float, float]]:
        """``(u, v)`` or None."""
        return None if self.u is None else (self.u, self.v)

    def as_dict(self) -> dict:
        """JSON-ready dict (numpy arrays and scalars converted)."""
        d = asdict(self)
        d["cov"] = None if self.cov is None else np.asarray(self.cov, dtype=float).tolist()
        d["coarse"] = None if self.coarse is None else [float(x) for x in self.coarse]
        for k, val in list(d.items()):
            if isinstance(val, np.generic):
                d[k] = val.item()
        return d


def _fail(reason: str, method: str, **kw) -> ShiftResult:
    return ShiftResult(ok=False, reason=reason, method=method, **kw)


# ---------------------------------------------------------------------------
# input handling
# ---------------------------------------------------------------------------


def _as_working(image: np.ndarray, name: str) -> Tuple[np.ndarray, Optional[np.ndarray]]:
    """Working array (uint8/uint16 kept as is for OpenCV, else float32) and validity.

    Validity is None when every pixel is valid; otherwise a bool array that is
    False at NaN/inf and, for uint8/uint16, at the dtype's maximum (saturated:
    the true value is unknown).
    """
    a = np.asarray(image)
    if a.ndim != 2:
        raise ValueError(
            f"{name} must be a 2-D (mono) array, got shape {a.shape}; convert colour with luminance()"
        )
    if a.dtype == bool or not (
        np.issubdtype(a.dtype, np.integer) or np.issubdtype(a.dtype, np.floating)
    ):
        raise ValueError(f"{name} dtype {a.dtype} is not an integer or float type")
    if a.size == 0:
        raise ValueError(f"{name} is empty")
    if a.dtype in (np.uint8, np.uint16):
        a = np.ascontiguousarray(a)
        sat = np.iinfo(a.dtype).max
        if cv2.minMaxLoc(a)[1] >= sat:
            return a, a != sat
        return a, None
    f = np.ascontiguousarray(a, dtype=np.float32)
    # finite iff the sum is: OpenCV sums float32 in double (no overflow of finite values; NaN and
    # inf propagate), one read of the frame and no temporary (cv2.checkRange took 3-6x longer)
    if np.issubdtype(a.dtype, np.floating) and not np.isfinite(cv2.sumElems(f)[0]):
        valid = np.isfinite(f)
        return np.where(valid, f, np.float32(0.0)), valid
    return f, None


def _is_constant(a: np.ndarray, valid: Optional[np.ndarray]) -> bool:
    if valid is None:
        lo, hi, _, _ = cv2.minMaxLoc(a)
    else:
        lo, hi, _, _ = cv2.minMaxLoc(a, mask=valid.astype(np.uint8))
    return hi <= lo


def _masks(
    mask: MaskArg, shape: Tuple[int, int]
) -> Tuple[Optional[np.ndarray], Optional[np.ndarray]]:
    if mask is None:
        return None, None
    if isinstance(mask, (tuple, list)):
        if len(mask) != 2:
            raise ValueError("mask must be an array or a (reference_mask, moving_mask) pair")
        out = []
        for m in mask:
            if m is None:
                out.append(None)
                continue
            m = np.asarray(m)
            if m.shape != shape:
                raise ValueError(f"mask shape {m.shape} != image shape {shape}")
            out.append(m.astype(bool, copy=False))  # read only: a bool mask is not copied
        return out[0], out[1]
    m = np.asarray(mask)
    if m.shape != shape:
        raise ValueError(f"mask shape {m.shape} != image shape {shape}")
    m = m.astype(bool, copy=False)
    return m, m


# ---------------------------------------------------------------------------
# the seed (METHODS.md A)
# ---------------------------------------------------------------------------


def _seed_sums(x: np.ndarray, y: np.ndarray):
    """Means of the seed's products (float64) plus <F F>, in one pass over D, E, F."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    s = x + y
    d = (s[2:, 1:-1] - s[:-2, 1:-1]).ravel()
    e = (s[1:-1, 2:] - s[1:-1, :-2]).ravel()
    f = (y[1:-1, 1:-1] - x[1:-1, 1:-1]).ravel()
    n = d.size
    dd, de, ee = np.dot(d, d) / n, np.dot(d, e) / n, np.dot(e, e) / n
    dm, em, fm = d.sum() / n, e.sum() / n, f.sum() / n
    A = np.array([[dd, de, dm], [de, ee, em], [dm, em, 1.0]])
    B = np.array([np.dot(f, d) / n, np.dot(f, e) / n, fm])
    return A, B, float(np.dot(f, f) / n), n


def seed_system(x: np.ndarray, y: np.ndarray) -> Tuple[np.ndarray, np.ndarray, int]:
    """The seed's normal equations ``A C = B`` (METHODS.md A), float64.

    ``x`` reference, ``y`` moving, both m x n. With (0-based) ``l = i + 2``,
    ``k = j + 1``: ``d = x[l,k] + y[l,k] - x[l-2,k] - y[l-2,k]``, ``e =
    x[l-1,k+1] + y[l-1,k+1] - x[l-1,k-1] - y[l-1,k-1]``, ``f = y[l-1,k] -
    x[l-1,k]`` on the (m-2) x (n-2) interior; ``A = [[<DD>,<DE>,<D>],
    [<DE>,<EE>,<E>],[<D>,<E>,1]]``, ``B = [<FD>,<FE>,<F>]`` (means of
    Hadamard products). Returns (A, B, number of interior pixels).
    """
    A, B, _, n = _seed_sums(x, y)
    return A, B, n


def seed_solve(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """The paper's raw solution ``C = (c_u, c_v, z)`` of ``A C = B``.

    Our shift convention is ``u = -4 c_u``, ``v = -4 c_v`` (module docstring).
    Raises ``numpy.linalg.LinAlgError`` if A is singular.
    """
    A, B, _ = seed_system(x, y)
    return np.linalg.solve(A, B)


def _seed_result(
    x: np.ndarray, y: np.ndarray, method: str, iterations: int, converged: bool
) -> ShiftResult:
    A, B, ff, n = _seed_sums(x, y)
    cond = float(np.linalg.cond(A))
    if not np.isfinite(cond) or cond > 1e12:
        return _fail(
            f"textureless or degenerate input: condition number of A is {cond:.3g}",
            method,
            cond=cond,
        )
    C = np.linalg.solve(A, B)
    u, v, z = -4.0 * C[0], -4.0 * C[1], C[2]
    # residual of f = c_u d + c_v e + z: <r^2> = <FF> - 2 C.B + C^T A C (no second pass)
    s2 = max(ff - 2.0 * float(C @ B) + float(C @ A @ C), 0.0) * n / max(n - 3, 1)
    covC = s2 * np.linalg.inv(A * n)
    cov = 16.0 * covC[:2, :2]
    return ShiftResult(
        ok=True,
        u=float(u),
        v=float(v),
        z=float(z),
        cov=cov,
        u_std=float(math.sqrt(max(cov[0, 0], 0.0))),
        v_std=float(math.sqrt(max(cov[1, 1], 0.0))),
        cond=cond,
        n_pixels=int(n),
        iterations=iterations,
        converged=converged,
        residual_rms=float(math.sqrt(s2)),
        method=method,
    )


def _warp_translate(
    img: np.ndarray, u: float, v: float, interp: int = cv2.INTER_CUBIC
) -> np.ndarray:
    """``out(x) = img(x + s)``: moves content by ``-s`` (undoes a shift ``s``)."""
    h, w = img.shape
    M = np.float64([[1, 0, v], [0, 1, u]])
    return cv2.warpAffine(
        img, M, (w, h), flags=interp | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE
    )


def _seed_iterated(x: np.ndarray, y: np.ndarray, iterations: int = 3) -> ShiftResult:
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    u = v = 0.0
    res = None
    b = 0
    for _ in range(iterations):
        yw = _warp_translate(y, u, v) if (u or v) else y
        b = int(math.ceil(max(abs(u), abs(v)))) + 2
        if 2 * b + 8 > min(x.shape):
            return _fail(
                "seed-iterated diverged: shift estimate exceeds the frame", "seed-iterated"
            )
        res = _seed_result(x[b:-b, b:-b], yw[b:-b, b:-b], "seed-iterated", 0, False)
        if not res.ok:
            return res
        u += res.u
        v += res.v
    res.u, res.v = float(u), float(v)
    res.iterations = iterations
    return res


# ---------------------------------------------------------------------------
# designed fractional-delay + prefilter kernels
# ---------------------------------------------------------------------------


@lru_cache(maxsize=4096)
def _kernel_cached(t_key: int, taps: int, sigma: float, band: float) -> Tuple[np.ndarray, int]:
    t = t_key / 2.0**20
    a = taps // 2
    j = np.arange(-a + 1, a + 1, dtype=np.float64)
    w = np.linspace(0.0, np.pi * band, 8 * taps + 1)
    target = np.exp(-0.5 * (sigma * w) ** 2) * np.exp(1j * w * t)
    E = np.exp(1j * np.outer(w, j))
    Ar = np.vstack([E.real, E.imag])
    br = np.concatenate([target.real, target.imag])
    h = np.linalg.lstsq(Ar, br, rcond=None)[0]
    h = h / h.sum()  # exact unit DC gain: z stays an intensity offset
    h = h.astype(np.float32)
    h.setflags(write=False)
    return h, a - 1


def fractional_shift_kernel(
    t: float, taps: int = 8, sigma: float = 0.8, band: float = 0.85
) -> Tuple[np.ndarray, int]:
    """FIR taps ``h_j`` (``j = -taps/2+1 .. taps/2``) and anchor for a delay ``t``.

    Least-squares design over ``|w| <= band*pi`` of ``sum_j h_j exp(i w j) ~=
    exp(-(sigma w)^2 / 2) exp(i w t)``: filtering a row with it (correlation,
    ``out[x] = sum_j h_j in[x + j]``) samples the Gaussian-prefiltered signal
    at ``x + t``. ``t`` in [0, 1) pixels (quantised to 2^-20 px), ``sigma`` in
    pixels. Returns (float32 taps, anchor index for cv2.sepFilter2D).
    """
    if not (0.0 <= t <= 1.0):
        raise ValueError("t must be in [0, 1]")
    return _kernel_cached(int(round(t * 2.0**20)), int(taps), float(sigma), float(band))


# ---------------------------------------------------------------------------
# coarse stage
# ---------------------------------------------------------------------------


def _fill_invalid(a: np.ndarray, valid: Optional[np.ndarray]) -> np.ndarray:
    if valid is None or valid.all():
        return a
    if not valid.any():
        return np.zeros_like(a)
    out = a.copy()
    out[~valid] = float(a[valid].mean())
    return out


def coarse_shift(
    reference: np.ndarray,
    moving: np.ndarray,
    max_size: int = 512,
) -> Tuple[Tuple[float, float], float, int]:
    """Phase-correlation shift (u, v) on a pyramid level <= ``max_size`` px.

    Both frames are block-averaged (INTER_AREA) by ``2^L`` so the larger side
    is at most ``max_size``, then ``cv2.phaseCorrelate`` with a Hanning
    window gives the shift at that level, scaled back by ``2^L``. Returns
    ((u, v) in full-resolution px, peak response in [0, 1], L).
    """
    h, w = reference.shape
    L = 0
    while max(h, w) / 2**L > max_size and min(h, w) / 2 ** (L + 1) >= 32:
        L += 1
    r, m = reference, moving
    if L:
        # crop to a multiple of 2^L first: INTER_AREA by an integer factor is a plain block mean (fast);
        # a fractional factor (odd sizes, e.g. a 1079-row crop) takes OpenCV's general path, 4x slower
        hc, wc = (h >> L) << L, (w >> L) << L
        size = (max(w >> L, 1), max(h >> L, 1))
        r = cv2.resize(reference[:hc, :wc], size, interpolation=cv2.INTER_AREA)
        m = cv2.resize(moving[:hc, :wc], size, interpolation=cv2.INTER_AREA)
    # a light blur keeps noise-dominated high frequencies out of the whitened spectrum
    r = cv2.GaussianBlur(r.astype(np.float64), (0, 0), 1.0)
    m = cv2.GaussianBlur(m.astype(np.float64), (0, 0), 1.0)
    win = cv2.createHanningWindow((r.shape[1], r.shape[0]), cv2.CV_64F)
    (dx, dy), resp = cv2.phaseCorrelate(r, m, win)
    return (dy * 2**L, dx * 2**L), float(resp), L


# ---------------------------------------------------------------------------
# the default estimator
# ---------------------------------------------------------------------------


_DEFAULT_SIGMA = 0.8  # prefilter (px) against aliasing when the pair is not noise-limited
_ADAPTIVE_SIGMAS = (
    0.7,
    0.6,
    0.5,
    0.4,
)  # candidates on noise-limited pairs (smallest predicted variance wins)
_NOISE_LIMITED_PX = 0.005  # standard error (px) above which a pair counts as noise-limited
_NOISY_PIXEL_FACTOR = 4  # a noise-limited pair gets this many times the max_pixels budget
_BLOCK = 16  # block size (px) of the sandwich covariance and the misfit grid
_TILE = 128  # tile size (px) when only the most textured max_pixels are used


def _block_sum(a: np.ndarray, bs: int) -> np.ndarray:
    """Sums over bs x bs blocks of a 2-D float32 array (the last row/column of blocks may be partial)."""
    h, w = a.shape
    ph, pw = -h % bs, -w % bs
    if ph or pw:  # a partial last block row/column: zero padding adds nothing to its sums
        a = cv2.copyMakeBorder(a, 0, ph, 0, pw, cv2.BORDER_CONSTANT, value=0)
        h, w = a.shape
    return cv2.resize(a, (w // bs, h // bs), interpolation=cv2.INTER_AREA).astype(np.float64) * (
        bs * bs
    )


def _block_counts(shape: Tuple[int, int], bs: int) -> np.ndarray:
    """Pixels per bs x bs block of an array of ``shape`` (as :func:`_block_sum` of ones)."""

    def ext(n: int) -> np.ndarray:
        e = np.full(-(-n // bs), float(bs))
        if n % bs:
            e[-1] = float(n % bs)
        return e

    return np.outer(ext(shape[0]), ext(shape[1]))


def _dilate_invalid(valid: Optional[np.ndarray], before: int, after: int) -> Optional[np.ndarray]:
    """Pixels x whose window x-before .. x+after (both axes) is entirely valid."""
    if valid is None:
        return None
    inv = (~valid).astype(np.uint8)
    n = before + after + 1
    return cv2.dilate(inv, np.ones((n, n), np.uint8), anchor=(before, before)) == 0


class _Level:
    """One pyramid level: frames, validity, and stacked tiles for Gauss-Newton.

    The working pixels are one rectangle (the whole overlap) or, above
    ``max_pixels``, the most textured ``_TILE``-sized tiles spread over a 3x3
    grid of the frame. Tiles are stacked vertically (each with its filter
    margin) so every filter and product is one OpenCV call.
    """

    def __init__(self, R, M, vr, vm, taps, sigma, band, max_pixels, score=None, kmax=2):
        self.R, self.M = R, M
        self.taps, self.sigma, self.band = taps, sigma, band
        self.h, self.w = R.shape
        self.a = a = taps // 2
        self.m = a + 1  # reference margin: filter (a) + gradient (1)
        self.max_pixels = max_pixels
        self.score = score  # callable (r0, r1, c0, c1) -> texture score, or None
        self.vr = _dilate_invalid(vr, a + 1, a + 1)
        self.vm = _dilate_invalid(vm, a - 1, a)
        self._ref_key = None
        self._rects_cache = {}
        self.kmax = int(kmax)  # the tile lattice stays valid for |k| <= kmax
        self.blocks = False  # True on the level whose final sums need 16x16 block statistics
        self._tiles = None

    # -- geometry ---------------------------------------------------------
    def rects(self, k0: int, k1: int, border: int):
        key = (k0, k1, border)
        if key not in self._rects_cache:
            self._rects_cache[key] = self._rects(k0, k1, border)
        return self._rects_cache[key]

    def _rects(self, k0: int, k1: int, border: int):
        a, bs = self.a, _BLOCK
        r0 = max(border, self.m, -k0 + a - 1)
        r1 = min(self.h - border, self.h - self.m, self.h - k0 - a)
        c0 = max(border, self.m, -k1 + a - 1)
        c1 = min(self.w - border, self.w - self.m, self.w - k1 - a)
        if r1 - r0 < bs or c1 - c0 < bs:
            return None
        # the whole overlap is used (the last block row/column may be partial)
        if self.max_pixels is None or (r1 - r0) * (c1 - c0) <= self.max_pixels:
            return ((r0, r1, c0, c1),)
        # tiles: chosen once on a lattice valid for |k| <= kmax, then the ones that
        # fit at this k are used (so the reference side is prepared once)
        if self._tiles is None:
            self._tiles = self._choose_tiles(border)
        ok = [
            t
            for t in self._tiles
            if t[0] + k0 - a + 1 >= 0
            and t[1] + k0 + a <= self.h
            and t[2] + k1 - a + 1 >= 0
            and t[3] + k1 + a <= self.w
        ]
        return tuple(ok) if ok else None

    def _choose_tiles(self, border: int):
        a, T = self.a, _TILE
        mg = max(border, self.m, self.kmax + a + 1)
        r0, r1, c0, c1 = mg, self.h - mg, mg, self.w - mg
        rows = np.arange(r0, r1 - T + 1, T)
        cols = np.arange(c0, c1 - T + 1, T)
        if rows.size == 0 or cols.size == 0:
            return []
        rows = rows + ((r1 - r0) - rows.size * T) // 2
        cols = cols + ((c1 - c0) - cols.size * T) // 2
        RR, CC = np.meshgrid(rows, cols, indexing="ij")
        RR, CC = RR.ravel(), CC.ravel()
        ntile = max(1, int(self.max_pixels // (T * T)))
        if ntile >= RR.size:
            return [(int(r), int(r) + T, int(c), int(c) + T) for r, c in zip(RR, CC)]
        sc = self.score(RR, RR + T, CC, CC + T) if self.score else np.zeros(RR.size)
        cell = np.minimum(((RR + T / 2) * 3 / self.h).astype(int), 2) * 3 + np.minimum(
            ((CC + T / 2) * 3 / self.w).astype(int), 2
        )
        per = int(math.ceil(ntile / 9))
        chosen = []
        for c in range(9):
            idx = np.flatnonzero(cell == c)
            chosen.extend(idx[np.argsort(-sc[idx])][:per].tolist())
        chosen = sorted(chosen, key=lambda i: -sc[i])[:ntile]
        return [(int(RR[i]), int(RR[i]) + T, int(CC[i]), int(CC[i]) + T) for i in sorted(chosen)]

    # -- reference side (fixed while the tile set is fixed) -----------------
    def prepare_reference(self, rects):
        if self._ref_key == rects:
            return
        self._ref_key = rects
        m = self.m
        h0, anc = fractional_shift_kernel(0.0, self.taps, self.sigma, self.band)
        wins = [self.R[r0 - m : r1 + m, c0 - m : c1 + m] for r0, r1, c0, c1 in rects]
        stack = wins[0] if len(wins) == 1 else np.concatenate(wins, axis=0)
        Rb = cv2.sepFilter2D(
            stack, cv2.CV_32F, h0, h0, anchor=(anc, anc), borderType=cv2.BORDER_REPLICATE
        )
        k = np.float32([-0.5, 0.0, 0.5])
        one = np.float32([1.0])
        g0 = cv2.sepFilter2D(Rb, cv2.CV_32F, one, k, borderType=cv2.BORDER_REPLICATE)
        g1 = cv2.sepFilter2D(Rb, cv2.CV_32F, k, one, borderType=cv2.BORDER_REPLICATE)
        self.Rb = self._interior(Rb, rects, m, m)
        self.g0 = self._interior(g0, rects, m, m)
        self.g1 = self._interior(g1, rects, m, m)
        if self.vr is not None:
            self.wr = self._interior_of(self.vr, rects)
        else:
            self.wr = None
        self._ref_sums = None

    @staticmethod
    def _interior(stack, rects, top, left):
        """Concatenate the interiors (rect shape) of stacked windows into one 2-D array."""
        if len(rects) == 1:
            r0, r1, c0, c1 = rects[0]
            return np.ascontiguousarray(stack[top : top + r1 - r0, left : left + c1 - c0])
        r0, r1, c0, c1 = rects[0]
        th, tw = r1 - r0, c1 - c0
        wh = stack.shape[0] // len(rects)
        s3 = stack.reshape(len(rects), wh, stack.shape[1])[:, top : top + th, left : left + tw]
        return np.ascontiguousarray(s3).reshape(len(rects) * th, tw)

    @staticmethod
    def _interior_of(full, rects, k0=0, k1=0):
        parts = [full[r0 + k0 : r1 + k0, c0 + k1 : c1 + k1] for r0, r1, c0, c1 in rects]
        return parts[0] if len(parts) == 1 else np.concatenate(parts, axis=0)

    # -- moving side ---------------------------------------------------------
    def sample_moving(self, rects, s):
        """``(H_t * M)(x + k)`` on the rects for ``s = k + t`` (stacked like the reference)."""
        k = np.floor(s).astype(int)
        t = s - k
        hr, anc = fractional_shift_kernel(float(t[0]), self.taps, self.sigma, self.band)
        hc, _ = fractional_shift_kernel(float(t[1]), self.taps, self.sigma, self.band)
        a = self.a
        k0, k1 = int(k[0]), int(k[1])
        wins = [
            self.M[r0 + k0 - a + 1 : r1 + k0 + a, c0 + k1 - a + 1 : c1 + k1 + a]
            for r0, r1, c0, c1 in rects
        ]
        stack = wins[0] if len(wins) == 1 else np.concatenate(wins, axis=0)
        out = cv2.sepFilter2D(
            stack, cv2.CV_32F, hc, hr, anchor=(anc, anc), borderType=cv2.BORDER_REPLICATE
        )
        return self._interior(out, rects, a - 1, a - 1)

    def weights(self, rects, s) -> Optional[np.ndarray]:
        k = np.floor(s).astype(int)
        w = self.wr
        if self.vm is not None:
            wm = self._interior_of(self.vm, rects, int(k[0]), int(k[1]))
            w = wm if w is None else (w & wm)
        return w

    @staticmethod
    def block_centres(rects):
        """Centres (rows, cols; level px) of the 16x16 blocks of ``rects``, in block order (rect by rect,
        row-major). The rects are one region or equal tiles (:meth:`rects`), so one block layout serves all."""
        r = np.asarray(rects, dtype=np.int64).reshape(-1, 4)
        th, tw = int(r[0, 1] - r[0, 0]), int(r[0, 3] - r[0, 2])
        if not (np.all(r[:, 1] - r[:, 0] == th) and np.all(r[:, 3] - r[:, 2] == tw)):
            raise ValueError("block_centres: rects of unequal size")
        ra = np.arange(0, th, _BLOCK)
        ca = np.arange(0, tw, _BLOCK)
        rc = (ra + np.minimum(ra + _BLOCK, th)) / 2.0  # centre of a possibly partial block
        cc = (ca + np.minimum(ca + _BLOCK, tw)) / 2.0
        shape = (len(r), ra.size, ca.size)
        rr = np.broadcast_to(r[:, 0, None, None] + rc[None, :, None], shape)
        cl = np.broadcast_to(r[:, 2, None, None] + cc[None, None, :], shape)
        return rr.reshape(-1), cl.reshape(-1)


def _gn_sums(lv: _Level, rects, s, want_blocks: bool):
    """Normal equations ``A d = b`` at shift ``s`` (optionally per 16x16 block).

    ``J = [g0, g1, 1]`` (prefiltered reference gradient, eq. of the module
    docstring), ``e = (H_t*M)(x+k) - (H_0*R)(x)``; ``A = sum w J^T J``,
    ``b = sum w J^T e``. Returns (A, b, sum w e^2, n, blocks) where blocks is
    a list of 10 block-sum arrays [g00, g01, g11, g0, g1, ge0, ge1, e, ee, n]
    (block order as :meth:`_Level.block_centres`) or None.
    """
    lv.prepare_reference(rects)
    Mw = lv.sample_moving(rects, s)
    e = cv2.subtract(Mw, lv.Rb)
    w = lv.weights(rects, s)
    g0, g1 = lv.g0, lv.g1
    if w is not None:
        wf = w.astype(np.float32)
        e = cv2.multiply(e, wf)
        g0 = cv2.multiply(g0, wf)
        g1 = cv2.multiply(g1, wf)
        ref_maps = [cv2.multiply(g0, g0), cv2.multiply(g0, g1), cv2.multiply(g1, g1), g0, g1, wf]
        ref_sums = None
    else:
        ref_sums = lv._ref_sums
        if ref_sums is None or (want_blocks and ref_sums[1] is None):
            maps = [cv2.multiply(g0, g0), cv2.multiply(g0, g1), cv2.multiply(g1, g1), g0, g1]
            if want_blocks or lv.blocks:  # a level that will need blocks computes them once
                bl = [_block_sum(mp, _BLOCK) for mp in maps]
                bl.append(_block_counts(g0.shape, _BLOCK))
                tot = [float(x.sum()) for x in bl]
            else:
                bl = None
                tot = [float(cv2.sumElems(mp)[0]) for mp in maps] + [float(g0.size)]
            ref_sums = (tot, bl)
            lv._ref_sums = ref_sums
        ref_maps = None
    ef = e.ravel()
    see = float(np.dot(ef, ef))
    blocks = None
    if want_blocks:
        ge0 = cv2.multiply(g0, e)
        ge1 = cv2.multiply(g1, e)
        rb = [_block_sum(mp, _BLOCK) for mp in ref_maps] if ref_maps is not None else ref_sums[1]
        eb = [_block_sum(mp, _BLOCK) for mp in (ge0, ge1, e)]
        blocks = rb[:5] + eb + [None, rb[5]]
        s00, s01, s11, s0, s1, cnt = (float(x.sum()) for x in rb)
        se0, se1, se = (float(x.sum()) for x in eb)
    else:
        if ref_maps is not None:
            s00, s01, s11, s0, s1, cnt = (float(cv2.sumElems(mp)[0]) for mp in ref_maps)
        else:
            s00, s01, s11, s0, s1, cnt = ref_sums[0]
        se0 = float(np.dot(np.ascontiguousarray(g0).ravel(), ef))
        se1 = float(np.dot(np.ascontiguousarray(g1).ravel(), ef))
        se = float(cv2.sumElems(e)[0])
    A = np.array([[s00, s01, s0], [s01, s11, s1], [s0, s1, cnt]])
    b = np.array([se0, se1, se])
    return A, b, see, int(round(cnt)), blocks


def _solve(A: np.ndarray, b: np.ndarray) -> Optional[np.ndarray]:
    try:
        d = np.linalg.solve(A, b)
    except np.linalg.LinAlgError:
        return None
    return d if np.all(np.isfinite(d)) else None


def _noise_variance(
    A: np.ndarray, b: np.ndarray, ee: float, n: int, taps: int, sigma: float, band: float, t
) -> Optional[float]:
    """Per-frame white-noise variance (DN^2) from the least-squares residual.

    ``var(e) = sig2 (|h_t|^2 |h_t|^2 + |h_0|^2 |h_0|^2)`` (separable 2-D norms
    of the moving-side and reference-side filters), with ``var(e)`` the residual
    energy after the solve over ``n - 3`` degrees of freedom. Model error
    (aliasing, misfit) counts as noise here. None if ``A`` is singular.
    """
    d = _solve(A, b)
    if d is None:
        return None
    h0, _ = fractional_shift_kernel(0.0, taps, sigma, band)
    htr, _ = fractional_shift_kernel(float(t[0]), taps, sigma, band)
    htc, _ = fractional_shift_kernel(float(t[1]), taps, sigma, band)
    n0 = float(np.dot(h0, h0))
    fit = max(ee - float(d @ b), 0.0) / max(n - 3, 1)
    return fit / (float(np.dot(htr, htr)) * float(np.dot(htc, htc)) + n0 * n0)


_SPECTRUM_SIZE = 256  # side (px) of the central crop whose spectrum chooses the prefilter


def predicted_shift_variance(
    ref: np.ndarray, mov: np.ndarray, noise_var: float, sigmas: Sequence[float]
) -> np.ndarray:
    """Predicted variance (px^2, u + v) of the Gaussian-prefiltered estimator, per ``sigma``.

    Frequency-domain model of the estimating equation ``sum g e = 0`` for a
    pair with white noise of variance ``noise_var`` (DN^2) in each frame: with
    weight ``W = |G_sigma(w)|^2``, gradient ``s_i = sin(w_i)`` (central
    difference) and signal power ``P`` (the Hann-windowed periodograms of the
    two frames averaged, less the noise ``nu = noise_var sum w^2``), the slope
    is ``S = sum W s w^T P`` and the score covariance ``B = 2 sum W^2 s s^T
    (P nu + nu^2 / 2)``; the ``nu^2`` term is the noise-times-noise part that
    keeps this estimator above ``2 sigma^2 J^-1``. Returns
    ``trace(S^-1 B S^-T)`` for each sigma (inf where S is singular). Only the
    central ``_SPECTRUM_SIZE`` px square of the frames is used.
    """
    h, w = ref.shape
    sh, sw = min(h, _SPECTRUM_SIZE), min(w, _SPECTRUM_SIZE)
    r0, c0 = (h - sh) // 2, (w - sw) // 2
    win = cv2.createHanningWindow((sw, sh), cv2.CV_64F)
    nc = sw // 2 + 1
    P = np.zeros((sh, nc))
    for a in (ref, mov):
        x = np.asarray(a[r0 : r0 + sh, c0 : c0 + sw], dtype=np.float64)
        f = np.fft.rfft2((x - x.mean()) * win)
        P += 0.5 * (f.real**2 + f.imag**2)
    nu = float(noise_var) * float(np.sum(win * win))
    P -= nu
    # half-plane spectrum: columns other than 0 (and Nyquist) stand for their mirror too
    mult = np.full(nc, 2.0)
    mult[0] = 1.0
    if sw % 2 == 0:
        mult[-1] = 1.0
    wy = np.broadcast_to(2.0 * np.pi * np.fft.fftfreq(sh)[:, None], P.shape)
    wx = np.broadcast_to(2.0 * np.pi * np.fft.rfftfreq(sw)[None, :], P.shape)
    sy, sx = np.sin(wy), np.sin(wx)
    Pm = P * mult
    nt = (P * nu + 0.5 * nu * nu) * mult
    fa = np.stack([sy * wy * Pm, sy * wx * Pm, sx * wy * Pm, sx * wx * Pm]).reshape(4, -1)
    fb = np.stack([sy * sy * nt, sy * sx * nt, sx * sx * nt]).reshape(3, -1)
    sg = np.asarray(sigmas, dtype=np.float64)[:, None]
    W = np.exp(-(sg**2) * (wy * wy + wx * wx).reshape(1, -1))
    Sa = W @ fa.T  # (K, 4): slope entries
    Bb = 2.0 * ((W * W) @ fb.T)  # (K, 3): score covariance entries
    out = []
    for k in range(sg.shape[0]):
        S = Sa[k].reshape(2, 2)
        B = np.array([[Bb[k, 0], Bb[k, 1]], [Bb[k, 1], Bb[k, 2]]])
        try:
            Si = np.linalg.inv(S)
        except np.linalg.LinAlgError:
            out.append(np.inf)
            continue
        v = float(np.trace(Si @ B @ Si.T))
        out.append(v if np.isfinite(v) and v >= 0 else np.inf)
    return np.array(out)


def _signal_matrix(
    A: np.ndarray, b: np.ndarray, ee: float, n: int, taps: int, sigma: float, band: float, t
) -> np.ndarray:
    """Normal matrix with the reference-noise energy removed from the gradient terms.

    The slope of the estimating equation ``sum g e = 0`` with respect to the
    shift is ``sum grad(R_signal) grad(M)^T``; ``A = sum g g^T`` also holds the
    energy of the reference noise in ``g``. With white noise of variance
    ``sig2`` per frame, ``var(e) = sig2 (|h_t|^2 |h_t|^2 + |h_0|^2 |h_0|^2)``
    (separable 2-D norms) and ``var(g_i) = sig2 |k * h_0|^2 |h_0|^2`` (k the
    central difference), so ``sig2`` follows from the least-squares residual
    and ``n sig2 |k*h_0|^2 |h_0|^2`` is taken off the diagonal (at most 80 %
    of it). Only used near the solution, where the residual is mostly noise.
    """
    sig2 = _noise_variance(A, b, ee, n, taps, sigma, band, t)
    if sig2 is None:
        return A
    h0, _ = fractional_shift_kernel(0.0, taps, sigma, band)
    n0 = float(np.dot(h0, h0))
    nk = float(np.sum(np.convolve(h0.astype(np.float64), [0.5, 0.0, -0.5]) ** 2))
    out = A.copy()
    for i in (0, 1):
        out[i, i] = max(A[i, i] - n * sig2 * nk * n0, 0.2 * A[i, i])
    return out


def _texture_check(A: np.ndarray, n: int) -> str:
    """Reason string if the gradient normal matrix is too weak / one-directional."""
    if n < 64:
        return f"too few valid pixels ({n})"
    G = A[:2, :2] / n
    ev = np.linalg.eigvalsh(G)
    if not np.all(np.isfinite(ev)) or ev[1] <= 1e-6:
        return "textureless input: no image gradient to measure a shift from"
    if ev[0] <= 1e-6 * ev[1] or ev[0] <= 1e-6:
        return f"texture in one direction only (aperture problem): gradient eigenvalues {ev[0]:.3g}, {ev[1]:.3g}"
    return ""


def _gauss_newton(lv: _Level, s0, max_iter: int, tol: float, border: int, blocks: bool = False):
    """Iterate from s0. Returns a dict: s (after the last step), s_eval and the
    sums (A, b, ee, n, blocks, d) of the last solve, rects, it, converged, last
    (size of the last step, px) and reason (non-empty on failure)."""
    s = np.array(s0, dtype=np.float64)
    last = float("inf")
    out = dict(s=s, rects=None, it=0, converged=False, last=last, reason="")
    prev = None
    for it in range(1, max_iter + 1):
        k = np.floor(s).astype(int)
        rects = lv.rects(int(k[0]), int(k[1]), border)
        out.update(it=it, rects=rects)
        if rects is None:
            out["reason"] = "frames do not overlap at the estimated shift"
            return out
        A, b, ee, n, bl = _gn_sums(lv, rects, s, blocks and it >= 2)
        if it == 1:
            why = _texture_check(A, n)
            if why:
                out["reason"] = why
                return out
        d = _solve(A, b)
        As = A
        if d is not None and np.max(np.abs(d[:2])) < 0.3:
            As = _signal_matrix(A, b, ee, n, lv.taps, lv.sigma, lv.band, s - np.floor(s))
            d = _solve(As, b)
        if d is None:
            out["reason"] = "singular normal equations"
            return out
        step = -d[:2]
        nrm = float(np.max(np.abs(step)))
        if nrm > 1.0:  # a linearised step beyond 1 px is not trusted in one go
            step = step / nrm
        if prev is not None and float(step @ prev) < 0 and nrm > 10 * tol:
            step = 0.5 * step  # oscillation (over-corrected slope in heavy noise): damp
        prev = step
        out.update(s_eval=s.copy(), A=A, As=As, b=b, ee=ee, n=n, blocks=bl, d=d)
        s = s + step
        last = nrm
        out.update(s=s, last=last)
        if nrm < tol:
            out["converged"] = True
            break
    if blocks and out.get("blocks") is None and "s_eval" in out:
        A, b, ee, n, bl = _gn_sums(lv, out["rects"], out["s_eval"], True)
        As = _signal_matrix(
            A, b, ee, n, lv.taps, lv.sigma, lv.band, out["s_eval"] - np.floor(out["s_eval"])
        )
        out.update(A=A, As=As, b=b, ee=ee, n=n, blocks=bl, d=_solve(As, b))
        if out["d"] is None:
            out["reason"] = "singular normal equations"
    return out


def _texture_scorer(img: np.ndarray, scale: float):
    """Gradient energy of regions (in level-L coordinates) read from a small pyramid level.

    Returns ``score(r0, r1, c0, c1)`` taking equal-length integer arrays and
    returning the summed squared Sobel gradient of each region (integral image).
    """
    f = img.astype(np.float32)
    gx = cv2.Sobel(f, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(f, cv2.CV_32F, 0, 1, ksize=3)
    en = cv2.add(cv2.multiply(gx, gx), cv2.multiply(gy, gy))
    S = cv2.integral(en, sdepth=cv2.CV_64F)
    H, W = en.shape

    def score(r0, r1, c0, c1):
        a0 = np.clip((np.asarray(r0) * scale).astype(int), 0, H - 1)
        a1 = np.clip(np.ceil(np.asarray(r1) * scale).astype(int), a0 + 1, H)
        b0 = np.clip((np.asarray(c0) * scale).astype(int), 0, W - 1)
        b1 = np.clip(np.ceil(np.asarray(c1) * scale).astype(int), b0 + 1, W)
        return S[a1, b1] - S[a0, b1] - S[a1, b0] + S[a0, b0]

    return score


def _pyr(a: np.ndarray) -> np.ndarray:
    """2x2 block means (the last odd row/column dropped: an integer factor keeps INTER_AREA on its fast path)."""
    h, w = a.shape[0] // 2, a.shape[1] // 2
    return cv2.resize(a[: 2 * h, : 2 * w], (w, h), interpolation=cv2.INTER_AREA)


def _pyr_mask(v: Optional[np.ndarray]) -> Optional[np.ndarray]:
    if v is None:
        return None
    return _pyr(v.astype(np.float32)) >= 0.999


def _default(
    R, M, vr, vm, prior, max_iterations, tol, taps, sigma, band, max_pixels, coarse_size, misfit_px
) -> ShiftResult:
    method = "default"
    adaptive = sigma is None
    if adaptive:
        sigma = _DEFAULT_SIGMA
    h, w = R.shape
    border = 2
    # pyramid: level L has 1/2^L the size; the coarsest is used for phase correlation
    Rp, Mp, VRp, VMp = [R], [M], [vr], [vm]
    while min(Rp[-1].shape) / 2 >= 64 and max(Rp[-1].shape) > coarse_size:
        Rp.append(_pyr(Rp[-1]))
        Mp.append(_pyr(Mp[-1]))
        VRp.append(_pyr_mask(VRp[-1]))
        VMp.append(_pyr_mask(VMp[-1]))
    levels = len(Rp) - 1
    coarse = None
    if prior is not None:
        s = np.asarray(prior, dtype=np.float64).reshape(2) / 2**levels
    else:
        (cu, cv), _, _ = coarse_shift(
            _fill_invalid(Rp[-1], VRp[-1]), _fill_invalid(Mp[-1], VMp[-1]), max_size=1 << 30
        )
        coarse = (cu * 2**levels, cv * 2**levels)
        s = np.array([cu, cv], dtype=np.float64)
    # Gauss-Newton on the small pyramid levels only (the big ones cost more than they save)
    small = 1 << 18
    for L in range(levels, 0, -1):
        if Rp[L].size > small and L < levels:
            s = s * 2.0
            continue
        sc = _texture_scorer(Rp[-1], 2.0 ** (L - levels)) if L < levels else None
        lv = _Level(
            Rp[L].astype(np.float32),
            Mp[L].astype(np.float32),
            VRp[L],
            VMp[L],
            taps,
            sigma,
            band,
            small,
            sc,
            kmax=int(np.max(np.abs(s))) + 3,
        )
        out = _gauss_newton(lv, s, 8, 0.01, border)
        if not out["reason"]:
            s = out["s"]
        s = s * 2.0
    score = _texture_scorer(Rp[-1], 2.0 ** (-levels)) if levels else None
    lv = _Level(R, M, vr, vm, taps, sigma, band, max_pixels, score, kmax=int(np.max(np.abs(s))) + 3)
    lv.blocks = True
    out = _gauss_newton(lv, s, max_iterations, tol, border, blocks=True)
    if (out["reason"] or (not out["converged"] and out["last"] > 0.05)) and np.max(np.abs(s)) > 0.5:
        # the coarse start was wrong (e.g. a noise peak in the phase correlation):
        # try the co-registered start (0, 0) and keep it if that converges
        out0 = _gauss_newton(lv, np.zeros(2), max_iterations, tol, border, blocks=True)
        if out0["converged"]:
            out = out0
    it = out["it"]
    if out["reason"]:
        return _fail(out["reason"], method, iterations=it, coarse=coarse)
    conv, last = out["converged"], out["last"]
    if not conv and last > 0.05:
        return _fail(
            f"Gauss-Newton did not converge (last step {last:.3g} px)",
            method,
            iterations=it,
            coarse=coarse,
        )
    res = _statistics(out, lv, h, w, misfit_px, coarse)
    if res.ok and adaptive and not res.misfit and max(res.u_std, res.v_std) > _NOISE_LIMITED_PX:
        # noise-limited pair: aliasing bias (< 0.003 px) no longer matters and the
        # prefilter is re-chosen for the smallest noise variance (module docstring, step 3)
        se = out["s_eval"]
        sig2 = _noise_variance(
            out["A"], out["b"], out["ee"], out["n"], taps, sigma, band, se - np.floor(se)
        )
        if sig2 is not None and sig2 > 0:
            cands = (sigma,) + tuple(x for x in _ADAPTIVE_SIGMAS if x != sigma)
            pv = predicted_shift_variance(_fill_invalid(R, vr), _fill_invalid(M, vm), sig2, cands)
            best = cands[int(np.argmin(pv))]
            # tiles only (a pixel budget): noise-limited precision grows with the pixel count
            tiled = out["rects"] is not None and len(out["rects"]) > 1
            mp_c = max_pixels * _NOISY_PIXEL_FACTOR if tiled else max_pixels
            if (best != sigma or tiled) and np.isfinite(pv.min()):
                s1 = np.array([res.u, res.v])
                lv_c = _Level(
                    R, M, vr, vm, taps, best, band, mp_c, score, kmax=int(np.max(np.abs(s1))) + 3
                )
                lv_c.blocks = True
                out_c = _gauss_newton(lv_c, s1, max_iterations, tol, border, blocks=True)
                if not out_c["reason"] and (out_c["converged"] or out_c["last"] <= 0.05):
                    res_c = _statistics(out_c, lv_c, h, w, misfit_px, coarse)
                    if res_c.ok and not res_c.misfit:
                        res_c.iterations += res.iterations
                        res = res_c
    return res


def _score_slope(
    lv: "_Level", rects, s: np.ndarray, A: np.ndarray, b: np.ndarray, delta: float = 1e-3
) -> Optional[np.ndarray]:
    """Slope of the estimating equation ``b(s) = sum J e(s)`` at ``s``: ``[db/du, db/dv, db/dz]``.

    ``db/dz = sum J`` (the third column of ``A``); ``db/du``, ``db/dv`` by a
    one-sided difference of ``delta`` px (away from the next integer, so the
    pixel set stays the same). This is the bread of the sandwich covariance:
    ``A = sum J J^T`` differs from it because the reference gradient is a
    central difference of a noisy frame (``sin(w)`` instead of ``w``, noise
    energy in ``g g^T``), by 10-25 % on noisy, lightly prefiltered pairs.
    """
    S = np.empty((3, 3))
    S[:, 2] = A[:, 2]
    for j in (0, 1):
        sp = np.array(s, dtype=np.float64)
        dj = delta if (sp[j] - math.floor(sp[j])) + delta < 1.0 else -delta
        sp[j] += dj
        bp = _gn_sums(lv, rects, sp, False)[1]
        S[:, j] = (bp - b) / dj
    return S if np.all(np.isfinite(S)) else None


_HAC_WEIGHT = 1.0  # weight of the neighbouring-block cross products in the score covariance


def _block_meat(Bg: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Covariance of the summed score from per-block scores ``Bg`` (rows, cols, 3).

    ``sum_k b_k b_k^T`` plus ``_HAC_WEIGHT`` times the cross products of
    8-neighbouring blocks within the same tile (``seg``: tile id per block row):
    a spatial HAC estimate. The neighbour terms matter because the filtered
    noise is correlated over a few pixels, so products across a block edge
    enter the two blocks with opposite signs (they telescope in the total);
    without them ``sum b_k b_k^T`` overstates the variance of low-pass
    filtered pairs. The result is symmetrised and, if not positive
    semi-definite, replaced by the plain sum.
    """
    flat = Bg.reshape(-1, 3)
    base = flat.T @ flat
    meat = base.copy()
    R, C, _ = Bg.shape
    for di, dj in ((0, 1), (1, 0), (1, 1), (1, -1)):
        if dj >= 0:
            a, b = Bg[: R - di, : C - dj], Bg[di:, dj:]
        else:
            a, b = Bg[: R - di, -dj:], Bg[di:, : C + dj]
        same = (seg[: R - di] == seg[di:])[:, None, None]
        x = (a * same).reshape(-1, 3)
        y = b.reshape(-1, 3)
        cross = x.T @ y
        meat += _HAC_WEIGHT * (cross + cross.T)
    meat = 0.5 * (meat + meat.T)
    if np.any(np.linalg.eigvalsh(meat[:2, :2]) <= 0):
        return base
    return meat


def _statistics(out: dict, lv: "_Level", h: int, w: int, misfit_px: float, coarse) -> ShiftResult:
    """Result, sandwich covariance and misfit test from a converged Gauss-Newton run."""
    method = "default"
    it, conv = out["it"], out["converged"]
    # statistics of the last solve (at s_eval); the result is s_eval - d
    A, b, ee, n, bl, d = out["A"], out["b"], out["ee"], out["n"], out["blocks"], out["d"]
    rects = out["rects"]
    s = out["s_eval"] - d[:2]
    z = float(d[2])
    cond = float(np.linalg.cond(A))
    see_final = max(ee - 2.0 * float(d @ b) + float(d @ A @ d), 0.0)
    resid_rms = math.sqrt(see_final / max(n - 3, 1))
    # bread of the sandwich: the measured slope of the estimating equation
    Ainv = None
    Sd = _score_slope(lv, rects, out["s_eval"], A, b)
    if Sd is not None:
        try:
            Ainv = np.linalg.inv(Sd)
        except np.linalg.LinAlgError:
            Ainv = None
    if Ainv is None:
        try:
            Ainv = np.linalg.inv(out["As"])
        except np.linalg.LinAlgError:
            Ainv = np.linalg.inv(A)
    g00, g01, g11, g0, g1, ge0, ge1, e, _, cnt = (None if x is None else x.ravel() for x in bl)
    # block scores of the residual after the final step: b_k = sum_k J^T (e - J d)
    r0 = ge0 - (g00 * d[0] + g01 * d[1] + g0 * d[2])
    r1 = ge1 - (g01 * d[0] + g11 * d[1] + g1 * d[2])
    r2 = e - (g0 * d[0] + g1 * d[1] + cnt * d[2])
    Bk = np.stack([r0, r1, r2], 1)
    nb = Bk.shape[0]
    grid = bl[0].shape
    seg = np.repeat(np.arange(len(rects)), [-(-(r1_ - r0_) // _BLOCK) for r0_, r1_, _, _ in rects])
    meat = _block_meat(Bk.reshape(grid[0], grid[1], 3), seg)
    cov3 = Ainv @ meat @ Ainv.T * (nb / max(nb - 3, 1))
    cov = cov3[:2, :2].copy()
    # misfit: local shifts on a 3x3 grid of the frame
    RR, CC = lv.block_centres(rects)
    gi = np.minimum((RR * 3 / h).astype(int), 2) * 3 + np.minimum((CC * 3 / w).astype(int), 2)

    # per grid cell (all 9 at once): block counts, score sums and normal-equation sums
    def per_cell(x: np.ndarray) -> np.ndarray:
        return np.bincount(gi, weights=x, minlength=9)

    nblk = np.bincount(gi, minlength=9)
    bsum = np.stack([per_cell(Bk[:, j]) for j in range(3)], 1)
    used = nblk[gi] >= 2  # blocks of the cells with at least 2 blocks
    dev_b = (Bk - bsum[gi] / np.maximum(nblk[gi], 1)[:, None])[used]
    within = dev_b.T @ dev_b
    nwb = int(used.sum())
    ncell = int(np.count_nonzero(nblk >= 2))
    s00, s01, s11, s0_, s1_, cn = (per_cell(x) for x in (g00, g01, g11, g0, g1, cnt))
    Ak = np.stack(
        [
            np.stack([s00, s01, s0_], -1),
            np.stack([s01, s11, s1_], -1),
            np.stack([s0_, s1_, cn], -1),
        ],
        1,
    )
    cells = np.flatnonzero(nblk >= 4)
    if cells.size:
        ck = np.linalg.cond(Ak[cells])
        cells = cells[np.isfinite(ck) & (ck <= 1e10)]
    dks = (
        np.linalg.solve(Ak[cells], bsum[cells][:, :, None])[:, :, 0]
        if cells.size
        else np.zeros((0, 3))
    )
    local = [(-dk[:2], n / max(float(cn[c]), 1.0)) for c, dk in zip(cells, dks)]
    # noise-only covariance: the sandwich over the block scores demeaned within each
    # grid cell (a misfit shifts whole cells and would otherwise count as noise)
    cov_noise = (Ainv @ within @ Ainv.T)[:2, :2] * (nwb / max(nwb - ncell - 3, 1))
    misfit = False
    mis_px = None
    warning = ""
    if len(local) >= 3:
        ds = np.array([x[0] for x in local])
        dev = ds - ds.mean(0)
        mis_px = float(np.sqrt(np.mean(np.sum(dev**2, 1))))
        # significance against the global covariance scaled to each cell's share of pixels
        chi2 = 0.0
        cinv = np.linalg.pinv(cov_noise)
        for (dk, scale), dv in zip(local, dev):
            chi2 += float(dv @ cinv @ dv) / scale
        dof_m = 2 * (len(local) - 1)
        significant = chi2 > dof_m + 5.0 * math.sqrt(2.0 * dof_m)
        if mis_px > misfit_px and significant:
            misfit = True
            warning = (
                f"residual misfit: local shifts across the frame differ by {mis_px:.3g} px RMS "
                "(rotation, scale or parallax); a pure translation does not describe this pair"
            )
            # no confident answer: the spread of the local shifts is the honest error
            cov = cov + np.cov(ds.T, bias=True)
    u_std = math.sqrt(max(cov[0, 0], 0.0))
    v_std = math.sqrt(max(cov[1, 1], 0.0))
    if max(u_std, v_std) > 0.5:
        return _fail(
            f"shift undetermined: standard error {max(u_std, v_std):.3g} px (too little texture for the noise)",
            method,
            n_pixels=n,
            iterations=it,
            cond=cond,
            coarse=coarse,
        )
    return ShiftResult(
        ok=True,
        u=float(s[0]),
        v=float(s[1]),
        z=z,
        cov=cov,
        u_std=u_std,
        v_std=v_std,
        cond=cond,
        n_pixels=int(n),
        iterations=int(it),
        converged=bool(conv),
        residual_rms=resid_rms,
        misfit=misfit,
        misfit_px=mis_px,
        warning=warning,
        method=method,
        coarse=coarse,
    )


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
    """Shift ``(u, v)`` of the scene content from ``reference`` to ``moving``.

    A feature at (r, c) in ``reference`` appears at (r + u, c + v) in
    ``moving`` (pixels; rows, columns). Both are 2-D arrays of equal shape and
    any integer or float dtype (use :func:`subpix_ros.core.luminance.luminance`
    for colour).

    ``mask``: bool array (True = valid in both frames) or a pair
    ``(reference_mask, moving_mask)``; NaN/inf pixels and integer pixels at
    the dtype's maximum (saturated) are invalid too. Invalid pixels, and every
    pixel whose filter support touches one, are left out of all sums.

    ``method``: ``"default"`` (coarse phase correlation + designed-filter
    Gauss-Newton, module docstring), ``"seed"`` (the paper's single solve,
    METHODS.md A; ignores mask and prior) or ``"seed-iterated"``.
    ``prior``: starting (u, v) guess, replaces the coarse stage.
    ``tol``: convergence threshold on the Gauss-Newton step (px).
    ``taps``, ``prefilter_sigma`` (px), ``band`` (fraction of Nyquist): the
    designed filter; ``prefilter_sigma=None`` (default) is 0.8 px, re-chosen
    for noise-limited pairs from the noise estimated in the data (module
    docstring, step 3); a number fixes it. ``max_pixels``: above this many
    pixels only the most textured 128x128 tiles (up to that total; 4x that on
    noise-limited pairs) enter the fine stage (None: all).
    ``misfit_px``: RMS spread of 3x3-grid local shifts above which (and
    statistically significant) the result is flagged ``misfit``.

    Returns a :class:`ShiftResult`; ``ok=False`` with ``u = v = z = None`` and
    a reason for textureless, constant, all-invalid, too small or
    non-overlapping input.
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {METHODS}")
    R, vr = _as_working(reference, "reference")
    M, vm = _as_working(moving, "moving")
    if R.shape != M.shape:
        raise ValueError(f"reference {R.shape} and moving {M.shape} must have the same shape")
    if taps < 4 or taps % 2:
        raise ValueError("taps must be an even number >= 4")
    mr, mm = _masks(mask, R.shape)
    if mr is not None and not mr.all():
        vr = mr if vr is None else (vr & mr)
    if mm is not None and not mm.all():
        vm = mm if vm is None else (vm & mm)
    if method == "default":
        # one mask for both frames (the usual aligned pair) is looked at once
        box = common_valid_box([m for m in ((vr,) if vr is vm else (vr, vm)) if m is not None])
        if (
            box is not None
        ):  # validity is a rectangle (an integer-crop alignment): crop to it, no mask needed
            r0, r1, c0, c1 = box
            R, M = R[r0:r1, c0:c1], M[r0:r1, c0:c1]
            vr = vm = None
    min_side = 8 if method == "seed" else 2 * (taps // 2 + 2) + 2 * _BLOCK
    if min(R.shape) < min_side:
        return _fail(
            f"input too small: {R.shape[0]}x{R.shape[1]} px, need at least {min_side} px per side",
            method,
        )
    if (vr is not None and not vr.any()) or (vm is not None and not vm.any()):
        return _fail("no valid pixels (all NaN, masked or saturated)", method)
    if prior is not None:
        pr = np.asarray(prior, dtype=np.float64).reshape(-1)
        if pr.size != 2 or not np.all(np.isfinite(pr)):
            raise ValueError("prior must be a finite (u, v) pair")
    if _is_constant(R, vr) or _is_constant(M, vm):
        return _fail("textureless input: constant frame", method)
    if method in ("seed", "seed-iterated"):
        # the published method has no mask: saturated pixels enter as they are,
        # but NaN/inf or a user mask cannot be honoured
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
    return _default(
        R,
        M,
        vr,
        vm,
        prior,
        int(max_iterations),
        float(tol),
        int(taps),
        None if prefilter_sigma is None else float(prefilter_sigma),
        float(band),
        max_pixels,
        int(coarse_size),
        float(misfit_px),
    )
