"""What the nodes hand each other, in memory (pipeline) or as ROS messages.

The payloads (:class:`Frame`, :class:`Aligned`, :class:`Shift`) are the
stages' (``subpix_ros.stages.types``), re-exported here. In the
single-process ``pipeline`` they pass between stages directly; between
processes they travel as the documented ROS messages, and the ``*_from_cdr``
/ ``*_to_cdr`` helpers here convert (fast raw-CDR path).
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np

from subpix_ros.io import cdr
from subpix_ros.io.images import image_to_numpy
from subpix_ros.runtime import MMAP_THRESHOLD
from subpix_ros.stages.types import Aligned, Frame, Shift  # noqa: F401 - re-exported


# ---------------------------------------------------------------- messages -> payloads
def frame_from_cdr(raw: bytes, received: float | None = None) -> Frame:
    """Decode a raw sensor_msgs/Image: mono as HxW, colour as BGR (zero-copy for mono8/bgr8)."""
    msg = cdr.cdr_to_image_msg(raw)
    enc = msg.encoding.lower()
    plain = enc in ("mono8", "mono16", "bgr8", "8uc1", "16uc1", "32fc1")
    image = image_to_numpy(msg, "passthrough" if plain else "bgr8")
    return Frame(
        cdr.header_to_ns(msg.header), image, msg.header.frame_id, received or time.monotonic()
    )


def frame_from_compressed_cdr(raw: bytes, received: float | None = None) -> Frame:
    """Decode a sensor_msgs/CompressedImage into a BGR :class:`Frame`."""
    image, header = cdr.cdr_to_compressed(raw, "bgr8")
    return Frame(cdr.header_to_ns(header), image, header.frame_id, received or time.monotonic())


def homography_from_cdr(raw: bytes) -> np.ndarray:
    """Decode a 3x3 homography (Float64MultiArray, row-major); ValueError if malformed."""
    data = cdr.cdr_to_float64_array(raw)
    if data.size != 9 or not np.all(np.isfinite(data)):
        raise ValueError(f"homography message must hold 9 finite values, got {data.size}")
    return data.reshape(3, 3)


def shift_from_cdr(raw: bytes) -> Shift:
    """Decode a ``shift`` message (its standard errors are not on it: NaN)."""
    vec, header = cdr.cdr_to_vector3_stamped(raw)
    return Shift(
        cdr.header_to_ns(header),
        -1,
        float(vec[0]),
        float(vec[1]),
        float(vec[2]),
        float("nan"),
        float("nan"),
        header.frame_id,
    )


# ---------------------------------------------------------------- payloads -> messages
def image_cdr(image: np.ndarray, stamp_ns: int, frame_id: str = "") -> bytes:
    """Encode an image (mono8, bgr8, mono16 or 32FC1, by its dtype and shape)."""
    if image.dtype == np.uint8:
        encoding = "mono8" if image.ndim == 2 else "bgr8"
    elif image.dtype == np.uint16 and image.ndim == 2:
        encoding = "mono16"
    elif image.dtype == np.float32 and image.ndim == 2:
        encoding = "32FC1"
    else:
        raise ValueError(f"no image encoding for {image.dtype} with shape {image.shape}")
    return cdr.image_to_cdr(image, encoding, stamp_ns, frame_id)


def adopt_pixels(sr: Any, raw: bytes, min_bytes: int = MMAP_THRESHOLD) -> bool:
    """Point a super-resolved image (and its result) at the pixels inside its message ``raw``.

    The message holds a copy of the pixels (:func:`image_cdr`); viewing them there (read-only,
    no copy) frees the array itself while the message is published and whatever receives the
    image in this process uses it: at 4K, 100 MB less at the node's peak. Only for images of at
    least ``min_bytes`` (the allocator's mmap threshold, :data:`subpix_ros.runtime.MMAP_THRESHOLD`):
    those go back to the system when freed; a smaller array's memory stays in the heap, and
    freeing it early did not lower the 1080p peak (docs/design-notes.md). Returns True if the
    image was adopted.
    """
    old = sr.image
    if old.nbytes < min_bytes:
        return False
    view = cdr.cdr_to_image(raw)[0]
    if view.shape != old.shape or view.dtype != old.dtype:
        raise ValueError(f"message pixels {view.shape} {view.dtype} are not the image's")
    sr.image = view
    if getattr(sr.result, "image", None) is old:
        sr.result.image = view
    return True


def mask_cdr(mask: np.ndarray, stamp_ns: int, frame_id: str = "") -> bytes:
    """Encode a validity mask as mono8 (255 valid, 0 not)."""
    return cdr.image_to_cdr(np.where(mask, np.uint8(255), np.uint8(0)), "mono8", stamp_ns, frame_id)


def homography_cdr(h: np.ndarray) -> bytes:
    """3x3 homography, row-major, in a Float64MultiArray with dims rows=3, cols=3."""
    return cdr.float64_array_to_cdr(np.asarray(h, dtype=np.float64).reshape(3, 3), ["rows", "cols"])


def shift_cdr(s: Shift) -> bytes:
    """Vector3Stamped: x = u (rows), y = v (columns), z = intensity offset; header of the moving frame."""
    return cdr.vector3_stamped_to_cdr((s.u, s.v, s.z), s.stamp_ns, s.frame_id)


def shift_std_cdr(s: Shift) -> bytes:
    """Vector3Stamped: x = standard error of u, y = of v (px), z = 0; header of the moving frame."""
    return cdr.vector3_stamped_to_cdr((s.u_std, s.v_std, 0.0), s.stamp_ns, s.frame_id)


def reference_link_cdr(stamp_ns: int, reference_stamp_ns: int, frame_id: str = "") -> bytes:
    """Encode the link naming an aligned frame's reference (sensor_msgs/TimeReference).

    Header = the aligned frame's (stamp, frame_id), ``time_ref`` = its reference frame's stamp.
    """
    return cdr.time_reference_to_cdr(
        stamp_ns, reference_stamp_ns, frame_id, "subpix_ros reference frame"
    )


def reference_link_from_cdr(raw: bytes) -> tuple[int, int]:
    """``(aligned frame stamp ns, reference stamp ns)`` from :func:`reference_link_cdr` bytes."""
    stamp, ref, _ = cdr.cdr_to_time_reference(raw)
    return stamp, ref
