"""registration_node in this process: video-rate tracking from the constant-velocity prediction, and its fallback."""

import time

import numpy as np
from conftest import scene_frames
from rclpy.parameter import Parameter

from subpix_ros.nodes import payloads as pl


def _run(node, frames, ticks):
    got = []
    node.listen("aligned", got.append)
    for k, img in zip(ticks, frames):
        node.handle_frame(
            pl.Frame(stamp_ns=1_000_000_000 + k * 100_000_000, image=img, frame_id="camera")
        )
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not node.worker.idle():
            time.sleep(0.01)
    return got


def test_tracking_follows_constant_velocity_and_falls_back_on_a_jump(ctx):
    from subpix_ros.nodes.registration_node import RegistrationNode

    step = np.array([1.41, -2.27])  # px per 0.1 s frame interval
    # frames 0-6 at 10 Hz, then three frames lost (the next is 0.4 s later, 10.7 px further: the time-scaled
    # prediction must still hit it), then a frame that jumps 40 px off the prediction
    ticks = list(range(7)) + [10, 11]
    offsets = [k * step for k in ticks[:-1]] + [11 * step + [25.0, 31.0]]
    node = RegistrationNode(
        subscribe_inputs=False,
        parameter_overrides=[
            Parameter("selection", value="all"),
            Parameter("distortion", value=False),
            Parameter("n_points", value=300),
            Parameter("max_frames_per_reference", value=20),
        ],
    )
    try:
        got = _run(node, scene_frames(offsets), ticks)
        assert len(got) == 8  # frame 0 is the reference, every other frame aligned
        # frame 1: no motion known yet (full search, no prior); frames 2-6 and the one after the gap follow the
        # prediction; the last jumps 40 px off it: tracking fails and the full search takes over
        assert node.tracked == 6 and node.track_fallbacks == 1, (node.tracked, node.track_fallbacks)
        for a, off in zip(got, offsets[1:]):
            # prior: the sub-pixel remainder (rows, cols) left in the aligned frame after the integer crop
            assert np.all(np.abs(a.prior) <= 0.5 + 1e-9)
            n_y = round(off[0] - a.prior[0])
            n_x = round(off[1] - a.prior[1])
            assert (
                abs(off[0] - n_y - a.prior[0]) < 0.05 and abs(off[1] - n_x - a.prior[1]) < 0.05
            ), (off, a.prior)
            # the homography maps moving -> reference: a moving pixel goes back by the content offset
            assert (
                abs(a.homography[0, 2] + off[1]) < 0.05 and abs(a.homography[1, 2] + off[0]) < 0.05
            )
        # diagnostics carry the residual split along / across the baseline (a flat scene: both tiny)
        kv = {x.key: x.value for x in node.diag.snapshot().values}
        assert float(kv["rms_along_px"]) < 0.1 and float(kv["rms_cross_px"]) < 0.1, kv
    finally:
        node.close()
        node.destroy_node()


def test_predicted_loss_of_overlap_starts_a_new_reference_without_a_failed_search(ctx):
    """Start a new reference at once when the next frame would overlap too little.

    A strip of widely spaced frames (280 px per frame on 640 px): frame 1 overlaps the reference by
    56 %, frame 2 is predicted to keep 12.5 % (< min_overlap / 2): it becomes the reference at once,
    with no failed registration; frame 3 then registers to it, tracked from the carried-on motion.
    """
    from subpix_ros.nodes.registration_node import RegistrationNode

    offsets = [(0.0, -280.0 * k) for k in range(4)]
    node = RegistrationNode(
        subscribe_inputs=False,
        parameter_overrides=[
            Parameter("selection", value="all"),
            Parameter("distortion", value=False),
            Parameter("n_points", value=300),
            Parameter("max_frames_per_reference", value=20),
        ],
    )
    try:
        got = _run(node, scene_frames(offsets, w=640, h=480), [0, 1, 2, 3])
        assert node.references_predicted == 1 and node.failures == 0, (
            node.references_predicted,
            node.failures,
        )
        assert len(got) == 2  # frames 1 and 3; frames 0 and 2 are references
        assert got[1].reference.stamp_ns == 1_000_000_000 + 2 * 100_000_000
        for a in got:  # 280 px of content motion to the left, in each frame's own pair
            assert abs(a.homography[0, 2] - 280.0) < 0.05 and abs(a.homography[1, 2]) < 0.05, (
                a.homography
            )
        assert node.tracked == 1  # frame 3, from the motion measured on frame 1
    finally:
        node.close()
        node.destroy_node()


def test_telemetry_that_does_not_fit_the_frames_holds_the_status_at_warn(ctx, flight, sample_bags):
    """The sample flight (2x downscaled Seneca frames) with the node's default 1.54 um pixels."""
    from subpix_ros.nodes.diagnostics import OK, WARN
    from subpix_ros.nodes.registration_node import RegistrationNode
    from subpix_ros.process.inputs import open_flight

    frames, _ = flight
    samples = open_flight(sample_bags / "subpixel").telemetry_samples()
    for pitch, level in ((1.54, WARN), (3.08, OK)):
        node = RegistrationNode(
            subscribe_inputs=False,
            parameter_overrides=[
                Parameter("selection", value="all"),
                Parameter("distortion", value=False),
                Parameter("pixel_pitch_um", value=pitch),
            ],
        )
        try:
            for sample in samples:
                node.handle_telemetry(sample)
            got = []
            node.listen("aligned", got.append)
            for f in frames:  # at the flight's own stamps, where its telemetry is
                node.handle_frame(pl.Frame(stamp_ns=f.stamp_ns, image=f.image, frame_id="camera"))
                deadline = time.monotonic() + 30
                while time.monotonic() < deadline and not node.worker.idle():
                    time.sleep(0.01)
            assert len(got) >= 18
            status = node.diag.snapshot()
            kv = {x.key: x.value for x in status.values}
            assert status.level == level.to_bytes(1, "little"), (pitch, status.message)
            if level == WARN:
                assert status.message.startswith("telemetry disagrees: the frames moved 0.50")
                assert abs(float(kv["telemetry_scale"]) - 0.5) < 0.01, kv
            else:
                assert kv["telemetry_check"].startswith("agrees: the frames moved"), kv
                assert abs(float(kv["telemetry_scale"]) - 1.0) < 0.01, kv
        finally:
            node.close()
            node.destroy_node()


def test_a_repeated_stamp_is_left_out_by_the_node_and_the_next_frame_aligned(ctx, flight):
    """The node checks the time before the stage's add: only a true repeat is left out."""
    from subpix_ros.nodes.diagnostics import WARN
    from subpix_ros.nodes.registration_node import RegistrationNode

    frames, _ = flight
    node = RegistrationNode(
        subscribe_inputs=False,
        parameter_overrides=[
            Parameter("selection", value="all"),
            Parameter("distortion", value=False),
        ],
    )
    try:
        got = []
        node.listen("aligned", got.append)
        stamps = [frames[0].stamp_ns, frames[0].stamp_ns, frames[1].stamp_ns, frames[2].stamp_ns]
        for stamp, f in zip(stamps, frames):
            node.handle_frame(pl.Frame(stamp_ns=stamp, image=f.image, frame_id="camera"))
            deadline = time.monotonic() + 30
            while time.monotonic() < deadline and not node.worker.idle():
                time.sleep(0.01)
        assert [a.stamp_ns for a in got] == stamps[2:]
        assert node.stage.stats.skipped_by_reason == {"duplicate_stamp": 1}
        status = node.diag.snapshot()
        kv = {x.key: x.value for x in status.values}
        assert kv["frames_skipped"] == "1"
        assert "stamp" in status.message and "repeats the previous frame's" in status.message
        assert status.level == WARN.to_bytes(1, "little")  # held: the frames after are ok
    finally:
        node.close()
        node.destroy_node()
