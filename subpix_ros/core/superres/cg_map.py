"""MAP super-resolution by conjugate gradients with the spatial frame operators (eq. 9)."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .model import FrameOperator
from .spectrum import rolloff_precision


def _cg_map(
    frames: np.ndarray,
    homographies: np.ndarray,
    p: int,
    blur_sigma: float,
    noise_sigma: float,
    masks: Sequence[np.ndarray] | None,
    prior: tuple[float, float],
    reg: float,
    x0: np.ndarray,
    iters: int,
    motion_blur: tuple[float, float] = (0.0, 0.0),
    rolloff: float = 0.0,
) -> np.ndarray:
    """Compute the MAP estimate of eq. 9 by conjugate gradients with the spatial operators.

    Parameters
    ----------
    frames : numpy.ndarray
        (N, H, W) frames.
    homographies : numpy.ndarray
        (N, 3, 3) reference -> frame LR pixel coordinates.
    p : int
        Resolution factor.
    blur_sigma : float
        Optics blur std (LR px).
    noise_sigma : float
        Per-pixel noise std (DN).
    masks : sequence of numpy.ndarray or None
        A bool array per frame (True = valid).
    prior : (float, float)
        ``(c, alpha)`` of ``S_x(f) = c |f|^-alpha``.
    reg : float
        Prior strength multiplier.
    x0 : numpy.ndarray
        (p H, p W) starting image (the Fourier solution).
    iters : int
        Most CG iterations (each 2 N resamplings and 2 FFTs).
    motion_blur : (float, float), optional
        Image motion during the exposure ``(du, dv)`` (LR px; default none): a line kernel
        in every frame operator.
    rolloff : float, optional
        ``k`` of the prior's Gaussian roll-off, ``S_x(f) = c |f|^-alpha exp(-k |f|^2)``
        (f in cycles / HR px; default 0: none).

    Returns
    -------
    numpy.ndarray
        float64 (p H, p W).

    Notes
    -----
    Solves ``(sum_n A_n^T M_n A_n / sigma^2 + reg Q) x = sum_n A_n^T M_n y_n / sigma^2`` where
    ``A_n`` is :class:`~subpix_ros.core.superres.model.FrameOperator` (blur, motion blur, any
    homography, box integration; bilinear resampling), ``M_n`` the validity mask (given mask and
    footprint inside the HR grid) and ``Q`` the stationary prior precision, applied by FFT:
    ``Q x = ifft(fft(x) / S_x(f))`` (DC unregularised).
    """
    hh, hw = x0.shape
    c, alpha = prior
    fy = np.fft.fftfreq(hh)[:, None]
    fx = np.fft.rfftfreq(hw)[None, :]
    fr = np.hypot(fy, fx)
    prec = np.where(fr > 0, np.maximum(fr, 1e-6) ** alpha / c, 0.0)
    if rolloff > 0:
        prec *= rolloff_precision(fr * fr, rolloff)
    ops = _masked_operators(frames, homographies, p, blur_sigma, masks, (hh, hw), motion_blur)
    inv_var = 1.0 / noise_sigma**2

    def normal(x: np.ndarray) -> np.ndarray:
        """Apply the normal-equation operator to ``x``."""
        out = reg * np.fft.irfft2(np.fft.rfft2(x) * prec, s=x.shape)
        for op, m in ops:
            out += inv_var * op.adjoint(m * op.forward(x))
        return out

    b = np.zeros((hh, hw))
    for (op, m), y in zip(ops, frames):
        b += inv_var * op.adjoint(m * y)
    return _conjugate_gradients(normal, b, x0, iters)


def _masked_operators(
    frames: np.ndarray,
    homographies: np.ndarray,
    p: int,
    blur_sigma: float,
    masks: Sequence[np.ndarray] | None,
    hr_shape: tuple[int, int],
    motion_blur: tuple[float, float] = (0.0, 0.0),
) -> list[tuple[FrameOperator, np.ndarray]]:
    """Return each frame's operator and its mask (footprint inside the HR grid, and given)."""
    ops = []
    for i in range(frames.shape[0]):  # one operator per frame
        op = FrameOperator(
            homographies[i], frames[i].shape, hr_shape, p, p, blur_sigma, tuple(motion_blur)
        )
        m = op.valid.astype(np.float64)
        if masks is not None:
            m = m * np.asarray(masks[i], dtype=bool)
        ops.append((op, m))
    return ops


def _conjugate_gradients(normal, b: np.ndarray, x0: np.ndarray, iters: int) -> np.ndarray:
    """Solve ``normal(x) = b`` by at most ``iters`` CG steps from ``x0``.

    Stops early once the squared residual falls below 1e-12 of the initial one.
    """
    x = x0.copy()
    r = b - normal(x)
    d = r.copy()
    rr = float(np.sum(r * r))
    r0 = rr
    for _ in range(iters):  # CG iterations
        if rr <= 1e-12 * max(r0, 1e-30):
            break
        q = normal(d)
        alpha_k = rr / float(np.sum(d * q))
        x += alpha_k * d
        r -= alpha_k * q
        rr_new = float(np.sum(r * r))
        d = r + (rr_new / rr) * d
        rr = rr_new
    return x
