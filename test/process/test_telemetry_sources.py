"""Where `subpix process` finds a flight's telemetry, and what it says when it cannot.

Found by an outside trial (wave 2 session 23): a .tlog of HEARTBEATs only was "no telemetry
(no /telemetry/* topics, no .tlog beside the bag: ...)" with the flight `ok`; a bag recorded
under a namespace (/drone1/telemetry/*) or with mavros topics was "no telemetry", naming
nothing it had. Each test fails on the code before.
"""

import json
import struct
import subprocess
import sys
from pathlib import Path

from pymavlink import mavutil

from subpix_ros.io.bags import BagWriter, read_messages

ROOT = Path(__file__).resolve().parents[2]
DEMO = str(ROOT / "config" / "demo.yaml")


def _run(*args):
    cmd = [sys.executable, "-m", "subpix_ros.cli", "process", *args]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=600)


def _bag(path, msgs, rename=lambda topic: topic):
    with BagWriter(path, storage="mcap") as w:
        for m in msgs:
            w.write(rename(m.topic), m.msgtype, m.timestamp_ns, m.raw)
    return path


def _summary(folder):
    return json.loads((folder / "summary.json").read_text())


def test_a_tlog_of_heartbeats_only_is_unusable_telemetry_and_a_partial_flight(
    sample_bags, tmp_path
):
    frames = [m for m in read_messages(sample_bags / "subpixel") if m.topic == "/camera/image_raw"]
    bag = _bag(tmp_path / "flight", frames)
    log = mavutil.mavlink_connection(str(sample_bags / "subpixel.tlog"), dialect="common")
    n = 0
    with open(tmp_path / "flight.tlog", "wb") as out:
        while (msg := log.recv_match()) is not None:
            if msg.get_type() == "HEARTBEAT":
                out.write(struct.pack(">Q", int(msg._timestamp * 1e6)) + msg.get_msgbuf())
                n += 1
    assert n >= 2
    r = _run(str(bag), "-o", str(tmp_path / "out"), "--params", DEMO, "--telemetry", "tlog")
    assert r.returncode == 1, r.stdout + r.stderr
    s = _summary(tmp_path / "out" / "flight")
    assert s["status"] == "partial"
    text = (
        f"telemetry unusable: flight.tlog has no usable telemetry sample (none of its {n} "
        f"MAVLink frames ({n} HEARTBEAT) is a GLOBAL_POSITION_INT"
    )
    assert any(p.startswith(text) for p in s["problems"]), s["problems"]
    assert not any("no .tlog beside the bag" in p for p in s["problems"]), s["problems"]
    assert s["telemetry"]["note"].startswith("flight.tlog has no usable telemetry sample")


def test_telemetry_recorded_under_a_namespace_is_read_and_said(sample_bags, tmp_path):
    msgs = list(read_messages(sample_bags / "subpixel"))
    ns = "/drone1"
    bag = _bag(
        tmp_path / "flight",
        msgs,
        lambda t: ns + t if t.startswith("/telemetry/") else t,
    )
    r = _run(str(bag), "-o", str(tmp_path / "out"), "--params", DEMO)
    s = _summary(tmp_path / "out" / "flight")
    root = _summary_of(sample_bags, tmp_path)
    assert s["telemetry"]["source"] == "topics", s["problems"]
    assert s["telemetry"]["samples"] == root["telemetry"]["samples"] > 20
    assert "read from /drone1/telemetry/*" in s["telemetry"]["note"]
    assert s["status"] == root["status"], r.stdout
    with (
        open(tmp_path / "out" / "flight" / "shifts.csv") as a,
        open(tmp_path / "root" / "subpixel" / "shifts.csv") as b,
    ):
        assert a.read() == b.read()  # the same expected shifts as from /telemetry/*


def _summary_of(sample_bags, tmp_path):
    r = _run(str(sample_bags / "subpixel"), "-o", str(tmp_path / "root"), "--params", DEMO)
    assert (tmp_path / "root" / "subpixel" / "summary.json").is_file(), r.stdout + r.stderr
    return _summary(tmp_path / "root" / "subpixel")


def test_several_telemetry_namespaces_or_mavros_topics_are_named(sample_bags, tmp_path):
    msgs = list(read_messages(sample_bags / "subpixel"))
    tel = [m for m in msgs if m.topic.startswith("/telemetry/")]
    frames = [m for m in msgs if m.topic == "/camera/image_raw"]
    two = _bag(
        tmp_path / "two",
        frames + [m for m in tel] + [m for m in tel],
        rename=_alternate("/drone1", "/drone2"),
    )
    r = _run(str(two), "-o", str(tmp_path / "out"), "--params", DEMO)
    s = _summary(tmp_path / "out" / "two")
    text = "telemetry topics under several namespaces (/drone1/telemetry/*, /drone2/telemetry/*)"
    assert any(text in p for p in s["problems"]), s["problems"]
    assert s["telemetry"]["source"] == "none", r.stdout

    mav = _bag(
        tmp_path / "mav",
        frames + tel,
        lambda t: "/mavros/" + t.removeprefix("/telemetry/") if t.startswith("/telemetry/") else t,
    )
    r = _run(str(mav), "-o", str(tmp_path / "out"), "--params", DEMO)
    s = _summary(tmp_path / "out" / "mav")
    assert any("but mavros topics (/mavros/" in p for p in s["problems"]), s["problems"]
    r = _run(str(mav), "-o", str(tmp_path / "out2"), "--telemetry", "topics")
    assert "mav: failed: bag" in r.stdout and "but mavros topics" in r.stdout, r.stdout


def _alternate(a, b):
    seen = {}

    def rename(topic):
        if not topic.startswith("/telemetry/"):
            return topic
        seen[topic] = seen.get(topic, 0) + 1
        return (a if seen[topic] % 2 else b) + topic

    return rename
