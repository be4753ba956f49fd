"""The shared node glue: parameter checks, the drop-oldest worker, rates."""

import threading
import time

import pytest

from subpix_ros.nodes.params import Param
from subpix_ros.nodes.worker import DropOldestWorker, RateMeter


def test_param_check_type_and_range():
    p = Param("p", 2.0, "x", 2.0, 16.0)
    assert p.check(3.0) is None and p.check(3) is None  # an int is a fine float
    assert "below the minimum" in p.check(1.0)
    assert "above the maximum" in p.check(17.0)
    assert "expected float" in p.check("3")
    q = Param("mode", "a", "x", choices=("a", "b"))
    assert q.check("b") is None and "not one of" in q.check("c")
    b = Param("flag", True, "x")
    assert "expected bool" in b.check(1)


def test_worker_drops_oldest_and_counts():
    gate = threading.Event()
    seen = []

    def handler(x):
        gate.wait(5)
        seen.append(x)

    w = DropOldestWorker(handler, maxsize=2)
    w.put(0)
    time.sleep(0.1)  # the worker takes 0 and blocks on the gate
    for i in range(1, 6):
        w.put(i)
    assert w.dropped == 3 and w.depth == 2
    gate.set()
    deadline = time.time() + 5
    while not w.idle() and time.time() < deadline:
        time.sleep(0.01)
    assert seen == [0, 4, 5]  # the newest survive, the oldest were dropped
    w.stop()


def test_worker_survives_exceptions():
    errors = []
    out = []

    def handler(x):
        if x == "bad":
            raise ValueError("bad input")
        out.append(x)

    w = DropOldestWorker(handler, maxsize=10, on_error=errors.append)
    for x in ["a", "bad", "b"]:
        w.put(x)
    deadline = time.time() + 5
    while (len(out) < 2) and time.time() < deadline:
        time.sleep(0.01)
    assert out == ["a", "b"] and w.errors == 1 and isinstance(errors[0], ValueError)
    w.stop()


def test_worker_stopped_with_a_drain_handles_what_is_queued_first():
    """A node's close(): the frames still queued are handled, not dropped unsaid.

    (Was: ``stop()`` ended the thread with the queue as it was, so a pipeline stopped as the
    camera stopped lost its last frames and the reconstruction's open set fell below
    ``min_frames``.)
    """
    seen = []
    w = DropOldestWorker(lambda x: (time.sleep(0.05), seen.append(x)), maxsize=10)
    for i in range(5):
        w.put(i)
    assert w.stop(drain_s=10.0) == 0
    assert seen == [0, 1, 2, 3, 4] and w.dropped == 0


def test_worker_stopped_says_how_many_it_left():
    gate = threading.Event()
    w = DropOldestWorker(lambda x: gate.wait(5), maxsize=10)
    for i in range(4):
        w.put(i)
    time.sleep(0.1)  # the worker holds 0 at the gate
    t = time.monotonic()
    left = w.stop(timeout=0.1, drain_s=0.3)
    assert left == 3 and 0.3 <= time.monotonic() - t < 2.0
    gate.set()
    assert w.stop() == 0  # nothing queued any more


def test_rate_meter():
    r = RateMeter(window_s=1.0)
    for i in range(10):
        r.tick(100.0 + i * 0.05)
    assert r.rate(100.5) == 10.0 and r.rate(102.0) == 0.0 and r.total == 10


def test_publish_if_subscribed_builds_nothing_without_subscribers(rclpy_node):
    from std_msgs.msg import String

    from subpix_ros.nodes.qos import publish_if_subscribed, reliable_qos

    pub = rclpy_node.create_publisher(String, "/lazy_test", reliable_qos(5))
    built = []

    def make():
        built.append(1)
        return String(data="x")

    assert not publish_if_subscribed(pub, make) and not built  # nobody listens: no 6 MB copy made
    got = []
    rclpy_node.create_subscription(String, "/lazy_test", got.append, reliable_qos(5))
    assert publish_if_subscribed(pub, make) and built == [1]


def test_worker_measures_its_cpu_time_per_item():
    def busy(_):
        t = time.thread_time()
        while time.thread_time() - t < 0.02:  # 20 ms of CPU in this thread
            pass

    w = DropOldestWorker(busy, maxsize=10)
    try:
        for i in range(3):
            w.put(i)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and w.processed < 3:
            time.sleep(0.01)
        time.sleep(0.05)  # cpu_s is added just after processed
        assert w.processed == 3
        assert 19.0 <= w.cpu_ms_per_item <= 40.0, w.cpu_ms_per_item
    finally:
        w.stop()


def test_diagnostics_stage_times_report_last_median_and_max(rclpy_node):
    import pytest

    from subpix_ros.nodes.diagnostics import Diagnostics

    d = Diagnostics(rclpy_node)

    def values():
        return {kv.key: kv.value for kv in d.snapshot().values}

    for ms in (5.0, 100.0, 7.0, 6.0):
        d.stage_time("x_ms", ms)
    v = values()
    assert float(v["x_ms"]) == 6.0  # the last one
    assert float(v["x_ms_p50"]) == 7.0  # median of 5, 6, 7, 100 (the upper one of the middle two)
    assert float(v["x_ms_max"]) == 100.0
    for _ in range(Diagnostics.HISTORY):  # the slow one leaves the history
        d.stage_time("x_ms", 1.0)
    v = values()
    assert float(v["x_ms_p50"]) == 1.0 and float(v["x_ms_max"]) == 1.0
    for bad in (float("nan"), float("inf"), -1.0):
        with pytest.raises(ValueError, match="x_ms"):
            d.stage_time("x_ms", bad)
    assert float(values()["x_ms_max"]) == 1.0  # nothing recorded
    d.clear_stage_times()
    v = values()
    assert "x_ms_p50" not in v and "x_ms_max" not in v
    assert float(v["x_ms"]) == 1.0  # the last value stays until the next one
    d.stage_time("x_ms", 3.0)
    assert float(values()["x_ms_p50"]) == 3.0
    rclpy_node.destroy_timer(d.timer)
    rclpy_node.destroy_publisher(d.pub)


def test_stage_times_restart_when_time_jumps_back(rclpy_node):
    from subpix_ros.nodes.base import StageNode

    node = StageNode("stage_time_probe")
    try:

        def keys():
            return {kv.key for kv in node.diag.snapshot().values}

        assert node.check_time(2_000_000_000) is False
        node.diag.stage_time("work_ms", 50.0)
        assert node.check_time(3_000_000_000) is False  # forwards: kept
        assert "work_ms_p50" in keys()
        assert node.check_time(1_000_000_000) is True  # backwards (a looped bag): a new stream
        assert "work_ms_p50" not in keys()
        node.diag.stage_time("work_ms", 7.0)
        assert {kv.key: kv.value for kv in node.diag.snapshot().values}["work_ms_max"] == "7"
    finally:
        node.destroy_node()


def test_a_published_image_keeps_one_copy_of_its_pixels():
    """The reconstruction node's image, once encoded, is viewed in its message (not kept twice)."""
    import weakref
    from types import SimpleNamespace

    import numpy as np

    from subpix_ros.nodes import payloads as pl

    image = np.random.default_rng(1).integers(0, 256, (40, 60, 3), dtype=np.uint8)
    expected = image.copy()
    sr = SimpleNamespace(image=image, result=SimpleNamespace(image=image))
    gone = weakref.ref(image)
    raw = pl.image_cdr(image, 5, "cam")
    assert not pl.adopt_pixels(sr, raw)  # below the allocator's mmap threshold: left as it is
    assert sr.image is image and sr.result.image is image
    del image
    assert pl.adopt_pixels(sr, raw, min_bytes=0)
    assert gone() is None  # the array itself is freed: its pixels live in the message
    assert sr.result.image is sr.image and np.array_equal(sr.image, expected)
    assert np.shares_memory(sr.image, np.frombuffer(raw, np.uint8))
    assert not sr.image.flags.writeable  # nothing can change the published pixels
    other = SimpleNamespace(image=np.zeros((4, 4), np.uint8), result=None)
    with pytest.raises(ValueError, match="not the image's"):
        pl.adopt_pixels(other, raw, min_bytes=0)


def test_a_node_dropping_input_at_its_queue_says_so_in_its_status(rclpy_node):
    """Drops at the worker's queue: WARN "falling behind", not "ok" with a counter only.

    (Was: ``dropped_frames`` grew while the level stayed OK, so an onboard node shedding
    frames because it could not keep up looked healthy in the monitor's table.)
    """
    from subpix_ros.nodes.diagnostics import OK, WARN, Diagnostics

    diag = Diagnostics(rclpy_node, hold_s=0.2)
    gate = threading.Event()
    w = DropOldestWorker(lambda x: gate.wait(5), maxsize=1)
    diag.attach(w, "aligned frame(s)")
    try:
        diag.publish()
        diag.ok()
        assert diag.level == OK
        w.put(0)
        time.sleep(0.1)  # the worker holds 0 at the gate
        for i in range(1, 4):
            w.put(i)
        assert w.dropped == 2
        diag.publish()
        assert diag.level == WARN and "falling behind: aligned frame(s) dropped" in diag.message
        values = {kv.key: kv.value for kv in diag.snapshot().values}
        assert values["dropped_frames"] == "2"
        time.sleep(0.3)
        diag.publish()  # no new drop: the warning ends after hold_s
        diag.ok()
        assert diag.level == OK
    finally:
        gate.set()
        w.stop()
