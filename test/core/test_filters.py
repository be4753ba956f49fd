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


@pytest.mark.parametrize("shape", [(64, 81), (81, 64), (3, 5), (2, 2)])
def test_rfft2_32_into_a_given_array_contiguous_or_not(shape):
    """Written into ``out`` (a stack's slot, or a strided view) it is the same DFT."""
    x = np.random.default_rng(1).normal(100.0, 30.0, shape).astype(np.float32)
    want = rfft2_32(x)
    stack = np.zeros((2,) + want.shape, np.complex64)
    rfft2_32(x, out=stack[1])
    assert np.array_equal(stack[1], want) and not stack[0].any()
    wide = np.zeros((want.shape[0], 2 * want.shape[1]), np.complex64)
    rfft2_32(x, out=wide[:, ::2])  # not contiguous: the same values
    assert np.array_equal(wide[:, ::2], want) and not wide[:, 1::2].any()
    ref = np.fft.rfft2(x.astype(np.float64))
    assert np.abs(want - ref).max() <= 1e-6 * np.abs(ref).max()
