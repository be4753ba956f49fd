"""`subpix record` started before the publishers (issue 19, item 4).

As one starts `ros2 bag record` before a flight: real processes over real DDS.
"""

import contextlib
import os
import signal
import subprocess
import time
from pathlib import Path

import pytest
from conftest import subpix_cmd

from subpix_ros.io.bags import bag_topics, read_messages

TOPICS = ("/camera/image_raw", "/telemetry/velocity")


def _ns():
    """Topic names of this test alone (no stale publisher or subscriber of another test matches)."""
    return f"/late_{os.getpid()}_{time.monotonic_ns() % 1_000_000}"


def _replay(bag, ns, topics, wait=True):
    args = [
        "replay",
        str(bag),
        "--topics",
        *topics,
        "--remap",
        *(f"{t}:={ns}{t}" for t in topics),
        "--delay",
        "0.5",
    ]
    if wait:
        args += ["--wait-for", *topics]
    return subprocess.run(subpix_cmd(*args), capture_output=True, text=True, timeout=90)


def _wait(proc, timeout, log, context=""):
    """Return the recorder's (stdout, stderr) once it exits; fail with its stacks if it does not.

    ``log``: a recorder started by :func:`_recording` (output to files, not pipes that
    nobody drains while the test sleeps). A recorder that does not finish in time is asked
    for every thread's stack (SIGUSR1), then stopped (SIGINT, then SIGKILL), and the test
    fails with what it printed.
    """
    try:
        proc.wait(timeout=timeout)
    except subprocess.TimeoutExpired:
        proc.send_signal(signal.SIGUSR1)
        time.sleep(1.0)
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout=15)
            how = "stopped by SIGINT"
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
            how = "did not stop on SIGINT either: killed"
        out, err = _read(log)
        pytest.fail(
            f"recorder did not finish within {timeout} s ({how}){context}\n"
            f"--- stdout\n{out}\n--- stderr\n{err}"
        )
    return _read(log)


@contextlib.contextmanager
def _recording(log, *args):
    """Run ``subpix record ARGS``, its stdout and stderr in files ``log``.out / ``log``.err.

    Yields the process; one still running when the block ends (a failed test) is killed.
    """
    with open(f"{log}.out", "w") as out, open(f"{log}.err", "w") as err:
        rec = subprocess.Popen(subpix_cmd("record", *args), stdout=out, stderr=err, text=True)
    try:
        yield rec
    finally:
        if rec.poll() is None:
            rec.kill()


def _interrupt(rec, log, sig=signal.SIGINT):
    """Send ``sig`` to the recorder; its (stdout, stderr) once it has exited (see :func:`_wait`)."""
    rec.send_signal(sig)
    return _wait(rec, 20, log)


def _read(log):
    return Path(f"{log}.out").read_text(), Path(f"{log}.err").read_text()


def test_recorder_waits_for_a_publisher_that_starts_late(sample_bags, tmp_path):
    """Recorder first, publisher 12 s later: every message recorded.

    (Was: exit after 10 s, 'no publisher found'.)
    """
    bag = sample_bags / "subpixel"
    original = {t: [m.raw for m in read_messages(bag, [t])] for t in TOPICS}
    total = sum(len(v) for v in original.values())
    ns, out = _ns(), tmp_path / "late.mcap"
    log = tmp_path / "rec"
    with _recording(log, "-o", str(out), *(ns + t for t in TOPICS), "--count", str(total)) as rec:
        time.sleep(12.5)
        assert rec.poll() is None, f"the recorder quit before the publisher started: {_read(log)}"
        play = _replay(bag, ns, TOPICS)
        assert play.returncode == 0, play.stderr
        rec_out, err = _wait(
            rec, 30, log, f"\n--- replay stdout\n{play.stdout}\n--- replay stderr\n{play.stderr}"
        )
    assert rec.returncode == 0, err
    assert f"recorded {total} messages" in rec_out
    assert {t: [m.raw for m in read_messages(out, [ns + t])] for t in TOPICS} == original


def test_recorder_subscribes_each_topic_when_it_appears_and_stops_cleanly_on_sigint(
    sample_bags, tmp_path
):
    """Two topics published one after the other, a third never: both recorded.

    Then SIGINT leaves a complete bag (readable, every chunk checked) and a warning naming the
    missing topic.
    """
    bag = sample_bags / "subpixel"
    first, second = TOPICS
    original = {t: [m.raw for m in read_messages(bag, [t])] for t in TOPICS}
    ns, out = _ns(), tmp_path / "two.mcap"
    log = tmp_path / "rec"
    with _recording(log, "-o", str(out), ns + first, ns + second, ns + "/never") as rec:
        play1 = _replay(bag, ns, [first])
        assert play1.returncode == 0, play1.stderr
        play2 = _replay(bag, ns, [second])
        assert play2.returncode == 0, play2.stderr
        time.sleep(1.0)
        assert rec.poll() is None
        rec_out, err = _interrupt(rec, log)
    assert rec.returncode == 0, err
    assert f"no publisher appeared for {ns}/never" in err
    assert {t.name: t.count for t in bag_topics(out)} == {ns + t: len(original[t]) for t in TOPICS}
    assert {t: [m.raw for m in read_messages(out, [ns + t])] for t in TOPICS} == original


def test_recorder_sigterm_leaves_a_complete_bag(sample_bags, tmp_path):
    bag = sample_bags / "subpixel"
    topic = TOPICS[1]
    ns, out = _ns(), tmp_path / "term.mcap"
    log = tmp_path / "rec"
    with _recording(log, "-o", str(out), ns + topic) as rec:
        play = _replay(bag, ns, [topic])
        assert play.returncode == 0, play.stderr
        time.sleep(1.0)
        rec_out, err = _interrupt(rec, log, signal.SIGTERM)
    assert rec.returncode == 0, err
    assert [m.raw for m in read_messages(out)] == [m.raw for m in read_messages(bag, [topic])]


def test_recorder_discover_timeout(tmp_path):
    t0 = time.monotonic()
    r = subprocess.run(
        subpix_cmd(
            "record", "-o", str(tmp_path / "x.mcap"), _ns() + "/nobody", "--discover-timeout", "1.5"
        ),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode != 0
    lines = [ln for ln in r.stderr.splitlines() if ln.strip()]
    assert (
        len(lines) == 1
        and "no publisher found for topic(s)" in lines[0]
        and "within 1.5 s" in lines[0]
    )
    assert time.monotonic() - t0 < 20
    assert not (tmp_path / "x.mcap").exists()


def test_recorder_takes_a_latched_topic_and_the_replay_keeps_it_latched(tmp_path, rclpy_node):
    """A transient-local publisher that published before the recorder started.

    The recorder subscribes transient local (as the publisher offers) and gets its last messages,
    stores the offered QoS in the bag, and `subpix replay` offers the topic transient local again.
    """
    import rclpy
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from rosbags.interfaces import QosDurability, QosReliability
    from std_msgs.msg import String

    topic = _ns() + "/latched"
    latched = QoSProfile(
        depth=5, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
    )
    pub = rclpy_node.create_publisher(String, topic, latched)
    for i in range(3):
        pub.publish(String(data=f"state {i}"))
    out = tmp_path / "latched.mcap"
    log = tmp_path / "rec"
    with _recording(log, "-o", str(out), topic, "--count", "3") as rec:
        deadline = time.monotonic() + 30
        while rec.poll() is None and time.monotonic() < deadline:
            rclpy.spin_once(rclpy_node, timeout_sec=0.05)
        rec_out, err = _wait(rec, 5, log)
    assert rec.returncode == 0, err
    from rclpy.serialization import deserialize_message

    assert [deserialize_message(m.raw, String).data for m in read_messages(out)] == [
        f"state {i}" for i in range(3)
    ]
    (info,) = bag_topics(out)
    assert [q.durability for q in info.qos] == [QosDurability.TRANSIENT_LOCAL]
    assert info.qos[0].reliability == QosReliability.RELIABLE  # (depth is not discoverable: 0)
    rclpy_node.destroy_publisher(pub)
    # replayed: while the replay waits for a subscriber (--wait-for), its publisher is in the graph
    # offering transient local, as recorded; then a transient-local subscriber gets the 3 messages
    replay_topic = topic + "_again"
    play = subprocess.Popen(
        subpix_cmd(
            "replay",
            str(out),
            "--remap",
            f"{topic}:={replay_topic}",
            "--wait-for",
            topic,
            "--wait-timeout",
            "30",
            "--delay",
            "0",
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    got = []
    try:
        deadline = time.monotonic() + 30
        offered = []
        while not offered and time.monotonic() < deadline:
            offered = rclpy_node.get_publishers_info_by_topic(replay_topic)
            rclpy.spin_once(rclpy_node, timeout_sec=0.05)
        assert [i.qos_profile.durability for i in offered] == [DurabilityPolicy.TRANSIENT_LOCAL]
        rclpy_node.create_subscription(
            String,
            replay_topic,
            lambda m: got.append(m.data),
            QoSProfile(
                depth=10,
                reliability=ReliabilityPolicy.RELIABLE,
                durability=DurabilityPolicy.TRANSIENT_LOCAL,
            ),
        )
        deadline = time.monotonic() + 20
        while len(got) < 3 and time.monotonic() < deadline:
            rclpy.spin_once(rclpy_node, timeout_sec=0.05)
        play.communicate(timeout=30)
    finally:
        if play.poll() is None:
            play.kill()
    assert play.returncode == 0
    assert got == [f"state {i}" for i in range(3)]


def test_sigusr1_prints_the_stacks_and_the_recorder_goes_on(tmp_path):
    """``kill -USR1``: every thread's Python stack on stderr; the command keeps running."""
    log, topic = tmp_path / "rec", _ns() + "/nobody"
    with _recording(log, "-o", str(tmp_path / "x.mcap"), topic) as rec:
        deadline = time.monotonic() + 30
        while "waiting for publishers" not in _read(log)[0] and time.monotonic() < deadline:
            time.sleep(0.1)
        rec.send_signal(signal.SIGUSR1)
        time.sleep(1.0)
        assert rec.poll() is None, _read(log)
        out, err = _interrupt(rec, log)
    assert "Current thread" in err and "subpix_ros/cli/record.py" in err, err
    assert rec.returncode != 0 and f"no publisher appeared for {topic}" in err


def test_frames_lost_in_transport_are_said_by_the_recorder(tmp_path):
    """A camera's frames that never reached the recorder: a warning naming the topic and count.

    (Was: the bag simply lacked them, exit 0, "recorded N messages".) The burst camera (no
    package profile, 1.5 MB frames over UDP) loses some of its 100 frames in transport.
    """
    from conftest import burst_camera

    topic, out, log = _ns() + "/camera", tmp_path / "lossy.mcap", tmp_path / "rec"
    with _recording(log, "-o", str(out), topic) as rec:
        cam = burst_camera(topic)
        assert "sent 1" in cam.stdout, cam.stdout + cam.stderr
        rec_out, err = _interrupt(rec, log)
    assert rec.returncode == 0, err
    kept = len(list(read_messages(out)))
    assert (
        f"messages lost in transport before the recorder took them, not in the bag: {topic} "
        in (err)
    ), err
    lost = int(err.split(f"{topic} ")[1].split()[0])
    assert lost > 0 and kept + lost <= 100, (kept, lost)
