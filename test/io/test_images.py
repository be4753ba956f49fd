"""sensor_msgs/Image and CompressedImage <-> numpy: round trips, conversions, bad input."""

from __future__ import annotations

import array
import tracemalloc
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from conftest import ImageMsg as Msg

from subpix_ros.data import seneca_frame_paths
from subpix_ros.io.images import (
    KNOWN_ENCODINGS,
    FrameFormatTracker,
    ImageConversionError,
    compressed_to_numpy,
    encoding_info,
    finite_fraction,
    image_to_numpy,
    numpy_to_compressed,
    numpy_to_image_fields,
    require_finite,
)


def msg_of(array, encoding, **kw) -> Msg:
    return Msg(**numpy_to_image_fields(array, encoding, **kw))


@pytest.fixture(scope="module")
def colour():
    """Return a 96x128 BGR crop of a real bundled Seneca frame."""
    img = cv2.imread(str(seneca_frame_paths()[0]), cv2.IMREAD_COLOR)
    assert img is not None
    return np.ascontiguousarray(img[600:696, 800:928])


@pytest.fixture(scope="module")
def gray(crops):
    return np.ascontiguousarray(crops["crop_trees"][:96, :128])


def ramps(h=48, w=64, dtype=np.uint8, scale=1):
    """BGR linear ramps with different directions per channel (bilinear demosaic is exact on them)."""
    r, c = np.mgrid[0:h, 0:w]
    return (np.stack([40 + 2 * c, 100 + c + r, 30 + 3 * r], -1) * scale).astype(dtype)


def plain_sample(gray, encoding):
    """Real image content in the dtype/channels of ``encoding``."""
    info = encoding_info(encoding)
    g = gray.astype(np.float64)
    chans = [np.roll(g, 7 * k, axis=1) for k in range(info.channels)]
    a = np.stack(chans, -1) if info.channels > 1 else chans[0]
    dt = info.dtype
    if dt == np.uint16:
        a = a * 257 + 3
    elif dt == np.int8 or dt == np.int16 or dt == np.int32:
        a = a - 128
    elif dt.kind == "f":
        a = a / 255.0 - 0.25
    return a.astype(dt)


PLAIN = [e for e in KNOWN_ENCODINGS if encoding_info(e).kind == "plain"]


# ----------------------------------------------------------------------------- round trips


@pytest.mark.parametrize("encoding", PLAIN)
@pytest.mark.parametrize("pad", [0, 5])
@pytest.mark.parametrize("bigendian", [False, True])
def test_plain_round_trip_exact(gray, encoding, pad, bigendian):
    a = plain_sample(gray, encoding)
    row = a.shape[1] * encoding_info(encoding).pixel_bytes
    m = msg_of(a, encoding, step=row + pad, bigendian=bigendian)
    assert m.step == row + pad and len(m.data) == m.step * m.height
    assert m.is_bigendian == int(bigendian and a.itemsize > 1)
    out = image_to_numpy(m)
    assert out.dtype == a.dtype and out.shape == a.shape
    np.testing.assert_array_equal(out, a)


def test_bigendian_mono16_bytes_are_big_endian():
    a = np.array([[0x0102, 0xA0B0]], dtype=np.uint16)
    m = msg_of(a, "mono16", bigendian=True)
    assert bytes(m.data) == b"\x01\x02\xa0\xb0"
    # The same bytes read as little-endian would be different numbers.
    m.is_bigendian = 0
    assert image_to_numpy(m).tolist() == [[0x0201, 0xB0A0]]
    m.is_bigendian = 1
    assert image_to_numpy(m).tolist() == [[0x0102, 0xA0B0]]


def test_padded_step_ignores_pad_bytes(gray):
    m = msg_of(gray, "mono8", step=gray.shape[1] + 3)
    data = np.asarray(m.data).reshape(m.height, m.step).copy()
    data[:, -3:] = 255  # garbage in the padding must not leak into the image
    m.data = data.reshape(-1)
    np.testing.assert_array_equal(image_to_numpy(m), gray)


@pytest.mark.parametrize(
    "container", ["bytes", "bytearray", "array", "memoryview", "ndarray", "list"]
)
def test_data_containers(colour, container):
    f = numpy_to_image_fields(colour, "bgr8", step=colour.shape[1] * 3 + 2)
    raw = f["data"]
    f["data"] = {
        "bytes": lambda: raw.tobytes(),
        "bytearray": lambda: bytearray(raw.tobytes()),
        "array": lambda: array.array("B", raw.tobytes()),
        "memoryview": lambda: memoryview(raw.tobytes()),
        "ndarray": lambda: raw.copy(),
        "list": lambda: raw.tolist(),
    }[container]()
    np.testing.assert_array_equal(image_to_numpy(Msg(**f)), colour)


def test_passthrough_is_zero_copy_view(colour):
    buf = bytearray(numpy_to_image_fields(colour, "bgr8")["data"].tobytes())
    m = Msg(colour.shape[0], colour.shape[1], "bgr8", 0, colour.shape[1] * 3, buf)
    out = image_to_numpy(m)
    assert np.shares_memory(out, np.frombuffer(buf, np.uint8))
    buf[0] = (buf[0] + 1) % 256
    assert out[0, 0, 0] == buf[0]
    ro = image_to_numpy(Msg(m.height, m.width, "bgr8", 0, m.step, bytes(buf)))
    assert not ro.flags.writeable  # a view of immutable bytes stays read-only


def test_fields_data_is_view_when_possible(colour):
    f = numpy_to_image_fields(colour, "bgr8")
    assert np.shares_memory(f["data"], colour)
    assert f["data"].dtype == np.uint8 and f["data"].ndim == 1 and f["data"].flags.c_contiguous


# ----------------------------------------------------------------------------- conversions


def test_colour_orders_to_bgr8_and_mono8(colour):
    rgb = colour[..., ::-1].copy()
    bgra = np.dstack([colour, np.full(colour.shape[:2], 77, np.uint8)])
    rgba = np.dstack([rgb, np.full(colour.shape[:2], 77, np.uint8)])
    gray_ref = cv2.cvtColor(colour, cv2.COLOR_BGR2GRAY)
    for arr, enc in (
        (colour, "bgr8"),
        (rgb, "rgb8"),
        (bgra, "bgra8"),
        (rgba, "rgba8"),
        (colour, "8UC3"),
    ):
        m = msg_of(arr, enc)
        np.testing.assert_array_equal(image_to_numpy(m, "bgr8"), colour)
        if enc != "8UC3":
            np.testing.assert_array_equal(image_to_numpy(m, "mono8"), gray_ref)
            np.testing.assert_array_equal(image_to_numpy(m, "mono"), gray_ref)


def test_mono_to_bgr8_replicates(gray):
    out = image_to_numpy(msg_of(gray, "mono8"), "bgr8")
    assert out.shape == gray.shape + (3,)
    for k in range(3):
        np.testing.assert_array_equal(out[..., k], gray)


def test_16bit_scaling():
    a = np.array([[0, 257, 257 * 128, 65535, 128]], dtype=np.uint16)
    m = msg_of(a, "mono16")
    assert image_to_numpy(m, "mono8").tolist() == [[0, 1, 128, 255, 0]]
    assert image_to_numpy(m, "mono").dtype == np.uint16
    np.testing.assert_array_equal(image_to_numpy(m, "mono"), a)
    np.testing.assert_array_equal(
        image_to_numpy(msg_of(a, "16UC1"), "mono8"), image_to_numpy(m, "mono8")
    )
    b16 = np.dstack([a, a // 2, a // 4])
    np.testing.assert_array_equal(
        image_to_numpy(msg_of(b16, "bgr16"), "bgr8"), cv2.convertScaleAbs(b16, alpha=255 / 65535)
    )
    rgb16 = b16[..., ::-1].copy()
    np.testing.assert_array_equal(
        image_to_numpy(msg_of(rgb16, "rgb16"), "bgr8"), image_to_numpy(msg_of(b16, "bgr16"), "bgr8")
    )


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
def test_bayer_mosaic_layout(pattern):
    """Encoding side pinned by hand: which colour sits where in the 2x2 cell."""
    bgr = np.zeros((2, 2, 3), np.uint8)
    bgr[..., 0], bgr[..., 1], bgr[..., 2] = 10, 20, 30  # B, G, R
    letters = {"r": 30, "g": 20, "b": 10}
    expect = [
        [letters[pattern[0]], letters[pattern[1]]],
        [letters[pattern[2]], letters[pattern[3]]],
    ]
    m = msg_of(bgr, f"bayer_{pattern}8")
    assert np.asarray(m.data).reshape(2, 2).tolist() == expect
    np.testing.assert_array_equal(image_to_numpy(m, "raw"), np.array(expect, np.uint8))


@pytest.mark.parametrize("pattern", ["rggb", "bggr", "gbrg", "grbg"])
@pytest.mark.parametrize("bits", [8, 16])
def test_bayer_demosaic_recovers_colour(pattern, bits):
    """Check that bilinear demosaicing is exact on linear ramps away from the border.

    Bilinear demosaicing is exact on linear ramps away from the 1-px border:
    a swapped pattern (R and B confused) would be off by tens of levels.
    """
    bgr = ramps(dtype=np.uint8 if bits == 8 else np.uint16, scale=1 if bits == 8 else 200)
    m = msg_of(bgr, f"bayer_{pattern}{bits}", step=bgr.shape[1] * bits // 8 + 6)
    out = image_to_numpy(m)
    assert out.shape == bgr.shape and out.dtype == bgr.dtype
    np.testing.assert_array_equal(out[2:-2, 2:-2], bgr[2:-2, 2:-2])
    g8 = image_to_numpy(m, "mono8")
    ref = cv2.cvtColor(image_to_numpy(m, "bgr8"), cv2.COLOR_BGR2GRAY)
    assert g8.dtype == np.uint8
    assert np.abs(g8[2:-2, 2:-2].astype(int) - ref[2:-2, 2:-2]).max() <= 1
    if bits == 8:
        np.testing.assert_array_equal(image_to_numpy(m, "bgr8"), out)


@pytest.mark.parametrize("new,old", [("uyvy", "yuv422"), ("yuyv", "yuv422_yuy2")])
def test_yuv422_old_and_new_names(colour, new, old):
    pair = np.repeat(
        colour[:, ::2], 2, axis=1
    )  # chroma constant over pixel pairs: 4:2:2 loses nothing
    m_new, m_old = msg_of(pair, new), msg_of(pair, old)
    np.testing.assert_array_equal(np.asarray(m_new.data), np.asarray(m_old.data))
    out = image_to_numpy(m_new)
    np.testing.assert_array_equal(out, image_to_numpy(m_old))
    assert out.dtype == np.uint8 and out.shape == pair.shape
    assert np.abs(out.astype(int) - pair).max() <= 3
    g = image_to_numpy(m_new, "mono8")
    assert np.abs(g.astype(int) - cv2.cvtColor(out, cv2.COLOR_BGR2GRAY)).max() <= 2
    raw = image_to_numpy(m_new, "raw")
    assert raw.shape == pair.shape[:2] + (2,)


def test_yuv422_byte_order():
    grey = np.full((2, 4, 3), 200, np.uint8)
    y = round(16 + 219 * 200 / 255)
    uyvy = np.asarray(msg_of(grey, "uyvy").data)[:4].tolist()
    yuyv = np.asarray(msg_of(grey, "yuyv").data)[:4].tolist()
    assert uyvy == [128, y, 128, y]
    assert yuyv == [y, 128, y, 128]
    # Decoding reads the same order: swapping the names swaps Y and chroma and breaks the grey.
    wrong = image_to_numpy(Msg(2, 4, "yuyv", 0, 8, bytes(msg_of(grey, "uyvy").data)))
    assert np.abs(wrong.astype(int) - 200).max() > 50
    assert np.abs(image_to_numpy(msg_of(grey, "uyvy")).astype(int) - 200).max() <= 2


# ----------------------------------------------------------------------------- bad input


def good_fields():
    return numpy_to_image_fields(np.arange(24, dtype=np.uint8).reshape(4, 6), "mono8")


@pytest.mark.parametrize(
    "change,pattern",
    [
        ({"encoding": "bgr9"}, "unknown image encoding 'bgr9'; did you mean 'bgr8'"),
        ({"encoding": "BGR8"}, "did you mean 'bgr8'"),
        ({"encoding": "32fc1"}, "did you mean '32FC1'"),
        ({"encoding": "bayer_rgbg8"}, "did you mean 'bayer_rggb8'"),
        ({"encoding": ""}, "empty image encoding"),
        ({"encoding": "jpeg2000"}, "unknown image encoding 'jpeg2000'"),
        ({"width": 0, "step": 0}, "zero or negative size"),
        ({"height": 0}, "zero or negative size"),
        ({"height": -2}, "zero or negative size"),
        ({"step": 5}, "step 5 is smaller than one row"),
        ({"height": 5}, "too short: 24 bytes, expected step\\*height = 6\\*5 = 30"),
        ({"height": 3}, "too long: 24 bytes, expected step\\*height = 6\\*3 = 18 \\(6 extra"),
        (
            {"width": 3, "encoding": "mono16", "height": 2},
            "too long: 24 bytes, expected step\\*height = 6\\*2 = 12",
        ),
        ({"encoding": "rgb8"}, "step 6 is smaller than one row: width 6 x 3 bytes per pixel = 18"),
        ({"encoding": "uyvy", "width": 3}, "even width, got 3"),
        ({"encoding": "bayer_rggb8", "width": 5}, "even width and height"),
        ({"encoding": "bayer_rggb8", "height": 3, "step": 8}, "even width and height"),
        ({"step": 6.0}, "step must be an integer"),
        ({"data": np.zeros(24, np.float32)}, "must be uint8"),
        ({"data": [1, 2, 300] * 8}, "not a sequence of bytes"),
        ({"data": 12345}, "not a byte buffer"),
    ],
)
def test_bad_messages_raise_clear_errors(change, pattern):
    f = good_fields()
    f.update(change)
    with pytest.raises(ImageConversionError, match=pattern):
        image_to_numpy(Msg(**f))


def test_trailing_bytes_can_be_allowed_explicitly():
    f = good_fields()
    f["data"] = np.concatenate([f["data"], np.full(7, 9, np.uint8)])
    with pytest.raises(ImageConversionError, match="7 extra bytes"):
        image_to_numpy(Msg(**f))
    np.testing.assert_array_equal(
        image_to_numpy(Msg(**f), allow_trailing=True), np.arange(24).reshape(4, 6)
    )


def test_missing_field():
    with pytest.raises(ImageConversionError, match="no field 'step'"):
        image_to_numpy(
            SimpleNamespace(height=1, width=1, encoding="mono8", is_bigendian=0, data=b"\x00")
        )


def test_bad_desired_and_undefined_conversions(gray):
    with pytest.raises(
        ImageConversionError, match="unknown desired format 'bgr' .*did you mean 'bgr8'"
    ):
        image_to_numpy(msg_of(gray, "mono8"), "bgr")
    f32 = gray.astype(np.float32)
    for desired in ("bgr8", "mono8"):
        with pytest.raises(ImageConversionError, match="no defined 8-bit scale"):
            image_to_numpy(msg_of(f32, "32FC1"), desired)
    np.testing.assert_array_equal(image_to_numpy(msg_of(f32, "32FC1"), "mono"), f32)
    c3 = np.dstack([gray] * 3)
    with pytest.raises(ImageConversionError, match="no colour order"):
        image_to_numpy(msg_of(c3, "8UC3"), "mono8")


@pytest.mark.parametrize(
    "array,encoding,kw,pattern",
    [
        (np.zeros((4, 4), np.uint8), "mono16", {}, "mono16 needs uint16 samples, array is uint8"),
        (np.zeros((4, 4), np.uint8), "bgr8", {}, "bgr8 needs 3 channel"),
        (np.zeros((4, 4, 3), np.float64), "bgr8", {}, "needs uint8"),
        (np.zeros((4, 4), np.uint8), "mono8", {"step": 3}, "step 3 is smaller"),
        (np.zeros((4, 5, 3), np.uint8), "bayer_grbg8", {}, "even width and height"),
        (np.zeros((4, 5, 3), np.uint8), "yuyv", {}, "even width"),
        (np.zeros((0, 4), np.uint8), "mono8", {}, "non-empty"),
        (np.zeros((4, 4), np.uint8), "mono9", {}, "did you mean 'mono8'"),
    ],
)
def test_bad_arrays_for_encoding(array, encoding, kw, pattern):
    with pytest.raises(ImageConversionError, match=pattern):
        numpy_to_image_fields(array, encoding, **kw)


def test_float_nan_inf_are_converted_and_reportable(gray):
    f = gray.astype(np.float32) / 255
    f[3, 4] = np.nan
    f[10, 11] = np.inf
    f[20, 0] = -np.inf
    out = image_to_numpy(msg_of(f, "32FC1"))
    assert np.isnan(out[3, 4]) and out[10, 11] == np.inf and out[20, 0] == -np.inf
    assert finite_fraction(out) == pytest.approx(1 - 3 / f.size)
    with pytest.raises(
        ImageConversionError, match=r"non-finite samples \(NaN/Inf\): 99\.97\d% finite"
    ):
        require_finite(out)
    assert require_finite(out, min_fraction=0.99) is out
    assert finite_fraction(gray) == 1.0
    assert require_finite(np.ones((2, 2), np.float64)) is not None


@pytest.mark.parametrize("kind", ["black", "saturated", "textureless"])
def test_degenerate_frames_convert_unchanged(kind):
    """Convert all-black, saturated and flat frames like any other.

    All-black, saturated and flat frames are valid images: the conversion must not
    invent texture or fail (rejecting them is the estimators' job).
    """
    value = {"black": 0, "saturated": 255, "textureless": 117}[kind]
    img = np.full((16, 20, 3), value, np.uint8)
    for enc in ("bgr8", "rgb8", "bayer_rggb8", "uyvy"):
        out = image_to_numpy(msg_of(img, enc), "bgr8")
        assert np.abs(out.astype(int) - value).max() <= 1, enc


def test_frame_size_change_mid_stream_is_reported(gray):
    tracker = FrameFormatTracker()
    small = gray[:48, :64]
    msgs = [
        msg_of(gray, "mono8"),
        msg_of(gray, "mono8"),
        msg_of(small, "mono8"),
        msg_of(small, "mono8"),
        msg_of(np.dstack([small] * 3), "bgr8"),
    ]
    notes = [tracker.update_from(m) for m in msgs]
    assert notes[:2] == [None, None] and notes[3] is None
    assert (
        notes[2] == "frame format changed mid-stream: 128x96 mono8 -> 64x48 mono8 (width x height)"
    )
    assert notes[4] == "frame format changed mid-stream: 64x48 mono8 -> 64x48 bgr8 (width x height)"
    assert tracker.changes == 2 and tracker.current == (48, 64, "bgr8")
    # Each frame still converts on its own terms.
    assert image_to_numpy(msgs[2]).shape == (48, 64)


def test_huge_frame_no_extra_copies():
    """8000x6000 BGR: passthrough allocates nothing, mono8 only its output."""
    big = np.zeros((6000, 8000, 3), np.uint8)
    big[::97, ::89] = 200
    m = msg_of(big, "bgr8")
    tracemalloc.start()
    try:
        view = image_to_numpy(m)
        _, peak_view = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        gray = image_to_numpy(m, "mono8")
        _, peak_gray = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert np.shares_memory(view, big)
    assert peak_view < 1_000_000
    assert gray.shape == (6000, 8000)
    assert gray.nbytes <= peak_gray < gray.nbytes + 1_000_000
    assert gray[97, 89] == cv2.cvtColor(np.full((1, 1, 3), 200, np.uint8), cv2.COLOR_BGR2GRAY)[0, 0]


# ----------------------------------------------------------------------------- compressed


def psnr(a, b):
    mse = np.mean((a.astype(np.float64) - b.astype(np.float64)) ** 2)
    return 10 * np.log10(255.0**2 / mse)


def test_jpeg_round_trip(colour, gray):
    fmt, data = numpy_to_compressed(colour, "jpeg", quality=95)
    assert fmt == "bgr8; jpeg compressed bgr8" and isinstance(data, bytes)
    out = compressed_to_numpy(SimpleNamespace(format=fmt, data=data))
    assert out.shape == colour.shape and psnr(out, colour) > 35
    for plain in ("jpeg", "", "rgb8; jpeg compressed bgr8"):
        np.testing.assert_array_equal(
            compressed_to_numpy(SimpleNamespace(format=plain, data=data)), out
        )
    fmt_g, data_g = numpy_to_compressed(gray, "jpeg", quality=95)
    assert fmt_g == "mono8; jpeg compressed mono8"
    out_g = compressed_to_numpy(SimpleNamespace(format=fmt_g, data=array.array("B", data_g)))
    assert out_g.shape == gray.shape and psnr(out_g, gray) > 35
    m8 = compressed_to_numpy(SimpleNamespace(format=fmt, data=data), "mono8")
    np.testing.assert_array_equal(m8, cv2.cvtColor(out, cv2.COLOR_BGR2GRAY))


def test_png_round_trips_exact(colour, gray):
    bgra = np.dstack([colour, gray])
    g16 = gray.astype(np.uint16) * 257 + 1
    for arr, enc in ((gray, "mono8"), (colour, "bgr8"), (bgra, "bgra8"), (g16, "mono16")):
        fmt, data = numpy_to_compressed(arr, "png")
        assert fmt == f"{enc}; png compressed {enc}"
        out = compressed_to_numpy(SimpleNamespace(format=fmt, data=np.frombuffer(data, np.uint8)))
        assert out.dtype == arr.dtype
        np.testing.assert_array_equal(out, arr)
        np.testing.assert_array_equal(
            compressed_to_numpy(SimpleNamespace(format="png", data=data)), arr
        )
    assert (
        compressed_to_numpy(
            SimpleNamespace(format="png", data=numpy_to_compressed(g16, "png")[1]), "mono"
        ).dtype
        == np.uint16
    )


def test_corrupt_compressed_raises(colour):
    _, jpg = numpy_to_compressed(colour, "jpeg")
    _, png = numpy_to_compressed(colour, "png")
    png_bad_crc = bytearray(png)
    png_bad_crc[100:150] = bytes(50)
    cases = [
        ("jpeg", b"", "no data"),
        ("jpeg", b"hello, not an image" * 4, "does not start with a JPEG marker"),
        ("jpeg", jpg[: len(jpg) // 2], "JPEG data is truncated"),
        ("png", png[:-30], "PNG data is truncated"),
        ("png", bytes(png_bad_crc), "cannot decode the png"),
        ("png", jpg, "does not start with the PNG signature"),
        ("", b"\x00" * 64, "neither JPEG nor PNG"),
        ("tiff", png, "'tiff' is not supported"),
        ("16UC1; compressedDepth png", png, "compressedDepth"),
        (None, png, "format must be a string"),
    ]
    for fmt, data, pattern in cases:
        with pytest.raises(ImageConversionError, match=pattern):
            compressed_to_numpy(SimpleNamespace(format=fmt, data=data))


def test_numpy_to_compressed_rejects(gray):
    with pytest.raises(ImageConversionError, match="JPEG cannot store mono16"):
        numpy_to_compressed(gray.astype(np.uint16), "jpeg")
    with pytest.raises(ImageConversionError, match="cannot compress float32"):
        numpy_to_compressed(gray.astype(np.float32), "png")
    with pytest.raises(ImageConversionError, match="quality must be 1..100"):
        numpy_to_compressed(gray, "jpeg", quality=0)
    with pytest.raises(ImageConversionError, match="'webp' is not supported"):
        numpy_to_compressed(gray, "webp")
    with pytest.raises(ImageConversionError, match="shape"):
        numpy_to_compressed(np.zeros((4, 4, 2), np.uint8), "png")
