"""The products' bicubic reference image: made in row bands, the values of one whole resize."""

import cv2
import numpy as np
import pytest

from subpix_ros.core.superres.result import to_integer_image
from subpix_ros.data import load_crop
from subpix_ros.stages.types import bicubic_upscale


def _whole(image: np.ndarray, p: int, dtype) -> np.ndarray:
    """Return the definition: one cv2.resize of the float32 image, rounded."""
    h, w = image.shape[:2]
    up = cv2.resize(image.astype(np.float32), (w * p, h * p), interpolation=cv2.INTER_CUBIC)
    return to_integer_image(up, dtype)


@pytest.mark.parametrize("factor", [2, 3, 4])
@pytest.mark.parametrize("depth", ["mono8", "bgr8", "bgr16"])
def test_bands_give_the_whole_resize(factor, depth):
    grey = load_crop("crop_road")  # a real crop, 8 bit
    img = cv2.merge([grey, np.roll(grey, 7, axis=1), np.roll(grey, 5, axis=0)])
    img = img[:150, :131]  # rows not a multiple of the band, odd width
    if depth == "mono8":
        img = img[..., 0]
    if depth == "bgr16":
        img = img.astype(np.uint16) * 257 + 3
    dtype = img.dtype
    # bands of 8 rows: many band edges, each must match the whole image's rows
    got = bicubic_upscale(img, factor, dtype, rows=8)
    want = _whole(img, factor, dtype)
    assert got.dtype == want.dtype and got.shape == want.shape
    assert np.array_equal(got, want)
    assert np.array_equal(bicubic_upscale(img, factor, dtype), want)
