"""Image encodings: their layout in ``data`` and the OpenCV conversion codes."""

from __future__ import annotations

import difflib
import re
from dataclasses import dataclass

import cv2
import numpy as np

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
