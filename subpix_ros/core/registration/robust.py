"""Robust model fitting of tie points: MAGSAC, residuals, the radial term, calibration."""

from __future__ import annotations

import cv2
import numpy as np

from .fit import (
    Normaliser,
    distort_points,
    fit_homography_distortion_lm,
    fit_homography_lm,
    undistort_points,
)
from .geometry import _valid_grid, apply_h
from .result import RegistrationResult


def _robust(
    pm: np.ndarray, pr: np.ndarray, thresh: float, affine: bool
) -> tuple[np.ndarray | None, np.ndarray]:
    """Reject outliers by USAC/MAGSAC; return (H or None, inlier mask)."""
    n = len(pm)
    if n < (3 if affine else 4) + 2:
        return None, np.zeros(n, bool)
    if affine:
        a, mask = cv2.estimateAffine2D(
            pm,
            pr,
            method=cv2.USAC_MAGSAC,
            ransacReprojThreshold=thresh,
            maxIters=2000,
            confidence=0.999,
        )
        h = None if a is None else np.vstack([a, [0, 0, 1]])
    else:
        h, mask = cv2.findHomography(
            pm, pr, cv2.USAC_MAGSAC, thresh, maxIters=2000, confidence=0.999
        )
    if h is None or mask is None:
        return None, np.zeros(n, bool)
    return h.astype(np.float64), mask.ravel().astype(bool)


def _residuals(h: np.ndarray, pm: np.ndarray, pr: np.ndarray) -> np.ndarray:
    return np.hypot(*(apply_h(h, pm) - pr).T)


def _spread(pr: np.ndarray, h_mr: np.ndarray, shape_ref, shape_mov, cells: int = 6) -> float:
    """Return the fraction of the overlap's grid cells holding at least one inlier.

    The bounding box of the overlap (in the reference) is cut into
    ``cells x cells``; only cells whose centre lies in the overlap count.
    """
    step = 8
    valid = _valid_grid(shape_ref, shape_mov, h_mr, 0, step)
    ys, xs = np.nonzero(valid)
    if xs.size == 0:
        return 0.0
    x0, x1, y0, y1 = xs.min() * step, (xs.max() + 1) * step, ys.min() * step, (ys.max() + 1) * step
    cx = np.clip(((pr[:, 0] - x0) * cells // max(x1 - x0, 1)).astype(int), 0, cells - 1)
    cy = np.clip(((pr[:, 1] - y0) * cells // max(y1 - y0, 1)).astype(int), 0, cells - 1)
    occ = np.zeros((cells, cells), bool)
    occ[cy, cx] = True
    gy = ((np.arange(cells) + 0.5) * (y1 - y0) / cells + y0) / step
    gx = ((np.arange(cells) + 0.5) * (x1 - x0) / cells + x0) / step
    iy = np.clip(gy.astype(int), 0, valid.shape[0] - 1)
    ix = np.clip(gx.astype(int), 0, valid.shape[1] - 1)
    in_overlap = valid[iy[:, None], ix[None, :]]
    n_in = int(in_overlap.sum())
    return float((occ & in_overlap).sum() / max(n_in, 1))


def _full_residuals(
    hu: np.ndarray, lam: float, norm: Normaliser, pm: np.ndarray, pr: np.ndarray
) -> np.ndarray:
    """Return the residuals ``|D(H_u(U(x_m))) - x_r|`` (reference px); inf where invalid."""
    res = np.hypot(
        *(distort_points(apply_h(hu, undistort_points(pm, lam, norm)), lam, norm) - pr).T
    )
    return np.where(np.isfinite(res), res, np.inf)


def _model_residuals(
    h: np.ndarray,
    hu: np.ndarray | None,
    lam: float,
    norm: Normaliser,
    pm: np.ndarray,
    pr: np.ndarray,
) -> np.ndarray:
    """Return the residuals of the current model: ``(hu, lam)`` once fitted, else ``h``."""
    return _full_residuals(hu, lam, norm, pm, pr) if hu is not None else _residuals(h, pm, pr)


def _fit_fixed_lambda(
    pm: np.ndarray, pr: np.ndarray, lam: float, norm: Normaliser, affine: bool, h0: np.ndarray
) -> np.ndarray:
    """Fit ``H_u`` for a known division-model ``lam``: eq. P by LM between undistorted points.

    The residual is measured between undistorted coordinates; with |lam| << 1
    it differs from the distorted-space residual by a factor ``1 + O(lam)``.
    """
    return fit_homography_lm(
        undistort_points(pm, lam, norm), undistort_points(pr, lam, norm), norm, affine, h0=h0
    )


def _refit_distortion(
    pm: np.ndarray,
    pr: np.ndarray,
    lam: float,
    hu: np.ndarray,
    fixed_lam: float | None,
    norm: Normaliser,
    affine: bool,
) -> tuple[np.ndarray, float]:
    """Refit the full model on the tie points ``pm`` -> ``pr``; return ``(H_u, lambda)``.

    ``H_u`` alone with a fixed camera lambda (``fixed_lam``), else ``H_u`` and lambda jointly
    from ``(hu, lam)``.
    """
    if fixed_lam is not None:
        return _fit_fixed_lambda(pm, pr, lam, norm, affine, hu), lam
    return fit_homography_distortion_lm(pm, pr, norm, hu, affine)


def calibrate_distortion(results: list[RegistrationResult], lam_range: float = 0.1) -> float:
    """Estimate one division-model lambda for a camera from several registrations.

    Parameters
    ----------
    results : list of RegistrationResult
        Registrations of frames of one camera (failed ones and those with fewer than 8 tie
        points are ignored).
    lam_range : float
        Search interval ``[-lam_range, lam_range]``.

    Returns
    -------
    float
        Lambda (dimensionless, radius in half-diagonals), so a value from half-resolution
        frames holds at full resolution.

    Raises
    ------
    ValueError
        Without at least one usable result.

    Notes
    -----
    Minimises the pooled sum of squared transfer residuals (each clipped at 10 px)::

        sum_pairs sum_i |D(H_u,p(U(x_m,i))) - x_r,i|^2

    over ``lam`` by golden-section search, each pair's ``H_u`` refitted for each ``lam``.
    """
    use = [r for r in results if r.ok and len(r.points) >= 8]
    if not use:
        raise ValueError("calibrate_distortion needs at least one successful registration")
    affine = [r.model == "affine" for r in use]

    def cost(lam: float) -> float:
        tot = 0.0
        for r, aff in zip(use, affine):
            norm = Normaliser.for_shape(r.ref_shape)
            pr, pm = r.points[:, :2], r.points[:, 2:]
            hu = _fit_fixed_lambda(pm, pr, lam, norm, aff, r.homography)
            tot += float(np.sum(np.minimum(_full_residuals(hu, lam, norm, pm, pr), 10.0) ** 2))
        return tot

    g = (np.sqrt(5) - 1) / 2
    a, b = -lam_range, lam_range
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = cost(c), cost(d)
    for _ in range(30):  # bracket shrinks by 0.618 per step: 2e-7 of the range after 30
        if fc < fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = cost(c)
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = cost(d)
    return float((a + b) / 2)
