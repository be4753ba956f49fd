"""A node whose main input is silent says so (issue 19, item 1): real node processes, real DDS.

The node is started as its console entry point does (``python -m subpix_ros.nodes.<node>``), this
test process is the camera (or not) and reads /diagnostics.
"""

import sys
import time

import numpy as np
import pytest
import rclpy
from conftest import logged_popen
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import Image

from subpix_ros.cli._ros import stop_processes
from subpix_ros.io import cdr
from subpix_ros.nodes.qos import reliable_qos

WARN = 1


@pytest.fixture
def ros():
    rclpy.init()
    node = rclpy.create_node("input_watch_test")
    yield node
    node.destroy_node()
    rclpy.shutdown()


def _start(module, *ros_args):
    cmd = [sys.executable, "-m", f"subpix_ros.nodes.{module}", "--ros-args", *ros_args]
    return logged_popen(cmd)


class Status:
    def __init__(self, node, name):
        self.latest = None
        self.sub = node.create_subscription(DiagnosticArray, "/diagnostics", self._on, 50)
        self.name = name

    def _on(self, msg):
        for s in msg.status:
            if s.name == self.name:
                self.latest = (s.level[0], s.message, {kv.key: kv.value for kv in s.values})


def _spin_until(node, cond, timeout, proc):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
        assert proc.poll() is None, proc.stdout.read()
        if cond():
            return True
    return False


def _log(proc):
    stop_processes([proc])
    return proc.stdout.read()


def test_silent_camera_is_reported_with_its_publishers_and_qos(ros):
    """Report a silent input: no publisher, or a publisher that sends nothing.

    No publisher: WARN 'no publisher on /x'; a publisher that sends nothing: WARN naming it
    and its QoS; each logged once while it lasts; frames arriving end it.
    """
    proc = _start(
        "registration_node",
        "-r",
        "image:=/watch/camera",
        "-r",
        "__node:=watched_registration",
        "-p",
        "input_timeout_s:=1.0",
        "-p",
        "use_sim_time:=true",
    )  # and no /clock: diagnostics must still run
    status = Status(ros, "watched_registration")
    try:
        warned = lambda: status.latest is not None and status.latest[0] == WARN  # noqa: E731
        assert _spin_until(ros, warned, 30, proc), f"no WARN; latest status {status.latest}"
        level, message, values = status.latest
        assert message == "no publisher on /watch/camera or /image/compressed", message
        assert float(values["input_silent_s"]) >= 1.0

        cam = rclpy.create_node("silent_camera")
        try:
            pub = cam.create_publisher(Image, "/watch/camera", reliable_qos(5))
            named = lambda: "silent_camera" in status.latest[1]  # noqa: E731
            assert _spin_until(ros, named, 30, proc), status.latest
            level, message, _ = status.latest
            assert level == WARN
            assert message.startswith(
                "nothing received on /watch/camera or /image/compressed for over 1 s "
                "(input_timeout_s) from /watch/camera: 1 publisher(s) "
                "/silent_camera (reliable, volatile)"
            ), message
            # the silence goes on: still WARN, no second log line
            _spin_until(ros, lambda: False, 3.0, proc)
            assert status.latest[0] == WARN and status.latest[1] == message
            frame = np.tile(np.arange(64, dtype=np.uint8), (64, 1))
            t_end = time.monotonic() + 30
            while time.monotonic() < t_end and status.latest[2].get("input_total") in (None, "0"):
                pub.publish(cdr.image_to_cdr(frame, "mono8", 1_000_000_000, "cam"))
                _spin_until(ros, lambda: False, 0.3, proc)
            assert int(status.latest[2]["input_total"]) > 0
            assert _spin_until(ros, lambda: status.latest[2].get("input_silent_s") == "0", 10, proc)
        finally:
            cam.destroy_node()
    finally:
        log = _log(proc)
    assert log.count("]: no publisher on /watch/camera") == 1, log
    assert log.count("]: nothing received on /watch/camera") == 1, log
    assert "input arriving again" in log


def test_shift_node_without_aligned_frames_warns(ros):
    proc = _start("shift_node", "-r", "__ns:=/watchns", "-p", "input_timeout_s:=1.0")
    status = Status(ros, "watchns/shift_node")  # the status names the namespace
    try:
        warned = lambda: status.latest is not None and status.latest[0] == WARN  # noqa: E731
        assert _spin_until(ros, warned, 30, proc), status.latest
        assert status.latest[1] == "no publisher on /watchns/aligned"
    finally:
        _log(proc)


def test_input_timeout_is_a_declared_parameter_with_a_range():
    from subpix_ros.nodes.base import StageNode
    from subpix_ros.nodes.mosaic_node import MosaicNode
    from subpix_ros.nodes.reconstruction_node import ReconstructionNode
    from subpix_ros.nodes.registration_node import RegistrationNode
    from subpix_ros.nodes.shift_node import ShiftNode

    for cls in (RegistrationNode, ShiftNode, ReconstructionNode, MosaicNode):
        assert issubclass(cls, StageNode) and cls.MAIN_INPUTS
        p = {p.name: p for p in cls.PARAMS}["input_timeout_s"]
        assert p.default == 5.0 and p.min > 0 and p.max >= 60
        assert p.check(0.0) and p.check(-1.0) and p.check(5.0) is None
