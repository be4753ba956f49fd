"""sensor_msgs/Image and sensor_msgs/CompressedImage <-> numpy (numpy/OpenCV only).

Messages are duck-typed: any object with ``height``, ``width``, ``encoding``,
``is_bigendian``, ``step`` and ``data`` works (rclpy ``sensor_msgs.msg.Image``,
a rosbags ``Image``, a dataclass). ``data`` may be ``bytes``, ``bytearray``,
``array.array('B')``, ``memoryview`` or a numpy ``uint8`` array.

Array conventions (shared by all of subpix_ros): images are numpy arrays,
mono ``H x W`` or colour ``H x W x C``; colour is in OpenCV BGR(A) order unless
the encoding says otherwise. Row ``r`` of the message is row ``r`` of the array
(no flips); pixel values are not rescaled except where stated below.

Supported encodings (ROS ``sensor_msgs/image_encodings`` names):

* plain: ``mono8 mono16 bgr8 rgb8 bgra8 rgba8 bgr16 rgb16 bgra16 rgba16`` and
  the generic ``{8,16,32,64}{U,S,F}C{1..4}`` (``8UC1``, ``16UC1``, ``32FC1`` ...;
  valid depths 8U 8S 16U 16S 32S 32F 64F);
* Bayer mosaics ``bayer_rggb8 bayer_bggr8 bayer_gbrg8 bayer_grbg8`` (and the
  ``...16`` variants): demosaiced with OpenCV (bilinear) to BGR; each pixel
  keeps its own measured colour sample, except the 1-pixel image border,
  which OpenCV fills from its neighbours;
* packed YUV 4:2:2: ``yuv422`` = ``uyvy`` (byte order U Y0 V Y1) and
  ``yuv422_yuy2`` = ``yuyv`` (Y0 U Y1 V), old and new names: decoded with
  OpenCV (BT.601) to BGR8.

``desired`` in :func:`image_to_numpy` (decided here, documented once):

* ``"passthrough"`` -- the image as stored, no colour or depth conversion.
  For plain encodings this is a **zero-copy view** into ``data`` (read-only
  when ``data`` is ``bytes``; copy it before writing), ``H x W`` for one
  channel, ``H x W x C`` otherwise, native byte order. Bayer and YUV
  encodings are not usable arrays as stored, so they are decoded to BGR
  (Bayer keeps its bit depth; YUV gives uint8).
* ``"raw"`` -- the stored samples without any decoding, also a zero-copy view:
  Bayer as the ``H x W`` mosaic, YUV 4:2:2 as ``H x W x 2`` bytes.
* ``"bgr8"`` -- ``H x W x 3`` uint8 BGR. Mono is replicated to three channels,
  RGB is reordered, alpha dropped; 16-bit data is scaled by 255/65535 (rounded).
* ``"mono8"`` -- ``H x W`` uint8 luminance: OpenCV's BT.601
  ``Y = 0.299 R + 0.587 G + 0.114 B`` for colour, Bayer demosaiced to grey,
  the video-range Y plane rescaled to 0..255 for YUV; 16-bit scaled by 255/65535.
* ``"mono"`` -- ``H x W`` single-channel luminance in the stored bit depth
  (uint8 stays uint8, 16-bit stays uint16, single-channel signed/float stays
  as is). Float luminance with the METHODS.md A weights is left to ``core``.

Float and signed images have no defined display scale: asking for ``bgr8`` or
``mono8`` from them raises. Generic encodings (``8UC3`` ...) have no colour
order: they convert only to a target with the same number of channels.

Size rules: ``height`` and ``width`` must be positive; ``step`` (bytes per row)
must be at least ``width * channels * bytes_per_sample``; ``data`` must hold
exactly ``step * height`` bytes. Longer data is bad input (issue 7) and is
rejected with the byte counts in the message; pass ``allow_trailing=True`` to
accept and ignore trailing bytes. Every violation raises
:class:`ImageConversionError` (a ``ValueError``) naming the problem; a garbled
array is never returned. Float images may contain NaN/Inf: they are converted
as they are, and :func:`finite_fraction` / :func:`require_finite` let callers
reject them.

Memory: a plain passthrough never copies, so an 8000 x 6000 frame costs no
extra memory; conversions allocate only their output (plus one byte-swapped
copy for big-endian multi-byte data).
"""

from __future__ import annotations

import difflib
import re
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

__all__ = [
    "ImageConversionError",
    "EncodingInfo",
    "DESIRED",
    "KNOWN_ENCODINGS",
    "encoding_info",
    "image_to_numpy",
    "numpy_to_image_fields",
    "compressed_to_numpy",
    "numpy_to_compressed",
    "finite_fraction",
    "require_finite",
    "FrameFormatTracker",
]

DESIRED = ("passthrough", "raw", "bgr8", "mono8", "mono")


class ImageConversionError(ValueError):
    """An image message (or array) that cannot be converted; the message says why."""


@dataclass(frozen=True)
class EncodingInfo:
    """How an encoding is laid out in ``data``.

    ``channels`` counts the stored samples per pixel (Bayer: 1, YUV 4:2:2: 2
    bytes per pixel), ``dtype`` is the sample type in native byte order,
    ``kind`` is ``"plain"``, ``"bayer"`` or ``"yuv422"``, ``order`` is the colour
    order (``"mono"``, ``"bgr"``, ``"rgb"``, ``"bgra"``, ``"rgba"``), the Bayer
    pattern (``"rggb"`` ...), the YUV byte order (``"uyvy"``, ``"yuyv"``) or
    ``"generic"`` (no colour meaning).
    """

    name: str
    channels: int
    dtype: np.dtype
    kind: str
    order: str

    @property
    def pixel_bytes(self) -> int:
        """Bytes per pixel in ``data`` (channels x bytes per sample)."""
        return self.channels * self.dtype.itemsize


_U8 = np.dtype(np.uint8)
_U16 = np.dtype(np.uint16)


def _named_encodings() -> dict[str, EncodingInfo]:
    enc: dict[str, EncodingInfo] = {}
    for order, ch in (("mono", 1), ("bgr", 3), ("rgb", 3), ("bgra", 4), ("rgba", 4)):
        for bits, dt in ((8, _U8), (16, _U16)):
            name = f"{order}{bits}"
            enc[name] = EncodingInfo(name, ch, dt, "plain", order)
    for pattern in ("rggb", "bggr", "gbrg", "grbg"):
        for bits, dt in ((8, _U8), (16, _U16)):
            name = f"bayer_{pattern}{bits}"
            enc[name] = EncodingInfo(name, 1, dt, "bayer", pattern)
    for name, order in (
        ("yuv422", "uyvy"),
        ("uyvy", "uyvy"),
        ("yuv422_yuy2", "yuyv"),
        ("yuyv", "yuyv"),
    ):
        enc[name] = EncodingInfo(name, 2, _U8, "yuv422", order)
    return enc


_NAMED = _named_encodings()
_GENERIC_DEPTHS = {
    "8U": np.uint8,
    "8S": np.int8,
    "16U": np.uint16,
    "16S": np.int16,
    "32S": np.int32,
    "32F": np.float32,
    "64F": np.float64,
}
_GENERIC_RE = re.compile(r"^(8|16|32|64)([USF])C([1-4])$")
KNOWN_ENCODINGS: tuple[str, ...] = tuple(_NAMED) + tuple(
    f"{depth}C{c}" for depth in _GENERIC_DEPTHS for c in (1, 2, 3, 4)
)

# OpenCV codes. The explicit RGGB/BGGR/... names equal cv_bridge's mapping
# (bayer_rggb8 -> COLOR_BayerBG2BGR etc.); test_images checks them on colour data.
_BAYER_TO_BGR = {
    "rggb": cv2.COLOR_BayerRGGB2BGR,
    "bggr": cv2.COLOR_BayerBGGR2BGR,
    "gbrg": cv2.COLOR_BayerGBRG2BGR,
    "grbg": cv2.COLOR_BayerGRBG2BGR,
}
_BAYER_TO_GRAY = {
    "rggb": cv2.COLOR_BayerRGGB2GRAY,
    "bggr": cv2.COLOR_BayerBGGR2GRAY,
    "gbrg": cv2.COLOR_BayerGBRG2GRAY,
    "grbg": cv2.COLOR_BayerGRBG2GRAY,
}
# Which BGR channel (0 B, 1 G, 2 R) sits at mosaic positions (0,0) (0,1) (1,0) (1,1).
_BAYER_LAYOUT = {
    "rggb": (2, 1, 1, 0),
    "bggr": (0, 1, 1, 2),
    "gbrg": (1, 0, 2, 1),
    "grbg": (1, 2, 0, 1),
}
_YUV_TO_BGR = {"uyvy": cv2.COLOR_YUV2BGR_UYVY, "yuyv": cv2.COLOR_YUV2BGR_YUYV}
_BGR_TO_YUV = {"uyvy": cv2.COLOR_BGR2YUV_UYVY, "yuyv": cv2.COLOR_BGR2YUV_YUYV}
_TO_BGR = {"rgb": cv2.COLOR_RGB2BGR, "bgra": cv2.COLOR_BGRA2BGR, "rgba": cv2.COLOR_RGBA2BGR}
_TO_GRAY = {
    "bgr": cv2.COLOR_BGR2GRAY,
    "rgb": cv2.COLOR_RGB2GRAY,
    "bgra": cv2.COLOR_BGRA2GRAY,
    "rgba": cv2.COLOR_RGBA2GRAY,
}


def encoding_info(encoding: str) -> EncodingInfo:
    """Layout of ``encoding``; unknown names raise with the closest known name."""
    if not isinstance(encoding, str):
        raise ImageConversionError(f"encoding must be a string, got {type(encoding).__name__}")
    info = _NAMED.get(encoding)
    if info is not None:
        return info
    m = _GENERIC_RE.match(encoding)
    if m and f"{m.group(1)}{m.group(2)}" in _GENERIC_DEPTHS:
        dt = np.dtype(_GENERIC_DEPTHS[f"{m.group(1)}{m.group(2)}"])
        return EncodingInfo(encoding, int(m.group(3)), dt, "plain", "generic")
    if encoding == "":
        raise ImageConversionError("empty image encoding (expected e.g. 'bgr8', 'mono8', '32FC1')")
    candidates = {name.lower(): name for name in KNOWN_ENCODINGS}
    close = difflib.get_close_matches(encoding.lower(), list(candidates), n=1, cutoff=0.5)
    hint = f"; did you mean {candidates[close[0]]!r}?" if close else ""
    raise ImageConversionError(f"unknown image encoding {encoding!r}{hint}")


def _as_byte_buffer(data: Any) -> np.ndarray:
    """``data`` as a 1-D uint8 array, zero-copy for buffer objects."""
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
    """``a`` if OpenCV can wrap it (rows may be padded), else a contiguous copy."""
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

    ``desired`` is one of ``"passthrough"``, ``"raw"``, ``"bgr8"``, ``"mono8"``,
    ``"mono"`` (see the module docstring for the exact meaning; passthrough of
    plain encodings is a zero-copy view into ``msg.data``). Honours ``step``
    (row padding, bytes) and ``is_bigendian``. Raises
    :class:`ImageConversionError` for any inconsistent message.
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
    """The samples to store for ``info``, shape (H, W) or (H, W, C), dtype info.dtype."""
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
    """Fields of a sensor_msgs/Image holding ``array`` in ``encoding``.

    Returns ``{"height", "width", "encoding", "is_bigendian", "step", "data"}``
    with ``data`` a contiguous 1-D uint8 array of ``step * height`` bytes.
    ``step`` (bytes per row) defaults to the packed row size; a larger step
    pads each row with zero bytes. ``bigendian`` stores multi-byte samples
    big-endian. Plain encodings need the matching dtype and channel count (no
    silent casts). Bayer encodings take a BGR image (mosaiced here, for tests
    and simulators) or an already-mosaiced ``H x W`` array; YUV 4:2:2 encodings
    take BGR8 (converted by OpenCV, BT.601) or packed ``H x W x 2`` bytes.
    When the array is already C-contiguous, unpadded and native-endian,
    ``data`` is a zero-copy view of it.
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


def finite_fraction(image: np.ndarray) -> float:
    """Fraction (0..1) of samples that are finite (not NaN/Inf); 1.0 for integer images."""
    a = np.asarray(image)
    if a.size == 0:
        raise ImageConversionError("finite_fraction of an empty image")
    if not np.issubdtype(a.dtype, np.floating):
        return 1.0
    return float(np.count_nonzero(np.isfinite(a))) / a.size


def require_finite(image: np.ndarray, min_fraction: float = 1.0, what: str = "image") -> np.ndarray:
    """Return ``image`` if at least ``min_fraction`` of its samples are finite, else raise.

    Callers use it to reject float (e.g. 32FC1) frames with NaN/Inf before
    numerical work; the error names the measured fraction.
    """
    if not 0.0 <= min_fraction <= 1.0:
        raise ValueError(f"min_fraction must be in [0, 1], got {min_fraction}")
    frac = finite_fraction(image)
    if frac < min_fraction:
        raise ImageConversionError(
            f"{what} has non-finite samples (NaN/Inf): {100.0 * frac:.3f}% finite, need >= {100.0 * min_fraction:.3f}%"
        )
    return image


class FrameFormatTracker:
    """Notices when the size or encoding of a stream's frames changes mid-stream.

    ``update(height, width, encoding)`` returns ``None`` for the first frame and
    for frames in the current format, and a one-line description
    (``"frame format changed mid-stream: 1920x1080 bgr8 -> 1280x720 bgr8"``)
    when it changes; the new format then becomes current and ``changes``
    counts the switches. Callers decide what to do (typically: log it and
    reset state that depends on the frame size, e.g. the previous frame).
    """

    def __init__(self) -> None:
        self.current: tuple[int, int, str] | None = None
        self.changes = 0

    def update(self, height: int, width: int, encoding: str) -> str | None:
        fmt = (int(height), int(width), str(encoding))
        if self.current is None or fmt == self.current:
            self.current = fmt
            return None
        old, self.current = self.current, fmt
        self.changes += 1
        return (
            f"frame format changed mid-stream: {old[1]}x{old[0]} {old[2]} -> {fmt[1]}x{fmt[0]} {fmt[2]} "
            f"(width x height)"
        )

    def update_from(self, msg: Any) -> str | None:
        """:meth:`update` with the fields of an Image message."""
        return self.update(msg.height, msg.width, msg.encoding)


# ---------------------------------------------------------------------------- compressed

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

    ``format`` as image_transport writes it (``"bgr8; jpeg compressed bgr8"``,
    ``"mono16; png compressed mono16"``) or plain ``"jpeg"`` / ``"png"`` (empty:
    detected from the data). ``passthrough`` returns what the codec stores: BGR
    for colour (also when the original encoding was rgb8), ``H x W`` for mono,
    uint16 for 16-bit PNG, BGRA for PNG with alpha. ``bgr8`` / ``mono8`` /
    ``mono`` convert as :func:`image_to_numpy` does. Empty, truncated (no
    JPEG end-of-image marker / PNG IEND chunk), mislabelled or undecodable
    data raises :class:`ImageConversionError`. Limitation: bytes damaged
    *inside* a JPEG's entropy-coded scan can still decode (libjpeg only warns
    and OpenCV does not report it); PNG's per-chunk CRC catches that case.
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
    """Compress ``array`` for a sensor_msgs/CompressedImage: ``(format_string, data)``.

    The encoding is read from the array: uint8 ``H x W`` mono8, ``H x W x 3``
    bgr8, ``H x W x 4`` bgra8 (PNG only), uint16 mono16 / bgr16 (PNG only).
    The format string is image_transport's, e.g. ``"bgr8; jpeg compressed
    bgr8"``. ``quality`` is the JPEG quality 1..100; ``png_level`` the PNG
    compression level 0..9.
    """
    fmt_l = fmt.lower()
    if fmt_l in ("jpg", "jpeg"):
        codec = "jpeg"
    elif fmt_l == "png":
        codec = "png"
    else:
        raise ImageConversionError(f"compressed format {fmt!r} is not supported (jpeg or png)")
    a = np.asarray(array)
    if a.ndim not in (2, 3) or a.size == 0 or (a.ndim == 3 and a.shape[2] not in (3, 4)):
        raise ImageConversionError(
            f"cannot compress an array of shape {a.shape}: need H x W, H x W x 3 or H x W x 4"
        )
    if a.dtype not in (_U8, _U16):
        raise ImageConversionError(f"cannot compress {a.dtype} images (uint8, or uint16 for PNG)")
    bits = 8 if a.dtype == np.uint8 else 16
    enc = ("mono" if a.ndim == 2 else {3: "bgr", 4: "bgra"}[a.shape[2]]) + str(bits)
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
    return f"{enc}; {codec} compressed {enc}", out.tobytes()
