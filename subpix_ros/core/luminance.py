"""Luminance of colour frames, exactly as the seed (METHODS.md A).

    gray = 0.2989 R + 0.587 G + 0.1141 B                         (METHODS A, luminance)

Values keep their digital-number scale (uint8 0..255 stays 0..255, uint16
0..65535 stays 0..65535, float stays as given); the output is always float64
so later sums accumulate in double precision.
"""
from __future__ import annotations

import numpy as np

__all__ = ["luminance", "LUMA_WEIGHTS_RGB", "ORDERS"]

#: Seed weights for (R, G, B).
LUMA_WEIGHTS_RGB = (0.2989, 0.587, 0.1141)

#: Accepted channel orders and, for each, the index of R, G and B.
ORDERS = {
    "bgr": (2, 1, 0),
    "rgb": (0, 1, 2),
    "bgra": (2, 1, 0),
    "rgba": (0, 1, 2),
    "mono": None,
}


def luminance(image: np.ndarray, order: str = "bgr") -> np.ndarray:
    """Seed luminance ``0.2989 R + 0.587 G + 0.1141 B`` as float64 HxW.

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
    img = np.asarray(image)
    if img.dtype == bool or not (np.issubdtype(img.dtype, np.integer) or np.issubdtype(img.dtype, np.floating)):
        raise ValueError(f"image dtype {img.dtype} is not an integer or float type")
    if img.ndim == 3 and img.shape[2] == 1:
        img = img[:, :, 0]
    if img.ndim == 2:
        return img.astype(np.float64, copy=True)
    if img.ndim != 3:
        raise ValueError(f"image must be HxW or HxWxC, got shape {img.shape}")
    need = 4 if order.endswith("a") else 3
    if order == "mono":
        raise ValueError(f"order 'mono' given for a {img.shape[2]}-channel image")
    if img.shape[2] != need:
        raise ValueError(f"order {order!r} needs {need} channels, image has {img.shape[2]}")
    ir, ig, ib = ORDERS[order]
    wr, wg, wb = LUMA_WEIGHTS_RGB
    out = wr * img[:, :, ir].astype(np.float64)
    out += wg * img[:, :, ig]
    out += wb * img[:, :, ib]
    return out
