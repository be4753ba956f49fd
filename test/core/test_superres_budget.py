"""A memory budget makes the reconstruction use tiles or fewer frames (and say so), not grow."""

import cv2
import numpy as np
import pytest

from subpix_ros.core.render import render_sequence
from subpix_ros.core.superres import bicubic_upscale, psnr
from subpix_ros.core.superres.budget import (
    estimate_peak_mb,
    plan_reconstruction,
    reconstruct_within_budget,
)
from subpix_ros.core.superres.masks import reconstruct_aligned

SHIFTS8 = [
    (0, 0),
    (0.5, 0),
    (0, 0.5),
    (0.5, 0.5),
    (0.25, 0.75),
    (0.75, 0.25),
    (0.3, 0.1),
    (0.6, 0.8),
]
KW = dict(method="map", geometry="translation", refine_shifts=False)


@pytest.fixture(scope="module")
def seq(crops):
    return render_sequence(crops["crop_rows"][:720, :720], 2, SHIFTS8, 0.4, snr_db=40, seed=3)


def test_plan_unbounded_and_generous_budget_change_nothing():
    for budget in (None, 0, 10_000):
        plan = plan_reconstruction(16, (1080, 1920), 2, budget)
        assert plan.grid == (1, 1) and plan.n_frames == 16 and not plan.reduced and not plan.bicubic
    # the model grows with the frames and the area
    assert estimate_peak_mb(16, (1080, 1920), 2, True) > estimate_peak_mb(8, (1080, 1920), 2, True)
    assert estimate_peak_mb(8, (2160, 3840), 2, True) > 3 * estimate_peak_mb(
        8, (1080, 1920), 2, True
    )


def test_plan_prefers_tiles_then_fewer_frames_then_bicubic():
    whole = estimate_peak_mb(16, (1080, 1920), 2, True)
    plan = plan_reconstruction(16, (1080, 1920), 2, whole / 2)
    assert plan.n_frames == 16 and plan.grid[0] * plan.grid[1] > 1  # all frames kept, tiled
    assert plan.estimate_mb <= whole / 2 and plan.unbounded_mb == pytest.approx(whole)
    assert any("tiles" in r for r in plan.reductions)
    # frames smaller than two minimum tiles cannot be tiled: frames are dropped instead
    small = plan_reconstruction(
        16, (200, 200), 2, estimate_peak_mb(6, (200, 200), 2, True), min_frames=4
    )
    assert small.grid == (1, 1) and small.n_frames == 6 and small.reductions == ["6 of 16 frames"]
    # nothing fits: bicubic, and the reason says so
    tiny = plan_reconstruction(16, (1080, 1920), 2, 5, min_frames=4)
    assert tiny.bicubic and "bicubic" in tiny.reductions[0]
    with pytest.raises(ValueError):
        plan_reconstruction(1, (100, 100), 2, 100)


def test_tiled_reconstruction_fits_the_budget_and_keeps_the_gain(seq):
    h, w = seq.frames[0].shape
    full, plan0 = reconstruct_within_budget(seq.frames, seq.shifts, 2, **KW)
    assert not plan0.reduced
    budget = 0.9 * plan0.unbounded_mb  # small frames: the fixed overheads are a large part
    tiled, plan = reconstruct_within_budget(
        seq.frames, seq.shifts, 2, max_memory_mb=budget, overlap=16, **KW
    )
    assert plan.reduced and plan.n_frames == len(seq.frames) and plan.grid[0] * plan.grid[1] >= 2
    assert plan.estimate_mb <= budget
    assert (
        tiled.image.shape == full.image.shape == (2 * h, 2 * w) and np.isfinite(tiled.image).all()
    )
    assert tiled.method == "map" and not tiled.fell_back
    b = 16
    inner = (slice(b, 2 * h - b), slice(b, 2 * w - b))
    p_full = psnr(full.image[inner], seq.truth[inner])
    p_tiled = psnr(tiled.image[inner], seq.truth[inner])
    p_bic = psnr(bicubic_upscale(seq.frames[0], 2)[inner], seq.truth[inner])
    # the tiles keep the super-resolution gain (each tile fits its own prior: not bit-equal)
    assert p_full - p_bic > 1.0
    assert p_tiled > p_full - 0.3


def test_fewer_frames_are_the_first_frames_reconstructed_as_usual(seq):
    small = [f[:150, :150] for f in seq.frames]
    budget = estimate_peak_mb(5, (150, 150), 2, False)
    res, plan = reconstruct_within_budget(
        small, seq.shifts, 2, max_memory_mb=budget, min_frames=4, **KW
    )
    assert plan.n_frames == 5 and plan.reductions == [f"5 of {len(small)} frames"]
    ref = reconstruct_aligned(small[:5], np.asarray(seq.shifts)[:5], 2, **KW)
    np.testing.assert_array_equal(res.image, ref.image)


def test_budget_too_small_gives_the_bicubic_reference_and_says_why(seq):
    res, plan = reconstruct_within_budget(seq.frames, seq.shifts, 2, max_memory_mb=1, **KW)
    assert plan.bicubic and res.fell_back and res.method == "bicubic" and "MB" in res.reason
    np.testing.assert_allclose(res.image, bicubic_upscale(seq.frames[0], 2))


def test_colour_and_strip_masks_are_tiled_inside_the_common_rectangle(seq):
    frames = [np.repeat(f[:, :, None], 3, axis=2) for f in seq.frames]
    h, w = frames[0].shape[:2]
    masks = [np.ones((h, w), bool) for _ in frames]
    masks[1][:5] = False
    masks[2][:, -7:] = False
    full = reconstruct_aligned(frames, seq.shifts, 2, masks=masks, **KW)
    res, plan = reconstruct_within_budget(
        frames,
        seq.shifts,
        2,
        masks=masks,
        max_memory_mb=0.9 * estimate_peak_mb(8, (h, w), 2, True),
        overlap=16,
        **KW,
    )
    assert plan.grid[0] * plan.grid[1] >= 2 and res.image.shape == (2 * h, 2 * w, 3)
    assert res.image.dtype == np.float32 and np.isfinite(res.image).all()
    # outside the common rectangle both are the reference's bicubic upscale
    np.testing.assert_allclose(res.image[:10], full.image[:10], atol=1e-3)
    np.testing.assert_allclose(res.image[:, -14:], full.image[:, -14:], atol=1e-3)
    b = 24
    inner = (slice(10 + b, 2 * h - b), slice(b, 2 * w - 14 - b))
    assert (
        psnr(res.image[inner][..., 0], seq.truth[inner])
        > psnr(full.image[inner][..., 0], seq.truth[inner]) - 0.3
    )


def _colour_masked(seq):
    frames = [np.repeat(np.clip(f, 0, 255)[:, :, None], 3, axis=2) for f in seq.frames]
    h, w = frames[0].shape[:2]
    masks = [np.ones((h, w), bool) for _ in frames]
    masks[1][:5] = False  # a strip outside the common rectangle: bicubic there
    masks[2][:, -7:] = False
    return frames, masks, estimate_peak_mb(8, (h, w), 2, True)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("tiled", [False, True], ids=["whole", "tiles"])
def test_out_dtype_rounds_what_the_float_image_would_hold(seq, dtype, tiled):
    from subpix_ros.core.superres.result import to_integer_image

    frames, masks, whole_mb = _colour_masked(seq)
    if dtype is np.uint16:
        frames = [f * 200.0 for f in frames]  # beyond 8 bit
    budget = 0.9 * whole_mb if tiled else None
    kw = dict(masks=masks, overlap=16, **KW)
    got, plan = reconstruct_within_budget(
        frames, seq.shifts, 2, out_dtype=dtype, max_memory_mb=budget, **kw
    )
    # the float image under the budget that gives it the same plan (its output is larger)
    h, w = frames[0].shape[:2]
    extra = (4 - np.dtype(dtype).itemsize) * h * w * 4 * 3 / 1e6
    flt, plan2 = reconstruct_within_budget(
        frames, seq.shifts, 2, max_memory_mb=budget and budget + extra, **kw
    )
    assert (plan2.n_frames, plan2.grid) == (plan.n_frames, plan.grid)
    assert (plan.grid != (1, 1)) == tiled
    assert got.image.dtype == dtype
    np.testing.assert_array_equal(got.image, to_integer_image(flt.image, dtype))


def test_an_integer_output_is_planned_at_its_own_size():
    """A 4K colour set rounded into uint8 fits 250 MB in tiles; as float32 it would not.

    The stitched output counts 1 B per value, not 4 (a 7680x4320 colour image: 100 MB, not
    398 MB); with nothing that fits, the bicubic fallback is made in the output type too.
    """
    as_float = plan_reconstruction(8, (2160, 3840), 2, 250.0)
    as_uint8 = plan_reconstruction(8, (2160, 3840), 2, 250.0, out_bytes=1)
    assert as_float.bicubic and not as_uint8.bicubic
    assert as_uint8.n_frames == 8 and as_uint8.grid[0] * as_uint8.grid[1] > 1
    assert as_uint8.estimate_mb <= 250.0
    # nothing fits: the fallback is the reference's bicubic upscale, rounded, as uint8
    rng = np.random.default_rng(0)
    ref = rng.integers(0, 256, (64, 96, 3), dtype=np.uint8)
    frames = [ref, np.roll(ref, 1, axis=1)]
    res, plan = reconstruct_within_budget(
        frames, np.array([[0.0, 0.0], [0.0, 1.0]]), 2, max_memory_mb=0.01, out_dtype=np.uint8
    )
    assert plan.bicubic and res.method == "bicubic" and res.fell_back
    up = cv2.resize(ref.astype(np.float32), (192, 128), interpolation=cv2.INTER_CUBIC)
    from subpix_ros.core.superres.result import to_integer_image

    assert res.image.dtype == np.uint8
    np.testing.assert_array_equal(res.image, to_integer_image(up, np.uint8))


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
def test_colour_out_dtype_rounds_the_float_image_with_real_chroma(seq, dtype):
    """Integer colour images are the rounded float32 ones, for real chroma.

    Chroma varies across the frame and saturates in places; the bicubic border is included.
    """
    from subpix_ros.core.superres.result import to_integer_image

    scale = 255.0 if dtype is np.uint8 else 65535.0
    frames = []
    for f in seq.frames:
        g = np.clip(f, 0, 255) / 255.0
        ramp = np.linspace(0.0, 1.0, g.shape[1])[None, :]
        bgr = np.dstack([g, 0.6 * g + 0.4 * ramp, np.clip(1.2 - g - 0.3 * ramp, 0, 1)])
        frames.append(np.round(bgr * scale).astype(dtype))
    _, masks, _ = _colour_masked(seq)
    kw = dict(masks=masks, **KW)
    flt = reconstruct_aligned(frames, seq.shifts, 2, **kw)
    got = reconstruct_aligned(frames, seq.shifts, 2, out_dtype=dtype, **kw)
    assert flt.image.dtype == np.float32 and got.image.dtype == dtype
    assert np.ptp(got.image[..., 2].astype(float) - got.image[..., 0]) > 0.3 * scale
    np.testing.assert_array_equal(got.image, to_integer_image(flt.image, dtype))


def test_out_dtype_refuses_non_finite_pixels_whole_or_in_tiles(seq, monkeypatch):
    from subpix_ros.core.superres import reconstruction as recon_mod
    from subpix_ros.core.superres.result import NonFiniteImageError

    real = recon_mod.reconstruct  # the luminance solve, whole or per tile

    def nan_corner(*a, **k):
        res = real(*a, **k)
        res.image[3, 3] = np.nan
        return res

    monkeypatch.setattr(recon_mod, "reconstruct", nan_corner)
    frames, masks, whole_mb = _colour_masked(seq)
    for budget in (None, 0.9 * whole_mb):
        kw = dict(masks=masks, max_memory_mb=budget, overlap=16, **KW)
        with pytest.raises(NonFiniteImageError):
            reconstruct_within_budget(frames, seq.shifts, 2, out_dtype=np.uint8, **kw)
        flt, _ = reconstruct_within_budget(frames, seq.shifts, 2, **kw)  # the float image as is
        assert np.isnan(flt.image).any()


def test_boxes_give_the_same_image_and_plan_as_their_masks(seq):
    """Rectangles instead of masks (integer crops) give bit-identical images.

    Whole, tiled, with frames cut, and on the masked (CG) path.
    """
    from subpix_ros.core.validity import box_mask

    frames = [np.repeat(np.clip(f, 0, 255)[:, :, None], 3, axis=2) for f in seq.frames]
    h, w = frames[0].shape[:2]
    whole = estimate_peak_mb(8, (h, w), 2, True)
    wide = [(0, h, 0, w), (5, h, 0, w), (0, h, 0, w - 7)] + [(0, h, 0, w)] * 5
    small = [f[:200, :200] for f in frames]
    # the last frame's rectangle is narrower: a plan without it has a wider one
    cut = [(0, 200, 0, 200), (4, 200, 0, 200)] + [(0, 200, 0, 197)] * 5 + [(0, 200, 0, 190)]
    cases = [
        (frames, wide, None),
        (frames, wide, 0.9 * whole),
        (small, cut, None),
        (
            small,
            cut,
            estimate_peak_mb(5, (200, 200), 2, True),
        ),
        (
            [f[:96, :96] for f in frames],
            [(0, 96, 0, 96), (0, 96, 0, 20)] + [(0, 96, 0, 96)] * 6,
            None,
        ),
    ]
    plans = []
    for fr, boxes, budget in cases:
        shape = fr[0].shape[:2]
        masks = [box_mask(shape, b) for b in boxes]
        kw = dict(max_memory_mb=budget, overlap=16, out_dtype=np.uint8, **KW)
        a, plan_a = reconstruct_within_budget(fr, seq.shifts, 2, masks=masks, **kw)
        b, plan_b = reconstruct_within_budget(fr, seq.shifts, 2, boxes=boxes, **kw)
        assert plan_a == plan_b
        assert a.method == b.method and np.array_equal(a.image, b.image), (shape, budget)
        plans.append((plan_a, a.method))
    assert plans[1][0].grid != (1, 1)  # tiled
    assert plans[3][0].n_frames < 8 and plans[3][0].grid == (1, 1)  # frames cut
    assert plans[4][1] == "map-cg"  # the masked solver, its masks made from the boxes
    with pytest.raises(ValueError):
        reconstruct_within_budget(
            frames, seq.shifts, 2, masks=[box_mask((h, w), b) for b in wide], boxes=wide
        )
