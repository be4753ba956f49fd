"""Seed luminance: 0.2989 R + 0.587 G + 0.1141 B, channel order explicit."""

import numpy as np
import pytest

from subpix_ros.core.luminance import luminance


def _rgb():
    rng = np.random.default_rng(1)
    return rng.integers(0, 256, (7, 9, 3), dtype=np.uint8)


def test_hand_value_pure_channels():
    px = np.zeros((1, 3, 3), np.uint8)
    px[0, 0] = (255, 0, 0)  # BGR: blue
    px[0, 1] = (0, 255, 0)  # green
    px[0, 2] = (0, 0, 255)  # red
    y = luminance(px, "bgr")
    assert y.dtype == np.float64 and y.shape == (1, 3)
    np.testing.assert_allclose(y[0], [0.1141 * 255, 0.587 * 255, 0.2989 * 255], rtol=0, atol=1e-12)
    y = luminance(px, "rgb")
    np.testing.assert_allclose(y[0], [0.2989 * 255, 0.587 * 255, 0.1141 * 255], rtol=0, atol=1e-12)


def test_white_and_formula_uint8_uint16_float():
    rgb = _rgb()
    expect = 0.2989 * rgb[..., 0].astype(float) + 0.587 * rgb[..., 1] + 0.1141 * rgb[..., 2]
    np.testing.assert_allclose(luminance(rgb, "rgb"), expect, atol=1e-12)
    np.testing.assert_allclose(luminance(rgb[..., ::-1], "bgr"), expect, atol=1e-12)
    u16 = rgb.astype(np.uint16) * 257
    np.testing.assert_allclose(luminance(u16, "rgb"), expect * 257, rtol=1e-12)
    f = rgb.astype(np.float32) / 255
    np.testing.assert_allclose(luminance(f, "rgb"), expect / 255, atol=1e-6)
    white = np.full((2, 2, 3), 200, np.uint8)
    np.testing.assert_allclose(luminance(white), 200 * (0.2989 + 0.587 + 0.1141), atol=1e-12)


def test_alpha_orders_ignore_alpha():
    rgb = _rgb()
    rgba = np.concatenate([rgb, np.full(rgb.shape[:2] + (1,), 7, np.uint8)], axis=2)
    np.testing.assert_array_equal(luminance(rgba, "rgba"), luminance(rgb, "rgb"))
    bgra = np.concatenate([rgb[..., ::-1], np.zeros(rgb.shape[:2] + (1,), np.uint8)], axis=2)
    np.testing.assert_array_equal(luminance(bgra, "bgra"), luminance(rgb, "rgb"))


def test_mono_passes_through():
    m = np.arange(12, dtype=np.uint16).reshape(3, 4) * 1000
    for order in ("mono", "bgr"):
        y = luminance(m, order)
        assert y.dtype == np.float64
        np.testing.assert_array_equal(y, m.astype(np.float64))
    np.testing.assert_array_equal(luminance(m[..., None], "mono"), m.astype(np.float64))


@pytest.mark.parametrize(
    "img,order",
    [
        (np.zeros((4, 4, 3), np.uint8), "xyz"),
        (np.zeros((4, 4, 4), np.uint8), "bgr"),
        (np.zeros((4, 4, 3), np.uint8), "rgba"),
        (np.zeros((4, 4, 3), np.uint8), "mono"),
        (np.zeros((4, 4, 3), bool), "bgr"),
        (np.zeros((4,), np.uint8), "mono"),
        (np.zeros((4, 4), np.complex128), "mono"),
    ],
)
def test_rejects(img, order):
    with pytest.raises(ValueError):
        luminance(img, order)


@pytest.mark.parametrize("order", ["bgr", "rgb", "bgra", "rgba"])
@pytest.mark.parametrize("dt", [np.uint8, np.uint16, np.float64])
def test_float32_output_matches_the_seed_weights(order, dt):
    rng = np.random.default_rng(3)
    top = 255 if dt == np.uint8 else 65535
    img = (rng.random((9, 11, len(order))) * top).astype(dt)
    ref = luminance(img, order)
    out = luminance(img, order, dtype=np.float32)
    assert out.dtype == np.float32 and out.shape == (9, 11)
    # float32 rounding only: relative 1e-6 of the value range
    assert np.max(np.abs(out - ref)) <= 2e-6 * top
    assert luminance(img[..., 0], "mono", dtype=np.float32).dtype == np.float32
    with pytest.raises(ValueError):
        luminance(img, order, dtype=np.int32)
