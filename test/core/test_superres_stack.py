"""The reconstruction reads a set's frames as stored where it converts them itself.

``FrameStack`` converts a frame to float64 when it is indexed; the padding before the DFTs
and the low-pass windows of the shift refinement and the tile registration take the stored
pixels instead (``FrameStack.window``). These tests hold them to the values of the plain
float64 stack.
"""

from __future__ import annotations

import numpy as np
import pytest

from subpix_ros.core.superres.fourier_map import _consistent_padding
from subpix_ros.core.superres.geometry import _refine_shifts, detect_geometry
from subpix_ros.core.superres.validation import FrameStack


@pytest.fixture(scope="module", params=[np.uint8, np.float32, np.uint16])
def frames(request):
    rng = np.random.default_rng(5)
    base = rng.normal(0, 1, (620, 700))  # frames above 512^2 px: no whole-frame low-pass
    base = np.cumsum(np.cumsum(base, 0), 1)  # a rough, smooth-ish scene
    base = (base - base.min()) / np.ptp(base)
    top = 255 if request.param is np.uint8 else (60000 if request.param is np.uint16 else 1.7)
    out = []
    for k in range(5):
        img = np.roll(base, (k, 2 * k), (0, 1))[10:580, 20:660] * top
        out.append(
            np.rint(img).astype(request.param)
            if request.param != np.float32
            else img.astype(np.float32)
        )
    return out


def test_padding_from_stored_frames_equals_the_float64_stack(frames):
    stack, plain = FrameStack(frames), np.stack([f.astype(np.float64) for f in frames])
    ishift = np.array([[0, 0], [1, 2], [2, 4], [3, 6], [4, 8]])
    resid = np.array([[0, 0], [0.2, -0.1], [0.4, 0.3], [-0.3, 0.1], [0.1, 0.45]])
    for a, b in zip(
        _consistent_padding(stack, ishift, resid, 16, 610, 700),
        _consistent_padding(plain, ishift, resid, 16, 610, 700),
    ):
        assert np.array_equal(a, b)


def test_refinement_and_tiles_from_stored_frames_equal_the_float64_stack(frames):
    stack, plain = FrameStack(frames), np.stack([f.astype(np.float64) for f in frames])
    ishift = np.array([[0, 0], [1, 2], [2, 4], [3, 6], [4, 8]], dtype=float)
    resid = np.zeros((5, 2))
    for a, b in zip(_refine_shifts(stack, ishift, resid), _refine_shifts(plain, ishift, resid)):
        assert np.array_equal(np.asarray(a), np.asarray(b), equal_nan=True)
    shifts = ishift + 0.1
    ga, gb = detect_geometry(stack, shifts), detect_geometry(plain, shifts)
    assert (ga[0] is None) == (gb[0] is None)
    assert np.array_equal(ga[1], gb[1], equal_nan=True)
    assert np.array_equal(np.asarray(ga[2]), np.asarray(gb[2]), equal_nan=True)
