"""Frame timing (METHODS.md B, eqs. 1-2) against hand-computed numbers."""

import math

import pytest

from subpix_ros.core.timing import (
    FrameSelector,
    detector_angle,
    expected_shift_px,
    frame_interval,
    image_speed_px_s,
)

# Seneca camera (Canon ELPH 300 HS): pitch 1.54 um, f = 4.3 mm.
A = 1.54e-6
F = 4.3e-3


def test_detector_angle_hand_values():
    assert detector_angle(2) == pytest.approx(math.pi / 4, abs=1e-15)  # arctan(1)
    assert math.degrees(detector_angle(4)) == pytest.approx(
        18.434948822922, abs=1e-9
    )  # arctan(1/3)
    assert math.tan(detector_angle(5)) == pytest.approx(0.25, abs=1e-15)


@pytest.mark.parametrize("p", [1, 1.5, 0, -3, float("nan"), float("inf")])
def test_detector_angle_rejects(p):
    with pytest.raises(ValueError):
        detector_angle(p)


def test_frame_interval_seneca_hand_value():
    # t = a H cos(phi) / (p f V) = 1.54e-6 * 60 / (2 * 4.3e-3 * 10) = 9.24e-5 / 0.086
    r = frame_interval(A, 60.0, F, 10.0, 2)
    assert r.ok and r.reason == ""
    assert r.interval_s == pytest.approx(1.0744186046511628e-3, rel=1e-12)
    assert r.phi_rad == 0.0
    # image speed f V / (H a) = 0.043 / 9.24e-5 px/s
    assert r.shift_px_per_s == pytest.approx(465.36796536796535, rel=1e-12)
    assert r.step_px == pytest.approx(0.5, rel=1e-12)  # cos(0)/p
    assert r.frame_rate_hz == pytest.approx(1 / 1.0744186046511628e-3, rel=1e-12)


def test_frame_interval_with_detector_rotation():
    # p = 4, phi = arctan(1/3): cos = 3/sqrt(10); t = 1.54e-6*60*0.9486833/(4*4.3e-3*10)
    phi = detector_angle(4)
    r = frame_interval(A, 60.0, F, 10.0, 4, phi)
    assert r.ok
    assert r.interval_s == pytest.approx(1.54e-6 * 60 * 3 / math.sqrt(10) / 0.172, rel=1e-12)
    assert r.interval_s == pytest.approx(5.09641e-4, rel=1e-5)
    assert r.phi_deg == pytest.approx(18.434948822922)
    assert r.as_dict()["interval_s"] == r.interval_s


@pytest.mark.parametrize(
    "kw,word",
    [
        (dict(speed_mps=0.0), "speed"),
        (dict(speed_mps=-5.0), "speed"),
        (dict(speed_mps=float("nan")), "speed"),
        (dict(speed_mps=float("inf")), "speed"),
        (dict(height_m=0.0), "height"),
        (dict(height_m=-10.0), "height"),
        (dict(focal_length_m=0.0), "focal"),
        (dict(pixel_pitch_m=float("nan")), "pitch"),
        (dict(p=1), "p must"),
        (dict(p=1.9), "p must"),
        (dict(phi_rad=math.pi / 2), "cos(phi)"),
        (dict(phi_rad=float("nan")), "phi"),
    ],
)
def test_frame_interval_bad_input_gives_reason_not_number(kw, word):
    args = dict(pixel_pitch_m=A, height_m=60.0, focal_length_m=F, speed_mps=10.0, p=2)
    args.update(kw)
    r = frame_interval(**args)
    assert r.ok is False
    assert r.interval_s is None
    assert word in r.reason


def test_expected_shift_directions_and_scale():
    s = image_speed_px_s(10.0, 60.0, F, A)
    assert s == pytest.approx(465.36796536796535, rel=1e-12)
    # flying towards the image top: features slide down (u > 0)
    u, v = expected_shift_px(10.0, 0.0, 60.0, F, A, 0.01)
    assert u == pytest.approx(4.6536796536796535, rel=1e-12) and abs(v) < 1e-12
    # flying towards the image right (course east, image top north): features slide left
    u, v = expected_shift_px(10.0, math.pi / 2, 60.0, F, A, 0.01)
    assert abs(u) < 1e-12 and v == pytest.approx(-4.6536796536796535, rel=1e-12)
    # image rotated: top points east, flying east -> like flying to the top
    u, v = expected_shift_px(10.0, math.pi / 2, 60.0, F, A, 0.01, image_heading_rad=math.pi / 2)
    assert u == pytest.approx(4.6536796536796535, rel=1e-12) and abs(v) < 1e-12
    # 30 deg right of the image top
    u, v = expected_shift_px(10.0, math.radians(30), 60.0, F, A, 1.0)
    assert (u, v) == pytest.approx((s * math.sqrt(3) / 2, -s / 2), rel=1e-12)
    assert expected_shift_px(0.0, 1.0, 60.0, F, A, 1.0) == (0.0, -0.0)


@pytest.mark.parametrize(
    "args",
    [
        (-1.0, 0.0, 60.0, F, A, 1.0),
        (10.0, 0.0, 0.0, F, A, 1.0),
        (10.0, 0.0, 60.0, F, A, -1.0),
        (10.0, float("nan"), 60.0, F, A, 1.0),
        (float("inf"), 0.0, 60.0, F, A, 1.0),
    ],
)
def test_expected_shift_rejects(args):
    with pytest.raises(ValueError):
        expected_shift_px(*args)


def _run(sel, rate, fps, n):
    kept = []
    for i in range(n):
        d = sel.decide(i / fps, rate)
        if d.keep:
            kept.append(i)
    return kept


def test_selector_steps_by_one_over_p():
    # 0.05 px per frame along u, p = 4 -> keep every 5th frame (0.25 px)
    sel = FrameSelector(4)
    kept = _run(sel, (1.5, 0.0), 30.0, 41)
    assert kept == list(range(0, 41, 5))
    steps = [0.05 * (b - a) for a, b in zip(kept, kept[1:])]
    assert all(abs(s - 0.25) < 1e-9 for s in steps)


def test_selector_picks_closest_frame():
    # 0.07 px/frame, p = 4: candidates 0.21 (3 frames) and 0.28 (4 frames); 0.28 is closer
    sel = FrameSelector(4)
    kept = _run(sel, (0.0, -2.1), 30.0, 13)
    assert kept[:3] == [0, 4, 8]
    assert FrameSelector(4).decide(0.0, (0.0, -2.1)).reason == "first frame"


def test_selector_without_or_with_stale_telemetry_keeps_every_frame():
    sel = FrameSelector(3)
    ds = [sel.decide(i * 0.1, None) for i in range(5)]
    assert all(d.keep for d in ds)
    assert all("no telemetry" in d.reason for d in ds[1:])
    sel = FrameSelector(3, max_age_s=0.5)
    sel.decide(0.0, (1.0, 0.0), 0.0)
    d = sel.decide(2.0, (1.0, 0.0), rate_stamp_s=0.2)
    assert d.keep and "stale" in d.reason
    d = sel.decide(2.1, (float("nan"), 0.0))
    assert d.keep and "not finite" in d.reason


def test_selector_too_slow_stream_and_time_reversal():
    sel = FrameSelector(4)
    sel.decide(0.0, (30.0, 0.0))
    d = sel.decide(1 / 30, (30.0, 0.0))  # 1 px per frame > 0.25
    assert d.keep and "too low" in d.reason
    d = sel.decide(0.0, (30.0, 0.0))
    assert d.keep and "did not increase" in d.reason


def test_selector_phase_mode():
    # 2.05 px per frame, p = 4: accumulated 2.05, 4.10, 6.15, 8.20, 10.25 -> phase 0.25 at frame 5
    sel = FrameSelector(4, mode="phase", tolerance_px=0.03)
    kept = _run(sel, (0.0, 61.5), 30.0, 16)
    assert kept == [0, 5, 10, 15]
    # in step mode the same stream is too slow for 1/p: every frame kept
    assert _run(FrameSelector(4), (0.0, 61.5), 30.0, 6) == list(range(6))


def test_selector_rejects_bad_config():
    with pytest.raises(ValueError):
        FrameSelector(1)
    with pytest.raises(ValueError):
        FrameSelector(4, mode="nope")
    with pytest.raises(ValueError):
        FrameSelector(4, max_age_s=0)
