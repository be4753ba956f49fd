"""LazyLuminance: the blur calibration's luminance read only where it is needed, same numbers."""

import re
from dataclasses import asdict

import numpy as np
import pytest
from conftest import assert_lazy_reads, roof_frames

from subpix_ros.core.blur import estimate_blur
from subpix_ros.core.blur_edges import find_edge_rois, spectral_cap
from subpix_ros.core.mtf import slanted_edge_mtf
from subpix_ros.core.superres import colour_luminance
from subpix_ros.core.superres.luma import LazyLuminance


@pytest.fixture(scope="module")
def frames():
    """Eight BGR frames of a real scene with a roof drawn in (conftest.roof_frames)."""
    return roof_frames()


def test_slices_and_range_are_those_of_the_whole_luminance(frames):
    f = frames[3]
    full = colour_luminance(f)
    lazy = LazyLuminance(f)
    assert lazy.shape == full.shape and lazy.ndim == 2
    assert_lazy_reads(lazy, full, 200, seed=0)
    with pytest.raises(IndexError):
        lazy[::2, :]
    with pytest.raises(ValueError):
        LazyLuminance(f.astype(np.float32))


def test_blur_estimate_and_its_parts_are_bit_identical(frames):
    full = [colour_luminance(f) for f in frames]
    lazy = [full[0]] + [LazyLuminance(f) for f in frames[1:]]
    shifts = np.array([[0.23 * k, 0.37 * k] for k in range(8)])
    assert spectral_cap(lazy, 1.0) == spectral_cap(full, 1.0)
    measured = 0
    for roi in find_edge_rois(full[0])[:6]:  # edge ROIs measured both ways, in every frame
        for k in range(1, 8):
            try:
                a = slanted_edge_mtf(full[k], roi)
            except ValueError as exc:
                with pytest.raises(ValueError, match=re.escape(str(exc))):
                    slanted_edge_mtf(lazy[k], roi)
                continue
            b = slanted_edge_mtf(lazy[k], roi)
            assert a.mtf50 == b.mtf50 and np.array_equal(a.mtf, b.mtf)
            measured += 1
    assert measured >= 7
    want = estimate_blur(full, shifts)
    got = estimate_blur(lazy, shifts)
    assert want.source == "edges", want.reason  # the edge path, not the fallback
    assert repr(asdict(got)) == repr(asdict(want))


def test_boxes_give_the_estimate_their_masks_give(frames):
    """Valid rectangles (integer crops) instead of masks: the same edges measured, same numbers."""
    from subpix_ros.core.validity import box_mask

    lazy = [colour_luminance(frames[0])] + [LazyLuminance(f) for f in frames[1:]]
    shifts = np.array([[0.23 * k, 0.37 * k] for k in range(8)])
    h, w = lazy[0].shape
    full = (0, h, 0, w)
    estimates = []
    for boxes in (
        [full] * 8,
        [full] * 4 + [(3, h, 0, 300)] * 4,  # the roof's right side out of half the frames
        [full] + [(0, 200, 0, w)] * 7,  # its lower edge out of all but the reference
    ):
        masks = [box_mask((h, w), b) for b in boxes]
        want = estimate_blur(lazy, shifts, masks=masks)
        got = estimate_blur(lazy, shifts, boxes=boxes)
        assert repr(asdict(got)) == repr(asdict(want))
        estimates.append(want)
    assert estimates[0].source == "edges"
    assert len({e.reason for e in estimates}) > 1  # the rectangles did change what was measured
