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
    """Shift an image's content by ``shift`` (rows, cols; pixels) and blur it.

    Implements ``I'(x) = (G_sigma * I)(x - shift)`` in the Fourier domain:
    ``F[I'](k) = F[I](k) exp(-2 pi i k.shift) exp(-2 pi^2 sigma^2 |k|^2)`` with
    ``k`` in cycles/pixel. The image is reflect-padded by ``pad`` pixels first
    so the periodic wrap of the FFT stays away from the returned area (the
    ``pad`` must exceed ``|shift| + 4 sigma``). float64 in, float64 out.
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
    """Detector pixel integration (METHODS.md B, eq. 3, as a mean).

    ``y[i, j] = mean(x[factor*i : factor*(i+1), factor*j : factor*(j+1)])``.
    Trailing rows/columns that do not fill a block are dropped.
    """
    h, w = image.shape[0] // factor, image.shape[1] // factor
    x = np.asarray(image, dtype=np.float64)[: h * factor, : w * factor]
    return x.reshape(h, factor, w, factor).mean(axis=(1, 3))


def noise_sigma_for_snr(signal: np.ndarray, snr_db: float) -> float:
    """Noise standard deviation giving ``snr_db = 20 log10(std(signal) / sigma)``."""
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
    """Render one LR frame from an HR scene (see module docstring).

    ``shift`` and ``blur_sigma`` are in LR pixels; ``noise_sigma`` in output
    digital numbers (DN). With ``quantize`` the result is rounded and clipped
    to uint8, else float64.
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
    """LR frames with their true shifts and the HR truths on the output grid."""

    frames: list[np.ndarray]
    shifts: np.ndarray  # (N, 2) true (u, v) per frame, LR px, relative to frame 0
    truth: np.ndarray  # sharp HR truth (float64), factor * LR shape
    truth_blurred: np.ndarray  # HR truth through the optics blur only
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
    """Render N LR frames of ``hr`` with the given shifts (LR px, rows/cols).

    The first shift is normally (0, 0): frame 0 is the reference whose grid
    defines the truth. ``margin`` LR pixels are cut from every side after
    rendering (so no wrap or padding artefact reaches the frames); the truths
    are cut identically. ``snr_db``, if given, overrides ``noise_sigma`` with
    ``noise_sigma_for_snr(reference frame, snr_db)``.
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
    """A real scene with a slanted-edge target (ISO 12233 style) pasted in its middle.

    The first ``(lr + 2 margin) * factor`` rows/columns of ``base`` (HR px)
    get a square half their size holding a straight edge tilted ``angle_deg``
    from the columns, dark ``levels[0]`` / bright ``levels[1]`` DN, area-sampled
    4x4 per pixel. Returns the float64 scene and the edge ROI ``(x, y, w, h)``
    in LR px of frames rendered from it by :func:`render_sequence` with the
    same ``factor`` and ``margin``.
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
