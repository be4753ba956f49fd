"""Set members packed as their luminance (``core.superres.luma``): what the reconstruction reads."""

from dataclasses import asdict

import cv2
import numpy as np
import pytest
from conftest import assert_lazy_reads, roof_frames

from subpix_ros.core.blur import estimate_blur
from subpix_ros.core.superres import (
    colour_luminance,
    estimate_peak_mb,
    pack_luminance,
    reconstruct_within_budget,
)
from subpix_ros.core.superres.luma import (
    LUMA_FIXED_SCALE,
    LazyLuminance,
    frame_luminance,
    lazy_member_luminance,
)

KW = dict(method="map", geometry="translation", refine_shifts=False, blur_sigma=0.3)


@pytest.fixture(scope="module")
def frames():
    """Eight BGR frames of a real scene with a roof drawn in (conftest.roof_frames)."""
    return roof_frames()


SHIFTS = np.array([[0.23 * k, 0.37 * k] for k in range(8)])


def test_uint8_members_pack_into_two_bytes_within_a_512th_of_a_level(frames):
    f = frames[2]
    packed = pack_luminance(f)
    assert packed.dtype == np.uint16 and packed.shape == f.shape[:2]
    assert packed.nbytes * 3 == f.nbytes * 2
    y = colour_luminance(f)
    back = frame_luminance(packed)
    assert back.dtype == np.float32
    err = np.abs(back.astype(np.float64) - y)
    assert err.max() <= 0.5 / LUMA_FIXED_SCALE + 1e-4 and err.max() > 0  # rounded, not exact
    assert np.array_equal(back, packed.astype(np.float32) / np.float32(LUMA_FIXED_SCALE))


def test_uint16_members_pack_into_their_float32_luminance_exactly(frames):
    f16 = frames[2].astype(np.uint16) * 257
    packed = pack_luminance(f16)
    assert packed.dtype == np.float32 and packed.nbytes * 3 == f16.nbytes * 2
    assert np.array_equal(packed, colour_luminance(f16))
    # mono and float frames are not packed
    assert pack_luminance(frames[0][..., 0]) is not None
    mono = frames[0][..., 1]
    assert pack_luminance(mono) is mono


def test_lazy_reads_of_a_packed_member_are_its_unpacked_values(frames):
    packed = pack_luminance(frames[5])
    lazy = lazy_member_luminance(packed, packed=True)
    assert isinstance(lazy, LazyLuminance)
    full = frame_luminance(packed)
    assert_lazy_reads(lazy, full, 100, seed=1)
    # not packed: the member's own luminance (a mono member is its own)
    assert isinstance(lazy_member_luminance(frames[5], packed=False), LazyLuminance)
    mono = frames[5][..., 0]
    assert lazy_member_luminance(mono, packed=False) is mono


def test_the_blur_estimate_reads_packed_members_as_their_luminance(frames):
    """Edges measured on packed members: the estimate of the unpacked luminance."""
    packed = [colour_luminance(frames[0])] + [
        lazy_member_luminance(pack_luminance(f), packed=True) for f in frames[1:]
    ]
    unpacked = [colour_luminance(frames[0])] + [
        frame_luminance(pack_luminance(f)) for f in frames[1:]
    ]
    got, want = estimate_blur(packed, SHIFTS), estimate_blur(unpacked, SHIFTS)
    assert want.source == "edges", want.reason
    assert repr(asdict(got)) == repr(asdict(want))
    exact = estimate_blur([colour_luminance(f) for f in frames], SHIFTS)
    assert abs(got.sigma - exact.sigma) < 0.005  # a 512th of a level moves it by far less


@pytest.mark.parametrize("tiled", [False, True], ids=["whole", "tiles"])
def test_packed_members_give_the_image_of_their_bgr_frames(frames, tiled):
    """uint16 BGR whole: the same image bit for bit; else within one level, in few pixels.

    (A tile's BGR crop is converted on its own, which OpenCV may round differently in the
    last bit from the whole frame the packed luminance was converted from.)
    """
    budget = 0.6 * estimate_peak_mb(8, frames[0].shape[:2], 2, True) if tiled else None
    for dtype in (np.uint16, np.uint8):
        bgr = [f.astype(np.uint16) * 257 for f in frames] if dtype == np.uint16 else frames
        packed = [bgr[0]] + [pack_luminance(f) for f in bgr[1:]]
        kw = dict(max_memory_mb=budget, out_dtype=dtype, overlap=16, **KW)
        want, plan = reconstruct_within_budget(bgr, SHIFTS, 2, **kw)
        got, plan2 = reconstruct_within_budget(packed, SHIFTS, 2, **kw)
        assert plan.grid == plan2.grid and (plan.grid != (1, 1)) == tiled
        assert got.method == want.method == "map" and not got.fell_back
        d = np.abs(got.image.astype(np.int64) - want.image)
        if dtype == np.uint16 and not tiled:
            assert d.max() == 0
        else:
            assert d.max() <= 1 and (d > 0).mean() < 0.01


def test_a_two_d_member_that_is_not_packed_is_refused(frames):
    """A mono uint8 frame among BGR ones is not read as a packed luminance (it would be 256x off)."""
    mono = cv2.cvtColor(frames[1], cv2.COLOR_BGR2GRAY)
    with pytest.raises(ValueError, match="packed"):
        reconstruct_within_budget([frames[0], mono] + frames[2:], SHIFTS, 2, **KW)
