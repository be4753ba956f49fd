"""Input checks of the shift estimator: working arrays, validity masks, constant frames."""

from __future__ import annotations

from typing import Optional, Tuple, Union

import cv2
import numpy as np

MaskArg = Union[None, np.ndarray, Tuple[Optional[np.ndarray], Optional[np.ndarray]]]


def _as_working(image: np.ndarray, name: str) -> Tuple[np.ndarray, Optional[np.ndarray]]:
    """Return the working array and its validity.

    Parameters
    ----------
    image : ndarray
        A 2-D frame of any integer or float dtype.
    name : str
        The argument's name, for error messages.

    Returns
    -------
    working : ndarray
        uint8/uint16 kept as is (for OpenCV), anything else as float32 (invalid pixels 0).
    valid : ndarray of bool or None
        None when every pixel is valid; otherwise False at NaN/inf and, for uint8/uint16, at
        the dtype's maximum (saturated: the true value is unknown).

    Raises
    ------
    ValueError
        For a frame that is not 2-D, not numeric or empty.
    """
    arr = np.asarray(image)
    if arr.ndim != 2:
        raise ValueError(
            f"{name} must be a 2-D (mono) array, got shape {arr.shape}; "
            "convert colour with luminance()"
        )
    if arr.dtype == bool or not (
        np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)
    ):
        raise ValueError(f"{name} dtype {arr.dtype} is not an integer or float type")
    if arr.size == 0:
        raise ValueError(f"{name} is empty")
    if arr.dtype in (np.uint8, np.uint16):
        arr = np.ascontiguousarray(arr)
        saturated = np.iinfo(arr.dtype).max
        if cv2.minMaxLoc(arr)[1] >= saturated:
            return arr, arr != saturated
        return arr, None
    work = np.ascontiguousarray(arr, dtype=np.float32)
    # finite iff the sum is (OpenCV sums float32 in double; NaN and inf propagate): one read
    if np.issubdtype(arr.dtype, np.floating) and not np.isfinite(cv2.sumElems(work)[0]):
        valid = np.isfinite(work)
        return np.where(valid, work, np.float32(0.0)), valid
    return work, None


def _is_constant(image: np.ndarray, valid: Optional[np.ndarray]) -> bool:
    """Return True if the valid pixels of ``image`` all have one value."""
    if valid is None:
        lo, hi, _, _ = cv2.minMaxLoc(image)
    else:
        lo, hi, _, _ = cv2.minMaxLoc(image, mask=valid.astype(np.uint8))
    return hi <= lo


def _masks(
    mask: MaskArg, shape: Tuple[int, int]
) -> Tuple[Optional[np.ndarray], Optional[np.ndarray]]:
    """Split the ``mask`` argument into (reference mask, moving mask), each bool or None.

    Raises
    ------
    ValueError
        For a mask of the wrong shape or a tuple that is not a pair.
    """
    if mask is None:
        return None, None
    if isinstance(mask, (tuple, list)):
        if len(mask) != 2:
            raise ValueError("mask must be an array or a (reference_mask, moving_mask) pair")
        out = []
        for one in mask:
            if one is None:
                out.append(None)
                continue
            one = np.asarray(one)
            if one.shape != shape:
                raise ValueError(f"mask shape {one.shape} != image shape {shape}")
            out.append(one.astype(bool, copy=False))  # read only: a bool mask is not copied
        return out[0], out[1]
    both = np.asarray(mask)
    if both.shape != shape:
        raise ValueError(f"mask shape {both.shape} != image shape {shape}")
    both = both.astype(bool, copy=False)
    return both, both


def _fill_invalid(image: np.ndarray, valid: Optional[np.ndarray]) -> np.ndarray:
    """Return ``image`` with its invalid pixels set to the mean of the valid ones."""
    if valid is None or valid.all():
        return image
    if not valid.any():
        return np.zeros_like(image)
    out = image.copy()
    out[~valid] = float(image[valid].mean())
    return out
