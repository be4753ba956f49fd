"""Node parameters at start-up and at run time: in effect or refused, said in the log and /diagnostics."""

import threading

import pytest
from rclpy.parameter import Parameter

from subpix_ros.nodes.diagnostics import ERROR, OK

#: The trial's start-up line: 7 of these are rejected (exposure_s:=0 is taken as 0.0).
TRIAL_OVERRIDES = {
    "n_frames": 4,
    "min_frames": 10,
    "factor": 7,
    "method": "foo",
    "blur_sigma": "banana",
    "queue_size": 2.5,
    "max_memory_mb": -1.0,
    "time_tolerance_s": "abc",
    "exposure_s": 0,
}


def _node(cls, overrides=(), **kw):
    return cls(
        subscribe_inputs=False,
        parameter_overrides=[Parameter(k, value=v) for k, v in dict(overrides).items()],
        **kw,
    )


def _close(node):
    node.close()
    node.destroy_node()


def _set(node, name, value):
    return node.set_parameters([Parameter(name, value=value)])[0]


def _node_classes():
    from subpix_ros.nodes.mosaic_node import MosaicNode
    from subpix_ros.nodes.reconstruction_node import ReconstructionNode
    from subpix_ros.nodes.registration_node import RegistrationNode
    from subpix_ros.nodes.shift_node import ShiftNode

    return [RegistrationNode, ShiftNode, ReconstructionNode, MosaicNode]


def test_read_only_parameters_are_refused_at_run_time_with_a_reason(ctx):
    # QoS and topic choices are made when the subscriptions are: a run-time change was accepted
    # (camera_reliable) and did nothing. Every read-only parameter is refused, with why.
    from subpix_ros.nodes.monitor_node import MonitorNode

    read_only = {}
    for cls in _node_classes():
        node = _node(cls)
        try:
            read_only[cls.__name__] = [p.name for p in cls.PARAMS if p.read_only]
            for p in cls.PARAMS:
                if not p.read_only:
                    continue
                other = (not p.default) if isinstance(p.default, bool) else p.default
                r = _set(node, p.name, other)
                assert not r.successful and f"{p.name} is read-only" in r.reason, (cls, p.name)
                assert "start-up" in r.reason and node.param(p.name) == p.default
        finally:
            _close(node)
    assert "camera_reliable" in read_only["RegistrationNode"]
    assert "camera_reliable" in read_only["MosaicNode"]
    assert "latch_output" in read_only["ReconstructionNode"]
    node = MonitorNode(subscribe_inputs=False, parameter_overrides=[Parameter("port", value=0)])
    try:
        for name in ("camera_reliable", "mosaic_compressed", "shift_std_wait_s", "host"):
            assert next(p for p in MonitorNode.PARAMS if p.name == name).read_only
        r = _set(node, "camera_reliable", True)
        assert not r.successful and "camera_reliable is read-only" in r.reason
    finally:
        _close(node)


@pytest.mark.parametrize("index", range(4))
def test_queue_size_changed_at_run_time_bounds_the_worker_queue(ctx, index):
    # the trial: queue_size 100 accepted, queue_depth never above 2, drops kept rising
    cls = _node_classes()[index]
    node = _node(cls)
    gate = threading.Event()
    try:
        assert _set(node, "queue_size", 20).successful
        assert node.worker.maxsize == 20
        handler = node.worker._handler
        node.worker._handler = lambda item: gate.wait(10)  # the worker busy: items wait
        for i in range(21):  # one taken by the busy worker, 20 queued
            node.worker.put(i)
        assert node.worker.dropped <= 1 and node.worker.depth >= 19
        assert _set(node, "queue_size", 3).successful  # smaller: the oldest beyond go
        assert node.worker.maxsize == 3 and node.worker.depth == 3
        node.worker._handler = handler
    finally:
        gate.set()
        _close(node)


def test_other_construction_time_settings_follow_a_run_time_change(ctx):
    from subpix_ros.nodes.mosaic_node import MosaicNode
    from subpix_ros.nodes.registration_node import RegistrationNode

    node = _node(MosaicNode)
    try:
        assert _set(node, "publish_rate_hz", 4.0).successful
        assert node.timer.timer_period_ns == 250_000_000
    finally:
        _close(node)
    node = _node(RegistrationNode)
    try:
        assert _set(node, "telemetry_timeout_s", 5.0).successful
        assert node.selector.max_age_s == 5.0 and node.telemetry.stale_after_s == 5.0
    finally:
        _close(node)


def test_start_up_rejections_hold_diagnostics_at_error_until_set(ctx):
    from subpix_ros.nodes.reconstruction_node import ReconstructionNode

    node = _node(ReconstructionNode, TRIAL_OVERRIDES)
    try:
        node.diag.hold_s = 0.0  # not a 5 s hold: held until the parameters are set
        st = node.diag.snapshot()
        values = {kv.key: kv.value for kv in st.values}
        assert st.level == bytes([ERROR]) and values["errors_total"] == "7"
        assert st.message.startswith("7 parameter(s) rejected at start-up, defaults used: ")
        for said in (
            "factor 7 (range 2..4)",
            "method 'foo' (one of map, windowed, pinv, bicubic)",
            "queue_size 2.5 (expected int)",
            "time_tolerance_s 'abc' (expected float)",
            "max_memory_mb -1.0 (range 0.0..1000000.0)",
            "blur_sigma 'banana' (",
            "min_frames 10 (10 is above n_frames 4",
        ):
            assert said in st.message, (said, st.message)
        node.diag.ok()  # a good result does not end it
        assert node.diag.level == ERROR
        fixes = {"factor": 3, "method": "map", "blur_sigma": "auto", "queue_size": 2}
        fixes.update(max_memory_mb=0.0, time_tolerance_s=0.001)
        for name, value in fixes.items():
            assert _set(node, name, value).successful
        st = node.diag.snapshot()
        assert st.level == bytes([ERROR]) and st.message.startswith("1 parameter(s) rejected")
        assert _set(node, "min_frames", 3).successful
        node.diag.ok()
        assert node.diag.snapshot().level == bytes([OK])
    finally:
        _close(node)


def test_an_integer_is_taken_for_a_double_not_the_other_way_round(ctx):
    from subpix_ros.nodes.reconstruction_node import ReconstructionNode

    node = _node(ReconstructionNode, {"exposure_s": 0, "blur_sigma": 1, "flush_after_s": 3})
    try:
        assert node.param("exposure_s") == 0.0 and isinstance(node.param("exposure_s"), float)
        assert node.param("flush_after_s") == 3.0 and node.stage.param("flush_after_s") == 3.0
        assert node.param("blur_sigma") == "1" and node.stage.blur.setting == 1.0
        assert not node.rejected_at_start
        r = _set(node, "exposure_s", 0)
        assert r.successful and isinstance(node.param("exposure_s"), float)
        assert _set(node, "max_memory_mb", 512).successful
        assert node.stage.param("max_memory_mb") == 512.0
        assert _set(node, "blur_sigma", 0.5).successful and node.stage.blur.setting == 0.5
        r = _set(node, "queue_size", 2.5)
        assert not r.successful and "expected int" in r.reason and node.param("queue_size") == 2
    finally:
        _close(node)
    node = _node(ReconstructionNode, {"queue_size": 2.5})
    try:
        assert node.param("queue_size") == 2 and "queue_size" in node.rejected_at_start
    finally:
        _close(node)


def test_min_frames_above_n_frames_is_refused_naming_both(ctx):
    from subpix_ros.nodes.reconstruction_node import ReconstructionNode

    node = _node(ReconstructionNode, {"n_frames": 4, "min_frames": 10})
    try:
        assert node.param("n_frames") == 4 and node.param("min_frames") == 4  # the default
        assert "min_frames 10 (10 is above n_frames 4" in node.rejected_at_start["min_frames"]
        assert _set(node, "min_frames", 3).successful and _set(node, "n_frames", 3).successful
        r = _set(node, "min_frames", 64)
        assert not r.successful and "min_frames: 64 is above n_frames 3" in r.reason
        r = _set(node, "n_frames", 2)
        assert not r.successful and "n_frames: 2 is below min_frames 3" in r.reason
        assert (node.param("n_frames"), node.param("min_frames")) == (3, 3)
        assert (node.stage.param("n_frames"), node.stage.param("min_frames")) == (3, 3)
    finally:
        _close(node)
    # only n_frames given, below the default min_frames: the default follows it, nothing refused
    node = _node(ReconstructionNode, {"n_frames": 3})
    try:
        assert (node.param("n_frames"), node.param("min_frames")) == (3, 3)
        assert not node.rejected_at_start
    finally:
        _close(node)


def test_a_rejected_run_time_change_is_logged(ctx, capfd):
    from subpix_ros.nodes.reconstruction_node import ReconstructionNode

    node = _node(ReconstructionNode)
    try:
        capfd.readouterr()
        assert not _set(node, "factor", 5).successful  # the descriptor's range: rclpy's check
        assert not _set(node, "method", "foo").successful  # the node's own check
        assert not _set(node, "latch_output", False).successful  # read-only
        r = node.set_parameters_atomically([Parameter("factor", value=9)])  # the service's way
        assert not r.successful and "factor: 9 is above the maximum 4" == r.reason
        err = capfd.readouterr().err
        lines = [line for line in err.splitlines() if "rejected" in line]
        assert len(lines) == 4, err
        assert "parameter factor = 5 rejected: factor: 5 is above the maximum 4" in lines[0]
        assert "parameter method = 'foo' rejected: method: 'foo' is not one of" in lines[1]
        assert "parameter latch_output = False rejected: latch_output is read-only" in lines[2]
        assert "parameter factor = 9 rejected" in lines[3]
        assert all("[WARN]" in line for line in lines)
    finally:
        _close(node)
