"""Buffers reused from one reconstruction to the next change nothing in the images.

:class:`subpix_ros.core.superres.workspace.Workspace` hands the same memory to every set of
a stream (frame spectra, luminance, padded frame, HR spectrum). Its contents are left over
from the last set, so a solve that read an element it did not write would differ from a
fresh one: each test compares against the solve without a workspace, bit for bit, with sets
of different sizes in turn (a smaller set on a larger set's memory).
"""

import cv2
import numpy as np
import pytest

from subpix_ros.core.filters import rfft2_32
from subpix_ros.core.render import render_sequence
from subpix_ros.core.superres import colour_luminance, reconstruct_aligned, reconstruct_colour
from subpix_ros.core.superres.workspace import Workspace, work_array
from subpix_ros.data import load_crop

SHIFTS = np.array([[0, 0], [0.5, 0], [0, 0.5], [0.5, 0.5], [0.25, 0.75], [0.8, 0.3]])


def test_a_name_keeps_its_memory_and_grows_only_for_a_larger_request():
    ws = Workspace()
    a = ws.array("x", (10, 20), np.float32)
    assert a.shape == (10, 20) and a.dtype == np.float32 and a.flags.c_contiguous
    b = ws.array("x", (5, 7), np.complex64)  # smaller: the same memory, any type
    assert b.shape == (5, 7) and b.dtype == np.complex64 and np.shares_memory(a, b)
    c = ws.array("y", (10, 20), np.float32)  # another name: its own memory
    assert not np.shares_memory(a, c)
    assert ws.nbytes == 2 * 800
    d = ws.array("x", (30, 20), np.float32)  # larger: a new buffer
    assert not np.shares_memory(a, d) and ws.nbytes == 2400 + 800
    ws.clear()
    assert ws.nbytes == 0
    assert work_array(None, "x", (3, 4), np.float64).shape == (3, 4)


def test_rfft2_32_and_colour_luminance_write_into_a_given_array():
    rng = np.random.default_rng(1)
    img = rng.normal(size=(18, 26)).astype(np.float32)
    out = np.full((18, 14), np.nan, np.complex64)
    assert rfft2_32(img, out=out) is out
    np.testing.assert_allclose(out, np.fft.rfft2(img), rtol=0, atol=1e-4)
    with pytest.raises(ValueError, match="complex64"):
        rfft2_32(img, out=np.empty((18, 13), np.complex64))
    bgr = rng.integers(0, 256, (9, 11, 3), dtype=np.uint8)
    lum = np.full((9, 11), np.nan, np.float32)
    assert colour_luminance(bgr, out=lum) is lum
    assert np.array_equal(lum, colour_luminance(bgr))
    assert np.array_equal(lum, cv2.cvtColor(bgr.astype(np.float32), cv2.COLOR_BGR2GRAY))
    with pytest.raises(ValueError, match="float32"):
        colour_luminance(bgr, out=np.empty((9, 11), np.float64))


def _colour_set(size: int, seed: int) -> list[np.ndarray]:
    """Six BGR frames of a real crop at :data:`SHIFTS` (x2, blur 0.4 px, 40 dB), uint8."""
    crop = load_crop("crop_trees")[: 2 * size, : 2 * size]
    chans = [
        render_sequence(crop * s, 2, SHIFTS, 0.4, snr_db=40, seed=seed + i).frames
        for i, s in enumerate((0.8, 1.0, 0.9))
    ]
    return [
        np.clip(np.rint(np.dstack([c[k] for c in chans])), 0, 255).astype(np.uint8)
        for k in range(len(SHIFTS))
    ]


@pytest.mark.parametrize("out_dtype", [None, np.uint8])
def test_a_reused_workspace_gives_the_images_of_fresh_memory(out_dtype):
    ws = Workspace()
    sets = [_colour_set(96, 3), _colour_set(64, 4), _colour_set(80, 5), _colour_set(96, 6)]
    for frames in sets:
        fresh = reconstruct_colour(frames, SHIFTS, 2, blur_sigma=0.4, out_dtype=out_dtype)
        reused = reconstruct_colour(
            frames, SHIFTS, 2, blur_sigma=0.4, out_dtype=out_dtype, workspace=ws
        )
        assert not fresh.fell_back and fresh.method == reused.method == "map"
        assert np.array_equal(fresh.image, reused.image)
        assert np.isfinite(reused.image).all()
        # the image is the caller's own: the next set cannot overwrite it
        for buf in ws._buffers.values():
            assert not np.shares_memory(reused.image, buf)
    assert ws.nbytes > 0


def test_aligned_frames_with_border_masks_reuse_it_the_same_way():
    ws = Workspace()
    frames = _colour_set(96, 7)
    masks = []
    for k in range(len(frames)):
        m = np.ones(frames[0].shape[:2], bool)
        m[: 3 + k, :] = False  # border strips: the rectangle inside them is solved
        m[:, -2 - k :] = False
        masks.append(m)
    kw = dict(blur_sigma=0.4, out_dtype=np.uint8)
    fresh = reconstruct_aligned(frames, SHIFTS, 2, masks=masks, **kw)
    first = reconstruct_aligned(frames, SHIFTS, 2, masks=masks, workspace=ws, **kw)
    small = _colour_set(64, 8)
    other = reconstruct_aligned(small, SHIFTS, 2, workspace=ws, **kw)
    again = reconstruct_aligned(frames, SHIFTS, 2, masks=masks, workspace=ws, **kw)
    h, w = small[0].shape[:2]
    assert other.image.shape == (2 * h, 2 * w, 3) and h < frames[0].shape[0]
    assert np.array_equal(fresh.image, first.image) and np.array_equal(fresh.image, again.image)
