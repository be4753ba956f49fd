"""``subpix process``: telemetry that does not cover the frames' times is said (no silent gap)."""

import pytest

from subpix_ros.core.telemetry import sample_from_enu
from subpix_ros.process.summary import telemetry_coverage, telemetry_unusable

T0 = 1_717_000_000.0  # 2024-05-29 16:26:40 UTC
FRAMES = [T0 + 0.1 * k for k in range(20)]  # 2 s of frames


def test_telemetry_over_the_frames_is_not_a_problem():
    samples = [T0 - 1.0 + 0.2 * k for k in range(20)]  # -1 .. +2.8 s
    assert telemetry_coverage(samples, FRAMES, 0.0, 0.5) is None
    # starting a little late (2 frames before its first sample): ordinary, not a problem
    assert telemetry_coverage([T0 + 0.15 + 0.2 * k for k in range(20)], FRAMES, 0.0, 0.5) is None


def test_telemetry_an_hour_off_is_said_with_both_spans():
    samples = [T0 + 3600.0 + 0.2 * k for k in range(20)]
    text = telemetry_coverage(samples, FRAMES, 0.0, 0.5)
    assert text.startswith("telemetry covers 0 of 20 frames")
    assert "2024-05-29 17:26:40.0 - 2024-05-29 17:26:43.8 UTC" in text
    assert "2024-05-29 16:26:40.0 - 2024-05-29 16:26:41.9" in text
    assert "the telemetry starts 3598.1 s after the last frame" in text
    # the same clocks put right by telemetry_time_offset_s: covered
    assert telemetry_coverage(samples, FRAMES, 3600.0, 0.5) is None


def test_telemetry_ending_early_or_covering_half_is_said():
    ended = telemetry_coverage([T0 - 60.0 + k for k in range(10)], FRAMES, 0.0, 0.5)
    assert "covers 0 of 20" in ended and "it ends 50.5 s before the first frame" in ended
    half = telemetry_coverage([T0 + 1.0 + 0.2 * k for k in range(20)], FRAMES, 0.0, 0.5)
    assert half.startswith("telemetry covers 10 of 20 frames")
    assert "starts" not in half and "ends" not in half


def test_nothing_to_compare_is_not_this_problem():
    # no telemetry at all is said elsewhere ("no telemetry ..."), no frames likewise
    assert telemetry_coverage([], FRAMES, 0.0, 0.5) is None
    assert telemetry_coverage([T0], [], 0.0, 0.5) is None


def _samples(n, height=60.0, east=5.0):
    return [sample_from_enu(T0 + 0.1 * k, (east, 2.0, 0.0), height) for k in range(n)]


@pytest.mark.parametrize(
    "height, east, what",
    [
        (-3.0, 5.0, "have height -3 m (must be > 0)"),
        (0.0, 5.0, "have height 0 m (must be > 0)"),
        (float("nan"), 5.0, "have height nan m (must be finite and > 0)"),
        (60.0, float("nan"), "have velocity nan m/s (must be finite)"),
    ],
)
def test_telemetry_present_but_unusable_is_said_with_why(height, east, what):
    text = telemetry_unusable(_samples(28, height, east))
    said = f"telemetry unusable: 28 of 28 samples {what}: no frame timing or expected shift"
    assert text == said + " from it", text


def test_telemetry_partly_unusable_is_said_by_kind_and_a_few_bad_samples_are_not():
    good = _samples(20)
    assert telemetry_unusable(good) is None
    assert telemetry_unusable(good + _samples(2, -1.0)) is None  # max(2, 10 %): ordinary
    text = telemetry_unusable(good + _samples(3, -1.0) + _samples(1, -2.0) + _samples(3, 60, 1e3))
    assert text.startswith(
        "telemetry partly unusable: 4 of 27 samples have height e.g. -1 m (must be > 0), "
        "3 are invalid (absurd ground speed"
    ), text
    assert text.endswith("the frames at their times have no frame timing or expected shift")
    hovering = _samples(20, east=0.0)  # valid: the frame selection says it hovers
    assert telemetry_unusable([sample_from_enu(T0, (0.0, 0.0, 0.0), 60.0)] + hovering) is None
