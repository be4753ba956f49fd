"""Single-precision discrete Fourier transforms through OpenCV."""

from __future__ import annotations

import cv2
import numpy as np


def _rfft2_32(img: np.ndarray) -> np.ndarray:
    """Half-plane 2-D DFT (as ``np.fft.rfft2``) in single precision via ``cv2.dft``."""
    f = cv2.dft(np.ascontiguousarray(img, dtype=np.float32), flags=cv2.DFT_COMPLEX_OUTPUT)
    return f.view(np.complex64)[..., 0][:, : img.shape[1] // 2 + 1]


def _as_c2(z: np.ndarray) -> np.ndarray:
    """complex64 array -> 2-channel float32 view (OpenCV's complex matrices)."""
    z = np.ascontiguousarray(z, dtype=np.complex64)
    return z.view(np.float32).reshape(z.shape + (2,))
