"""Noise seen through the designed filters: variance from the residual, signal-only slope."""

from __future__ import annotations

from typing import Optional

import numpy as np

from .prefilter import fractional_shift_kernel


def _solve(normal: np.ndarray, rhs: np.ndarray) -> Optional[np.ndarray]:
    """Solve ``normal d = rhs``; None if singular or not finite."""
    try:
        step = np.linalg.solve(normal, rhs)
    except np.linalg.LinAlgError:
        return None
    return step if np.all(np.isfinite(step)) else None


def _noise_variance(
    normal: np.ndarray,
    rhs: np.ndarray,
    sse: float,
    n: int,
    taps: int,
    sigma: float,
    band: float,
    t,
) -> Optional[float]:
    """Estimate the per-frame white-noise variance (DN^2) from the least-squares residual.

    Parameters
    ----------
    normal, rhs : ndarray
        Normal equations ``A d = b`` of the last Gauss-Newton solve.
    sse : float
        Residual energy ``sum w e^2`` before the solve.
    n : int
        Pixels in the sums.
    taps, sigma, band : int, float, float
        The designed filter (:func:`.fractional_shift_kernel`).
    t : array_like of float
        Fractional part of the shift (rows, columns).

    Returns
    -------
    float or None
        None if ``normal`` is singular.

    Notes
    -----
    ``var(e) = sig2 (|h_t|^2 |h_t|^2 + |h_0|^2 |h_0|^2)`` (separable 2-D norms of the
    moving-side and reference-side filters), with ``var(e)`` the residual energy after the
    solve over ``n - 3`` degrees of freedom. Model error (aliasing, misfit) counts as noise.
    """
    step = _solve(normal, rhs)
    if step is None:
        return None
    h0, _ = fractional_shift_kernel(0.0, taps, sigma, band)
    h_row, _ = fractional_shift_kernel(float(t[0]), taps, sigma, band)
    h_col, _ = fractional_shift_kernel(float(t[1]), taps, sigma, band)
    n0 = float(np.dot(h0, h0))
    fit = max(sse - float(step @ rhs), 0.0) / max(n - 3, 1)
    return fit / (float(np.dot(h_row, h_row)) * float(np.dot(h_col, h_col)) + n0 * n0)


def _signal_matrix(
    normal: np.ndarray,
    rhs: np.ndarray,
    sse: float,
    n: int,
    taps: int,
    sigma: float,
    band: float,
    t,
) -> np.ndarray:
    """Return the normal matrix with the reference-noise energy removed from the gradient terms.

    Parameters are those of :func:`_noise_variance`.

    Notes
    -----
    The slope of the estimating equation ``sum g e = 0`` with respect to the shift is
    ``sum grad(R_signal) grad(M)^T``; ``A = sum g g^T`` also holds the energy of the
    reference noise in ``g``. With white noise of variance ``sig2`` per frame,
    ``var(g_i) = sig2 |k * h_0|^2 |h_0|^2`` (``k`` the central difference), so
    ``n sig2 |k * h_0|^2 |h_0|^2`` is taken off the diagonal (at most 80 % of it). Only used
    near the solution, where the residual is mostly noise.
    """
    sig2 = _noise_variance(normal, rhs, sse, n, taps, sigma, band, t)
    if sig2 is None:
        return normal
    h0, _ = fractional_shift_kernel(0.0, taps, sigma, band)
    n0 = float(np.dot(h0, h0))
    nk = float(np.sum(np.convolve(h0.astype(np.float64), [0.5, 0.0, -0.5]) ** 2))
    out = normal.copy()
    for i in (0, 1):
        out[i, i] = max(normal[i, i] - n * sig2 * nk * n0, 0.2 * normal[i, i])
    return out
