"""``subpix process``: gaps in the camera's stream (frames the bag never had) are said."""

import numpy as np

from subpix_ros.process.summary import frame_gaps

DT = 100_000_000  # 10 Hz, ns


def test_a_steady_stream_with_jitter_has_no_gap():
    rng = np.random.default_rng(0)
    stamps = np.cumsum(DT + rng.integers(-20_000_000, 20_000_000, 50)).tolist()
    assert frame_gaps(stamps) is None
    assert frame_gaps([0, DT, 5 * DT]) is None  # too few frames for a median interval


def test_lost_frames_are_counted_with_the_largest_gap():
    stamps = [k * DT for k in range(30) if k not in (10, 11, 12, 20)]
    text = frame_gaps(stamps)
    assert text.startswith("2 gaps in the camera's stream (about 4 frames missing"), text
    assert "median interval 0.1 s; largest 0.4 s" in text and "lost before the bag" in text


def test_every_other_frame_lost_is_not_taken_for_the_stream_rate():
    """Half the frames gone from the middle: the median is still the camera's interval."""
    stamps = [k * DT for k in range(40) if k < 14 or k > 26 or k % 2 == 0]
    text = frame_gaps(stamps)
    assert text is not None and text.startswith("6 gaps") and "about 6 frames" in text, text


def test_stamps_going_back_are_left_to_the_time_jumps():
    stamps = [k * DT for k in range(20)] + [k * DT for k in range(20)]
    assert frame_gaps(stamps) is None
