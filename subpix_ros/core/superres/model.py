"""Observation model of super-resolution (METHODS.md B, eq. 3) and its adjoint.

Two views of the same physics:

* The paper's *interleaved* form (eq. 3 / eq. 5): on the high-resolution (HR)
  sub-pixel grid, ``y[k, l] = sum_{a<p, b<q} x[k+a, l+b]`` — every p x q box of
  sub-pixels summed ("valid" box sum, ``T1 X T2 = Y``). Frames shifted by
  whole sub-pixels fill the interleaved ``y``. :func:`box_sum` and
  :func:`box_sum_adjoint` are ``X -> T1 X T2`` and ``Y -> T1^T Y T2^T``.

* The *frame* form used by the reconstruction: frame ``n`` is
  ``y_n = D_pq S_n B x`` — optics blur ``B`` (Gaussian, sigma in LR pixels),
  resampling ``S_n`` of the HR image onto frame n's own sub-pixel grid (any
  translation or homography, bilinear), and detector integration ``D_pq``
  (mean of each p x q block = eq. 3 divided by p*q, so intensities keep their
  scale). :class:`FrameOperator` applies ``A_n`` and its exact adjoint
  ``A_n^T`` to arrays; it is what the conjugate-gradient solver uses.

Conventions (project-wide): shifts ``(u, v)`` = (rows, cols) in LR pixels;
content at (r, c) in the reference frame appears at (r+u, c+v) in frame n.
Homographies map reference-frame LR pixel coordinates ``(x=col, y=row, 1)``
to frame-n LR pixel coordinates (pixel centres at integers); a translation
``(u, v)`` is ``[[1, 0, v], [0, 1, u], [0, 0, 1]]``. Output grid: LR pixel i
of the reference covers HR pixels ``p*i .. p*i+p-1``; HR pixel k has its
centre at LR coordinate ``(k + 0.5)/p - 0.5``.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import cv2
import numpy as np

__all__ = [
    "box_sum",
    "box_sum_adjoint",
    "gaussian_kernel",
    "blur",
    "decimate_mean",
    "decimate_mean_adjoint",
    "translation_homography",
    "FrameOperator",
    "frame_transfer_1d",
    "motion_transfer",
    "motion_filter",
    "motion_blur_vector",
]


def box_sum(x: np.ndarray, p: int, q: int) -> np.ndarray:
    """Apply eq. 3/5, ``Y = T1 X T2``: ``y[k, l] = sum_{a<p, b<q} x[k+a, l+b]``.

    Parameters
    ----------
    x : numpy.ndarray
        (n_x + p - 1, n_y + q - 1) HR sub-pixels.
    p, q : int
        Box size along rows and columns.

    Returns
    -------
    numpy.ndarray
        (n_x, n_y) "valid" box sums (sums, not means, as in the paper), by cumulative sums.
    """
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[0] < p or x.shape[1] < q:
        raise ValueError(f"box_sum needs a 2-D array of at least {p}x{q}, got {x.shape}")
    c = np.zeros((x.shape[0] + 1, x.shape[1] + 1))
    c[1:, 1:] = x.cumsum(0).cumsum(1)
    return c[p:, q:] - c[:-p, q:] - c[p:, :-q] + c[:-p, :-q]


def box_sum_adjoint(y: np.ndarray, p: int, q: int) -> np.ndarray:
    """Apply the adjoint of :func:`box_sum`, ``T1^T Y T2^T`` ("full" box sum).

    Returns an (n_x + p - 1, n_y + q - 1) array for an (n_x, n_y) ``y``.
    """
    y = np.asarray(y, dtype=np.float64)
    padded = np.pad(y, ((p - 1, p - 1), (q - 1, q - 1)))
    return box_sum(padded, p, q)


def gaussian_kernel(sigma: float, radius: int | None = None) -> np.ndarray:
    """Return the normalised 1-D Gaussian ``g[k] ~ exp(-k^2 / (2 sigma^2))``.

    Parameters
    ----------
    sigma : float
        Std in samples; ``[1]`` for sigma <= 0.
    radius : int, optional
        Half-length (default ``ceil(4 sigma)``).

    Returns
    -------
    numpy.ndarray
        float64 taps, summing to 1.
    """
    if sigma <= 0:
        return np.ones(1)
    r = int(np.ceil(4.0 * sigma)) if radius is None else radius
    k = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-0.5 * (k / sigma) ** 2)
    return g / g.sum()


def blur(x: np.ndarray, sigma: float) -> np.ndarray:
    """Blur with a separable Gaussian (sigma in pixels of ``x``) and a zero border.

    The kernel is symmetric and the border constant zero, so the operator is self-adjoint
    (as the conjugate-gradient solver needs).
    """
    if sigma <= 0:
        return np.asarray(x, dtype=np.float64)
    g = gaussian_kernel(sigma)
    return cv2.sepFilter2D(
        np.asarray(x, dtype=np.float64), cv2.CV_64F, g, g, borderType=cv2.BORDER_CONSTANT
    )


def motion_blur_vector(motion_blur) -> tuple[float, float]:
    """Return a ``motion_blur`` setting as a float pair ``(du, dv)`` (LR px); None is (0, 0).

    Parameters
    ----------
    motion_blur : None or (float, float)
        The image motion during the exposure (rows, cols; LR px).

    Returns
    -------
    (float, float)
        ``(du, dv)``.

    Raises
    ------
    ValueError
        If it is not two finite numbers.
    """
    if motion_blur is None:
        return (0.0, 0.0)
    d = np.asarray(motion_blur, dtype=np.float64).ravel()
    if d.shape != (2,) or not np.isfinite(d).all():
        raise ValueError(
            f"motion_blur must be two finite numbers (du, dv) in LR px, got {motion_blur}"
        )
    return (float(d[0]), float(d[1]))


def motion_transfer(fy: np.ndarray, fx: np.ndarray, p: int, motion_blur) -> np.ndarray:
    """Return the transfer ``M(f)`` of the motion blur at HR frequencies ``(fy, fx)``.

    Parameters
    ----------
    fy, fx : numpy.ndarray
        Signed HR frequencies (cycles / HR px) along rows and columns; broadcast together.
    p : int
        Factor (HR px per LR px).
    motion_blur : (float, float)
        ``d = (du, dv)``: the image motion during the exposure (LR px, rows and cols).

    Returns
    -------
    numpy.ndarray
        float64, real: ``M = sinc(p (fy du + fx dv))`` (numpy's ``sinc(x) = sin(pi x) / (pi x)``).

    Notes
    -----
    The PSF of a uniform motion over the exposure is a 1-D box of length ``|d|`` along ``d``,
    centred on the mid-exposure position (the frame's shift): its Fourier transform is
    ``M(nu) = sinc(nu . d)`` with ``nu = p f`` in cycles / LR px. It is real and even, so the
    sign of ``d`` does not matter, and common to every frame of a set (one velocity), so like
    the optics blur it commutes with the shifts. It is separable only when ``d`` lies along
    an axis.
    """
    du, dv = motion_blur
    return np.sinc(p * (np.asarray(fy) * du + np.asarray(fx) * dv))


@functools.lru_cache(maxsize=8)
def _motion_fft(
    shape: tuple[int, int], du_hr: float, dv_hr: float
) -> tuple[int, tuple[int, int], np.ndarray]:
    """Return ``(pad, padded shape, transfer)`` of :func:`motion_filter` (cached, read-only)."""
    pad = int(np.ceil(np.hypot(du_hr, dv_hr) / 2.0)) + 2
    hp = cv2.getOptimalDFTSize(shape[0] + 2 * pad)
    wp = cv2.getOptimalDFTSize(shape[1] + 2 * pad)
    m = motion_transfer(
        np.fft.fftfreq(hp)[:, None], np.fft.rfftfreq(wp)[None, :], 1, (du_hr, dv_hr)
    )
    m.flags.writeable = False
    return pad, (hp, wp), m


def motion_filter(x: np.ndarray, du_hr: float, dv_hr: float) -> np.ndarray:
    """Blur by a motion of ``(du_hr, dv_hr)`` pixels of ``x`` (rows, cols), zero border.

    Parameters
    ----------
    x : numpy.ndarray
        2-D image (float).
    du_hr, dv_hr : float
        Motion during the exposure along rows and columns (pixels of ``x``).

    Returns
    -------
    numpy.ndarray
        float64, the shape of ``x``; ``x`` itself for no motion.

    Notes
    -----
    ``x`` is zero-padded by ``ceil(|d| / 2) + 2`` px, multiplied in the DFT by the exact
    transfer ``sinc(f . d)`` (:func:`motion_transfer`, f in cycles / px: the same as the
    Fourier solve's) and cropped back: ``P^T F^-1 M F P`` with M real and even is symmetric,
    so the operator is self-adjoint, as the conjugate-gradient solver needs.
    """
    if du_hr == 0.0 and dv_hr == 0.0:
        return x
    h, w = x.shape
    pad, (hp, wp), m = _motion_fft((h, w), float(du_hr), float(dv_hr))
    buf = np.zeros((hp, wp))
    buf[pad : pad + h, pad : pad + w] = x
    out = np.fft.irfft2(np.fft.rfft2(buf) * m, s=(hp, wp))
    return out[pad : pad + h, pad : pad + w]


def decimate_mean(z: np.ndarray, p: int, q: int) -> np.ndarray:
    """Apply detector integration ``D_pq``: the mean of each p x q block (eq. 3 / (p q))."""
    h, w = z.shape[0] // p, z.shape[1] // q
    return z[: h * p, : w * q].reshape(h, p, w, q).mean(axis=(1, 3))


def decimate_mean_adjoint(y: np.ndarray, p: int, q: int) -> np.ndarray:
    """Apply the adjoint of :func:`decimate_mean`: each value spread over its block, / (p q)."""
    return np.repeat(np.repeat(np.asarray(y, dtype=np.float64), p, axis=0), q, axis=1) / (p * q)


def translation_homography(u: float, v: float) -> np.ndarray:
    """Return the homography of a pure shift (u rows, v cols), project convention."""
    return np.array([[1.0, 0.0, v], [0.0, 1.0, u], [0.0, 0.0, 1.0]])


@dataclass
class FrameOperator:
    """The frame operator ``A_n = D_pq S_n L B``: HR image (reference grid) -> LR frame n.

    Parameters
    ----------
    homography : numpy.ndarray
        (3, 3) reference LR pixel coordinates -> frame-n LR pixel coordinates.
    lr_shape : (int, int)
        Frame n's shape.
    hr_shape : (int, int)
        The HR grid's shape.
    p, q : int
        Factors along rows and columns.
    blur_sigma : float
        Optics blur std (LR px).
    motion_blur : (float, float), optional
        Image motion during the exposure ``d = (du, dv)`` (LR px, rows and cols; default
        none): ``L`` is the motion blur of ``(p du, q dv)`` HR px (:func:`motion_filter`,
        the exact ``sinc`` transfer) applied on the HR grid after the optics blur ``B``. On
        the reference grid: exact for translations, an approximation for homographies far
        from one.

    Notes
    -----
    Sub-pixels of frame n whose scene position falls outside the HR grid (or within
    ``3 blur_sigma max(p, q)`` HR px, plus half the motion's length and 1 px, of its edge,
    where the zero-border blur is wrong) are invalid; :attr:`valid` marks the LR pixels all
    of whose sub-pixels are valid.
    Resampling is bilinear (4 taps per sub-pixel), its adjoint a weighted scatter
    (``np.bincount``).
    """

    homography: np.ndarray
    lr_shape: tuple[int, int]
    hr_shape: tuple[int, int]
    p: int
    q: int
    blur_sigma: float = 0.4  # LR pixels
    motion_blur: tuple[float, float] = (0.0, 0.0)  # LR pixels (rows, cols)
    _motion_hr: tuple[float, float] = field(init=False, repr=False)
    _idx: np.ndarray = field(init=False, repr=False)
    _wts: np.ndarray = field(init=False, repr=False)
    valid: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        """Precompute the bilinear taps and weights of every sub-pixel, and :attr:`valid`."""
        p, q = self.p, self.q
        h, w = self.lr_shape
        hh, hw = self.hr_shape
        sub_r = (np.arange(h * p) + 0.5) / p - 0.5  # frame-n LR coordinates of sub-pixel centres
        sub_c = (np.arange(w * q) + 0.5) / q - 0.5
        cc, rr = np.meshgrid(sub_c, sub_r)
        hinv = np.linalg.inv(np.asarray(self.homography, dtype=np.float64))
        den = hinv[2, 0] * cc + hinv[2, 1] * rr + hinv[2, 2]
        x0 = (hinv[0, 0] * cc + hinv[0, 1] * rr + hinv[0, 2]) / den  # reference LR coords
        y0 = (hinv[1, 0] * cc + hinv[1, 1] * rr + hinv[1, 2]) / den
        hr_r = p * (y0 + 0.5) - 0.5  # HR index coordinates
        hr_c = q * (x0 + 0.5) - 0.5
        du, dv = motion_blur_vector(self.motion_blur)
        self._motion_hr = (p * du, q * dv)
        border = int(np.ceil(3.0 * self.blur_sigma * max(p, q)))
        if (du, dv) != (0.0, 0.0):
            border += int(np.ceil(np.hypot(*self._motion_hr) / 2.0)) + 1
        ok = (
            (hr_r >= border)
            & (hr_r <= hh - 1 - border)
            & (hr_c >= border)
            & (hr_c <= hw - 1 - border)
        )
        r0 = np.clip(np.floor(hr_r), 0, hh - 2).astype(np.int64)
        c0 = np.clip(np.floor(hr_c), 0, hw - 2).astype(np.int64)
        fr = np.clip(hr_r - r0, 0.0, 1.0)
        fc = np.clip(hr_c - c0, 0.0, 1.0)
        base = r0 * hw + c0
        self._idx = np.stack([base, base + 1, base + hw, base + hw + 1]).reshape(4, -1)
        wts = np.stack([(1 - fr) * (1 - fc), (1 - fr) * fc, fr * (1 - fc), fr * fc]) * ok
        self._wts = wts.reshape(4, -1)
        self.valid = decimate_mean(ok.astype(np.float64), p, q) > 1.0 - 1e-9

    def forward(self, x: np.ndarray) -> np.ndarray:
        """Apply ``A_n x``: HR image (hr_shape) -> LR frame (lr_shape), invalid pixels 0."""
        bx = motion_filter(blur(x, self.blur_sigma * self.p), *self._motion_hr).ravel()
        sub = (
            (bx[self._idx] * self._wts)
            .sum(axis=0)
            .reshape(self.lr_shape[0] * self.p, self.lr_shape[1] * self.q)
        )
        return decimate_mean(sub, self.p, self.q) * self.valid

    def adjoint(self, y: np.ndarray) -> np.ndarray:
        """Apply ``A_n^T y``: LR frame -> HR image; the exact adjoint of :meth:`forward`."""
        sub = decimate_mean_adjoint(
            np.asarray(y, dtype=np.float64) * self.valid, self.p, self.q
        ).ravel()
        n = self.hr_shape[0] * self.hr_shape[1]
        acc = np.bincount(
            self._idx.ravel(), weights=(self._wts * sub[None, :]).ravel(), minlength=n
        )
        return blur(
            motion_filter(acc.reshape(self.hr_shape), *self._motion_hr), self.blur_sigma * self.p
        )


def frame_transfer_1d(
    n_lr: int,
    p: int,
    shift: float,
    blur_sigma: float,
    shift_var: float = 0.0,
    pixel_fill: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Return the per-axis Fourier transfer of eq. 3 with blur and shift, folded onto LR bins.

    Parameters
    ----------
    n_lr : int
        LR DFT length (the HR one is ``p n_lr``).
    p : int
        Factor.
    shift : float
        Frame shift (LR px).
    blur_sigma : float
        Optics blur std (LR px).
    shift_var : float, optional
        Variance of a Gaussian shift error (LR px^2).
    pixel_fill : float, optional
        The pixel aperture's width ``w`` (LR px, the fill factor; default 1: the discrete
        mean over the block's p HR pixels).

    Returns
    -------
    a : numpy.ndarray
        complex (p, n_lr): ``Y[k] = sum_m a[m, k] X[K_m]``.
    f : numpy.ndarray
        (p, n_lr) signed HR frequency of ``K_m`` (cycles / HR px).

    Notes
    -----
    LR bin ``k`` receives the p aliased HR bins ``K_m = k + m n_lr`` (m = 0..p-1)::

        a[m, k] = (1/p) Hbox(f) G(f) exp(-2 pi i f s) exp(-2 pi^2 f^2 var_s)

    with ``Hbox(f) = (1/p) sum_{a<p} exp(2 pi i f a)`` (mean over the block that starts at
    HR pixel p i), ``G(f) = exp(-2 pi^2 (p sigma)^2 f^2)`` the optics, ``s = p shift`` HR px
    and ``var_s = p^2 shift_var`` (expected transfer under a Gaussian shift error, METHODS
    eq. 9 with registration noise). The leading 1/p is the DFT aliasing factor.

    With ``pixel_fill`` ``w != 1`` the discrete mean is replaced by a continuous box of
    width ``w`` LR px centred on the pixel centre, with the same phase reference (the block's
    centre is ``(p - 1) / 2`` HR px after its start)::

        Hbox(f) = sinc(w p f) exp(pi i f (p - 1))

    (numpy's ``sinc``; ``w p f`` = ``w nu``, ``nu`` in cycles / LR px). Its magnitude at
    ``w = 1`` is ``|sinc(p f)|``, not the discrete ``|sin(pi p f) / (p sin(pi f))|``, so the
    default keeps the discrete form (the model of before, bit for bit).
    """
    f_all = np.fft.fftfreq(p * n_lr)
    k = np.arange(n_lr)
    f = np.stack([f_all[k + m * n_lr] for m in range(p)])
    if pixel_fill == 1.0:
        hbox = np.exp(2j * np.pi * f[..., None] * np.arange(p)).mean(axis=-1)
    else:
        hbox = np.sinc(pixel_fill * p * f) * np.exp(1j * np.pi * f * (p - 1))
    s = p * shift
    a = hbox * np.exp(-2.0 * np.pi**2 * (p * blur_sigma) ** 2 * f**2) * np.exp(-2j * np.pi * f * s)
    if shift_var > 0:
        a = a * np.exp(-2.0 * np.pi**2 * f**2 * p * p * shift_var)
    return a / p, f


@functools.lru_cache(maxsize=32)
def _transfer_base(
    n_lr: int, p: int, blur_sigma: float, pixel_fill: float = 1.0
) -> tuple[np.ndarray, np.ndarray]:
    """Return :func:`frame_transfer_1d` at zero shift, ``(a0, f)`` (cached, read-only)."""
    a0, f = frame_transfer_1d(n_lr, p, 0.0, blur_sigma, pixel_fill=pixel_fill)
    a0.flags.writeable = False
    f.flags.writeable = False
    return a0, f


def _frame_transfers(
    n_lr: int,
    p: int,
    shifts: np.ndarray,
    blur_sigma: float,
    keep: int | None = None,
    pixel_fill: float = 1.0,
) -> tuple[np.ndarray, np.ndarray]:
    """Return :func:`frame_transfer_1d` for every shift at once, and f.

    ``a[n] = a0 exp(-2 pi i f p s_n)``, (N, p, keep): ``a0`` is the zero-shift transfer
    (cached); the shift enters as the phase factor only, as in ``frame_transfer_1d`` (the same
    values to round-off). ``keep``: the first columns only (the rfft half). ``pixel_fill``:
    the aperture width (LR px), as in ``frame_transfer_1d``.
    """
    a0, f = _transfer_base(n_lr, p, float(blur_sigma), float(pixel_fill))
    if keep is not None:
        a0, f = a0[:, :keep], f[:, :keep]
    s = np.asarray(shifts, dtype=np.float64)
    return a0[None] * np.exp((-2j * np.pi * p) * f[None] * s[:, None, None]), f
