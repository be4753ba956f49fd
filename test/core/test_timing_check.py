"""The telemetry's expected shifts (METHODS B, eq. 1) against the frames': known answers."""

import math

import numpy as np
import pytest

from subpix_ros.core.timing import expected_shift_px
from subpix_ros.core.timing_check import telemetry_agreement, what_would_fit

F = 4.3e-3  # Seneca camera: f = 4.3 mm, 1.54 um pixels


def _flight(pitch_m: float, yaw_offset_deg: float = 0.0, n: int = 24, seed: int = 0):
    """(N, 2) shifts of frames k = 1..7 after their reference, a curving 8 m/s flight at 60 m."""
    rng = np.random.default_rng(seed)
    out = []
    for i in range(n):
        course = math.radians(30.0 + 4.0 * i)
        heading = math.radians(10.0 + 3.0 * i + yaw_offset_deg)
        speed = 8.0 + 0.5 * rng.standard_normal()
        dt = 0.01 * (1 + i % 7)
        out.append(expected_shift_px(speed, course, 60.0, F, pitch_m, dt, heading))
    return np.array(out)


def test_a_stream_downscaled_2x_shows_as_scale_one_half():
    # the frames are a 2x downscaled stream (3.08 um per published pixel); the parameters
    # still say 1.54 um, so the telemetry expects twice the motion the frames show
    measured = _flight(3.08e-6)
    expected = _flight(1.54e-6)
    res = telemetry_agreement(measured, expected)
    assert res.agrees is False
    assert res.scale == pytest.approx(0.5, abs=1e-9)
    assert res.rotation_deg == pytest.approx(0.0, abs=1e-6)
    assert res.pairs == 24 and res.outliers == 0
    assert res.reason.startswith("disagrees: the frames moved 0.500x")
    advice = what_would_fit(res, 4.3, 1.54, 0.0)  # f/a 2792 px given, 1396 px in the frames
    assert "they imply f/a 1396 px (e.g. pixel_pitch_um 3.08" in advice
    assert "yaw" not in advice


@pytest.mark.parametrize("offset", [-25.0, 15.0])
def test_a_camera_yawed_off_its_offset_shows_as_that_rotation(offset):
    # the image's heading is `offset` clockwise of the configured one: the fit says how much
    # to add to camera_yaw_offset_deg
    measured = _flight(1.54e-6, yaw_offset_deg=offset)
    expected = _flight(1.54e-6)
    res = telemetry_agreement(measured, expected)
    assert res.rotation_deg == pytest.approx(offset, abs=1e-6)
    assert res.scale == pytest.approx(1.0, abs=1e-9)
    assert res.agrees is False
    advice = what_would_fit(res, 4.3, 1.54, 5.0)
    assert f"give yaw offset {5.0 + offset:.1f} deg" in advice and "f/a" not in advice


def test_frames_that_did_not_move_are_said_not_fitted_to_a_parameter():
    # a frozen camera: every frame the same image, registration noise of 0.005 px against the
    # telemetry's motion; no pixel pitch or yaw offset would fit, none is given
    expected = _flight(3.08e-6)
    measured = np.random.default_rng(3).normal(0.0, 0.005, expected.shape)
    res = telemetry_agreement(measured, expected)
    assert res.agrees is False and res.still
    assert not res.scale_off and not res.rotation_off and res.rotation_deg is None
    assert res.scale < 0.1
    assert res.reason.startswith("disagrees: the frames did not move (0.01 px RMS")
    assert f"expects {np.sqrt(np.mean(np.sum(expected**2, 1))):.2f} px RMS" in res.reason
    advice = what_would_fit(res, 4.3, 1.54, 0.0)
    assert advice.startswith("a frozen camera or repeated frames?")
    assert "yaw" not in advice and "f/a" not in advice and "pixel_pitch_um" not in advice
    # slow frames (a tenth of the motion and more) are a scale, not a frozen camera
    slow = telemetry_agreement(expected * 0.2, expected)
    assert slow.agrees is False and not slow.still and slow.scale_off


def test_noisy_agreeing_flight_agrees_within_its_error():
    expected = _flight(1.54e-6)
    rng = np.random.default_rng(5)
    measured = expected * 1.01 + rng.normal(0.0, 0.05, expected.shape)  # 1 % and 0.05 px
    res = telemetry_agreement(measured, expected)
    assert res.agrees is True
    assert abs(res.scale - 1.01) < 4 * res.scale_se
    assert 0 < res.scale_se < 0.01
    assert res.rms_px == pytest.approx(0.05 * math.sqrt(2), rel=0.4)
    assert res.reason.startswith("agrees:")
    assert what_would_fit(res, 4.3, 1.54, 0.0) == ""


def test_a_failed_registration_is_left_out_not_fitted():
    expected = _flight(1.54e-6)
    measured = expected.copy()
    measured[3] += (40.0, -25.0)  # a wrong homography
    measured[7] = np.nan  # a pair without a measured shift
    res = telemetry_agreement(measured, expected)
    assert res.outliers == 1 and res.pairs == 22
    assert res.scale == pytest.approx(1.0, abs=1e-9)
    assert res.agrees is True


def test_too_little_to_tell_says_why():
    expected = _flight(1.54e-6)
    few = telemetry_agreement(expected[:2], expected[:2])
    assert few.agrees is None and few.scale is None
    assert "2 frame pairs" in few.reason
    hover = telemetry_agreement(expected * 1e-3, expected * 1e-3)
    assert hover.agrees is None and "px RMS" in hover.reason


def test_a_noisy_fit_is_undecided_not_agreeing():
    # 4 pairs of about 1.5 px against 1 px of registration noise: a 10 % scale is beyond them
    expected = _flight(1.54e-6)[:4]
    rng = np.random.default_rng(2)
    measured = expected + rng.normal(0.0, 1.0, expected.shape)
    res = telemetry_agreement(measured, expected)
    assert res.agrees is None and res.scale is not None
    assert 3 * res.scale_se > 0.1
    assert res.reason.startswith("undecided")


def test_malformed_input_raises():
    with pytest.raises(ValueError):
        telemetry_agreement(np.zeros((5, 3)), np.zeros((5, 3)))
    with pytest.raises(ValueError):
        telemetry_agreement(np.zeros((5, 2)), np.zeros((6, 2)))
