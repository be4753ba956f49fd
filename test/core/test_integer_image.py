"""The float -> integer output conversion of super-resolved and bicubic images."""

from __future__ import annotations

import numpy as np
import pytest

from subpix_ros.core.superres.result import to_integer_image


def _reference(img, dtype):
    out = np.rint(img)
    np.clip(out, 0, np.iinfo(dtype).max, out=out)
    return out.astype(dtype)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("src", [np.float32, np.float64])
@pytest.mark.parametrize("shape", [(33, 47), (33, 47, 3), (9, 11, 4), (5, 6, 7)])
def test_to_integer_image_rounds_half_to_even_and_saturates(dtype, src, shape):
    top = np.iinfo(dtype).max
    rng = np.random.default_rng(1)
    img = rng.uniform(-0.3 * top, 1.3 * top, shape).astype(src)
    flat = img.reshape(-1)
    ties = np.array([0.5, 1.5, 2.5, -0.5, top - 0.5, top + 0.5, -0.49, 3.5, 4.5])
    flat[: ties.size] = ties
    out = to_integer_image(img, dtype)
    assert out.dtype == dtype and out.shape == img.shape
    assert np.array_equal(out, _reference(img, dtype))
    assert list(out.reshape(-1)[:4]) == [0, 2, 2, 0]  # half to even, negatives to 0
