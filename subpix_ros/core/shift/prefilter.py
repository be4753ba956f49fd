"""The designed prefilter + fractional-delay kernel, and the choice of its Gaussian width.

References
----------
.. [1] T. I. Laakso, V. Valimaki, M. Karjalainen and U. K. Laine, "Splitting the unit delay:
   tools for fractional delay filter design", IEEE Signal Processing Magazine 13(1), 30-60,
   1996. https://doi.org/10.1109/79.482137
"""

from __future__ import annotations

from functools import lru_cache
from typing import Sequence, Tuple

import cv2
import numpy as np

_DEFAULT_SIGMA = 0.8  # prefilter (px) against aliasing when the pair is not noise-limited
# candidates on noise-limited pairs (smallest predicted variance wins)
_ADAPTIVE_SIGMAS = (0.7, 0.6, 0.5, 0.4)
_SPECTRUM_SIZE = 256  # side (px) of the central crop whose spectrum chooses the prefilter


@lru_cache(maxsize=4096)
def _kernel_cached(t_key: int, taps: int, sigma: float, band: float) -> Tuple[np.ndarray, int]:
    """Design the kernel of :func:`fractional_shift_kernel` for ``t = t_key / 2^20`` (cached)."""
    t = t_key / 2.0**20
    half = taps // 2
    offsets = np.arange(-half + 1, half + 1, dtype=np.float64)
    freqs = np.linspace(0.0, np.pi * band, 8 * taps + 1)
    target = np.exp(-0.5 * (sigma * freqs) ** 2) * np.exp(1j * freqs * t)
    basis = np.exp(1j * np.outer(freqs, offsets))
    design = np.vstack([basis.real, basis.imag])
    rhs = np.concatenate([target.real, target.imag])
    kernel = np.linalg.lstsq(design, rhs, rcond=None)[0]
    kernel = kernel / kernel.sum()  # exact unit DC gain: z stays an intensity offset
    kernel = kernel.astype(np.float32)
    kernel.setflags(write=False)
    return kernel, half - 1


def fractional_shift_kernel(
    t: float, taps: int = 8, sigma: float = 0.8, band: float = 0.85
) -> Tuple[np.ndarray, int]:
    """Design FIR taps that sample a Gaussian-prefiltered row at a fractional delay ``t``.

    Parameters
    ----------
    t : float
        Delay in [0, 1] pixels (quantised to 2^-20 px).
    taps : int
        Number of taps (even); ``j = -taps/2 + 1 .. taps/2``.
    sigma : float
        Gaussian prefilter width (px).
    band : float
        Design band as a fraction of Nyquist.

    Returns
    -------
    kernel : ndarray of float32, shape (taps,)
        Read-only taps ``h_j``, normalised to unit DC gain.
    anchor : int
        Anchor index for ``cv2.sepFilter2D``.

    Raises
    ------
    ValueError
        If ``t`` is outside [0, 1].

    Notes
    -----
    Least-squares design over ``|w| <= band pi`` of::

        sum_j h_j exp(i w j) ~= exp(-(sigma w)^2 / 2) exp(i w t),

    so filtering a row with it (correlation, ``out[x] = sum_j h_j in[x + j]``) samples the
    Gaussian-prefiltered signal at ``x + t`` [1]_.
    """
    if not (0.0 <= t <= 1.0):
        raise ValueError("t must be in [0, 1]")
    return _kernel_cached(int(round(t * 2.0**20)), int(taps), float(sigma), float(band))


def predicted_shift_variance(
    ref: np.ndarray, mov: np.ndarray, noise_var: float, sigmas: Sequence[float]
) -> np.ndarray:
    """Predict the variance of the Gaussian-prefiltered estimator for each prefilter width.

    Parameters
    ----------
    ref, mov : ndarray
        The two frames (only their central ``_SPECTRUM_SIZE`` px square is used).
    noise_var : float
        White-noise variance per frame (DN^2).
    sigmas : sequence of float
        Candidate prefilter widths (px).

    Returns
    -------
    ndarray
        ``trace(S^-1 B S^-T)`` (px^2, u + v) per sigma; inf where ``S`` is singular.

    Notes
    -----
    Frequency-domain model of the estimating equation ``sum g e = 0``: with weight
    ``W = |G_sigma(w)|^2``, gradient ``s_i = sin(w_i)`` (central difference) and signal power
    ``P`` (the Hann-windowed periodograms of the two frames averaged, less the noise
    ``nu = noise_var sum w^2``), the slope is ``S = sum W s w^T P`` and the score covariance::

        B = 2 sum W^2 s s^T (P nu + nu^2 / 2);

    the ``nu^2`` term is the noise-times-noise part that keeps this estimator above the
    Cramer-Rao bound ``2 sigma^2 J^-1``.
    """
    h, w = ref.shape
    sh, sw = min(h, _SPECTRUM_SIZE), min(w, _SPECTRUM_SIZE)
    r0, c0 = (h - sh) // 2, (w - sw) // 2
    win = cv2.createHanningWindow((sw, sh), cv2.CV_64F)
    n_cols = sw // 2 + 1
    power = np.zeros((sh, n_cols))
    for frame in (ref, mov):
        crop = np.asarray(frame[r0 : r0 + sh, c0 : c0 + sw], dtype=np.float64)
        spec = np.fft.rfft2((crop - crop.mean()) * win)
        power += 0.5 * (spec.real**2 + spec.imag**2)
    nu = float(noise_var) * float(np.sum(win * win))
    power -= nu
    # half-plane spectrum: columns other than 0 (and Nyquist) stand for their mirror too
    mult = np.full(n_cols, 2.0)
    mult[0] = 1.0
    if sw % 2 == 0:
        mult[-1] = 1.0
    wy = np.broadcast_to(2.0 * np.pi * np.fft.fftfreq(sh)[:, None], power.shape)
    wx = np.broadcast_to(2.0 * np.pi * np.fft.rfftfreq(sw)[None, :], power.shape)
    sy, sx = np.sin(wy), np.sin(wx)
    weighted = power * mult
    noise_term = (power * nu + 0.5 * nu * nu) * mult
    fa = np.stack([sy * wy * weighted, sy * wx * weighted, sx * wy * weighted, sx * wx * weighted])
    fa = fa.reshape(4, -1)
    fb = np.stack([sy * sy * noise_term, sy * sx * noise_term, sx * sx * noise_term])
    fb = fb.reshape(3, -1)
    sg = np.asarray(sigmas, dtype=np.float64)[:, None]
    weight = np.exp(-(sg**2) * (wy * wy + wx * wx).reshape(1, -1))
    slope_entries = weight @ fa.T  # (K, 4)
    score_entries = 2.0 * ((weight * weight) @ fb.T)  # (K, 3)
    out = []
    for k in range(sg.shape[0]):
        slope = slope_entries[k].reshape(2, 2)
        sc = score_entries[k]
        score_cov = np.array([[sc[0], sc[1]], [sc[1], sc[2]]])
        try:
            slope_inv = np.linalg.inv(slope)
        except np.linalg.LinAlgError:
            out.append(np.inf)
            continue
        var = float(np.trace(slope_inv @ score_cov @ slope_inv.T))
        out.append(var if np.isfinite(var) and var >= 0 else np.inf)
    return np.array(out)
