"""Input checks of the super-resolution entry points."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from .result import MAX_FACTOR, METHODS


def _validate(
    frames: Sequence[np.ndarray], shifts, factor: int, masks, shift_cov, homographies
) -> tuple[list[np.ndarray], np.ndarray | None, int]:
    """Check the inputs of :func:`~subpix_ros.core.superres.reconstruct`.

    Returns
    -------
    arrs : list of numpy.ndarray
        The frames as arrays (not copied).
    shifts : numpy.ndarray or None
        (N, 2) float64 shifts relative to frame 0 (None with homographies only).
    factor : int
        The factor as a plain int.

    Raises
    ------
    ValueError
        On malformed input: fewer than 2 frames, not 2-D, mismatched shapes, smaller than
        16x16, non-finite values, factor outside 2..``MAX_FACTOR``, bad shifts, masks,
        ``shift_cov`` or homographies.
    """
    if not isinstance(factor, (int, np.integer)) or isinstance(factor, bool):
        raise ValueError(f"factor must be an integer, got {factor!r}")
    if not 2 <= int(factor) <= MAX_FACTOR:
        raise ValueError(f"factor must be in 2..{MAX_FACTOR}, got {factor}")
    arrs = _validate_frames(frames)
    n, shape = len(arrs), arrs[0].shape
    if shifts is None:
        if homographies is None:
            raise ValueError("give shifts (N, 2) or homographies (N, 3, 3)")
        rel = None
    else:
        rel = np.asarray(shifts, dtype=np.float64)
        if rel.shape != (n, 2):
            raise ValueError(f"shifts must have shape ({n}, 2), got {rel.shape}")
        if not np.isfinite(rel).all():
            raise ValueError("shifts contain NaN or infinite values")
        rel = rel - rel[0]  # relative to frame 0, whose grid is the output grid
    if masks is not None and (len(masks) != n or any(np.asarray(m).shape != shape for m in masks)):
        raise ValueError("masks must be one boolean array per frame, each of the frames' shape")
    if shift_cov is not None:
        cov = np.asarray(shift_cov, dtype=np.float64)
        if cov.shape != (n, 2, 2) or not np.isfinite(cov).all():
            raise ValueError(f"shift_cov must be a finite ({n}, 2, 2) array")
    if homographies is not None:
        hs = np.asarray(homographies, dtype=np.float64)
        if hs.shape != (n, 3, 3) or not np.isfinite(hs).all():
            raise ValueError(f"homographies must be a finite ({n}, 3, 3) array")
    return arrs, rel, int(factor)


def _validate_frames(frames: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Check that there are >= 2 finite 2-D frames of one shape, >= 16x16; return them as arrays."""
    if frames is None or len(frames) < 2:
        raise ValueError(
            f"super-resolution needs at least 2 frames, got {0 if frames is None else len(frames)}"
        )
    arrs = [np.asarray(f) for f in frames]
    if any(a.ndim != 2 for a in arrs):
        raise ValueError("frames must be 2-D (mono); use reconstruct_colour for colour frames")
    shape = arrs[0].shape
    if any(a.shape != shape for a in arrs):
        raise ValueError(
            f"all frames must have the same shape, got {sorted({a.shape for a in arrs})}"
        )
    if min(shape) < 16:
        raise ValueError(f"frames too small for reconstruction: {shape} (need >= 16x16)")
    if any(
        not (np.issubdtype(a.dtype, np.integer) or a.dtype == bool) and not np.isfinite(a).all()
        for a in arrs
    ):  # integer frames are always finite
        raise ValueError("frames contain NaN or infinite values")
    return arrs


def _check_options(
    method: str, geometry: str, blur_sigma: float, reg: float, noise_sigma: float | None
) -> None:
    """Raise ValueError for an unknown method or geometry, or an out-of-range setting."""
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose from {METHODS}")
    if geometry not in ("auto", "translation"):
        raise ValueError(f"geometry must be 'auto' or 'translation', got {geometry!r}")
    if blur_sigma < 0 or reg <= 0:
        raise ValueError("blur_sigma must be >= 0 and reg > 0")
    if noise_sigma is not None and (not np.isfinite(noise_sigma) or noise_sigma < 0):
        raise ValueError(f"noise_sigma must be finite and >= 0, got {noise_sigma}")


def _small_ints(arrs: list[np.ndarray]) -> bool:
    """Tell whether every frame has an integer dtype of at most 16 bits.

    Such values and their ``p q`` sums are exact in float32.
    """
    return all(
        (np.issubdtype(a.dtype, np.integer) and a.dtype.itemsize <= 2) or a.dtype == bool
        for a in arrs
    )


class FrameStack:
    """The frames of a set as an (N, H, W) float64 stack, each frame converted when read.

    Indexing gives what the same index of ``np.stack(frames).astype(np.float64)`` gives
    (``stack[i]``, ``stack[i, rows, cols]``, ``stack[:2, rows, cols]``, ``stack[bool mask]``)
    without holding the stack: a 1080p set of 16 frames is 265 MB as float64, and building it
    cost more than a third of the reconstruction's time. ``np.asarray(stack)`` builds it.
    """

    def __init__(self, arrs: Sequence[np.ndarray]) -> None:
        self._arrs = list(arrs)
        self.shape = (len(self._arrs),) + tuple(self._arrs[0].shape)
        self.ndim = 3
        self.dtype = np.dtype(np.float64)

    def __len__(self) -> int:
        """Return the number of frames."""
        return len(self._arrs)

    def __iter__(self):
        """Yield each frame as float64."""
        for a in self._arrs:
            yield np.asarray(a, dtype=np.float64)

    def __getitem__(self, key):
        """Return frames or parts of frames as float64 (a subset of frames as a FrameStack)."""
        head, rest = (key[0], key[1:]) if isinstance(key, tuple) else (key, ())
        if isinstance(head, (int, np.integer)):
            return np.asarray(self._arrs[head][rest] if rest else self._arrs[head], np.float64)
        if isinstance(head, slice):
            chosen = self._arrs[head]
        else:
            idx = np.asarray(head)
            idx = np.flatnonzero(idx) if idx.dtype == bool else idx.ravel()
            chosen = [self._arrs[int(i)] for i in idx]
        if rest:
            return np.stack([np.asarray(a[rest], np.float64) for a in chosen])
        return FrameStack(chosen)

    def window(self, i: int, rows: slice, cols: slice) -> np.ndarray:
        """Return frame ``i``'s pixels ``[rows, cols]`` as stored (a view, not converted).

        For a caller that converts them itself (e.g. into a float32 buffer): every stored
        dtype converts to float32 with the same value directly as through float64.
        """
        return np.asarray(self._arrs[i])[rows, cols]

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        """Build the whole float64 stack (one pass per frame)."""
        out = np.empty(self.shape)
        for i, a in enumerate(self._arrs):  # frames
            out[i] = a
        return out if dtype is None else out.astype(dtype)

    def all_integer_valued(self) -> bool:
        """Tell whether every value of every frame is a whole number (frame by frame)."""
        return all(np.array_equal(f, np.rint(f)) for f in self)


def stored(frames, i: int, rows: slice = slice(None), cols: slice = slice(None)) -> np.ndarray:
    """Return frame ``i``'s pixels ``[rows, cols]``: as stored from a :class:`FrameStack`.

    For a caller that converts them itself (a float32 buffer, ``cv2.sepFilter2D`` into
    float64): every stored dtype gives there the values of its float64 copy, without the
    copy of the whole frame that indexing a FrameStack makes. Any other (N, H, W) array is
    indexed as it is.
    """
    if isinstance(frames, FrameStack):
        return frames.window(i, rows, cols)
    return frames[i, rows, cols]
