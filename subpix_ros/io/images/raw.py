"""sensor_msgs/Image fields <-> numpy arrays (zero-copy views where the layout allows)."""

from __future__ import annotations

import difflib
from typing import Any

import cv2
import numpy as np

from .encodings import (
    _BAYER_LAYOUT,
    _BAYER_TO_BGR,
    _BAYER_TO_GRAY,
    _BGR_TO_YUV,
    _TO_BGR,
    _TO_GRAY,
    _U8,
    _U16,
    _YUV_TO_BGR,
    DESIRED,
    EncodingInfo,
    ImageConversionError,
    encoding_info,
)


def _as_byte_buffer(data: Any) -> np.ndarray:
    """View ``data`` as a 1-D uint8 array, zero-copy for buffer objects."""
    if isinstance(data, np.ndarray):
        if data.dtype != np.uint8:
            raise ImageConversionError(f"image data array must be uint8, got {data.dtype}")
        return data.reshape(-1)
    if isinstance(data, (list, tuple)):
        try:
            return np.asarray(data, dtype=np.uint8)
        except (OverflowError, ValueError, TypeError) as exc:
            raise ImageConversionError(
                f"image data is not a sequence of bytes 0..255: {exc}"
            ) from None
    try:
        return np.frombuffer(data, dtype=np.uint8)
    except (TypeError, ValueError, BufferError):
        pass
    try:  # non-contiguous or non-byte memoryviews: one copy
        return np.frombuffer(memoryview(data).tobytes(), dtype=np.uint8)
    except TypeError:
        raise ImageConversionError(
            f"image data of type {type(data).__name__} is not a byte buffer"
        ) from None


def _field_int(msg: Any, name: str) -> int:
    try:
        value = getattr(msg, name)
    except AttributeError:
        raise ImageConversionError(f"image message has no field {name!r}") from None
    if isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, np.integer)):
        raise ImageConversionError(f"image {name} must be an integer, got {value!r}")
    return int(value)


def _stored_view(msg: Any, *, allow_trailing: bool = False) -> tuple[np.ndarray, EncodingInfo]:
    """Validate ``msg`` and return the stored samples as an array (view if possible).

    Shape ``(H, W)`` for one sample per pixel, else ``(H, W, C)``; strides
    ``(step, C*itemsize, itemsize)`` over ``data``. Big-endian multi-byte data
    is returned as a native-order copy.
    """
    try:
        encoding = msg.encoding
    except AttributeError:
        raise ImageConversionError("image message has no field 'encoding'") from None
    info = encoding_info(encoding)
    height, width, step = (_field_int(msg, f) for f in ("height", "width", "step"))
    if height <= 0 or width <= 0:
        raise ImageConversionError(
            f"{encoding} image has zero or negative size {height}x{width} (height x width)"
        )
    row_bytes = width * info.pixel_bytes
    if step < row_bytes:
        raise ImageConversionError(
            f"{encoding} image step {step} is smaller than one row: width {width} x {info.pixel_bytes} bytes "
            f"per pixel = {row_bytes}"
        )
    if info.kind == "yuv422" and width % 2:
        raise ImageConversionError(f"{encoding} (YUV 4:2:2) needs an even width, got {width}")
    if info.kind == "bayer" and (width % 2 or height % 2):
        raise ImageConversionError(
            f"{encoding} (Bayer) needs even width and height, got {height}x{width}"
        )
    try:
        data = msg.data
    except AttributeError:
        raise ImageConversionError("image message has no field 'data'") from None
    buf = _as_byte_buffer(data)
    expected = step * height
    if buf.size < expected:
        raise ImageConversionError(
            f"{encoding} image data too short: {buf.size} bytes, expected step*height = {step}*{height} = {expected}"
        )
    if buf.size > expected and not allow_trailing:
        raise ImageConversionError(
            f"{encoding} image data too long: {buf.size} bytes, expected step*height = {step}*{height} = {expected} "
            f"({buf.size - expected} extra bytes; wrong height/step, or pass allow_trailing=True to ignore them)"
        )
    itemsize = info.dtype.itemsize
    bigendian = bool(getattr(msg, "is_bigendian", 0))
    dtype = info.dtype.newbyteorder(">" if bigendian else "<") if itemsize > 1 else info.dtype
    if info.channels == 1:
        shape: tuple[int, ...] = (height, width)
        strides: tuple[int, ...] = (step, itemsize)
    else:
        shape = (height, width, info.channels)
        strides = (step, info.channels * itemsize, itemsize)
    arr = np.ndarray(shape=shape, dtype=dtype, buffer=buf, offset=0, strides=strides)
    if not dtype.isnative:
        arr = arr.astype(dtype.newbyteorder("="))
    return arr, info


def _cv_input(a: np.ndarray) -> np.ndarray:
    """Return ``a`` if OpenCV can wrap it (rows may be padded), else a contiguous copy."""
    inner_ok = (
        a.strides[-1] == a.itemsize
        if a.ndim == 2
        else (a.strides[2] == a.itemsize and a.strides[1] == a.shape[2] * a.itemsize)
    )
    if inner_ok and a.flags.aligned and a.strides[0] % a.itemsize == 0:
        return a
    return np.ascontiguousarray(a)


def _to_8bit(a: np.ndarray) -> np.ndarray:
    """uint8 as is; uint16 scaled by 255/65535 and rounded (0 -> 0, 65535 -> 255)."""
    if a.dtype == np.uint8:
        return a
    if a.dtype == np.uint16:
        return cv2.convertScaleAbs(_cv_input(a), alpha=255.0 / 65535.0)
    raise ImageConversionError(
        f"{a.dtype} samples have no defined 8-bit scale; use desired='passthrough' or 'mono'"
    )


def _decode_stored(arr: np.ndarray, info: EncodingInfo) -> tuple[np.ndarray, str]:
    """Bayer/YUV to BGR; plain stays. Returns (array, colour order)."""
    if info.kind == "bayer":
        return cv2.cvtColor(_cv_input(arr), _BAYER_TO_BGR[info.order]), "bgr"
    if info.kind == "yuv422":
        return cv2.cvtColor(_cv_input(arr), _YUV_TO_BGR[info.order]), "bgr"
    return arr, info.order


def _convert(arr: np.ndarray, info: EncodingInfo, desired: str) -> np.ndarray:
    name = info.name
    if desired == "raw":
        return arr
    if desired == "passthrough":
        return _decode_stored(arr, info)[0]
    if desired not in DESIRED:
        close = difflib.get_close_matches(str(desired), DESIRED, n=1, cutoff=0.4)
        hint = f"; did you mean {close[0]!r}?" if close else ""
        raise ImageConversionError(
            f"unknown desired format {desired!r} (one of {', '.join(DESIRED)}){hint}"
        )
    # Luminance straight from the stored samples where OpenCV can (no BGR detour).
    if desired in ("mono8", "mono") and info.kind == "yuv422":
        # OpenCV's 4:2:2 is BT.601 video range: Y' in 16..235. The grey of the
        # decoded BGR is 255/219 (Y' - 16) (the chroma terms cancel in the
        # 0.299/0.587/0.114 sum), so scale the Y plane instead of decoding.
        y_plane = arr[..., 1] if info.order == "uyvy" else arr[..., 0]
        return cv2.convertScaleAbs(
            _cv_input(y_plane), alpha=255.0 / 219.0, beta=-16.0 * 255.0 / 219.0
        )
    if desired in ("mono8", "mono") and info.kind == "bayer":
        gray = cv2.cvtColor(_cv_input(arr), _BAYER_TO_GRAY[info.order])
        return _to_8bit(gray) if desired == "mono8" else gray
    if desired == "bgr8" and info.kind != "plain":
        return _to_8bit(_decode_stored(arr, info)[0])
    if info.order == "generic":
        if desired != "mono" and info.dtype not in (_U8, _U16):
            raise ImageConversionError(
                f"{name} ({info.dtype}) has no defined 8-bit scale; use 'passthrough' or 'mono'"
            )
        want = 3 if desired == "bgr8" else 1
        if info.channels != want:
            raise ImageConversionError(
                f"{name} has {info.channels} channel(s) and no colour order; cannot convert to {desired} "
                f"(use desired='passthrough')"
            )
        return arr if desired == "mono" else _to_8bit(arr)
    order = info.order
    if desired == "bgr8":
        out = _to_8bit(arr)
        if order == "mono":
            return cv2.cvtColor(_cv_input(out), cv2.COLOR_GRAY2BGR)
        if order == "bgr":
            return out
        return cv2.cvtColor(_cv_input(out), _TO_BGR[order])
    # mono8 / mono
    gray = arr if order == "mono" else cv2.cvtColor(_cv_input(arr), _TO_GRAY[order])
    return _to_8bit(gray) if desired == "mono8" else gray


def image_to_numpy(
    msg: Any, desired: str = "passthrough", *, allow_trailing: bool = False
) -> np.ndarray:
    """Convert a sensor_msgs/Image-like message to a numpy array.

    Parameters
    ----------
    msg : object
        Any object with ``height``, ``width``, ``encoding``, ``is_bigendian``, ``step`` and
        ``data`` (row padding and byte order are honoured).
    desired : str
        ``"passthrough"``, ``"raw"``, ``"bgr8"``, ``"mono8"`` or ``"mono"`` (see the package
        docstring; passthrough of plain encodings is a zero-copy view into ``msg.data``).
    allow_trailing : bool
        Accept and ignore bytes past ``step * height``.

    Returns
    -------
    numpy.ndarray
        ``H x W`` or ``H x W x C``.

    Raises
    ------
    ImageConversionError
        Any inconsistent message.
    """
    arr, info = _stored_view(msg, allow_trailing=allow_trailing)
    try:
        return _convert(arr, info, desired)
    except cv2.error as exc:  # should not happen after validation; never leak a cv2 traceback wall
        raise ImageConversionError(
            f"OpenCV could not convert {info.name} to {desired}: {exc.err}"
        ) from None


def _bayer_mosaic(bgr: np.ndarray, pattern: str) -> np.ndarray:
    """Sample a BGR image through a Bayer colour filter (pattern = 2x2 top-left layout)."""
    h, w = bgr.shape[:2]
    out = np.empty((h, w), dtype=bgr.dtype)
    c00, c01, c10, c11 = _BAYER_LAYOUT[pattern]
    out[0::2, 0::2] = bgr[0::2, 0::2, c00]
    out[0::2, 1::2] = bgr[0::2, 1::2, c01]
    out[1::2, 0::2] = bgr[1::2, 0::2, c10]
    out[1::2, 1::2] = bgr[1::2, 1::2, c11]
    return out


def _stored_from_array(array: np.ndarray, info: EncodingInfo) -> np.ndarray:
    """Return the samples to store for ``info``: shape (H, W) or (H, W, C), dtype info.dtype."""
    a = np.asarray(array)
    if a.ndim not in (2, 3) or a.shape[0] == 0 or a.shape[1] == 0:
        raise ImageConversionError(
            f"cannot encode an array of shape {a.shape} as {info.name}: need H x W or H x W x C, non-empty"
        )
    if info.kind == "bayer":
        if a.shape[0] % 2 or a.shape[1] % 2:
            raise ImageConversionError(
                f"{info.name} (Bayer) needs even width and height, got {a.shape[0]}x{a.shape[1]}"
            )
        if a.dtype != info.dtype:
            raise ImageConversionError(f"{info.name} needs {info.dtype} input, got {a.dtype}")
        if a.ndim == 2:  # already a mosaic
            return a
        if a.shape[2] != 3:
            raise ImageConversionError(
                f"{info.name} encodes from BGR (H x W x 3) or a raw mosaic (H x W), got {a.shape}"
            )
        return _bayer_mosaic(a, info.order)
    if info.kind == "yuv422":
        if a.shape[1] % 2:
            raise ImageConversionError(
                f"{info.name} (YUV 4:2:2) needs an even width, got {a.shape[1]}"
            )
        if a.dtype != np.uint8:
            raise ImageConversionError(f"{info.name} needs uint8 input, got {a.dtype}")
        if a.ndim == 3 and a.shape[2] == 2:  # already packed
            return a
        if a.ndim != 3 or a.shape[2] != 3:
            raise ImageConversionError(
                f"{info.name} encodes from BGR (H x W x 3) or packed H x W x 2, got {a.shape}"
            )
        return cv2.cvtColor(_cv_input(a), _BGR_TO_YUV[info.order])
    channels = 1 if a.ndim == 2 else a.shape[2]
    if channels != info.channels:
        raise ImageConversionError(
            f"{info.name} needs {info.channels} channel(s), array has shape {a.shape}"
        )
    if a.dtype != info.dtype:
        raise ImageConversionError(
            f"{info.name} needs {info.dtype} samples, array is {a.dtype} (convert it explicitly)"
        )
    return a


def numpy_to_image_fields(
    array: np.ndarray, encoding: str, *, step: int | None = None, bigendian: bool = False
) -> dict[str, Any]:
    """Build the fields of a sensor_msgs/Image holding ``array`` in ``encoding``.

    Parameters
    ----------
    array : numpy.ndarray
        Plain encodings need the matching dtype and channel count (no silent casts). Bayer
        encodings take a BGR image (mosaiced here, for tests and simulators) or an
        already-mosaiced ``H x W`` array; YUV 4:2:2 encodings take BGR8 (converted by OpenCV,
        BT.601) or packed ``H x W x 2`` bytes.
    encoding : str
        A ROS image encoding.
    step : int, optional
        Bytes per row (default the packed row size); a larger step pads each row with zeros.
    bigendian : bool
        Store multi-byte samples big-endian.

    Returns
    -------
    dict
        ``{"height", "width", "encoding", "is_bigendian", "step", "data"}`` with ``data`` a
        contiguous 1-D uint8 array of ``step * height`` bytes; a zero-copy view of ``array`` when
        it is already C-contiguous, unpadded and native-endian.
    """
    info = encoding_info(encoding)
    stored = _stored_from_array(array, info)
    height, width = stored.shape[:2]
    row_bytes = width * info.pixel_bytes
    if step is None:
        step = row_bytes
    if isinstance(step, bool) or not isinstance(step, (int, np.integer)) or step < row_bytes:
        raise ImageConversionError(
            f"step {step!r} is smaller than one {encoding} row ({row_bytes} bytes)"
        )
    step = int(step)
    swap = bigendian and info.dtype.itemsize > 1
    if swap:
        stored = stored.astype(info.dtype.newbyteorder(">"))
    if step == row_bytes:
        data = np.ascontiguousarray(stored).reshape(-1).view(np.uint8)
    else:
        rows = np.zeros((height, step), dtype=np.uint8)
        rows[:, :row_bytes] = np.ascontiguousarray(stored).reshape(height, -1).view(np.uint8)
        data = rows.reshape(-1)
    return {
        "height": int(height),
        "width": int(width),
        "encoding": encoding,
        "is_bigendian": int(bool(swap)),
        "step": step,
        "data": data,
    }
