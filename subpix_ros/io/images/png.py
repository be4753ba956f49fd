"""PNG files of products: fpng for 8-bit colour where it is installed, OpenCV otherwise.

A 3840x2160 BGR super-resolved image takes OpenCV's libpng/zlib encoder about 0.23 s of CPU
(0.19 s even uncompressed: the filters and checksums); fpng [1]_ writes a valid PNG of
about the same size in about 0.04 s. ``subpix process`` writes two such images per set, so
the encoder is a large part of its CPU (figures in docs/design-notes.md).

fpng encodes only 8-bit RGB and RGBA; everything else (mono, 16-bit, float), and every
image when the ``fpng`` module is missing or fails, goes through ``cv2.imwrite``. Both decode
to the same pixels: only the file's compressed bytes differ.

References
----------
.. [1] R. Geldreich, "fpng: super fast C++ .PNG writer/reader",
   https://github.com/richgel999/fpng (Python binding: https://github.com/dofuuz/py-fpng-nb).
"""

from __future__ import annotations

import os
from pathlib import Path

import cv2
import numpy as np

__all__ = ["encode_png", "write_png", "fast_png_available"]

_PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
_fpng_ext = None
_fpng_tried = False


def _fpng():
    """Return fpng's extension module, or None (missing, or ``SUBPIX_NO_FPNG`` set)."""
    global _fpng_ext, _fpng_tried
    if not _fpng_tried:
        _fpng_tried = True
        if not os.environ.get("SUBPIX_NO_FPNG"):
            try:
                from fpng import fpng_ext  # optional dependency

                _fpng_ext = fpng_ext
            except Exception:  # ImportError, or a broken binary wheel: OpenCV does it
                _fpng_ext = None
    return _fpng_ext


def fast_png_available() -> bool:
    """Return True if 8-bit colour images are written by fpng."""
    return _fpng() is not None


def encode_png(image: np.ndarray) -> bytes:
    """Encode ``image`` (OpenCV order: mono, BGR or BGRA; 8 or 16 bit) as PNG bytes.

    Parameters
    ----------
    image : numpy.ndarray
        (H, W), (H, W, 3) BGR or (H, W, 4) BGRA, uint8 or uint16.

    Returns
    -------
    bytes
        A PNG file. 8-bit BGR/BGRA goes through fpng (channels swapped to RGB/RGBA, the
        order PNG stores) when it is available; otherwise ``cv2.imencode`` (its defaults).

    Raises
    ------
    ValueError
        If neither encoder can write the image.
    """
    a = np.asarray(image)
    ext = _fpng()
    if ext is not None and a.dtype == np.uint8 and a.ndim == 3 and a.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2RGB if a.shape[2] == 3 else cv2.COLOR_BGRA2RGBA
        rgb = np.ascontiguousarray(cv2.cvtColor(a, code))
        try:
            out = bytes(ext.encode_ndarray(rgb))
        except Exception:  # an unexpected array the binding refuses: OpenCV writes it
            out = b""
        if out.startswith(_PNG_SIGNATURE):  # fpng returns b"" on failure (no exception)
            return out
    try:
        ok, buf = cv2.imencode(".png", a)
    except cv2.error:
        ok = False
    if not ok:
        raise ValueError(f"cannot encode a {a.dtype} {a.shape} image as PNG")
    return buf.tobytes()


def write_png(path: str | os.PathLike, image: np.ndarray) -> None:
    """Write ``image`` as a PNG file at ``path`` (see :func:`encode_png`).

    Raises
    ------
    OSError
        If the file cannot be written.
    """
    data = encode_png(image)
    Path(path).write_bytes(data)
