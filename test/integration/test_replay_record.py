"""`subpix replay` and `subpix record` in their own processes, over real DDS."""

import os
import subprocess
import time

import pytest
from conftest import logged_popen, subpix_cmd

from subpix_ros.io import cdr
from subpix_ros.io.bags import read_messages


def _collect(node, topic, msg_cls, expected, timeout=30.0, proc=None):
    from rclpy.qos import QoSProfile, ReliabilityPolicy

    got = []
    node.create_subscription(
        msg_cls,
        topic,
        lambda raw: got.append(raw),
        QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE),
        raw=True,
    )
    import rclpy

    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline and len(got) < expected:
        rclpy.spin_once(node, timeout_sec=0.05)
    return got


def test_replay_feeds_other_process_with_original_stamps(sample_bags, rclpy_node):
    from sensor_msgs.msg import Image

    bag = sample_bags / "subpixel"
    recorded = [(m.timestamp_ns, m.raw) for m in read_messages(bag, ["/camera/image_raw"])]
    proc = subprocess.Popen(
        subpix_cmd(
            "replay", str(bag), "--topics", "/camera/image_raw", "--wait-for", "/camera/image_raw"
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        got = _collect(rclpy_node, "/camera/image_raw", Image, len(recorded))
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert len(got) == len(recorded)
    # byte-identical pass-through, so every header stamp is the original
    assert [bytes(g) for g in got] == [r for _, r in recorded]
    stamps = [cdr.header_to_ns(cdr.cdr_to_image_msg(g).header) for g in got]
    assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)


def test_replay_rate_and_clock(sample_bags, rclpy_node):
    """--clock publishes bag time on /clock; --rate scales the timing."""
    import rclpy
    from rclpy.qos import QoSProfile
    from rosgraph_msgs.msg import Clock

    bag = sample_bags / "subpixel"
    clocks = []
    rclpy_node.create_subscription(
        Clock,
        "/clock",
        lambda m: clocks.append(m.clock.sec * 10**9 + m.clock.nanosec),
        QoSProfile(depth=100),
    )
    t0 = time.monotonic()
    proc = subprocess.Popen(
        subpix_cmd(
            "replay",
            str(bag),
            "--clock",
            "--rate",
            "0.5",
            "--topics",
            "/camera/image_raw",
            "--wait-for",
            "/clock",
            "--delay",
            "0",
        ),
        stderr=subprocess.PIPE,
        text=True,
    )
    while proc.poll() is None and time.monotonic() - t0 < 30:
        rclpy.spin_once(rclpy_node, timeout_sec=0.05)
    assert proc.returncode == 0, proc.stderr.read()
    first = next(read_messages(bag, ["/camera/image_raw"])).timestamp_ns
    assert clocks and min(clocks) >= first
    span = (max(clocks) - min(clocks)) / 1e9
    assert 0.7 < span < 0.8  # 24 frames at 30 Hz = 0.767 s of bag time
    # at half speed, 0.767 s of bag time takes >= 1.5 s of wall time
    assert time.monotonic() - t0 > 1.5


def test_record_then_replay_round_trip(sample_bags, tmp_path):
    import signal

    from subpix_ros.cli._ros import stop_processes

    bag = sample_bags / "subpixel"
    out = tmp_path / "rec.mcap"
    topics = ("/camera/image_raw", "/telemetry/velocity")
    original = {t: [m.raw for m in read_messages(bag, [t])] for t in topics}
    total = sum(len(v) for v in original.values())
    # Topics of this test alone: a subscriber or publisher of the same names left from an earlier test (or
    # not yet forgotten by discovery) could otherwise satisfy the replay's --wait-for before the recorder's
    # own subscriptions match, or make the recorder take best effort from a stale offer.
    ns = f"/roundtrip_{os.getpid()}_{time.monotonic_ns() % 1_000_000}"
    # the recorder's output in a file (logged_popen), so that any failure below can say what it printed
    rec = logged_popen(
        subpix_cmd(
            "record",
            "-o",
            str(out),
            *(ns + t for t in topics),
            "--count",
            str(total),
            "--discover-timeout",
            "20",
        )
    )
    try:
        play = subprocess.run(
            subpix_cmd(
                "replay",
                str(bag),
                "--topics",
                *topics,
                "--remap",
                *(f"{t}:={ns}{t}" for t in topics),
                "--wait-for",
                *topics,
                "--delay",
                "0.5",
            ),
            capture_output=True,
            text=True,
            timeout=60,
        )
        assert play.returncode == 0, (
            f"replay failed: {play.stdout!r} {play.stderr!r}; recorder said: {rec.stdout.read()!r}"
        )
        try:
            rec.wait(timeout=30)  # it stops by itself once it has every message (--count)
        except subprocess.TimeoutExpired:
            rec.send_signal(signal.SIGUSR1)  # every thread's Python stack into its log
            time.sleep(1.0)
            pytest.fail(
                f"recorder did not finish within 30 s (it stops by itself after {total} "
                f"messages); replay said: {play.stdout!r} {play.stderr!r}; recorder said:\n"
                f"{rec.stdout.read()}"
            )
        rec_out = rec.stdout.read()
    finally:
        stop_processes([rec])  # whatever failed: no recorder left running for the later tests
    assert rec.returncode == 0, rec_out
    recorded = {t: [m.raw for m in read_messages(out, [ns + t])] for t in topics}
    assert recorded == original
    # and what we recorded replays
    again = subprocess.run(
        subpix_cmd("replay", str(out), "--delay", "0", "--no-wait"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert again.returncode == 0 and "replayed" in again.stdout, again.stdout + again.stderr


def test_the_commands_take_the_discovery_listener_off_before_their_participant_goes():
    """`subpix record` / `replay` teardown: the Fast DDS deadlock work-around applies here.

    (Was: a recorder stopping (--count) just as its replay left hung for good in
    ``destroy_node``, about 1 run in 100 of the round trip above: Fast DDS's
    ``set_listener(nullptr)`` with its overflowing infinite timeout, a discovery callback in
    flight; see ``io.participant.detach_discovery_listener``.) If an RMW or Fast DDS upgrade renames
    what it calls, it does nothing and this fails, rather than the hang coming back unseen.
    """
    from subpix_ros.cli._ros import ros_node
    from subpix_ros.io.participant import detach_discovery_listener

    with ros_node("subpix_test_detach", rclpy_signals=False) as node:
        assert detach_discovery_listener(node)


@pytest.mark.parametrize(
    "args, message",
    [
        (["replay", "/nonexistent/bag"], "bag not found"),
        (["replay", "{bag}", "--topics", "/nope"], "not in bag"),
        (["replay", "{corrupt}"], "is corrupt at byte offset 8: no MCAP header record"),
        (["replay", "{bag}", "--rate", "0"], "rate must be > 0"),
        (["replay", "{bag}", "--ack-timeout", "-1"], "--ack-timeout must be >= 0"),
    ],
)
def test_replay_errors_are_one_line(sample_bags, tmp_path, args, message):
    corrupt = tmp_path / "corrupt.mcap"
    corrupt.write_bytes(b"\x89MCAP0\r\n" + b"garbage" * 100)
    args = [a.format(bag=sample_bags / "subpixel", corrupt=corrupt) for a in args]
    r = subprocess.run(subpix_cmd(*args), capture_output=True, text=True, timeout=60)
    assert r.returncode != 0
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(lines) == 1 and message in lines[0], r.stderr


def _damaged_bag(tmp_path, n=45):
    """Write a bag of ``n`` 256x256 images (3 chunks for 45), its second chunk overwritten.

    Returns (bag, offset of that chunk, messages before it, messages after it).
    """
    import numpy as np

    from subpix_ros.io import _mcap
    from subpix_ros.io.bags import BagWriter

    bag = tmp_path / "damaged.mcap"
    with BagWriter(bag) as w:
        for i in range(n):
            img = np.random.default_rng(i).integers(0, 256, (256, 256)).astype(np.uint8)
            w.write(
                "/camera/image_raw",
                "sensor_msgs/msg/Image",
                10**9 + i * 10**7,
                cdr.image_to_cdr(img, "mono8", 10**9 + i * 10**7, "cam"),
            )
    f, _ = _mcap.open_mcap(bag)
    counts = [sum(c.counts.values()) for c in f.chunks]
    c = f.chunks[1]
    raw = bytearray(bag.read_bytes())
    raw[c.offset + c.length // 2 : c.offset + c.length // 2 + 64] = bytes(64)
    bag.write_bytes(bytes(raw))
    return bag, c.offset, counts[0], counts[2]


def test_ctrl_c_stops_a_looped_replay_cleanly(sample_bags):
    """Ctrl-C (SIGINT) on a looped replay: what went out said, exit 0, no traceback.

    (Was: rclpy's own SIGINT handler invalidated the context under the player: RCLError
    "publisher's context is invalid", a traceback and exit status 1.)
    """
    import signal

    p = subprocess.Popen(
        subpix_cmd("replay", str(sample_bags / "subpixel"), "--loop", "--rate", "0.5", "--no-wait"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        # as a shell starts `subpix replay ... &`: SIGINT inherited ignored
        preexec_fn=lambda: signal.signal(signal.SIGINT, signal.SIG_IGN),
    )
    try:
        time.sleep(5.0)
        assert p.poll() is None
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0 and "Traceback" not in err, err
    assert "replayed" in out, out


def test_ctrl_c_while_a_replay_waits_for_its_subscribers_is_no_error(sample_bags):
    """Ctrl-C (or the ``subpix demo`` that started it stopping it) during ``--wait-for``.

    Nothing replayed, said, exit 0 as a stopped replay (was: "error: no subscribers on ...
    within 60 s" after a few seconds, exit 1, on the demo's terminal when it was interrupted).
    """
    import signal

    p = subprocess.Popen(
        subpix_cmd(
            "replay",
            str(sample_bags / "subpixel"),
            "--wait-for",
            "/camera/image_raw",
            "--wait-timeout",
            "60",
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        time.sleep(5.0)  # no subscriber: still waiting
        assert p.poll() is None
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=30)
    finally:
        if p.poll() is None:
            p.kill()
    assert p.returncode == 0 and not err.strip(), err
    assert "replayed 0 messages" in out, out


def test_replay_stops_at_a_damaged_chunk(tmp_path):
    """Issue 19 item 2: the first bad offset and the count read, one line, non-zero exit.

    (Was: the damaged chunk's messages lost without a word, exit 0.)
    """
    bag, offset, before, _ = _damaged_bag(tmp_path)
    r = subprocess.run(
        # no subscriber here: --no-wait, or the replay waits 15 s for one and says so
        subpix_cmd("replay", str(bag), "--delay", "0", "--no-wait"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode != 0
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    assert len(lines) == 1, r.stderr
    assert (
        f"corrupt at byte offset {offset}" in lines[0]
        and f"{before} message(s) could be read" in lines[0]
    )
    assert f"replayed {before} messages before it" in lines[0]


def test_replay_skip_corrupt_reports_what_it_skipped(tmp_path):
    bag, offset, before, after = _damaged_bag(tmp_path)
    r = subprocess.run(
        subpix_cmd("replay", str(bag), "--delay", "0", "--skip-corrupt", "--no-wait"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode != 0
    assert f"replayed {before + after} messages" in r.stdout
    lines = [line for line in r.stderr.splitlines() if line.strip()]
    lost = 45 - before - after
    assert (
        len(lines) == 1 and f"skipped 1 corrupt record(s) holding {lost} message(s)" in lines[0]
    ), r.stderr
    assert f"byte offset {offset}" in lines[0]


def test_replay_unknown_message_type(tmp_path):
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    from subpix_ros.io.bags import BagWriter

    store = get_typestore(Stores.ROS2_JAZZY)
    # a type this machine's rclpy has no Python package for
    store.register(get_types_from_msg("string data", "nosuch_msgs/msg/Thing"))
    raw = store.serialize_cdr(
        store.types["nosuch_msgs/msg/Thing"](data="x"), "nosuch_msgs/msg/Thing"
    )
    with BagWriter(tmp_path / "odd", typestore=store) as w:
        w.write("/odd", "nosuch_msgs/msg/Thing", 1, raw)
    r = subprocess.run(
        subpix_cmd("replay", str(tmp_path / "odd")), capture_output=True, text=True, timeout=60
    )
    assert (
        r.returncode != 0
        and "unknown message type" in r.stderr
        and len(r.stderr.strip().splitlines()) == 1
    )


def _replay_to_a_stalled_recorder(node, bag, out, *replay_args, count=0):
    """Run `subpix record` of /camera/image_raw into ``out`` and `subpix replay` of ``bag``.

    Rate 10, the recorder stopped (SIGSTOP) after it subscribed and BEFORE the first frame:
    replay also waits for a /clock subscriber, which this process creates only once the recorder
    is stopped. Returns (rec, play, t) with ``t`` the time the replay was let go.
    """
    import signal

    import rclpy
    from rosgraph_msgs.msg import Clock

    # UDP only between these two: a process frozen by SIGSTOP cannot then hold a lock inside a Fast DDS
    # shared-memory segment that other participants (later tests) would wait on.
    env = dict(os.environ, FASTDDS_BUILTIN_TRANSPORTS="UDPv4")
    rec = subprocess.Popen(
        subpix_cmd(
            "record",
            "-o",
            str(out),
            "/camera/image_raw",
            "--discover-timeout",
            "30",
            "--count",
            str(count),
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    play = subprocess.Popen(
        subpix_cmd(
            "replay",
            str(bag),
            "--topics",
            "/camera/image_raw",
            "--rate",
            "10",
            "--clock",
            "--wait-for",
            "/camera/image_raw",
            "/clock",
            "--delay",
            "0.5",
            "--wait-timeout",  # the set-up's own wait, not what the tests measure (CI load)
            "60",
            *replay_args,
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env,
    )
    deadline = time.monotonic() + 30
    while node.count_subscribers("/camera/image_raw") < 1 and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.05)
    assert node.count_subscribers("/camera/image_raw") >= 1, "the recorder never subscribed"
    # this process saw the recorder's reader announced; give the replay's participant the same
    # moment to match it (a reader frozen before the replay knows it is never matched: the
    # replay then waits for a subscriber until --wait-timeout and fails, seen once in CI)
    time.sleep(1.0)
    rec.send_signal(signal.SIGSTOP)
    node.create_subscription(Clock, "/clock", lambda m: None, 10)  # lets the replay start
    return rec, play, time.monotonic()


def _finish(*procs):
    """Resume what is still stopped, then stop it cleanly (SIGINT; kill only what hangs)."""
    import signal

    from subpix_ros.cli._ros import stop_processes

    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGCONT)
    stop_processes(procs)


def test_replay_waits_until_a_stalled_subscriber_has_every_message(
    sample_bags, rclpy_node, tmp_path
):
    """A reliable subscriber that falls behind still gets every message.

    Here its process is stopped while the bag plays (14 MB of frames): replay waits for the
    acknowledgements before it exits, instead of tearing its writers down with samples the
    subscriber has yet to receive.
    """
    import signal

    bag = sample_bags / "subpixel"
    out = tmp_path / "slow.mcap"
    rec, play, _ = _replay_to_a_stalled_recorder(rclpy_node, bag, out, count=24)
    try:
        time.sleep(
            3.0
        )  # the bag (0.08 s at rate 10, after 0.5 s) is long published; replay waits for the acks
        assert play.poll() is None, (
            "replay exited while a matched reliable subscriber still lacked messages"
        )
        rec.send_signal(signal.SIGCONT)
        _, err_play = play.communicate(timeout=60)
        assert play.returncode == 0 and "warning" not in err_play, err_play
        _, err = rec.communicate(
            timeout=30
        )  # it stops by itself once it has written all 24 (--count 24)
    finally:
        _finish(rec, play)
    assert rec.returncode == 0, err
    original = [m.raw for m in read_messages(bag, ["/camera/image_raw"])]
    assert [m.raw for m in read_messages(out, ["/camera/image_raw"])] == original


def test_replay_gives_up_on_a_subscriber_that_stays_stalled_and_says_so(
    sample_bags, rclpy_node, tmp_path
):
    rec, play, t0 = _replay_to_a_stalled_recorder(
        rclpy_node, sample_bags / "subpixel", tmp_path / "never.mcap", "--ack-timeout", "2"
    )
    try:
        out, err = play.communicate(timeout=60)
        waited = time.monotonic() - t0
    finally:
        _finish(rec, play)
    assert play.returncode == 0 and "replayed 24 messages" in out
    assert "not every reliable subscriber acknowledged every message within 2 s" in err, err
    assert 2.0 <= waited < 15.0


def test_replay_waits_for_a_subscriber_by_default(sample_bags, rclpy_node):
    """Without --wait-for the replay holds its first message until some replayed topic is matched.

    (Issue 19: an 8-frame bag replayed at once was lost whole while discovery was going on.)
    Old code: the bag was over before the subscriber came.
    """
    from sensor_msgs.msg import Image

    bag = sample_bags / "subpixel"
    n = sum(1 for _ in read_messages(bag, ["/camera/image_raw"]))
    topic = f"/waits_{os.getpid()}_{time.monotonic_ns() % 1_000_000}/image"
    proc = subprocess.Popen(
        subpix_cmd(
            "replay",
            str(bag),
            "--topics",
            "/camera/image_raw",
            "--remap",
            f"/camera/image_raw:={topic}",
        ),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        time.sleep(6.0)  # the subscriber comes late (the bag lasts 2.4 s)
        assert proc.poll() is None, proc.communicate()
        got = _collect(rclpy_node, topic, Image, n, timeout=60)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert len(got) == n, (len(got), out, err)


def test_replay_without_subscriber_goes_ahead_after_the_wait(sample_bags):
    r = subprocess.run(
        subpix_cmd(
            "replay",
            str(sample_bags / "subpixel"),
            "--topics",
            "/camera/image_raw",
            "--remap",
            f"/camera/image_raw:=/nobody_{os.getpid()}",
            "--wait-timeout",
            "1",
        ),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode == 0, r.stderr
    assert "no subscriber on any replayed topic within 1 s: replaying anyway" in r.stderr
    assert "replayed 24 messages" in r.stdout


def test_replay_waits_until_the_topic_has_as_many_readers_as_asked(sample_bags, rclpy_node):
    """--wait-count N: a second reader still being discovered does not miss the first frames.

    The camera of a live pipeline has several readers (registration, mosaic, monitor); with
    --wait-for alone the replay starts when the first is matched.
    """
    import rclpy
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    bag = sample_bags / "subpixel"
    n = sum(1 for _ in read_messages(bag, ["/camera/image_raw"]))
    topic = f"/count_{os.getpid()}_{time.monotonic_ns() % 1_000_000}/image"
    base = ["replay", str(bag), "--topics", "/camera/image_raw"]
    base += ["--remap", f"/camera/image_raw:={topic}", "--wait-for", topic]  # the name it has
    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    got: list[list] = [[], []]
    rclpy_node.create_subscription(Image, topic, got[0].append, qos, raw=True)
    r = subprocess.run(
        subpix_cmd(*base, "--wait-count", "3", "--wait-timeout", "3"),
        capture_output=True,
        text=True,
        timeout=60,
    )
    assert r.returncode != 0, r.stderr
    assert f"fewer than 3 subscribers on {topic} within 3 s" in r.stderr
    proc = subprocess.Popen(
        subpix_cmd(*base, "--wait-count", "2", "--wait-timeout", "60"),
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 4.0  # one reader only: the replay holds its first frame
        while time.monotonic() < deadline:
            rclpy.spin_once(rclpy_node, timeout_sec=0.05)
        assert proc.poll() is None and got[0] == [], proc.communicate()
        rclpy_node.create_subscription(Image, topic, got[1].append, qos, raw=True)
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and min(map(len, got)) < n:
            rclpy.spin_once(rclpy_node, timeout_sec=0.05)
        out, err = proc.communicate(timeout=30)
    finally:
        proc.kill()
    assert proc.returncode == 0, err
    assert [len(g) for g in got] == [n, n]  # the late reader has every frame too
    r = subprocess.run(subpix_cmd(*base[:4], "--wait-count", "2"), capture_output=True, text=True)
    assert r.returncode != 0 and "--wait-count 2: needs --wait-for" in r.stderr
