"""Standard errors and misfit test of the Gauss-Newton shift: a cluster-robust sandwich.

The covariance of ``(u, v, z)`` is ``S^-1 M S^-T`` over 16x16-pixel blocks of the final
residual scores ``b_k = sum_block J^T (e - J d)``: ``M = sum_k b_k b_k^T`` plus the cross
products of neighbouring blocks (a spatial HAC estimate [1]_, for the noise the filters
correlate across block edges), valid for correlated noise and model error; ``S`` is the
measured slope of the estimating equation (:func:`_score_slope`).

Local shifts over a 3x3 grid of the frame measure residual misfit (rotation, scale,
parallax): ``misfit`` is set when their RMS spread exceeds ``misfit_px`` and is significant
(chi-square) against the noise covariance from block scores demeaned within each grid cell;
a flagged result carries the spread in its covariance.

References
----------
.. [1] T. G. Conley, "GMM estimation with cross sectional dependence", Journal of
   Econometrics 92(1), 1-45, 1999. https://doi.org/10.1016/S0304-4076(98)00084-0
"""

from __future__ import annotations

import math
from typing import Optional

import numpy as np

from .gauss_newton import _GaussNewtonRun, _gn_sums
from .level import _BLOCK, _Level
from .result import ShiftResult, _fail

_HAC_WEIGHT = 1.0  # weight of the neighbouring-block cross products in the score covariance


def _score_slope(
    lv: _Level, rects, s: np.ndarray, A: np.ndarray, b: np.ndarray, delta: float = 1e-3
) -> Optional[np.ndarray]:
    """Measure the slope ``[db/du, db/dv, db/dz]`` of the estimating equation at ``s``.

    Parameters
    ----------
    lv : _Level
        The level of the run.
    rects : tuple
        Its working rectangles.
    s : ndarray, shape (2,)
        Where the sums were built.
    A, b : ndarray
        The normal equations there (``b(s) = sum J e(s)``).
    delta : float
        Finite-difference step (px).

    Returns
    -------
    ndarray, shape (3, 3) or None
        None if not finite.

    Notes
    -----
    ``db/dz = sum J`` (the third column of ``A``); ``db/du``, ``db/dv`` by a one-sided
    difference of ``delta`` px (away from the next integer, so the pixel set stays the same).
    This is the bread of the sandwich covariance: ``A = sum J J^T`` differs from it because
    the reference gradient is a central difference of a noisy frame (``sin(w)`` instead of
    ``w``, noise energy in ``g g^T``).
    """
    slope = np.empty((3, 3))
    slope[:, 2] = A[:, 2]
    for j in (0, 1):
        moved = np.array(s, dtype=np.float64)
        dj = delta if (moved[j] - math.floor(moved[j])) + delta < 1.0 else -delta
        moved[j] += dj
        b_moved = _gn_sums(lv, rects, moved, False)[1]
        slope[:, j] = (b_moved - b) / dj
    return slope if np.all(np.isfinite(slope)) else None


def _block_meat(block_scores: np.ndarray, seg: np.ndarray) -> np.ndarray:
    """Return the covariance of the summed score from per-block scores (rows, cols, 3).

    ``sum_k b_k b_k^T`` plus ``_HAC_WEIGHT`` times the cross products of 8-neighbouring blocks
    within the same tile (``seg``: tile id per block row): a spatial HAC estimate. The
    neighbour terms matter because the filtered noise is correlated over a few pixels, so
    products across a block edge enter the two blocks with opposite signs (they telescope in
    the total). The result is symmetrised and, if not positive semi-definite, replaced by the
    plain sum.
    """
    flat = block_scores.reshape(-1, 3)
    base = flat.T @ flat
    meat = base.copy()
    rows, cols, _ = block_scores.shape
    for di, dj in ((0, 1), (1, 0), (1, 1), (1, -1)):
        if dj >= 0:
            first, second = block_scores[: rows - di, : cols - dj], block_scores[di:, dj:]
        else:
            first, second = block_scores[: rows - di, -dj:], block_scores[di:, : cols + dj]
        same = (seg[: rows - di] == seg[di:])[:, None, None]
        x = (first * same).reshape(-1, 3)
        y = second.reshape(-1, 3)
        cross = x.T @ y
        meat += _HAC_WEIGHT * (cross + cross.T)
    meat = 0.5 * (meat + meat.T)
    if np.any(np.linalg.eigvalsh(meat[:2, :2]) <= 0):
        return base
    return meat


def _slope_inverse(lv: _Level, run: _GaussNewtonRun) -> np.ndarray:
    """Invert the bread of the sandwich: the measured slope, else ``As``, else ``A``."""
    inverse = None
    slope = _score_slope(lv, run.rects, run.s_eval, run.A, run.b)
    if slope is not None:
        try:
            inverse = np.linalg.inv(slope)
        except np.linalg.LinAlgError:
            inverse = None
    if inverse is None:
        try:
            inverse = np.linalg.inv(run.As)
        except np.linalg.LinAlgError:
            inverse = np.linalg.inv(run.A)
    return inverse


def _residual_block_scores(run: _GaussNewtonRun):
    """Return the flattened block sums and the block scores ``b_k = sum J^T (e - J d)``."""
    g00, g01, g11, g0, g1, ge0, ge1, e, _, cnt = (
        None if x is None else x.ravel() for x in run.blocks
    )
    d = run.d
    r0 = ge0 - (g00 * d[0] + g01 * d[1] + g0 * d[2])
    r1 = ge1 - (g01 * d[0] + g11 * d[1] + g1 * d[2])
    r2 = e - (g0 * d[0] + g1 * d[1] + cnt * d[2])
    return (g00, g01, g11, g0, g1, cnt), np.stack([r0, r1, r2], 1)


def _local_shifts(lv, run, sums, scores, slope_inv, h: int, w: int):
    """Solve for the shift in each cell of a 3x3 grid of the frame (cells with >= 4 blocks).

    Returns
    -------
    local : list of (ndarray, float)
        Each cell's shift change and its share of the pixels (inverse).
    cov_noise : ndarray, shape (2, 2)
        Noise-only covariance: the sandwich over the block scores demeaned within each cell
        (a misfit shifts whole cells and would otherwise count as noise).
    """
    g00, g01, g11, g0, g1, cnt = sums
    block_rows, block_cols = lv.block_centres(run.rects)
    cell_of = np.minimum((block_rows * 3 / h).astype(int), 2) * 3 + np.minimum(
        (block_cols * 3 / w).astype(int), 2
    )

    def per_cell(x: np.ndarray) -> np.ndarray:
        return np.bincount(cell_of, weights=x, minlength=9)

    n_blocks = np.bincount(cell_of, minlength=9)
    score_sum = np.stack([per_cell(scores[:, j]) for j in range(3)], 1)
    used = n_blocks[cell_of] >= 2  # blocks of the cells with at least 2 blocks
    dev_b = (scores - score_sum[cell_of] / np.maximum(n_blocks[cell_of], 1)[:, None])[used]
    within = dev_b.T @ dev_b
    n_used = int(used.sum())
    n_cells = int(np.count_nonzero(n_blocks >= 2))
    s00, s01, s11, s0_, s1_, cn = (per_cell(x) for x in (g00, g01, g11, g0, g1, cnt))
    cell_normal = np.stack(
        [
            np.stack([s00, s01, s0_], -1),
            np.stack([s01, s11, s1_], -1),
            np.stack([s0_, s1_, cn], -1),
        ],
        1,
    )
    cells = np.flatnonzero(n_blocks >= 4)
    if cells.size:
        ck = np.linalg.cond(cell_normal[cells])
        cells = cells[np.isfinite(ck) & (ck <= 1e10)]
    steps = (
        np.linalg.solve(cell_normal[cells], score_sum[cells][:, :, None])[:, :, 0]
        if cells.size
        else np.zeros((0, 3))
    )
    local = [(-dk[:2], run.n / max(float(cn[c]), 1.0)) for c, dk in zip(cells, steps)]
    cov_noise = (slope_inv @ within @ slope_inv.T)[:2, :2] * (n_used / max(n_used - n_cells - 3, 1))
    return local, cov_noise


def _misfit_test(local, cov_noise: np.ndarray, misfit_px: float):
    """Test the spread of the local shifts; return (misfit, spread px or None, warning, cov+).

    The spread is significant when its chi-square against ``cov_noise`` (scaled to each cell's
    share of the pixels) exceeds ``dof + 5 sqrt(2 dof)``; ``cov+`` is the spread's covariance
    to add to a flagged result (None when not flagged).
    """
    if len(local) < 3:
        return False, None, "", None
    ds = np.array([x[0] for x in local])
    dev = ds - ds.mean(0)
    spread = float(np.sqrt(np.mean(np.sum(dev**2, 1))))
    chi2 = 0.0
    cinv = np.linalg.pinv(cov_noise)
    for (_, scale), dv in zip(local, dev):
        chi2 += float(dv @ cinv @ dv) / scale
    dof = 2 * (len(local) - 1)
    significant = chi2 > dof + 5.0 * math.sqrt(2.0 * dof)
    if spread > misfit_px and significant:
        warning = (
            f"residual misfit: local shifts across the frame differ by {spread:.3g} px RMS "
            "(rotation, scale or parallax); a pure translation does not describe this pair"
        )
        # no confident answer: the spread of the local shifts is the honest error
        return True, spread, warning, np.cov(ds.T, bias=True)
    return False, spread, "", None


def _statistics(
    run: _GaussNewtonRun, lv: _Level, h: int, w: int, misfit_px: float, coarse
) -> ShiftResult:
    """Return the result, sandwich covariance and misfit test of a converged run.

    ``h``, ``w``: the frame's shape (for the 3x3 grid); ``coarse``: the coarse-stage shift,
    passed on to the result.
    """
    method = "default"
    A, b, n, d = run.A, run.b, run.n, run.d
    s = run.s_eval - d[:2]
    z = float(d[2])
    cond = float(np.linalg.cond(A))
    sse_final = max(run.sse - 2.0 * float(d @ b) + float(d @ A @ d), 0.0)
    resid_rms = math.sqrt(sse_final / max(n - 3, 1))
    slope_inv = _slope_inverse(lv, run)
    sums, scores = _residual_block_scores(run)
    n_blocks = scores.shape[0]
    grid = run.blocks[0].shape
    seg = np.repeat(
        np.arange(len(run.rects)), [-(-(r1 - r0) // _BLOCK) for r0, r1, _, _ in run.rects]
    )
    meat = _block_meat(scores.reshape(grid[0], grid[1], 3), seg)
    cov3 = slope_inv @ meat @ slope_inv.T * (n_blocks / max(n_blocks - 3, 1))
    cov = cov3[:2, :2].copy()
    local, cov_noise = _local_shifts(lv, run, sums, scores, slope_inv, h, w)
    misfit, spread, warning, spread_cov = _misfit_test(local, cov_noise, misfit_px)
    if spread_cov is not None:
        cov = cov + spread_cov
    u_std = math.sqrt(max(cov[0, 0], 0.0))
    v_std = math.sqrt(max(cov[1, 1], 0.0))
    if max(u_std, v_std) > 0.5:
        return _fail(
            f"shift undetermined: standard error {max(u_std, v_std):.3g} px "
            "(too little texture for the noise)",
            method,
            n_pixels=n,
            iterations=run.it,
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
        iterations=int(run.it),
        converged=bool(run.converged),
        residual_rms=resid_rms,
        misfit=misfit,
        misfit_px=spread,
        warning=warning,
        method=method,
        coarse=coarse,
    )
