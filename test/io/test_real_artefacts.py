"""Bags written by rosbag2 itself and telemetry logs from ArduPilot.

Bags written by rosbag2 itself and telemetry logs from ArduPilot (test/data/README.md says where
each comes from): each is read, replayed or parsed, or refused with one clear line (issue 19,
item 6).
"""

import subprocess
from pathlib import Path

import pytest
import yaml
from conftest import subpix_cmd
from rosbags.interfaces import QosDurability, QosReliability

from subpix_ros.io.bags import BagError, bag_topics, read_messages

DATA = Path(__file__).resolve().parents[1] / "data"
BAGS = DATA / "rosbag2"

# bag folder, metadata version, storage
READABLE = [
    ("mcap_talker_v4", 4, "mcap"),
    ("sqlite3_talker_v4", 4, "sqlite3"),
    ("mcap_convert_a_v5", 5, "mcap"),
    ("mcap_seek_v6", 6, "mcap"),
    ("mcap_cdr_test_v7", 7, "mcap"),
    ("sqlite3_cdr_test_v7", 7, "sqlite3"),
    ("mcap_services_v8", 8, "mcap"),
]


def _metadata(bag):
    return yaml.safe_load((bag / "metadata.yaml").read_text())["rosbag2_bagfile_information"]


@pytest.mark.parametrize("name, version, storage", READABLE)
def test_rosbag2_bag_reads_as_its_metadata_says(name, version, storage):
    bag = BAGS / name
    meta = _metadata(bag)
    assert meta["version"] == version and meta["storage_identifier"] == storage

    def short(msgtype):  # version 6's test_bag_for_seek says "test_msgs/BasicTypes"
        return msgtype.replace("/msg/", "/")

    want = {
        t["topic_metadata"]["name"]: (short(t["topic_metadata"]["type"]), t["message_count"])
        for t in meta["topics_with_message_count"]
    }
    assert {t.name: (short(t.msgtype), t.count) for t in bag_topics(bag)} == want
    msgs = list(read_messages(bag))
    assert len(msgs) == meta["message_count"] == sum(n for _, n in want.values())
    stamps = [m.timestamp_ns for m in msgs]
    assert stamps == sorted(stamps)
    assert stamps[0] >= meta["starting_time"]["nanoseconds_since_epoch"]
    for name_, (_, n) in want.items():
        assert sum(m.topic == name_ for m in msgs) == n
    # every topic's offered QoS profiles parse (integer enums before version 9)
    for t in bag_topics(bag):
        if t.qos:
            assert all(
                q.reliability in (QosReliability.RELIABLE, QosReliability.BEST_EFFORT)
                for q in t.qos
            )


def test_rosbag2_mcap_cdr_decodes_with_its_own_definitions():
    """Decode the real CDR of a rosbag2 test bag to the values it wrote.

    The bytes read are the real CDR: test_msgs/BasicTypes decodes to the values the rosbag2
    test wrote (bool_value true, int32 123 ...) with the definition in the file.
    """
    from rosbags.typesys import get_types_from_msg

    from subpix_ros.io import _mcap

    path = BAGS / "mcap_cdr_test_v7" / "cdr_test_0.mcap"
    f, buf = _mcap.open_mcap(path)
    # the schema of /test_topic, from the file (ros2msg text)
    raw = bytes(buf)
    start = raw.index(b"test_msgs/msg/BasicTypes")
    enc_at = start + len(b"test_msgs/msg/BasicTypes")
    n2 = int.from_bytes(raw[enc_at : enc_at + 4], "little")
    assert raw[enc_at + 4 : enc_at + 4 + n2] == b"ros2msg"
    p = enc_at + 4 + n2
    n3 = int.from_bytes(raw[p : p + 4], "little")
    text = raw[p + 4 : p + 4 + n3].decode()
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_JAZZY)
    store.register(get_types_from_msg(text, "test_msgs/msg/BasicTypes"))
    msgs = list(read_messages(BAGS / "mcap_cdr_test_v7", ["/test_topic"]))
    assert len(msgs) == 3
    for m in msgs:
        v = store.deserialize_cdr(m.raw, "test_msgs/msg/BasicTypes")
        # rosbag2's cdr_test writes BasicTypes with int32_value = 123 and every other field 0
        assert (
            v.int32_value == 123
            and not v.bool_value
            and v.int64_value == 0
            and v.float64_value == 0.0
        )
    # and sqlite3 storage of the same test holds the same bytes
    assert [m.raw for m in read_messages(BAGS / "sqlite3_cdr_test_v7", ["/test_topic"])] == [
        m.raw for m in msgs
    ]


@pytest.mark.parametrize("name", ["mcap_talker_v4", "sqlite3_talker_v4"])
def test_rosbag2_talker_decodes_and_keeps_its_qos(name):
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import String

    bag = BAGS / name
    texts = [deserialize_message(m.raw, String).data for m in read_messages(bag, ["/topic"])]
    assert texts == [f"Hello, world! {i}" for i in range(10)]
    rosout = next(t for t in bag_topics(bag) if t.name == "/rosout")
    assert [q.durability for q in rosout.qos] == [QosDurability.TRANSIENT_LOCAL]
    assert rosout.qos[0].lifespan.sec == 10


def test_rosbag2_single_mcap_file_without_metadata():
    topics = {t.name: (t.msgtype, t.count) for t in bag_topics(BAGS / "only_topics.mcap")}
    assert topics["/parameter_events"] == ("rcl_interfaces/msg/ParameterEvent", 7)
    msgs = list(read_messages(BAGS / "only_topics.mcap", ["/parameter_events"]))
    assert len(msgs) == 7


def test_rosbag2_wrong_serialisation_format_is_refused_in_one_line():
    with pytest.raises(
        BagError,
        match="topic /test_topic is serialised as 'wrong_format', not CDR|"
        "topic /array_topic is serialised as 'wrong_format', not CDR",
    ):
        list(read_messages(BAGS / "sqlite3_wrong_format_v4"))
    r = subprocess.run(
        subpix_cmd("replay", str(BAGS / "sqlite3_wrong_format_v4"), "--delay", "0"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert r.returncode != 0 and len(lines) == 1 and "not CDR" in lines[0], r.stderr


def test_rosbag2_bag_of_unknown_types_replay_fails_in_one_line():
    r = subprocess.run(
        subpix_cmd("replay", str(BAGS / "mcap_cdr_test_v7"), "--delay", "0"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert (
        r.returncode != 0 and len(lines) == 1 and "unknown message type 'test_msgs/msg/" in lines[0]
    ), r.stderr


@pytest.mark.parametrize("name", ["mcap_talker_v4", "sqlite3_talker_v4"])
def test_rosbag2_talker_replays_to_another_process(name, rclpy_node):
    """Replay a bag rosbag2 wrote, byte for byte and with its recorded QoS.

    `subpix replay` of a bag rosbag2 wrote: the subscribers in this process get every message,
    byte for byte, and /rosout is offered transient local, as it was recorded (/topic volatile).
    """
    import time

    import rclpy
    from rcl_interfaces.msg import Log
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from std_msgs.msg import String

    bag = BAGS / name
    ns = f"/artefact_{name}_{time.monotonic_ns() % 1_000_000}"
    args = [
        "replay",
        str(bag),
        "--topics",
        "/topic",
        "/rosout",
        "--rate",
        "20",
        "--remap",
        f"/topic:={ns}/topic",
        f"/rosout:={ns}/rosout",
        "--wait-for",
        "/topic",
        "/rosout",
        "--wait-timeout",
        "30",
    ]
    play = subprocess.Popen(
        subpix_cmd(*args), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
    )
    got = {"/topic": [], "/rosout": []}
    try:
        # the replay waits for our subscribers (--wait-for): its publishers are in the graph
        offered = {}
        deadline = time.monotonic() + 30
        while len(offered) < 2 and time.monotonic() < deadline:
            for t in got:
                infos = rclpy_node.get_publishers_info_by_topic(ns + t)
                if infos:
                    offered[t] = [i.qos_profile.durability for i in infos]
            rclpy.spin_once(rclpy_node, timeout_sec=0.05)
        assert offered == {
            "/topic": [DurabilityPolicy.VOLATILE],
            "/rosout": [DurabilityPolicy.TRANSIENT_LOCAL],
        }
        for t, cls, durability in (
            ("/topic", String, DurabilityPolicy.VOLATILE),
            ("/rosout", Log, DurabilityPolicy.TRANSIENT_LOCAL),
        ):
            rclpy_node.create_subscription(
                cls,
                ns + t,
                lambda raw, t=t: got[t].append(bytes(raw)),
                QoSProfile(
                    depth=100, reliability=ReliabilityPolicy.RELIABLE, durability=durability
                ),
                raw=True,
            )
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and sum(map(len, got.values())) < 20:
            rclpy.spin_once(rclpy_node, timeout_sec=0.05)
        out, err = play.communicate(timeout=30)
    finally:
        if play.poll() is None:
            play.kill()
    assert play.returncode == 0, err
    for t in got:
        assert got[t] == [m.raw for m in read_messages(bag, [t])]


# ----------------------------------------------------------------- ArduPilot telemetry logs
def _gpi(path):
    """GLOBAL_POSITION_INT of system 1, as pymavlink parses the log by itself."""
    from pymavlink import mavutil

    m = mavutil.mavlink_connection(str(path))
    out = []
    while True:
        msg = m.recv_match(type="GLOBAL_POSITION_INT")
        if msg is None:
            return out
        if msg.get_srcSystem() == 1:
            out.append(msg)


@pytest.mark.parametrize(
    "name, n_samples", [("apm_bench_2012.tlog", 11), ("arducopter_sitl_flight_excerpt.tlog", 209)]
)
def test_ardupilot_tlog_parses(name, n_samples):
    from subpix_ros.io.mavlink import MavlinkReader

    path = DATA / "tlog" / name
    samples, events = [], []
    reader = MavlinkReader(str(path), on_sample=samples.append, on_status=events.append).start()
    assert reader.join(60)
    st = reader.stats
    gpi = _gpi(path)
    assert len(samples) == len(gpi) == n_samples and st.rejected == 0 and st.exceptions == 0
    assert [e.state for e in events][-1] == "end_of_log"
    for s, g in zip(samples, gpi):
        assert s.lat_deg == pytest.approx(g.lat * 1e-7) and s.lon_deg == pytest.approx(g.lon * 1e-7)
        assert s.height_agl_m == pytest.approx(g.relative_alt / 1000.0)
        assert s.time_boot_ms == g.time_boot_ms and s.system_id == 1
    assert st.mavlink1 == st.packets and st.mavlink2 == 0
    from subpix_ros.process.inputs import read_tlog

    kept, note = read_tlog(path)  # what subpix process takes: samples with a GNSS fix
    if name.startswith("apm"):  # a bench log: fix_type 1, position 0, 0
        assert kept == [] and note == "11 of 11 samples without a GNSS fix left out"
    else:
        assert len(kept) == n_samples and "GNSS" not in note
    if name.startswith("arducopter"):
        # in flight at the SITL home, and the packets of a changed definition counted, not fatal
        assert (
            max(s.ground_speed_mps for s in samples) > 5
            and max(s.height_agl_m for s in samples) > 10
        )
        assert all(
            abs(s.lat_deg + 35.3622) < 0.01 and abs(s.lon_deg - 149.1657) < 0.01 for s in samples
        )
        assert st.bad_crc == 78
        ts = [s.t for s in samples]
        assert ts == sorted(ts) and 75 < ts[-1] - ts[0] < 81


def test_telemetry_node_replays_the_ardupilot_sitl_log(rclpy_node):
    """Run telemetry_node on the ArduPilot SITL excerpt.

    telemetry_node in its own process on the SITL excerpt (10x speed): a NavSatFix for every
    GLOBAL_POSITION_INT of the vehicle, at its position, and heights as the log has them.
    """
    import sys
    import time

    import rclpy
    from sensor_msgs.msg import NavSatFix
    from std_msgs.msg import Float64

    from subpix_ros.nodes.qos import reliable_qos

    path = DATA / "tlog" / "arducopter_sitl_flight_excerpt.tlog"
    gpi = _gpi(path)
    fixes, heights = [], []
    rclpy_node.create_subscription(NavSatFix, "/telemetry/fix", fixes.append, reliable_qos(500))
    rclpy_node.create_subscription(Float64, "/telemetry/height", heights.append, reliable_qos(500))
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "subpix_ros.nodes.telemetry_node",
            "--ros-args",
            "-p",
            f"connection:={path}",
            "-p",
            "tlog_rate:=10.0",
            "-p",
            "tlog_start_delay_s:=5.0",  # discovery on a loaded machine (3 s lost the first 7)
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        deadline = time.monotonic() + 60
        n_last, t_last = 0, time.monotonic()
        while time.monotonic() < deadline and len(fixes) < len(gpi):
            rclpy.spin_once(rclpy_node, timeout_sec=0.05)
            if len(fixes) != n_last:
                n_last, t_last = len(fixes), time.monotonic()
            elif fixes and time.monotonic() - t_last > 5:
                break  # the log has ended (8 s at 10x)
        assert proc.poll() is None  # the end of the log does not end the node
    finally:
        proc.terminate()
        proc.wait(10)
    assert len(fixes) == len(gpi) == 209
    for f, g in zip(fixes, gpi):
        assert f.latitude == pytest.approx(g.lat * 1e-7, abs=1e-9)
        assert f.longitude == pytest.approx(g.lon * 1e-7, abs=1e-9)
    assert [h.data for h in heights][:5] == pytest.approx([g.relative_alt / 1000 for g in gpi][:5])


def test_sample_without_attitude_has_no_imu_message_but_the_rest():
    """GLOBAL_POSITION_INT 89 of the SITL excerpt comes with no ATTITUDE in the last 0.5 s."""
    from subpix_ros.io import telemetry_msgs as tm
    from subpix_ros.io.mavlink import MavlinkReader

    samples = []
    reader = MavlinkReader(
        str(DATA / "tlog" / "arducopter_sitl_flight_excerpt.tlog"), on_sample=samples.append
    ).start()
    assert reader.join(60)
    bare = [s for s in samples if s.roll_rad is None]
    assert len(bare) == 1 and bare[0].time_boot_ms == 408139
    topics = [t for t, _, _ in tm.sample_messages(bare[0], 0.5)]
    assert topics == [
        "telemetry/fix",
        "telemetry/height",
        "telemetry/velocity",
        "telemetry/frame_interval",
    ]
    assert "telemetry/imu" in [t for t, _, _ in tm.sample_messages(samples[0], 0.5)]
