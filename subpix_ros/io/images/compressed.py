"""sensor_msgs/CompressedImage (JPEG, PNG) <-> numpy arrays, through OpenCV."""

from __future__ import annotations

from typing import Any

import cv2
import numpy as np

from .encodings import _U8, _U16, ImageConversionError, encoding_info
from .raw import _as_byte_buffer, _convert, _cv_input

_JPEG_MAGIC = b"\xff\xd8\xff"
_PNG_MAGIC = b"\x89PNG\r\n\x1a\n"


def _codec_of(fmt: str, head: bytes) -> str:
    f = fmt.strip().lower()
    if "compresseddepth" in f:
        raise ImageConversionError(
            f"CompressedImage format {fmt!r} (compressedDepth) is not supported"
        )
    if "jpeg" in f or "jpg" in f:
        return "jpeg"
    if "png" in f:
        return "png"
    if f == "":
        if head.startswith(_JPEG_MAGIC):
            return "jpeg"
        if head.startswith(_PNG_MAGIC):
            return "png"
        raise ImageConversionError(
            "CompressedImage has an empty format and data that is neither JPEG nor PNG"
        )
    raise ImageConversionError(f"CompressedImage format {fmt!r} is not supported (jpeg or png)")


def compressed_to_numpy(msg: Any, desired: str = "passthrough") -> np.ndarray:
    """Decode a sensor_msgs/CompressedImage-like message (``format``, ``data``).

    Parameters
    ----------
    msg : object
        ``format`` as image_transport writes it (``"bgr8; jpeg compressed bgr8"``,
        ``"mono16; png compressed mono16"``) or plain ``"jpeg"`` / ``"png"`` (empty: detected
        from the data).
    desired : str
        ``passthrough`` returns what the codec stores: BGR for colour (also when the original
        encoding was rgb8), ``H x W`` for mono, uint16 for 16-bit PNG, BGRA for PNG with alpha;
        ``bgr8`` / ``mono8`` / ``mono`` convert as :func:`image_to_numpy` does.

    Returns
    -------
    numpy.ndarray
        The decoded image.

    Raises
    ------
    ImageConversionError
        Empty, truncated (no JPEG end-of-image marker / PNG IEND chunk), mislabelled or
        undecodable data.

    Notes
    -----
    Bytes damaged *inside* a JPEG's entropy-coded scan can still decode (libjpeg only warns and
    OpenCV does not report it); PNG's per-chunk CRC catches that case.
    """
    fmt = getattr(msg, "format", None)
    if not isinstance(fmt, str):
        raise ImageConversionError(f"CompressedImage format must be a string, got {fmt!r}")
    buf = _as_byte_buffer(getattr(msg, "data", b""))
    if buf.size == 0:
        raise ImageConversionError("CompressedImage has no data")
    head = buf[:8].tobytes()
    codec = _codec_of(fmt, head)
    if codec == "jpeg":
        if not head.startswith(_JPEG_MAGIC):
            raise ImageConversionError(
                f"CompressedImage format {fmt!r} but data does not start with a JPEG marker"
            )
        tail = np.flatnonzero(buf[-4096:])  # some drivers pad with zero bytes after EOI
        end = buf.size - min(buf.size, 4096) + (int(tail[-1]) + 1 if tail.size else 0)
        if end < 4 or buf[end - 2] != 0xFF or buf[end - 1] != 0xD9:
            raise ImageConversionError(
                "corrupt CompressedImage: JPEG data is truncated (no end-of-image marker)"
            )
    else:
        if not head.startswith(_PNG_MAGIC):
            raise ImageConversionError(
                f"CompressedImage format {fmt!r} but data does not start with the PNG signature"
            )
        if buf.size < 20 or buf[-12:-4].tobytes() != b"\x00\x00\x00\x00IEND":
            raise ImageConversionError(
                "corrupt CompressedImage: PNG data is truncated (no IEND chunk)"
            )
    try:
        img = cv2.imdecode(buf, cv2.IMREAD_UNCHANGED)
    except cv2.error as exc:
        raise ImageConversionError(
            f"corrupt CompressedImage: OpenCV cannot decode the {codec}: {exc.err}"
        ) from None
    if img is None or img.size == 0:
        raise ImageConversionError(
            f"corrupt CompressedImage: OpenCV cannot decode the {codec} data"
        )
    if img.ndim == 2:
        enc = "mono8" if img.dtype == np.uint8 else "mono16"
    else:
        enc = {3: "bgr", 4: "bgra"}[img.shape[2]] + ("8" if img.dtype == np.uint8 else "16")
    if desired == "passthrough":
        return img
    return _convert(img, encoding_info(enc), desired)


def numpy_to_compressed(
    array: np.ndarray, fmt: str = "jpeg", quality: int = 90, *, png_level: int = 3
) -> tuple[str, bytes]:
    """Compress ``array`` for a sensor_msgs/CompressedImage.

    Parameters
    ----------
    array : numpy.ndarray
        uint8 ``H x W`` (mono8), ``H x W x 3`` (bgr8), ``H x W x 4`` (bgra8, PNG only); uint16
        mono16 / bgr16 (PNG only).
    fmt : str
        ``"jpeg"`` or ``"png"``.
    quality : int
        JPEG quality 1..100.
    png_level : int
        PNG compression level 0..9.

    Returns
    -------
    tuple of (str, bytes)
        image_transport's format string (e.g. ``"bgr8; jpeg compressed bgr8"``) and the data.
    """
    fmt_l = fmt.lower()
    if fmt_l in ("jpg", "jpeg"):
        codec = "jpeg"
    elif fmt_l == "png":
        codec = "png"
    else:
        raise ImageConversionError(f"compressed format {fmt!r} is not supported (jpeg or png)")
    a = np.asarray(array)
    enc = compressible_encoding(a)
    if codec == "jpeg":
        if enc not in ("mono8", "bgr8"):
            raise ImageConversionError(f"JPEG cannot store {enc}; use fmt='png'")
        if not 1 <= int(quality) <= 100:
            raise ImageConversionError(f"JPEG quality must be 1..100, got {quality}")
        ok, out = cv2.imencode(".jpg", _cv_input(a), [cv2.IMWRITE_JPEG_QUALITY, int(quality)])
    else:
        if not 0 <= int(png_level) <= 9:
            raise ImageConversionError(f"PNG level must be 0..9, got {png_level}")
        ok, out = cv2.imencode(".png", _cv_input(a), [cv2.IMWRITE_PNG_COMPRESSION, int(png_level)])
    if not ok:
        raise ImageConversionError(f"OpenCV failed to encode {enc} as {codec}")
    return compressed_format(enc, codec), out.tobytes()


def compressible_encoding(array: np.ndarray) -> str:
    """Return the encoding of an array a CompressedImage can hold (``mono8`` ... ``bgra16``).

    Raises ImageConversionError for any other shape or type (H x W, H x W x 3 BGR or
    H x W x 4 BGRA; uint8 or uint16).
    """
    a = np.asarray(array)
    if a.ndim not in (2, 3) or a.size == 0 or (a.ndim == 3 and a.shape[2] not in (3, 4)):
        raise ImageConversionError(
            f"cannot compress an array of shape {a.shape}: need H x W, H x W x 3 or H x W x 4"
        )
    if a.dtype not in (_U8, _U16):
        raise ImageConversionError(f"cannot compress {a.dtype} images (uint8, or uint16 for PNG)")
    bits = 8 if a.dtype == np.uint8 else 16
    return ("mono" if a.ndim == 2 else {3: "bgr", 4: "bgra"}[a.shape[2]]) + str(bits)


def compressed_format(encoding: str, codec: str) -> str:
    """Return image_transport's format string, e.g. ``"bgr8; png compressed bgr8"``."""
    return f"{encoding}; {codec} compressed {encoding}"
