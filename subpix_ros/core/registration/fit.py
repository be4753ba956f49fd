"""Projective / affine model fitting for co-registration (METHODS.md C, stage 3).

The frame-to-frame model is the projective transform of METHODS C:

    u = (a1 x + a2 y + a0) / (c0 x + c1 y + 1)
    v = (d1 x + d2 y + d0) / (c0 x + c1 y + 1)                  (METHODS C, eq. P)

held as a 3x3 matrix ``H = [[a1, a2, a0], [d1, d2, d0], [c0, c1, 1]]``
mapping MOVING pixel coordinates (x=col, y=row) to REFERENCE pixel
coordinates. The affine option fixes ``c0 = c1 = 0``.

Fitting is Levenberg-Marquardt on the squared transfer residuals
``sum |H(x_m) - x_r|^2`` (px^2), started from the identity as in the paper,
in coordinates normalised by the image centre and half-diagonal (the same
normalisation for both frames, so the identity stays the identity).

Lens distortion (optional): one radial term shared by both frames (same
camera), Fitzgibbon's division model about the image centre ``c``,

    x_u = c + (x_d - c) / (1 + lam r_d^2),  r_d = |x_d - c| / s     (radial, division model)

with ``s`` the half-diagonal (so ``lam`` is dimensionless). The full model
maps a moving pixel ``x_d`` to the reference as ``D(H_u(U(x_d)))``; the
residual is measured in reference pixels.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .geometry import apply_h

__all__ = [
    "Normaliser",
    "levenberg_marquardt",
    "fit_homography_lm",
    "fit_homography_distortion_lm",
    "undistort_points",
    "distort_points",
    "check_homography",
]


@dataclass(frozen=True)
class Normaliser:
    """Pixel <-> normalised coordinates: ``n = (x - c) / s``, s = half-diagonal (px)."""

    cx: float
    cy: float
    s: float

    @classmethod
    def for_shape(cls, shape: tuple[int, ...]) -> "Normaliser":
        """Return the normaliser of a frame of ``shape``: centre and half-diagonal."""
        h, w = shape[:2]
        return cls((w - 1) / 2.0, (h - 1) / 2.0, 0.5 * float(np.hypot(w, h)))

    @property
    def t(self) -> np.ndarray:
        """The 3x3 matrix ``T`` taking pixel to normalised coordinates."""
        return np.array(
            [[1 / self.s, 0, -self.cx / self.s], [0, 1 / self.s, -self.cy / self.s], [0, 0, 1.0]]
        )

    def to_pixel_h(self, hn: np.ndarray) -> np.ndarray:
        """Return ``H_px = T^-1 H_n T`` (normalised-coordinate homography to pixel coordinates)."""
        t = self.t
        h = np.linalg.inv(t) @ hn @ t
        return h / h[2, 2]

    def to_norm_h(self, h: np.ndarray) -> np.ndarray:
        """Return ``H_n = T H_px T^-1`` (pixel homography to normalised coordinates)."""
        t = self.t
        hn = t @ h @ np.linalg.inv(t)
        return hn / hn[2, 2]


def levenberg_marquardt(
    fun: Callable[[np.ndarray], np.ndarray],
    p0: np.ndarray,
    iterations: int = 50,
    tol: float = 1e-12,
    jac: Callable[[np.ndarray], np.ndarray] | None = None,
) -> np.ndarray:
    """Minimise ``|fun(p)|^2`` by Levenberg-Marquardt.

    Parameters
    ----------
    fun : callable
        Residual vector of the parameters.
    p0 : ndarray
        Start.
    iterations : int
        Most Jacobian evaluations.
    tol : float
        Stop when the relative cost decrease falls below this.
    jac : callable, optional
        Jacobian of ``fun``; forward differences without it.

    Returns
    -------
    ndarray
        The parameters.

    Notes
    -----
    Damped normal equations ``(J^T J + mu diag(J^T J)) dp = -J^T r``; ``mu`` is divided by 3
    after an accepted step and multiplied by 4 after a rejected one [1]_.

    References
    ----------
    .. [1] D. W. Marquardt, "An algorithm for least-squares estimation of nonlinear
       parameters", J. SIAM 11(2), 431-441, 1963. https://doi.org/10.1137/0111030
    """
    p = np.asarray(p0, dtype=np.float64).copy()
    r = fun(p)
    cost = float(r @ r)
    mu = 1e-3
    eps = 1e-7
    for _ in range(iterations):
        if jac is not None:
            jm = jac(p)
        else:
            jm = np.empty((r.size, p.size))
            for i in range(p.size):  # one column per parameter (<= 9), each vectorised over points
                dp = np.zeros_like(p)
                dp[i] = eps
                jm[:, i] = (fun(p + dp) - r) / eps
        jtj = jm.T @ jm
        g = jm.T @ r
        improved = False
        for _ in range(10):
            a = jtj + mu * np.diag(np.maximum(np.diag(jtj), 1e-12))
            try:
                step = np.linalg.solve(a, -g)
            except np.linalg.LinAlgError:
                mu *= 4
                continue
            pn = p + step
            rn = fun(pn)
            cn = float(rn @ rn)
            if np.isfinite(cn) and cn < cost:
                rel = (cost - cn) / max(cost, 1e-300)
                p, r, cost = pn, rn, cn
                mu = max(mu / 3, 1e-12)
                improved = True
                break
            mu *= 4
        if not improved or rel < tol:
            break
    return p


def _h_from_params(q: np.ndarray, affine: bool) -> np.ndarray:
    if affine:
        return np.array([[q[0], q[1], q[2]], [q[3], q[4], q[5]], [0.0, 0.0, 1.0]])
    return np.array([[q[0], q[1], q[2]], [q[3], q[4], q[5]], [q[6], q[7], 1.0]])


def _params_from_h(h: np.ndarray, affine: bool) -> np.ndarray:
    h = h / h[2, 2]
    q = [h[0, 0], h[0, 1], h[0, 2], h[1, 0], h[1, 1], h[1, 2]]
    if not affine:
        q += [h[2, 0], h[2, 1]]
    return np.array(q)


def _jacobian_eq_p(q: np.ndarray, m: np.ndarray, affine: bool) -> np.ndarray:
    """Return the analytic Jacobian of the eq. P residuals with respect to the parameters.

    Rows ``u0, v0, u1, v1, ...``.

    With ``w = c0 x + c1 y + 1``: ``du/da_i = (x, y, 1) / w``, ``dv/dd_i = (x, y, 1) / w``,
    ``du/dc = -u (x, y) / w``, ``dv/dc = -v (x, y) / w``.
    """
    x, y = m[:, 0], m[:, 1]
    n = len(m)
    w = np.ones(n) if affine else q[6] * x + q[7] * y + 1.0
    iw = 1.0 / w
    j = np.zeros((n, 2, 6 if affine else 8))
    j[:, 0, 0], j[:, 0, 1], j[:, 0, 2] = x * iw, y * iw, iw
    j[:, 1, 3], j[:, 1, 4], j[:, 1, 5] = x * iw, y * iw, iw
    if not affine:
        u = (q[0] * x + q[1] * y + q[2]) * iw
        v = (q[3] * x + q[4] * y + q[5]) * iw
        j[:, 0, 6], j[:, 0, 7] = -u * x * iw, -u * y * iw
        j[:, 1, 6], j[:, 1, 7] = -v * x * iw, -v * y * iw
    return j.reshape(2 * n, -1)


def fit_homography_lm(
    pts_mov: np.ndarray,
    pts_ref: np.ndarray,
    norm: Normaliser,
    affine: bool = False,
    h0: np.ndarray | None = None,
) -> np.ndarray:
    """Fit eq. P (or its affine case) to tie points by Levenberg-Marquardt.

    Parameters
    ----------
    pts_mov, pts_ref : ndarray, shape (N, 2)
        Tie points (x, y) in the moving and reference frames (px).
    norm : Normaliser
        Coordinate normalisation.
    affine : bool
        Fix ``c0 = c1 = 0``.
    h0 : ndarray, shape (3, 3), optional
        Start (pixel H); the identity (METHODS C) without it.

    Returns
    -------
    ndarray, shape (3, 3)
        Pixel homography, moving -> reference.

    Notes
    -----
    Residual ``H(x_m) - x_r`` in normalised units (px / s).
    """
    t = norm.t
    m = apply_h(t, pts_mov)
    r = apply_h(t, pts_ref)
    start = np.eye(3) if h0 is None else norm.to_norm_h(h0)

    def res(q: np.ndarray) -> np.ndarray:
        return (apply_h(_h_from_params(q, affine), m) - r).ravel()

    def jac(q: np.ndarray) -> np.ndarray:
        return _jacobian_eq_p(q, m, affine)

    q = levenberg_marquardt(res, _params_from_h(start, affine), jac=jac)
    return norm.to_pixel_h(_h_from_params(q, affine))


def undistort_points(pts: np.ndarray, lam: float, norm: Normaliser) -> np.ndarray:
    """Undistort points with the division model ``x_u = c + (x_d - c) / (1 + lam r_d^2)``.

    Parameters
    ----------
    pts : ndarray, shape (N, 2)
        Distorted points (px).
    lam : float
        Division-model lambda.
    norm : Normaliser
        Centre ``c`` and scale (``r_d`` in half-diagonals).

    Returns
    -------
    ndarray, shape (N, 2)
        Undistorted points (px).
    """
    c = np.array([norm.cx, norm.cy])
    d = (pts - c) / norm.s
    r2 = (d * d).sum(axis=1, keepdims=True)
    return c + norm.s * d / (1.0 + lam * r2)


def distort_points(pts: np.ndarray, lam: float, norm: Normaliser) -> np.ndarray:
    """Distort points: the inverse of :func:`undistort_points` in closed form.

    Parameters
    ----------
    pts : ndarray, shape (N, 2)
        Undistorted points (px).
    lam : float
        Division-model lambda.
    norm : Normaliser
        Centre and scale.

    Returns
    -------
    ndarray, shape (N, 2)
        Distorted points (px); inf beyond the model's validity (negative discriminant).

    Notes
    -----
    With ``r_u = r_d / (1 + lam r_d^2)``: ``r_d = (1 - sqrt(1 - 4 lam r_u^2)) / (2 lam r_u)``.
    """
    c = np.array([norm.cx, norm.cy])
    u = (pts - c) / norm.s
    ru = np.sqrt((u * u).sum(axis=1))
    if abs(lam) < 1e-15:
        return pts.astype(np.float64).copy()
    disc = 1.0 - 4.0 * lam * ru * ru
    with np.errstate(invalid="ignore", divide="ignore"):
        rd = np.where(
            ru > 1e-12,
            (1.0 - np.sqrt(np.where(disc >= 0, disc, np.nan)))
            / (2.0 * lam * np.maximum(ru, 1e-12)),
            0.0,
        )
        scale = np.where(ru > 1e-12, rd / np.maximum(ru, 1e-12), 1.0)
    out = c + norm.s * u * scale[:, None]
    out[~np.isfinite(out).all(axis=1)] = np.inf
    return out


def fit_homography_distortion_lm(
    pts_mov: np.ndarray, pts_ref: np.ndarray, norm: Normaliser, h0: np.ndarray, affine: bool = False
) -> tuple[np.ndarray, float]:
    """Fit ``H_u`` (eq. P on undistorted points) and the division-model ``lam`` jointly.

    Parameters
    ----------
    pts_mov, pts_ref : ndarray, shape (N, 2)
        Tie points (px).
    norm : Normaliser
        Coordinate normalisation (centre of distortion, half-diagonal).
    h0 : ndarray, shape (3, 3)
        Start (pixel H), with ``lam = 0``.
    affine : bool
        Fix ``c0 = c1 = 0``.

    Returns
    -------
    h_u : ndarray, shape (3, 3)
        Maps UNDISTORTED moving pixel coordinates to UNDISTORTED reference pixel coordinates.
    lam : float

    Notes
    -----
    Residual, in normalised units, measured in the undistorted reference frame and scaled back
    to distorted units to first order::

        e_i = (1 + lam r_i^2) (H_u(U(x_m,i)) - U(x_r,i)),   r_i = |x_r,i - c| / s

    (``D`` divides radii by ``1 / (1 + lam r_d^2)`` near ``U(x_r)``, so ``e_i`` equals
    ``D(H_u(U(x_m))) - x_r`` up to O(lam e); the factor keeps lambda from shrinking all
    residuals by shrinking the coordinates). The Jacobian is analytic.
    """
    t = norm.t
    m = apply_h(t, pts_mov)  # normalised coordinates: centre 0, half-diagonal 1
    r = apply_h(t, pts_ref)
    rm2 = (m * m).sum(axis=1)
    rr2 = (r * r).sum(axis=1)

    def parts(q: np.ndarray):
        lam = q[-1]
        um = m / (1.0 + lam * rm2)[:, None]
        ur = r / (1.0 + lam * rr2)[:, None]
        hq = _h_from_params(q[:-1], affine)
        y = apply_h(hq, um)
        wgt = 1.0 + lam * rr2
        return lam, um, ur, hq, y, wgt

    def res(q: np.ndarray) -> np.ndarray:
        _, _, ur, _, y, wgt = parts(q)
        out = (wgt[:, None] * (y - ur)).ravel()
        return np.where(np.isfinite(out), out, 1e3)

    def jac(q: np.ndarray) -> np.ndarray:
        lam, um, ur, hq, y, wgt = parts(q)
        n = len(m)
        jh = _jacobian_eq_p(q[:-1], um, affine).reshape(n, 2, -1) * wgt[:, None, None]
        # d/dlam: w (dH/du dU(m)/dlam - dU(r)/dlam) + r^2 (H(U(m)) - U(r)),
        # with dU(p)/dlam = -p rp^2 / (1 + lam rp^2)^2
        w = hq[2, 0] * um[:, 0] + hq[2, 1] * um[:, 1] + 1.0
        a = np.empty((n, 2, 2))
        a[:, 0, 0] = (hq[0, 0] - y[:, 0] * hq[2, 0]) / w
        a[:, 0, 1] = (hq[0, 1] - y[:, 0] * hq[2, 1]) / w
        a[:, 1, 0] = (hq[1, 0] - y[:, 1] * hq[2, 0]) / w
        a[:, 1, 1] = (hq[1, 1] - y[:, 1] * hq[2, 1]) / w
        dum = -m * (rm2 / (1.0 + lam * rm2) ** 2)[:, None]
        dur = -r * (rr2 / (1.0 + lam * rr2) ** 2)[:, None]
        jl = wgt[:, None] * (np.einsum("nij,nj->ni", a, dum) - dur) + rr2[:, None] * (y - ur)
        out = np.concatenate([jh, jl[:, :, None]], axis=2).reshape(2 * n, -1)
        return np.where(np.isfinite(out), out, 0.0)

    q0 = np.concatenate([_params_from_h(norm.to_norm_h(h0), affine), [0.0]])
    q = levenberg_marquardt(res, q0, jac=jac)
    return norm.to_pixel_h(_h_from_params(q[:-1], affine)), float(q[-1])


def check_homography(
    h: np.ndarray, shape_mov: tuple[int, ...], max_scale: float = 3.0, max_aniso: float = 2.0
) -> str:
    """Check a moving -> reference homography for sanity.

    Parameters
    ----------
    h : ndarray, shape (3, 3)
        The homography.
    shape_mov : tuple of int
        Moving frame shape.
    max_scale : float
        Largest local scale (and its inverse the smallest).
    max_aniso : float
        Largest singular-value ratio (shear / anisotropy) of the local linear part.

    Returns
    -------
    str
        '' if sane, else the reason.

    Notes
    -----
    Checks: finite; the moving frame's corners map to a convex, same-orientation quadrilateral
    (no fold, the perspective horizon stays outside the frame); the local linear part at every
    corner has ``|det|`` in ``[1/max_scale^2, max_scale^2]`` and singular-value ratio at most
    ``max_aniso``.
    """
    if h is None or not np.isfinite(h).all():
        return "homography is not finite"
    hh, ww = shape_mov[:2]
    corners = np.array([[0, 0], [ww - 1, 0], [ww - 1, hh - 1], [0, hh - 1]], float)
    wden = h[2, 0] * corners[:, 0] + h[2, 1] * corners[:, 1] + h[2, 2]
    if np.any(wden <= 0) or np.ptp(np.sign(wden)) != 0:
        return "degenerate fit: the frame crosses the perspective horizon"
    q = apply_h(h, corners)
    e = np.roll(q, -1, axis=0) - q
    cross = e[:, 0] * np.roll(e, -1, axis=0)[:, 1] - e[:, 1] * np.roll(e, -1, axis=0)[:, 0]
    if not (np.all(cross > 0) or np.all(cross < 0)):
        return "degenerate fit: the mapped frame is folded or not convex"
    if np.all(cross < 0):
        return "degenerate fit: the mapping mirrors the frame"
    for (x, y), wv in zip(corners, wden):
        # Jacobian of eq. P at (x, y).
        u = (h[0, 0] * x + h[0, 1] * y + h[0, 2]) / wv
        v = (h[1, 0] * x + h[1, 1] * y + h[1, 2]) / wv
        j = (
            np.array(
                [
                    [h[0, 0] - u * h[2, 0], h[0, 1] - u * h[2, 1]],
                    [h[1, 0] - v * h[2, 0], h[1, 1] - v * h[2, 1]],
                ]
            )
            / wv
        )
        sv = np.linalg.svd(j, compute_uv=False)
        det = sv[0] * sv[1]
        if not (1 / max_scale**2 <= det <= max_scale**2):
            return (
                f"degenerate fit: local scale {np.sqrt(det):.2f} "
                f"outside [1/{max_scale}, {max_scale}]"
            )
        if sv[0] > max_aniso * sv[1]:
            return f"degenerate fit: shear/anisotropy {sv[0] / sv[1]:.2f} > {max_aniso}"
    return ""
