"""core/filters.py: the single-precision real DFT against numpy's."""

import numpy as np
import pytest

from subpix_ros.core.filters import rfft2_32


@pytest.mark.parametrize(
    "shape", [(1125, 2000), (1124, 2000), (1125, 1999), (64, 81), (81, 64), (2, 2), (3, 5), (1, 8)]
)
def test_rfft2_32_matches_numpy_on_odd_and_even_sizes(shape):
    x = np.random.default_rng(0).normal(100.0, 30.0, shape).astype(np.float32)
    ref = np.fft.rfft2(x.astype(np.float64))
    got = rfft2_32(x)
    assert got.dtype == np.complex64 and got.shape == ref.shape
    assert np.abs(got - ref).max() <= 1e-6 * np.abs(ref).max()
