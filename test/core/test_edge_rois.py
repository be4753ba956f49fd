"""find_edge_rois' 8-bit frame: made in row blocks, the values of the whole-frame float64 formula."""

import cv2
import numpy as np
import pytest

from subpix_ros.core.blur_edges import _scaled_8bit, find_edge_rois
from subpix_ros.data import load_crop


def _whole(frame: np.ndarray) -> np.ndarray:
    """Return the definition (as before the blocks): one float64 copy, then the scaling."""
    f = np.asarray(frame, dtype=np.float64)
    lo, hi = np.percentile(f[::4, ::4], [0.5, 99.5])
    return np.clip((f - lo) * (255.0 / max(hi - lo, 1e-9)), 0, 255).astype(np.uint8)


@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.uint8, np.uint16])
def test_blocks_give_the_whole_frame_values(dtype):
    crop = load_crop("crop_road").astype(np.float64)
    big = cv2.resize(crop, (1100, 700), interpolation=cv2.INTER_CUBIC)  # > 1024: halved for LSD
    frame = big * (257.0 if dtype == np.uint16 else 1.0) + 0.37  # fractional values for floats
    if np.issubdtype(dtype, np.integer):
        frame = np.clip(np.rint(frame), 0, np.iinfo(dtype).max)
    frame = frame.astype(dtype)
    want = _whole(frame)
    for rows in (7, 256):  # many block edges, and the default
        assert np.array_equal(_scaled_8bit(frame, rows=rows), want)
    assert _scaled_8bit(frame[:20]) is None  # too small: no ROI
    assert find_edge_rois(frame) == find_edge_rois(frame.astype(np.float64))
