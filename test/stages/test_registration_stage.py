"""RegistrationStage without ROS: reference switching, skips, tracking fallback, time jumps."""

import math
import re

import numpy as np
import pytest
from conftest import scene_frames

from subpix_ros.core.telemetry import sample_from_enu
from subpix_ros.data import load_crop
from subpix_ros.stages import Aligned, Frame, NewReference, RegistrationStage, Skipped

FAST = dict(selection="all", distortion=False, n_points=300)


def stamp(k, t0=1_000_000_000, dt=100_000_000):
    return t0 + k * dt


def _run(stage, frames):
    return [stage.add(f) for f in frames]


def test_reference_switches_when_the_set_is_complete(flight):
    frames, _ = flight
    stage = RegistrationStage(max_frames_per_reference=3, **FAST)
    out = _run(stage, frames[:9])
    kinds = [type(r).__name__ for r in out]
    assert kinds == ["NewReference", "Aligned", "Aligned", "Aligned"] * 2 + ["NewReference"], kinds
    assert [r.reason for r in out if isinstance(r, NewReference)] == [
        "first frame",
        "set complete",
        "set complete",
    ]
    assert all(a.reference is out[0].frame for a in out[1:4])
    assert (
        stage.stats.references == 3
        and stage.stats.kept == 9
        and stage.stats.registration_failures == 0
    )
    assert stage.stats.reference_stamp_ns == frames[8].stamp_ns


def test_an_integer_crop_is_held_as_its_rectangle_not_a_mask(flight):
    """Translation-only frames are aligned by integer crops: no 2 MB mask per 1080p frame held."""
    from subpix_ros.core.validity import common_valid_box

    frames, _ = flight
    stage = RegistrationStage(max_frames_per_reference=3, **FAST)
    out = [r for r in _run(stage, frames[:4]) if isinstance(r, Aligned)]
    assert len(out) == 3
    for a in out:
        assert a.mask is None and a.box is not None
        valid = a.valid_mask()
        assert valid.shape == a.image.shape[:2] and common_valid_box([valid]) == a.box
        assert not a.image[~valid].any()  # outside the rectangle: nothing from the frame
    with pytest.raises(ValueError, match="mask or a box"):
        Aligned(0, frames[0].image, None, frames[0], np.eye(3))


def test_a_failed_registration_starts_a_new_reference_with_its_reason(flight):
    frames, _ = flight
    problems = []
    stage = RegistrationStage(**FAST)
    stage.on_problem = lambda level, msg: problems.append((level, msg))
    other = load_crop("crop_road")[: frames[0].image.shape[0], : frames[0].image.shape[1]]
    if frames[0].image.ndim == 3:
        other = np.repeat(other[:, :, None], 3, axis=2)
    out = _run(stage, [frames[0], frames[1], Frame(frames[2].stamp_ns, other)])
    assert isinstance(out[1], Aligned) and isinstance(out[2], NewReference), out
    assert (
        out[2].reason
        and out[2].reason not in ("first frame", "set complete")
        and not out[2].predicted
    )
    assert stage.stats.registration_failures == 1
    assert any(
        level == "warn" and "registration to reference failed" in m for level, m in problems
    ), problems
    # the next frame of the flight does not match the road crop either: it fails and starts another
    nxt = stage.add(frames[3])
    assert isinstance(nxt, NewReference) and stage.stats.registration_failures == 2


def test_predicted_loss_of_overlap_starts_a_new_reference_without_a_search():
    offsets = [(0.0, -280.0 * k) for k in range(4)]
    stage = RegistrationStage(max_frames_per_reference=20, **FAST)
    out = _run(
        stage, [Frame(stamp(k), img) for k, img in enumerate(scene_frames(offsets, w=640, h=480))]
    )
    assert [type(r).__name__ for r in out] == ["NewReference", "Aligned", "NewReference", "Aligned"]
    assert out[2].predicted and "predicted overlap" in out[2].reason
    assert stage.stats.references_predicted == 1 and stage.stats.registration_failures == 0
    assert stage.stats.tracked == 1  # frame 3, from the motion measured on frame 1


def test_tracking_fallback_is_counted():
    step = np.array([1.41, -2.27])
    ticks = list(range(5)) + [6]
    offsets = [k * step for k in ticks[:-1]] + [
        6 * step + [25.0, 31.0]
    ]  # the last jumps off the prediction
    stage = RegistrationStage(max_frames_per_reference=20, **FAST)
    out = _run(
        stage, [Frame(stamp(k), img) for k, img in zip(ticks, scene_frames(offsets, w=640, h=480))]
    )
    assert all(isinstance(r, Aligned) for r in out[1:]), out
    # frame 1: no motion yet (full search); 2-4 tracked; the jump: tracking fails, full search
    assert stage.stats.tracked == 3 and stage.stats.fallbacks == 1, stage.stats
    assert stage.stats.last_tracking_fallback
    assert abs(out[-1].homography[0, 2] + offsets[-1][1]) < 0.05


def _telemetry(stage, t0_s, seconds, speed=0.1, height=56.0):
    for i in range(int(seconds * 10) + 1):
        stage.add_telemetry(sample_from_enu(t0_s + 0.1 * i, (0.0, speed, 0.0), height))


def test_frame_selection_skips_by_reason_and_keeps_every_frame_without_telemetry():
    img = load_crop("crop_trees")[:96, :128]
    stage = RegistrationStage(
        pixel_pitch_um=3.08,
        telemetry_timeout_s=0.5,
        min_inliers=4,
        max_rms_px=50.0,
        min_overlap=0.0,
    )
    problems = []
    stage.on_problem = lambda level, msg: problems.append(msg)
    dt = 33_333_333
    out = [
        stage.add(Frame(k * dt, img)) for k in range(10)
    ]  # no telemetry: every frame kept, said so
    assert not any(isinstance(r, Skipped) for r in out)
    assert any("keeping every frame" in m for m in problems)
    _telemetry(
        stage, 10 * dt / 1e9, 3.0
    )  # north at 0.1 m/s, 56 m: 2.5 px/s, a 1/2 px step every 6 frames
    out = [stage.add(Frame(k * dt, img)) for k in range(10, 70)]
    skipped = [r for r in out if isinstance(r, Skipped)]
    assert 48 <= len(skipped) <= 52 and all(r.reason == "selection" and r.detail for r in skipped)
    assert stage.stats.skipped_by_reason == {"selection": len(skipped)}
    assert stage.stats.kept == 10 + 60 - len(skipped)
    # telemetry stale: every frame kept again
    out = [stage.add(Frame(k * dt, img)) for k in range(200, 210)]
    assert not any(isinstance(r, Skipped) for r in out)


def test_parameters_are_checked_and_selection_follows_a_change():
    stage = RegistrationStage()
    assert stage.selector.p == 2.0
    for bad in (dict(p=40.0), dict(selection="sometimes"), dict(n_points="many")):
        try:
            stage.configure(**bad)
        except ValueError as exc:
            assert next(iter(bad)) in str(exc)
        else:
            raise AssertionError(f"{bad} accepted")
    assert stage.param("p") == 2.0
    stage.configure(p=3.0)
    assert stage.selector.p == 3.0 and math.isclose(stage.selector.target_px, 1 / 3)


def test_time_jumping_back_resets_the_reference(flight):
    frames, _ = flight
    stage = RegistrationStage(**FAST)
    _run(stage, frames[:3])
    looped = stage.add(frames[0])  # the bag starts again
    assert isinstance(looped, NewReference) and looped.reason == "first frame"
    assert stage.stats.resets == 1 and "time jumped back" in stage.stats.last_warning
    assert isinstance(stage.add(frames[1]), Aligned)


def _sample_telemetry(sample_bags):
    from subpix_ros.process.inputs import open_flight

    return open_flight(sample_bags / "subpixel").telemetry_samples()


@pytest.mark.parametrize(
    "params, agrees",
    [
        (dict(pixel_pitch_um=3.08), True),  # the sample camera: Seneca's pixels, 2x downscaled
        (dict(pixel_pitch_um=1.54), False),  # the node default: the stream's downscale missed
        (dict(pixel_pitch_um=3.08, camera_yaw_offset_deg=30.0), False),  # camera mounted off
    ],
)
def test_telemetry_that_does_not_fit_the_frames_is_a_warning(flight, sample_bags, params, agrees):
    """METHODS eq. 1 against the aligned frames' own motion, live, on the sample flight."""
    frames, _ = flight
    stage = RegistrationStage(**FAST, **params)
    for sample in _sample_telemetry(sample_bags):
        stage.add_telemetry(sample)
    problems = []
    stage.on_problem = lambda level, msg: problems.append(msg)
    _run(stage, frames)
    st = stage.stats
    assert st.telemetry_pairs >= 15 and st.telemetry_agrees is agrees, st.telemetry_check
    warned = [m for m in problems if m.startswith("telemetry disagrees")]
    if agrees:
        assert abs(st.telemetry_scale - 1.0) < 0.01 and abs(st.telemetry_rotation_deg) < 0.5
        assert not warned
    else:
        assert len(warned) == 1, problems  # once per 10 s of stamps: the flight is 2.4 s
        if "camera_yaw_offset_deg" in params:
            assert abs(st.telemetry_rotation_deg + 30.0) < 1.0, st.telemetry_check
            yaw = float(re.search(r"yaw offset (-?[\d.]+) deg", warned[0]).group(1))
            assert abs(yaw) < 1.0, warned[0]  # 30 + the rotation: the true mount, 0
        else:
            assert abs(st.telemetry_scale - 0.5) < 0.01, st.telemetry_check
            f_px = float(re.search(r"they imply f/a (\d+) px", warned[0]).group(1))
            assert abs(f_px - 4300 / 3.08) < 15, warned[0]  # the camera's f/a
    stage.configure(pixel_pitch_um=2.0)  # other parameters: the check starts again
    assert st.telemetry_pairs == 0 and st.telemetry_agrees is None


def test_a_frozen_camera_is_warned_as_such_not_as_a_camera_parameter(flight, sample_bags):
    """The sample flight's telemetry, every frame the first image (a camera that froze)."""
    frames, _ = flight
    stage = RegistrationStage(**FAST, pixel_pitch_um=3.08)
    for sample in _sample_telemetry(sample_bags):
        stage.add_telemetry(sample)
    problems = []
    stage.on_problem = lambda level, msg: problems.append(msg)
    _run(stage, [Frame(f.stamp_ns, frames[0].image) for f in frames])
    st = stage.stats
    assert st.telemetry_agrees is False, st.telemetry_check
    warned = [m for m in problems if m.startswith("telemetry disagrees")]
    assert len(warned) == 1, problems
    assert warned[0].startswith("telemetry disagrees: the frames did not move"), warned[0]
    assert "a frozen camera or repeated frames?" in warned[0]
    assert "yaw offset" not in warned[0] and "f/a" not in warned[0]


def test_a_frame_repeating_the_previous_stamp_is_left_out_and_said(flight):
    """An unstamped camera (every stamp 0) or a duplicated message: outputs are keyed by stamp."""
    frames, _ = flight
    stage = RegistrationStage(**FAST)
    problems = []
    stage.on_problem = lambda level, msg: problems.append(msg)
    first = stage.add(frames[0])
    again = stage.add(Frame(frames[0].stamp_ns, frames[1].image))
    assert isinstance(first, NewReference)
    assert isinstance(again, Skipped) and again.reason == "duplicate_stamp"
    assert "repeats the previous frame's" in again.detail
    assert stage.stats.skipped_by_reason == {"duplicate_stamp": 1}
    assert problems and "does the camera driver stamp its images?" in problems[-1]
    # the next stamp goes on as usual, against the same reference
    assert isinstance(stage.add(frames[1]), Aligned)
    assert stage.reference.stamp_ns == frames[0].stamp_ns and stage.stats.resets == 0


def test_telemetry_timeout_changed_at_run_time_applies_to_the_telemetry_kept():
    # the buffer judged staleness by the timeout it was made with: a run-time change was
    # accepted and logged but telemetry 2 s old stayed stale (and 0.5 s old stayed fresh)
    stage = RegistrationStage(telemetry_timeout_s=1.0)
    stage.add_telemetry(sample_from_enu(10.0, (0.0, 1.0, 0.0), 50.0))
    assert stage.telemetry.at(12.0)[0] is None  # 2 s old: stale at 1 s
    stage.configure(telemetry_timeout_s=5.0)
    assert stage.telemetry.at(12.0)[0] is not None
    stage.configure(telemetry_timeout_s=0.2)
    sample, why = stage.telemetry.at(10.5)
    assert sample is None and "> 0.2 s" in why
