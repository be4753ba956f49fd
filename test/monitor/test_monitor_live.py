"""monitor_node over real sockets: the sample flight replayed through the nodes.

`subpix replay` -> registration/shift/reconstruction/mosaic nodes -> monitor_node, every one a
separate process on real DDS; a foxglove.sdk.v1 WebSocket client (the `websockets` package)
reads what the operator's Foxglove would, and this test process listens to `/shift` over rclpy
to check the served shifts against the topic.
"""

import signal
import socket
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest
import rclpy
from conftest import ROOT, node_process, subpix_cmd
from geometry_msgs.msg import Vector3Stamped

from subpix_ros.cli._ros import stop_processes
from subpix_ros.io import cdr
from subpix_ros.io.bags import read_messages
from subpix_ros.monitor import TOPICS
from subpix_ros.monitor.client import FoxgloveClient
from subpix_ros.nodes.qos import reliable_qos

PARAMS = str(ROOT / "config" / "demo.yaml")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _node(name, *extra):
    return node_process(name, PARAMS, *extra)


def _spin(node, until, timeout, procs=()):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and not until():
        rclpy.spin_once(node, timeout_sec=0.05)
        for p in procs:
            assert p.poll() is None, f"{p.args[2:4]} died:\n{p.stdout.read()}"
    return until()


def _replay_cmd(sample_bags, readers=1):
    """`subpix replay` of the subpixel flight at half speed, once the camera has its readers.

    With the nodes in separate processes, registration, mosaic and monitor each read the
    camera: with one matched, the registration could still be in discovery and miss the
    first frames (seen in a CI run: 14 of 21 shifts), hence ``readers`` 3 there.
    """
    return subpix_cmd(
        "replay",
        str(sample_bags / "subpixel"),
        "--rate",
        "0.5",
        "--wait-for",
        "/camera/image_raw",
        "--wait-count",
        str(readers),
        "--wait-timeout",
        "60",
    )


def _listen_to_shifts(node):
    """Subscribe ``node`` to /shift and /shift/std; return the two dicts they fill (stamp -> x, y)."""
    shifts, stds = {}, {}

    def keep(table):
        def put(raw):
            vec, header = cdr.cdr_to_vector3_stamped(raw)
            table[cdr.header_to_ns(header)] = tuple(vec[:2])

        return put

    node.create_subscription(Vector3Stamped, "/shift", keep(shifts), reliable_qos(100), raw=True)
    node.create_subscription(Vector3Stamped, "/shift/std", keep(stds), reliable_qos(100), raw=True)
    return shifts, stds


@pytest.fixture
def flight(sample_bags):
    """Run the nodes and the monitor.

    Yields (port, procs, test node, shifts seen on /shift, their standard errors on /shift/std).
    """
    port = free_port()
    cam = "image:=/camera/image_raw"
    procs = [
        _node("registration_node", "-r", cam),
        _node("shift_node"),
        # volatile, as the onboard profile publishes it: the monitor must follow (a latched
        # subscription would match no publisher and show no super-resolved image)
        _node("reconstruction_node", "-p", "latch_output:=false"),
        _node("mosaic_node", "-r", cam),
        _node(
            "monitor_node",
            "-r",
            cam,
            "-p",
            f"port:={port}",
            "-p",
            "mosaic_period_s:=0.5",
            "-p",
            "camera_period_s:=0.5",
        ),
    ]
    rclpy.init()
    node = rclpy.create_node("monitor_test")
    shifts, stds = _listen_to_shifts(node)
    try:
        yield port, procs, node, shifts, stds
    finally:
        node.destroy_node()
        rclpy.shutdown()
        stop_processes(procs)


def test_monitor_serves_the_flight(flight, sample_bags):
    port, procs, node, shifts, stds = flight
    url = f"ws://127.0.0.1:{port}"
    # the server is up once the port accepts; the first client sees every channel with its schema
    deadline = time.monotonic() + 30
    a = None
    while time.monotonic() < deadline:
        a = FoxgloveClient(url)
        if a.wait(lambda: len(a.channels) >= len(TOPICS), 3):
            break
        a.close()
        assert procs[-1].poll() is None, procs[-1].stdout.read()
    assert {t: c["schemaName"] for t, c in a.channels.items()} == TOPICS
    assert a.server_info["capabilities"] == []  # no client publish, parameters or services
    for t, c in a.channels.items():
        assert c["encoding"] == ("json" if TOPICS[t].startswith("subpix.") else "protobuf"), t
        assert c["schema"], t

    assert _spin(node, lambda: node.count_publishers("/shift") > 0, 30, procs)
    _spin(node, lambda: False, 1.0, procs)
    replay = subprocess.Popen(_replay_cmd(sample_bags, readers=3))
    assert _spin(node, lambda: replay.poll() is not None, 120, procs) and replay.returncode == 0
    _spin(node, lambda: len(shifts) >= 21 and len(a.messages("/shift")) >= len(shifts), 30, procs)

    # shifts: the served values and standard errors are the topics', stamp by stamp
    served = {}
    for r in a.messages("/shift"):
        d = a.decode("/shift", r.payload)
        stamp = d["timestamp"]["sec"] * 10**9 + d["timestamp"]["nsec"]
        served[stamp] = (d["u"], d["v"], d["u_std"], d["v_std"])
    common = set(served) & set(shifts)
    assert len(common) >= 15, (
        f"{len(served)} served, {len(shifts)} on /shift, {len(common)} in both"
    )
    assert set(stds) == set(shifts), "every shift on /shift has its /shift/std"
    for s in common:  # sent to 1e-5 px, the errors to 3 significant digits
        assert served[s][:2] == tuple(round(x, 5) for x in shifts[s])
        assert served[s][2] is not None and served[s][3] is not None, f"no errors served at {s}"
        assert served[s][2:] == tuple(float(f"{x:.3g}") for x in stds[s])
        assert 0 < stds[s][0] <= 0.1 and 0 < stds[s][1] <= 0.1

    # the mosaic decodes to an image
    assert a.wait(lambda: a.messages("/mosaic"), 15), "no mosaic served"
    m = a.decode("/mosaic", a.messages("/mosaic")[-1].payload)
    assert m.format == "jpeg"
    img = cv2.imdecode(np.frombuffer(m.data, np.uint8), cv2.IMREAD_COLOR)
    assert img is not None and min(img.shape[:2]) >= 64

    # a LocationFix from the bag's telemetry
    fixes = [
        cdr.deserialize(x.raw, "sensor_msgs/msg/NavSatFix")
        for x in read_messages(sample_bags / "subpixel", ["/telemetry/fix"])
    ]
    assert a.wait(lambda: a.messages("/fix"), 10)
    f = a.decode("/fix", a.messages("/fix")[-1].payload)
    assert min(abs(f.latitude - x.latitude) + abs(f.longitude - x.longitude) for x in fixes) < 1e-9

    # the super-resolved crop and its bicubic twin
    assert a.wait(lambda: a.messages("/super_resolved") and a.messages("/bicubic"), 20)
    # health: a row per pipeline node, from their /diagnostics
    assert a.wait(
        lambda: any(
            {"registration_node", "shift_node", "mosaic_node"}
            <= {n["name"] for n in a.decode("/health", r.payload)["nodes"]}
            for r in a.messages("/health")
        ),
        10,
    )

    # a second client, later, gets the latest mosaic at once
    last_mosaic = a.messages("/mosaic")[-1].payload
    b = FoxgloveClient(url, topics=("/mosaic", "/health"))
    t0 = time.monotonic()
    assert b.wait(lambda: b.messages("/mosaic"), 5)
    assert b.messages("/mosaic")[0].t - t0 < 2.0
    assert b.messages("/mosaic")[0].payload == last_mosaic

    # a client killed (no close handshake) disturbs neither the others nor the pipeline
    killed = subprocess.Popen(
        [sys.executable, "-m", "subpix_ros.monitor.client", url, "60"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
    )
    time.sleep(2.0)
    killed.send_signal(signal.SIGKILL)
    killed.wait()
    n_a, n_b = len(a.messages("/health")), len(b.messages("/health"))
    _spin(node, lambda: False, 3.0, procs)
    assert len(a.messages("/health")) >= n_a + 2 and len(b.messages("/health")) >= n_b + 2
    assert a.error is None and b.error is None
    for p in procs:
        assert p.poll() is None
    a.close()
    b.close()


def test_monitor_node_refuses_an_exposed_host_without_tls():
    port = free_port()
    p = subprocess.run(
        [
            sys.executable,
            "-m",
            "subpix_ros.nodes.monitor_node",
            "--ros-args",
            "-p",
            "host:=0.0.0.0",
            "-p",
            f"port:={port}",
        ],
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert p.returncode == 2
    lines = [line for line in p.stderr.splitlines() if line.strip()]
    assert lines and "refusing to serve on '0.0.0.0' without TLS" in lines[-1], p.stderr
    with socket.socket() as s:  # nothing listens
        assert s.connect_ex(("127.0.0.1", port)) != 0


def test_pipeline_with_monitor_serves_shifts_with_their_errors(sample_bags):
    """`pipeline --monitor`: the monitor fed in memory; shifts carry their standard errors."""
    port = free_port()
    pipe = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "subpix_ros.nodes.pipeline",
            "--no-telemetry",
            "--monitor",
            "--ros-args",
            "--params-file",
            PARAMS,
            "-r",
            "image:=/camera/image_raw",
            "-p",
            f"monitor_node:port:={port}",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    rclpy.init()
    node = rclpy.create_node("monitor_pipeline_test")
    shifts, stds = _listen_to_shifts(node)
    a = None
    try:
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline:
            a = FoxgloveClient(f"ws://127.0.0.1:{port}")
            if a.wait(lambda: len(a.channels) == len(TOPICS), 3):
                break
            a.close()
            assert pipe.poll() is None, pipe.stdout.read()
        assert _spin(node, lambda: node.count_publishers("/shift") > 0, 30, [pipe])
        _spin(node, lambda: False, 1.0, [pipe])
        replay = subprocess.Popen(_replay_cmd(sample_bags))
        assert (
            _spin(node, lambda: replay.poll() is not None, 120, [pipe]) and replay.returncode == 0
        )
        _spin(
            node, lambda: len(shifts) >= 21 and len(a.messages("/shift")) >= len(shifts), 30, [pipe]
        )
        served = {}
        for r in a.messages("/shift"):
            d = a.decode("/shift", r.payload)
            served[d["timestamp"]["sec"] * 10**9 + d["timestamp"]["nsec"]] = d
        assert len(set(served) & set(shifts)) >= 15
        for s in set(served) & set(shifts):
            assert (served[s]["u"], served[s]["v"]) == tuple(round(x, 5) for x in shifts[s])
            # within shift_node's max_std_px
            assert 0 < served[s]["u_std"] <= 0.1 and 0 < served[s]["v_std"] <= 0.1
        assert a.wait(
            lambda: (
                a.messages("/super_resolved") and a.messages("/camera") and a.messages("/mosaic")
            ),
            20,
        )
        sr = a.decode("/super_resolved", a.messages("/super_resolved")[-1].payload)
        assert cv2.imdecode(np.frombuffer(sr.data, np.uint8), cv2.IMREAD_COLOR) is not None
    finally:
        if a is not None:
            a.close()
        node.destroy_node()
        rclpy.shutdown()
        stop_processes([pipe])
