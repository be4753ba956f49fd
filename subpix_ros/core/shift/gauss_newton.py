"""The iterative Gauss-Newton stage on ``(u, v, z)`` with the reference-side Jacobian.

Minimises ``sum w ((H_t * M)(x + k) - (H_0 * R)(x) - z)^2`` where ``k = floor(s)``,
``t = s - k`` and ``H_t`` the designed prefilter + fractional delay of
:func:`.fractional_shift_kernel` (inverse compositional: the Jacobian ``J = [g0, g1, 1]`` is the
prefiltered reference's central-difference gradient, fixed while the tiles are).

References
----------
.. [1] S. Baker and I. Matthews, "Lucas-Kanade 20 years on: a unifying framework",
   International Journal of Computer Vision 56(3), 221-255, 2004.
   https://doi.org/10.1023/B:VISI.0000011205.11775.fd
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import cv2
import numpy as np

from .level import _BLOCK, _block_counts, _block_sum, _Level
from .noise import _signal_matrix, _solve


def _gn_sums(lv: _Level, rects, s, want_blocks: bool):
    """Build the normal equations ``A d = b`` at shift ``s`` (optionally per 16x16 block).

    Parameters
    ----------
    lv : _Level
        The level (frames, validity, filters).
    rects : tuple
        Working rectangles (:meth:`_Level.rects`).
    s : ndarray, shape (2,)
        Current shift (rows, columns; level px).
    want_blocks : bool
        Also return the per-block sums.

    Returns
    -------
    A : ndarray, shape (3, 3)
        ``sum w J^T J`` with ``J = [g0, g1, 1]``.
    b : ndarray, shape (3,)
        ``sum w J^T e`` with ``e = (H_t * M)(x + k) - (H_0 * R)(x)``.
    sse : float
        ``sum w e^2``.
    n : int
        Pixels in the sums.
    blocks : list of ndarray or None
        Ten block-sum arrays ``[g00, g01, g11, g0, g1, ge0, ge1, e, ee, n]`` (``ee`` is None;
        block order as :meth:`_Level.block_centres`).
    """
    lv.prepare_reference(rects)
    err = cv2.subtract(lv.sample_moving(rects, s), lv.ref_filtered)
    weight = lv.weights(rects, s)
    g0, g1 = lv.g0, lv.g1
    if weight is not None:
        wf = weight.astype(np.float32)
        err = cv2.multiply(err, wf)
        g0 = cv2.multiply(g0, wf)
        g1 = cv2.multiply(g1, wf)
        ref_maps = [cv2.multiply(g0, g0), cv2.multiply(g0, g1), cv2.multiply(g1, g1), g0, g1, wf]
        ref_sums = None
    else:
        ref_sums = _reference_sums(lv, want_blocks)
        ref_maps = None
    err_flat = err.ravel()
    sse = float(np.dot(err_flat, err_flat))
    blocks = None
    if want_blocks:
        ge0 = cv2.multiply(g0, err)
        ge1 = cv2.multiply(g1, err)
        ref_blocks = (
            [_block_sum(mp, _BLOCK) for mp in ref_maps] if ref_maps is not None else ref_sums[1]
        )
        err_blocks = [_block_sum(mp, _BLOCK) for mp in (ge0, ge1, err)]
        blocks = ref_blocks[:5] + err_blocks + [None, ref_blocks[5]]
        s00, s01, s11, s0, s1, cnt = (float(x.sum()) for x in ref_blocks)
        se0, se1, se = (float(x.sum()) for x in err_blocks)
    else:
        if ref_maps is not None:
            s00, s01, s11, s0, s1, cnt = (float(cv2.sumElems(mp)[0]) for mp in ref_maps)
        else:
            s00, s01, s11, s0, s1, cnt = ref_sums[0]
        se0 = float(np.dot(np.ascontiguousarray(g0).ravel(), err_flat))
        se1 = float(np.dot(np.ascontiguousarray(g1).ravel(), err_flat))
        se = float(cv2.sumElems(err)[0])
    A = np.array([[s00, s01, s0], [s01, s11, s1], [s0, s1, cnt]])
    b = np.array([se0, se1, se])
    return A, b, sse, int(round(cnt)), blocks


def _reference_sums(lv: _Level, want_blocks: bool):
    """Return the reference-only sums (totals, blocks or None) of an unweighted level, cached."""
    ref_sums = lv._ref_sums
    if ref_sums is None or (want_blocks and ref_sums[1] is None):
        g0, g1 = lv.g0, lv.g1
        maps = [cv2.multiply(g0, g0), cv2.multiply(g0, g1), cv2.multiply(g1, g1), g0, g1]
        if want_blocks or lv.blocks:  # a level that will need blocks computes them once
            blocks = [_block_sum(mp, _BLOCK) for mp in maps]
            blocks.append(_block_counts(g0.shape, _BLOCK))
            totals = [float(x.sum()) for x in blocks]
        else:
            blocks = None
            totals = [float(cv2.sumElems(mp)[0]) for mp in maps] + [float(g0.size)]
        ref_sums = (totals, blocks)
        lv._ref_sums = ref_sums
    return ref_sums


def _texture_check(normal: np.ndarray, n: int) -> str:
    """Return why the gradient normal matrix is too weak or one-directional ('' if fine)."""
    if n < 64:
        return f"too few valid pixels ({n})"
    gram = normal[:2, :2] / n
    ev = np.linalg.eigvalsh(gram)
    if not np.all(np.isfinite(ev)) or ev[1] <= 1e-6:
        return "textureless input: no image gradient to measure a shift from"
    if ev[0] <= 1e-6 * ev[1] or ev[0] <= 1e-6:
        return (
            "texture in one direction only (aperture problem): "
            f"gradient eigenvalues {ev[0]:.3g}, {ev[1]:.3g}"
        )
    return ""


@dataclass
class _GaussNewtonRun:
    """State of a Gauss-Newton run (:func:`_gauss_newton`).

    ``s`` is the shift after the last step; ``s_eval`` the shift where the last normal
    equations (``A``, ``As`` with the noise removed, ``b``, ``sse``, ``n``, ``blocks``) were
    built and ``d`` their solution, so the answer is ``s_eval - d[:2]``. ``last`` is the size
    of the last step (px); ``reason`` non-empty on failure.
    """

    s: np.ndarray
    rects: Optional[tuple] = None
    it: int = 0
    converged: bool = False
    last: float = float("inf")
    reason: str = ""
    s_eval: Optional[np.ndarray] = None
    A: Optional[np.ndarray] = None
    As: Optional[np.ndarray] = None
    b: Optional[np.ndarray] = None
    sse: float = 0.0
    n: int = 0
    blocks: Optional[list] = field(default=None, repr=False)
    d: Optional[np.ndarray] = None


def _gauss_newton(
    lv: _Level, s0, max_iter: int, tol: float, border: int, blocks: bool = False
) -> _GaussNewtonRun:
    """Iterate Gauss-Newton from ``s0`` on level ``lv``.

    Parameters
    ----------
    lv : _Level
        The level.
    s0 : array_like, shape (2,)
        Start (rows, columns; level px).
    max_iter : int
        Most solves.
    tol : float
        Convergence threshold on the step (px).
    border : int
        Pixels kept clear of the frame edges.
    blocks : bool
        The last solve keeps its 16x16 block sums (for the covariance).

    Returns
    -------
    _GaussNewtonRun

    Notes
    -----
    The step uses the slope with the reference-noise energy removed (:func:`_signal_matrix`)
    once it is below 0.3 px, is capped at 1 px and halved when it oscillates.
    """
    s = np.array(s0, dtype=np.float64)
    run = _GaussNewtonRun(s=s)
    prev = None
    for it in range(1, max_iter + 1):
        k = np.floor(s).astype(int)
        rects = lv.rects(int(k[0]), int(k[1]), border)
        run.it, run.rects = it, rects
        if rects is None:
            run.reason = "frames do not overlap at the estimated shift"
            return run
        A, b, sse, n, bl = _gn_sums(lv, rects, s, blocks and it >= 2)
        if it == 1:
            why = _texture_check(A, n)
            if why:
                run.reason = why
                return run
        d = _solve(A, b)
        As = A
        if d is not None and np.max(np.abs(d[:2])) < 0.3:
            As = _signal_matrix(A, b, sse, n, lv.taps, lv.sigma, lv.band, s - np.floor(s))
            d = _solve(As, b)
        if d is None:
            run.reason = "singular normal equations"
            return run
        step = -d[:2]
        size = float(np.max(np.abs(step)))
        if size > 1.0:  # a linearised step beyond 1 px is not trusted in one go
            step = step / size
        if prev is not None and float(step @ prev) < 0 and size > 10 * tol:
            step = 0.5 * step  # oscillation (over-corrected slope in heavy noise): damp
        prev = step
        run.s_eval, run.A, run.As, run.b, run.sse, run.n, run.blocks, run.d = (
            s.copy(),
            A,
            As,
            b,
            sse,
            n,
            bl,
            d,
        )
        s = s + step
        run.s, run.last = s, size
        if size < tol:
            run.converged = True
            break
    if blocks and run.blocks is None and run.s_eval is not None:
        _final_block_sums(lv, run)
    return run


def _final_block_sums(lv: _Level, run: _GaussNewtonRun) -> None:
    """Rebuild the last solve's sums with 16x16 blocks (a run that stopped at its first solve)."""
    A, b, sse, n, bl = _gn_sums(lv, run.rects, run.s_eval, True)
    As = _signal_matrix(A, b, sse, n, lv.taps, lv.sigma, lv.band, run.s_eval - np.floor(run.s_eval))
    run.A, run.As, run.b, run.sse, run.n, run.blocks, run.d = A, As, b, sse, n, bl, _solve(As, b)
    if run.d is None:
        run.reason = "singular normal equations"
