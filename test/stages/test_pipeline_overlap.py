"""Pipeline(overlap=True): the reconstruction on a worker thread.

It gives the same events, in the same order, one set later, in the caller's thread; failures on
the worker are reported.
"""

import threading

import numpy as np
import pytest

from subpix_ros.stages import Pipeline

PARAMS = {
    "registration_node": {"pixel_pitch_um": 3.08, "max_frames_per_reference": 7},
    "reconstruction_node": {"n_frames": 8, "method": "map"},
}


def _run(frames, overlap, params=PARAMS, solve_thread=True):
    events, threads = [], set()
    with Pipeline(params, with_mosaic=False, overlap=overlap, solve_thread=solve_thread) as pipe:
        for kind in ("reference", "shift", "super_resolved", "warning", "error"):
            pipe.on(
                kind,
                lambda x, kind=kind: (
                    events.append((kind, x)),
                    threads.add(threading.current_thread()),
                ),
            )
        returned = []
        for k, f in enumerate(frames):
            if k != 20:
                returned += pipe.add(f)
        returned += pipe.flush()
    return events, returned, threads, pipe


def test_overlap_gives_the_same_images_and_events_as_the_serial_pipeline(flight):
    frames, _ = flight
    serial, ret_s, _, _ = _run(frames, False)
    overlap, ret_o, threads, pipe = _run(frames, True)
    assert threads == {threading.main_thread()}, "every callback in the caller's thread"
    srs = [x for k, x in serial if k == "super_resolved"]
    sro = [x for k, x in overlap if k == "super_resolved"]
    assert len(srs) == len(sro) == 3 and [sr.n_frames for sr in sro] == [8, 8, 7]
    for a, b in zip(srs, sro):
        assert a.stamp_ns == b.stamp_ns and np.array_equal(a.image, b.image)
    assert [sr.stamp_ns for sr in ret_o] == [sr.stamp_ns for sr in sro]
    # the other events are the same, in the same order; only the images come later
    assert [k for k, _ in serial if k != "super_resolved"] == [
        k for k, _ in overlap if k != "super_resolved"
    ]
    # serial: the first image comes as its set completes (before the second reference's set is
    # complete); overlap: when the second set is handed to the worker (after the second reference)
    kinds_s, kinds_o = [k for k, _ in serial], [k for k, _ in overlap]
    assert kinds_s[: kinds_s.index("super_resolved")].count("reference") == 1
    assert kinds_o[: kinds_o.index("super_resolved")].count("reference") == 2
    assert pipe.stats()["reconstruction_node"].kept == 3


def test_a_failure_on_the_worker_is_an_error_in_the_callers_thread_and_the_stream_goes_on(
    flight, monkeypatch
):
    frames, _ = flight
    params = {
        "registration_node": {"max_frames_per_reference": 3},
        "reconstruction_node": {"n_frames": 4, "method": "bicubic"},
    }
    pipe = Pipeline(params, with_mosaic=False, overlap=True)
    real = pipe.reconstruction.reconstruct
    calls = []

    def flaky(fs):
        calls.append(fs.stamp_ns if hasattr(fs, "stamp_ns") else fs.reference.stamp_ns)
        if len(calls) == 1:
            pipe.reconstruction.warn("about to fail")
            raise RuntimeError("solver exploded")
        return real(fs)

    monkeypatch.setattr(pipe.reconstruction, "reconstruct", flaky)
    errors, warnings, images = [], [], []
    pipe.on("error", lambda e: errors.append((e, threading.current_thread())))
    pipe.on("warning", warnings.append)
    pipe.on("super_resolved", images.append)
    for f in frames[:12]:
        pipe.add(f)
    pipe.flush()
    pipe.close()
    assert [e[0] for e in errors] == [("reconstruction_node", "RuntimeError: solver exploded")]
    assert errors[0][1] is threading.main_thread()
    assert ("reconstruction_node", "about to fail") in warnings
    assert len(calls) == 3 and len(images) == 2
    assert pipe.stats()["reconstruction_node"].errors == 1


def test_close_is_idempotent_and_a_serial_pipeline_has_no_worker():
    pipe = Pipeline(with_mosaic=False)
    pipe.close()
    pipe = Pipeline(with_mosaic=False, overlap=True)
    pipe.close()
    pipe.close()
    with pytest.raises(Exception):
        pipe._pool.submit(print)  # noqa: SLF001 - closed: no worker left


def test_overlap_without_a_thread_emits_the_same_events_at_the_same_points(flight):
    frames, _ = flight
    threaded, _, _, _ = _run(frames, True)
    inline, _, threads, _ = _run(frames, True, solve_thread=False)
    assert threads == {threading.main_thread()}
    assert [k for k, _ in threaded] == [k for k, _ in inline]
    a = [x for k, x in threaded if k == "super_resolved"]
    b = [x for k, x in inline if k == "super_resolved"]
    assert len(a) == len(b) == 3
    assert all(np.array_equal(x.image, y.image) for x, y in zip(a, b))
