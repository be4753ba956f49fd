"""Physical rendering of low-resolution frames with exactly known sub-pixel shifts.

This is the forward model used to make ground truth for tests, benchmarks and
the rendered ``subpixel`` sample flight: a sharp high-resolution (HR) scene is

1. shifted by a known amount (band-limited Fourier shift, exact for any
   fraction of a pixel),
2. blurred by the optics (a Gaussian point-spread function, sigma given in
   low-resolution pixels),
3. integrated over the detector pixel: each low-resolution (LR) pixel is the
   mean of a ``factor x factor`` block of HR sub-pixels (METHODS.md B, eq. 3,
   divided by p*q so intensities keep their scale),
4. given Gaussian read noise and quantised to 8 bit (optional).

Conventions (used throughout subpix_ros):

* Shifts are ``(u, v)`` = (rows, columns) in LR pixels. A frame rendered with
  shift ``(u, v)`` shows the scene content moved by ``(u, v)`` relative to the
  frame rendered with ``(0, 0)``: a feature at (r, c) in the reference frame
  appears at (r + u, c + v) in the moving frame.
* Output grid: LR pixel ``i`` of the unshifted frame covers HR pixels
  ``factor*i .. factor*i + factor - 1`` of the returned truth.

References
----------
.. [1] S. A. Stankevich, S. V. Shklyar, M. S. Lubskyi, "Increasing the spatial
   resolution of aerial imaging by sub-pixel image registration", 2013
   (docs/METHODS.md B, eq. 3).
.. [2] ISO 12233, "Photography -- Electronic still picture imaging --
   Resolution and spatial frequency responses" (slanted-edge target).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np

__all__ = [
    "fourier_shift_blur",
    "box_integrate",
    "render_frame",
    "render_sequence",
    "RenderedSequence",
    "noise_sigma_for_snr",
    "slanted_edge_scene",
]


def fourier_shift_blur(
    image: np.ndarray,
    shift: tuple[float, float] = (0.0, 0.0),
    blur_sigma: float = 0.0,
    pad: int = 64,
) -> np.ndarray:
    """Shift an image's content by a known amount and blur it.

    Parameters
    ----------
    image : ndarray
        2-D image.
    shift : tuple of float
        ``(u, v)``: rows, columns; pixels.
    blur_sigma : float
        Gaussian blur sigma, pixels (0: none).
    pad : int
        Reflect padding, pixels: must exceed ``|shift| + 4 sigma`` so the
        periodic wrap of the FFT stays away from the returned area.

    Returns
    -------
    ndarray of float64
        The shifted, blurred image, same shape.

    Raises
    ------
    ValueError
        If ``pad`` is too small for the shift and blur.

    Notes
    -----
    ``I'(x) = (G_sigma * I)(x - shift)`` in the Fourier domain:
    ``F[I'](k) = F[I](k) exp(-2 pi i k.shift) exp(-2 pi^2 sigma^2 |k|^2)`` with
    ``k`` in cycles/pixel.
    """
    img = np.asarray(image, dtype=np.float64)
    if abs(shift[0]) + 4 * blur_sigma >= pad or abs(shift[1]) + 4 * blur_sigma >= pad:
        raise ValueError(f"pad={pad} too small for shift={shift} and blur_sigma={blur_sigma}")
    padded = np.pad(img, pad, mode="reflect")
    h, w = padded.shape
    ky = np.fft.fftfreq(h)
    kx = np.fft.rfftfreq(w)
    ty = np.exp(-2j * np.pi * ky * shift[0])
    tx = np.exp(-2j * np.pi * kx * shift[1])
    # A Nyquist component cos(pi x) shifted by d, sampled at integers, is
    # cos(pi d) cos(pi x): its transfer factor is real.
    if h % 2 == 0:
        ty[h // 2] = np.cos(np.pi * shift[0])
    if w % 2 == 0:
        tx[-1] = np.cos(np.pi * shift[1])
    transfer = ty[:, None] * tx[None, :]
    if blur_sigma > 0:
        transfer = transfer * np.exp(
            -2.0 * np.pi**2 * blur_sigma**2 * (ky[:, None] ** 2 + kx[None, :] ** 2)
        )
    out = np.fft.irfft2(np.fft.rfft2(padded) * transfer, s=(h, w))
    return out[pad:-pad, pad:-pad]


def box_integrate(image: np.ndarray, factor: int) -> np.ndarray:
    """Integrate over detector pixels (METHODS.md B, eq. 3, as a mean).

    Parameters
    ----------
    image : ndarray
        HR image.
    factor : int
        Sub-pixels per detector pixel along each axis.

    Returns
    -------
    ndarray of float64
        ``y[i, j] = mean(x[factor*i : factor*(i+1), factor*j : factor*(j+1)])``;
        trailing rows/columns that do not fill a block are dropped.

    Notes
    -----
    Eq. (3) of [1]_ sums each block; the mean keeps intensities on their scale.
    """
    h, w = image.shape[0] // factor, image.shape[1] // factor
    x = np.asarray(image, dtype=np.float64)[: h * factor, : w * factor]
    return x.reshape(h, factor, w, factor).mean(axis=(1, 3))


def noise_sigma_for_snr(signal: np.ndarray, snr_db: float) -> float:
    """Return the noise standard deviation giving ``snr_db = 20 log10(std(signal) / sigma)``."""
    return float(np.std(signal) / 10.0 ** (snr_db / 20.0))


def render_frame(
    hr: np.ndarray,
    factor: int,
    shift: tuple[float, float] = (0.0, 0.0),
    blur_sigma: float = 0.4,
    noise_sigma: float = 0.0,
    rng: np.random.Generator | None = None,
    quantize: bool = True,
    pad: int = 64,
) -> np.ndarray:
    """Render one LR frame from an HR scene (the steps of the module docstring).

    Parameters
    ----------
    hr : ndarray
        Sharp HR scene.
    factor : int
        HR pixels per LR pixel along each axis.
    shift : tuple of float
        ``(u, v)``, LR pixels.
    blur_sigma : float
        Optics blur sigma, LR pixels.
    noise_sigma : float
        Gaussian read noise, output digital numbers (DN).
    rng : numpy.random.Generator or None
        Noise source (default: a fresh one).
    quantize : bool
        Round and clip to uint8 (else float64).
    pad : int
        Reflect padding for the Fourier shift, HR pixels.

    Returns
    -------
    ndarray
        The LR frame, uint8 with ``quantize``, else float64.
    """
    hr_shift = (shift[0] * factor, shift[1] * factor)
    blurred = fourier_shift_blur(hr, hr_shift, blur_sigma * factor, pad=pad)
    lr = box_integrate(blurred, factor)
    if noise_sigma > 0:
        rng = rng if rng is not None else np.random.default_rng()
        lr = lr + rng.normal(0.0, noise_sigma, lr.shape)
    if quantize:
        return np.clip(np.rint(lr), 0, 255).astype(np.uint8)
    return lr


@dataclass
class RenderedSequence:
    """LR frames with their true shifts and the HR truths on the output grid.

    Parameters
    ----------
    frames : list of ndarray
        The LR frames.
    shifts : ndarray, shape (N, 2)
        True (u, v) per frame, LR px, relative to frame 0.
    truth : ndarray
        Sharp HR truth (float64), ``factor`` times the LR shape.
    truth_blurred : ndarray
        HR truth through the optics blur only.
    factor : int
        HR pixels per LR pixel.
    blur_sigma : float
        Optics blur sigma, LR pixels.
    noise_sigma : float
        Read noise, DN.
    """

    frames: list[np.ndarray]
    shifts: np.ndarray
    truth: np.ndarray
    truth_blurred: np.ndarray
    factor: int
    blur_sigma: float
    noise_sigma: float


def render_sequence(
    hr: np.ndarray,
    factor: int,
    shifts: Sequence[tuple[float, float]],
    blur_sigma: float = 0.4,
    noise_sigma: float = 0.0,
    snr_db: float | None = None,
    seed: int = 0,
    margin: int = 8,
    quantize: bool = True,
) -> RenderedSequence:
    """Render N LR frames of an HR scene with the given shifts.

    Parameters
    ----------
    hr : ndarray
        Sharp HR scene.
    factor : int
        HR pixels per LR pixel (>= 1).
    shifts : sequence of tuple of float
        ``(u, v)`` per frame, LR px; the first is normally (0, 0): frame 0 is
        the reference whose grid defines the truth.
    blur_sigma : float
        Optics blur sigma, LR pixels.
    noise_sigma : float
        Read noise, DN.
    snr_db : float or None
        If given, overrides ``noise_sigma`` with
        ``noise_sigma_for_snr(reference frame, snr_db)``.
    seed : int
        Seed of the noise.
    margin : int
        LR pixels cut from every side after rendering (so no wrap or padding
        artefact reaches the frames); the truths are cut identically.
    quantize : bool
        Round and clip the frames to uint8.

    Returns
    -------
    RenderedSequence
        The frames, their shifts and the truths.

    Raises
    ------
    ValueError
        If ``factor < 1``.
    """
    if factor < 1:
        raise ValueError("factor must be >= 1")
    rng = np.random.default_rng(seed)
    hr = np.asarray(hr, dtype=np.float64)
    h, w = (hr.shape[0] // factor) * factor, (hr.shape[1] // factor) * factor
    hr = hr[:h, :w]
    if snr_db is not None:
        ref = box_integrate(fourier_shift_blur(hr, (0, 0), blur_sigma * factor), factor)
        noise_sigma = noise_sigma_for_snr(ref, snr_db)
    pad = (
        int(
            np.ceil(
                max(max(abs(s[0]), abs(s[1])) for s in shifts) * factor + 4 * blur_sigma * factor
            )
        )
        + 32
    )
    frames = []
    for s in shifts:
        lr = render_frame(hr, factor, s, blur_sigma, noise_sigma, rng, quantize, pad=pad)
        frames.append(lr[margin:-margin, margin:-margin] if margin else lr)
    m = margin * factor
    truth_blurred = fourier_shift_blur(hr, (0, 0), blur_sigma * factor, pad=pad)
    sl = (slice(m, h - m), slice(m, w - m))
    return RenderedSequence(
        frames=frames,
        shifts=np.asarray(shifts, dtype=np.float64).reshape(-1, 2),
        truth=hr[sl].copy(),
        truth_blurred=truth_blurred[sl],
        factor=factor,
        blur_sigma=blur_sigma,
        noise_sigma=float(noise_sigma),
    )


def slanted_edge_scene(
    base: np.ndarray,
    factor: int,
    lr: int,
    angle_deg: float = 5.0,
    margin: int = 8,
    levels: tuple[float, float] = (50.0, 210.0),
) -> tuple[np.ndarray, tuple[int, int, int, int]]:
    """Paste a slanted-edge target (ISO 12233 style [2]_) in the middle of a real scene.

    Parameters
    ----------
    base : ndarray
        HR scene; its first ``(lr + 2 margin) * factor`` rows/columns are used.
    factor : int
        HR pixels per LR pixel.
    lr : int
        LR frame side, px (before the margin is cut).
    angle_deg : float
        Tilt of the edge from the columns, degrees.
    margin : int
        The ``margin`` that :func:`render_sequence` will cut, LR px.
    levels : tuple of float
        Dark and bright sides, DN.

    Returns
    -------
    scene : ndarray of float64
        The scene with a square half its size holding the straight edge,
        area-sampled 4x4 per pixel.
    roi : tuple of int
        Edge ROI ``(x, y, w, h)`` in LR px of frames rendered from the scene by
        :func:`render_sequence` with the same ``factor`` and ``margin``.
    """
    n = (lr + 2 * margin) * factor
    scene = np.asarray(base, dtype=np.float64)[:n, :n].copy()
    th = np.deg2rad(angle_deg)
    ss = 4
    sub = (np.arange(ss) + 0.5) / ss - 0.5
    r = np.arange(n)[:, None, None, None] + sub[None, None, :, None] - n / 2
    c = np.arange(n)[None, :, None, None] + sub[None, None, None, :] - n / 2
    edge = levels[0] + (levels[1] - levels[0]) * ((c * np.cos(th) - r * np.sin(th)) > 0).mean(
        axis=(2, 3)
    )
    q0, q1 = n // 4, 3 * n // 4
    scene[q0:q1, q0:q1] = edge[q0:q1, q0:q1]
    x0 = q0 // factor - margin + 4
    side = (q1 - q0) // factor - 8
    return scene, (x0, x0, side, side)
