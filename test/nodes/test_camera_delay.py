"""Camera frames that arrive late are reported (a stall outside the node is not silent).

The meter alone, then the registration node as its console entry point starts it (a real process,
real DDS): this test process is the camera and stamps its frames on time, late, or on another clock.
"""

import sys
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import rclpy
from conftest import logged_popen
from diagnostic_msgs.msg import DiagnosticArray
from sensor_msgs.msg import Image

from subpix_ros.cli._ros import stop_processes
from subpix_ros.io import cdr
from subpix_ros.nodes.delivery import DeliveryDelay
from subpix_ros.nodes.qos import reliable_qos

WARN = 1
DATA = Path(__file__).resolve().parents[2] / "data"


def test_delay_is_reception_minus_stamp_and_other_clocks_are_not_measured():
    d = DeliveryDelay(history=3)
    assert d.values() == {}
    assert d.add(10_000_000_000, 10_250_000_000) == pytest.approx(0.25)
    assert d.add(10_000_000_000, 9_990_000_000) == pytest.approx(-0.01)  # clock offset kept
    assert d.values() == {"camera_delay_ms_p50": "250.0", "camera_delay_ms_max": "250.0"}
    for late in (0.1, 0.2, 0.3):
        d.add(0, int(late * 1e9))
    assert d.values() == {"camera_delay_ms_p50": "200.0", "camera_delay_ms_max": "300.0"}

    assert DeliveryDelay.problem(None, 0.3) is None and DeliveryDelay.problem(0.3, 0.3) is None
    assert DeliveryDelay.problem(0.61, 0.3).startswith(
        "camera frame received 610 ms after its stamp (over camera_delay_warn_ms 300)"
    )

    other = DeliveryDelay()
    assert other.add(1_000_000_000, 1_700_000_000_000_000_000) is None  # a bag's stamps, wall clock
    assert other.unmeasured == 1
    assert other.values()["camera_delay_ms_max"].startswith("n/a (stamps +1699999999 s")
    assert other.values()["camera_delay_unmeasured"] == "1"
    other.add(0, 50_000_000)
    assert other.values() == {
        "camera_delay_unmeasured": "1",
        "camera_delay_ms_p50": "50.0",
        "camera_delay_ms_max": "50.0",
    }


def test_registration_node_warns_when_frames_arrive_late(rclpy_node):
    ros = rclpy_node
    cmd = [
        sys.executable,
        "-m",
        "subpix_ros.nodes.registration_node",
        "--ros-args",
        "-r",
        "image:=/delay/camera",
        "-r",
        "__node:=delay_registration",
        "-p",
        "selection:=all",  # no telemetry here: no selection warning to mix with
        "-p",
        "camera_reliable:=true",
        "-p",
        "camera_delay_warn_ms:=500.0",
    ]
    proc = logged_popen(cmd)
    latest = {}

    def on_diag(msg):
        for s in msg.status:
            if s.name == "delay_registration":
                latest["status"] = (s.level[0], {kv.key: kv.value for kv in s.values})

    ros.create_subscription(DiagnosticArray, "/diagnostics", on_diag, 50)
    pub = ros.create_publisher(Image, "/delay/camera", reliable_qos(5))
    scene = cv2.imread(str(DATA / "seneca" / "IMG_0463.jpg"), cv2.IMREAD_GRAYSCALE)
    frame = np.ascontiguousarray(scene[:240, :320])  # registers onto itself: no other warning
    clock = ros.get_clock()

    def send(n, age_s, until):
        """Publish ``n`` frames stamped ``age_s`` before now; spin until ``until()`` or 20 s."""
        deadline = time.monotonic() + 20
        sent = 0
        while time.monotonic() < deadline:
            if sent < n:
                stamp = clock.now().nanoseconds - int(age_s * 1e9)
                pub.publish(cdr.image_to_cdr(frame, "mono8", stamp, "cam"))
                sent += 1
            rclpy.spin_once(ros, timeout_sec=0.1)
            assert proc.poll() is None, proc.stdout.read()
            if sent == n and until():
                return latest["status"]
        raise AssertionError(f"not seen within 20 s; latest status {latest.get('status')}")

    def values():
        return latest.get("status", (0, {}))[1]

    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not pub.get_subscription_count():
            rclpy.spin_once(ros, timeout_sec=0.1)
        # on time: measured, no warning
        level, v = send(3, 0.0, lambda: values().get("input_total") == "3")
        assert float(v["camera_delay_ms_max"]) < 500.0, v
        assert "after its stamp" not in v["recent_problems"], v
        # late by 2 s (after 2.5 s, so its stamp still follows the last one): reported, with the
        # likely cause
        end = time.monotonic() + 2.5
        while time.monotonic() < end:
            rclpy.spin_once(ros, timeout_sec=0.1)
        level, v = send(1, 2.0, lambda: float(values().get("camera_delay_ms_max", 0)) > 1900)
        assert float(v["camera_delay_ms_max"]) < 3000.0, v
        assert level == WARN, v
        assert v["last_error"].startswith("camera frame received 200"), v
        assert "ms after its stamp (over camera_delay_warn_ms 500)" in v["last_error"], v
        assert "Fast DDS profile" in v["last_error"], v
        assert v["errors_total"] == "0" and v["warnings_total"] == "1", v
        warnings = int(v["warnings_total"])
        # stamped on another clock (a day ahead): not a delay, not a warning
        send(2, -86400.0, lambda: values().get("input_total") == "6")
        _, v = latest["status"]
        assert int(v["warnings_total"]) == warnings, v
        assert float(v["camera_delay_ms_max"]) > 1900  # the measured ones are kept
        assert v["camera_delay_unmeasured"] == "2", v
    finally:
        stop_processes([proc])
        log = proc.stdout.read()
    assert "ms after its stamp" in log, log
