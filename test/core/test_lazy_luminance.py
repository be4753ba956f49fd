"""LazyLuminance: the blur calibration's luminance read only where it is needed, same numbers."""

import re
from dataclasses import asdict
from pathlib import Path

import cv2
import numpy as np
import pytest

from subpix_ros.core.blur import estimate_blur
from subpix_ros.core.blur_edges import find_edge_rois, spectral_cap
from subpix_ros.core.mtf import slanted_edge_mtf
from subpix_ros.core.superres import colour_luminance
from subpix_ros.core.superres.luma import LazyLuminance

SCENE = Path(__file__).resolve().parents[2] / "data" / "seneca" / "IMG_0463.jpg"


@pytest.fixture(scope="module")
def frames():
    """Eight BGR frames of a real scene with a roof drawn in, at sub-pixel offsets, 8 bit."""
    scene = cv2.imread(str(SCENE), cv2.IMREAD_COLOR)
    big = cv2.resize(scene, None, fx=4, fy=4, interpolation=cv2.INTER_CUBIC)
    roof = np.array([[1600, 1000], [2300, 1100], [2230, 1600], [1530, 1500]], np.int32)
    cv2.fillPoly(big, [roof], (200, 210, 220), lineType=cv2.LINE_AA)  # straight, slanted edges
    small = cv2.resize(big, None, fx=0.25, fy=0.25, interpolation=cv2.INTER_AREA)
    out = []
    for k in range(8):
        m = np.float32([[1, 0, -200 + 0.37 * k], [0, 1, -100 + 0.23 * k]])
        out.append(cv2.warpAffine(small, m, (521, 463), flags=cv2.INTER_CUBIC))
    return out


def test_slices_and_range_are_those_of_the_whole_luminance(frames):
    f = frames[3]
    full = colour_luminance(f)
    lazy = LazyLuminance(f)
    assert lazy.shape == full.shape and lazy.ndim == 2
    rng = np.random.default_rng(0)
    for _ in range(200):
        r0, c0 = rng.integers(0, 450), rng.integers(0, 500)
        r1, c1 = r0 + rng.integers(1, 140), c0 + rng.integers(1, 90)
        assert np.array_equal(lazy[r0:r1, c0:c1], full[r0:r1, c0:c1])
    assert lazy.min() == full.min() and lazy.max() == full.max()
    assert np.array_equal(np.asarray(lazy), full)
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
