"""Hypothesis property tests for image conversion.

Hypothesis property tests for image conversion: round trips over random shapes,
dtypes, padded steps, byte orders and containers; every bad size is rejected.
"""

from __future__ import annotations

import array
from dataclasses import dataclass

import cv2
import numpy as np
import pytest
from conftest import ImageMsg as Msg
from hypothesis import given, settings
from hypothesis import strategies as st

from subpix_ros.io.images import (
    KNOWN_ENCODINGS,
    ImageConversionError,
    compressed_to_numpy,
    encoding_info,
    image_to_numpy,
    numpy_to_compressed,
    numpy_to_image_fields,
)

FAST = settings(max_examples=60, deadline=None)

PLAIN = [e for e in KNOWN_ENCODINGS if encoding_info(e).kind == "plain"]
BAYER = [e for e in KNOWN_ENCODINGS if encoding_info(e).kind == "bayer"]
YUV = [e for e in KNOWN_ENCODINGS if encoding_info(e).kind == "yuv422"]
CONTAINERS = ["bytes", "bytearray", "array", "memoryview", "ndarray"]


@dataclass
class CMsg:
    format: str
    data: bytes


def wrap(data: np.ndarray, container: str):
    raw = data.tobytes()
    return {
        "bytes": raw,
        "bytearray": bytearray(raw),
        "array": array.array("B", raw),
        "memoryview": memoryview(raw),
        "ndarray": np.frombuffer(raw, np.uint8).copy(),
    }[container]


@FAST
@given(
    encoding=st.sampled_from(PLAIN),
    h=st.integers(1, 17),
    w=st.integers(1, 17),
    pad=st.integers(0, 9),
    bigendian=st.booleans(),
    container=st.sampled_from(CONTAINERS),
    seed=st.integers(0, 2**32 - 1),
)
def test_plain_round_trip_bit_exact(encoding, h, w, pad, bigendian, container, seed):
    """Random bytes (so floats include NaN payloads, Inf, denormals) survive bit-exactly."""
    info = encoding_info(encoding)
    shape = (h, w) if info.channels == 1 else (h, w, info.channels)
    a = np.frombuffer(
        np.random.default_rng(seed).bytes(h * w * info.pixel_bytes), info.dtype
    ).reshape(shape)
    f = numpy_to_image_fields(a, encoding, step=w * info.pixel_bytes + pad, bigendian=bigendian)
    f["data"] = wrap(f["data"], container)
    out = image_to_numpy(Msg(**f))
    assert out.shape == a.shape and out.dtype == a.dtype and out.dtype.isnative
    assert out.tobytes() == a.tobytes()


@FAST
@given(
    encoding=st.sampled_from(BAYER),
    hh=st.integers(2, 9),
    hw=st.integers(2, 9),
    pad=st.integers(0, 6),
    seed=st.integers(0, 2**32 - 1),
)
def test_bayer_demosaic_keeps_measured_samples(encoding, hh, hw, pad, seed):
    """Re-mosaic the demosaiced image and get the mosaic back.

    Away from the 1-px border, demosaicing keeps each pixel's own measured colour, so
    re-mosaicing the decoded image gives back the mosaic (fails if the pattern is wrong).
    """
    info = encoding_info(encoding)
    h, w = 2 * hh, 2 * hw
    top = np.iinfo(info.dtype).max
    mosaic = np.random.default_rng(seed).integers(0, top + 1, (h, w), dtype=info.dtype)
    m = Msg(**numpy_to_image_fields(mosaic, encoding, step=w * info.pixel_bytes + pad))
    np.testing.assert_array_equal(image_to_numpy(m, "raw"), mosaic)
    bgr = image_to_numpy(m)
    assert bgr.shape == (h, w, 3) and bgr.dtype == info.dtype
    again = numpy_to_image_fields(bgr, encoding)["data"].view(info.dtype).reshape(h, w)
    np.testing.assert_array_equal(again[1:-1, 1:-1], mosaic[1:-1, 1:-1])


@FAST
@given(
    encoding=st.sampled_from(YUV),
    h=st.integers(1, 12),
    hw=st.integers(1, 10),
    pad=st.integers(0, 6),
    seed=st.integers(0, 2**32 - 1),
)
def test_yuv422_grey_round_trip(encoding, h, hw, pad, seed):
    """Grey images (no chroma) survive 4:2:2 within 2 levels and the packed bytes come back as stored."""
    w = 2 * hw
    g = np.random.default_rng(seed).integers(0, 256, (h, w), dtype=np.uint8)
    bgr = np.dstack([g, g, g])
    m = Msg(**numpy_to_image_fields(bgr, encoding, step=2 * w + pad))
    packed = np.asarray(m.data).reshape(h, 2 * w + pad)[:, : 2 * w].reshape(h, w, 2)
    np.testing.assert_array_equal(image_to_numpy(m, "raw"), packed)
    out = image_to_numpy(m, "bgr8")
    assert np.abs(out.astype(int) - bgr).max() <= 2
    assert np.abs(image_to_numpy(m, "mono8").astype(int) - g).max() <= 2


@FAST
@given(
    encoding=st.sampled_from(PLAIN + BAYER + YUV),
    hh=st.integers(1, 8),
    hw=st.integers(1, 8),
    pad=st.integers(0, 5),
    delta=st.integers(-40, 40).filter(lambda d: d != 0),
)
def test_wrong_data_size_always_rejected(encoding, hh, hw, pad, delta):
    info = encoding_info(encoding)
    h, w = 2 * hh, 2 * hw
    step = w * info.pixel_bytes + pad
    size = max(0, step * h + delta)
    m = Msg(h, w, encoding, 0, step, bytes(size))
    with pytest.raises(ImageConversionError, match="too short" if size < step * h else "too long"):
        image_to_numpy(m)


@FAST
@given(
    encoding=st.sampled_from(PLAIN + BAYER + YUV),
    hh=st.integers(1, 8),
    hw=st.integers(1, 8),
    short=st.integers(1, 8),
)
def test_step_smaller_than_row_always_rejected(encoding, hh, hw, short):
    info = encoding_info(encoding)
    h, w = 2 * hh, 2 * hw
    step = max(0, w * info.pixel_bytes - short)
    with pytest.raises(ImageConversionError, match="smaller than one row"):
        image_to_numpy(Msg(h, w, encoding, 0, step, bytes(step * h)))


@FAST
@given(
    h=st.integers(1, 24),
    w=st.integers(1, 24),
    kind=st.sampled_from(["mono8", "bgr8", "bgra8", "mono16", "bgr16"]),
    seed=st.integers(0, 2**32 - 1),
)
def test_png_round_trip_exact(h, w, kind, seed):
    dt = np.uint16 if kind.endswith("16") else np.uint8
    ch = {"mono": 0, "bgr": 3, "bgra": 4}[kind.rstrip("0123456789")]
    shape = (h, w) if ch == 0 else (h, w, ch)
    a = np.random.default_rng(seed).integers(0, np.iinfo(dt).max + 1, shape, dtype=dt)
    fmt, data = numpy_to_compressed(a, "png")
    out = compressed_to_numpy(CMsg(fmt, data))
    assert out.dtype == a.dtype
    np.testing.assert_array_equal(out, a)


@settings(max_examples=30, deadline=None)
@given(
    h=st.integers(8, 40),
    w=st.integers(8, 40),
    cut=st.floats(0.05, 0.95),
    seed=st.integers(0, 2**32 - 1),
)
def test_truncated_compressed_always_rejected(h, w, cut, seed):
    g = cv2.GaussianBlur(
        np.random.default_rng(seed).integers(0, 256, (h, w, 3), dtype=np.uint8), (0, 0), 1.5
    )
    for codec in ("jpeg", "png"):
        fmt, data = numpy_to_compressed(g, codec)
        n = max(1, int(len(data) * cut))
        with pytest.raises(ImageConversionError):
            compressed_to_numpy(CMsg(fmt, data[:n]))
