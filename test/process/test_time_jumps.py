"""``subpix process``: frames whose stamps go back in time are said, with what it did."""

from subpix_ros.process.summary import time_jumps_back


def test_stamps_that_only_go_forward_are_not_a_problem():
    assert time_jumps_back([]) is None


def test_jumps_back_are_counted_with_the_largest():
    text = time_jumps_back([33_333_333, 1_000_000_000, 33_333_333])
    assert text.startswith("3 time jump(s) back in the frames' stamps (largest 1 s)"), text
    assert "the pipeline restarted at each" in text and "frames out of order in the bag" in text
