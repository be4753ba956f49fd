"""Pipeline without ROS on the rendered sample flight: the chain, callbacks, end-of-stream flush."""

import numpy as np

from subpix_ros.core.evaluate import wrapped_error
from subpix_ros.stages import Pipeline, RegistrationStats

PARAMS = {
    "registration_node": {"pixel_pitch_um": 3.08, "max_frames_per_reference": 7, "queue_size": 30},
    "reconstruction_node": {"n_frames": 8, "method": "map"},
}


def test_the_flight_with_a_lost_frame_still_gives_its_last_image(flight):
    """Issue 19 item 3 on the stages: the end-of-stream flush reconstructs a set cut short.

    24 frames in sets of 8, frame 20 lost: the last set (7 frames) never completes; the flush
    reconstructs it. Shifts match the bag's truth.
    """
    frames, truth = flight
    pipe = Pipeline(PARAMS, with_mosaic=True)
    got = {
        k: []
        for k in ("aligned", "reference", "skipped", "shift", "super_resolved", "mosaic", "error")
    }
    for kind, store in got.items():
        pipe.on(kind, store.append)
    for k, f in enumerate(frames):
        if k != 20:
            pipe.add(f)
    assert [sr.n_frames for sr in got["super_resolved"]] == [8, 8]
    assert [r.frame.stamp_ns for r in got["reference"]] == [frames[k].stamp_ns for k in (0, 8, 16)]
    flushed = pipe.flush()
    assert [sr.n_frames for sr in flushed] == [7] and not flushed[0].complete
    assert flushed[0].stamp_ns == frames[16].stamp_ns and got["super_resolved"][-1] is flushed[0]
    assert flushed[0].image.shape[:2] == (
        2 * frames[0].image.shape[0],
        2 * frames[0].image.shape[1],
    )
    err = [
        wrapped_error(
            np.array([s.u, s.v]), np.subtract(truth[s.stamp_ns], truth[s.reference_stamp_ns])
        )
        for s, _ in got["shift"]
    ]
    assert len(err) >= 18 and float(np.sqrt(np.mean(np.square(err)))) <= 0.02
    stats = pipe.stats()
    assert isinstance(stats["registration_node"], RegistrationStats)
    assert (
        stats["registration_node"].frames_in == 23
        and stats["reconstruction_node"].sets_flushed == 1
    )
    assert stats["mosaic_node"].kept == len(got["mosaic"]) > 0 and pipe.mosaic.canvas() is not None
    assert not got["error"]


def test_looping_the_flight_resets_every_stage(flight):
    frames, _ = flight
    pipe = Pipeline(
        {
            "reconstruction_node": {"n_frames": 4, "method": "bicubic"},
            "registration_node": {"max_frames_per_reference": 3},
        },
        with_mosaic=False,
    )
    warnings = []
    pipe.on("warning", warnings.append)
    first = [sr for f in frames[:6] for sr in pipe.add(f)]
    again = [sr for f in frames[:4] for sr in pipe.add(f)]
    assert [sr.stamp_ns for sr in first] == [frames[0].stamp_ns]
    assert [sr.stamp_ns for sr in again] == [
        frames[0].stamp_ns
    ]  # a fresh set, not mixed with 4 and 5
    assert pipe.registration.reference.stamp_ns == frames[0].stamp_ns
    assert pipe.flush() == []  # frames 4, 5 were forgotten with the reset


def test_an_exception_in_a_stage_is_reported_and_the_stream_goes_on(flight):
    frames, _ = flight
    pipe = Pipeline(
        {"reconstruction_node": {"n_frames": 3, "min_frames": 3, "method": "bicubic"}},
        with_mosaic=False,
    )
    errors = []
    pipe.on("error", errors.append)
    pipe.add(frames[0])
    bad = type(frames[1])(frames[1].stamp_ns, np.zeros((0, 0), np.uint8))
    pipe.add(bad)
    assert errors and errors[0][0] == "registration_node"
    out = [sr for f in frames[2:4] for sr in pipe.add(f)]
    assert len(out) == 1 and pipe.stats()["registration_node"].errors == 1
