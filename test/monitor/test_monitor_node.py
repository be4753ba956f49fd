"""monitor_node in this process over real DDS and a real socket: bad input, parameters."""

import contextlib
import math
import socket
import time

import cv2
import numpy as np
import pytest
import rclpy
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import Vector3Stamped
from rclpy.executors import SingleThreadedExecutor
from rclpy.parameter import Parameter
from rclpy.qos import QoSProfile, ReliabilityPolicy
from sensor_msgs.msg import CompressedImage, Image, NavSatFix
from std_msgs.msg import Float64

from subpix_ros.io import cdr
from subpix_ros.monitor import TOPICS
from subpix_ros.monitor.client import FoxgloveClient
from subpix_ros.nodes.qos import camera_qos, latched_qos, output_qos, reliable_qos

T0 = 1_700_000_000_000_000_000


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def _monitor_node(**params):
    """monitor_node with ``params``, a harness node, their executor and a Foxglove client."""
    from subpix_ros.nodes.monitor_node import MonitorNode

    rclpy.init()
    port = _free_port()
    node = MonitorNode(
        parameter_overrides=[Parameter("port", value=port)]
        + [Parameter(k, value=v) for k, v in params.items()]
    )
    h = rclpy.create_node("harness")
    ex = SingleThreadedExecutor()
    ex.add_node(node)
    ex.add_node(h)
    client = FoxgloveClient(f"ws://127.0.0.1:{port}")
    try:
        yield node, h, ex, client
    finally:
        client.close()
        node.close()
        ex.shutdown()
        node.destroy_node()
        h.destroy_node()
        rclpy.shutdown()


@pytest.fixture
def served():
    with _monitor_node(bandwidth_kbps=1.0) as s:
        yield s


def _own_status(h):
    """Collect monitor_node's own /diagnostics statuses as the harness receives them."""
    own = []
    h.create_subscription(
        DiagnosticArray,
        "/diagnostics",
        lambda m: own.extend(s for s in m.status if s.name == "monitor_node"),
        10,
    )
    return own


def _spin(ex, until, timeout):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not until():
        ex.spin_once(timeout_sec=0.02)
    return until()


def test_bad_input_is_reported_and_the_node_keeps_serving(served):
    node, h, ex, client = served
    # bandwidth_kbps 1.0 is below the range (8 ..): rejected at start-up, the default stays
    assert node.get_parameter("bandwidth_kbps").value == 2000.0
    assert node.monitor.cfg.bandwidth_kbps == 2000.0
    pubs = {
        "image": h.create_publisher(Image, "image", camera_qos(False)),
        "super_resolved": h.create_publisher(Image, "super_resolved", latched_qos()),
        "mosaic/compressed": h.create_publisher(
            CompressedImage, "mosaic/compressed", latched_qos()
        ),
        "shift": h.create_publisher(Vector3Stamped, "shift", reliable_qos(20)),
        "telemetry/fix": h.create_publisher(NavSatFix, "telemetry/fix", 10),
    }
    diag = _own_status(h)
    assert _spin(
        ex,
        lambda: (
            all(p.get_subscription_count() for p in pubs.values())
            and len(client.channels) == len(TOPICS)
        ),
        10,
    )
    T = cdr.TYPESTORE.types
    bad = T["sensor_msgs/msg/Image"](
        header=cdr.make_header(T0, "cam"),
        height=64,
        width=64,
        encoding="mono_8",
        is_bigendian=0,
        step=64,
        data=np.zeros(64 * 64, np.uint8),
    )
    pubs["image"].publish(cdr.serialize(bad, "sensor_msgs/msg/Image"))
    truncated = cdr.image_to_cdr(np.zeros((64, 64), np.uint8), "mono8", T0, "sr")[:40]
    pubs["super_resolved"].publish(truncated)
    pubs["mosaic/compressed"].publish(
        cdr.serialize(
            T["sensor_msgs/msg/CompressedImage"](
                header=cdr.make_header(T0, "m"),
                format="jpeg",
                data=np.frombuffer(b"not a jpeg", np.uint8),
            ),
            "sensor_msgs/msg/CompressedImage",
        )
    )
    fix = NavSatFix()
    fix.latitude, fix.longitude = math.nan, 10.0
    pubs["telemetry/fix"].publish(fix)
    pubs["shift"].publish(cdr.vector3_stamped_to_cdr((0.25, -0.5, 0.0), T0 + 5))
    assert _spin(ex, lambda: len(client.messages("/log")) >= 3 and client.messages("/shift"), 10), (
        client.received
    )
    logs = [client.decode("/log", r.payload) for r in client.messages("/log")]
    text = " | ".join(x.message for x in logs)
    for topic in ("_on_camera", "_on_sr", "_on_mosaic_c"):
        assert topic in text, text
    assert all(x.level >= 4 for x in logs)  # foxglove.Log ERROR = 4
    s = client.decode("/shift", client.messages("/shift")[0].payload)
    assert (s["u"], s["v"], s["timestamp"]["nsec"]) == (0.25, -0.5, 5)
    assert s["header"]["stamp"] == s["timestamp"]  # what the layout's plot orders by
    assert not client.messages("/fix")  # a NaN fix is not served, and that is said
    assert _spin(
        ex,
        lambda: any(
            {kv.key: kv.value for kv in st.values}.get("fixes_ignored") == "1" for st in diag
        ),
        5,
    )
    assert _spin(ex, lambda: any(st.level[0] == 2 for st in diag), 5)
    # the node goes on: a good mosaic after the bad ones is served
    good = np.full((64, 96, 3), 120, np.uint8)
    pubs["mosaic/compressed"].publish(cdr.compressed_to_cdr(good, T0 + 9, "mosaic", "jpeg", 90))
    assert _spin(ex, lambda: client.messages("/mosaic"), 10)


def test_a_super_resolved_png_as_the_results_bag_holds_it_is_served(served):
    """``subpix process`` records ``/super_resolved/compressed`` (PNG): replayed, it is served."""
    node, h, ex, client = served
    pub = h.create_publisher(CompressedImage, "super_resolved/compressed", latched_qos())
    assert _spin(
        ex, lambda: pub.get_subscription_count() and len(client.channels) == len(TOPICS), 10
    )
    sr = np.zeros((128, 160), np.uint16)
    sr[:, 80:] = 40000
    pub.publish(cdr.compressed_to_cdr(sr, T0 + 7, "sr", "png"))
    assert _spin(ex, lambda: client.messages("/super_resolved"), 10), client.received
    assert not client.messages("/log")  # decoded, no error


def test_a_volatile_super_resolved_is_served(served):
    """A reconstruction with ``latch_output: false`` publishes volatile: the monitor follows it.

    A transient-local subscription would match no volatile publisher and receive nothing.
    """
    node, h, ex, client = served
    pub = h.create_publisher(Image, "super_resolved", output_qos(False))
    assert _spin(
        ex, lambda: pub.get_subscription_count() and len(client.channels) == len(TOPICS), 10
    )
    sr = np.zeros((128, 160), np.uint8)
    sr[:, 80:] = 200
    pub.publish(cdr.image_to_cdr(sr, "mono8", T0 + 8, "sr"))
    assert _spin(ex, lambda: client.messages("/super_resolved"), 10), client.received
    assert not client.messages("/log")


def test_bandwidth_changes_at_run_time(served):
    node, h, ex, client = served
    assert not node.set_parameters([Parameter("bandwidth_kbps", value=1e9)])[0].successful
    assert node.monitor.cfg.bandwidth_kbps == 2000.0
    assert node.set_parameters([Parameter("bandwidth_kbps", value=500.0)])[0].successful
    assert node.monitor.bucket.rate == 500.0 * 125
    assert not node.set_parameters([Parameter("host", value="0.0.0.0")])[0].successful  # read-only


def test_shifts_without_their_standard_errors_are_served_and_said():
    # a node started without rejected parameters (those hold the status at ERROR: see
    # test/nodes/test_node_params.py), so the warning is its status
    with _monitor_node() as (node, h, ex, client):
        _shifts_without_std_are_said(node, h, ex, client)


def _shifts_without_std_are_said(node, h, ex, client):
    pub = h.create_publisher(Vector3Stamped, "shift", reliable_qos(20))
    diag = _own_status(h)
    assert _spin(ex, lambda: pub.get_subscription_count() > 0, 10)
    msg = Vector3Stamped()
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(T0, 10**9)
    msg.vector.x, msg.vector.y = 0.25, -0.5
    pub.publish(msg)  # no shift/std for it
    assert _spin(ex, lambda: client.messages("/shift"), 10)  # after shift_std_wait_s (0.5 s)
    d = client.decode("/shift", client.messages("/shift")[-1].payload)
    assert (d["u"], d["v"], d["u_std"], d["v_std"]) == (0.25, -0.5, None, None)
    assert _spin(
        ex,
        lambda: any(s.level == b"\x01" and "without standard errors" in s.message for s in diag),
        5,
    ), [(s.level, s.message) for s in diag[-3:]]


def _spy_sr(node):
    """Record what the node hands the (real) monitor for each super-resolved image."""
    seen = []
    real = node.monitor.on_super_resolved

    def spy(sr, bic, stamp, factor=None, fallback=None):
        seen.append((stamp, factor, fallback))
        real(sr, bic, stamp, factor, fallback)

    node.monitor.on_super_resolved = spy
    return seen


def test_a_bicubic_fallback_is_served_as_one_not_as_super_resolved(served):
    """An image that is the reference's bicubic upscale is labelled a fallback; SR is not.

    Over DDS an Image has no "fell back" flag: the node compares it with the bicubic upscale
    of its reference (the reconstruction's fallback is that image, rounded from float32). In
    memory the stage's own flag and reason are passed on.
    """
    from subpix_ros.core.superres.result import bicubic_integer
    from subpix_ros.stages.types import Frame, SuperResolved

    node, h, ex, client = served
    seen = _spy_sr(node)
    ref_pub = h.create_publisher(Image, "aligned/reference", latched_qos(4))
    sr_pub = h.create_publisher(Image, "super_resolved", latched_qos())
    assert _spin(
        ex, lambda: ref_pub.get_subscription_count() and sr_pub.get_subscription_count(), 10
    )
    rng = np.random.default_rng(1)
    ref = cv2.GaussianBlur(rng.integers(0, 256, (96, 128, 3), dtype=np.uint8), (0, 0), 1.0)
    ref_pub.publish(cdr.image_to_cdr(ref, "bgr8", T0, "cam"))
    assert _spin(ex, lambda: T0 in node._refs, 10)
    fallback = bicubic_integer(ref, 2, np.uint8)  # what the reconstruction falls back to
    sharpened = cv2.addWeighted(fallback, 2.0, cv2.GaussianBlur(fallback, (0, 0), 2.0), -1.0, 0)
    sr_pub.publish(cdr.image_to_cdr(fallback, "bgr8", T0, "cam"))
    assert _spin(ex, lambda: len(seen) == 1, 10)
    sr_pub.publish(cdr.image_to_cdr(sharpened, "bgr8", T0, "cam"))
    assert _spin(ex, lambda: len(seen) == 2, 10)
    assert seen[0] == (T0, 2, "the image equals the bicubic upscale of its reference")
    assert seen[1] == (T0, 2, None)
    # in memory: the stage's flag and reason
    frame = Frame(T0 + 1, ref)
    node.handle_super_resolved(
        SuperResolved(fallback, frame, [], "bicubic", True, "no plan fits 250 MB", 2)
    )
    node.handle_super_resolved(SuperResolved(sharpened, frame, [], "map", False, "", 2))
    # a reconstruction that came out as bicubic (a flat scene): the stage's word is taken
    node.handle_super_resolved(SuperResolved(fallback, frame, [], "map", False, "", 2))
    assert seen[2:] == [(T0 + 1, 2, "no plan fits 250 MB"), (T0 + 1, 2, None), (T0 + 1, 2, None)]


def _camera(h):
    """Return a function that publishes the next camera frame from the harness."""
    cam = h.create_publisher(Image, "image", camera_qos(False, depth=1))
    stamp = [T0]

    def frame():
        stamp[0] += 100_000_000
        cam.publish(cdr.image_to_cdr(np.zeros((48, 64), np.uint8), "mono8", stamp[0]))

    return frame


def _health_table(client):
    msg = client.decode("/health", client.messages("/health")[-1].payload)
    return {n["name"]: n for n in msg["nodes"]}


def _spin_until_ok(ex, own, *feeds):
    """Feed while spinning until monitor_node's status is OK (a warning is held for 5 s)."""
    t0 = time.monotonic()
    while time.monotonic() - t0 < 10 and not (own and own[-1].level == b"\x00"):
        for feed in feeds:
            feed()
        _spin(ex, lambda: False, 0.2)
    assert own and own[-1].level == b"\x00", own[-1].message if own else "no status"


def test_a_stopped_node_and_a_silent_camera_are_said_by_the_monitor():
    """The operator's window must not sit on a dead node's last OK, nor say OK showing nothing."""
    from diagnostic_msgs.msg import DiagnosticStatus

    with _monitor_node(stale_after_s=1.0, input_timeout_s=1.0) as (_, h, ex, client):
        own = _own_status(h)
        pub = h.create_publisher(DiagnosticArray, "/diagnostics", 10)
        frame = _camera(h)

        def report():
            msg = DiagnosticArray()
            msg.status = [
                DiagnosticStatus(level=DiagnosticStatus.OK, name="shift_node", message="ok")
            ]
            pub.publish(msg)

        # nothing on the camera or the mosaic: said, naming the topics
        assert _spin(
            ex, lambda: any(s.level == b"\x01" and "/image" in s.message for s in own), 10
        ), [s.message for s in own[-3:]]
        _spin_until_ok(ex, own, report, frame)  # frames arrive and shift_node reports
        assert _health_table(client)["shift_node"]["level"] == "OK"
        # shift_node stops reporting (killed); frames still arrive
        assert _spin(
            ex,
            lambda: (
                frame() or any("no /diagnostics status from shift_node" in s.message for s in own)
            ),
            10,
        ), [s.message for s in own[-3:]]
        assert own[-1].level == b"\x01"
        assert {kv.key: kv.value for kv in own[-1].values}["stale_nodes"] == "shift_node"
        _spin(ex, lambda: frame() or False, 2.5)  # the silence goes on: the text stays the same
        said = {s.message for s in own if "no /diagnostics status" in s.message}
        assert said == {
            "no /diagnostics status from shift_node for over 1 s: stopped, or no longer reachable"
        }, said  # (with the age in it, each second was a new Log entry for the operator)
        assert _health_table(client)["shift_node"]["level"] == "STALE"


def test_the_same_node_in_two_namespaces_is_two_rows_and_no_restart():
    """Two shift_node processes in /droneA and /droneB: two rows on the health table, no alarm.

    (Was: both reported 'shift_node', the monitor kept them in one row whose process id changed
    at every status and said "restarted (process A -> B)" twice a second.)
    """
    import sys
    import uuid

    from conftest import logged_popen

    tag = uuid.uuid4().hex[:6]
    names = [f"drone{k}_{tag}/shift_node" for k in (1, 2)]
    procs = [
        logged_popen(
            [sys.executable, "-m", "subpix_ros.nodes.shift_node", "--ros-args", "-r"]
            + [f"__ns:=/{name.split('/')[0]}"]
        )
        for name in names
    ]
    with _monitor_node() as (_, _h, ex, client):
        try:

            def rows():
                return _health_table(client) if client.messages("/health") else {}

            def logs():
                return [client.decode("/log", m.payload).message for m in client.messages("/log")]

            assert _spin(ex, lambda: set(names) <= rows().keys(), 30), (
                rows().keys(),
                [p.stdout.read() for p in procs if p.poll() is not None],
            )
            _spin(ex, lambda: False, 3.0)  # three statuses of each
            assert set(names) <= rows().keys() and "shift_node" not in rows()
            assert not [t for t in logs() if "restarted" in t], logs()
            assert all(p.poll() is None for p in procs)
        finally:
            for p in procs:
                p.terminate()
            for p in procs:
                p.wait(10)


def test_telemetry_that_stops_is_not_served_as_current_and_is_said():
    """A lost MAVLink link: no shift compared with the old expected shift, no footprint there."""
    with _monitor_node(telemetry_timeout_s=1.0, shift_std_wait_s=0.0, geo_period_s=0.5) as (
        node,
        h,
        ex,
        client,
    ):
        own = _own_status(h)
        frame = _camera(h)
        tel = QoSProfile(depth=20, reliability=ReliabilityPolicy.BEST_EFFORT)
        expected = h.create_publisher(Vector3Stamped, "telemetry/expected_shift", tel)
        fix = h.create_publisher(NavSatFix, "telemetry/fix", tel)
        height = h.create_publisher(Float64, "telemetry/height", tel)
        shift = h.create_publisher(Vector3Stamped, "shift", reliable_qos(20))

        def telemetry():
            m = Vector3Stamped()
            m.vector.x, m.vector.y = 0.41, 0.27
            expected.publish(m)
            f = NavSatFix()
            f.latitude, f.longitude, f.altitude = 42.8, -76.7, 120.0
            f.status.status = f.status.STATUS_FIX  # Jazzy's default is STATUS_UNKNOWN
            fix.publish(f)
            height.publish(Float64(data=56.0))

        n = [0]

        def one_shift():
            n[0] += 1
            shift.publish(cdr.vector3_stamped_to_cdr((0.4, 0.3, 0.0), T0 + n[0]))

        _spin_until_ok(ex, own, telemetry, frame)
        assert _spin(ex, lambda: telemetry() or frame() or client.messages("/footprints"), 5)
        one_shift()
        assert _spin(ex, lambda: client.messages("/shift"), 10)
        d = client.decode("/shift", client.messages("/shift")[-1].payload)
        assert (d["expected_u"], d["expected_v"]) == (0.41, 0.27)
        # the link is lost; the camera and the shifts go on
        assert _spin(
            ex,
            lambda: frame() or any("no telemetry for" in s.message for s in own),
            10,
        ), [s.message for s in own[-3:]]
        assert own[-1].level == b"\x01"
        assert float({kv.key: kv.value for kv in own[-1].values}["telemetry_age_s"]) > 1.0
        served = len(client.messages("/shift"))
        one_shift()
        assert _spin(ex, lambda: len(client.messages("/shift")) > served, 10)
        d = client.decode("/shift", client.messages("/shift")[-1].payload)
        assert d["expected_u"] is None and d["expected_v"] is None, d
        _spin(ex, lambda: False, 1.0)  # the last footprint drawn while the fix was fresh goes out
        n_fp = len(client.messages("/footprints"))
        for _ in range(10):  # frames without a current position draw no footprint
            frame()
            _spin(ex, lambda: False, 0.3)
        assert len(client.messages("/footprints")) == n_fp


def test_a_link_too_small_for_the_essentials_is_the_nodes_warning():
    """8 kbit/s against 10 shifts a second: monitor_node's status is WARN with the figures."""
    from rcl_interfaces.msg import Log

    from benchmarks.bench_monitor_link import Flight

    with _monitor_node(bandwidth_kbps=8.0) as (node, h, ex, client):
        own = _own_status(h)
        rosout = []
        h.create_subscription(
            Log, "/rosout", lambda m: rosout.append(m) if m.name == "monitor_node" else None, 50
        )
        frame = _camera(h)  # the camera arrives (else its silence is the warning)
        assert _spin(ex, lambda: len(client.channels) == len(TOPICS), 10)
        flight = Flight(node.monitor, track=200).start()
        try:

            def warned():
                return (
                    own and own[-1].level == b"\x01" and "link budget too small" in own[-1].message
                )

            assert _spin(ex, lambda: frame() or warned(), 30), [s.message for s in own[-3:]]
            said = own[-1].message
            assert "kbit/s (/shift" in said and "of the 8 kbit/s budget: no images go" in said
            values = {kv.key: kv.value for kv in own[-1].values}
            assert float(values["essential_kbps"]) > 8.0, values
            _spin(ex, lambda: frame() or False, 3.0)  # it goes on: the same text, logged once
            assert own[-1].message == said
            assert sum("link budget too small" in m.msg for m in rosout) == 1, [
                m.msg for m in rosout
            ]
        finally:
            flight.stop()
