"""Luminance of the frames the colour reconstruction super-resolves, and set members packed.

:func:`colour_luminance` is the luminance :func:`~.reconstruction.reconstruct_colour`
reconstructs (ITU-R BT.601, float32). A set's members besides the reference are only ever
read as luminance (the chroma is the reference's), so a stage holding a set may keep each
member as its luminance packed into 2 bytes per pixel (:func:`pack_luminance`) instead of
3 (uint8 BGR) or 6 (uint16 BGR): :func:`frame_luminance` and :class:`LazyLuminance` read
such a member back.
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = [
    "LUMA_FIXED_SCALE",
    "LazyLuminance",
    "colour_luminance",
    "frame_luminance",
    "lazy_luminance",
    "lazy_member_luminance",
    "pack_luminance",
    "packed_dtype",
]

#: A packed uint16 member holds ``round(Y * LUMA_FIXED_SCALE)`` (Y of a uint8 BGR frame).
LUMA_FIXED_SCALE = 256.0


def pack_luminance(frame: np.ndarray) -> np.ndarray:
    """Return a colour set member as the luminance the reconstruction reads from it, packed.

    Parameters
    ----------
    frame : numpy.ndarray
        HxWx3 BGR member of a colour set, uint8 or uint16; anything else (a mono frame, a
        float frame) is returned unchanged.

    Returns
    -------
    numpy.ndarray
        HxW: for uint8 BGR, uint16 ``round(Y * LUMA_FIXED_SCALE)`` (2 bytes per pixel
        instead of 3); for uint16 BGR, float32 ``Y`` (4 instead of 6, the same values);
        ``Y`` as :func:`colour_luminance`.

    Notes
    -----
    ``Y`` of a uint8 frame lies in [0, 255], so ``Y * 256 <= 65280`` fits uint16, and the
    packed value differs from the float32 ``Y`` by at most 1/512 DN (a 256th of the
    frame's own quantisation step); :func:`frame_luminance` divides by 256 exactly.
    Converted in blocks of ``_LUMA_ROWS`` rows (no frame-sized float32 copy).
    """
    if frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype not in (np.uint8, np.uint16):
        return frame
    if frame.dtype == np.uint16:
        return colour_luminance(frame)
    out = np.empty(frame.shape[:2], np.uint16)
    blk = np.empty((_LUMA_ROWS, frame.shape[1]), np.float32)
    for r0 in range(0, frame.shape[0], _LUMA_ROWS):
        y = _luma_block(frame, r0, blk[: min(_LUMA_ROWS, frame.shape[0] - r0)])
        y *= np.float32(LUMA_FIXED_SCALE)
        np.rint(y, out=y)
        out[r0 : r0 + _LUMA_ROWS] = y  # in [0, 65280]: exact in uint16
    return out


def frame_luminance(frame: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Return the float32 luminance of a colour set's frame: BGR, or a packed member.

    Parameters
    ----------
    frame : numpy.ndarray
        HxWx3 BGR (:func:`colour_luminance`), or 2-D: a member packed by
        :func:`pack_luminance` (uint16: ``Y * LUMA_FIXED_SCALE``; float: ``Y``).
    out : numpy.ndarray, optional
        As :func:`colour_luminance`.

    Returns
    -------
    numpy.ndarray
        float32 HxW ``Y`` on the frame's own intensity scale.
    """
    if frame.ndim == 3:
        return colour_luminance(frame, out)
    if out is None:
        out = np.empty(frame.shape, np.float32)
    if np.issubdtype(frame.dtype, np.integer):
        np.multiply(frame, np.float32(1.0 / LUMA_FIXED_SCALE), out=out)  # exact: a power of 2
    else:
        out[...] = frame
    return out


def colour_luminance(frame: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
    """Return the luminance :func:`reconstruct_colour` super-resolves (a mono frame as it is).

    Parameters
    ----------
    frame : numpy.ndarray
        HxWx3 BGR frame (OpenCV order), or a 2-D mono frame.
    out : numpy.ndarray, optional
        C-contiguous float32 HxW array to write a colour frame's luminance into (e.g. a
        reused buffer); default: a new array. A mono frame is returned as it is, ``out``
        unused.

    Returns
    -------
    numpy.ndarray
        ``Y = 0.299 R + 0.587 G + 0.114 B`` (ITU-R BT.601, ``cv2.COLOR_BGR2GRAY``) in float32 on
        the frame's own scale; a 2-D frame is returned unchanged.
    """
    if frame.ndim == 2:
        return frame
    if out is None:
        out = np.empty(frame.shape[:2], np.float32)
    elif out.shape != frame.shape[:2] or out.dtype != np.float32 or not out.flags.c_contiguous:
        raise ValueError(f"out must be C-contiguous float32 of shape {frame.shape[:2]}")
    if frame.dtype == np.float32:
        return cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY, dst=out)
    # in blocks of rows: each block's float32 copy stays in cache (same values as converting
    # the whole frame first: the conversion and the weighted sum are per pixel)
    for r0 in range(0, frame.shape[0], _LUMA_ROWS):
        _luma_block(frame, r0, out[r0 : r0 + _LUMA_ROWS])
    return out


_LUMA_ROWS = 64  # rows per block of colour_luminance


def _luma_block(frame: np.ndarray, r0: int, out: np.ndarray) -> np.ndarray:
    """Write the luminance of the ``_LUMA_ROWS`` full rows from ``r0`` of an integer BGR frame.

    The one conversion :func:`colour_luminance` and :class:`LazyLuminance` both use, so their
    values are the same bit for bit. A 2-D (packed uint16) frame is unpacked
    (:func:`frame_luminance`).
    """
    if frame.ndim == 2:
        return frame_luminance(frame[r0 : r0 + _LUMA_ROWS], out)
    blk = frame[r0 : r0 + _LUMA_ROWS].astype(np.float32)
    return cv2.cvtColor(blk, cv2.COLOR_BGR2GRAY, dst=out)


def lazy_luminance(frame: np.ndarray):
    """Return a :class:`LazyLuminance` of ``frame`` where one applies, else its luminance.

    Integer BGR frames are converted where they are read; mono frames (as they are) and
    float32 BGR frames (one conversion) go through :func:`colour_luminance`.
    """
    if frame.ndim == 3 and frame.shape[2] == 3 and frame.dtype != np.float32:
        return LazyLuminance(frame)
    return colour_luminance(frame)


def lazy_member_luminance(frame: np.ndarray, packed: bool):
    """Return a set member's luminance, computed where it is read.

    ``packed``: ``frame`` was packed by :func:`pack_luminance` (uint16: unpacked where read,
    :class:`LazyLuminance`; float32: it is the luminance); else :func:`lazy_luminance`.
    """
    if not packed:
        return lazy_luminance(frame)
    if frame.dtype == np.uint16:
        return LazyLuminance(frame)
    return frame.astype(np.float32, copy=False)


def packed_dtype(reference: np.ndarray):
    """Return the dtype :func:`pack_luminance` gives members of a set with this BGR reference."""
    return _PACKED_DTYPE.get(np.dtype(reference.dtype))


#: A packed member's dtype by the BGR frame's: uint8 -> uint16 (Y * 256), uint16 -> float32 (Y)
_PACKED_DTYPE = {np.dtype(np.uint8): np.dtype(np.uint16), np.dtype(np.uint16): np.dtype(np.float32)}


class LazyLuminance:
    """:func:`colour_luminance` of a uint8/uint16 BGR frame, computed only where it is read.

    Also a member packed into uint16 by :func:`pack_luminance` (2-D), unpacked where read.

    For the blur calibration, which reads a few edge ROIs, a central square and the intensity
    range of most frames: it needs no frame-sized float32 copy of each.

    Parameters
    ----------
    frame : numpy.ndarray
        HxWx3 BGR frame, integer dtype; or a 2-D uint16 packed member.

    Notes
    -----
    Slicing ``lum[r0:r1, c0:c1]`` returns float32 values bit-identical to
    ``colour_luminance(frame)[r0:r1, c0:c1]``: the rows are converted in the same blocks of
    ``_LUMA_ROWS`` full rows as :func:`colour_luminance` converts them (OpenCV's vector and
    scalar loops may round differently, so a crop converted alone can differ in the last
    bit). :meth:`min` and :meth:`max` convert every block once, keeping none.
    """

    ndim = 2
    dtype = np.dtype(np.float32)

    def __init__(self, frame: np.ndarray) -> None:
        packed = frame.ndim == 2 and frame.dtype == np.uint16
        if not packed and (frame.ndim != 3 or frame.shape[2] != 3 or frame.dtype == np.float32):
            raise ValueError("LazyLuminance takes an integer HxWx3 BGR frame or a packed member")
        self.frame = frame
        self.shape = tuple(frame.shape[:2])
        self._blocks: dict[int, np.ndarray] = {}
        self._range: tuple[float, float] | None = None

    def _block(self, b: int, keep: bool = True) -> np.ndarray:
        """Return the luminance of row block ``b`` (rows ``b * _LUMA_ROWS`` onwards)."""
        out = self._blocks.get(b)
        if out is None:
            rows = min(_LUMA_ROWS, self.shape[0] - b * _LUMA_ROWS)
            out = _luma_block(
                self.frame, b * _LUMA_ROWS, np.empty((rows, self.shape[1]), np.float32)
            )
            if keep:
                self._blocks[b] = out
        return out

    def __getitem__(self, key) -> np.ndarray:
        """Return ``colour_luminance(frame)[rows, cols]`` for two slices of step 1."""
        rows, cols = key
        r0, r1, step = rows.indices(self.shape[0])
        if step != 1 or not isinstance(cols, slice):
            raise IndexError("LazyLuminance takes [r0:r1, c0:c1]")
        if r1 <= r0:
            return np.empty((0, self.shape[1]), np.float32)[:, cols]
        first, last = r0 // _LUMA_ROWS, (r1 - 1) // _LUMA_ROWS
        band = [self._block(b) for b in range(first, last + 1)]
        band = band[0] if len(band) == 1 else np.concatenate(band)
        return band[r0 - first * _LUMA_ROWS : r1 - first * _LUMA_ROWS, cols]

    def _minmax(self) -> tuple[float, float]:
        if self._range is None:
            lo, hi = np.inf, -np.inf
            for b in range(-(-self.shape[0] // _LUMA_ROWS)):
                blk = self._block(b, keep=False)
                lo, hi = min(lo, float(blk.min())), max(hi, float(blk.max()))
            self._range = (lo, hi)
        return self._range

    def min(self) -> float:
        """Return the smallest luminance value (as ``colour_luminance(frame).min()``)."""
        return self._minmax()[0]

    def max(self) -> float:
        """Return the largest luminance value."""
        return self._minmax()[1]

    def __array__(self, dtype=None, copy=None) -> np.ndarray:
        """Return the whole luminance (as :func:`colour_luminance`)."""
        full = frame_luminance(self.frame)
        return full if dtype is None else full.astype(dtype, copy=False)
