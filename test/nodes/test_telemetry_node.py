"""telemetry_node in its own process: real MAVLink 2 over UDP loopback and the sample tlog."""

import math
import socket
import sys
import time

import numpy as np
import pytest
from conftest import logged_popen, spin
from diagnostic_msgs.msg import DiagnosticArray
from geometry_msgs.msg import TwistStamped
from sensor_msgs.msg import Imu, NavSatFix, NavSatStatus
from std_msgs.msg import Float64

from subpix_ros.core.telemetry import TelemetrySample
from subpix_ros.io.frame_metadata import trajectory_from_frames_csv
from subpix_ros.io.mavlink import MavlinkSender, encode_samples
from subpix_ros.nodes.qos import reliable_qos


def _free_udp_port() -> int:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    port = s.getsockname()[1]
    s.close()
    return port


class Sink:
    def __init__(self, node):
        self.fix, self.vel, self.height, self.interval, self.imu, self.diag = [], [], [], [], [], []
        q = reliable_qos(500)
        node.create_subscription(NavSatFix, "/telemetry/fix", self.fix.append, q)
        node.create_subscription(TwistStamped, "/telemetry/velocity", self.vel.append, q)
        node.create_subscription(Float64, "/telemetry/height", self.height.append, q)
        node.create_subscription(Float64, "/telemetry/frame_interval", self.interval.append, q)
        node.create_subscription(Imu, "/telemetry/imu", self.imu.append, q)
        node.create_subscription(
            DiagnosticArray,
            "/diagnostics",
            lambda m: self.diag.extend(s for s in m.status if s.name == "telemetry_node"),
            50,
        )


def _start(*params):
    args = [sys.executable, "-m", "subpix_ros.nodes.telemetry_node", "--ros-args"]
    for p in params:
        args += ["-p", p]
    return logged_popen(args)


def test_udp_mavlink_to_ros_topics_and_link_loss(rclpy_node):
    port = _free_udp_port()
    proc = _start(
        f"connection:=udpin:127.0.0.1:{port}",
        "link_timeout_s:=1.0",
        "p:=2.0",
        "focal_length_mm:=4.3",
        "pixel_pitch_um:=1.54",
    )
    sink = Sink(rclpy_node)
    sender = MavlinkSender(f"udpout:127.0.0.1:{port}")
    try:
        packets = _packets(400)
        # keep sending until the node is up and its messages arrive
        i = 0
        while not spin(rclpy_node, lambda: len(sink.interval) >= 3, 0.1) and i < len(packets):
            for _ in range(8):
                sender.send(packets[i % len(packets)])
                i += 1
        assert len(sink.interval) >= 3, (
            proc.stdout.read() if proc.poll() is not None else "no messages"
        )
        f = sink.fix[-1]
        assert f.latitude == pytest.approx(41.035308, abs=1e-7) and f.longitude == pytest.approx(
            -83.3062512, abs=1e-7
        )
        assert f.altitude == pytest.approx(288.4, abs=1e-3)
        v = sink.vel[-1].twist.linear
        np.testing.assert_allclose(
            [v.x, v.y, v.z], [7.0, 4.0, 0.5], atol=1e-6
        )  # ENU: east, north, up
        assert sink.height[-1].data == pytest.approx(58.4, abs=1e-3)
        # eq. 1 by hand: t = a H cos(0) / (p f V) = 1.54e-6 * 58.4 / (2 * 4.3e-3 * 8.0622577) s
        assert sink.interval[-1].data == pytest.approx(
            1.54e-6 * 58.4 / (2 * 4.3e-3 * 8.0622577), rel=1e-4
        )
        # link loss: stop sending; the node says so in /diagnostics within the timeout + 1 s report period
        assert spin(rclpy_node, lambda: any("link lost" in s.message for s in sink.diag), 6.0)
        assert proc.poll() is None  # and keeps running
    finally:
        sender.close()
        proc.terminate()
        proc.wait(10)


def test_tlog_replay_matches_the_flight(rclpy_node, sample_bags):
    from subpix_ros.data import data_root

    proc = _start(
        f"connection:={sample_bags / 'seneca.tlog'}",
        "tlog_rate:=10.0",
        "pixel_pitch_um:=3.08",
        "tlog_start_delay_s:=5.0",  # discovery on a loaded machine (3 s lost the first 19)
    )
    sink = Sink(rclpy_node)
    try:
        assert spin(rclpy_node, lambda: len(sink.fix) >= 361, 60.0), len(sink.fix)
    finally:
        proc.terminate()
        proc.wait(10)
    rows = [
        line.split(",")
        for line in (data_root() / "seneca" / "frames.csv").read_text().splitlines()[1:]
    ]
    fixes = {(round(f.latitude, 7), round(f.longitude, 7)) for f in sink.fix}
    # the trajectory passes through every frame's GPS fix (1e-7 deg: MAVLink's resolution)
    for r in rows:
        assert (round(float(r[2]), 7), round(float(r[3]), 7)) in fixes, r[0]
    h = np.array([m.data for m in sink.height])
    assert h.min() == pytest.approx(278.64 - 230.0, abs=0.05) and h.max() == pytest.approx(
        288.40 - 230.0, abs=0.5
    )
    speed = np.array([math.hypot(m.twist.linear.x, m.twist.linear.y) for m in sink.vel])
    assert 4.0 < np.median(speed) < 10.0  # the strip: 25-50 m between frames 4-6 s apart
    # every interval is eq. 1 for the published height and speed (flat terrain, phi = 0)
    traj = trajectory_from_frames_csv(data_root() / "seneca" / "frames.csv")
    s = traj[0]
    expected = 3.08e-6 * s.height_agl_m / (2 * 4.3e-3 * s.ground_speed_mps)
    assert sink.interval[0].data == pytest.approx(expected, rel=1e-3)


@pytest.mark.parametrize(
    "connection, expect",
    [
        ("/nonexistent/flight.tlog", "tlog file not found"),
        ("udpin:127.0.0.1:14550; rm -rf /tmp/x", "cannot open MAVLink connection"),
        ("ftp://example.org/flight", "cannot open MAVLink connection"),
    ],
)
def test_bad_connection_parameter_is_reported_and_node_keeps_running(
    rclpy_node, connection, expect
):
    proc = _start(f"connection:={connection}")
    sink = Sink(rclpy_node)
    try:
        assert spin(
            rclpy_node,
            lambda: any(
                expect in s.message or any(expect in kv.value for kv in s.values) for s in sink.diag
            ),
            20.0,
        )
        assert proc.poll() is None
    finally:
        proc.terminate()
        proc.wait(10)


def _level(status) -> int:
    """DiagnosticStatus level as an int (rclpy gives the byte field as bytes)."""
    lv = status.level
    return lv[0] if isinstance(lv, (bytes, bytearray)) else int(lv)


def _packets(n=200, lat=41.035308, lon=-83.3062512, height=58.4):
    t0 = time.time()
    samples = [
        TelemetrySample(
            t=t0 + 0.1 * k,
            lat_deg=lat,
            lon_deg=lon,
            alt_msl_m=288.4,
            height_agl_m=height,
            vel_ned_mps=(4.0, 7.0, -0.5),
            ground_speed_mps=math.hypot(4, 7),
            course_rad=math.atan2(7, 4),
            roll_rad=0.0,
            pitch_rad=0.0,
            yaw_rad=math.atan2(7, 4),
        )
        for k in range(n)
    ]
    return [p for _, p in encode_samples(samples, boot_time=t0)]


def test_missing_serial_device_stays_error_and_is_opened_when_plugged_in(rclpy_node):
    """A serial device absent at start: ERROR for as long as it is (past the 5-s hold), retried.

    The "USB autopilot" appears later as a symlink to a pseudo-terminal, and MAVLink bytes
    written to the pty's master side come out as /telemetry/fix.
    """
    import os
    import tty
    import uuid

    device = f"/dev/shm/subpix-test-tty-{uuid.uuid4().hex[:8]}"
    proc = _start(f"connection:={device}", "open_retry_s:=0.3")
    sink = Sink(rclpy_node)
    master = slave = None
    try:
        assert spin(
            rclpy_node, lambda: any("serial device not found" in s.message for s in sink.diag), 20
        ), [s.message for s in sink.diag]
        first = next(i for i, s in enumerate(sink.diag) if "serial device not found" in s.message)
        spin(rclpy_node, lambda: False, 6.5)  # past Diagnostics.hold_s (5 s)
        held = sink.diag[first:]
        assert len(held) >= 5 and all(_level(s) == 2 for s in held), [
            (_level(s), s.message) for s in held
        ]
        assert all("cannot open MAVLink connection" in s.message for s in held)
        # plugged in
        master, slave = os.openpty()
        tty.setraw(slave)
        os.set_blocking(master, False)
        os.symlink(os.ttyname(slave), device)
        packets, i = _packets(), 0

        def fix_arrived():
            nonlocal i
            for _ in range(8):
                try:
                    os.write(master, packets[i % len(packets)])
                    os.read(master, 65536)  # anything the node wrote (nothing expected)
                except BlockingIOError:
                    pass
                i += 1
            return len(sink.fix) >= 3

        assert spin(rclpy_node, fix_arrived, 15), proc.stdout.read()
        assert sink.fix[-1].latitude == pytest.approx(41.035308, abs=1e-7)
        assert "opened" in proc.stdout.read()
        assert proc.poll() is None
    finally:
        proc.terminate()
        proc.wait(10)
        for fd in (master, slave):
            if fd is not None:
                os.close(fd)
        if os.path.lexists(device):
            os.unlink(device)


def test_udp_link_without_any_autopilot_warns_naming_the_port(rclpy_node):
    port = _free_udp_port()
    url = f"udpin:127.0.0.1:{port}"
    proc = _start(f"connection:={url}", "input_timeout_s:=1.0")
    sink = Sink(rclpy_node)
    sender = MavlinkSender(f"udpout:127.0.0.1:{port}")
    try:
        expect = f"no MAVLink message received on {url} for over 1 s"
        assert spin(
            rclpy_node, lambda: any(expect in s.message and _level(s) == 1 for s in sink.diag), 15
        ), [s.message for s in sink.diag]
        assert "is the autopilot sending to this port?" in sink.diag[-1].message
        # the autopilot starts sending: the telemetry flows and the warning goes
        packets, i = _packets(), 0

        def sending():
            nonlocal i
            for _ in range(8):
                sender.send(packets[i % len(packets)])
                i += 1
            return len(sink.fix) >= 3

        assert spin(rclpy_node, sending, 10)
        n = len(sink.diag)
        assert spin(rclpy_node, lambda: sending() and len(sink.diag) >= n + 2, 5)
        values = {kv.key: kv.value for kv in sink.diag[-1].values}
        assert values["input_silent_s"] == "0" and int(values["input_total"]) > 0, values
    finally:
        sender.close()
        proc.terminate()
        proc.wait(10)


def test_mavros_source_without_mavros_warns_naming_its_topics(rclpy_node):
    import uuid

    ns = f"/mavros_{uuid.uuid4().hex[:8]}"  # topics nothing publishes on
    proc = _start(
        "source:=mavros",
        "input_timeout_s:=1.0",
        f"mavros_fix_topic:={ns}/global_position/global",
        f"mavros_velocity_topic:={ns}/local_position/velocity_local",
        f"mavros_height_topic:={ns}/global_position/rel_alt",
    )
    sink = Sink(rclpy_node)
    try:
        assert spin(
            rclpy_node,
            lambda: any("no mavros telemetry" in s.message and _level(s) == 1 for s in sink.diag),
            15,
        ), [s.message for s in sink.diag]
        msg = next(s.message for s in sink.diag if "no mavros telemetry" in s.message)
        for topic in ("local_position/velocity_local", "global_position/global", "rel_alt"):
            assert f"{topic}: no publisher" in msg, msg
        assert "is mavros running?" in msg
    finally:
        proc.terminate()
        proc.wait(10)


class _Autopilot:
    """Real MAVLink 2 frames, like ArduPilot's, with or without a GNSS fix."""

    def __init__(self):
        from pymavlink.dialects.v20 import ardupilotmega as mav2

        self.mav2 = mav2
        self.enc = mav2.MAVLink(None, srcSystem=1, srcComponent=1)
        self.boot_ms = 1000

    def frames(self, fix_type: int, sats: int) -> bytes:
        m, fix = self.mav2, fix_type >= 2
        self.boot_ms += 100
        lat, lon = (410353080, -833062512) if fix else (0, 0)
        msgs = [
            m.MAVLink_heartbeat_message(
                m.MAV_TYPE_QUADROTOR, m.MAV_AUTOPILOT_ARDUPILOTMEGA, 209, 4, 4, 3
            ),
            m.MAVLink_gps_raw_int_message(0, fix_type, lat, lon, 150000, 80, 120, 500, 9000, sats),
            # without a fix ArduPilot sends lat/lon 0, relative_alt 0 and velocity 0
            m.MAVLink_global_position_int_message(
                self.boot_ms,
                lat,
                lon,
                288400,
                58400 if fix else 0,
                400 if fix else 0,
                700 if fix else 0,
                0,
                6000,
            ),
            m.MAVLink_attitude_message(self.boot_ms, 0.0, 0.0, 1.05, 0, 0, 0),
        ]
        return b"".join(msg.pack(self.enc) for msg in msgs)


def test_gnss_without_fix_is_published_as_no_fix_and_nothing_made_up(rclpy_node):
    from geometry_msgs.msg import Vector3Stamped

    port = _free_udp_port()
    proc = _start(f"connection:=udpin:127.0.0.1:{port}")
    sink = Sink(rclpy_node)
    shifts = []
    rclpy_node.create_subscription(
        Vector3Stamped, "/telemetry/expected_shift", shifts.append, reliable_qos(100)
    )
    sender = MavlinkSender(f"udpout:127.0.0.1:{port}")
    ap = _Autopilot()
    try:
        # no fix: fix_type 0, no satellites, position 0
        warned = lambda: any(  # noqa: E731
            "GNSS: no fix (fix_type 0, 0 satellites)" in s.message and _level(s) == 1
            for s in sink.diag
        )
        assert spin(
            rclpy_node,
            lambda: sender.send(ap.frames(0, 0)) or (len(sink.fix) >= 5 and warned()),
            15,
        ), ([s.message for s in sink.diag], len(sink.fix))
        assert {f.status.status for f in sink.fix} == {NavSatStatus.STATUS_NO_FIX}
        assert sink.imu  # attitude is not GNSS: still published
        assert not sink.vel and not sink.height and not sink.interval and not shifts
        # an RTK fix: the fix says so, and velocity, height and the shift are published again
        assert spin(
            rclpy_node,
            lambda: (
                sender.send(ap.frames(6, 20))
                or (
                    len(sink.vel) >= 3
                    and sink.fix[-1].status.status == NavSatStatus.STATUS_GBAS_FIX
                )
            ),
            10,
        )
        assert sink.fix[-1].latitude == pytest.approx(41.035308, abs=1e-7)
        assert sink.height[-1].data == pytest.approx(58.4) and shifts
        assert spin(
            rclpy_node,
            lambda: (
                sender.send(ap.frames(4, 20))
                or (sink.fix[-1].status.status == NavSatStatus.STATUS_SBAS_FIX)
            ),
            5,
        )
    finally:
        sender.close()
        proc.terminate()
        proc.wait(10)


def test_mavros_fix_status_is_kept_and_no_fix_publishes_no_velocity(rclpy_node):
    import uuid

    ns = f"/mavros_{uuid.uuid4().hex[:8]}"
    proc = _start(
        "source:=mavros",
        f"mavros_fix_topic:={ns}/global",
        f"mavros_velocity_topic:={ns}/velocity_local",
        f"mavros_height_topic:={ns}/rel_alt",
        f"mavros_imu_topic:={ns}/imu",
    )
    sink = Sink(rclpy_node)
    q = reliable_qos(20)
    pub_fix = rclpy_node.create_publisher(NavSatFix, f"{ns}/global", q)
    pub_h = rclpy_node.create_publisher(Float64, f"{ns}/rel_alt", q)
    pub_v = rclpy_node.create_publisher(TwistStamped, f"{ns}/velocity_local", q)

    def send(status: int, lat: float) -> None:
        fix = NavSatFix(latitude=lat, longitude=-83.3 if lat else 0.0, altitude=288.4)
        fix.status.status = status
        pub_fix.publish(fix)
        pub_h.publish(Float64(data=58.4))
        v = TwistStamped()
        v.header.stamp = rclpy_node.get_clock().now().to_msg()
        v.twist.linear.x, v.twist.linear.y = 7.0, 4.0
        pub_v.publish(v)

    try:
        no_fix = NavSatStatus.STATUS_NO_FIX
        assert spin(
            rclpy_node,
            lambda: (
                send(no_fix, 0.0)
                or (
                    len(sink.fix) >= 3
                    and any(
                        "GNSS: no fix (mavros NavSatFix status -1)" in s.message for s in sink.diag
                    )
                )
            ),
            15,
        ), [s.message for s in sink.diag]
        assert {f.status.status for f in sink.fix} == {no_fix}
        assert not sink.vel and not sink.height
        sbas = NavSatStatus.STATUS_SBAS_FIX
        assert spin(
            rclpy_node,
            lambda: send(sbas, 41.0) or (len(sink.vel) >= 3 and sink.fix[-1].status.status == sbas),
            10,
        )
    finally:
        proc.terminate()
        proc.wait(10)


def test_mavros_sensor_data_qos_publishers_reach_the_telemetry_topics(rclpy_node):
    """Topics published as mavros 2 does, with rclcpp's SensorDataQoS (best effort), arrive.

    (Was: the node subscribed reliable, which matches no best-effort publisher: nothing
    received from a real mavros.)
    """
    import uuid

    from rclpy.qos import qos_profile_sensor_data

    ns = f"/mavros_{uuid.uuid4().hex[:8]}"
    proc = _start(
        "source:=mavros",
        f"mavros_fix_topic:={ns}/global_position/global",
        f"mavros_velocity_topic:={ns}/local_position/velocity_local",
        f"mavros_height_topic:={ns}/global_position/rel_alt",
        f"mavros_imu_topic:={ns}/imu/data",
    )
    sink = Sink(rclpy_node)
    q = qos_profile_sensor_data  # as mavros publishes them
    pub_fix = rclpy_node.create_publisher(NavSatFix, f"{ns}/global_position/global", q)
    pub_h = rclpy_node.create_publisher(Float64, f"{ns}/global_position/rel_alt", q)
    pub_v = rclpy_node.create_publisher(TwistStamped, f"{ns}/local_position/velocity_local", q)
    pub_imu = rclpy_node.create_publisher(Imu, f"{ns}/imu/data", q)

    def send() -> None:
        fix = NavSatFix(latitude=41.035308, longitude=-83.3062512, altitude=288.4)
        fix.status.status = NavSatStatus.STATUS_FIX
        pub_fix.publish(fix)
        pub_h.publish(Float64(data=58.4))
        imu = Imu()
        imu.orientation.w = 1.0
        pub_imu.publish(imu)
        v = TwistStamped()
        v.header.stamp = rclpy_node.get_clock().now().to_msg()
        v.twist.linear.x, v.twist.linear.y = 7.0, 4.0
        pub_v.publish(v)

    try:
        assert spin(
            rclpy_node, lambda: send() or (len(sink.vel) >= 3 and len(sink.height) >= 3), 20
        ), (len(sink.fix), [s.message for s in sink.diag][-3:])
        assert sink.fix[-1].latitude == pytest.approx(41.035308, abs=1e-7)
        assert sink.height[-1].data == pytest.approx(58.4)
        v = sink.vel[-1].twist.linear
        assert (v.x, v.y) == pytest.approx((7.0, 4.0))
        assert sink.imu  # with the mavros attitude
        assert proc.poll() is None
    finally:
        proc.terminate()
        proc.wait(10)


def test_p_changed_at_run_time_republishes_the_detector_angle_and_links_are_read_only(
    rclpy_node,
):
    import rclpy
    from rcl_interfaces.msg import Parameter, ParameterType, ParameterValue
    from rcl_interfaces.srv import SetParameters

    from subpix_ros.core.timing import detector_angle
    from subpix_ros.nodes.qos import latched_qos

    port = _free_udp_port()
    proc = _start(f"connection:=udpin:127.0.0.1:{port}", "p:=4.0")
    angles = []
    rclpy_node.create_subscription(
        Float64, "/telemetry/detector_angle", lambda m: angles.append(m.data), latched_qos()
    )
    client = rclpy_node.create_client(SetParameters, "/telemetry_node/set_parameters")

    def set_param(name, **value):
        req = SetParameters.Request(
            parameters=[Parameter(name=name, value=ParameterValue(**value))]
        )
        future = client.call_async(req)
        rclpy.spin_until_future_complete(rclpy_node, future, timeout_sec=10)
        return future.result().results[0]

    try:
        assert spin(rclpy_node, lambda: angles and client.service_is_ready(), 20), angles
        assert angles[-1] == pytest.approx(detector_angle(4.0)) == pytest.approx(0.32175, abs=1e-5)
        assert set_param("p", type=ParameterType.PARAMETER_DOUBLE, double_value=8.0).successful
        assert spin(rclpy_node, lambda: angles[-1] == pytest.approx(0.14190, abs=1e-5), 5), angles
        for name in ("connection", "source"):
            r = set_param(name, type=ParameterType.PARAMETER_STRING, string_value="mavros")
            assert not r.successful and "read-only" in r.reason, (name, r)
        assert proc.poll() is None
    finally:
        proc.terminate()
        proc.wait(10)


def test_a_link_losing_frames_is_a_warning_with_its_loss(rclpy_node):
    """Real MAVLink over UDP, every third frame lost: WARN naming the loss, the figures shown.

    (Was: ``packets`` and ``bad_crc`` only; a radio link dropping a third of its frames looked
    like a healthy one, and the telemetry samples it still made came late or not at all.)
    """
    port = _free_udp_port()
    proc = _start(f"connection:=udpin:127.0.0.1:{port}")
    sink = Sink(rclpy_node)
    sender = MavlinkSender(f"udpout:127.0.0.1:{port}")
    try:
        frames = _packets(600)
        i = 0

        def warned():
            return any("losing more than 20 %" in s.message for s in sink.diag)

        deadline = time.monotonic() + 30
        while not warned() and time.monotonic() < deadline:
            for _ in range(10):
                if i % 3 != 2:
                    sender.send(frames[i % len(frames)])
                i += 1
            spin(rclpy_node, lambda: False, 0.05)
        assert warned(), proc.stdout.read() if proc.poll() is not None else sink.diag[-1:]
        values = {kv.key: kv.value for kv in sink.diag[-1].values}
        assert int(values["packets_lost"]) > 0
        assert 25.0 <= float(values["loss_percent_10s"]) <= 40.0, values["loss_percent_10s"]
        assert proc.poll() is None
    finally:
        sender.close()
        proc.terminate()
        proc.wait(10)


def test_frame_ids_are_parameters_for_several_vehicles(rclpy_node):
    """Each telemetry message's frame_id comes from its parameter (was fixed: gps, map, ...)."""
    from geometry_msgs.msg import Vector3Stamped

    port = _free_udp_port()
    proc = _start(
        f"connection:=udpin:127.0.0.1:{port}",
        "gps_frame_id:=drone1/gps",
        "world_frame_id:=drone1/odom",
        "base_frame_id:=drone1/base_link",
        "camera_frame_id:=drone1/cam_optical_frame",
    )
    sink = Sink(rclpy_node)
    shifts = []
    rclpy_node.create_subscription(
        Vector3Stamped, "/telemetry/expected_shift", shifts.append, reliable_qos(50)
    )
    sender = MavlinkSender(f"udpout:127.0.0.1:{port}")
    try:
        packets = _packets(400)
        i = 0
        done = lambda: sink.imu and sink.vel and sink.fix and shifts  # noqa: E731
        while not spin(rclpy_node, done, 0.1) and i < len(packets):
            for _ in range(8):
                sender.send(packets[i % len(packets)])
                i += 1
        assert done(), proc.stdout.read() if proc.poll() is not None else "no messages"
        assert sink.fix[-1].header.frame_id == "drone1/gps"
        assert sink.vel[-1].header.frame_id == "drone1/odom"
        assert sink.imu[-1].header.frame_id == "drone1/base_link"
        assert shifts[-1].header.frame_id == "drone1/cam_optical_frame"
    finally:
        sender.close()
        proc.terminate()
        proc.wait(10)
