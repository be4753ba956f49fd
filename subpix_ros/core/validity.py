"""Validity masks that are rectangles (the border strips an integer-crop alignment leaves).

Pixel alignment by an integer crop (:func:`subpix_ros.core.registration.align`)
marks a frame valid on one axis-aligned rectangle. Consumers that would
otherwise take a slower masked path (masked sums in the shift estimator, the
conjugate-gradient solver in super-resolution) crop to that rectangle instead.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

__all__ = ["box_mask", "common_box", "common_region", "common_valid_box"]


def common_valid_box(masks: Sequence[np.ndarray]) -> tuple[int, int, int, int] | None:
    """Return the rectangle the pixels valid in every mask form, if they form one.

    Parameters
    ----------
    masks : sequence of ndarray of bool
        Validity masks of equal shape.

    Returns
    -------
    tuple of int or None
        ``(r0, r1, c0, c1)`` (rows r0..r1-1, columns c0..c1-1), or None if the valid pixels are
        not exactly a rectangle (also for no mask or no valid pixel).
    """
    if len(masks) == 0:
        return None
    valid = np.array(masks[0], dtype=bool)  # a copy, and-ed in place (no stack of all masks)
    for m in masks[1:]:
        np.logical_and(valid, np.asarray(m, bool), out=valid)
    rows = np.flatnonzero(valid.any(axis=1))
    cols = np.flatnonzero(valid.any(axis=0))
    if rows.size == 0 or cols.size == 0:
        return None
    r0, r1, c0, c1 = int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1
    if (r1 - r0) * (c1 - c0) != int(np.count_nonzero(valid)):
        return None
    return r0, r1, c0, c1


def box_mask(shape: tuple[int, int], box: tuple[int, int, int, int]) -> np.ndarray:
    """Return the bool mask of ``shape`` that is True exactly in ``box``.

    Parameters
    ----------
    shape : (int, int)
        Rows, columns.
    box : (int, int, int, int)
        ``(r0, r1, c0, c1)``: rows r0..r1-1, columns c0..c1-1 (clipped to ``shape``).

    Returns
    -------
    ndarray of bool
        The mask; :func:`common_valid_box` of it gives ``box`` back (if not empty).
    """
    mask = np.zeros(shape[:2], bool)
    r0, r1, c0, c1 = box
    mask[max(r0, 0) : max(r1, 0), max(c0, 0) : max(c1, 0)] = True
    return mask


def common_box(
    boxes: Sequence[tuple[int, int, int, int]], shape: tuple[int, int]
) -> tuple[int, int, int, int] | None:
    """Return the rectangle inside every box (each clipped to ``shape``), or None if empty.

    Parameters
    ----------
    boxes : sequence of (int, int, int, int)
        ``(r0, r1, c0, c1)`` per frame, as :func:`box_mask` takes them.
    shape : (int, int)
        Rows, columns of the frames.

    Returns
    -------
    tuple of int or None
        What :func:`common_valid_box` finds in the masks of ``boxes`` (:func:`box_mask`),
        without making them; None for no box or an empty intersection.
    """
    if len(boxes) == 0:
        return None
    r0, r1, c0, c1 = 0, int(shape[0]), 0, int(shape[1])
    for b0, b1, d0, d1 in boxes:
        r0, r1 = max(r0, int(b0)), min(r1, int(b1))
        c0, c1 = max(c0, int(d0)), min(c1, int(d1))
    if r1 <= r0 or c1 <= c0:
        return None
    return r0, r1, c0, c1


def common_region(
    shape: tuple[int, int],
    masks: Sequence[np.ndarray] | None = None,
    boxes: Sequence[tuple[int, int, int, int]] | None = None,
) -> tuple[int, int, int, int] | None:
    """Return the rectangle valid in every frame, given as masks, as boxes, or neither.

    Parameters
    ----------
    shape : (int, int)
        Rows, columns of the frames.
    masks : sequence of numpy.ndarray, optional
        Bool validity masks (:func:`common_valid_box`).
    boxes : sequence of (int, int, int, int), optional
        Valid rectangles ``(r0, r1, c0, c1)`` instead of masks (:func:`common_box`).

    Returns
    -------
    tuple of int or None
        ``(r0, r1, c0, c1)``; the whole frame when neither is given; None if empty.

    Raises
    ------
    ValueError
        If both masks and boxes are given.
    """
    if boxes is not None:
        if masks is not None:
            raise ValueError("give masks or boxes, not both")
        return common_box(boxes, shape)
    if masks is not None:
        return common_valid_box(masks)
    return 0, int(shape[0]), 0, int(shape[1])
