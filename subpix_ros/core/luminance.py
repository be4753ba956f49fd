"""Luminance of colour frames, exactly as the seed (METHODS.md A).

    gray = 0.2989 R + 0.587 G + 0.1141 B                         (METHODS A, luminance)

Values keep their digital-number scale (uint8 0..255 stays 0..255, uint16
0..65535 stays 0..65535, float stays as given); the output is float64 so
later sums accumulate in double precision, or float32 on request (the shift
estimator works in float32: asking for it saves a float64 frame and a
conversion; the weighted sum then carries ~1e-5 DN of rounding at 8 bit).
"""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["luminance", "LUMA_WEIGHTS_RGB", "ORDERS"]

#: Seed weights for (R, G, B).
LUMA_WEIGHTS_RGB = (0.2989, 0.587, 0.1141)

#: Rows per block of the float32 path.
_ROWS = 64

#: Accepted channel orders and, for each, the index of R, G and B.
ORDERS = {
    "bgr": (2, 1, 0),
    "rgb": (0, 1, 2),
    "bgra": (2, 1, 0),
    "rgba": (0, 1, 2),
    "mono": None,
}


def luminance(image: np.ndarray, order: str = "bgr", dtype: type = np.float64) -> np.ndarray:
    """Return the seed luminance ``0.2989 R + 0.587 G + 0.1141 B`` as HxW float64 or float32.

    ``order`` names the channel layout of an HxWxC array: ``"bgr"`` (OpenCV,
    ROS ``bgr8``), ``"rgb"`` (ROS ``rgb8``), ``"bgra"``, ``"rgba"`` (alpha is
    ignored), or ``"mono"``. A 2-D (or HxWx1) array is monochrome and passes
    through as float64 whatever ``order`` says. Integer (uint8, uint16, ...)
    and float input are accepted; no rescaling is applied.

    Raises ``ValueError`` for an unknown order, a channel count that does not
    match it, or a non-numeric / boolean / complex array; ``TypeError`` is
    never silently coerced into a made-up image.
    """
    if order not in ORDERS:
        raise ValueError(f"unknown channel order {order!r}; choose from {sorted(ORDERS)}")
    dtype = np.dtype(dtype)
    if dtype not in (np.float64, np.float32):
        raise ValueError(f"dtype must be float64 or float32, got {dtype}")
    img = np.asarray(image)
    if img.dtype == bool or not (
        np.issubdtype(img.dtype, np.integer) or np.issubdtype(img.dtype, np.floating)
    ):
        raise ValueError(f"image dtype {img.dtype} is not an integer or float type")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 2:
        return img.astype(dtype, copy=True)
    if img.ndim != 3:
        raise ValueError(f"image must be HxW or HxWxC, got shape {img.shape}")
    need = 4 if order.endswith("a") else 3
    if order == "mono":
        raise ValueError(f"order 'mono' given for a {img.shape[2]}-channel image")
    if img.shape[2] != need:
        raise ValueError(f"order {order!r} needs {need} channels, image has {img.shape[2]}")
    ir, ig, ib = ORDERS[order]
    wr, wg, wb = LUMA_WEIGHTS_RGB
    if (
        dtype == np.float32
    ):  # one OpenCV pass over the pixels, weights in B, G, R order of the array
        w = np.zeros((1, img.shape[2]), np.float32)
        w[0, ir], w[0, ig], w[0, ib] = wr, wg, wb
        # In blocks of _ROWS rows: each block's float32 copy stays in cache and small, instead of a
        # frame-sized HxWxC float32 temporary (same values; its page faults cost more than the sum).
        out = np.empty(img.shape[:2], np.float32)
        for r0 in range(0, img.shape[0], _ROWS):
            blk = img[r0 : r0 + _ROWS]
            out[r0 : r0 + _ROWS] = cv2.transform(blk.astype(np.float32, copy=False), w).reshape(
                blk.shape[:2]
            )
        return out
    out = wr * img[:, :, ir].astype(np.float64)
    out += wg * img[:, :, ig]
    out += wb * img[:, :, ib]
    return out
