"""Strip masks from integer alignment take the fast solver, and the result matches."""

import time

import numpy as np
import pytest

from subpix_ros.core.render import render_sequence
from subpix_ros.core.superres import psnr, reconstruct
from subpix_ros.core.superres.masks import reconstruct_aligned
from subpix_ros.core.validity import common_valid_box


def test_common_valid_box():
    a = np.ones((20, 30), bool)
    b = a.copy()
    b[:2] = False
    c = a.copy()
    c[:, -3:] = False
    assert common_valid_box([a, b, c]) == (2, 20, 0, 27)
    d = a.copy()
    d[5, 5] = False  # a hole: not a rectangle
    assert common_valid_box([a, d]) is None
    assert common_valid_box([np.zeros((4, 4), bool)]) is None


def test_strip_masks_match_the_unmasked_solution(crops):
    seq = render_sequence(
        crops["crop_rows"][:400, :400],
        2,
        [(0, 0), (0.5, 0), (0, 0.5), (0.5, 0.5)],
        0.4,
        snr_db=40,
        seed=4,
    )
    h, w = seq.frames[0].shape
    masks = [np.ones((h, w), bool) for _ in seq.frames]
    masks[1][:3] = False  # an integer crop left these rows without data
    masks[2][:, -2:] = False
    t = time.perf_counter()
    fast = reconstruct_aligned(seq.frames, seq.shifts, 2, masks=masks)
    t_fast = time.perf_counter() - t
    full = reconstruct(seq.frames, seq.shifts, 2)
    assert fast.method == "map"  # the Fourier-domain solver, not conjugate gradients
    b = 16
    inner = (slice(2 * 3 + b, 2 * h - b), slice(b, 2 * (w - 2) - b))
    # inside the common rectangle: the unmasked solution up to the rectangle's own border effects
    assert (
        psnr(fast.image[inner], seq.truth[inner]) > psnr(full.image[inner], seq.truth[inner]) - 0.3
    )
    # the strips are filled from the reference (bicubic), never left empty or NaN
    assert np.isfinite(fast.image).all() and fast.image.shape == (2 * h, 2 * w)
    assert t_fast < 5.0


def test_strips_outside_the_box_are_the_whole_frame_bicubic():
    from subpix_ros.core.superres import bicubic_upscale
    from subpix_ros.core.superres.masks import bicubic_outside as _bicubic_outside

    rng = np.random.default_rng(8)
    for ref in (rng.uniform(0, 255, (40, 52)), rng.uniform(0, 255, (40, 52, 3))):
        for p, box in ((2, (3, 37, 2, 49)), (3, (0, 35, 5, 52)), (4, (6, 40, 0, 47))):
            out = np.full((40 * p, 52 * p) + ref.shape[2:], np.nan)
            _bicubic_outside(out, ref, p, box)
            whole = bicubic_upscale(ref, p)
            r0, r1, c0, c1 = box
            inside = np.zeros(out.shape[:2], bool)
            inside[p * r0 : p * r1, p * c0 : p * c1] = True
            assert np.isnan(out[inside]).all()  # the box is left to the caller
            # OpenCV computes the cubic weights in single precision from absolute coordinates
            assert np.abs(out[~inside] - whole[~inside]).max() < 0.02


def test_colour_strip_masks(crops):
    import cv2

    seq = render_sequence(
        crops["crop_rows"][:300, :300],
        2,
        [(0, 0), (0.5, 0), (0, 0.5), (0.5, 0.5)],
        0.4,
        snr_db=40,
        seed=4,
    )
    h, w = seq.frames[0].shape
    colour = [cv2.merge([f, f, f]) for f in seq.frames]  # grey: the luminance is the mono frame
    masks = [np.ones((h, w), bool) for _ in seq.frames]
    masks[3][-4:] = False
    res = reconstruct_aligned(colour, seq.shifts, 2, masks=masks)
    mono = reconstruct_aligned(seq.frames, seq.shifts, 2, masks=masks)
    assert res.image.shape == (2 * h, 2 * w, 3) and np.isfinite(res.image).all()
    # its luminance is the mono reconstruction (to single-precision round-off), its chroma neutral
    y = cv2.cvtColor(res.image.astype(np.float32), cv2.COLOR_BGR2GRAY)
    assert np.abs(y - mono.image).max() < 0.05
    assert np.abs(res.image[..., 0] - res.image[..., 2]).max() < 0.05


def test_common_box_is_what_common_valid_box_finds_in_the_box_masks():
    from subpix_ros.core.validity import box_mask, common_box

    shape = (20, 30)
    for boxes in (
        [(0, 20, 0, 30), (2, 20, 0, 30), (0, 20, 0, 27)],
        [(0, 20, 0, 30), (-3, 25, 4, 40)],  # beyond the frame: clipped as box_mask clips
        [(0, 10, 0, 30), (12, 20, 0, 30)],  # nothing in common
    ):
        assert common_box(boxes, shape) == common_valid_box([box_mask(shape, b) for b in boxes])
    assert common_box([], shape) is None


def test_common_region_takes_masks_boxes_or_neither():
    from subpix_ros.core.validity import box_mask, common_region

    shape, boxes = (40, 50), [(0, 40, 0, 50), (3, 38, 2, 47)]
    masks = [box_mask(shape, b) for b in boxes]
    assert common_region(shape, boxes=boxes) == common_region(shape, masks=masks) == (3, 38, 2, 47)
    assert common_region(shape) == (0, 40, 0, 50)
    with pytest.raises(ValueError, match="not both"):
        common_region(shape, masks, boxes)
