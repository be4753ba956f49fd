"""The fast raw-CDR path for images and the small messages the nodes publish.

rclpy's own conversion of a large ``sensor_msgs/Image`` is slow: assigning a
numpy array to ``msg.data`` and ``serialize_message`` walk the buffer in
Python and copy it several times. rclpy can instead publish ready-made CDR
bytes (``publisher.publish(raw_bytes)``) and hand a subscriber the raw bytes
(``node.create_subscription(Image, topic, cb, qos, raw=True)``). This module
makes and reads those bytes without rclpy:

* :func:`image_to_cdr` writes the few header fields with ``struct`` and copies
  the pixel buffer once (``bytes.join``); the result is byte-identical to
  rosbags' ``serialize_cdr`` of the same message, and rclpy's
  ``deserialize_message`` reads it back exactly (``test/io/test_cdr.py``).
  rclpy's own ``serialize_message`` output differs from it only in the
  alignment padding bytes, which Fast CDR leaves uninitialised.
* :func:`cdr_to_image` / :func:`cdr_to_image_msg` parse with the rosbags
  typestore (``Stores.ROS2_JAZZY``); the pixel array is a **zero-copy view** of
  the received bytes (read-only when they are ``bytes``, as rclpy delivers).
* Everything else goes through rosbags classes and ``TYPESTORE.serialize_cdr``
  (:func:`serialize` / :func:`deserialize`).

CDR layout of sensor_msgs/msg/Image after the 4-byte encapsulation header
(``00 01 00 00`` = CDR little-endian; alignment counted from after it):
``int32 sec, uint32 nanosec, string frame_id, uint32 height, uint32 width,
string encoding, uint8 is_bigendian, uint32 step, uint32 n, uint8 data[n]``;
a string is ``uint32 length+1, bytes, NUL``; uint32 fields are 4-aligned with
zero padding. Stamps are integer nanoseconds since the epoch:
``sec = floor(stamp_ns / 1e9)``, ``nanosec = stamp_ns - 1e9 sec`` (0..999999999).

No rclpy import here: nodes use ``rclpy`` only to move the bytes.
"""

from __future__ import annotations

import struct
from typing import Any, Sequence

import numpy as np
from rosbags.serde import SerdeError
from rosbags.typesys import Stores, get_typestore

from .images import compressed_to_numpy, image_to_numpy, numpy_to_compressed, numpy_to_image_fields

__all__ = [
    "TYPESTORE",
    "CdrError",
    "IMAGE",
    "COMPRESSED_IMAGE",
    "FLOAT64_MULTI_ARRAY",
    "VECTOR3_STAMPED",
    "serialize",
    "deserialize",
    "make_header",
    "header_to_ns",
    "image_to_cdr",
    "cdr_to_image",
    "cdr_to_image_msg",
    "compressed_to_cdr",
    "cdr_to_compressed",
    "encoded_to_compressed_cdr",
    "cdr_to_compressed_msg",
    "float64_array_to_cdr",
    "cdr_to_float64_array",
    "vector3_stamped_to_cdr",
    "cdr_to_vector3_stamped",
    "time_reference_to_cdr",
    "cdr_to_time_reference",
]

TYPESTORE = get_typestore(Stores.ROS2_JAZZY)
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
FLOAT64_MULTI_ARRAY = "std_msgs/msg/Float64MultiArray"
VECTOR3_STAMPED = "geometry_msgs/msg/Vector3Stamped"
TIME_REFERENCE = "sensor_msgs/msg/TimeReference"

_T = TYPESTORE.types
_Header = _T["std_msgs/msg/Header"]
_Time = _T["builtin_interfaces/msg/Time"]
_CompressedImage = _T[COMPRESSED_IMAGE]
_Float64MultiArray = _T[FLOAT64_MULTI_ARRAY]
_MultiArrayLayout = _T["std_msgs/msg/MultiArrayLayout"]
_MultiArrayDimension = _T["std_msgs/msg/MultiArrayDimension"]
_Vector3Stamped = _T[VECTOR3_STAMPED]
_Vector3 = _T["geometry_msgs/msg/Vector3"]
_TimeReference = _T[TIME_REFERENCE]

_NS = 1_000_000_000
_INT32 = (-(2**31), 2**31 - 1)
_UINT32_MAX = 2**32 - 1


class CdrError(ValueError):
    """Bytes that are not a valid CDR message of the expected type (or unserialisable values)."""


def serialize(msg: Any, typename: str) -> bytes:
    """CDR (little-endian) bytes of a rosbags message ``msg`` of ``typename``.

    Returns ``bytes`` because rclpy's ``Publisher.publish`` accepts raw data
    only as ``bytes``.
    """
    try:
        return bytes(TYPESTORE.serialize_cdr(msg, typename, little_endian=True))
    except (SerdeError, struct.error, KeyError, AttributeError, TypeError, ValueError) as exc:
        raise CdrError(f"cannot serialise {typename}: {exc}") from None


def deserialize(raw: bytes | bytearray | memoryview, typename: str) -> Any:
    """Parse CDR ``raw`` into a rosbags message of ``typename``.

    ``raw`` is wrapped in a memoryview, so array fields (image data) are
    zero-copy numpy views of it.
    """
    try:
        view = memoryview(raw)
    except TypeError:
        raise CdrError(
            f"{typename} CDR data must be bytes-like, got {type(raw).__name__}"
        ) from None
    if view.ndim != 1 or view.itemsize != 1:
        view = view.cast("B")
    try:
        return TYPESTORE.deserialize_cdr(view, typename)
    except SerdeError as exc:
        raise CdrError(f"not a valid {typename} CDR message ({len(view)} bytes): {exc}") from None
    except (struct.error, IndexError, ValueError, UnicodeDecodeError) as exc:
        raise CdrError(f"not a valid {typename} CDR message ({len(view)} bytes): {exc}") from None


def _split_stamp(stamp_ns: int) -> tuple[int, int]:
    if isinstance(stamp_ns, bool) or not isinstance(stamp_ns, (int, np.integer)):
        raise CdrError(f"stamp_ns must be an integer number of nanoseconds, got {stamp_ns!r}")
    sec, nanosec = divmod(int(stamp_ns), _NS)
    if not _INT32[0] <= sec <= _INT32[1]:
        raise CdrError(
            f"stamp_ns {stamp_ns} is outside the int32 seconds range of builtin_interfaces/Time"
        )
    return sec, nanosec


def _time(stamp_ns: int) -> Any:
    """Build a rosbags ``builtin_interfaces/msg/Time`` for ``stamp_ns`` (ns since the epoch)."""
    sec, nanosec = _split_stamp(stamp_ns)
    return _Time(sec=sec, nanosec=nanosec)


def _time_to_ns(t: Any) -> int:
    """Convert a builtin_interfaces Time (rosbags or rclpy) to ns: ``sec * 1e9 + nanosec``."""
    return int(t.sec) * _NS + int(t.nanosec)


def make_header(stamp_ns: int, frame_id: str = "") -> Any:
    """Build a rosbags ``std_msgs/msg/Header`` for ``stamp_ns`` (integer ns since the epoch)."""
    stamp = _time(stamp_ns)
    if not isinstance(frame_id, str):
        raise CdrError(f"frame_id must be a string, got {frame_id!r}")
    return _Header(stamp=stamp, frame_id=frame_id)


def header_to_ns(header: Any) -> int:
    """Stamp of a Header (rosbags or rclpy) as integer nanoseconds: ``sec * 1e9 + nanosec``."""
    return _time_to_ns(header.stamp)


def _put_string(buf: bytearray, text: str) -> None:
    """Append a CDR string (4-aligned uint32 length incl. NUL, bytes, NUL)."""
    raw = text.encode("utf-8")
    if b"\x00" in raw:
        raise CdrError(f"string {text!r} contains a NUL character")
    _align(buf, 4)
    buf += struct.pack("<I", len(raw) + 1)
    buf += raw
    buf += b"\x00"


def _align(buf: bytearray, n: int) -> None:
    """Zero-pad so the next field starts at a multiple of ``n`` (after the 4-byte encapsulation)."""
    pad = -(len(buf) - 4) % n
    if pad:
        buf += bytes(pad)


def image_to_cdr(
    array: np.ndarray,
    encoding: str,
    stamp_ns: int,
    frame_id: str = "",
    step: int | None = None,
    *,
    bigendian: bool = False,
) -> bytes:
    """CDR bytes of a sensor_msgs/msg/Image holding ``array`` (one copy of the pixels).

    ``encoding``, ``step`` and ``bigendian`` as in
    :func:`subpix_ros.io.images.numpy_to_image_fields` (which validates the
    array against the encoding and raises ``ImageConversionError``).
    ``stamp_ns`` is integer nanoseconds since the epoch. Publish the result with
    ``publisher.publish(raw)``.
    """
    fields = numpy_to_image_fields(array, encoding, step=step, bigendian=bigendian)
    sec, nanosec = _split_stamp(stamp_ns)
    if not isinstance(frame_id, str):
        raise CdrError(f"frame_id must be a string, got {frame_id!r}")
    data = fields["data"]
    for name in ("height", "width", "step"):
        if fields[name] > _UINT32_MAX:
            raise CdrError(f"image {name} {fields[name]} does not fit a uint32")
    if data.size > _UINT32_MAX:
        raise CdrError(
            f"image data of {data.size} bytes does not fit a CDR sequence (max {_UINT32_MAX})"
        )
    buf = bytearray(b"\x00\x01\x00\x00")
    buf += struct.pack("<iI", sec, nanosec)
    _put_string(buf, frame_id)
    _align(buf, 4)
    buf += struct.pack("<II", fields["height"], fields["width"])
    _put_string(buf, encoding)
    buf += struct.pack("<B", fields["is_bigendian"])
    _align(buf, 4)
    buf += struct.pack("<II", fields["step"], data.size)
    return b"".join((buf, data))


def cdr_to_image_msg(raw: bytes | bytearray | memoryview) -> Any:
    """Parse CDR bytes into a rosbags ``sensor_msgs/msg/Image``; ``.data`` is a zero-copy view."""
    return deserialize(raw, IMAGE)


def cdr_to_image(
    raw: bytes | bytearray | memoryview,
    desired: str = "passthrough",
    *,
    allow_trailing: bool = False,
) -> tuple[np.ndarray, Any]:
    """``(array, header)`` from sensor_msgs/msg/Image CDR bytes (e.g. a ``raw=True`` callback).

    ``desired`` as in :func:`subpix_ros.io.images.image_to_numpy`; passthrough
    of plain encodings is a zero-copy view of ``raw``. Malformed bytes raise
    :class:`CdrError`, an inconsistent image ``ImageConversionError`` (both
    ``ValueError``).
    """
    msg = cdr_to_image_msg(raw)
    return image_to_numpy(msg, desired, allow_trailing=allow_trailing), msg.header


def compressed_to_cdr(
    array: np.ndarray, stamp_ns: int, frame_id: str = "", fmt: str = "jpeg", quality: int = 90
) -> bytes:
    """CDR bytes of a sensor_msgs/msg/CompressedImage of ``array`` (JPEG or PNG).

    The format string is image_transport's (see
    :func:`subpix_ros.io.images.numpy_to_compressed`).
    """
    format_string, data = numpy_to_compressed(array, fmt, quality)
    return encoded_to_compressed_cdr(data, format_string, stamp_ns, frame_id)


def encoded_to_compressed_cdr(data: bytes, fmt: str, stamp_ns: int, frame_id: str = "") -> bytes:
    """CDR bytes of a sensor_msgs/msg/CompressedImage carrying already encoded ``data``.

    ``fmt`` is the message's format string (image_transport's, e.g.
    ``"bgr8; png compressed bgr8"``); ``data`` is used as it is (one copy into the message),
    so a PNG written to a file and the message hold the same bytes.
    """
    msg = _CompressedImage(
        header=make_header(stamp_ns, frame_id),
        format=str(fmt),
        data=np.frombuffer(data, np.uint8),
    )
    return serialize(msg, COMPRESSED_IMAGE)


def cdr_to_compressed_msg(raw: bytes | bytearray | memoryview) -> Any:
    """Parse CDR bytes into a rosbags ``sensor_msgs/msg/CompressedImage`` (data is a view)."""
    return deserialize(raw, COMPRESSED_IMAGE)


def cdr_to_compressed(
    raw: bytes | bytearray | memoryview, desired: str = "passthrough"
) -> tuple[np.ndarray, Any]:
    """Decode sensor_msgs/msg/CompressedImage CDR bytes to ``(array, header)``."""
    msg = cdr_to_compressed_msg(raw)
    return compressed_to_numpy(msg, desired), msg.header


def float64_array_to_cdr(
    values: np.ndarray | Sequence[float], labels: Sequence[str] | None = None
) -> bytes:
    """CDR bytes of a std_msgs/msg/Float64MultiArray holding ``values`` (any shape).

    The layout follows the std_msgs convention: one dimension per axis with
    ``size`` and ``stride`` = number of elements spanned by one step of the
    previous axis (``dim[0].stride`` = total size), ``data_offset`` 0, data in
    C order. ``labels`` name the axes (default ``""``).
    """
    a = np.ascontiguousarray(values, dtype=np.float64)
    shape = a.shape if a.ndim else (1,)
    if labels is None:
        labels = [""] * len(shape)
    if len(labels) != len(shape):
        raise CdrError(f"{len(labels)} labels for an array with {len(shape)} axes")
    strides = np.cumprod(shape[::-1])[::-1]
    dims = [
        _MultiArrayDimension(label=str(lbl), size=int(n), stride=int(s))
        for lbl, n, s in zip(labels, shape, strides)
    ]
    msg = _Float64MultiArray(layout=_MultiArrayLayout(dim=dims, data_offset=0), data=a.reshape(-1))
    return serialize(msg, FLOAT64_MULTI_ARRAY)


def cdr_to_float64_array(raw: bytes | bytearray | memoryview) -> np.ndarray:
    """Return the data of a std_msgs/msg/Float64MultiArray, shaped by its layout (flat if none)."""
    msg = deserialize(raw, FLOAT64_MULTI_ARRAY)
    data = np.asarray(msg.data, dtype=np.float64)[int(msg.layout.data_offset) :]
    dims = msg.layout.dim
    if not dims:
        return data
    shape = tuple(int(d.size) for d in dims)
    if int(np.prod(shape)) != data.size:
        raise CdrError(f"Float64MultiArray layout {shape} does not match {data.size} data values")
    return data.reshape(shape)


def vector3_stamped_to_cdr(vector: Sequence[float], stamp_ns: int, frame_id: str = "") -> bytes:
    """CDR bytes of a geometry_msgs/msg/Vector3Stamped ``(x, y, z)``."""
    v = np.asarray(vector, dtype=np.float64).reshape(-1)
    if v.size != 3:
        raise CdrError(f"Vector3Stamped needs 3 values, got {v.size}")
    msg = _Vector3Stamped(
        header=make_header(stamp_ns, frame_id),
        vector=_Vector3(x=float(v[0]), y=float(v[1]), z=float(v[2])),
    )
    return serialize(msg, VECTOR3_STAMPED)


def cdr_to_vector3_stamped(raw: bytes | bytearray | memoryview) -> tuple[np.ndarray, Any]:
    """``(array([x, y, z]), header)`` from geometry_msgs/msg/Vector3Stamped CDR bytes."""
    msg = deserialize(raw, VECTOR3_STAMPED)
    return np.array([msg.vector.x, msg.vector.y, msg.vector.z], dtype=np.float64), msg.header


def time_reference_to_cdr(
    stamp_ns: int, time_ref_ns: int, frame_id: str = "", source: str = ""
) -> bytes:
    """CDR bytes of a sensor_msgs/msg/TimeReference: ``header.stamp`` = ``stamp_ns``, ``time_ref`` = ``time_ref_ns``."""
    if not isinstance(source, str):
        raise CdrError(f"source must be a str, got {type(source).__name__}")
    msg = _TimeReference(
        header=make_header(stamp_ns, frame_id), time_ref=_time(time_ref_ns), source=source
    )
    return serialize(msg, TIME_REFERENCE)


def cdr_to_time_reference(raw: bytes | bytearray | memoryview) -> tuple[int, int, Any]:
    """``(header stamp ns, time_ref ns, message)`` from sensor_msgs/msg/TimeReference CDR bytes."""
    msg = deserialize(raw, TIME_REFERENCE)
    return header_to_ns(msg.header), _time_to_ns(msg.time_ref), msg
