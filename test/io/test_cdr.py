"""Raw CDR fast path: byte layout vs rosbags and rclpy, and real rclpy raw pub/sub across processes."""

from __future__ import annotations

import array
import os
import random
import subprocess
import sys
import textwrap
import time
import uuid
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from subpix_ros.io.cdr import (
    COMPRESSED_IMAGE,
    IMAGE,
    TYPESTORE,
    CdrError,
    cdr_to_compressed,
    cdr_to_float64_array,
    cdr_to_image,
    cdr_to_image_msg,
    cdr_to_time_reference,
    cdr_to_vector3_stamped,
    compressed_to_cdr,
    deserialize,
    float64_array_to_cdr,
    header_to_ns,
    image_to_cdr,
    make_header,
    serialize,
    time_reference_to_cdr,
    vector3_stamped_to_cdr,
)
from subpix_ros.io.images import ImageConversionError, numpy_to_image_fields

ROOT = Path(__file__).resolve().parents[2]
STAMP = 1_700_000_123_456_789_012


@pytest.fixture(scope="module")
def bgr(crops):
    g = crops["crop_road"][:120, :160]
    return np.ascontiguousarray(np.dstack([g, np.roll(g, 5, 1), np.roll(g, 9, 0)]))


def rosbags_image_bytes(array_, encoding, stamp_ns, frame_id, step=None, bigendian=False):
    f = numpy_to_image_fields(array_, encoding, step=step, bigendian=bigendian)
    msg = TYPESTORE.types[IMAGE](header=make_header(stamp_ns, frame_id), **f)
    return bytes(TYPESTORE.serialize_cdr(msg, IMAGE))


def rclpy_image(array_, encoding, stamp_ns, frame_id, step=None):
    from sensor_msgs.msg import Image

    f = numpy_to_image_fields(array_, encoding, step=step)
    m = Image()
    m.header.stamp.sec, m.header.stamp.nanosec = divmod(stamp_ns, 10**9)
    m.header.frame_id = frame_id
    m.height, m.width, m.encoding, m.is_bigendian, m.step = (
        f["height"],
        f["width"],
        encoding,
        0,
        f["step"],
    )
    m.data = array.array("B", f["data"].tobytes())
    return m


# ----------------------------------------------------------------------------- layout


@settings(max_examples=40, deadline=None)
@given(
    frame_id=st.text(alphabet="abcxyz_/0", max_size=9),
    encoding=st.sampled_from(
        ["mono8", "mono16", "bgr8", "rgba8", "32FC1", "yuv422_yuy2", "bayer_gbrg8", "16SC3"]
    ),
    h=st.integers(1, 6).map(lambda k: 2 * k),
    w=st.integers(1, 6).map(lambda k: 2 * k),
    pad=st.integers(0, 7),
    bigendian=st.booleans(),
    stamp=st.integers(0, 2**31 * 10**9 - 1),
    seed=st.integers(0, 2**32 - 1),
)
def test_image_to_cdr_matches_rosbags_bytes(frame_id, encoding, h, w, pad, bigendian, stamp, seed):
    from subpix_ros.io.images import encoding_info

    info = encoding_info(encoding)
    rng = np.random.default_rng(seed)
    if info.kind == "bayer" or info.kind == "yuv422":
        a = rng.integers(0, 256, (h, w, 3), dtype=np.uint8)
    else:
        shape = (h, w) if info.channels == 1 else (h, w, info.channels)
        a = np.frombuffer(rng.bytes(h * w * info.pixel_bytes), dtype=info.dtype).reshape(shape)
    row = w * info.pixel_bytes
    raw = image_to_cdr(a, encoding, stamp, frame_id, step=row + pad, bigendian=bigendian)
    assert isinstance(raw, bytes)
    assert raw == rosbags_image_bytes(
        a, encoding, stamp, frame_id, step=row + pad, bigendian=bigendian
    )


def test_rclpy_reads_our_bytes_and_we_read_rclpys(bgr):
    from rclpy.serialization import deserialize_message, serialize_message
    from sensor_msgs.msg import Image

    raw = image_to_cdr(bgr, "bgr8", STAMP, "camera_optical", step=bgr.shape[1] * 3 + 4)
    m = deserialize_message(raw, Image)
    assert (m.height, m.width, m.encoding, m.is_bigendian, m.step) == (120, 160, "bgr8", 0, 484)
    assert (m.header.stamp.sec, m.header.stamp.nanosec, m.header.frame_id) == (
        1_700_000_123,
        456_789_012,
        "camera_optical",
    )
    rows = np.frombuffer(m.data, np.uint8).reshape(120, 484)
    np.testing.assert_array_equal(rows[:, :480].reshape(120, 160, 3), bgr)

    their = serialize_message(rclpy_image(bgr, "bgr8", STAMP, "camera_optical", step=484))
    img, header = cdr_to_image(their)
    np.testing.assert_array_equal(img, bgr)
    assert header_to_ns(header) == STAMP and header.frame_id == "camera_optical"
    # Round trip through rclpy: their re-serialisation of our message parses to the same thing.
    img2, header2 = cdr_to_image(serialize_message(m))
    np.testing.assert_array_equal(img2, bgr)
    assert header_to_ns(header2) == STAMP


def test_cdr_to_image_is_zero_copy(bgr):
    raw = image_to_cdr(bgr, "bgr8", STAMP)
    msg = cdr_to_image_msg(raw)
    img, _ = cdr_to_image(raw)
    base = np.frombuffer(raw, np.uint8)
    assert np.shares_memory(msg.data, base) and np.shares_memory(img, base)
    assert not img.flags.writeable
    buf = bytearray(raw)
    img_rw, _ = cdr_to_image(buf)
    buf[-1] ^= 0xFF
    assert img_rw[-1, -1, -1] == bgr[-1, -1, -1] ^ 0xFF


def test_huge_frame_fast_path_memory():
    """8000x6000: image_to_cdr allocates the message once; cdr_to_image allocates nothing."""
    import tracemalloc

    big = np.zeros((6000, 8000), np.uint8)
    big[::101, ::103] = 9
    tracemalloc.start()
    try:
        raw = image_to_cdr(big, "mono8", STAMP, "cam")
        _, peak_ser = tracemalloc.get_traced_memory()
        tracemalloc.reset_peak()
        base, _ = tracemalloc.get_traced_memory()
        img, _ = cdr_to_image(raw)
        current, peak_de = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    assert big.nbytes <= len(raw) < peak_ser + 1 and peak_ser < big.nbytes + 1_000_000
    assert peak_de - base < 1_000_000
    assert (
        img.shape == big.shape
        and img[101, 103] == 9
        and np.shares_memory(img, np.frombuffer(raw, np.uint8))
    )


def test_desired_through_cdr(bgr):
    import cv2

    raw = image_to_cdr(bgr, "bayer_rggb8", STAMP)
    img, _ = cdr_to_image(raw, "mono8")
    assert img.shape == bgr.shape[:2] and img.dtype == np.uint8
    raw_rgb = image_to_cdr(bgr[..., ::-1].copy(), "rgb8", STAMP)
    np.testing.assert_array_equal(
        cdr_to_image(raw_rgb, "mono8")[0], cv2.cvtColor(bgr, cv2.COLOR_BGR2GRAY)
    )


def test_make_header_and_stamps():
    h = make_header(STAMP, "map")
    assert (h.stamp.sec, h.stamp.nanosec, h.frame_id) == (1_700_000_123, 456_789_012, "map")
    assert header_to_ns(h) == STAMP
    neg = make_header(-1)
    assert (neg.stamp.sec, neg.stamp.nanosec) == (-1, 999_999_999) and header_to_ns(neg) == -1
    with pytest.raises(CdrError, match="int32 seconds range"):
        make_header(2**31 * 10**9)
    with pytest.raises(CdrError, match="integer number of nanoseconds"):
        make_header(1.5)
    with pytest.raises(CdrError, match="frame_id must be a string"):
        image_to_cdr(np.zeros((2, 2), np.uint8), "mono8", 0, frame_id=None)


def test_bad_cdr_bytes(bgr):
    raw = image_to_cdr(bgr, "bgr8", STAMP, "cam")
    with pytest.raises(CdrError, match="not a valid sensor_msgs/msg/Image"):
        cdr_to_image(raw[:-100])  # truncated in the pixel data
    with pytest.raises(CdrError, match="not a valid sensor_msgs/msg/Image"):
        cdr_to_image(raw[:30])  # truncated in the header
    with pytest.raises(CdrError, match="not a valid"):
        cdr_to_image(b"\x07\x07" + raw[2:])  # unknown encapsulation
    with pytest.raises(CdrError, match="not a valid"):
        cdr_to_image(b"")
    with pytest.raises(CdrError, match="bytes-like"):
        cdr_to_image(12345)
    # Well-formed CDR whose image fields disagree with the data: the image layer says so.
    f = numpy_to_image_fields(bgr, "bgr8")
    f["height"] = 100
    bad = serialize(TYPESTORE.types[IMAGE](header=make_header(0), **f), IMAGE)
    with pytest.raises(ImageConversionError, match="too long"):
        cdr_to_image(bad)
    with pytest.raises(ImageConversionError, match="unknown image encoding 'bgr7'"):
        cdr_to_image(image_to_cdr(bgr, "bgr8", 0).replace(b"bgr8", b"bgr7", 1))


def test_compressed_through_cdr(bgr):
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import CompressedImage

    raw = compressed_to_cdr(bgr, STAMP, "cam", fmt="png")
    img, header = cdr_to_compressed(raw)
    np.testing.assert_array_equal(img, bgr)
    assert header_to_ns(header) == STAMP
    m = deserialize_message(raw, CompressedImage)
    assert m.format == "bgr8; png compressed bgr8" and m.header.frame_id == "cam"
    raw_j = compressed_to_cdr(bgr, STAMP, fmt="jpeg", quality=92)
    assert deserialize(raw_j, COMPRESSED_IMAGE).format == "bgr8; jpeg compressed bgr8"
    assert cdr_to_compressed(raw_j, "mono8")[0].shape == bgr.shape[:2]
    # Corrupt payload inside a valid CDR envelope.
    msg = deserialize(raw, COMPRESSED_IMAGE)
    msg.data = msg.data[: msg.data.size // 2].copy()
    with pytest.raises(ImageConversionError, match="truncated"):
        cdr_to_compressed(serialize(msg, COMPRESSED_IMAGE))


def test_float64_array_and_vector3():
    from geometry_msgs.msg import Vector3Stamped
    from rclpy.serialization import deserialize_message
    from std_msgs.msg import Float64MultiArray

    a = np.arange(12, dtype=np.float64).reshape(3, 4) / 7
    raw = float64_array_to_cdr(a, ["rows", "cols"])
    np.testing.assert_array_equal(cdr_to_float64_array(raw), a)
    m = deserialize_message(raw, Float64MultiArray)
    assert [(d.label, d.size, d.stride) for d in m.layout.dim] == [("rows", 3, 12), ("cols", 4, 4)]
    np.testing.assert_array_equal(np.array(m.data), a.ravel())
    np.testing.assert_array_equal(
        cdr_to_float64_array(float64_array_to_cdr([1.5, -2.0])), [1.5, -2.0]
    )
    with pytest.raises(CdrError, match="labels"):
        float64_array_to_cdr(a, ["only_one"])

    rv = vector3_stamped_to_cdr((0.25, -1.5, 3.0), STAMP, "cam")
    v, h = cdr_to_vector3_stamped(rv)
    np.testing.assert_array_equal(v, [0.25, -1.5, 3.0])
    assert header_to_ns(h) == STAMP and h.frame_id == "cam"
    mv = deserialize_message(rv, Vector3Stamped)
    assert (mv.vector.x, mv.vector.y, mv.vector.z) == (0.25, -1.5, 3.0)
    with pytest.raises(CdrError, match="3 values"):
        vector3_stamped_to_cdr((1.0, 2.0), 0)


def test_time_reference_round_trip_and_rclpy():
    from rclpy.serialization import deserialize_message
    from sensor_msgs.msg import TimeReference

    ref = STAMP - 2_345_678_901
    raw = time_reference_to_cdr(STAMP, ref, "cam", "subpix_ros reference frame")
    stamp, time_ref, msg = cdr_to_time_reference(raw)
    assert (stamp, time_ref, msg.header.frame_id, msg.source) == (
        STAMP,
        ref,
        "cam",
        "subpix_ros reference frame",
    )
    m = deserialize_message(raw, TimeReference)
    assert (
        m.time_ref.sec * 10**9 + m.time_ref.nanosec == ref
        and m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == STAMP
    )
    with pytest.raises(CdrError):
        time_reference_to_cdr(STAMP, 2**80)
    with pytest.raises(CdrError):
        cdr_to_time_reference(b"\x00\x01\x00\x00\x01")


# ----------------------------------------------------------------------------- rclpy, two processes

EXPECTED_SRC = textwrap.dedent(
    """
    import numpy as np
    def expected():
        r, c = np.mgrid[0:90, 0:120]
        return np.stack([(r * 3 + c) % 256, (c * 5) % 256, (r * c) % 256], -1).astype(np.uint8)
    STAMP = 1_700_000_123_456_789_012
    """
)
exec(EXPECTED_SRC)  # defines expected(), the same image the child process builds

PUBLISHER = EXPECTED_SRC + textwrap.dedent(
    """
    import sys, time, array
    import rclpy
    from sensor_msgs.msg import Image
    from subpix_ros.io.cdr import image_to_cdr
    topic_raw, topic_typed, seconds = sys.argv[1], sys.argv[2], float(sys.argv[3])
    rclpy.init()
    node = rclpy.create_node("subpix_test_publisher")
    pub_raw = node.create_publisher(Image, topic_raw, 10)
    pub_typed = node.create_publisher(Image, topic_typed, 10)
    img = expected()
    raw = image_to_cdr(img, "bgr8", STAMP, "cam_raw")
    typed = Image()
    typed.header.stamp.sec, typed.header.stamp.nanosec = divmod(STAMP, 10**9)
    typed.header.frame_id = "cam_typed"
    typed.height, typed.width, typed.encoding, typed.step = 90, 120, "bgr8", 360
    typed.data = array.array("B", img.tobytes())
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline:
        pub_raw.publish(raw)
        pub_typed.publish(typed)
        time.sleep(0.1)
    node.destroy_node()
    rclpy.shutdown()
    """
)

SUBSCRIBER = EXPECTED_SRC + textwrap.dedent(
    """
    import faulthandler, sys, time
    faulthandler.dump_traceback_later(30)  # a hang (e.g. in DDS start-up) shows where, before the test gives up
    import numpy as np
    import rclpy
    from sensor_msgs.msg import Image
    topic, seconds = sys.argv[1], float(sys.argv[2])
    rclpy.init()
    node = rclpy.create_node("subpix_test_subscriber")
    got = []
    node.create_subscription(Image, topic, got.append, 10)
    print("READY", flush=True)
    deadline = time.monotonic() + seconds
    while not got and time.monotonic() < deadline:
        rclpy.spin_once(node, timeout_sec=0.1)
    if not got:
        print("TIMEOUT", flush=True)
        sys.exit(2)
    m = got[0]
    img = np.frombuffer(m.data, np.uint8).reshape(m.height, m.step)[:, : m.width * 3].reshape(m.height, m.width, 3)
    ok = (m.encoding == "bgr8" and m.header.frame_id == "cam_test" and np.array_equal(img, expected())
          and m.header.stamp.sec * 10**9 + m.header.stamp.nanosec == STAMP)
    print("OK" if ok else f"MISMATCH {m.encoding} {m.header.frame_id} {m.height}x{m.width}", flush=True)
    sys.exit(0 if ok else 1)
    """
)


@pytest.fixture
def ros_env(monkeypatch):
    """Pick a private DDS domain on this machine for one test (other runs may share the host)."""
    domain = random.randint(1, 100)
    monkeypatch.setenv("ROS_DOMAIN_ID", str(domain))
    monkeypatch.setenv("ROS_AUTOMATIC_DISCOVERY_RANGE", "LOCALHOST")
    monkeypatch.setenv(
        "RMW_IMPLEMENTATION", os.environ.get("RMW_IMPLEMENTATION", "rmw_fastrtps_cpp")
    )
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + os.pathsep + env.get("PYTHONPATH", "")
    return domain, env


@pytest.fixture
def rclpy_node(ros_env):
    import rclpy
    from rclpy.executors import SingleThreadedExecutor

    domain, _ = ros_env
    ctx = rclpy.Context()
    rclpy.init(context=ctx, domain_id=domain)
    node = rclpy.create_node(f"subpix_test_{uuid.uuid4().hex[:8]}", context=ctx)
    executor = SingleThreadedExecutor(context=ctx)
    executor.add_node(node)
    try:
        yield node, executor
    finally:
        executor.shutdown()
        node.destroy_node()
        rclpy.shutdown(context=ctx)


def _kill(proc):
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(timeout=5)


def test_rclpy_raw_subscription_receives_our_bytes(ros_env, rclpy_node):
    """Receive raw CDR image bytes published by a child process.

    A child process publishes image_to_cdr bytes (raw) and an rclpy Image (typed);
    we subscribe with raw=True and get bytes that cdr_to_image turns into the image.
    """
    from sensor_msgs.msg import Image

    _, env = ros_env
    node, executor = rclpy_node
    tag = uuid.uuid4().hex[:8]
    topics = {"raw": f"/subpix_test/raw_{tag}", "typed": f"/subpix_test/typed_{tag}"}
    got: dict[str, object] = {}
    for key, topic in topics.items():
        node.create_subscription(
            Image, topic, lambda b, key=key: got.setdefault(key, b), 10, raw=True
        )
    proc = subprocess.Popen(
        [sys.executable, "-c", PUBLISHER, topics["raw"], topics["typed"], "40"],
        env=env,
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 40
        while len(got) < 2 and time.monotonic() < deadline and proc.poll() is None:
            executor.spin_once(timeout_sec=0.1)
    finally:
        _kill(proc)
    assert len(got) == 2, (
        f"received {sorted(got)} only; publisher stderr: {proc.stderr.read()[-2000:]}"
    )
    for key, frame_id in (("raw", "cam_raw"), ("typed", "cam_typed")):
        assert isinstance(got[key], bytes)
        img, header = cdr_to_image(got[key])
        np.testing.assert_array_equal(img, expected())  # noqa: F821 (exec above)
        assert header_to_ns(header) == STAMP and header.frame_id == frame_id


def test_rclpy_typed_subscriber_receives_our_raw_publish(ros_env, rclpy_node):
    """Publish raw CDR image bytes to a typed subscriber in a child process.

    We publish image_to_cdr bytes with publisher.publish(raw); a child process with an
    ordinary typed rclpy subscription checks the image it receives.
    """
    from sensor_msgs.msg import Image

    _, env = ros_env
    node, executor = rclpy_node
    topic = f"/subpix_test/pub_{uuid.uuid4().hex[:8]}"
    pub = node.create_publisher(Image, topic, 10)
    raw = image_to_cdr(expected(), "bgr8", STAMP, "cam_test")  # noqa: F821 (exec above)
    proc = subprocess.Popen(
        [sys.executable, "-c", SUBSCRIBER, topic, "40"],
        env=env,
        cwd=ROOT,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    try:
        deadline = time.monotonic() + 45
        while proc.poll() is None and time.monotonic() < deadline:
            pub.publish(raw)
            executor.spin_once(timeout_sec=0.1)
    finally:
        _kill(proc)
    out = proc.stdout.read()
    assert proc.returncode == 0 and "OK" in out, (
        f"subscriber said {out!r}; stderr: {proc.stderr.read()[-2000:]}"
    )
