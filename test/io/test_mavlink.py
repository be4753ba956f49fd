"""MAVLink I/O with real packets: pymavlink over UDP loopback and .tlog files."""

import math
import time

import numpy as np
import pytest
from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mav2

from subpix_ros.core.telemetry import (
    TelemetrySample,
    attitude_quaternion_enu,
    timing_usable,
    trajectory_straight,
)
from subpix_ros.data import data_root
from subpix_ros.io.frame_metadata import trajectory_from_frames_csv
from subpix_ros.io.mavlink import (
    LinkLoss,
    MavlinkReader,
    MavlinkSender,
    encode_samples,
    parse_url,
    read_tlog_packets,
    write_tlog,
)

T0 = 1_700_000_000.0  # boot time of the synthetic autopilot (POSIX s)


def wait_until(pred, timeout=5.0):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if pred():
            return True
        time.sleep(0.01)
    return pred()


def make(dt, **kw):
    """Build a hand-made sample ``dt`` seconds after boot (time_boot_ms = 1000 dt)."""
    base = dict(
        t=T0 + dt,
        lat_deg=41.0353080,
        lon_deg=-83.3062512,
        alt_msl_m=288.4,
        height_agl_m=58.4,
        vel_ned_mps=(4.0, 7.0, -0.5),
        ground_speed_mps=math.hypot(4.0, 7.0),
        course_rad=math.atan2(7.0, 4.0),
        roll_rad=0.05,
        pitch_rad=-0.02,
        yaw_rad=1.0,
    )
    base.update(kw)
    return TelemetrySample(**base)


def packets(samples, **kw):
    kw.setdefault("heartbeat_hz", 0.0)
    return b"".join(p for _, p in encode_samples(samples, boot_time=T0, **kw))


class Collector:
    def __init__(self):
        self.samples, self.events = [], []

    def reader(self, url="udpin:127.0.0.1:0", **kw):
        return MavlinkReader(url, on_sample=self.samples.append, on_status=self.events.append, **kw)

    def states(self):
        return [e.state for e in self.events]


@pytest.fixture
def udp():
    """Start a reader on an ephemeral loopback UDP port and a sender to it."""
    made = []

    def factory(**kw):
        col = Collector()
        reader = col.reader(**kw).start()
        host, port = reader.local_address
        sender = MavlinkSender(f"udpout:{host}:{port}")
        made.append((reader, sender))
        return col, reader, sender

    yield factory
    for reader, sender in made:
        sender.close()
        reader.stop()


# --------------------------------------------------------------------------- encoding
def test_encoded_fields_follow_mavlink_units():
    s = make(2.5)
    pk = encode_samples([s], system_id=3, component_id=1, boot_time=T0)
    parser = mav2.MAVLink(None)
    msgs = [parser.parse_char(buf) for _, buf in pk]
    assert [m.get_type() for m in msgs] == [
        "HEARTBEAT",
        "ATTITUDE",
        "VFR_HUD",
        "GLOBAL_POSITION_INT",
    ]
    assert all(m.get_srcSystem() == 3 for m in msgs)
    assert [m.get_seq() for m in msgs] == [0, 1, 2, 3]
    hb, att, hud, gpi = msgs
    assert hb.type == mav2.MAV_TYPE_QUADROTOR and hb.autopilot == mav2.MAV_AUTOPILOT_GENERIC
    assert gpi.time_boot_ms == 2500 and att.time_boot_ms == 2500
    assert (gpi.lat, gpi.lon) == (410353080, -833062512)  # 1e-7 deg
    assert (gpi.alt, gpi.relative_alt) == (288400, 58400)  # mm
    assert (gpi.vx, gpi.vy, gpi.vz) == (400, 700, -50)  # cm/s NED
    assert gpi.hdg == 5730  # yaw 1 rad = 57.2958 deg, centidegrees
    assert hud.groundspeed == pytest.approx(math.hypot(4, 7), rel=1e-7)
    assert hud.heading == 57 and hud.alt == pytest.approx(288.4, rel=1e-7)
    assert hud.climb == pytest.approx(0.5)
    assert att.roll == pytest.approx(0.05, rel=1e-7) and att.yaw == pytest.approx(1.0, rel=1e-7)
    assert all(buf[0] == 0xFD for _, buf in pk)
    assert all(buf[0] == 0xFE for _, buf in encode_samples([s], mavlink1=True))


def test_heartbeat_rate_and_encoding_errors():
    traj = trajectory_straight(t0=T0, duration_s=9.9, rate_hz=10.0)
    pk = encode_samples(traj, heartbeat_hz=1.0)
    parser = mav2.MAVLink(None)
    types = [parser.parse_char(b).get_type() for _, b in pk]
    assert types.count("HEARTBEAT") == 10 and types.count("GLOBAL_POSITION_INT") == 100
    with pytest.raises(ValueError, match="non-finite lat"):
        encode_samples([make(0, lat_deg=float("nan"))])
    with pytest.raises(ValueError, match="vx"):
        encode_samples([make(0, vel_ned_mps=(400.0, 0.0, 0.0))])
    with pytest.raises(ValueError, match="before boot_time"):
        encode_samples([make(0)], boot_time=T0 + 5)


def gps_raw(fix_type, sats=12, lat=410353080, lon=-833062512, system_id=1):
    """One GPS_RAW_INT packet (MAVLink 2) from ``system_id``."""
    enc = mav2.MAVLink(None, srcSystem=system_id, srcComponent=1)
    msg = mav2.MAVLink_gps_raw_int_message(0, fix_type, lat, lon, 150000, 80, 120, 500, 9000, sats)
    return msg.pack(enc)


# --------------------------------------------------------------------------- UDP
def test_udp_fix_status_follows_gps_raw_int_fix_type(udp):
    """GPS_RAW_INT.fix_type gives each sample's NavSatStatus; lat = lon = 0 is no fix."""
    col, reader, sender = udp()
    sender.send(packets([make(0.0)], heartbeat_hz=1.0))  # no GPS_RAW_INT yet: a fix
    expected = [None]
    for k, (fix_type, status) in enumerate(
        [(0, -1), (1, -1), (2, 0), (3, 0), (4, 1), (5, 2), (6, 2), (7, 0), (8, 0)], start=1
    ):
        sender.send(gps_raw(fix_type))
        sender.send(packets([make(0.1 * k)]))
        expected.append(status)
    # an autopilot without a position: lat and lon exactly 0, whatever GPS_RAW_INT says
    sender.send(packets([make(1.0, lat_deg=0.0, lon_deg=0.0)]))
    expected.append(-1)
    assert wait_until(lambda: len(col.samples) == len(expected)), len(col.samples)
    assert [s.fix_status for s in col.samples] == expected
    assert [s.has_fix for s in col.samples] == [x is None or x >= 0 for x in expected]
    assert col.samples[0].navsat_status == 0 and reader.gps_raw == (8, 12)  # the latest


def test_udp_no_gps_raw_int_and_zero_position_is_no_fix(udp):
    col, reader, sender = udp()
    sender.send(packets([make(0.0, lat_deg=0.0, lon_deg=0.0)], heartbeat_hz=1.0))
    assert wait_until(lambda: len(col.samples) == 1)
    s = col.samples[0]
    assert s.fix_status == -1 and s.navsat_status == -1 and not s.has_fix
    assert reader.gps_raw is None


def test_udp_sample_matches_hand_computed_values(udp):
    col, reader, sender = udp()
    sender.send(packets([make(0.0)], heartbeat_hz=1.0))
    sender.send(
        packets([make(0.1, vel_ned_mps=(-3.0, 0.0, 1.2), ground_speed_mps=3.0, yaw_rad=-2.0)])
    )
    assert wait_until(lambda: len(col.samples) == 2)
    s, s2 = col.samples
    assert reader.target_system == 1 and s.system_id == 1 and s.time_boot_ms == 0
    assert s.lat_deg == 41.035308 and s.lon_deg == -83.3062512
    assert s.alt_msl_m == 288.4 and s.height_agl_m == 58.4
    assert s.ground_speed_mps == pytest.approx(8.0622577, rel=1e-7)  # hypot(4, 7)
    assert math.degrees(s.course_rad) == pytest.approx(60.2551187, abs=1e-6)  # atan2(7, 4)
    np.testing.assert_allclose(s.vel_enu_mps, [7.0, 4.0, 0.5])  # east, north, up
    np.testing.assert_allclose(
        s.orientation_enu(), attitude_quaternion_enu(0.05, -0.02, 1.0), atol=1e-7
    )
    assert time.time() - 5 < s.t <= time.time()  # live link: receive time
    # Flying south, 3 m/s, sinking: course 180 deg, ENU velocity (0, -3, -1.2).
    assert s2.time_boot_ms == 100 and s2.t >= s.t
    assert math.degrees(s2.course_rad) == pytest.approx(180.0)
    np.testing.assert_allclose(s2.vel_enu_mps, [0.0, -3.0, -1.2])
    assert s2.yaw_rad == pytest.approx(-2.0, rel=1e-7)
    assert col.states() == ["connected"]
    st = reader.stats
    assert st.samples == 2 and st.heartbeats == 1 and st.rejected == 0 and st.exceptions == 0


def test_udp_link_lost_after_timeout_and_restored(udp):
    col, reader, sender = udp(link_timeout_s=0.4)
    traj = trajectory_straight(t0=T0, duration_s=1.0, rate_hz=10.0)
    before_send = time.time()  # every packet is received after this instant
    sender.send_packets(encode_samples(traj[:5], boot_time=T0), rate=None)
    assert wait_until(lambda: "lost" in col.states(), timeout=3.0)
    assert col.states() == ["connected", "lost"]
    lost = col.events[-1]
    assert lost.t - before_send > 0.4 and "no MAVLink from system 1" in lost.reason
    assert reader.link_state == "lost"
    sender.send_packets(encode_samples(traj[5:], boot_time=T0), rate=None)
    assert wait_until(lambda: col.states() == ["connected", "lost", "restored"])
    assert wait_until(lambda: len(col.samples) == len(traj))
    assert reader.stats.link_losses == 1


def test_udp_bad_input_is_counted_and_valid_data_survives(udp):
    col, reader, sender = udp()
    garbage = b"\x00\x11 not mavlink \x7f\x42" * 3  # no 0xFD/0xFE magic bytes inside
    bad_crc = bytearray(packets([make(0.2)]))
    bad_crc[-1] ^= 0xFF  # the last frame (GLOBAL_POSITION_INT) gets a wrong checksum
    mav1 = packets([make(0.4, lat_deg=41.0354537)], mavlink1=True)
    sender.send(
        packets([make(0.1)], heartbeat_hz=1.0) + garbage + bytes(bad_crc)
    )  # garbage between frames
    sender.send(garbage)
    sender.send(
        packets([make(0.3, lat_deg=12.0)], system_id=7, heartbeat_hz=1.0)
    )  # another vehicle
    sender.send(mav1)
    sender.send(packets([make(0.5, roll_rad=float("nan"))]))
    sender.send(packets([make(0.6, height_agl_m=-2.0)]))
    sender.send(packets([make(0.7, vel_ned_mps=(0.0, 0.0, 0.0), ground_speed_mps=0.0)]))  # hover
    sender.send(packets([make(0.8, ground_speed_mps=500.0)]))  # VFR_HUD says 500 m/s
    sender.send(packets([make(0.9, lat_deg=95.0)]))
    sender.send(packets([make(0.65)]))  # time_boot_ms goes back 250 ms
    sender.send(packets([make(0.9)]))  # same time_boot_ms again
    sender.send(packets([make(1.0)]))
    assert wait_until(lambda: len(col.samples) == 4 and reader.stats.rejected == 6)
    time.sleep(0.1)
    assert [s.time_boot_ms for s in col.samples] == [100, 400, 700, 1000]
    assert col.samples[1].lat_deg == 41.0354537  # the MAVLink 1 sample
    hover = col.samples[2]
    assert hover.ground_speed_mps == 0.0 and not timing_usable(hover)[0]
    assert math.degrees(hover.course_rad) == pytest.approx(
        math.degrees(1.0), abs=1e-5
    )  # heading at hover
    st = reader.stats
    assert st.bad_crc == 1
    assert st.bad_data == 2 and st.garbage_bytes == 2 * len(garbage)
    assert st.other_system == 4  # HEARTBEAT, ATTITUDE, VFR_HUD, GLOBAL_POSITION_INT of system 7
    assert st.mavlink1 == 3 and st.mavlink2 == st.packets - 3
    assert st.out_of_order == 1 and st.duplicates == 1
    assert st.reject_reasons == {
        "non-finite roll_rad": 1,
        "negative height above ground": 1,
        "absurd ground speed": 1,
        "latitude out of range": 1,
        "out-of-order time_boot_ms": 1,
        "duplicate time_boot_ms": 1,
    }
    assert st.exceptions == 0 and reader.target_system == 1


def test_udp_frames_lost_on_the_link_are_counted_from_sequence_numbers(udp):
    """A link that loses every third frame: ``packets_lost`` counts the gaps, about a third."""
    col, reader, sender = udp()
    frames = [p for _, p in encode_samples([make(0.1 * k) for k in range(60)], boot_time=T0)]
    sent = [f for i, f in enumerate(frames) if i % 3 != 2]
    for f in sent:
        sender.send(f)
    assert wait_until(lambda: reader.stats.packets == len(sent)), reader.stats.packets
    st = reader.stats
    # each dropped frame is a gap seen at the next frame (a dropped last one is not seen)
    assert st.packets_lost == len(frames) - len(sent) - (1 if len(frames) % 3 == 0 else 0)


def test_link_loss_over_its_window():
    """``LinkLoss``: lost / (received + lost) over the last window; too few frames say nothing."""
    meter = LinkLoss(window_s=10.0, min_frames=50)
    assert meter.add(0.0, 0, 0) is None
    assert meter.add(1.0, 20, 5) is None  # 25 frames: too few
    assert meter.add(2.0, 80, 20) == pytest.approx(0.2)  # since t = 0
    for t in range(3, 13):  # a clean link from then on: 100 frames a second
        last = meter.add(float(t), 80 + 100 * (t - 2), 20)
    assert last == pytest.approx(0.0)  # the lossy start has left the 10-s window
    assert meter.add(13.0, 5, 0) is None  # counters restarted (a new connection)


def test_udp_system_id_filter_and_callback_errors(udp):
    col, reader, sender = udp(system_id=7)
    calls = []

    def flaky(sample):
        calls.append(sample)
        if len(calls) == 1:
            raise RuntimeError("consumer bug")

    reader.on_sample = flaky
    for k in range(3):
        sender.send(packets([make(0.1 * k + 0.1, lat_deg=10.0)], system_id=1))
        sender.send(packets([make(0.1 * k + 0.1, lat_deg=20.0)], system_id=7))
    assert wait_until(lambda: len(calls) == 3)
    time.sleep(0.1)
    assert [s.lat_deg for s in calls] == [20.0, 20.0, 20.0] and all(s.system_id == 7 for s in calls)
    st = reader.stats
    assert st.other_system == 9 and st.callback_errors == 1 and "consumer bug" in st.last_error
    assert st.samples == 3


# --------------------------------------------------------------------------- tlog
@pytest.fixture(scope="module")
def frames_traj():
    return trajectory_from_frames_csv(data_root() / "seneca" / "frames.csv")


def test_tlog_round_trip_recovers_every_sample(tmp_path, frames_traj):
    path = tmp_path / "seneca.tlog"
    n = write_tlog(path, frames_traj)
    assert n == 361 * 3 + 37  # ATTITUDE, VFR_HUD, GPI per sample + 1 Hz heartbeats over 36 s
    col = Collector()
    reader = col.reader(str(path)).start()
    assert reader.join(20.0)
    got = col.samples
    assert len(got) == len(frames_traj)
    for a, b in zip(frames_traj, got):
        assert abs(a.t - b.t) <= 4e-6  # tlog stores microseconds with the 2 link-id bits cleared
        assert abs(a.lat_deg - b.lat_deg) <= 0.5e-7 and abs(a.lon_deg - b.lon_deg) <= 0.5e-7
        assert (
            abs(a.height_agl_m - b.height_agl_m) <= 0.5e-3
            and abs(a.alt_msl_m - b.alt_msl_m) <= 0.5e-3
        )
        assert np.all(np.abs(a.vel_ned_mps - b.vel_ned_mps) <= 0.005 + 1e-12)  # cm/s
        assert b.ground_speed_mps == pytest.approx(a.ground_speed_mps, rel=1e-7)  # float32
        # course from cm/s velocities: error <= |dv| / |v| with |dv| <= 0.005 * sqrt(2)
        dc = (a.course_rad - b.course_rad + math.pi) % (2 * math.pi) - math.pi
        assert abs(dc) <= 0.00708 / a.ground_speed_mps
        assert b.yaw_rad == pytest.approx(a.yaw_rad, abs=1e-6) and b.roll_rad == 0.0
    assert col.states() == ["connected", "end_of_log"]
    st = reader.stats
    assert st.packets == n and st.samples == 361 and st.rejected == 0 and st.link_losses == 0
    # pymavlink's own reader sees the same file (the format MAVProxy writes).
    conn = mavutil.mavlink_connection(str(path))
    counts = {}
    while (m := conn.recv_match()) is not None:
        counts[m.get_type()] = counts.get(m.get_type(), 0) + 1
    conn.close()
    assert counts == {"HEARTBEAT": 37, "ATTITUDE": 361, "VFR_HUD": 361, "GLOBAL_POSITION_INT": 361}
    raw = read_tlog_packets(path)
    assert len(raw) == n and raw[0][0] == frames_traj[0].t


def test_tlog_gap_reports_link_loss_in_log_time(tmp_path):
    traj = trajectory_straight(t0=T0, duration_s=10.0, rate_hz=5.0)
    kept = [s for s in traj if not (T0 + 3.0 < s.t < T0 + 8.0)]  # a 5 s telemetry outage
    path = tmp_path / "gap.tlog"
    write_tlog(path, kept)
    col = Collector()
    reader = col.reader(str(path), link_timeout_s=2.0).start()
    assert reader.join(10.0)
    assert col.states() == ["connected", "lost", "restored", "end_of_log"]
    lost, restored = col.events[1], col.events[2]
    assert lost.t == pytest.approx(T0 + 3.0 + 2.0, abs=1e-5)
    assert restored.t == pytest.approx(T0 + 8.0, abs=1e-5)
    assert len(col.samples) == len(kept)


def test_tlog_replay_rate_paces_in_log_time(tmp_path):
    traj = trajectory_straight(t0=T0, duration_s=1.0, rate_hz=10.0)
    path = tmp_path / "short.tlog"
    write_tlog(path, traj)
    col = Collector()
    start = time.monotonic()
    reader = col.reader(str(path), rate=4.0).start()  # 1 s of log at 4x: >= 0.25 s
    assert reader.join(10.0)
    elapsed = time.monotonic() - start
    assert elapsed >= 0.25 - 0.01
    assert len(col.samples) == len(traj)


def test_tlog_mixed_mavlink1_and_2(tmp_path):
    traj = trajectory_straight(t0=T0, duration_s=2.0, rate_hz=5.0)
    pk = encode_samples(traj[:5], boot_time=T0) + encode_samples(
        traj[5:], boot_time=T0, mavlink1=True
    )
    path = tmp_path / "mixed.tlog"
    write_tlog(path, packets=pk)
    col = Collector()
    reader = col.reader(str(path)).start()
    assert reader.join(10.0)
    st = reader.stats
    assert len(col.samples) == len(traj)
    assert st.mavlink1 > 0 and st.mavlink2 > 0 and st.mavlink1 + st.mavlink2 == len(pk)


# --------------------------------------------------------------------------- URLs
def test_parse_url_defaults_to_loopback_and_validates(tmp_path):
    assert parse_url("udpin:14550").url == "udpin:127.0.0.1:14550"
    assert parse_url("udp::14550").url == "udpin:127.0.0.1:14550"
    assert parse_url("udpin:0.0.0.0:14550").address == "0.0.0.0:14550"
    assert parse_url("udpout:192.168.1.5:14550").kind == "udpout"
    assert parse_url("tcp:localhost:5760").address == "localhost:5760"
    assert parse_url("udpin:127.0.0.1:0").address.endswith(":0")  # ephemeral listener
    spec = parse_url("/dev/null,115200")  # any existing device path; not opened here
    assert spec.kind == "serial" and spec.baud == 115200
    log = tmp_path / "x.tlog"
    log.write_bytes(b"")
    assert parse_url(str(log)).kind == "tlog"
    for bad in (
        "",
        "udpin:abc",
        "udpout:127.0.0.1:0",
        "udpin:70000",
        "udpin:$(reboot):14550",
        "http://example.com",
        "mcast:",
        "/dev/null,fast",
        "/bin/ls",
        "notes.txt",
    ):
        with pytest.raises(ValueError):
            parse_url(bad)
    with pytest.raises(FileNotFoundError):
        parse_url(str(tmp_path / "missing.tlog"))
    with pytest.raises(FileNotFoundError):
        parse_url("/dev/ttyNOPE0")
    with pytest.raises(ValueError, match="rate"):
        MavlinkReader("udpin:127.0.0.1:0", rate=1.0)
    with pytest.raises(ValueError):
        MavlinkSender("udpin:127.0.0.1:14550")


def test_reader_stop_is_prompt_without_traffic():
    reader = MavlinkReader("udpin:127.0.0.1:0", link_timeout_s=0.2).start()
    time.sleep(0.3)
    start = time.monotonic()
    reader.stop()
    assert time.monotonic() - start < 1.0 and reader.join(0.0)
    assert reader.link_state == "waiting" and reader.stats.packets == 0


def test_tcp_stream_split_at_odd_boundaries_and_peer_close():
    import socket

    col = Collector()
    reader = col.reader("tcpin:127.0.0.1:0", link_timeout_s=0.3).start()
    try:
        host, port = reader.local_address
        traj = trajectory_straight(t0=T0, duration_s=1.0, rate_hz=10.0)
        data = packets(traj, heartbeat_hz=1.0)
        with socket.create_connection((host, port), timeout=2.0) as sock:
            for i in range(0, len(data), 7):  # 7-byte pieces: frames split anywhere
                sock.sendall(data[i : i + 7])
            assert wait_until(lambda: len(col.samples) == len(traj))
        assert wait_until(lambda: "lost" in col.states(), timeout=3.0)  # peer gone
        cpu0 = time.process_time()
        time.sleep(1.0)
        assert time.process_time() - cpu0 < 0.1  # the closed socket does not make the thread spin
        st = reader.stats
        assert (
            st.samples == len(traj) and st.bad_data == 0 and st.bad_crc == 0 and st.exceptions == 0
        )
    finally:
        reader.stop()


def test_autopilot_reboot_is_accepted_and_counted(tmp_path):
    before = trajectory_straight(t0=T0 + 30.0, duration_s=1.0, rate_hz=5.0)
    after = trajectory_straight(t0=T0 + 32.0, duration_s=1.0, rate_hz=5.0)
    # time_boot_ms 30000.. then, after a reboot 31.5 s later, 500..
    pk = encode_samples(before, boot_time=T0) + encode_samples(after, boot_time=T0 + 31.5)
    path = tmp_path / "reboot.tlog"
    write_tlog(path, packets=pk)
    col = Collector()
    reader = col.reader(str(path)).start()
    assert reader.join(10.0)
    assert len(col.samples) == len(before) + len(after)
    assert [s.time_boot_ms for s in col.samples[len(before) :]][:2] == [500, 700]
    assert reader.stats.reboots == 1 and reader.stats.rejected == 0


def test_reader_survives_internal_errors(udp):
    col, reader, sender = udp()
    original = reader._position
    calls = []

    def broken_once(*args):
        calls.append(1)
        if len(calls) == 1:
            raise KeyError("simulated decoder bug")
        return original(*args)

    reader._position = broken_once
    for k in range(3):
        sender.send(packets([make(0.1 * (k + 1))]))
    assert wait_until(lambda: len(col.samples) == 2)
    st = reader.stats
    assert st.exceptions == 1 and "simulated decoder bug" in st.last_error
    assert [s.time_boot_ms for s in col.samples] == [200, 300]


def test_import_leaves_the_environment_alone(tmp_path):
    """Importing the module sets no MAVLINK20: MAVLink 2 is chosen inside each connection.

    In a fresh interpreter without MAVLINK20, a tlog written by the package is read back
    whole by the package's reader and by pymavlink's own, and the environment is untouched.
    """
    import os
    import subprocess
    import sys

    code = f"""
import os
from subpix_ros.io import mavlink as m
assert "MAVLINK20" not in os.environ, "import set MAVLINK20"
from subpix_ros.io.frame_metadata import trajectory_from_frames_csv
from subpix_ros.data import data_root
traj = trajectory_from_frames_csv(data_root() / "seneca" / "frames.csv")
path = {str(tmp_path / "t.tlog")!r}
m.write_tlog(path, traj)
got = []
reader = m.MavlinkReader(path, on_sample=got.append).start()
assert reader.join(20.0)
assert len(got) == len(traj), (len(got), len(traj))
assert "MAVLINK20" not in os.environ, "reading set MAVLINK20"
print("ok", len(got))
"""
    env = {k: v for k, v in os.environ.items() if k != "MAVLINK20"}
    out = subprocess.run(
        [sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120
    )
    assert out.returncode == 0, out.stderr
    assert out.stdout.startswith("ok 361")


def test_a_tlog_of_a_lossy_link_is_noted_by_subpix_process(tmp_path):
    """A ``.tlog`` whose link lost a third of its frames: ``read_tlog``'s note says so."""
    from subpix_ros.process.inputs import read_tlog

    samples = [make(0.1 * k) for k in range(60)]
    frames = encode_samples(samples, boot_time=T0)
    kept = [(t, p) for i, (t, p) in enumerate(frames) if i % 3 != 2]
    write_tlog(tmp_path / "lossy.tlog", packets=kept)
    write_tlog(tmp_path / "clean.tlog", packets=frames)
    _, note = read_tlog(tmp_path / "lossy.tlog")
    lost = len(frames) - len(kept) - (1 if len(frames) % 3 == 0 else 0)
    assert f"the recorded link lost {lost} of {len(kept) + lost} MAVLink frames (33 %" in note
    assert "lost" not in read_tlog(tmp_path / "clean.tlog")[1]
