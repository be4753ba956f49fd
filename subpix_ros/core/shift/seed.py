"""The seed estimator of METHODS.md A: one closed-form solve of the paper's normal equations.

The paper's notation is kept: matrices ``D, E, F`` on the ``(m-2) x (n-2)`` interior, normal
equations ``A C = B`` with means of Hadamard products, float64 accumulation. The paper leaves
sign and scale open; ``d`` and ``e`` are two-pixel central differences summed over both frames
(``d ~ 4 dI/dr``, ``e ~ 4 dI/dc``) and ``f = y - x ~ -s.grad I + z``, so the paper's
``C = (c_u, c_v, z)`` relates to our shift by ``u = -4 c_u``, ``v = -4 c_v`` (checked by tests
against known shifts).

``method="seed-iterated"`` re-solves the seed's normal equations after warping the moving frame
by the current estimate with OpenCV INTER_CUBIC, 3 solves (biased by the cubic warp).

References
----------
.. [1] S. A. Stankevich, S. V. Shklyar, A. R. Lysenko, "Software module for estimating the
   sub-pixel shift of images acquired from a quadcopter", 2018 (docs/METHODS.md A).
"""

from __future__ import annotations

import math
from typing import Tuple

import cv2
import numpy as np

from .result import ShiftResult, _fail


def _seed_sums(reference: np.ndarray, moving: np.ndarray):
    """Return the seed's normal equations plus ``<F F>``, in one pass over ``D, E, F``.

    Returns
    -------
    A : ndarray, shape (3, 3)
        Means of the products of ``(D, E, 1)`` (float64).
    B : ndarray, shape (3,)
        Means of ``F D``, ``F E``, ``F``.
    ff : float
        Mean of ``F F``.
    n : int
        Number of interior pixels.
    """
    x = np.asarray(reference, dtype=np.float64)
    y = np.asarray(moving, dtype=np.float64)
    both = x + y
    d = (both[2:, 1:-1] - both[:-2, 1:-1]).ravel()
    e = (both[1:-1, 2:] - both[1:-1, :-2]).ravel()
    f = (y[1:-1, 1:-1] - x[1:-1, 1:-1]).ravel()
    n = d.size
    dd, de, ee = np.dot(d, d) / n, np.dot(d, e) / n, np.dot(e, e) / n
    dm, em, fm = d.sum() / n, e.sum() / n, f.sum() / n
    A = np.array([[dd, de, dm], [de, ee, em], [dm, em, 1.0]])
    B = np.array([np.dot(f, d) / n, np.dot(f, e) / n, fm])
    return A, B, float(np.dot(f, f) / n), n


def seed_system(x: np.ndarray, y: np.ndarray) -> Tuple[np.ndarray, np.ndarray, int]:
    """Build the seed's normal equations ``A C = B`` (METHODS.md A), float64.

    Parameters
    ----------
    x : ndarray, shape (m, n)
        Reference frame.
    y : ndarray, shape (m, n)
        Moving frame.

    Returns
    -------
    A : ndarray, shape (3, 3)
        ``[[<DD>, <DE>, <D>], [<DE>, <EE>, <E>], [<D>, <E>, 1]]``.
    B : ndarray, shape (3,)
        ``[<FD>, <FE>, <F>]``.
    n : int
        Number of interior pixels.

    Notes
    -----
    With (0-based) ``l = i + 2``, ``k = j + 1`` on the ``(m-2) x (n-2)`` interior::

        d = x[l, k] + y[l, k] - x[l-2, k] - y[l-2, k]
        e = x[l-1, k+1] + y[l-1, k+1] - x[l-1, k-1] - y[l-1, k-1]
        f = y[l-1, k] - x[l-1, k]

    and ``<.>`` is the mean of a Hadamard product.
    """
    A, B, _, n = _seed_sums(x, y)
    return A, B, n


def seed_solve(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Solve the seed's ``A C = B`` for the paper's raw ``C = (c_u, c_v, z)``.

    Parameters
    ----------
    x, y : ndarray
        Reference and moving frames, equal shapes.

    Returns
    -------
    C : ndarray, shape (3,)
        Our shift convention is ``u = -4 c_u``, ``v = -4 c_v`` (:mod:`.seed`).

    Raises
    ------
    numpy.linalg.LinAlgError
        If ``A`` is singular.
    """
    A, B, _ = seed_system(x, y)
    return np.linalg.solve(A, B)


def _seed_result(
    reference: np.ndarray, moving: np.ndarray, method: str, iterations: int, converged: bool
) -> ShiftResult:
    """Return the seed's shift, with the least-squares covariance of ``C`` scaled to px^2."""
    A, B, ff, n = _seed_sums(reference, moving)
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
    cov_c = s2 * np.linalg.inv(A * n)
    cov = 16.0 * cov_c[:2, :2]
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
    image: np.ndarray, u: float, v: float, interp: int = cv2.INTER_CUBIC
) -> np.ndarray:
    """Return ``out(x) = image(x + s)``: moves content by ``-s`` (undoes a shift ``s``)."""
    h, w = image.shape
    affine = np.float64([[1, 0, v], [0, 1, u]])
    return cv2.warpAffine(
        image, affine, (w, h), flags=interp | cv2.WARP_INVERSE_MAP, borderMode=cv2.BORDER_REPLICATE
    )


def _seed_iterated(x: np.ndarray, y: np.ndarray, iterations: int = 3) -> ShiftResult:
    """Re-solve the seed after warping ``y`` back by the running estimate, ``iterations`` times."""
    x = np.asarray(x, np.float64)
    y = np.asarray(y, np.float64)
    u = v = 0.0
    res = None
    border = 0
    for _ in range(iterations):
        warped = _warp_translate(y, u, v) if (u or v) else y
        border = int(math.ceil(max(abs(u), abs(v)))) + 2
        if 2 * border + 8 > min(x.shape):
            return _fail(
                "seed-iterated diverged: shift estimate exceeds the frame", "seed-iterated"
            )
        inner = (slice(border, -border), slice(border, -border))
        res = _seed_result(x[inner], warped[inner], "seed-iterated", 0, False)
        if not res.ok:
            return res
        u += res.u
        v += res.v
    res.u, res.v = float(u), float(v)
    res.iterations = iterations
    return res
