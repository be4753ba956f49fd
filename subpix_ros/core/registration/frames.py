"""Frames prepared for registration: luminance, pyramid, Harris maxima, ORB features."""

from __future__ import annotations

import threading
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field

import cv2
import numpy as np

from ..luminance import luminance
from .coarse import orb_features
from .harris import harris_peaks


def to_gray32(image: np.ndarray, name: str = "image") -> np.ndarray:
    """Validate a frame and return its luminance as float32 HxW (digital numbers).

    Parameters
    ----------
    image : ndarray
        Mono HxW (passes through) or HxWx3 OpenCV BGR, reduced with the seed weights
        ``gray = 0.2989 R + 0.587 G + 0.1141 B`` (METHODS A,
        :func:`subpix_ros.core.luminance.luminance`).
    name : str
        The frame's name, for error messages.

    Returns
    -------
    ndarray of float32
        Contiguous HxW luminance.

    Raises
    ------
    ValueError
        For other shapes, frames under 32x32, non-numeric dtypes or non-finite values.
    """
    img = np.asarray(image)
    if img.dtype == bool or not (
        np.issubdtype(img.dtype, np.integer) or np.issubdtype(img.dtype, np.floating)
    ):
        raise ValueError(f"{name}: dtype {img.dtype} is not an integer or float image")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 3 and img.shape[2] == 3:
        g = luminance(img, "bgr", dtype=np.float32)
    elif img.ndim == 2:
        g = img.astype(np.float32)
    else:
        raise ValueError(f"{name}: expected HxW or HxWx3 (BGR), got shape {img.shape}")
    if min(g.shape) < 32:
        raise ValueError(f"{name}: frame {g.shape} is too small (need at least 32x32)")
    if (
        np.issubdtype(img.dtype, np.floating) and not np.isfinite(g).all()
    ):  # integers are always finite
        raise ValueError(f"{name}: contains non-finite values")
    return np.ascontiguousarray(g)


@dataclass(eq=False)
class ReferenceFrame:
    """Reference-side work of :func:`register`, reusable across many moving frames.

    Holds the float32 luminance (:func:`to_gray32`), its Gaussian pyramid
    (``cv2.pyrDown``, level ``l`` has ``2^-l`` the resolution), the Harris
    maxima (:func:`~.harris.harris_peaks`) per level and the ORB
    features of the coarse level, each computed on first use and kept.
    Build it with :func:`prepare_reference` and pass it to :func:`register`
    in place of the reference array. Not thread-safe (a lazily filled cache).
    """

    gray: np.ndarray
    pyramid: list[np.ndarray]
    blank: bool
    _peaks: dict[int, tuple] = field(default_factory=dict, repr=False)
    _orb: dict[int, tuple] = field(default_factory=dict, repr=False)

    @classmethod
    def of(cls, gray: np.ndarray) -> "ReferenceFrame":
        """Return a frame of this float32 luminance, nothing computed yet.

        Blank if its std is below 1 DN (every 4th pixel is plenty to tell).
        """
        return cls(gray, [gray], float(gray[::2, ::2].std()) < 1.0)

    @property
    def shape(self) -> tuple[int, int]:
        """Shape of the luminance (rows, cols)."""
        return self.gray.shape

    def level(self, lev: int) -> np.ndarray:
        """Return pyramid level ``lev`` (extended on demand)."""
        while len(self.pyramid) <= lev:
            self.pyramid.append(cv2.pyrDown(self.pyramid[-1]))
        return self.pyramid[lev]

    def peaks(self, lev: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return the Harris maxima ``(xs, ys, R)`` of pyramid level ``lev`` (METHODS C 2)."""
        if lev not in self._peaks:
            self._peaks[lev] = harris_peaks(self.level(lev))
        return self._peaks[lev]

    def orb(self, lev: int) -> tuple:
        """Return the ORB keypoints and descriptors of pyramid level ``lev`` (coarse stage)."""
        if lev not in self._orb:
            self._orb[lev] = orb_features(self.level(lev))
        return self._orb[lev]


def _levels(shape: tuple[int, int], coarse_size: int, detect_size: int) -> tuple[int, int, int]:
    """Return :func:`.register`'s (top, detection, middle) levels for a reference of ``shape``."""
    n_lev = max(0, int(np.ceil(np.log2(max(shape) / coarse_size))))
    det_lev = min(n_lev, max(0, int(np.ceil(np.log2(max(shape) / detect_size)))))
    mid_lev = min(n_lev, max(0, int(np.ceil(np.log2(max(shape) / 480)))))
    return n_lev, det_lev, mid_lev


def prepare_reference(
    reference: np.ndarray | ReferenceFrame, *, coarse_size: int = 128, detect_size: int = 1000
) -> ReferenceFrame:
    """Prepare a reference for many registrations.

    Luminance, pyramid, Harris maxima (detection and refinement levels) and coarse ORB
    features, computed once.

    Parameters
    ----------
    reference : ndarray or ReferenceFrame
        The frame (a prepared one is returned as it is).
    coarse_size, detect_size : int
        Must match the ones given to :func:`.register` for the eager part to be reused
        (other levels are computed on demand).

    Returns
    -------
    ReferenceFrame
        Pass it to :func:`.register` (as ``reference``) for every frame registered to it.

    Raises
    ------
    ValueError
        For bad input (as :func:`to_gray32`).
    """
    if isinstance(reference, ReferenceFrame):
        return reference
    ref = ReferenceFrame.of(to_gray32(reference, "reference"))
    return _compute_eager(ref, ref.shape, coarse_size, detect_size, peaks=True)


def _compute_eager(
    frame: ReferenceFrame,
    ref_shape: tuple[int, ...],
    coarse_size: int,
    detect_size: int,
    *,
    peaks: bool,
) -> ReferenceFrame:
    """Compute now what :func:`.register`'s full pipeline uses of ``frame``; return ``frame``.

    Levels from the reference's shape ``ref_shape``: the pyramid, the coarse ORB features and,
    for a reference (``peaks``), the Harris maxima of the detection and refinement levels.
    Nothing for a blank frame.
    """
    if not frame.blank:
        n_lev, det_lev, mid_lev = _levels(ref_shape[:2], coarse_size, detect_size)
        frame.level(n_lev)
        if peaks:
            for lev in range(det_lev, max(mid_lev, det_lev) + 1):
                frame.peaks(lev)
        frame.orb(mid_lev)
    return frame


_POOL: ThreadPoolExecutor | None = None

_POOL_LOCK = threading.Lock()


def _pool() -> ThreadPoolExecutor:
    """Return the worker thread (made on first use) that prepares a pair's reference."""
    global _POOL
    with _POOL_LOCK:
        if _POOL is None:
            _POOL = ThreadPoolExecutor(max_workers=1, thread_name_prefix="subpix-register")
        return _POOL


def _prepare_pair(
    reference: np.ndarray, moving: np.ndarray, coarse_size: int, detect_size: int
) -> tuple[ReferenceFrame, ReferenceFrame]:
    """Prepare both frames of a one-off pair at the same time (two threads).

    The reference as :func:`prepare_reference` in the worker; in the calling thread the
    moving frame's share of :func:`.register`'s full pipeline (luminance, pyramid, coarse ORB
    features). OpenCV and numpy release the GIL in this work, so on two cores the two
    preparations take about the time of one. The same work as on one thread, so the same
    result. Bad input raises ``ValueError`` as before, the reference's first.
    """
    fut = _pool().submit(
        prepare_reference, reference, coarse_size=coarse_size, detect_size=detect_size
    )
    try:
        mov = _compute_eager(
            ReferenceFrame.of(to_gray32(moving, "moving")),
            np.shape(reference),
            coarse_size,
            detect_size,
            peaks=False,
        )
    except ValueError:
        fut.result()  # a bad reference is reported first, as on one thread
        raise
    return fut.result(), mov
