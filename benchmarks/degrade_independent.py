"""A second, independent degradation model for super-resolution tests and benchmarks (issue 17).

Written apart from :mod:`subpix_ros.core.render` (which renders with the
reconstruction's own assumptions: band-limited Fourier shift, a Gaussian on
the HR grid, full-pixel box) so that a method tuned to its own forward model
cannot look better than it is. What differs here:

* the scene is continuous: the HR crop interpolated (Lanczos-4,
  ``cv2.resize``) onto a grid ``oversample`` (8) times finer than the HR
  grid, i.e. ``8 p`` fine samples per LR pixel; an optional "roof" (a
  uniformly bright rotated rectangle, drawn analytically on the fine grid)
  puts a straight, truly sharp edge in view;
* optics and detector are integrated analytically over that fine grid: LR
  pixel i of frame n, per axis,

      y_n[i] = sum_j K(x_i - s_n - t_j) S[j] dt,
      K(x) = (Phi((x + a/2) / sigma) - Phi((x - a/2) / sigma)) / a

  with ``x_i`` the pixel centre and ``t_j`` the fine sample positions (LR
  px), ``s_n`` the frame's shift (content moves by +s_n), ``a`` the pixel
  fill factor (aperture width, 0.8-1.0 LR px; the model of the
  reconstruction assumes 1), ``sigma`` the Gaussian optics std (LR px),
  ``Phi`` the normal CDF: the Gaussian convolved with the aperture box, exact
  for any sub-pixel shift (no resampling of the scene); separable, applied
  as a banded gather per axis;
* Poisson-Gaussian noise: ``y = k Poisson(y / k) + N(0, sigma_r^2)``, the
  shot part and the read part each half the noise variance at the mean
  signal, scaled to a stated SNR ``20 log10(std(y_0) / sigma_total)``;
  8-bit rounding; optional JPEG compression (quality 90 by default);
* optional motion blur (the image moving by ``d = (du, dv)`` LR px during
  the exposure): the frame is the mean of ``J`` renders at the sub-positions
  ``s_n + t_j d``, ``t_j = (j + 1/2) / J - 1/2`` (one per fine sample of
  the path, ``J = ceil(8 p |d|)``), each integrated exactly as above: the
  scene integrated along the path on the fine grid, with no assumed PSF
  shape; ``s_n`` is the mid-exposure position.

Coordinates follow the project: LR pixel i of frame 0 covers output (HR)
pixels ``p i .. p i + p - 1``; the truth is the HR crop on that grid (inside
a roof: the area average of the analytic roof over each HR pixel).
Sign convention: a feature at (r, c) in frame 0 is at (r + u, c + v) in a
frame with shift (u, v).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import cv2
import numpy as np
from scipy import sparse
from scipy.special import ndtr

__all__ = ["Flight", "degrade", "shift_layout", "scene_crop", "ROOF_ANGLE_DEG"]

ROOF_ANGLE_DEG = (
    10.0  # roof edges this far from the pixel axes (slanted-edge friendly, like a real roof)
)


@dataclass
class Flight:
    """Frames rendered by :func:`degrade` with everything that made them."""

    frames: list  # uint8 LR frames (N), frame 0 the reference
    shifts: np.ndarray  # (N, 2) true (u, v), LR px, relative to frame 0
    truth: np.ndarray  # HR truth on frame 0's output grid, float64
    factor: int
    blur_sigma: float
    fill_factor: float
    snr_db: float
    noise_sigma: float  # total noise std at the mean signal (DN, before rounding)
    jpeg_quality: int | None
    roof_rois: list = field(default_factory=list)  # (x, y, w, h) LR px of frame 0 around roof edges


def shift_layout(
    kind: str, p: int, n: int | None = None, seed: int = 0
) -> list[tuple[float, float]]:
    """Shifts (LR px): ``"grid"`` the p x p k/p grid, ``"random"`` n uniform in [-1, 1)^2.

    The first shift is (0, 0) (the reference).
    """
    if kind == "grid":
        return [(a / p, b / p) for a in range(p) for b in range(p)]
    if kind == "random":
        rng = np.random.default_rng(seed)
        n = max(8, p * p) if n is None else n
        return [(0.0, 0.0)] + [tuple(float(x) for x in rng.uniform(-1, 1, 2)) for _ in range(n - 1)]
    raise ValueError(f"unknown shift layout {kind!r}")


def scene_crop(
    hr: np.ndarray, factor: int, lr: int, margin: int, offset: tuple[int, int] = (0, 0)
) -> np.ndarray:
    """Return the part of an HR image that :func:`degrade` needs for ``lr`` x ``lr`` LR frames."""
    n = (lr + 2 * margin) * factor
    r, c = offset
    out = np.asarray(hr, dtype=np.float64)[r : r + n, c : c + n]
    if out.shape != (n, n):
        raise ValueError(f"HR image too small: need {n}x{n} from offset {offset}, got {out.shape}")
    return out


def _axis_operator(
    n_lr: int,
    n_fine: int,
    ratio: int,
    margin: int,
    shift: float,
    sigma: float,
    fill: float,
    reach: int,
) -> sparse.csr_matrix:
    """One axis's banded operator (n_lr, n_fine): LR pixel i = weighted sum of fine samples."""
    sigma = max(float(sigma), 1e-4)
    centre = np.arange(n_lr) + margin - shift  # LR coordinate of the kernel centre per pixel
    first = np.floor((centre - reach + 0.5) * ratio - 0.5).astype(np.int64)
    idx = first[:, None] + np.arange(int(2 * reach * ratio) + 2)[None, :]
    if idx.min() < 0 or idx.max() >= n_fine:
        raise ValueError("margin too small for this blur and shift")
    t = (idx + 0.5) / ratio - 0.5  # fine sample positions, LR px
    x = centre[:, None] - t
    a = float(fill)
    w = (ndtr((x + a / 2) / sigma) - ndtr((x - a / 2) / sigma)) / a
    w /= w.sum(axis=1, keepdims=True)
    rows = np.repeat(np.arange(n_lr), idx.shape[1])
    return sparse.csr_matrix((w.ravel(), (rows, idx.ravel())), shape=(n_lr, n_fine))


def _roof_coverage(
    n_fine: int,
    ratio: int,
    centre: tuple[float, float],
    size: tuple[float, float],
    angle_deg: float,
) -> np.ndarray:
    """Fraction of each fine sample inside a rotated rectangle (LR px), 1-sample linear ramp."""
    t = (np.arange(n_fine, dtype=np.float32) + 0.5) / ratio - 0.5
    rr, cc = t[:, None] - centre[0], t[None, :] - centre[1]
    th = np.deg2rad(angle_deg)
    # rectangle axes: along (cos, sin) in (col, row) and its normal
    a = cc * np.cos(th) + rr * np.sin(th)
    b = -cc * np.sin(th) + rr * np.cos(th)
    half = 0.5 / ratio
    ca = np.clip((size[1] / 2 - np.abs(a)) / (2 * half) + 0.5, 0, 1)
    cb = np.clip((size[0] / 2 - np.abs(b)) / (2 * half) + 0.5, 0, 1)
    return (ca * cb).astype(np.float32)


def degrade(
    hr: np.ndarray,
    factor: int,
    shifts,
    blur_sigma: float,
    *,
    fill_factor: float = 1.0,
    snr_db: float = 40.0,
    jpeg_quality: int | None = None,
    roof: bool = False,
    seed: int = 0,
    margin: int = 6,
    oversample: int = 8,
    motion_blur: tuple[float, float] | None = None,
) -> Flight:
    """Render LR frames of an HR scene by the independent model of this module.

    Parameters
    ----------
    hr : (H, H) array, the HR scene; ``H = (lr + 2 margin) factor`` (see :func:`scene_crop`).
    factor : LR -> HR factor p (2..4).
    shifts : (N, 2) shifts (u, v), LR px; the first is normally (0, 0).
    blur_sigma : Gaussian optics std, LR px.
    fill_factor : pixel aperture width (LR px), 0 < a <= 1.
    snr_db : 20 log10(std(noise-free frame 0) / total noise std at the mean signal).
    jpeg_quality : JPEG-compress each 8-bit frame at this quality (None: no compression).
    roof : put a uniformly bright rotated rectangle (sharp straight edges) in the scene centre.
    seed : noise seed. margin : LR px cut from every side (the kernels' reach). oversample : fine
        samples per HR px.
    motion_blur : (du, dv) LR px, the image motion during each frame's exposure (the same for
        every frame, centred on its shift); None or (0, 0): none (the renders are then
        bit-identical to those without the argument).

    Returns
    -------
    Flight
    """
    hr = np.asarray(hr, dtype=np.float64)
    p, ratio = int(factor), int(oversample) * int(factor)
    n_hr = hr.shape[0]
    if hr.shape[0] != hr.shape[1] or n_hr % p:
        raise ValueError("hr must be square with a side divisible by factor")
    n_lr_full = n_hr // p
    n_lr = n_lr_full - 2 * margin
    sh = np.asarray(shifts, dtype=np.float64).reshape(-1, 2)
    d = np.zeros(2) if motion_blur is None else np.asarray(motion_blur, dtype=np.float64)
    n_sub = int(np.ceil(ratio * np.hypot(*d)))
    t_sub = (np.arange(n_sub) + 0.5) / max(n_sub, 1) - 0.5  # exposure sub-positions (fractions)
    reach = int(np.ceil(0.5 + 4.5 * blur_sigma + 0.5))
    if np.abs(sh).max() + np.abs(d).max() / 2 + reach + 1 > margin:
        raise ValueError(
            f"margin {margin} too small for shifts up to {np.abs(sh).max():.2f} px and blur "
            f"{blur_sigma}"
        )
    fine = cv2.resize(hr, None, fx=oversample, fy=oversample, interpolation=cv2.INTER_LANCZOS4)
    n_fine = fine.shape[0]
    truth = hr.copy()
    rois: list[tuple[int, int, int, int]] = []
    if roof:
        c = n_lr_full / 2.0 - 0.5
        size = (0.3 * n_lr, 0.38 * n_lr)  # LR px (across, along)
        level = 235.0 if hr.mean() < 128 else 20.0
        cov = _roof_coverage(n_fine, ratio, (c, c), size, ROOF_ANGLE_DEG)
        fine = fine * (1 - cov) + level * cov
        cov_hr = cv2.resize(cov, (n_hr, n_hr), interpolation=cv2.INTER_AREA).astype(np.float64)
        truth = truth * (1 - cov_hr) + level * cov_hr
        rois = _roof_rois(c - margin, size, n_lr)
    m = margin * p
    truth = truth[m : m + n_lr * p, m : m + n_lr * p]
    rng = np.random.default_rng(seed)
    clean = []
    for u, v in sh:  # frames
        if n_sub == 0:
            ky = _axis_operator(n_lr, n_fine, ratio, margin, u, blur_sigma, fill_factor, reach)
            kx = _axis_operator(n_lr, n_fine, ratio, margin, v, blur_sigma, fill_factor, reach)
            rows = ky @ fine  # (n_lr, n_fine)
            clean.append(np.asarray((kx @ rows.T).T, dtype=np.float64))
            continue
        acc = np.zeros((n_lr, n_lr))
        for t in t_sub:  # sub-positions along the path during the exposure
            ky = _axis_operator(
                n_lr, n_fine, ratio, margin, u + t * d[0], blur_sigma, fill_factor, reach
            )
            kx = _axis_operator(
                n_lr, n_fine, ratio, margin, v + t * d[1], blur_sigma, fill_factor, reach
            )
            acc += np.asarray((kx @ (ky @ fine).T).T, dtype=np.float64)
        clean.append(acc / n_sub)
    mean = float(np.mean(clean[0]))
    sig_tot = float(np.std(clean[0])) / 10.0 ** (snr_db / 20.0)
    k = 0.5 * sig_tot**2 / max(mean, 1e-6)  # DN per electron: shot variance k*mean = half the total
    sig_r = np.sqrt(0.5) * sig_tot
    frames = []
    for y in clean:  # noise, 8 bit, JPEG
        lam = np.maximum(y, 0) / k
        if lam.max() < 1e7:
            shot = k * rng.poisson(lam)
        else:  # (very high SNR) the Poisson law's normal limit
            shot = y + np.sqrt(k * np.maximum(y, 0)) * rng.standard_normal(y.shape)
        noisy = shot + rng.normal(0.0, sig_r, y.shape)
        f8 = np.clip(np.rint(noisy), 0, 255).astype(np.uint8)
        if jpeg_quality is not None:
            ok, buf = cv2.imencode(".jpg", f8, [cv2.IMWRITE_JPEG_QUALITY, int(jpeg_quality)])
            f8 = cv2.imdecode(buf, cv2.IMREAD_GRAYSCALE)
        frames.append(f8)
    return Flight(
        frames=frames,
        shifts=sh - sh[0],
        truth=truth,
        factor=p,
        blur_sigma=float(blur_sigma),
        fill_factor=float(fill_factor),
        snr_db=float(snr_db),
        noise_sigma=sig_tot,
        jpeg_quality=jpeg_quality,
        roof_rois=rois,
    )


def _roof_rois(c: float, size: tuple[float, float], n_lr: int) -> list[tuple[int, int, int, int]]:
    """ROIs (x, y, w, h) in frame-0 LR px around the middle of each of the roof's four edges."""
    th = np.deg2rad(ROOF_ANGLE_DEG)
    along, normal = (
        np.array([np.sin(th), np.cos(th)]),
        np.array([np.cos(th), -np.sin(th)]),
    )  # (row, col)
    half = int(min(size) * 0.4)
    out = []
    for sgn in (1, -1):
        for d, s in ((normal, size[0]), (along, size[1])):
            r, cc = np.array([c, c]) + sgn * d * s / 2
            x0, y0 = int(round(cc - half)), int(round(r - half))
            if 0 <= x0 and 0 <= y0 and x0 + 2 * half <= n_lr and y0 + 2 * half <= n_lr:
                out.append((x0, y0, 2 * half, 2 * half))
    return out
